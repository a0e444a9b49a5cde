"""Screening: from a simulated fault to an operator's verdict, every output time.

Sits above the core (the core never imports it).  Metrics per output time
(:mod:`~fault_screen.screening.metrics`), rules and traffic light
(:mod:`~fault_screen.screening.screener`), and :func:`screen_result`, which evaluates a whole
result and stores the HDF5 group ``/screening/``:

``/screening/{peak_slip_rate, x_peak_slip_rate, slipping_length, max_utilisation,
min_coulomb_margin, delta_cff, injection_overpressure, induced_slip, event_magnitude,
event_distance, event_rate}`` one value per output time (unit attribute each, table
:data:`fault_screen.rules.METRICS`); ``/screening/level`` (0 green, 1 yellow, 2 red);
``/screening/transitions`` compound (time s, from, to, rule).

Runs and the live monitor take the same path step by step
(:class:`~fault_screen.screening.stepwise.StepScreening`)::

    steps = StepScreening.for_scene(scene, fault_x, fault_weights)
    for each new stepper row:  metrics, transitions = steps.update(row, events=new_events)
"""
from __future__ import annotations

import numpy as np

from ..rules import METRICS
from .metrics import FAULT_FIELDS, INJECTION_FIELDS, MetricsTracker, fault_metrics, result_metrics
from .screener import (GREEN, LEVEL_NAMES, RED, UNSTABLE_RULE, YELLOW, Events, Screener, Transition,
                       Verdict, event_metrics, thresholds_of)
from .stepwise import TRANSITION_DTYPE, Screening, StepScreening

__all__ = ["screen_result", "Screening", "Screener", "StepScreening", "MetricsTracker", "event_metrics", "Transition", "Verdict", "Events",
           "fault_metrics", "result_metrics", "thresholds_of", "stopped_unstable", "GREEN", "YELLOW",
           "RED", "LEVEL_NAMES", "UNSTABLE_RULE", "TRANSITION_DTYPE", "METRICS", "read_transitions",
           "screen_file"]



def stopped_unstable(result) -> float | None:
    """Time (s) at which the run stopped on an unstable fault (``meta["stopped"]``), else None."""
    return _stop_time(getattr(result, "meta", None), lambda: result.time[-1])


def _stop_time(meta: dict | None, last_time) -> float | None:
    """The unstable stop of a run's ``meta`` (s), else None; ``last_time()``: the last output
    time, the stop's when the meta has none."""
    stopped = (meta or {}).get("stopped") or {}
    if stopped.get("reason") != "unstable":
        return None
    t = stopped.get("time")
    return float(t) if t is not None else float(last_time())


def _stored_events(result):
    return _events_of((getattr(result, "extra", None) or {}).get("events"))


def _events_of(ev: dict | None):
    """The events of a result's ``/events`` group (name -> array), or None."""
    if not ev or "time" not in ev:
        return None
    # the results' /events group names it distance_to_injection (outputs.SCHEMA)
    distance = ev.get("distance_to_injection", ev.get("distance"))
    return Events(ev["time"], ev["magnitude"], distance)


def _stored_metrics(result) -> dict:
    """The model metrics of a result whose fault profiles ``[output]`` thinned: those its run
    stored at every step (the profiles no longer hold every step)."""
    stored = (getattr(result, "extra", None) or {}).get("screening") or {}
    return {k: np.asarray(stored[k], dtype=float).copy() for k in _model_metric_names(stored)}


def _model_metric_names(stored) -> list:
    """The names of the model metrics (not the event ones), all of which ``stored`` (a
    ``/screening/`` group) must hold to screen a result with thinned profiles again."""
    names = [k for k in METRICS if not k.startswith("event_")]
    if not all(k in stored for k in names):
        raise ValueError("the fault profiles of this result were thinned by [output] and it holds "
                         "no /screening metrics of every step to screen again")
    return names


def screen_result(result, spec=None, events=None, *, store: bool = True) -> Screening:
    """Screen a whole :class:`~fault_screen.Result` with ``spec`` (default: its scene's
    ``[monitor]``) and ``events`` (default: the events stored in the result, if any); store the
    ``/screening/`` group in ``result.extra`` unless ``store`` is false.

    Equal, level for level, to streaming the rows through :class:`MetricsTracker` and
    :class:`Screener` with each event given by its origin time."""
    spec = spec if spec is not None else result.scene.monitor
    events = Events.coerce(events) if events is not None else _stored_events(result)
    metrics = result_metrics(result) if getattr(result, "fault_time", None) is None else _stored_metrics(result)
    t_stop = stopped_unstable(result)
    times = np.asarray(result.time, dtype=float)
    i_stop = None
    if t_stop is not None and times.size:
        i_stop = min(int(np.searchsorted(times, _unstable_from(t_stop))), times.size - 1)
    steps = StepScreening(spec, events=events)
    rows = {k: [] for k in ("event_magnitude", "event_distance", "event_rate")}
    level = np.zeros(times.size, dtype=np.int8)
    for i, t in enumerate(times):
        row = {k: float(v[i]) for k, v in metrics.items()}
        steps.screen(t, row, unstable=(i_stop is not None and i >= i_stop))
        for k in rows:
            rows[k].append(row[k])
        level[i] = steps.level
    metrics.update({k: np.asarray(v, dtype=float) for k, v in rows.items()})
    out = Screening(times, metrics, level, steps.transitions, steps.verdict, spec)
    if store:
        result.extra["screening"] = out.arrays()
    return out


def _unstable_from(t_stop: float | None) -> float | None:
    """The first output time counted unstable for a stop at ``t_stop`` (s) (round-off below
    it); None: no unstable stop."""
    return None if t_stop is None else t_stop - 1e-9 * max(1.0, abs(t_stop))


def screen_file(rf, spec=None, events=None, *, sink=None) -> Screening:
    """:func:`screen_result` of a result file read in bounded pieces
    (:class:`fault_screen.result.ResultFile`: at most ``rf.read_rows`` values of a dataset in
    memory at once), so its length does not count: the same metrics, levels, level changes and
    verdict. ``sink(first_row, arrays)``, if given, receives the ``/screening/`` metrics and
    level of each block of rows (the per-row values are not kept: the returned Screening holds
    the transitions and the verdict, its ``time``, ``metrics`` and ``level`` are None)."""
    spec = spec if spec is not None else rf.scene.monitor
    events = Events.coerce(events) if events is not None else _events_of(rf.group("events"))
    if rf.profiles_per_row():
        paths = [f"fault/{k}" for k in FAULT_FIELDS] + [f"injection/{k}" for k in INJECTION_FIELDS]
        blocks = MetricsTracker(rf.h5["fault/x"][()], rf.h5["fault/weight"][()],
                                rf.scene.fault.friction)

        def metrics_of(block):
            return blocks.block({k: block[f"fault/{k}"] for k in FAULT_FIELDS},
                                {k: block[f"injection/{k}"] for k in INJECTION_FIELDS})
    else:
        names = _model_metric_names(rf.h5["screening"] if "screening" in rf.h5 else {})
        paths = [f"screening/{k}" for k in names]

        def metrics_of(block):
            return {k: np.asarray(block[f"screening/{k}"], dtype=float).copy() for k in names}
    # the rows every dataset read holds (a file still being streamed may be between flushes)
    n = min(rf.h5[p].shape[0] for p in ["time"] + paths)
    unstable_from = _unstable_from(_stop_time(rf.meta, lambda: rf.last("time")) if n else None)
    steps = StepScreening(spec, events=events)
    for i0, block in rf.row_blocks(["time"] + paths, n):
        times = np.asarray(block["time"], dtype=float)
        metrics = metrics_of(block)
        rows = {k: np.empty(times.size) for k in ("event_magnitude", "event_distance", "event_rate")}
        level = np.zeros(times.size, dtype=np.int8)
        for j, t in enumerate(times):
            row = {k: float(v[j]) for k, v in metrics.items()}
            # as screen_result: from the first time at the stop, and the last row at the latest
            unstable = unstable_from is not None and (t >= unstable_from or i0 + j == n - 1)
            steps.screen(t, row, unstable=unstable)
            for k in rows:
                rows[k][j] = row[k]
            level[j] = steps.level
        if sink is not None:
            metrics.update(rows)
            sink(i0, {**metrics, "level": level})
    return Screening(None, None, None, steps.transitions, steps.verdict, spec)


def read_transitions(arrays: dict) -> list[tuple[float, int, int, str]]:
    """The transitions of a stored ``/screening/`` group as (time, from, to, rule) tuples."""
    tr = arrays.get("transitions")
    if tr is None:
        return []
    return [(float(r["time"]), int(r["from"]), int(r["to"]),
             r["rule"].decode("utf-8") if isinstance(r["rule"], bytes) else str(r["rule"])) for r in tr]


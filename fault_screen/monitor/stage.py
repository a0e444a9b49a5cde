"""The live-monitoring stage: samples and events in; model state, level changes and alerts out.

Embedding it::

    from fault_screen.monitor import Stage
    stage = Stage(scene, start=datetime_of_model_time_0)
    upd = stage.feed_samples([0.0, 5.0, 10.0], [0.0, 1.7e-4, 1.7e-4])   # s, m3/s [, Pa]
    stage.feed_events(events)                  # SeismicEvent list (model seconds)
    upd.steps, upd.time, upd.state, upd.transitions, upd.alerts
    stage.checkpoint("state.h5"); stage, _ = Stage.restore("state.h5")
    stage.finish()                             # last partial step, as a replay ends
    stage.result()                             # fault_screen.Result so far

Stepping.  The model never runs ahead of the data: after each batch of samples the stepper is
asked for the whole steps of the scene's own step sequence that end at or before the last
sample (``Simulation.advance(t_last, volume=..., align=True, max_steps=1)`` until it takes no
more), each receiving the log's exact
volume over it (linear rate between samples, the trapezoidal integral computed the way
:class:`~fault_screen.io.injection_log.InjectionLog` computes it, so a replay of the complete
log sees the same floating-point volumes).  The model time is therefore the same whether the
samples come one by one, in chunks or all at once, and after a restart.  ``finish()`` takes the
final partial step to the last sample, as ``fault-screen replay`` ends at the log's last stamp.

Screening.  After every step the screening metrics of the new row plus the event metrics
(``event_magnitude``, ``event_distance``, ``event_rate``) go to the screener; each level
change it returns becomes an alert (:func:`alert_payload`) with a stable id.

Events.  An event whose origin time lies in a step enters that step's metrics if it is known
by then; one reported after the model passed its time enters the next step (associated with
the state at the end of the step that contains its time, if still kept).  ``event_magnitude`` is the largest magnitude
among the events entering the step (NaN if none), ``event_distance`` that event's distance to
the injection point (m, NaN without a site), ``event_rate`` the number of known events with
origin time in the last ``event_window`` seconds, per hour.
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from collections import deque
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path
from time import perf_counter
from typing import List, Optional, Sequence

import numpy as np

from ..io.volume import PiecewiseLinearVolume
from ..stepper import Simulation
from ..screening import Events, StepScreening, event_metrics, screen_result
from ..screening.metrics import MetricsTracker
from .lookahead import (ENSEMBLE_LOOKAHEAD_COLUMNS, LOOKAHEAD_COLUMNS, LiveDrive, LiveLookAhead,
                        forecast_alert, forecast_change, lookahead_arrays, lookahead_record,
                        lookahead_streams, summary_of)
from .seismicity import SeismicEvent, Site, associate

_log = logging.getLogger("fault_screen.monitor")

__all__ = ["Stage", "Update", "SampleBuffer", "alert_payload", "alert_id", "LEVELS"]

LEVELS = ("green", "yellow", "red")
_STATE_ATTR = "fault_screen_monitor"
#: the layout of the stage's state record (plain data only: never code nor import paths)
_STATE_VERSION = 2
#: the checkpoint's group of every sample received (a look-ahead ensemble's history)
_RECEIVED = "monitor_received"
#: what an event association reads from a recorded row
_ROW_KEYS = ("time", "slip_rate", "contact_state", "shear_traction", "effective_normal_stress")


# ---------------------------------------------------------------------------------------------
# samples
# ---------------------------------------------------------------------------------------------
class SampleBuffer:
    """The samples not yet behind the model: their volume (the replay's
    :class:`~fault_screen.io.volume.PiecewiseLinearVolume`, so that every step gets the volume a
    replay gives it, bit for bit) and their pressures.  Samples wholly behind the model are
    dropped (memory stays bounded); the cumulative volume is kept absolute.
    """

    def __init__(self):
        self.flow = PiecewiseLinearVolume()
        self.p: List[Optional[float]] = []
        self.count = 0            # samples accepted since the start of the run

    @property
    def t(self) -> List[float]:
        return self.flow.time.tolist()

    @property
    def q(self) -> List[float]:
        return self.flow.flow_rate.tolist()

    @property
    def last_time(self) -> Optional[float]:
        return float(self.flow.time[-1]) if len(self.flow) else None

    def append(self, t: float, q: float, p: Optional[float]) -> None:
        self.flow.append(t, q)
        self.p.append(p)
        self.count += 1

    def volume(self, t0: float, t1: float) -> float:
        """m3 injected between t0 and t1 (s); t1 must not pass the last sample."""
        if not len(self.flow):
            raise ValueError("no samples yet")
        last = float(self.flow.time[-1])
        if t1 > last * (1 + 1e-12) + 1e-9:
            raise ValueError(f"volume asked up to {t1!r} s, beyond the last sample "
                             f"{last!r} s: the model may not run ahead of the data")
        return self.flow.volume(t0, t1)

    def rate_at(self, t: float) -> float:
        return self.flow.rate_at(t) if len(self.flow) else 0.0

    def drop_before(self, t: float) -> None:
        """Forget samples wholly before ``t`` (keep the one at or just before it)."""
        before = len(self.flow)
        self.flow.drop_before(t)
        del self.p[:before - len(self.flow)]

    def state(self) -> dict:
        return {"t": self.flow.time.tolist(), "q": self.flow.flow_rate.tolist(), "p": self.p,
                "cum": self.flow.cumulative.tolist(), "count": self.count}

    @classmethod
    def from_state(cls, s: dict) -> "SampleBuffer":
        b = cls()
        b.flow = PiecewiseLinearVolume(s["t"], s["q"], s["cum"])
        b.p = list(s["p"])
        b.count = int(s["count"])
        return b


# ---------------------------------------------------------------------------------------------
# alerts
# ---------------------------------------------------------------------------------------------
def _level_name(v) -> str:
    if isinstance(v, str):
        return v
    return LEVELS[int(v)] if v is not None and 0 <= int(v) < len(LEVELS) else str(v)


def _level_code(v) -> Optional[int]:
    if v is None:
        return None
    if isinstance(v, str):
        return LEVELS.index(v) if v in LEVELS else None
    return int(v)


def alert_id(run_key: str, model_time: float, previous, level, rule) -> str:
    """Stable idempotency key of an alert: the same level change of the same run (scene and
    log origin) always gets the same id, also when a restarted monitor recomputes it."""
    text = json.dumps([run_key, repr(float(model_time)), _level_name(previous),
                       _level_name(level), str(rule)])
    return "fs_" + hashlib.sha256(text.encode()).hexdigest()[:32]


def _finite(v):
    try:
        f = float(v)
    except (TypeError, ValueError):
        return v
    return f if math.isfinite(f) else None    # JSON has no NaN/inf: unknown -> null


def alert_payload(*, run_key: str, transition: dict, metrics: dict, start: Optional[datetime],
                  label: str = "") -> dict:
    """The alert handed to the plugins (JSON-able): ``id`` (idempotency key), ``level`` and
    ``previous_level`` (green/yellow/red) with their codes (0/1/2), ``rule``, ``action``,
    ``metrics`` (SI; null where unknown), ``model_time`` (s), ``model_datetime`` (ISO, when the
    log has stamps), ``wall_time`` (ISO UTC), ``scene``."""
    t = float(transition["time"])
    prev, lev = transition.get("previous"), transition.get("level")
    return {
        "id": alert_id(run_key, t, prev, lev, transition.get("rule", "")),
        "level": _level_name(lev), "level_code": _level_code(lev),
        "previous_level": _level_name(prev) if prev is not None else None,
        "previous_level_code": _level_code(prev),
        "rule": str(transition.get("rule", "")), "action": str(transition.get("action", "")),
        "metrics": {k: _finite(v) for k, v in metrics.items()},
        "model_time": t,
        "model_datetime": (start + timedelta(seconds=t)).isoformat() if start else None,
        "wall_time": datetime.now(timezone.utc).isoformat(),
        "scene": label,
    }


def _transition_dict(tr) -> dict:
    """A screener's transition (object or mapping) as a dict with time/previous/level/rule/
    action."""
    get = (lambda k: tr.get(k)) if isinstance(tr, dict) else (lambda k: getattr(tr, k, None))
    first = lambda *ks: next((get(k) for k in ks if get(k) is not None), None)  # noqa: E731
    return {"time": first("time"), "previous": first("previous", "from_level", "from_", "old"),
            "level": first("level", "to_level", "to", "new"), "rule": first("rule", "reason") or "",
            "action": first("action") or ""}


# ---------------------------------------------------------------------------------------------
# the stage
# ---------------------------------------------------------------------------------------------
@dataclass
class Update:
    """What one call to the stage did: ``steps`` taken, model ``time`` (s) after them, ``state``
    (the newest recorded row), ``metrics`` of the newest step, level ``transitions`` (dicts) and
    the ``alerts`` (payload dicts) they raised, ``level`` now; with a look-ahead, the
    ``forecasts`` (rows of the refreshes finished meanwhile) and the ``forecast_alerts`` they
    raised."""

    steps: int = 0
    time: float = 0.0
    state: Optional[dict] = None
    metrics: dict = field(default_factory=dict)
    transitions: list = field(default_factory=list)
    alerts: list = field(default_factory=list)
    level: int = 0
    step_seconds: list = field(default_factory=list)   # wall time of each step taken (s)
    forecasts: list = field(default_factory=list)      # look-ahead rows collected (dicts)
    forecast_alerts: list = field(default_factory=list)   # the forecast alerts they raised


class Stage:
    """Follow injection samples and seismic events with the model and the screening rules.

    ``scene``: a rate-controlled :class:`~fault_screen.Scene`.  ``start``: aware date-time of
    model time 0 (the log's first stamp; needed to place events and for alert times).
    ``simulation``: a stepper with the ``fault_screen.Simulation`` interface (default: a new
    one for ``scene``).  ``screener``: object with ``update(time, metrics, events=...) -> list
    of transitions`` (default: the scene's rules, through the same per-step path as run and
    replay, :class:`~fault_screen.screening.StepScreening`); ``metrics``: function
    ``(row, scene) -> dict`` of the screening metrics of a recorded row (default: the screening
    layer's).  A screener or metrics function given here is checkpointed through its own
    ``state()`` (plain data) and must be given again to :meth:`restore`.  ``site``:
    :class:`~fault_screen.monitor.seismicity.Site` to place hypocentres (default: the scene's
    ``[site]``).  ``event_window``: seconds over which
    ``event_rate`` counts events (default: ``[monitor] event_rate_window``).
    ``lookahead``: a :class:`~fault_screen.monitor.lookahead.LiveLookAhead` (plans, horizon,
    every, advice, forecaster): forecasts refreshed on forks in a worker thread, collected at
    each call (:meth:`poll_forecasts` between calls), kept in :attr:`forecasts` and ``/lookahead``
    of the results, ``on_forecast(rows, alert or None)`` called with each refresh's rows.
    ``on_alert(alert)``: called with each alert (level change or forecast) as soon as it is
    raised, before the stage takes its next step or fork (the service's outbox takes them so:
    the later steps of a batch and a look-ahead fork never delay an alert); the alerts are in
    the returned :class:`Update` as well.
    """

    def __init__(self, scene, *, start: Optional[datetime] = None, simulation=None,
                 screener=None, metrics=None, site: Optional[Site] = None,
                 event_window: Optional[float] = None, label: str = "", history: int = 16,
                 out=None, out_via_temporary: bool = False, lookahead=None, on_forecast=None,
                 on_alert=None):
        if getattr(scene.injection, "control", "rate") != "rate":
            raise ValueError(f"injection.control = {scene.injection.control!r}: the monitor "
                             f"drives the flow rate; use a scene with control = 'rate'")
        if event_window is None:      # the scene's [monitor] event_rate_window, else 1 h
            event_window = getattr(getattr(scene, "monitor", None), "event_rate_window", 3600.0)
        if not event_window > 0:
            raise ValueError(f"event_window must be > 0 s, got {event_window!r}")
        self.scene = scene
        self.start = start
        self.label = label
        self.site = site if site is not None else _site_of(scene)
        self.event_window = float(event_window)
        self.sim = simulation if simulation is not None else _new_simulation(scene)
        # the scene's rules through the one per-step path (bound to the fault points at the
        # first row), or an embedding program's own screener / metrics
        self.screener, self.metrics_fn = screener, metrics
        self.screening: Optional[StepScreening] = None
        self.samples = SampleBuffer()
        self.ignored = 0                  # samples at or before the last one (replays, repeats)
        self.steps = 0
        self.level = 0
        self.pending_events: List[SeismicEvent] = []
        self.event_times: deque = deque()   # origin times of known events, for event_rate
        self._event_ids: set = set()
        self.associations: List[dict] = []
        self.transitions: List[dict] = []
        self.alerts_raised = 0
        self._rows: deque = deque(maxlen=max(1, int(history)))
        self._geometry = None
        # results streamed to this HDF5 file as the stage goes (a stepper that can), else kept
        self.out = Path(out) if out is not None and hasattr(self.sim, "stream_to") else None
        # streamed under OUT.part and renamed when complete (a run without checkpoints, as run
        # and replay write): an earlier OUT stays intact until then
        self.out_via_temporary = bool(out_via_temporary)
        self.screened = 0                 # rows screened, the in-situ row included
        if lookahead is not None and screener is not None:
            raise ValueError("the look-ahead screens its forks with the scene's [monitor] rules: "
                             "it needs the stage's own screening (no screener given)")
        self.lookahead = lookahead
        self.on_forecast = on_forecast
        self.on_alert = on_alert
        self.largest_rate = 0.0           # m3/s, of the samples received (the advice's bound)
        # every sample since time 0, for a look-ahead whose own models follow the data (an
        # ensemble's members, rebuilt from time 0 after a restart); None when none does
        self.received = (PiecewiseLinearVolume() if lookahead is not None
                         and lookahead.follows_samples else None)

    # -- identity ---------------------------------------------------------------------------
    @property
    def run_key(self) -> str:
        """Hash of the scene and the log origin: the namespace of this run's alert ids."""
        text = self.scene.to_toml() if hasattr(self.scene, "to_toml") else repr(self.scene)
        origin = self.start.isoformat() if self.start else ""
        return hashlib.sha256((text + "\n" + origin).encode()).hexdigest()[:16]

    @property
    def time(self) -> float:
        """Model time (s)."""
        return float(self.sim.time)

    @property
    def last_sample_time(self) -> Optional[float]:
        return self.samples.last_time

    # -- input ------------------------------------------------------------------------------
    def feed_samples(self, time, rate, pressure=None) -> Update:
        """Add injection samples (``time`` s of model time, ``rate`` m3/s of the whole interval,
        ``pressure`` Pa or None; scalars or sequences) and advance the model as far as they
        allow.  Samples at or before the last one are ignored and counted in ``ignored`` (a
        restarted source replays its log from the start); the log's own checks (stamps going
        backwards, duplicates, gaps) and policies are the source's, as in a replay."""
        t = np.atleast_1d(np.asarray(time, dtype=np.float64))
        q = np.atleast_1d(np.asarray(rate, dtype=np.float64))
        p = None if pressure is None else np.atleast_1d(np.asarray(pressure, dtype=object))
        if q.shape != t.shape or (p is not None and p.shape != t.shape):
            raise ValueError("time, rate and pressure must have the same length")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q)) and np.all(q >= 0)):
            raise ValueError("sample times and rates must be finite, rates >= 0")
        if self.out is not None and self.sim.writer is None and t.size:
            self._open_stream(with_pressure=p is not None and p[0] is not None)
        writer = self.sim.writer if self.out is not None else None
        for k in range(t.size):
            tk = float(t[k])
            last = self.samples.last_time
            if last is not None and tk <= last:
                self.ignored += 1
                continue
            pk = None if p is None or p[k] is None else float(p[k])
            self.samples.append(tk, float(q[k]), pk)
            if self.received is not None:
                self.received.append(tk, float(q[k]))
            self.largest_rate = max(self.largest_rate, float(q[k]))
            if writer is not None:
                rec = {"/log/time": tk, "/log/flow_rate": float(q[k])}
                if "/log/pressure" in writer.streams["log"]:
                    rec["/log/pressure"] = math.nan if pk is None else pk
                writer.append("log", rec)
        return self._advance(align=True)

    # -- streamed results -------------------------------------------------------------------
    def _open_stream(self, with_pressure: bool) -> None:
        """Start the result file: the model's rows, the screening of every row and the
        samples that drive the model (``/log``, as replay writes it) grow in it as the stage
        goes (readable meanwhile: HDF5 single-writer/multiple-reader)."""
        streams = dict(StepScreening.streams()) if self.screener is None else {}
        log = {"/log/time": ("<f8", ()), "/log/flow_rate": ("<f8", ())}
        if with_pressure:
            log["/log/pressure"] = ("<f8", ())
        streams["log"] = log
        if self.lookahead is not None:
            streams.update(lookahead_streams(self.lookahead.columns))
            self.lookahead._stream = self.lookahead.columns
        self.sim.stream_to(self.stream_path, streams=streams, meta=self._meta())

    @property
    def stream_path(self) -> Optional[Path]:
        """The file the results stream to while the stage runs (``out``, or ``out.part`` when
        renamed at the end)."""
        if self.out is None or not self.out_via_temporary:
            return self.out
        return self.out.with_name(self.out.name + ".part")

    def flush(self) -> None:
        """Write the streamed results so far to the file (readers see them)."""
        if self.out is not None and self.sim.writer is not None:
            self.sim.flush()

    def close(self) -> Optional[Path]:
        """Finish the streamed result file (metadata, level changes, events); returns its path
        (None when the stage keeps its results in memory: see :meth:`result`). The look-ahead
        worker ends after the refresh it runs."""
        if self.lookahead is not None:
            self.lookahead.close()
        if self.out is None or self.sim.writer is None:
            return None
        path = Path(self.sim.close_stream(meta=self._meta(), groups=self._final_groups()))
        if path != self.out:
            os.replace(path, self.out)
            _fsync_dir(self.out.parent)
        return self.out

    def _meta(self) -> dict:
        meta = {"monitor_samples": self.samples.count, "monitor_ignored_samples": self.ignored,
                "monitor_alerts": self.alerts_raised}
        if self.start is not None:
            meta["start"] = self.start.isoformat()
        la = self.lookahead
        if la is not None:      # how many refreshes were made, skipped (busy worker), failed
            meta.update(lookahead=la.settings(), lookahead_made=la.made,
                        lookahead_skipped=la.skipped, lookahead_failed=la.failed)
        return meta

    def feed_events(self, events: Sequence[SeismicEvent]) -> None:
        """Add seismic events or detections (model seconds); they enter the metrics of the step
        that contains their time, or the next step if the model is already past it."""
        for ev in events:
            key = ev.id or f"{ev.kind}@{ev.time!r}"
            if key in self._event_ids:      # a catalogue read again after a restart
                continue
            self._event_ids.add(key)
            self.pending_events.append(ev)
            self.event_times.append(float(ev.time))
        self.pending_events.sort(key=lambda e: e.time)
        self.event_times = deque(sorted(self.event_times))

    def withdraw_events(self, ids) -> None:
        """Forget the events of these ids (an event service revised or deleted them), pending
        or already associated; a revised event is then fed again like a new one."""
        ids = set(ids)
        if not ids:
            return
        screened = [a["time"] for a in self.associations if a.get("id") in ids]
        gone = [e.time for e in self.pending_events if e.id in ids] + screened
        # the screener's event_rate counts them no more (the built-in one, or a custom one that can)
        screener = self.screener if self.screener is not None else \
            (self.screening.screener if self.screening is not None else None)
        if hasattr(screener, "forget_events"):
            screener.forget_events(screened)
        self.pending_events = [e for e in self.pending_events if e.id not in ids]
        self.associations = [a for a in self.associations if a.get("id") not in ids]
        times = list(self.event_times)
        for t in gone:
            if float(t) in times:
                times.remove(float(t))
        self.event_times = deque(times)
        self._event_ids -= ids

    def finish(self) -> Update:
        """Take the final partial step to the last sample (as a replay ends at its last stamp).
        Events reported after the model passed their time and not yet associated are associated
        with the newest state (recorded in the results; no step is left to screen them).
        After it the stage should not be fed again (its step sequence left the scene's)."""
        upd = self._advance(align=False)
        late = [e for e in self.pending_events if e.time <= self.time]
        if late and self._rows:
            self.pending_events = [e for e in self.pending_events if e.time > self.time]
            self.associations.extend(self._associate(e).to_dict() for e in late)
        return upd

    # -- stepping ---------------------------------------------------------------------------
    def _advance(self, align: bool) -> Update:
        upd = Update(time=self.time, level=self.level)
        t_last = self.samples.last_time
        if t_last is None or t_last <= self.time:
            return upd
        if self.screened == 0 and self.steps == 0:
            # the in-situ state at t = 0 is screened too, as replay screens every output time
            self._screen_step(dict(self.sim.last_row), upd)
        # one step per call: each step is screened (and its alerts raised) as soon as it is done;
        # the stepper's sequence state makes this the same steps as one call
        while True:
            wall = perf_counter()
            n = int(self.sim.advance(t_last, volume=self.samples.volume, align=align,
                                     max_steps=1) or 0)
            if n == 0:
                break
            self._screen_step(dict(self.sim.last_row), upd)
            upd.step_seconds.append(perf_counter() - wall)
            upd.steps += 1
            self.steps += 1
            self._refresh_lookahead()
        if upd.steps:
            self.samples.drop_before(self.time)
        self._collect_forecasts(upd)
        upd.time, upd.level = self.time, self.level
        return upd

    # -- look-ahead -------------------------------------------------------------------------
    def _refresh_lookahead(self) -> None:
        """After a step: a look-ahead refresh when one is due (the fork is taken here, between
        two steps; the plans run in the worker)."""
        la = self.lookahead
        if la is None or not la.due(self.time):
            return
        drive = None
        if not la.busy:      # (a busy worker skips the refresh: no drive to make)
            received = None
            if self.received is not None:
                # the samples the forecaster's models still need, a copy of their own: the
                # worker steps them while this thread takes the next samples
                received = _since(self.received, float(la.forecaster.samples_from))
            drive = LiveDrive(self.sim.schedule, self.samples.rate_at(self.time),
                              self.largest_rate, self.time, received=received)
        la.refresh(self.sim, self.screening, drive, self.time, start=self.start)

    def _collect_forecasts(self, upd: Update) -> None:
        la = self.lookahead
        if la is None:
            return
        writer = self.sim.writer if self.out is not None and la._stream else None
        columns = la._stream or la.columns       # (a continued file: the columns it was made with)
        for job in la.collect():
            if job.error is not None:
                la.failed += 1
                _log.error("look-ahead made at t = %.6g s failed (the live monitor goes on):\n%s",
                           job.made_at, job.error)
                continue
            rows = job.rows
            la.made += 1
            for row in rows:
                if writer is not None:
                    writer.append("lookahead", lookahead_record(row, columns))
                else:
                    la.rows.append(row)
                la.latest[str(row["plan"])] = row
            upd.forecasts.extend(rows)
            summary = [summary_of(r) for r in rows]
            alert = None
            if len(summary) == len(la.summary) and summary != la.summary:
                made_at, before, after = forecast_change(rows, la.summary)
                alert = forecast_alert(alert_id=alert_id(self.run_key, made_at, before, after,
                                                         "forecast"),
                                       rows=rows, previous=la.summary, start=self.start,
                                       label=self.label, advise_level=la.advise_level,
                                       confidence=la.confidence)
                upd.forecast_alerts.append(alert)
                if self.on_alert is not None:
                    self.on_alert(alert)
                self.alerts_raised += 1
            la.summary = summary
            if self.on_forecast is not None:
                self.on_forecast(rows, alert)

    @property
    def forecasts(self) -> dict:
        """The newest forecast row of each plan (plan name -> row; empty without look-ahead)."""
        return dict(self.lookahead.latest) if self.lookahead is not None else {}

    def poll_forecasts(self) -> Update:
        """Collect the look-ahead refreshes finished since the last call, without stepping."""
        upd = Update(time=self.time, level=self.level)
        self._collect_forecasts(upd)
        return upd

    def wait_forecasts(self, timeout: Optional[float] = None) -> Update:
        """Wait (up to ``timeout`` s) for the refresh that runs, then collect it."""
        if self.lookahead is not None:
            self.lookahead.wait(timeout)
        return self.poll_forecasts()

    def _bind(self) -> None:
        """The fault geometry and the per-step screening, at the first row."""
        if self._geometry is None:
            self._geometry = _fault_geometry(self.sim)
        if self.screening is None:
            g = self._geometry
            tracker = MetricsTracker(g.x, g.weights, self.scene.fault.friction)
            self.screening = StepScreening(self.scene.monitor, tracker)

    def _screen_step(self, row: dict, upd: Update) -> None:
        t = float(row["time"])
        self._bind()
        # the last few states, for events reported after the model passed their time
        self._rows.append({k: row[k] for k in _ROW_KEYS if k in row})
        if self.metrics_fn is not None:
            metrics = dict(self.metrics_fn(row, self.scene))
        else:
            metrics = self.screening.tracker.row_metrics(row)
        due = [e for e in self.pending_events if e.time <= t]
        if due:
            self.pending_events = [e for e in self.pending_events if e.time > t]
        assoc = [self._associate(e) for e in due]
        self.associations.extend(a.to_dict() for a in assoc)
        while self.event_times and self.event_times[0] <= t - self.event_window:
            self.event_times.popleft()
        upd.metrics, upd.state = metrics, row
        self.screened += 1
        events = {"time": [a.event.time for a in assoc],
                  "magnitude": [a.event.magnitude for a in assoc],
                  "distance": [a.distance_injection for a in assoc]} if assoc else None
        if self.screener is None:
            # a run stopped on an unstable fault is red from that row, as in replay; the
            # screener adds the event metrics to ``metrics``
            unstable = (getattr(self.sim, "stopped", None) or {}).get("reason") == "unstable"
            changes = self.screening.screen(t, metrics, events=events, unstable=unstable)
            if self.out is not None and self.sim.writer is not None:
                self.screening.write(self.sim.writer, metrics, changes)
        else:
            new = [(a.event.time, a.event.magnitude, a.distance_injection) for a in assoc]
            metrics.update(event_metrics(t, new, self.event_times, self.event_window))
            changes = list(self.screener.update(t, metrics, events=events) or ())
        if changes and hasattr(self.sim, "recorder"):
            self.sim.recorder.keep_profile()      # the fault profile at every level change
        for tr in changes:
            d = _transition_dict(tr)
            if d["time"] is None:
                d["time"] = t
            self.transitions.append(d)
            upd.transitions.append(d)
            code = _level_code(d["level"])
            if code is not None:
                self.level = code
            alert = alert_payload(run_key=self.run_key, transition=d, metrics=metrics,
                                  start=self.start, label=self.label)
            self.alerts_raised += 1
            upd.alerts.append(alert)
            if self.on_alert is not None:
                self.on_alert(alert)

    def _associate(self, ev: SeismicEvent):
        geo = self._geometry
        # the state at the end of the step containing the event (the current row for a timely
        # event; the oldest kept one for an event older than the kept history)
        row = next((r for r in self._rows if r["time"] >= ev.time), self._rows[0])
        return associate(ev, row, site=self.site, fault_xy=geo.xy, injection_xy=geo.injection_xy,
                         friction=float(self.scene.fault.friction))

    # -- output -----------------------------------------------------------------------------
    def result(self):
        """The model's :class:`~fault_screen.Result` so far, with the live level changes
        (``extra["monitor_transitions"]``), the events with the model state each was associated
        with (``extra["events"]``, the layout run and replay use) and ``/screening/``."""
        res = self.sim.result()
        extra = dict(getattr(res, "extra", {}) or {})
        extra.update(self._final_groups())
        res.extra = extra
        if self.screener is None:
            # /screening/ as replay and run write it: the rules over the whole result, with the
            # associated events at their origin times
            a = self.associations
            screen_result(res, events=Events([x["time"] for x in a],
                                             [_nan(x["magnitude"]) for x in a],
                                             [_nan(x["distance_injection"]) for x in a]))
        meta = dict(getattr(res, "meta", {}) or {})
        meta.update(self._meta())
        meta.pop("start", None)
        res.meta = meta
        return res

    def _final_groups(self) -> dict:
        """``/monitor_transitions`` and ``/events`` (with the state each event was associated
        with): the groups written when the results are complete."""
        extra = {}
        if self.transitions:
            extra["monitor_transitions"] = {
                "time": np.array([d["time"] for d in self.transitions], dtype=float),
                "from": np.array([_level_code(d["previous"]) if d["previous"] is not None
                                  else -1 for d in self.transitions], dtype=np.int64),
                "to": np.array([_level_code(d["level"]) for d in self.transitions],
                               dtype=np.int64),
                "rule": np.array([str(d["rule"]) for d in self.transitions], dtype="S"),
            }
        if self.associations:
            # /events as run and replay write it (plot and screen read it), plus the model
            # state each event was associated with
            a = self.associations
            ev = {"time": [x["time"] for x in a], "magnitude": [x["magnitude"] for x in a],
                  "latitude": [x["latitude"] for x in a], "longitude": [x["longitude"] for x in a],
                  "depth": [x["depth"] for x in a],
                  "distance_to_injection": [x["distance_injection"] for x in a],
                  "model_time": [x["model_time"] for x in a],
                  "distance_to_slipping": [x["distance_slipping"] for x in a],
                  "slip_rate": [x["slip_rate"] for x in a],
                  "utilisation": [x["utilisation"] for x in a]}
            ev = {k: np.array([_nan(v) for v in vals], dtype=float) for k, vals in ev.items()}
            ev["kind"] = np.array([x["kind"] for x in a], dtype="S")
            extra["events"] = ev
        if self.lookahead is not None and self.lookahead.rows:
            # the forecasts kept in memory (a result file streams them as they come)
            extra["lookahead"] = lookahead_arrays(self.lookahead.rows, self.lookahead.columns)
        return extra

    # -- checkpoints ------------------------------------------------------------------------
    def state(self) -> dict:
        """The stage's own state (JSON-able; the stepper's is written by the stepper)."""
        return {
            "version": _STATE_VERSION, "samples": self.samples.state(), "ignored": self.ignored,
            "steps": self.steps, "level": self.level,
            "pending_events": [e.to_dict() for e in self.pending_events],
            "event_times": list(self.event_times), "event_ids": sorted(self._event_ids),
            "associations": self.associations,
            "transitions": self.transitions, "alerts_raised": self.alerts_raised,
            "screening": None if self.screening is None else self.screening.state(),
            "screener": _own_state(self.screener), "metrics": _own_state(self.metrics_fn),
            "start": self.start.isoformat() if self.start else None,
            "event_window": self.event_window, "label": self.label,
            "rows": [_row_json(r) for r in self._rows],
            "screened": self.screened, "out": str(self.stream_path) if self.out is not None else None,
            "largest_rate": self.largest_rate,
            "lookahead": None if self.lookahead is None else self.lookahead.state(),
        }

    def checkpoint(self, path, extra: Optional[dict] = None) -> Path:
        """Write the full state (stepper + stage + ``extra``, e.g. the source's position)
        atomically to ``path``: a temporary file renamed over the old one, so a kill during the
        write leaves the previous checkpoint intact."""
        import h5py

        path = Path(path)
        tmp = path.with_name(path.name + ".tmp")
        try:
            self.sim.checkpoint(tmp)
            state = self.state()
            state["extra"] = extra or {}
            with h5py.File(tmp, "a") as h5:
                h5.attrs[_STATE_ATTR] = json.dumps(state, default=_json_default)
                if self.received is not None:       # every sample: datasets, not the record
                    for name, values in _received_arrays(self.received).items():
                        h5[f"{_RECEIVED}/{name}"] = values
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
            os.replace(tmp, path)
            _fsync_dir(path.parent)
        finally:
            if tmp.exists():
                tmp.unlink()
        return path

    @staticmethod
    def _saved_state(path) -> dict:
        import h5py

        with h5py.File(path, "r") as h5:
            if _STATE_ATTR not in h5.attrs:
                raise ValueError(f"{path}: not a monitor state file (no {_STATE_ATTR} record)")
            return json.loads(h5.attrs[_STATE_ATTR])

    @classmethod
    def saved_extra(cls, path) -> dict:
        """The ``extra`` dict saved with a checkpoint (without restoring the model)."""
        return cls._saved_state(path).get("extra", {})

    @classmethod
    def restore(cls, path, *, scene=None, simulation_class=None, screener=None, metrics=None,
                site: Optional[Site] = None, out=None, lookahead="saved", on_forecast=None,
                on_alert=None):
        """A stage continuing exactly from the checkpoint ``path``; returns ``(stage, extra)``.
        ``simulation_class`` (default ``fault_screen.Simulation``) provides ``restore(path)``.
        A stage that streamed its results continues its result file (``out``, default the one
        it streamed to), cut back to what the checkpoint counts.  ``lookahead``: the
        look-ahead from now on (a LiveLookAhead; None: none; default ``"saved"``: the saved
        settings, if any); it continues from the saved forecasts (alert summaries, due time)."""
        state = cls._saved_state(path)
        if state.get("version") != _STATE_VERSION:
            raise ValueError(f"{path}: a monitor state of layout {state.get('version')!r} (this "
                             f"version reads layout {_STATE_VERSION}); start without --state")
        for key, given in (("screener", screener), ("metrics", metrics)):
            if state.get(key) is not None and given is None:
                raise ValueError(f"{path}: this state was written with an embedding program's "
                                 f"own {key}: give it to restore again")
        if simulation_class is None:
            simulation_class = Simulation
        streamed = state.get("out") is not None
        if streamed:
            sim = simulation_class.restore(path, stream_to=out if out is not None else state["out"])
        else:
            sim = simulation_class.restore(path)
        if scene is not None and hasattr(scene, "to_toml") and scene.to_toml() != sim.scene.to_toml():
            raise ValueError(f"{path}: this state was written for another scene; start with "
                             f"the scene it was written for, or without --state")
        scene = scene if scene is not None else sim.scene
        start = datetime.fromisoformat(state["start"]) if state["start"] else None
        saved_la = state.get("lookahead")
        if isinstance(lookahead, str):
            lookahead = LiveLookAhead(**saved_la["settings"]) if saved_la is not None else None
        st = cls(scene, start=start, simulation=sim, screener=screener, metrics=metrics,
                 site=site, event_window=state["event_window"], label=state["label"],
                 out=(out if out is not None else state["out"]) if streamed else None,
                 lookahead=lookahead, on_forecast=on_forecast, on_alert=on_alert)
        if lookahead is not None:
            if saved_la is not None:
                lookahead.restore_state(saved_la)
            # a streamed file continued: its /lookahead stream was declared when it was made
            if streamed and saved_la is not None:
                lookahead._stream = (ENSEMBLE_LOOKAHEAD_COLUMNS
                                     if saved_la["settings"].get("ensemble") is not None
                                     else LOOKAHEAD_COLUMNS)
        if st.received is not None:
            # the forecaster's models are rebuilt from time 0 in the worker: every sample since
            st.received = _received_from(path)
        st.screener = _with_own_state(screener, state["screener"])
        st.metrics_fn = _with_own_state(metrics, state["metrics"])
        if state["screening"] is not None:
            st._geometry = _fault_geometry(st.sim)
            g = st._geometry
            st.screening = StepScreening.from_state(scene, g.x, g.weights, state["screening"])
        st.samples = SampleBuffer.from_state(state["samples"])
        st.ignored, st.steps, st.level = state["ignored"], state["steps"], state["level"]
        st.pending_events = [SeismicEvent(**_event_args(e)) for e in state["pending_events"]]
        st.event_times = deque(state["event_times"])
        st._event_ids = set(state["event_ids"])
        st.associations, st.transitions = state["associations"], state["transitions"]
        st.alerts_raised = state["alerts_raised"]
        st._rows.extend(_row_from_json(r) for r in state["rows"])
        st.screened = state.get("screened", st.steps)
        st.largest_rate = float(state.get("largest_rate", 0.0))
        return st, state.get("extra", {})


def _since(flow: PiecewiseLinearVolume, t: float) -> PiecewiseLinearVolume:
    """A copy of the samples of ``flow`` from the one at or just before ``t`` (s) on, their
    cumulative volume absolute (each step gets the volume the whole record gives it)."""
    k = max(int(np.searchsorted(flow.time, t, side="right")) - 1, 0)
    return PiecewiseLinearVolume(flow.time[k:], flow.flow_rate[k:], flow.cumulative[k:])


def _received_arrays(flow: PiecewiseLinearVolume) -> dict:
    return {"time": flow.time.copy(), "flow_rate": flow.flow_rate.copy(),
            "cumulative": flow.cumulative.copy()}


def _received_from(path) -> PiecewiseLinearVolume:
    """Every sample received, from a checkpoint (which must have them)."""
    import h5py

    with h5py.File(path, "r") as h5:
        if _RECEIVED not in h5:
            raise ValueError(f"{path}: this state was written without a look-ahead ensemble: its "
                             f"members cannot be rebuilt from time 0 (the samples are not kept); "
                             f"start without --state, or without --members")
        g = h5[_RECEIVED]
        return PiecewiseLinearVolume(g["time"][()], g["flow_rate"][()], g["cumulative"][()])


# ---------------------------------------------------------------------------------------------
# adapters to the stepper and the screening layer
# ---------------------------------------------------------------------------------------------
def _new_simulation(scene):
    return Simulation(scene)


@dataclass(frozen=True)
class _Geometry:
    """The model's fault points: along-fault position ``x`` (m, 0 at the injection point),
    coordinates ``xy`` (n, 2), quadrature ``weights`` (m), and the injection point (x, y)."""

    x: np.ndarray
    xy: np.ndarray
    weights: np.ndarray
    injection_xy: tuple


def _fault_geometry(sim) -> _Geometry:
    disc = getattr(sim, "disc", None)
    if disc is not None:        # the stepper's own fault points (its rows may be in a file)
        fp = disc.fault_points
        x, xy, w = fp.s - disc.injection.s, np.asarray(fp.xy, dtype=float).reshape(-1, 2), fp.weight
    else:
        res = sim.result()      # once per stage: the geometry does not change
        xy = np.asarray(res.fault_xy, dtype=float).reshape(-1, 2)
        x, w = np.asarray(res.fault_x, dtype=float), res.fault_weights
    inj = (0.0, 0.0)
    if xy.size:
        k = int(np.argmin(np.abs(x)))
        inj = (float(xy[k, 0]), float(xy[k, 1]))
    return _Geometry(np.asarray(x, dtype=float), xy, np.asarray(w, dtype=float), inj)


def _site_of(scene) -> Optional[Site]:
    return Site.from_spec(getattr(scene, "site", None))


def _own_state(obj):
    """The plain-data state of an embedding program's screener or metrics object (its own
    ``state()``), or None (none given, or one that keeps no state)."""
    if obj is None or not hasattr(obj, "state"):
        return None
    return obj.state()


def _with_own_state(given, saved):
    """``given`` continuing from its ``saved`` state: its class's ``from_state(saved)`` (the
    class of the object given at restore, never one named by the file)."""
    if given is None or saved is None or not hasattr(type(given), "from_state"):
        return given
    return type(given).from_state(saved)


def _row_json(row: dict) -> dict:
    return {k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v)
            for k, v in row.items()}


def _row_from_json(row: dict) -> dict:
    return {k: (np.asarray(v) if isinstance(v, list) else v) for k, v in row.items()}


def _event_args(d: dict) -> dict:
    keys = ("time", "magnitude", "latitude", "longitude", "depth", "kind", "id", "offset",
            "distance")
    out = {k: d[k] for k in keys if k in d}
    if out.get("magnitude") is None:
        out["magnitude"] = math.nan
    if out.get("offset") is not None:
        out["offset"] = tuple(out["offset"])
    return out


def _nan(v):
    return math.nan if v is None else float(v)


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(str(folder), os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)

"""Screening after each step: the one path that ``fault_screen.simulate``, ``run_streamed``, the
live monitor's stage and :func:`~fault_screen.screening.screen_result` all take.

A :class:`StepScreening` holds a :class:`~fault_screen.screening.metrics.MetricsTracker` (the
metrics of each recorded row, with what they keep of earlier rows) and a
:class:`~fault_screen.screening.screener.Screener` (the rules, the event metrics and the level).
Per row: :meth:`StepScreening.update` (a stepper row) or :meth:`StepScreening.screen` (metrics
already computed, as ``screen_result`` has them for a whole result).  Its :meth:`state` is plain
data, so a checkpoint holds numbers, never code.
"""
from __future__ import annotations

import numpy as np

from ..rules import METRICS
from .metrics import MetricsTracker
from .screener import Events, Screener, Transition, Verdict

__all__ = ["StepScreening", "Screening", "TRANSITION_DTYPE"]

#: the compound type of ``/screening/transitions``
TRANSITION_DTYPE = np.dtype([("time", "f8"), ("from", "i1"), ("to", "i1"), ("rule", "S64")])


def _transition_row(tr) -> tuple:
    """A level change as a record of :data:`TRANSITION_DTYPE` (the rule's name cut to 64 bytes)."""
    return (tr.time, tr.from_level, tr.to_level, tr.rule.encode("utf-8")[:64])


class Screening:
    """What :func:`screen_result` found: metrics and level per output time, transitions, verdict."""

    def __init__(self, time, metrics: dict, level, transitions: list[Transition], verdict: Verdict, spec):
        self.time = time
        self.metrics = metrics
        self.level = level
        self.transitions = transitions
        self.verdict = verdict
        self.spec = spec

    def arrays(self) -> dict:
        """The ``/screening/`` group as arrays (what :attr:`Result.extra` holds)."""
        out = {k: np.asarray(v, dtype=float) for k, v in self.metrics.items()}
        out["level"] = np.asarray(self.level, dtype=np.int8)
        tr = np.zeros(len(self.transitions), dtype=TRANSITION_DTYPE)
        for i, t in enumerate(self.transitions):
            tr[i] = _transition_row(t)
        out["transitions"] = tr
        return out


class StepScreening:
    """The screening of a run row by row with the ``[monitor]`` ``spec``: the metrics and level
    of every row (``/screening/<metric>``, ``/screening/level``) and each level change
    (``/screening/transitions``).

    ``tracker``: the metrics of stepper rows (None when the caller hands metrics to
    :meth:`screen`). ``events``: seismic events known from the start (a catalogue), each counted
    at its origin time; more may come with each row (the live monitor)."""

    def __init__(self, spec, tracker: MetricsTracker | None = None, events=None, *,
                 screener: Screener | None = None):
        self.tracker = tracker
        self.screener = screener if screener is not None else Screener(spec)
        self.screener.add_events(Events.coerce(events))
        self.records: list[dict] = []     # the rows screened, when kept in memory

    @classmethod
    def for_scene(cls, scene, fault_x, fault_weights, events=None) -> "StepScreening":
        """For the rows of a run of ``scene`` (fault points at ``fault_x`` m from the injection
        point, quadrature ``fault_weights`` m)."""
        return cls(scene.monitor, MetricsTracker(fault_x, fault_weights, scene.fault.friction), events)

    @property
    def spec(self):
        return self.screener.spec

    @property
    def level(self) -> int:
        return self.screener.level

    @property
    def transitions(self) -> list:
        return self.screener.transitions

    @property
    def verdict(self):
        return self.screener.verdict

    # -- one row ----------------------------------------------------------------------------
    def screen(self, time: float, metrics: dict, *, events=None, unstable: bool = False) -> list:
        """The rules at ``time`` (s) over ``metrics`` (SI, NaN = missing; the event metrics are
        added to it) and the new ``events``; ``unstable``: the run stopped here on an unstable
        fault. Returns the level changes."""
        return self.screener.update(time, metrics, events=events, unstable=unstable)

    def update(self, row: dict, *, unstable: bool = False, events=None) -> tuple[dict, list]:
        """Screen one recorded row of the stepper (``Simulation.last_row``). Returns
        ``(metrics, transitions)``."""
        metrics = self.tracker.row_metrics(row)
        return metrics, self.screen(row["time"], metrics, events=events, unstable=unstable)

    def record(self, metrics: dict) -> dict:
        """The ``screening`` stream's record of a screened row."""
        rec = {f"/screening/{k}": float(metrics[k]) for k in METRICS}
        rec["/screening/level"] = self.screener.level
        return rec

    @staticmethod
    def streams() -> dict:
        """The streams to declare to :meth:`~fault_screen.Simulation.stream_to`."""
        rows = {f"/screening/{name}": ("<f8", ()) for name in METRICS}
        rows["/screening/level"] = ("|i1", ())
        return {"screening": rows, "transitions": {"/screening/transitions": (TRANSITION_DTYPE, ())}}

    @staticmethod
    def transition_record(tr) -> dict:
        rec = np.zeros((), dtype=TRANSITION_DTYPE)
        rec[()] = _transition_row(tr)
        return {"/screening/transitions": rec}

    def write(self, writer, metrics: dict, transitions) -> None:
        """Append a screened row and its level changes to a result file's writer."""
        writer.append("screening", self.record(metrics))
        for tr in transitions:
            writer.append("transitions", self.transition_record(tr))

    # -- a stepper's run --------------------------------------------------------------------
    def screen_simulation(self, sim, *, events=None) -> list:
        """Screen the newest row of ``sim`` and append it to its result file (or keep it, for
        :meth:`arrays`, when ``sim`` keeps its results in memory); a level change keeps that
        row's fault profile. Returns the level changes."""
        stopped = (sim.stopped or {}).get("reason") == "unstable"
        metrics, transitions = self.update(sim.last_row, unstable=stopped, events=events)
        if sim.writer is not None:
            self.write(sim.writer, metrics, transitions)
        else:
            self.records.append(self.record(metrics))
        if transitions:
            sim.recorder.keep_profile()
        return transitions

    def arrays(self) -> dict:
        """The ``/screening/`` group of the rows screened in memory (``Result.extra``)."""
        out = {p.rsplit("/", 1)[1]: np.array([r[p] for r in self.records])
               for p in self.streams()["screening"]}
        out["level"] = out["level"].astype(np.int8)
        tr = [self.transition_record(t)["/screening/transitions"] for t in self.transitions]
        out["transitions"] = np.array(tr, dtype=TRANSITION_DTYPE).reshape(-1)
        return out

    def screening(self, result):
        """The :class:`~fault_screen.screening.Screening` of the streamed run (its verdict and
        level changes; the per-row values from ``result``, the file read back)."""
        arrays = result.extra.get("screening", {})
        metrics = {k: v for k, v in arrays.items() if k not in ("level", "transitions")}
        return Screening(result.time, metrics, arrays.get("level"), self.transitions,
                         self.verdict, self.spec)

    # -- checkpoints ------------------------------------------------------------------------
    def state(self) -> dict:
        """Plain data (JSON-able): the tracker's and the screener's memory of earlier rows."""
        return {"tracker": None if self.tracker is None else self.tracker.state(),
                "screener": self.screener.state()}

    @classmethod
    def from_state(cls, scene, fault_x, fault_weights, state: dict) -> "StepScreening":
        """The screening of a run of ``scene`` continuing from :meth:`state`."""
        tracker = None
        if state.get("tracker") is not None:
            tracker = MetricsTracker.from_state(fault_x, fault_weights, scene.fault.friction,
                                                state["tracker"])
        return cls(scene.monitor, tracker, screener=Screener.from_state(scene.monitor, state["screener"]))

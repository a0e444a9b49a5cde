"""Replaying an operator's injection log through the model, from Python.

::

    from fault_screen import Scene
    from fault_screen.io import read_injection_log, replay

    scene = Scene.from_toml("configs/rustrel-2015-calibrated.toml")
    log = read_injection_log("pump.csv", tz="Europe/Zurich")   # print(log.summary)
    result = replay(scene, log)          # model time 0 = the log's first stamp
    result.save("replay.h5")             # /log/* holds the samples used, in SI

The run ends at the log's last sample unless ``end`` (s) is given.  An ``end`` beyond the last
sample is accepted: the rate is zero after the log ends (a shut-in), and
:attr:`ReplayPlan.notes` says so (the command line prints it as a warning).  Every time step
receives exactly the log's volume over that step (the piecewise-linear rate integrated exactly).

:func:`plan_replay` does everything but the run, for callers that drive the model themselves
(the command line, a stepper).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from .injection_log import InjectionLog

__all__ = ["ReplayPlan", "plan_replay", "replay"]


@dataclass(frozen=True)
class ReplayPlan:
    """What a replay runs: ``scene`` (its ``time.end`` set to ``end``), the volume function
    ``injected_volume(t0, t1) -> m3``, the samples used (``log_arrays``, SI, for ``/log``),
    ``meta`` for the result and ``notes`` to show the user."""

    scene: object
    injected_volume: Callable[[float, float], float]
    end: float
    log_arrays: dict
    meta: dict
    notes: tuple = field(default=())


def plan_replay(scene, log: InjectionLog, end: Optional[float] = None, *,
                end_name: str = "end") -> ReplayPlan:
    """The scene and volume function that replay ``log``; ``end`` (s after the first stamp)
    defaults to the log's duration.  ``end_name`` is how ``end`` is named in notes
    (``--end`` on the command line).  Raises ValueError for a pressure-controlled scene or an
    ``end`` that is not positive."""
    if scene.injection.control != "rate":
        raise ValueError(f"injection.control = {scene.injection.control!r}: a log replay drives "
                         f"the flow rate; use a scene with control = 'rate'")
    t_end = float(end) if end is not None else log.duration
    if not t_end > 0:
        raise ValueError(f"{end_name} = {end!r}: must be > 0 s")
    notes = []
    if t_end > log.duration:
        notes.append(f"{end_name} {t_end:g} s is after the log's last sample "
                     f"({log.duration:g} s): the rate is taken as 0 from {log.duration:g} s to "
                     f"{t_end:g} s (shut-in)")
    ts = scene.time
    run_scene = scene.replace(time=dataclasses.replace(ts, end=t_end, dt=min(ts.dt, t_end)))

    # the samples the run uses: those inside [0, end] and the first one after it
    n = int(np.searchsorted(log.time, t_end, side="left")) + 1
    n = min(max(n, 2), log.time.size)
    used = {"time": np.array(log.time[:n]), "flow_rate": np.array(log.flow_rate[:n])}
    if log.pressure is not None:
        used["pressure"] = np.array(log.pressure[:n])
    meta = {
        "log_file": log.source,
        "log_start": log.start.isoformat() if log.start is not None else None,
        "log_flow_unit": log.flow_unit,
        "log_pressure_unit": log.pressure_unit,
        "log_summary": log.summary,
        "log_warnings": list(log.warnings),
        "log_volume": log.volume(0.0, t_end),
        "log_end": log.duration,
    }
    return ReplayPlan(run_scene, log.volume, t_end, used, meta, tuple(notes))


def replay(scene, log: InjectionLog, *, end: Optional[float] = None, progress=None):
    """Run ``scene`` driven by ``log`` and return the :class:`~fault_screen.Result`, with the
    log's samples in ``result.extra["log"]`` and its description in ``result.meta``."""
    from ..simulate import simulate    # the core is imported only to run

    plan = plan_replay(scene, log, end)
    result = simulate(plan.scene, injected_volume=plan.injected_volume, progress=progress)
    result.meta.update(plan.meta)
    result.meta["notes"] = list(plan.notes)
    if log.start is not None:
        result.meta.setdefault("start", log.start.isoformat())
    result.extra["log"] = plan.log_arrays
    return result

"""Look-ahead: each plan run on a fork of the simulation for a horizon, screened with the scene's
``[monitor]`` rules as the run itself is screened.

``LookAhead(sim, screening)`` takes the state "now" (a fork of ``sim`` and a copy of the
screening state: the metrics tracker, the screener's holds and level); :meth:`LookAhead.run`
then makes one :class:`Forecast` per plan, each on its own fork of that state, so the caller's
run is never touched and the look-ahead can run in a worker while the caller steps on. By
default a fork takes the scene's own step sequence, so that the plan ``scene`` reproduces the
uninterrupted run row for row. A :class:`StepLadder` makes it take longer steps from a handful
of sizes (doubling from the run's step) whose factorisations every look-ahead given the same
ladder shares; ``benchmarks/lookahead.py`` measures what each costs in accuracy.
"""
from __future__ import annotations

import collections
import copy
import dataclasses
import math
import time as _time
from dataclasses import dataclass, field
from datetime import datetime
from typing import Optional

import numpy as np

from ..screening.stepwise import StepScreening
from ..screening import LEVEL_NAMES, RED, YELLOW
from .plans import Plan

__all__ = ["LookAhead", "Forecast", "COLUMNS", "StepLadder", "screening_of"]

#: the columns of forecast.csv, in order
COLUMNS = ("made_at", "plan", "horizon", "level_now", "level_at_horizon", "max_level",
           "time_to_yellow", "time_to_red", "peak_slip_rate", "max_utilisation",
           "induced_slip_at_horizon", "advised_rate", "wall_s")


@dataclass
class Forecast:
    """What one plan does over the horizon from ``made_at`` (s, model time).

    Levels are 0 green, 1 yellow, 2 red; ``time_to_yellow``/``time_to_red``: s after
    ``made_at`` at which the level is first at least yellow/red (0 when it already is, None
    when not within the horizon); ``peak_slip_rate`` (m/s) and ``max_utilisation`` (-): the
    largest over the rows ahead; ``induced_slip_at_horizon`` (m); ``advised_rate`` (m3/s, or Pa
    under pressure control) when advice was asked; ``wall_s``: the wall time it took.
    ``time``, ``metrics`` and ``level``: the rows ahead (the "now" row first), for figures;
    ``iterations``: the Newton iterations of its steps (what a step costs grows with them)."""

    made_at: float
    plan: str
    horizon: float
    level_now: int
    level_at_horizon: int
    max_level: int
    time_to_yellow: Optional[float]
    time_to_red: Optional[float]
    peak_slip_rate: float
    max_utilisation: float
    induced_slip_at_horizon: float
    wall_s: float
    advised_rate: Optional[float] = None
    time: np.ndarray = field(default=None, repr=False)
    metrics: dict = field(default_factory=dict, repr=False)
    level: np.ndarray = field(default=None, repr=False)
    stopped: Optional[str] = None
    iterations: int = 0

    def reaches(self, level: int) -> bool:
        """Does the level reach ``level`` at a row ahead (the "now" row not counted)?"""
        return bool(self.level.size > 1 and np.max(self.level[1:]) >= level)

    def row(self) -> dict:
        """The forecast.csv row (SI; levels by name; None where empty)."""
        return {"made_at": self.made_at, "plan": self.plan, "horizon": self.horizon,
                "level_now": LEVEL_NAMES[self.level_now],
                "level_at_horizon": LEVEL_NAMES[self.level_at_horizon],
                "max_level": LEVEL_NAMES[self.max_level], "time_to_yellow": self.time_to_yellow,
                "time_to_red": self.time_to_red, "peak_slip_rate": self.peak_slip_rate,
                "max_utilisation": self.max_utilisation,
                "induced_slip_at_horizon": self.induced_slip_at_horizon,
                "advised_rate": self.advised_rate, "wall_s": self.wall_s}


def _screen_row(screening: StepScreening, row: dict, unstable: bool):
    """Screen one recorded row (the one place a look-ahead calls the screening): the metrics
    record and the level after it."""
    metrics, _ = screening.update(row, unstable=unstable)
    return screening.record(metrics), screening.screener.level


def _screen_newest(screening: StepScreening, sim):
    return _screen_row(screening, sim.last_row, (sim.stopped or {}).get("reason") == "unstable")


def screening_of(sim, events=None) -> StepScreening:
    """The screening state of a run whose rows are all in memory (e.g. just restored from a
    checkpoint): every row screened again, in order, as the run screened them."""
    rows = sim.recorder.rows
    if not rows or len(rows) != sim.recorder.count:
        raise ValueError("the rows of this run are not all in memory (streamed to a file, or a "
                         "fork): keep the screening state of the run itself")
    fp = sim.disc.fault_points
    screening = StepScreening.for_scene(sim.scene, fp.s - sim.disc.injection.s, fp.weight, events)
    unstable = (sim.stopped or {}).get("reason") == "unstable"
    for i, row in enumerate(rows):
        _screen_row(screening, row, unstable and i == len(rows) - 1)
    return screening


class LookAhead:
    """Look-aheads from the state of ``sim`` now, screened from the state of ``screening`` (a
    :class:`~fault_screen.screening.stepwise.StepScreening` that has screened every row of ``sim`` so far).

    ``drive``: what drove the run (``volume(t0, t1)``, ``rate_at(t)``; an InjectionLog, a live
    sample buffer), None for the scene's schedule; ``start``: date-time of model time 0 (for
    log plans with date-times). Neither ``sim`` nor ``screening`` is changed, now or later.

    ``growth`` and ``dt_max`` (s): a look-ahead whose steps grow from the run's current step by
    this factor up to ``dt_max`` instead of following the scene's sequence: faster, less exact
    (``benchmarks/lookahead.py`` measures what it costs); default: the scene's own sequence.
    ``ladder``: a :class:`StepLadder` instead (its sizes' factorisations shared with every
    look-ahead given the same ladder)."""

    def __init__(self, sim, screening: StepScreening, *, drive=None, start: Optional[datetime] = None,
                 growth: Optional[float] = None, dt_max: Optional[float] = None,
                 ladder: Optional["StepLadder"] = None):
        if ladder is not None and (growth is not None or dt_max is not None):
            raise ValueError("look-ahead steps: a ladder or growth/dt_max, not both")
        self.state = sim.fork()
        self.screening = _copy_screening(screening)
        self.drive = drive
        self.start = start
        self.made_at = float(sim.time)
        self.level_now = int(screening.screener.level)
        self.ladder = ladder
        self.time_steps = (_time_steps(sim.scene, growth, dt_max) if ladder is None
                           else ladder.scene_for(sim.scene))
        self._rungs = None if ladder is None else ladder.rungs(sim.dt)
        # the "now" row's metrics, the first row of every plan's forecast
        self._first = {k.rsplit("/", 1)[1]: v for k, v in _now_record(self.state, self.screening).items()}

    @property
    def control(self) -> str:
        return self.state.scene.injection.control

    def run(self, plan: Plan, horizon: float, *, until: Optional[int] = None) -> Forecast:
        """The forecast of ``plan`` over ``horizon`` (s) from now, on a fork. ``until``: stop at
        the first row ahead at this level or above (what the advice asks: whether the level is
        reached); the forecast's rows then end there and ``stopped`` says so."""
        wall0 = _time.perf_counter()
        sim = self.state.fork()
        if self.time_steps is not None:
            sim.scene = self.time_steps
        screening = _copy_screening(self.screening)
        drive = plan.drive(sim, self.drive, self.start)
        # the look-ahead reads each newest row once (its metrics are kept below): the fork's
        # recorder keeps no more than that row
        sim.recorder.rows = collections.deque(sim.recorder.rows, maxlen=1)
        times, levels, iterations = [self.made_at], [self.level_now], 0
        rows = {k: [v] for k, v in self._first.items()}
        end = self.made_at + float(horizon)
        ladder = self.ladder
        # BLAS held on one thread over all the steps (a ladder's systems then find it held),
        # not limited and restored at each step
        with sim.solver.blas_threads():
            while True:
                if ladder is not None and sim.stopped is None and sim.time < end * (1 - 1e-12):
                    made = ladder.set_step(sim, self._rungs, end)
                if not sim.advance(end, max_steps=1, **drive):
                    break
                if ladder is not None:
                    ladder.keep(sim, made)
                record, level = _screen_newest(screening, sim)
                iterations += int(sim.last_row.get("iterations", 0))
                times.append(float(sim.time))
                levels.append(int(level))
                for k, v in record.items():
                    rows.setdefault(k.rsplit("/", 1)[1], []).append(v)
                if until is not None and level >= until:
                    break
        stopped = (sim.stopped or {}).get("message")
        if until is not None and levels[-1] >= until and len(levels) > 1 and sim.time < end * (1 - 1e-12):
            stopped = (f"look-ahead stopped at t = {sim.time:.6g} s, where it reached "
                       f"{LEVEL_NAMES[levels[-1]]}")
        forecast = _summarise(self.made_at, plan.name, float(horizon), np.array(times), np.array(levels),
                              {k: np.asarray(v, dtype=float) for k, v in rows.items()},
                              _time.perf_counter() - wall0, stopped)
        forecast.iterations = iterations
        return forecast


class StepLadder:
    """Look-ahead steps from a handful of sizes: the run's step when the look-ahead begins,
    doubling at every step up to ``dt_max`` (s; rounded down to a size of the ladder), never
    beyond the step the run itself would take next (the friction law's limit, a step cut) and
    ending on the horizon with the largest sizes that fit. Each size's linear system (with rock
    pore pressure the bulk's factors depend on the step size) is factorised once and kept here:
    every look-ahead given this ladder (the plans, the advice's bisection, later refreshes of the
    same run) shares them, read-only. Valid for the forks of one run (its discretisation and
    scaling). ``factorizations``: how many the look-aheads on it have made so far."""

    def __init__(self, dt_max: float):
        dt_max = float(dt_max)
        if not (dt_max > 0 and math.isfinite(dt_max)):
            raise ValueError(f"look-ahead steps: the ladder's dt_max {dt_max!r} must be > 0")
        self.dt_max = dt_max
        self.factorizations = 0
        self._systems = {}        # step size (s) -> the solver's linear system prepared for it
        self._disc = None         # the discretisation of the run whose forks use the ladder

    def scene_for(self, scene):
        """The scene whose step sequence proposes the ladder's steps (doubling up to dt_max)."""
        return scene.replace(time=dataclasses.replace(scene.time, growth=2.0, dt_max=self.dt_max))

    def rungs(self, dt0: float) -> np.ndarray:
        """The sizes, largest first: dt0 * 2^k up to dt_max (dt0 alone when dt_max is smaller)."""
        sizes = [float(dt0)]
        while sizes[-1] * 2.0 <= self.dt_max * (1 + 1e-12):
            sizes.append(sizes[-1] * 2.0)
        return np.array(sizes[::-1])

    def set_step(self, sim, rungs, end) -> int:
        """Make the next step of ``sim`` the largest size of ``rungs`` within both the step it
        would take and what is left to ``end``, on that size's kept linear system. Returns the
        factorisations of that system so far (for ``keep``)."""
        if self._disc is None:
            self._disc = sim.disc
        elif sim.disc is not self._disc:
            raise ValueError("a step ladder serves the forks of one run: make one per run")
        room = min(sim.dt, end - sim.time)
        fit = rungs[rungs <= room * (1 + 1e-12)]
        dt = float(fit[0]) if fit.size else float(end - sim.time)
        sim.dt = dt
        solver = sim.solver
        kept = self._systems.get(dt)
        if kept is not None and solver.system.dt != dt:
            solver.system = kept.fork()
        return solver.system.factorizations

    def keep(self, sim, factorizations_before: int):
        """Keep the linear system of the step just taken (a size not kept before)."""
        system = sim.solver.system
        self.factorizations += system.factorizations - factorizations_before
        if system.dt is not None and system.dt not in self._systems:
            self._systems[system.dt] = system.fork()


def _time_steps(scene, growth, dt_max):
    """The scene whose step sequence a look-ahead follows, when not the run's own (None)."""
    if growth is None and dt_max is None:
        return None
    ts = scene.time
    growth = ts.growth if growth is None else float(growth)
    dt_max = (ts.dt_max if ts.dt_max is not None else ts.dt) if dt_max is None else float(dt_max)
    if not (growth >= 1.0 and dt_max > 0):
        raise ValueError(f"look-ahead steps: growth {growth!r} must be >= 1 and dt_max {dt_max!r} > 0")
    return scene.replace(time=dataclasses.replace(ts, growth=growth, dt_max=dt_max))


def _copy_screening(screening: StepScreening) -> StepScreening:
    """A screening state of its own (tracker, screener), without the rows screened so far."""
    records, screening.records = screening.records, []
    try:
        return copy.deepcopy(screening)
    finally:
        screening.records = records


def _now_record(sim, screening: StepScreening) -> dict:
    """The metrics of the "now" row: that row screened again on a copy (its tracker gives the same
    metrics for the same row: no slip increment, the same reference)."""
    record, _ = _screen_newest(_copy_screening(screening), sim)
    return record


def _summarise(made_at, name, horizon, times, levels, metrics, wall, stopped) -> Forecast:
    def first_at(level):
        hit = np.flatnonzero(levels >= level)
        return float(times[hit[0]] - made_at) if hit.size else None

    ahead = slice(1, None) if times.size > 1 else slice(0, None)
    peak = metrics.get("peak_slip_rate", np.zeros(1))[ahead]
    util = metrics.get("max_utilisation", np.zeros(1))[ahead]
    slip = metrics.get("induced_slip", np.zeros(1))
    return Forecast(made_at=made_at, plan=name, horizon=horizon, level_now=int(levels[0]),
                    level_at_horizon=int(levels[-1]), max_level=int(np.max(levels)),
                    time_to_yellow=first_at(YELLOW), time_to_red=first_at(RED),
                    peak_slip_rate=float(np.max(peak)) if peak.size else math.nan,
                    max_utilisation=float(np.max(util)) if util.size else math.nan,
                    induced_slip_at_horizon=float(slip[-1]) if slip.size else math.nan,
                    wall_s=float(wall), time=times, metrics=metrics, level=levels, stopped=stopped)


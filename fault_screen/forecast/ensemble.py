"""Forecasts over an ensemble of parameter draws: how likely each plan is to reach yellow and
red within the horizon, when, and the largest rate that keeps that likelihood low.

A *member* is the scene with one parameter draw (dotted scene keys, SI values, as
``fault-screen ensemble --vary`` draws them). :func:`run_member` runs one member's own history
from time 0 to every forecast time, forks there and runs each plan for the horizon (and, when
asked, the member's own advice): one task on the ensemble runner per member, so each history
runs once. :func:`summarise` turns the members' forecasts into one :class:`EnsembleForecast`
per forecast time and plan:

* ``p_yellow`` / ``p_red``: the fraction of the successful members whose level is at least
  yellow / red at some row from "now" to the horizon ("now" included, as ``time_to_yellow`` is
  0 when the level already is);
* ``time_to_yellow_p10/p50/p90``: percentiles of the time to yellow over *all* successful
  members, a member that does not reach yellow within the horizon counting as later than any
  that does (+inf). A percentile is the smallest time by which at least that fraction of the
  members is yellow (no interpolation between members), so it is empty (None) when fewer than
  that fraction reach yellow: p50 is empty when fewer than half do;
* ``members``: how many members succeeded; failed members are kept with their error.

:func:`ensemble_advice`: the largest constant rate whose probability of reaching the advice
level within the horizon is at most ``1 - confidence``. Each member bisects for its own largest
rate below the level to 2 % (:func:`~fault_screen.forecast.advice.advise`); a member reaches
the level at a rate above its own. The probability at a rate is then the fraction of members
whose own rate is below it, a step function of the rate, and the advised rate is the largest
rate at which that fraction is at most ``1 - confidence``: the (m+1)-th smallest member rate,
m = floor((1 - confidence) n). This is what a bisection on the rate with every evaluation over
all members converges to, with one task per member instead of a round trip per evaluation.

:class:`LiveEnsemble` keeps the members stepping with live data and makes the same rows on
demand, for the monitor's look-ahead worker.
"""
from __future__ import annotations

import dataclasses
import math
import os
import threading
import time as _time
import traceback
from dataclasses import dataclass, field
from datetime import datetime
from typing import Iterable, Optional, Sequence

import numpy as np

from ..screening import LEVEL_NAMES, RED, YELLOW
from .advice import Advice, advise
from .lookahead import COLUMNS, Forecast, LookAhead
from .plans import Plan

__all__ = ["ENSEMBLE_COLUMNS", "PERCENTILES", "ENSEMBLE_LADDER", "MemberRun", "EnsembleForecast",
           "EnsembleAdvice", "run_member", "run_members", "release", "chunks", "summarise",
           "ensemble_advice", "time_percentile", "LiveEnsemble", "lookaheads", "ensemble_rows"]

#: the columns forecast.csv gets with --members, after :data:`~fault_screen.forecast.COLUMNS`
ENSEMBLE_COLUMNS = ("p_yellow", "p_red", "time_to_yellow_p10", "time_to_yellow_p50",
                    "time_to_yellow_p90", "members")

#: the percentiles of the time to yellow (%)
PERCENTILES = (10, 50, 90)

#: the largest look-ahead step (s) of ``fault-screen forecast --members`` by default: a step ladder
#: (:class:`~fault_screen.forecast.lookahead.StepLadder`) takes an hour ahead of a 5-s run in 28
#: steps instead of 720, each member's time to yellow late by at most this much and its largest
#: utilisation up to a few hundredths low (benchmarks/lookahead.py), where an ensemble runs every
#: plan on every member (benchmarks/forecast_ensemble.py times both)
ENSEMBLE_LADDER = 160.0


@dataclass
class MemberRun:
    """What one member's task returns. ``forecasts``: one :class:`Forecast` per forecast time
    and plan (times outer, plans inner); ``advice``: one :class:`Advice` per forecast time when
    advice was asked (its look-aheads left out); ``wall_s`` / ``cpu_s``: the task's wall and
    CPU time (s; the process's, every thread), scene building and history included;
    ``thread_cpu_s``: the CPU time of the thread that ran it (the rest of ``cpu_s`` is what the
    process's other threads took meanwhile: a Dask worker's event loop); ``factorizations`` /
    ``shared_factorizations``: bulk factorisations made / taken from an earlier member of the
    same process (:func:`run_members`; 0 for a member run alone); ``worker``: the id of the
    process that ran it (which members shared a worker, for the benchmark's balance)."""

    index: int
    params: dict
    ok: bool = False
    forecasts: list = field(default_factory=list, repr=False)
    advice: list = field(default_factory=list, repr=False)
    error: str = ""
    wall_s: float = math.nan
    cpu_s: float = math.nan
    thread_cpu_s: float = math.nan
    factorizations: int = 0
    shared_factorizations: int = 0
    worker: int = 0


#: what a member's run records of each step (``Simulation(recording=...)``): the newest row
#: only, what the screening and the look-aheads read (``stepper.LeanRecorder``); its forecasts
#: equal those of a full recording bit for bit (tests/forecast/test_forecast_lean.py)
MEMBER_RECORDING = "lean"


def screen_row(screening, sim) -> None:
    """Screen the newest row of a member's run: the screening's state (its tracker, the
    screener's level and holds) moves on, no record of the row is kept (a look-ahead reads the
    state only)."""
    screening.update(sim.last_row, unstable=(sim.stopped or {}).get("reason") == "unstable")


def member_steps(steps: Optional[dict]) -> dict:
    """The keywords of :class:`LookAhead` for one member's look-aheads: ``growth``/``dt_max`` as
    given, or ``ladder`` (dt_max in s) made into a :class:`StepLadder` of the member's own (a
    ladder keeps factorisations of one run's discretisation, so members never share one)."""
    steps = dict(steps or {})
    if steps.get("ladder") is not None:
        from .lookahead import StepLadder

        steps["ladder"] = StepLadder(steps["ladder"])
    return steps


def lookaheads(scene, times: Sequence[float], drive=None, start: Optional[datetime] = None,
               steps: Optional[dict] = None):
    """Run ``scene`` from time 0, screened at every row, and yield a :class:`LookAhead` at the
    last step ending by each of ``times`` (s, ascending). ``drive``: what drives the run (an
    InjectionLog), None for the scene's schedule; ``start``: date-time of model time 0;
    ``steps``: the look-aheads' ``growth`` and ``dt_max``, or ``ladder`` (its dt_max, s)
    (default: the scene's own steps); and ``history_dt_max`` (s): the run itself on steps
    doubling from the scene's first up to this size, its last step before each of ``times``
    shortened to end there (faster, less exact: benchmarks/forecast_ensemble.py shows the state
    it reaches against the scene's own steps; default: the scene's own steps, aligned)."""
    from ..screening.stepwise import StepScreening
    from ..stepper import Simulation

    steps = dict(steps or {})
    history = steps.pop("history_dt_max", None)
    if history is not None:
        if not float(history) > 0:
            raise ValueError(f"history steps: dt_max {history!r} must be > 0")
        scene = scene.replace(time=dataclasses.replace(scene.time, growth=2.0, dt_max=float(history)))
    sim = Simulation(scene, recording=MEMBER_RECORDING)
    fp = sim.disc.fault_points
    screening = StepScreening.for_scene(scene, fp.s - sim.disc.injection.s, fp.weight)
    screen_row(screening, sim)
    volume = drive.volume if drive is not None else None
    keywords = member_steps(steps)
    for t in times:
        with sim.solver.blas_threads():   # (held over the steps, not limited and restored at each)
            while sim.advance(t, volume=volume, align=history is None, max_steps=1):
                screen_row(screening, sim)
        yield LookAhead(sim, screening, drive=drive, start=start, **keywords)


def run_member(index: int, scene_dict: dict, overrides: dict, times: Sequence[float], plans: Sequence[Plan],
               horizon: float, drive=None, start: Optional[datetime] = None,
               advice: Optional[dict] = None, steps: Optional[dict] = None) -> MemberRun:
    """One member (the scene of ``scene_dict`` with ``overrides``), run where it is called (a
    Dask worker, or this process). ``advice``: keywords of :func:`advise` (level, max_rate) to
    advise at every time too; ``steps``: the look-aheads' ``growth`` and ``dt_max`` (see
    :class:`LookAhead`). Never raises: a failure comes back with ``ok=False`` and the error,
    as the ensemble command records its runs."""
    from ..ensemble import scene_with
    from ..scene import Scene

    run = MemberRun(index=index, params=dict(overrides), worker=os.getpid())
    wall0, cpu0, thread0 = _time.perf_counter(), _time.process_time(), _time.thread_time()
    try:
        scene = scene_with(Scene.from_dict(scene_dict), overrides)
        for ahead in lookaheads(scene, times, drive, start, steps):
            if advice is not None:
                found = advise(ahead, horizon, **advice)
                found.forecasts = []     # the bisection's look-aheads stay in the worker
                run.advice.append(found)
            run.forecasts.extend(_lean(ahead.run(plan, horizon)) for plan in plans)
        run.ok = True
    except Exception as exc:  # recorded with the member's parameters, never dropped
        run.error = f"{type(exc).__name__}: {exc}"
        if os.environ.get("FAULT_SCREEN_TRACEBACK"):
            run.error += "\n" + traceback.format_exc()
    run.thread_cpu_s = _time.thread_time() - thread0   # (inside the process's window)
    run.cpu_s = _time.process_time() - cpu0
    run.wall_s = _time.perf_counter() - wall0
    return run


#: the bulk stores of this process, by ensemble (a worker keeps its latest ensemble's only)
_STORES: dict = {}


def run_members(ensemble: str, calls: Sequence[tuple]) -> list[MemberRun]:
    """Several members in turn (the arguments of :func:`run_member` each), as one task: the
    members of one ``ensemble`` (any id, the same for all its tasks) run in one process share
    the bulk's order, symbolic analyses and, where their bulks are equal, factors
    (:mod:`~fault_screen.shared_bulk`: bit-identical to each member run alone). A process keeps
    the store of the latest ensemble it ran only; :func:`release` drops it."""
    from ..shared_bulk import SharedBulk, sharing

    store = _STORES.get(ensemble)
    if store is None:
        _STORES.clear()
        store = _STORES[ensemble] = SharedBulk()
    out = []
    with sharing(store):
        for call in calls:
            made, shared = store.made, store.shared
            run = run_member(*call)
            run.factorizations, run.shared_factorizations = store.made - made, store.shared - shared
            out.append(run)
    return out


def release(ensemble: str) -> bool:
    """Drop this process's store of ``ensemble`` (after an ensemble run in this process)."""
    return _STORES.pop(ensemble, None) is not None


def chunks(calls: Sequence, workers: int, per_worker: Optional[int] = None) -> list[list]:
    """``calls`` dealt into tasks: one call a task by default (the scheduler hands the next
    member to whichever worker is free, so the workers end within one member of each other;
    a worker keeps the ensemble's store between its tasks, so nothing shared is lost), or
    ``per_worker`` tasks per worker, round robin, order kept within each; one task for no
    workers (this process)."""
    if workers <= 0:
        return [list(calls)] if len(calls) else []
    if per_worker is None:
        return [[c] for c in calls]
    n = max(1, min(len(calls), int(workers) * per_worker))
    return [list(calls[k::n]) for k in range(n) if calls[k::n]]


#: the series of a forecast a member sends back (for the figure's band)
BAND_METRICS = ("peak_slip_rate", "max_utilisation", "injection_overpressure")


def _lean(f: Forecast) -> Forecast:
    f.metrics = {k: v for k, v in f.metrics.items() if k in BAND_METRICS}
    return f


def time_percentile(times: np.ndarray, q: float) -> Optional[float]:
    """The smallest time by which at least ``q`` % of the members are yellow (``times``: one
    per member, +inf for a member that is not): None when fewer than ``q`` % ever are."""
    t = np.sort(np.asarray(times, dtype=float))
    if t.size == 0:
        return None
    k = max(int(math.ceil(q / 100.0 * t.size - 1e-9)), 1) - 1
    return float(t[k]) if math.isfinite(t[k]) else None


@dataclass
class EnsembleForecast:
    """One forecast time and plan over the ensemble (see the module docstring). ``base``: the
    forecast of the scene itself (the deterministic columns), when it was made; ``failed``:
    (member index, error) of the members that failed; ``advised_rate``: the ensemble's advice
    (m3/s; Pa under pressure control) when asked."""

    made_at: float
    plan: str
    horizon: float
    members: int
    p_yellow: float
    p_red: float
    time_to_yellow: np.ndarray = field(repr=False)
    failed: list = field(default_factory=list)
    base: Optional[Forecast] = None
    advised_rate: Optional[float] = None
    forecasts: list = field(default_factory=list, repr=False)

    def percentile(self, q: float) -> Optional[float]:
        return time_percentile(self.time_to_yellow, q)

    def columns(self) -> dict:
        """The ensemble columns of the forecast.csv row (None where empty)."""
        out = {"p_yellow": self.p_yellow, "p_red": self.p_red}
        for q in PERCENTILES:
            out[f"time_to_yellow_p{q}"] = self.percentile(q)
        out["members"] = self.members
        return out

    def row(self) -> dict:
        """The whole forecast.csv row: the base scene's forecast (made_at, plan and horizon
        always; the rest empty without it), the advice, the ensemble columns."""
        row = dict.fromkeys(COLUMNS)
        if self.base is not None:
            row.update(self.base.row())
        row.update(made_at=self.made_at, plan=self.plan, horizon=self.horizon,
                   advised_rate=self.advised_rate)
        row.update(self.columns())
        return row


def summarise(runs: Iterable[MemberRun], base: Optional[MemberRun] = None) -> list[EnsembleForecast]:
    """One :class:`EnsembleForecast` per forecast time and plan, in the members' order."""
    runs = list(runs)
    ok = [r for r in runs if r.ok]
    failed = [(r.index, r.error) for r in runs if not r.ok]
    shape = ok[0].forecasts if ok else (base.forecasts if base is not None and base.ok else [])
    out = []
    for k, first in enumerate(shape):
        fs = [r.forecasts[k] for r in ok]
        tty = np.array([math.inf if f.time_to_yellow is None else f.time_to_yellow for f in fs])
        n = len(fs)
        out.append(EnsembleForecast(
            made_at=first.made_at, plan=first.plan, horizon=first.horizon, members=n,
            p_yellow=float(np.mean([f.max_level >= YELLOW for f in fs])) if n else math.nan,
            p_red=float(np.mean([f.max_level >= RED for f in fs])) if n else math.nan,
            time_to_yellow=tty, failed=failed, forecasts=fs,
            base=base.forecasts[k] if base is not None and base.ok else None))
    return out


@dataclass
class EnsembleAdvice:
    """The largest constant ``rate`` (m3/s; Pa under pressure control) whose probability of
    reaching ``level`` within ``horizon`` (s) from ``made_at`` is at most ``1 - confidence``
    over ``members`` members. ``probability``: that probability at ``rate``; ``even_zero``:
    the fraction of members that reach the level even at rate 0 (when it exceeds
    ``1 - confidence`` the advice is 0 and says so); ``member_rates``: each member's own
    advised rate (-inf: even rate 0 reaches the level)."""

    made_at: float
    horizon: float
    level: int
    control: str
    confidence: float
    rate: float
    probability: float
    members: int
    even_zero: float
    max_rate: float
    member_rates: np.ndarray = field(repr=False)

    @property
    def even_zero_too_likely(self) -> bool:
        return self.even_zero > 1.0 - self.confidence + 1e-12

    def reaching(self, rate: float) -> float:
        """The fraction of members that reach the level at constant ``rate``, as far as their
        own bisections tell (a member reaches it above its own advised rate)."""
        return float(np.mean(self.member_rates < rate)) if self.members else math.nan

    def describe(self) -> str:
        name = LEVEL_NAMES[self.level]
        span = f"{self.horizon / 3600:.3g} h" if self.horizon >= 3600 else f"{self.horizon:.4g} s"
        allowed = f"{100 * (1 - self.confidence):.3g} %"
        where = f"ensemble advice at t = {self.made_at:.6g} s ({self.members} members)"
        if self.even_zero_too_likely:
            stop = "shut-in" if self.control == "rate" else "overpressure 0"
            return (f"{where}: even {stop} reaches {name} within {span} in {100 * self.even_zero:.3g} % "
                    f"of the members, more than {allowed}: the fault may go there whatever the injection does")
        value = (f"{self.rate * 60e3:.4g} L/min ({self.rate:.4g} m3/s)" if self.control == "rate"
                 else f"{self.rate / 1e6:.4g} MPa")
        what = "rate" if self.control == "rate" else "overpressure"
        return (f"{where}: largest constant {what} with P({name} within {span}) <= {allowed}: {value} "
                f"(P = {100 * self.probability:.3g} %)")


def ensemble_advice(advices: Sequence[Advice], confidence: float) -> EnsembleAdvice:
    """The ensemble's advice from each successful member's :class:`Advice` made at one time."""
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence = {confidence!r}: must be between 0 and 1 (e.g. 0.9)")
    if not advices:
        raise ValueError("no member succeeded: no ensemble advice")
    first = advices[0]
    rates = np.array([-math.inf if a.even_zero_reaches else a.rate for a in advices])
    n = rates.size
    allowed = int(math.floor((1.0 - confidence) * n + 1e-9))   # members that may reach the level
    ordered = np.sort(rates)
    rate = max(float(ordered[allowed]), 0.0) if allowed < n else float(first.max_rate)
    out = EnsembleAdvice(made_at=first.made_at, horizon=first.horizon, level=first.level,
                         control=first.control, confidence=float(confidence), rate=rate,
                         probability=math.nan, members=n,
                         even_zero=float(np.mean(np.isneginf(rates))),
                         max_rate=float(first.max_rate), member_rates=rates)
    out.probability = out.reaching(rate)
    return out


def ensemble_rows(made: Sequence[EnsembleForecast]) -> list[dict]:
    """The forecast.csv rows (COLUMNS + ENSEMBLE_COLUMNS) of ``made``."""
    return [m.row() for m in made]


class LiveEnsemble:
    """N member simulations stepping with live data, and their forecasts on demand.

    ``scene``: the base scene; ``draws``: one dict of dotted-key overrides (SI) per member
    (:func:`~fault_screen.calibration.sample_parameters`); ``base``: keep the scene itself
    stepping too, for the deterministic columns; ``drive``: what drives the members between
    :meth:`advance` calls that give no volume, and whose ``rate_at`` the plan ``hold`` reads
    (a live sample buffer or an InjectionLog), None for the scene's schedule; ``start``: the
    date-time of model time 0; ``advice`` (keywords of :func:`advise`) and ``confidence``: the
    ensemble advice with every forecast; ``steps``: the look-aheads' ``growth`` and ``dt_max``
    (default: the scene's own steps). A member whose step fails is set aside with its error and no
    longer counted (the rows' ``members`` says how many are left, ``members_set_aside`` how
    many were set aside, when any). ``scene`` None: the members are built at the first
    :meth:`forecast`, from the scene of the fork it is given (in the worker that calls it: a
    monitor's start-up does not wait for N models). With ``advice`` each member's bisection
    seeks its bracket around that member's previous advice first (``advise(..., near=)``).

    :meth:`forecast` is the monitor's forecaster protocol (:class:`~fault_screen.monitor.
    lookahead.Forecaster`): ``forecast(sim_fork, plans, horizon, now_utc, *, screening, drive,
    start) -> list[dict]``, one row per plan (forecast.csv's columns with the ensemble ones,
    plus ``made_at_utc``), made on forks of the members. ``drive.received`` (the samples
    received, a PiecewiseLinearVolume) first steps every member to the time of ``sim_fork``
    (whole steps of its sequence, as the live model took them; :attr:`samples_from` says from
    which time they are needed); ``sim_fork`` with ``screening`` (the live model's fork and
    screening state) gives the deterministic columns when the ensemble has no ``base`` member
    of its own; ``drive`` and ``start`` are what the plans read (default: the ensemble's). It
    runs in the caller's thread; :meth:`advance` and the forks a forecast starts from are taken
    under one lock, so a look-ahead worker may call both (stepping N members costs N live
    steps: keep it off the thread that sends the alerts). The members share one
    :class:`~fault_screen.shared_bulk.SharedBulk` (the bulk's order, symbolic analyses, the
    positions of its fixed pattern and the factors of equal bulks, as :func:`run_members`
    shares them: bit-identical to each member alone), in whichever thread steps them. The
    factors are shared within one round (one :meth:`advance` or :meth:`run` over the members)
    and dropped from the store after it: by then every member with an equal bulk has taken
    them and holds its own, and a drawn aperture gives every member a bulk of its own, so
    factors kept longer would only hold memory (a member's superseded ones, the forks')."""

    def __init__(self, scene, draws: Sequence[dict], *, base: bool = True, drive=None,
                 start: Optional[datetime] = None, advice: Optional[dict] = None,
                 confidence: Optional[float] = None, steps: Optional[dict] = None):
        self.drive, self.start = drive, start
        self.advice, self.confidence, self.steps = advice, confidence, dict(steps or {})
        self._keywords = {}   # member index -> its look-ahead keywords (its own ladder)
        self._near = {}       # member index -> its last advised rate (where its next bisection looks)
        self.last_base: Optional[MemberRun] = None   # the deterministic forecast's run, newest
        self.failed: list[tuple[int, str]] = []
        self.members = []     # (index, params, Simulation, StepScreening)
        self._lock = threading.Lock()
        from ..shared_bulk import SharedBulk

        self.store = SharedBulk()   # (thread-safe: the members may step in any thread)
        # the members still to build (None once built)
        self._entries = ([(-1, {})] if base else []) + [(i, dict(d)) for i, d in enumerate(draws)]
        if scene is not None:
            self._build(scene)

    def _build(self, scene) -> None:
        from ..ensemble import scene_with
        from ..screening.stepwise import StepScreening
        from ..stepper import Simulation

        for index, params in self._entries:
            sim = Simulation(scene_with(scene, params) if params else scene, recording=MEMBER_RECORDING)
            fp = sim.disc.fault_points
            screening = StepScreening.for_scene(sim.scene, fp.s - sim.disc.injection.s, fp.weight)
            screen_row(screening, sim)
            self.members.append((index, dict(params), sim, screening))
        self._entries = None

    @property
    def samples_from(self) -> float:
        """The model time (s) from which the members need the injection received: the time of
        the member furthest behind (0 before they are built; +inf when none is left)."""
        if self._entries is not None:
            return 0.0
        return min((float(m[2].time) for m in self.members), default=math.inf)

    def _member_keywords(self, index: int) -> dict:
        if index not in self._keywords:
            self._keywords[index] = member_steps(self.steps)
        return self._keywords[index]

    @property
    def time(self) -> float:
        return float(self.members[0][2].time) if self.members else math.nan

    def advance(self, t_next: float, *, volume=None, pressure=None, align: bool = False) -> int:
        """Step every member to ``t_next`` (s) with the same injection (what
        ``Simulation.advance`` takes; ``align``: whole steps of its sequence only, ending by
        ``t_next``), screening every row; returns the steps of the first."""
        if volume is None and pressure is None and self.drive is not None:
            volume = self.drive.volume
        from ..shared_bulk import sharing

        with self._lock, sharing(self.store):
            try:
                return self._advance(t_next, volume, pressure, align)
            finally:
                self.store.drop_factors()

    def _advance(self, t_next, volume, pressure, align=False) -> int:
        taken, alive = None, []
        for member in self.members:
            index, params, sim, screening = member
            try:
                steps = 0
                while sim.advance(t_next, volume=volume, pressure=pressure, align=align, max_steps=1):
                    screen_row(screening, sim)
                    steps += 1
                alive.append(member)
                taken = steps if taken is None else taken
            except Exception as exc:  # the member is set aside, with its error
                self.failed.append((index, f"{type(exc).__name__}: {exc}"))
        self.members = alive
        return taken or 0

    def run(self, plans: Sequence[Plan], horizon: float, *, sim=None, screening=None, drive=None,
            start: Optional[datetime] = None) -> tuple[list[EnsembleForecast], Optional[EnsembleAdvice]]:
        """The forecasts of every plan over ``horizon`` (s) from now, and the ensemble advice
        when asked (``advice`` keywords and a ``confidence`` given). ``sim`` and ``screening``:
        the model whose forecast gives the deterministic columns, when the ensemble has no base
        member; ``drive``, ``start``: what the plans read (default: the ensemble's)."""
        drive = self.drive if drive is None else drive
        start = self.start if start is None else start
        from ..shared_bulk import sharing

        with sharing(self.store):
            try:
                return self._run(plans, horizon, sim, screening, drive, start)
            finally:
                self.store.drop_factors()

    def _run(self, plans, horizon, sim, screening, drive, start):
        runs, base, aheads = [], None, []
        self.last_base = None
        with self._lock:    # every member forked at the same time
            entries = list(self.members)
            if sim is not None and screening is not None and not any(m[0] < 0 for m in entries):
                entries.insert(0, (-1, {}, sim, screening))
            for index, params, member, screened in entries:
                try:
                    aheads.append((index, params, LookAhead(member, screened, drive=drive, start=start,
                                                            **self._member_keywords(index))))
                except Exception as exc:
                    aheads.append((index, params, exc))
        for index, params, ahead in aheads:
            run = MemberRun(index=index, params=params)
            wall0, cpu0 = _time.perf_counter(), _time.process_time()
            try:
                if isinstance(ahead, Exception):
                    raise ahead
                if self.advice is not None and index >= 0:
                    found = advise(ahead, horizon, **self.advice, near=self._near.get(index))
                    found.forecasts = []
                    run.advice.append(found)
                    # (an advice with a bracket of one end, 0 or the largest rate, tells nothing)
                    self._near[index] = (found.rate if not found.even_zero_reaches and found.rate > 0
                                         and found.upper is not None else None)
                run.forecasts = [_lean(ahead.run(plan, horizon)) for plan in plans]
                run.ok = True
            except Exception as exc:
                run.error = f"{type(exc).__name__}: {exc}"
            run.wall_s, run.cpu_s = _time.perf_counter() - wall0, _time.process_time() - cpu0
            if index < 0:
                base = self.last_base = run
            else:
                runs.append(run)
        failed = [MemberRun(index=i, params={}, error=e) for i, e in self.failed]
        made = summarise(runs + failed, base)
        for m in made:       # made when the deterministic forecast is (a member may end a step before)
            if m.base is not None:
                m.made_at = m.base.made_at
        found = None
        if self.advice is not None and self.confidence is not None:
            advices = [r.advice[0] for r in runs if r.ok and r.advice]
            if advices:
                found = ensemble_advice(advices, self.confidence)
                for m in made:
                    m.advised_rate = found.rate
        return made, found

    def forecast(self, sim_fork, plans: Sequence[Plan], horizon: float, now_utc=None, *,
                 screening=None, drive=None, start=None) -> list[dict]:
        """The forecaster protocol of the monitor's look-ahead worker (see the class docstring)."""
        if self._entries is not None:
            if sim_fork is None:
                raise ValueError("an ensemble built without a scene needs the fork of the live "
                                 "model at its first forecast (its scene)")
            self._build(sim_fork.scene)
        received = getattr(drive, "received", None)
        if received is not None and sim_fork is not None:
            self.advance(float(sim_fork.time), volume=received.volume, align=True)
        live = sim_fork if screening is not None else None
        made, _ = self.run(plans, horizon, sim=live, screening=screening, drive=drive, start=start)
        if live is not None and not (self.last_base is not None and self.last_base.ok):
            # no deterministic columns, no level to alert on: the refresh fails (counted, logged)
            raise RuntimeError("the look-ahead of the live model failed: "
                               + (self.last_base.error if self.last_base is not None else "not made"))
        stamp = now_utc.isoformat() if isinstance(now_utc, datetime) else now_utc
        aside = {"members_set_aside": len(self.failed)} if self.failed else {}
        return [{**m.row(), "made_at_utc": stamp, **aside} for m in made]

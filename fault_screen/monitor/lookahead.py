"""Look-aheads refreshed live: the monitor's forecasts under injection plans, made on forks of
the live simulation in a worker thread while the live steps go on.

Every ``every`` seconds of model time (at the first step ending at or after each multiple),
the stage forks its simulation and copies its screening state on the live thread, between two
steps, and hands them to a worker thread; the worker runs the plans on them (a
:class:`Forecaster`) and the stage collects the rows at its next call.  The worker thread is
started at the first refresh and then waits for the next: a refresh puts its job in a queue,
so the live thread never waits for a new thread to be scheduled (on busy cores that wait, not
the fork, was most of a refresh's wall time on the live thread).  A refresh still running
when the next is due is not queued: the due one is skipped and logged, so at most one
refresh runs and none waits.

The worker thread runs at a lower scheduling priority (``nice`` +10 on Linux): the numba
kernels release the GIL, so the worker's arithmetic runs on the other core; when both
want the same core, the live thread wins.  The worker's Python parts take the GIL in turns
with the live thread: at the same priority, on busy cores, a worker lengthens the live steps'
wall time (not their CPU time); the lower priority keeps it from doing so unless the machine is
overloaded.  A worker process would avoid the GIL at the cost of sending the fork's state
across (not done).

Forecast alerts.  Each plan's forecast is summed up as (level at the horizon, bracket of the
time to yellow); the brackets are :data:`BRACKETS` (``now``: already yellow; ``none``: not
within the horizon).  When that summary changes for any plan, a ``forecast`` alert goes through
the same outbox and sinks as the level changes, its id built as theirs
(:func:`~fault_screen.monitor.stage.alert_id` of the run, the model time of the forecast and
the summaries before and after), so a restarted monitor that makes the same forecast again
does not send it twice.  The first forecast is compared with "green at the horizon, yellow not
within it" for every plan: a quiet start sends nothing.

Ensemble.  With ``ensemble`` (parameter draws, ``--vary``/``--members``) the forecaster is a
:class:`~fault_screen.forecast.ensemble.LiveEnsemble`: N member models, each with its own
history from time 0, stepped in the worker (never on the live thread) from a snapshot of the
samples received so far (taken on the live thread with the fork), caught up to the fork's time
before they forecast; the deterministic columns are the live model's own fork.  The rows get
the ensemble columns (``p_yellow``, ``p_red``, ``time_to_yellow_p10/p50/p90``, ``members``), the
summary of each plan a third part, the band of its P(yellow) (:data:`CHANCES`), and the alert
text the probabilities.
"""
from __future__ import annotations

import copy
import logging
import math
import os
import queue
import threading
import traceback
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from typing import List, Optional, Protocol, Sequence

import numpy as np

from ..forecast import COLUMNS, LookAhead, Plan, StepLadder, advise, parse_plan
from ..forecast.ensemble import ENSEMBLE_COLUMNS
from ..screening import LEVEL_NAMES, YELLOW

__all__ = ["Forecaster", "LookAheadForecaster", "LiveLookAhead", "LiveDrive", "BRACKETS",
           "CHANCES", "LOOKAHEAD_COLUMNS", "ENSEMBLE_LOOKAHEAD_COLUMNS", "bracket", "chance",
           "forecast_alert", "forecast_change", "forecast_text", "lookahead_streams"]

log = logging.getLogger("fault_screen.monitor.lookahead")

#: the columns of ``/lookahead``: forecast.csv's, and the wall-clock date-time of the forecast
LOOKAHEAD_COLUMNS = COLUMNS + ("made_at_utc",)
#: the columns of ``/lookahead`` with an ensemble: those and the ensemble's
ENSEMBLE_LOOKAHEAD_COLUMNS = LOOKAHEAD_COLUMNS + ENSEMBLE_COLUMNS
#: time-to-yellow brackets of the forecast alerts: (upper bound in s, name)
BRACKETS = ((15 * 60.0, "<15 min"), (30 * 60.0, "15-30 min"), (60 * 60.0, "30-60 min"),
            (math.inf, ">60 min"))
#: P(yellow within the horizon) bands of the ensemble's forecast alerts: (upper bound, name)
CHANCES = ((0.1, "<10 %"), (0.5, "10-50 %"), (0.9, "50-90 %"), (math.inf, ">=90 %"))
#: scheduling priority added to the worker thread (Linux: per thread)
WORKER_NICE = 10

_TEXT = {"plan": "S256", "level_now": "S6", "level_at_horizon": "S6", "max_level": "S6",
         "made_at_utc": "S32"}


def bracket(time_to_yellow: Optional[float]) -> str:
    """The bracket of a time to yellow (s): ``now`` (0: already yellow), ``<15 min``,
    ``15-30 min``, ``30-60 min``, ``>60 min``, or ``none`` (not within the horizon)."""
    if time_to_yellow is None or (isinstance(time_to_yellow, float) and math.isnan(time_to_yellow)):
        return "none"
    if time_to_yellow <= 0:
        return "now"
    return next(name for upper, name in BRACKETS if time_to_yellow < upper)


def chance(p_yellow: Optional[float]) -> str:
    """The band of an ensemble's P(yellow within the horizon): ``0`` (no member), ``<10 %``,
    ``10-50 %``, ``50-90 %``, ``>=90 %``; ``none`` when no member is left."""
    if p_yellow is None or not math.isfinite(p_yellow):
        return "none"
    if p_yellow <= 0:
        return "0"
    return next(name for upper, name in CHANCES if p_yellow < upper)


# ---------------------------------------------------------------------------------------------
# the forecaster protocol and the default one
# ---------------------------------------------------------------------------------------------
class Forecaster(Protocol):
    """What the live worker calls at each refresh (in the worker thread).

    ``forecast(sim_fork, plans, horizon, now_utc, *, screening, drive, start)`` returns one row
    per plan (a dict with at least the keys of :data:`LOOKAHEAD_COLUMNS`, ``None`` where empty).
    ``sim_fork``: a fork of the live simulation (``Simulation.fork()``), the forecaster's own;
    ``plans``: :class:`~fault_screen.forecast.Plan` list; ``horizon`` (s); ``now_utc``: aware
    date-time of the refresh; ``screening``: a copy of the live screening state
    (:class:`~fault_screen.screening.StepScreening`) at the fork, the forecaster's own;
    ``drive``: the live drive as a plan reads it (:class:`LiveDrive`); ``start``: date-time of
    model time 0 or None.  It may take as long as it needs (a refresh due meanwhile is
    skipped) and must not touch the live objects.

    A forecaster with models of its own that follow the data (an ensemble) has a
    ``samples_from`` attribute: the model time (s) from which it needs the samples received;
    the stage then keeps every sample and hands the forecaster a snapshot of them from that
    time on as ``drive.received`` (a
    :class:`~fault_screen.io.volume.PiecewiseLinearVolume` of its own)."""

    def forecast(self, sim_fork, plans: Sequence[Plan], horizon: float, now_utc: datetime, *,
                 screening, drive, start) -> List[dict]:
        ...


class LookAheadForecaster:
    """The default forecaster: :class:`~fault_screen.forecast.LookAhead` per plan, with the
    scene's own steps (so that the plan ``scene`` continues the run row for row) or, with
    ``ladder`` (its dt_max, s), on one :class:`~fault_screen.forecast.StepLadder` kept for the
    whole run (the factorisations of its step sizes shared by every refresh); with ``advise``
    the largest constant rate below ``advise_level`` over the horizon (up to ``max_rate`` m3/s,
    default twice the largest rate so far) in every row's ``advised_rate``.  :attr:`last_advice`
    keeps the newest advice; with ``reuse`` the next bisection seeks its bracket around it
    first (``advise(..., near=)``: the same 2 % bracket, fewer look-aheads when the advice
    moved little)."""

    def __init__(self, *, advise: bool = False, advise_level: int = YELLOW,
                 max_rate: Optional[float] = None, ladder: Optional[float] = None,
                 reuse: bool = True):
        self.advise = bool(advise)
        self.advise_level = int(advise_level)
        self.max_rate = max_rate
        self.ladder = StepLadder(ladder) if ladder is not None else None
        self.reuse = bool(reuse)
        self.last_advice = None

    @property
    def near(self) -> Optional[float]:
        """Where the next bisection looks first: the last advised rate (None: a fresh one, also
        after an advice of 0 or of the largest rate tried, whose bracket had one end only)."""
        last = self.last_advice
        if not self.reuse or last is None or last.even_zero_reaches or last.upper is None \
                or not last.rate > 0:
            return None
        return float(last.rate)

    def forecast(self, sim_fork, plans, horizon, now_utc, *, screening, drive=None, start=None):
        ahead = LookAhead(sim_fork, screening, drive=drive, start=start, ladder=self.ladder)
        advice = (advise(ahead, horizon, level=self.advise_level, max_rate=self.max_rate,
                         near=self.near) if self.advise else None)
        rows = []
        for plan in plans:
            f = ahead.run(plan, horizon)
            if advice is not None:
                f.advised_rate = advice.rate
            row = f.row()
            row["made_at_utc"] = now_utc.isoformat()
            rows.append(row)
        self.last_advice = advice
        return rows


class LiveDrive:
    """The live drive as a plan reads it, frozen at the refresh: ``volume(t0, t1)`` of the
    ``scene`` and ``scale`` plans is the scene's own schedule (the planned injection: the log
    stops at its last sample), ``rate_at`` gives the rate of the samples at the model time of
    the fork (the ``hold`` plan), ``time``/``flow_rate`` the largest rate received so far (the
    advice's default upper bound); ``received``: the snapshot of the samples received (for a
    forecaster with ``samples_from``), else None."""

    def __init__(self, schedule, rate_now: float, largest: float, now: float, received=None):
        self.volume = schedule.volume
        self.received = received
        self._rate_now = float(rate_now)
        self.time = np.array([float(now)])
        self.flow_rate = np.array([float(largest)])

    def rate_at(self, t: float) -> float:
        return self._rate_now


# ---------------------------------------------------------------------------------------------
# the worker
# ---------------------------------------------------------------------------------------------
@dataclass
class _Job:
    made_at: float
    sim: object
    screening: object
    drive: object
    now_utc: datetime
    start: Optional[datetime] = None
    rows: Optional[List[dict]] = None
    error: Optional[str] = None
    finished: threading.Event = field(default_factory=threading.Event)


@dataclass
class LiveLookAhead:
    """The look-ahead settings of a stage and its worker.

    ``plans``: plan texts or :class:`~fault_screen.forecast.Plan`; the first is the one the
    alert text leads with (the plan being followed).  ``horizon`` and ``every`` (s of model
    time); ``plan_log_options``: keywords of ``read_injection_log`` for a plan file;
    ``ladder``: the look-aheads' step ladder (its dt_max, s; default: the scene's own steps);
    ``ensemble``: ``{"draws": [dotted-key overrides, SI, one per member], "confidence": C or
    None}`` for an ensemble look-ahead (a :class:`~fault_screen.forecast.ensemble.LiveEnsemble`
    whose members are built in the worker at the first refresh, from the live scene, and replay
    the samples from time 0); ``forecaster``: a :class:`Forecaster` (default:
    :class:`LookAheadForecaster` with ``advise``, ``advise_level``, ``max_rate``, ``ladder``, or
    the ensemble)."""

    plans: Sequence = ("hold",)
    horizon: float = 3600.0
    every: float = 60.0
    advise: bool = False
    advise_level: int = YELLOW
    max_rate: Optional[float] = None
    plan_log_options: Optional[dict] = None
    ladder: Optional[float] = None
    ensemble: Optional[dict] = None
    forecaster: Optional[Forecaster] = None
    # the live state (checkpointed by the stage)
    next_due: float = field(default=None)
    summary: Optional[list] = None
    latest: dict = field(default_factory=dict)
    rows: list = field(default_factory=list)
    made: int = 0
    skipped: int = 0
    failed: int = 0

    def __post_init__(self):
        self.plans = [p if isinstance(p, Plan) else parse_plan(p, log_options=self.plan_log_options)
                      for p in self.plans]
        if not self.plans:
            raise ValueError("the look-ahead needs at least one plan")
        for p in self.plans:
            p.check("rate")
        if not (math.isfinite(self.horizon) and self.horizon > 0):
            raise ValueError(f"look-ahead horizon {self.horizon!r}: must be > 0 s")
        if not (math.isfinite(self.every) and self.every > 0):
            raise ValueError(f"look-ahead every {self.every!r}: must be > 0 s")
        if self.ladder is not None and not (math.isfinite(self.ladder) and self.ladder > 0):
            raise ValueError(f"look-ahead ladder {self.ladder!r}: must be > 0 s")
        if self.ensemble is not None:
            self.ensemble = _ensemble_settings(self.ensemble)
        if self.forecaster is None and self.ensemble is not None:
            from ..forecast.ensemble import LiveEnsemble

            self.forecaster = LiveEnsemble(
                None, self.ensemble["draws"], base=False,
                advice=(dict(level=self.advise_level, max_rate=self.max_rate) if self.advise
                        else None),
                confidence=self.confidence,
                steps=dict(ladder=self.ladder) if self.ladder is not None else None)
        elif self.forecaster is None:
            self.forecaster = LookAheadForecaster(advise=self.advise, advise_level=self.advise_level,
                                                  max_rate=self.max_rate, ladder=self.ladder)
        if self.next_due is None:
            self.next_due = float(self.every)
        if self.summary is None:
            self.summary = [self.quiet] * len(self.plans)
        self._thread: Optional[threading.Thread] = None   # the worker, once started
        self._jobs: "queue.Queue[Optional[_Job]]" = queue.Queue()
        self._done: "queue.Queue[_Job]" = queue.Queue()
        self._running: Optional[_Job] = None
        self._stream = False          # rows go to the result file (not kept)

    @property
    def quiet(self) -> tuple:
        """The summary a first forecast is compared with: green, yellow not within the horizon
        (and, with an ensemble, no member reaching it)."""
        return ("green", "none", "0") if self.ensemble is not None else ("green", "none")

    @property
    def columns(self) -> tuple:
        """The columns of ``/lookahead``."""
        return ENSEMBLE_LOOKAHEAD_COLUMNS if self.ensemble is not None else LOOKAHEAD_COLUMNS

    @property
    def follows_samples(self) -> bool:
        """Does the forecaster keep models that follow the samples (the stage keeps them all)?"""
        return getattr(self.forecaster, "samples_from", None) is not None

    @property
    def confidence(self) -> Optional[float]:
        """The ensemble advice's confidence (None: no ensemble advice)."""
        if self.ensemble is None or not self.advise:
            return None
        c = self.ensemble["confidence"]
        return 0.9 if c is None else c

    # -- settings as plain data ---------------------------------------------------------------
    def settings(self) -> dict:
        return {"plans": [p.name for p in self.plans], "horizon": self.horizon, "every": self.every,
                "advise": self.advise, "advise_level": self.advise_level, "max_rate": self.max_rate,
                "plan_log_options": self.plan_log_options, "ladder": self.ladder,
                "ensemble": self.ensemble}

    def state(self) -> dict:
        """The live state as plain data.  A refresh still running is made again after a
        restart (at the first step at or after its time): its due time is what is saved."""
        due = self._running.made_at if self._running is not None else self.next_due
        return {"settings": self.settings(), "next_due": min(due, self.next_due),
                "summary": [list(s) for s in self.summary], "latest": self.latest,
                "rows": [] if self._stream else self.rows, "made": self.made,
                "skipped": self.skipped, "failed": self.failed}

    def restore_state(self, state: dict) -> None:
        self.next_due = float(state["next_due"])
        summary = [tuple(s) for s in state["summary"]]
        names = state["settings"]["plans"]
        # the same plans continue their summaries; a plan new since then starts quiet
        by_name = dict(zip(names, summary))
        self.summary = [by_name.get(p.name, self.quiet) for p in self.plans]
        self.latest = dict(state.get("latest") or {})
        self.rows = list(state.get("rows") or [])
        self.made, self.skipped = int(state["made"]), int(state["skipped"])
        self.failed = int(state.get("failed", 0))

    # -- refreshes ------------------------------------------------------------------------------
    @property
    def busy(self) -> bool:
        return self._running is not None

    @property
    def running_since(self) -> Optional[float]:
        """Model time (s) of the refresh that runs, or None."""
        return self._running.made_at if self._running is not None else None

    def due(self, time: float) -> bool:
        return time >= self.next_due * (1 - 1e-12)

    def _advance_due(self, time: float) -> None:
        self.next_due = (math.floor(time / self.every * (1 + 1e-12)) + 1) * self.every

    def refresh(self, sim, screening, drive, time: float, start: Optional[datetime] = None) -> bool:
        """Called on the live thread after a step ending at ``time``: when due, fork and hand
        the fork to the worker, or skip when the previous refresh still runs.  Returns whether
        a refresh started."""
        if not self.due(time):
            return False
        self._advance_due(time)
        if self.busy:
            self.skipped += 1
            log.info("look-ahead at t = %.6g s skipped: the refresh made at t = %.6g s still runs",
                     time, self._running.made_at)
            return False
        # the stage's screening keeps no rows (it writes them): a deep copy is its state alone
        job = _Job(made_at=float(time), sim=sim.fork(), screening=copy.deepcopy(screening),
                   drive=drive, now_utc=datetime.now(timezone.utc), start=start)
        self._running = job
        if self._thread is None or not self._thread.is_alive():
            self._thread = threading.Thread(target=self._serve, args=(self._jobs,), daemon=True,
                                            name="look-ahead worker")
            self._thread.start()
        self._jobs.put(job)
        return True

    def _serve(self, jobs) -> None:
        """The worker thread: the refreshes one after the other, until :meth:`close`."""
        lower_worker_priority()
        while True:
            job = jobs.get()
            if job is None:
                return
            self._work(job)

    def close(self) -> None:
        """End the worker thread once its refresh (if any) is done (a later refresh starts
        another)."""
        if self._thread is not None:
            self._jobs.put(None)
            self._jobs = queue.Queue()     # (a later worker takes its jobs from a queue of its own)
        self._thread = None

    def _work(self, job: _Job) -> None:
        try:
            job.rows = list(self.forecaster.forecast(job.sim, self.plans, self.horizon, job.now_utc,
                                                     screening=job.screening, drive=job.drive,
                                                     start=job.start))
        except Exception:  # noqa: BLE001 - a failed look-ahead never stops the live monitor
            job.error = traceback.format_exc()
        finally:
            job.sim = job.screening = None
            self._done.put(job)
            job.finished.set()

    def wait(self, timeout: Optional[float] = None) -> bool:
        """Wait for the refresh that runs (if any); returns whether none runs now."""
        job = self._running
        return job is None or job.finished.wait(timeout)

    def collect(self) -> List[_Job]:
        """The refreshes finished since the last call (on the live thread)."""
        out = []
        while True:
            try:
                job = self._done.get_nowait()
            except queue.Empty:
                break
            if job is self._running:
                self._running = None
            out.append(job)
        return out


def lower_worker_priority() -> None:
    """The calling thread at :data:`WORKER_NICE` (Linux: per thread), where allowed."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), WORKER_NICE)
    except (AttributeError, OSError):    # not Linux, or not allowed: same priority
        pass


# ---------------------------------------------------------------------------------------------
# alerts and storage
# ---------------------------------------------------------------------------------------------
def summary_of(row: dict) -> tuple:
    """A forecast row summed up for the alerts: (level at the horizon, time-to-yellow bracket)
    and, for an ensemble's row, the band of its P(yellow)."""
    out = (str(row["level_at_horizon"]), bracket(row["time_to_yellow"]))
    if "p_yellow" in row:
        out += (chance(row["p_yellow"]),)
    return out


def _in(seconds: float) -> str:
    """A duration for the operator: ``1.5 h``, ``38 min``, ``3 min 30 s``, ``45 s``."""
    if seconds >= 3600:
        return f"{seconds / 3600:.3g} h"
    if seconds >= 600:
        return f"{seconds / 60:.0f} min"
    minutes, rest = divmod(int(round(seconds)), 60)
    if not minutes:
        return f"{rest} s"
    return f"{minutes} min" + (f" {rest} s" if rest else "")


def _when(row: dict, key: str, start: Optional[datetime]) -> str:
    t = float(row["made_at"]) + float(row[key])
    at = (start + timedelta(seconds=t)).astimezone(timezone.utc).strftime("%H:%M UTC") if start \
        else f"t = {t:.6g} s"
    return f"{at} (in {_in(float(row[key]))})"


def _phrase(row: dict, start: Optional[datetime], lead: bool) -> str:
    plan = row["plan"]
    if row["time_to_red"] is not None:
        what = "red now" if row["time_to_red"] == 0 else f"red expected {_when(row, 'time_to_red', start)}"
    elif row["time_to_yellow"] is not None:
        what = ("yellow now" if row["time_to_yellow"] == 0
                else f"yellow expected {_when(row, 'time_to_yellow', start)}")
    else:
        what = None
    if what is None:
        stays = f"stays {row['max_level']} for {_in(float(row['horizon']))}"
        return f"{stays} under plan {plan}" if lead else f"plan {plan} {stays}"
    if row["level_at_horizon"] != row["max_level"]:
        what += f", {row['level_at_horizon']} at the horizon"
    return f"{what} under plan {plan}" if lead else f"plan {plan}: {what}"


def _chances(rows: List[dict]) -> List[str]:
    """The ensemble's part of the text: P(yellow) (and P(red) when a member reaches red) within
    the horizon under each plan, and how many members are counted."""
    within = f"within {_in(float(rows[0]['horizon']))}"
    parts = []
    for key, name in (("p_yellow", "yellow"), ("p_red", "red")):
        values = [r.get(key) for r in rows]
        if name == "red" and not any(v is not None and v > 0 for v in values):
            continue
        each = [f"{'n/a' if v is None or not math.isfinite(v) else f'{v:.2f}'} under plan {r['plan']}"
                for v, r in zip(values, rows)]
        parts.append(f"P({name} {within}) = " + ", ".join(each))
    aside = rows[0].get("members_set_aside") or 0
    counted = f"{rows[0]['members']} members" + (f", {aside} set aside (failed)" if aside else "")
    parts[-1] += f" ({counted})"
    return parts


def forecast_text(rows: List[dict], start: Optional[datetime], advise_level: int = YELLOW,
                  confidence: Optional[float] = None) -> str:
    """One line for the operator: the first plan first, then each other plan, then (an
    ensemble) the probabilities, then the advice (e.g. ``forecast: yellow expected 14:32 UTC
    (in 38 min) under plan hold; plan stop stays green for 1 h; largest rate green for 1 h:
    31 L/min``; an ensemble adds ``P(yellow within 1 h) = 0.30 under plan hold, 0.00 under plan
    stop (10 members)`` and its advice is ``largest rate with P(yellow within 1 h) <= 10 %``)."""
    parts = [_phrase(r, start, i == 0) for i, r in enumerate(rows)]
    if rows[0].get("members") is not None:
        parts += _chances(rows)
    advised = rows[0].get("advised_rate")
    if advised is not None:
        span = _in(float(rows[0]["horizon"]))
        if confidence is not None:
            below = (f"with P({LEVEL_NAMES[advise_level]} within {span}) <= "
                     f"{100 * (1 - confidence):.3g} %")
        else:
            below = ("green" if advise_level == YELLOW else f"below {LEVEL_NAMES[advise_level]}") \
                + f" for {span}"
        parts.append(f"largest rate {below}: {advised * 60e3:.3g} L/min")
    return "forecast: " + "; ".join(parts)


def forecast_change(rows: List[dict], previous: list) -> tuple:
    """What a forecast alert's id is made of: (made_at, the summaries before, after), as text."""
    before = "; ".join(f"{r['plan']}: {', '.join(s)}" for r, s in zip(rows, previous))
    after = "; ".join(f"{r['plan']}: {', '.join(s)}" for r, s in zip(rows, map(summary_of, rows)))
    return float(rows[0]["made_at"]), before, after


def forecast_alert(*, alert_id: str, rows: List[dict], previous: list, start: Optional[datetime],
                   label: str = "", advise_level: int = YELLOW,
                   confidence: Optional[float] = None) -> dict:
    """The ``forecast`` alert of a refresh whose summaries changed from ``previous``: the
    fields of a level-change alert (``id``: ``alert_id`` of :func:`forecast_change`; ``level``,
    ``previous_level`` with codes: the first plan's level at the horizon now and before) plus
    ``kind`` = ``forecast``, ``text``, ``forecasts`` (the rows) and ``summary`` (level at the
    horizon and time-to-yellow bracket per plan)."""
    made_at = float(rows[0]["made_at"])
    now = [summary_of(r) for r in rows]
    level, prev_level = now[0][0], previous[0][0]
    text = forecast_text(rows, start, advise_level, confidence)
    return {
        "id": alert_id, "kind": "forecast", "level": level,
        "level_code": LEVEL_NAMES.index(level), "previous_level": prev_level,
        "previous_level_code": LEVEL_NAMES.index(prev_level),
        "rule": "forecast", "action": text, "text": text,
        "summary": [list(s) for s in now],
        "forecasts": [_json_row(r, ENSEMBLE_LOOKAHEAD_COLUMNS if "p_yellow" in r else LOOKAHEAD_COLUMNS)
                      for r in rows],
        "metrics": {}, "model_time": made_at,
        "model_datetime": (start + timedelta(seconds=made_at)).isoformat() if start else None,
        "wall_time": datetime.now(timezone.utc).isoformat(), "scene": label,
    }


def _json_row(row: dict, columns=LOOKAHEAD_COLUMNS) -> dict:
    out = {}
    for k in columns:
        v = row.get(k)
        out[k] = None if isinstance(v, float) and not math.isfinite(v) else v
    return out


def lookahead_streams(columns=LOOKAHEAD_COLUMNS) -> dict:
    """The ``lookahead`` stream of a result file: one record per forecast row."""
    return {"lookahead": {f"/lookahead/{c}": (_TEXT.get(c, "<f8"), ()) for c in columns}}


def lookahead_record(row: dict, columns=LOOKAHEAD_COLUMNS) -> dict:
    """A forecast row as a record of :func:`lookahead_streams` (empty: NaN)."""
    rec = {}
    for c in columns:
        v = row.get(c)
        if c in _TEXT:
            rec[f"/lookahead/{c}"] = str(v if v is not None else "").encode()
        else:
            rec[f"/lookahead/{c}"] = math.nan if v is None else float(v)
    return rec


def lookahead_arrays(rows: List[dict], columns=LOOKAHEAD_COLUMNS) -> dict:
    """The ``/lookahead`` group of rows kept in memory (the layout of the streamed one)."""
    recs = [lookahead_record(r, columns) for r in rows]
    return {c: np.array([r[f"/lookahead/{c}"] for r in recs], dtype=_TEXT.get(c, "<f8"))
            for c in columns}


def _ensemble_settings(given: dict) -> dict:
    """The ensemble settings as plain data, checked: draws (dicts of dotted keys to floats),
    confidence (0 < C < 1, or None)."""
    draws = [{str(k): float(v) for k, v in d.items()} for d in given.get("draws") or ()]
    if not draws:
        raise ValueError("an ensemble look-ahead needs at least one member (draws)")
    confidence = given.get("confidence")
    if confidence is not None and not 0.0 < float(confidence) < 1.0:
        raise ValueError(f"confidence = {confidence!r}: must be between 0 and 1 (e.g. 0.9)")
    return {"draws": draws, "confidence": None if confidence is None else float(confidence)}

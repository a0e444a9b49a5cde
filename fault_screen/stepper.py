"""The stepper: a scene advanced step by step with data that may arrive later.

``Simulation(scene)`` builds the terms, the discretisation and the solver and records the
in-situ state at t = 0 (``recording="lean"``: the newest row only, with what the screening reads
of it, :class:`LeanRecorder`). ``advance(t_next, volume=...)`` (rate control) or
``advance(t_next, pressure=...)`` (pressure control) moves it to ``t_next`` with the scene's
step sequence (first step ``time.dt``, growing by ``time.growth`` up to ``time.dt_max``); a step
whose Newton iteration fails is halved and retried up to ``solver.max_step_cuts`` times.
``checkpoint(path)`` writes the complete state to HDF5 and ``Simulation.restore(path)``
continues bit-identically; ``fork()`` does the same in memory: an independent simulation that
continues from the current state (a look-ahead), leaving this one as it was.

A run advanced in chunks takes the same steps as one advanced in one go when every chunk ends
on a step of the sequence, or always with ``align=True`` (then a chunk stops at the last whole
step that ends by ``t_next``, never shortening one): this is how a live stage follows data.
Without ``align``, the step that crosses ``t_next`` is shortened to end there and the sequence
continues from its natural size afterwards.
"""
from __future__ import annotations

import collections
import json
import math
import time as _time
import tomllib
from pathlib import Path
from typing import Callable

import numpy as np

from . import __version__
from .discretisation import Discretisation, discretise
from .kernels.contact import H_SLIP
from .outputs import SCHEMA, automatic_profile_due
from .result import Result, atomic_hdf5
from .scene import Scene
from .schedule import StepSchedule
from .solver import NewtonSolver, StepFailed, fault_at_rest, weighted_sum

CHECKPOINT_FORMAT = 1

#: After a step that converged only with the damped Newton, this many steps are damped from the
#: start instead of first failing the full Newton iteration (30 wasted iterations each).
DAMPED_AHEAD = 5

#: After a step that had to be cut, clean steps grow back by at least this factor until they
#: reach the size that failed (the scene's own growth may be 1: without it a single cut would
#: shrink every later step for good). When that size fails again, the next try waits
#: RECOVERY_HOLD clean steps, then twice as many, and so on.
RECOVERY_GROWTH = 1.5
RECOVERY_HOLD = 10

#: Stages of the load continuation, the last resort before a step is halved.
CONTINUATION_STAGES = 4

#: Accepted states an extrapolated first guess is made from (solver.first_guess): the current one
#: and two earlier, a quadratic in time. (On the paper-units Rustrel scene, Newton iterations:
#: 685 from the previous state, 484 linear, 340 quadratic.)
EXTRAPOLATED_STATES = 3


class SimulationError(RuntimeError):
    """The run could not continue (a step failed even after the allowed cuts)."""


class Simulation:
    """A scene advanced in time; see the module docstring."""

    _solver_origin = None   # the solver state a fork or a restored run began from

    def __init__(self, scene: Scene, *, recording: str = "full"):
        wall0 = _time.perf_counter()
        recorder_type = _recorder_type(recording)
        self.scene = scene
        self.disc = discretise(scene)
        self.physics = self.disc.physics
        self.solver = NewtonSolver(self.disc)
        self.schedule = StepSchedule(scene.injection.schedule)
        self.time = 0.0
        self.steps = 0
        self.x = np.zeros(self.disc.n_dofs)
        contact = self.physics.contact
        self.history = contact.initial_history(self.disc) if contact is not None else None
        self.dt = scene.time.dt          # size of the next step of the sequence (s)
        self.injected = 0.0              # m^3, whole interval, cumulative
        self.leaked = 0.0                # m^3 per m of thickness, cumulative
        self.damped_retries = 0          # steps that needed the line search (solver diagnostics)
        self.damped_ahead = 0            # further steps to take damped at once
        self.continuation_steps = 0      # steps that needed the load continuation
        self.dt_recover = 0.0            # step size to grow back to after cuts (s), 0: none
        self.dt_failed = 0.0             # the last step size that had to be cut (s)
        self.recovery_hold = 0           # clean steps to wait before growing back
        self.rung = 0.0                  # first step size of the theta ladder's rung (s), 0: none
        self.stopped = None              # why the run stopped early (meta["stopped"]), or None
        # the accepted states (t, x) before the current one, oldest first, for an extrapolated
        # first guess (solver.first_guess; kept only then)
        self.earlier_states = ()
        # a quasi-static instability can only be told from the slip rate of a rate-dependent law
        self.watch_instability = contact is not None and contact.law.rate_dependent
        self.recorder = recorder_type(self.disc, scene)
        self.recorder.record(0.0, self.x, fault_at_rest(self.disc, self.x), slip_rate=0.0,
                             flow_rate=0.0, volume=0.0, leaked=0.0, iterations=0, cuts=0, dt=0.0,
                             theta=scene.time.theta)
        self.disc.release_element_groups()   # (assembled: the steps do not read them)
        self.build_time = _time.perf_counter() - wall0
        self.wall_time = self.build_time

    # ------------------------------------------------------------------ stepping
    @property
    def last_row(self) -> dict:
        """The newest recorded output row (fault arrays at the Gauss points, scalars)."""
        return self.recorder.last

    def _injection_value(self, volume, pressure, t_next) -> Callable[[float, float], float]:
        """value(t0, t1) of a step: injected volume (rate control) or overpressure at t1."""
        injection = self.physics.injection
        control = injection.control if injection is not None else None
        if volume is not None and control != "rate":
            raise ValueError("volume= drives rate control; this scene has injection.control = "
                             f"{self.scene.injection.control!r}" if injection else "volume= needs a fault to inject into")
        if pressure is not None and control != "pressure":
            raise ValueError("pressure= drives pressure control; this scene has injection.control = "
                             f"{self.scene.injection.control!r}")
        if control == "pressure":
            if pressure is None:
                return lambda t0, t1: self.schedule.value_at(t1)
            if callable(pressure):
                return lambda t0, t1: pressure(t1)
            return lambda t0, t1: float(pressure)
        if volume is None:
            fn = self.schedule.volume
        elif callable(volume):
            fn = volume
        else:
            span = t_next - self.time
            fn = lambda t0, t1: float(volume) * (t1 - t0) / span  # noqa: E731
        if self.scene.injection.allow_flowback:
            return fn

        def checked(t0, t1):
            v = fn(t0, t1)
            if v < 0:
                raise ValueError(f"negative injected volume {v:.6g} m^3 over [{t0:.6g}, {t1:.6g}] s "
                                 f"(flowback): set injection.allow_flowback = true to allow it")
            return v
        return checked

    def advance(self, t_next: float, *, volume=None, pressure=None, align: bool = False,
                max_steps: int | None = None, progress: Callable | None = None,
                observer: Callable | None = None) -> int:
        """Advance to ``t_next`` (s); returns the number of steps taken.

        ``volume``: m^3 injected into the whole interval over [time, t_next] (spread evenly), or
        ``volume(t0, t1)`` -> m^3 over any sub-interval (a log); ``pressure``: overpressure (Pa)
        or ``pressure(t)``; neither: the scene's own schedule. ``align``: stop at the last whole
        step of the sequence that ends by ``t_next``; ``max_steps``: stop after that many steps
        (a caller that checkpoints or polls in between). ``progress(step, t, t_next, wall)`` after
        each step; ``observer(t, x, disc)`` sees every accepted state vector."""
        value = self._injection_value(volume, pressure, t_next)
        wall0 = _time.perf_counter()
        with self.solver.blas_threads():  # held over all the steps (see there)
            try:
                taken = self._advance(t_next, value, align, max_steps, progress, observer, wall0)
            finally:
                self.solver.settle()   # (no factors made ahead outlive the steps)
        self.wall_time += _time.perf_counter() - wall0
        return taken

    def _advance(self, t_next, value, align, max_steps, progress, observer, wall0):
        """The steps of ``advance``, ``value`` the injection value of a step (t0, t1), ``wall0``
        when the call began (for ``progress``)."""
        scene = self.scene
        injection = self.physics.injection
        nof = scene.injection.number_of_fractures
        contact = self.physics.contact
        taken = 0
        while self.time < t_next * (1 - 1e-12):
            if self.stopped is not None or (max_steps is not None and taken >= max_steps):
                break
            t = self.time
            if align and t + self.dt > t_next * (1 + 1e-12):
                break
            dt_try = min(self.dt, t_next - t)
            shortened = dt_try < self.dt
            cuts = 0
            if not shortened:
                self.solver.expect_rung(self._next_rung(t, dt_try, t_next, align,
                                                        None if max_steps is None else max_steps - taken))
            while True:
                t1 = t + dt_try
                step_value = value(t, t1)
                try:
                    out = self._step(dt_try, step_value)
                    break
                except StepFailed as exc:
                    self.solver.expect_rung(None)   # (a halved step: the prediction fails)
                    cuts += 1
                    if cuts > scene.solver.max_step_cuts:
                        raise SimulationError(f"step at t = {t:.6g} s failed after {cuts - 1} cuts "
                                              f"(dt = {dt_try:.3g} s): {exc}") from exc
                    dt_try *= 0.5
            self.rung = self._time_weight(dt_try).get("rung", 0.0)   # (the accepted step's)
            th = self.solver.time_weight   # (the step's: ``NewtonSolver.step``)
            q_model = (injection.model_fault_rate(self.disc, out.x, self.x, step_value, dt_try, th)
                       if injection is not None else 0.0)
            self.injected += q_model * dt_try * nof
            self.leaked += -dt_try * _boundary_inflow(self.disc, out.reactions)
            old_slip = self.history[:, H_SLIP] if self.history is not None else out.point["slip"]
            slip_rate = (out.point["slip"] - old_slip) / dt_try
            if self.scene.solver.first_guess == "extrapolated":
                self.earlier_states = (self.earlier_states + ((t, self.x),))[-(EXTRAPOLATED_STATES - 1):]
            self.x = out.x
            self.history = out.history
            self.steps += 1
            taken += 1
            self.time = t1
            self.recorder.record(t1, self.x, out.point, slip_rate=slip_rate, flow_rate=q_model * nof,
                                 volume=self.injected, leaked=self.leaked, iterations=out.iterations,
                                 cuts=cuts, dt=dt_try, theta=th)
            if observer is not None:
                observer(t1, self.x, self.disc)
            if progress is not None:
                progress(self.steps, t1, t_next, self.wall_time + _time.perf_counter() - wall0)
            if self.watch_instability:
                self._check_instability(t1, slip_rate)
            if cuts:
                # grow back towards the size that failed; if that size fails again, wait longer
                # (RECOVERY_HOLD clean steps, doubling) before the next try
                tried_before = self.dt >= 0.999 * self.dt_failed > 0.0
                self.recovery_hold = (max(RECOVERY_HOLD, 2 * self.recovery_hold) if tried_before else 0)
                self.dt_recover = max(self.dt_recover, self.dt)
                self.dt_failed = self.dt
                self.dt = dt_try
            elif not shortened:
                self.dt, self.dt_recover, self.recovery_hold = self._after_clean_step(
                    dt_try, self.dt_recover, self.recovery_hold)
            if contact is not None:
                limit = contact.law.max_step(slip_rate)
                if limit < self.dt:
                    self.dt_recover = max(self.dt_recover, self.dt)  # grow back once it slows
                    self.dt = limit
        return taken

    def _after_clean_step(self, dt_try, recover, hold):
        """(dt, dt_recover, recovery_hold) after a step of size dt_try that needed no cut and
        was not shortened, from dt_recover and recovery_hold before it: the sequence's growth up
        to dt_max, or back towards the size that failed after cuts (see RECOVERY_GROWTH)."""
        ts = self.scene.time
        dt_max = ts.dt_max if ts.dt_max is not None else ts.dt
        dt = min(dt_try * ts.growth, dt_max)
        if hold > 0:
            hold -= 1
        elif recover > dt:  # after cuts: back to the sequence's size, not stuck
            dt = min(dt_try * max(ts.growth, RECOVERY_GROWTH), recover)
        if dt >= recover:
            recover = 0.0
        return dt, recover, hold

    def _next_rung(self, t, dt_try, t_next, align, steps_left):
        """The first step size of the theta ladder's next rung when the step (t, t + dt_try)
        starts a rung and the steps after it go as planned (no cut, no slip-rate limit, none
        shortened) inside this ``advance`` call; else None. Its factors are then made beside
        this rung's steps (``NewtonSolver.expect_rung``); a wrong guess only costs their work.
        None under pressure control (its steps' sizes follow the held pressure's jumps)."""
        weight = self._time_weight(dt_try)
        injection = self.physics.injection
        if (weight.get("rung") != dt_try or weight.get("rung") == self.rung
                or (injection is not None and injection.control == "pressure")):
            return None
        dt, recover, hold = dt_try, self.dt_recover, self.recovery_hold
        t1, steps = t + dt_try, 1
        while steps_left is None or steps < steps_left:
            if t1 >= t_next * (1 - 1e-12):
                return None
            following, recover, hold = self._after_clean_step(dt, recover, hold)
            if following == dt:
                return None   # (a plateau: this rung's steps from here on)
            if following > t_next - t1 or (align and t1 + following > t_next * (1 + 1e-12)):
                return None   # (shortened to meet the end, or not taken)
            if not self._in_rung(dt_try, following):
                return following
            dt, t1, steps = following, t1 + following, steps + 1
        return None

    def _check_instability(self, t, slip_rate):
        """Stop (``self.stopped``) once the peak slip rate exceeds ``solver.unstable_slip_rate``:
        beyond it the fault slips dynamically, which a quasi-static model cannot follow. The step
        that crossed the limit is kept, so the result shows the runaway."""
        rate = np.abs(np.asarray(slip_rate, dtype=float))
        limit = self.scene.solver.unstable_slip_rate
        if rate.size and rate.max() > limit:
            g = int(np.argmax(rate))
            where = float(self.disc.fault_points.s[g] - self.disc.injection.s)
            self.stopped = dict(
                reason="unstable", time=float(t), slip_rate=float(rate[g]), x=where, limit=limit,
                message=(f"fault became unstable at t = {t:.6g} s: slip rate {rate[g]:.3g} m/s at "
                         f"x = {where:.4g} m exceeds solver.unstable_slip_rate = {limit:.3g} m/s"))

    def _time_weight(self, dt) -> dict:
        """The theta ladder's time weight of a step of size dt (``time.theta_min``), decided
        here alone, as NewtonSolver.step's keywords ({} without the ladder: the scene's theta).
        A step whose weight theta rung / dt (theta the scene's) lies in [theta_min, theta] stays
        in the current rung, at that weight: theta dt is the rung's, whose bulk factors serve it.
        That is a step that grew within the rung, a step shortened to meet an event or the end of
        ``advance`` but not below the rung's first size, and a plateau's size after it. Any other
        size (a cut, a step shorter than the rung's first, growth beyond dt0 theta / theta_min)
        starts a new rung at the scene's theta. The ladder needs a bulk whose factors depend on
        the step through theta dt alone (``CondensedSystem.keeps_factors_at_theta_dt``: rock
        pore pressure); without one the weight stays the scene's."""
        ts = self.scene.time
        if ts.theta_min is None or not self.solver.system.keeps_factors_at_theta_dt:
            return {}
        if self.rung > 0.0 and self._in_rung(self.rung, dt):
            return dict(time_weight=ts.theta * self.rung / dt, rung=self.rung)
        return dict(time_weight=ts.theta, rung=dt)

    def _in_rung(self, rung, dt) -> bool:
        """Is a step of size dt in the rung whose first size is ``rung``: its weight theta rung /
        dt (theta the scene's) in [theta_min, theta]?"""
        ts = self.scene.time
        return ts.theta_min <= ts.theta * rung / dt <= ts.theta

    def _step(self, dt, step_value):
        """One step of size dt: full Newton; if that fails a damped Newton (line search); if
        that fails the load continuation; then the caller halves the step. Each solve at the
        step's time weight (``_time_weight``)."""
        weight = self._time_weight(dt)
        if self.damped_ahead > 0:  # a recent step needed damping: its neighbours likely will
            self.damped_ahead -= 1
        else:
            guess, combination = self._extrapolated_guess(dt)
            if guess is not None:
                try:
                    return self.solver.step(self.x, self.history, dt, step_value, x0=guess,
                                            combination=combination, **weight)
                except StepFailed:
                    pass   # (from the previous state, as without a guess)
            try:
                return self.solver.step(self.x, self.history, dt, step_value, **weight)
            except StepFailed:
                self.damped_retries += 1
                self.damped_ahead = DAMPED_AHEAD
        try:
            return self.solver.step(self.x, self.history, dt, step_value, damped=True, **weight)
        except StepFailed:
            return self._continuation(dt, step_value, weight)

    def _extrapolated_guess(self, dt):
        """The first Newton iterate of a step of size dt under ``solver.first_guess =
        'extrapolated'``: the polynomial through the earlier accepted states and the current one
        (``earlier_states``; quadratic with two earlier ones) at the step's end, the fixed
        unknowns as they are now; with it the weights and the states, oldest first (the solver
        sums their linear products alike). (None, None) otherwise, or before a first step was
        accepted."""
        if not self.earlier_states:
            return None, None
        times = [t for t, _ in self.earlier_states] + [self.time]
        weights = extrapolation_weights(times, self.time + dt)
        guess = weighted_sum([weights[-1], *weights[:-1]],
                             [self.x] + [x for _, x in self.earlier_states])
        fixed = self.solver.fixed_unknowns   # (held by the boundary conditions: not extrapolated)
        guess[fixed] = self.x[fixed]
        return guess, (weights, [x for _, x in self.earlier_states] + [self.x])

    def _continuation(self, dt, step_value, weight):
        """The same step solved through intermediate loads: the step's injection value raised
        from its neutral value (the held overpressure at the step's start under pressure control,
        no volume under rate control) in CONTINUATION_STAGES stages, each damped Newton solve
        starting from the last. Only the final solve is the step: the contact history is that
        of the step's start throughout, so the result is the step's own solution. This is what
        helps a jump of the held pressure, which a shorter step does not reduce."""
        injection = self.physics.injection
        if injection is None:
            raise StepFailed("no load to continue in")
        start = self.disc.injection_overpressure(self.x) if injection.control == "pressure" else 0.0
        guess = None
        for k in range(1, CONTINUATION_STAGES):
            value = start + (step_value - start) * k / CONTINUATION_STAGES
            guess = self.solver.step(self.x, self.history, dt, value, damped=True, x0=guess,
                                     **weight).x
        out = self.solver.step(self.x, self.history, dt, step_value, damped=True, x0=guess,
                               **weight)
        self.continuation_steps += 1
        return out

    # ------------------------------------------------------------------ results
    def result(self) -> Result:
        """The Result of everything recorded so far (in memory; a run streamed to a file is
        read back with ``Result.load``)."""
        return self.recorder.result(self.scene, self.meta())

    def meta(self) -> dict:
        """The run's metadata (``Result.meta``): versions, unknowns, physics, wall times."""
        disc = self.disc
        meta = dict(wall_time=self.wall_time, build_time=self.build_time, version=__version__,
                    dofs=disc.n_dofs, dof_counts=disc.dof_counts(),
                    number_of_fractures=self.scene.injection.number_of_fractures,
                    physics=self.physics.names(), factorizations=self.solver.factorizations,
                    damped_retries=self.damped_retries, continuation_steps=self.continuation_steps,
                    fault_shift=disc.fault.shift)
        if disc.fault.tips is not None:  # a finite fault: where its snapped tips are (s, m)
            meta["fault_tips"] = list(disc.fault.tips)
        if self.stopped is not None:
            meta["stopped"] = dict(self.stopped)
        return meta

    # ------------------------------------------------------------------ streaming
    def stream_to(self, path, *, streams: dict | None = None, meta: dict | None = None):
        """Stream the results to the HDF5 file ``path`` from now on (the rows so far first):
        memory then holds the newest row only. ``streams``: the caller's own growing datasets
        (stream name -> {dataset path: (dtype, record shape)}, e.g. ``/screening/``), appended
        with ``self.writer.append``. The file can be read while the run goes (HDF5 SWMR);
        :meth:`close_stream` finishes it. Returns the writer."""
        from .result_stream import ResultWriter

        rec = self.recorder
        disc = self.disc
        fixed = {"/fault/x": disc.fault_points.s - disc.injection.s, "/fault/xy": disc.fault_points.xy,
                 "/fault/weight": disc.fault_points.weight}
        all_streams = dict(rec.stream_specs())
        all_streams.update(streams or {})
        attrs = {"scene": self.scene.to_toml(),
                 "meta": json.dumps({**self.meta(), **(meta or {}), "streaming": True}, default=float)}
        writer = ResultWriter.create(path, streams=all_streams, fixed=fixed, attrs=attrs)
        rec.stream(writer)
        return writer

    @property
    def writer(self):
        """The ResultWriter the results stream to, or None (kept in memory)."""
        return self.recorder.writer

    def flush(self) -> None:
        """Write the streamed rows so far to the result file (readers see them)."""
        self.recorder.flush()

    def close_stream(self, *, meta: dict | None = None, groups: dict | None = None):
        """Finish the streamed result file: the last row's profile, ``meta`` added to the run's
        metadata, the ``groups`` known only at the end (e.g. ``/events``). Returns its path."""
        rec = self.recorder
        rec.keep_profile()          # the last step always has its profile
        rec.flush()
        path = rec.writer.close(meta={**self.meta(), **(meta or {})}, groups=groups)
        rec.writer = None
        return path

    # ------------------------------------------------------------------ forks
    def fork(self) -> "Simulation":
        """An independent simulation continuing from this one's state, in memory: advancing it
        never changes this one, and it takes the steps this one would take (bit for bit). The
        scene, the discretisation, the physics terms, the solver's constant matrices and its
        current factorisations are shared: the steps only read them, and a fork that needs new
        factors makes its own (``NewtonSolver.fork``). The fork keeps its rows in memory,
        starting with this run's newest row (a look-ahead; this run may stream to a file).
        Call it between steps of this run; after that, this run and the fork may step at the
        same time in two threads (what either writes is its own)."""
        self.solver.system.finish_ahead()   # (the fork shares what that thread reads)
        twin = object.__new__(type(self))
        twin.__dict__.update(self.__dict__)     # the counters and step-sequence state: scalars
        twin.solver = self._forked_solver()
        twin.x = self.x.copy()
        twin.history = None if self.history is None else self.history.copy()
        twin.stopped = None if self.stopped is None else dict(self.stopped)
        twin.recorder = self.recorder.fork()
        return twin

    def _forked_solver(self):
        """The solver of a fork: this one's state, its read-only parts shared (the one place a
        fork gets its solver)."""
        return self.solver.fork()

    def _solver_state(self) -> dict:
        """The solver's checkpoint state; for a fork (or a restored run) that has not taken a
        step yet, the state it was given, which its solver holds but cannot report yet."""
        origin = self._solver_origin
        if origin is not None and self.solver.factorizations == 0:
            return origin
        return self.solver.checkpoint_state()

    # ------------------------------------------------------------------ checkpoints
    def checkpoint(self, path) -> Path:
        """Write the complete state (unknowns, fault history, step size, time, recorded rows,
        scene, solver scaling) to HDF5, atomically (temporary file, then rename)."""
        path = Path(path)
        self.solver.system.finish_ahead()   # (its thread ended: the state as it stands)
        with atomic_hdf5(path) as h5:
            h5.attrs["format"] = CHECKPOINT_FORMAT
            h5.attrs["version"] = __version__
            h5.attrs["scene"] = self.scene.to_toml()
            h5.attrs["state"] = json.dumps(dict(time=self.time, steps=self.steps, dt=self.dt,
                                                injected=self.injected, leaked=self.leaked,
                                                damped_retries=self.damped_retries,
                                                damped_ahead=self.damped_ahead,
                                                continuation_steps=self.continuation_steps,
                                                stopped=self.stopped, dt_recover=self.dt_recover,
                                                dt_failed=self.dt_failed,
                                                recovery_hold=self.recovery_hold, rung=self.rung,
                                                build_time=self.build_time, wall_time=self.wall_time))
            h5["x"] = self.x
            if self.earlier_states:
                h5["earlier_times"] = np.array([t for t, _ in self.earlier_states])
                h5["earlier_x"] = np.array([x for _, x in self.earlier_states])
            if self.history is not None:
                h5["history"] = self.history
            if self.solver.scale is not None:
                h5["solver_scale"] = self.solver.scale
            for key, value in self._solver_state().items():
                h5[f"solver/{key}"] = value
            rec = self.recorder
            h5.attrs["recorder"] = json.dumps(rec.state())
            if rec.writer is not None:
                # the rows are in the result file: the checkpoint keeps how many, and the newest
                rec.flush()
                h5.attrs["stream"] = json.dumps(dict(
                    path=str(Path(rec.writer.path).resolve()), counts=rec.writer.counts(),
                    streams={k: {p: [_descr(d), list(shape)] for p, (d, shape) in v.items()}
                             for k, v in rec.writer.streams.items()}))
                last = h5.create_group("last_row")
                for key, v in rec.last.items():
                    last[key] = v
            else:
                rows = h5.create_group("rows")
                for key in rec.rows[0]:
                    rows[key] = np.array([r[key] for r in rec.rows])
        return path

    @classmethod
    def restore(cls, path, *, stream_to=None) -> "Simulation":
        """A Simulation continuing exactly from a checkpoint. A run that streamed its results
        continues its result file (``stream_to``, default the file it streamed to), truncated
        to the rows the checkpoint counts."""
        import h5py

        from .result_stream import ResultWriter

        with h5py.File(path, "r") as h5:
            if int(h5.attrs.get("format", -1)) != CHECKPOINT_FORMAT:
                raise ValueError(f"{path}: not a fault_screen checkpoint (format {CHECKPOINT_FORMAT})")
            scene = Scene.from_dict(tomllib.loads(h5.attrs["scene"]))
            sim = cls(scene)
            state = json.loads(h5.attrs["state"])
            sim.time, sim.steps, sim.dt = state["time"], state["steps"], state["dt"]
            sim.injected, sim.leaked = state["injected"], state["leaked"]
            sim.damped_retries = state.get("damped_retries", 0)
            sim.damped_ahead = state.get("damped_ahead", 0)
            sim.continuation_steps = state.get("continuation_steps", 0)
            sim.stopped = state.get("stopped")
            sim.dt_recover = state.get("dt_recover", 0.0)
            sim.dt_failed = state.get("dt_failed", 0.0)
            sim.recovery_hold = state.get("recovery_hold", 0)
            sim.rung = state.get("rung", 0.0)
            sim.build_time, sim.wall_time = state["build_time"], state["wall_time"]
            sim.x = h5["x"][()]
            if "earlier_x" in h5:
                sim.earlier_states = tuple(zip(h5["earlier_times"][()].tolist(),
                                               list(h5["earlier_x"][()])))
            sim.history = h5["history"][()] if "history" in h5 else None
            if "solver_scale" in h5:
                sim.solver.scale = h5["solver_scale"][()]
            if "solver" in h5:
                sim._solver_origin = {k: h5["solver"][k][()] for k in h5["solver"]}
                sim.solver.restore_state(sim._solver_origin)
            rec_state = json.loads(h5.attrs["recorder"]) if "recorder" in h5.attrs else None
            stream = json.loads(h5.attrs["stream"]) if "stream" in h5.attrs else None
            if stream is not None:
                last = {k: _scalar(h5["last_row"][k][()]) for k in h5["last_row"]}
            else:
                rows = {k: h5["rows"][k][()] for k in h5["rows"]}
        rec = sim.recorder
        if stream is not None:
            target = stream_to if stream_to is not None else stream["path"]
            streams = {k: {p: (_dtype(d), tuple(shape)) for p, (d, shape) in v.items()}
                       for k, v in stream["streams"].items()}
            writer = ResultWriter.reopen(target, stream["counts"], streams=streams)
            rec.rows = []
            rec.writer = writer
            rec.set_state(rec_state, last)
            return sim
        n = len(next(iter(rows.values())))
        rec.rows = [{k: _scalar(v[i]) for k, v in rows.items()} for i in range(n)]
        for r in rec.rows:
            r.setdefault("profile", True)        # checkpoints before [output]
        rec.set_state(rec_state or dict(count=n), rec.rows[-1])
        return sim


def extrapolation_weights(times, at) -> np.ndarray:
    """Weights w_i of the Lagrange polynomial through values at ``times`` (distinct), evaluated at
    ``at``: p(at) = sum_i w_i v_i (exact for polynomials of degree len(times) - 1)."""
    times = np.asarray(times, dtype=float)
    weights = np.ones(len(times))
    for i, ti in enumerate(times):
        for j, tj in enumerate(times):
            if j != i:
                weights[i] *= (at - tj) / (ti - tj)
    return weights


def _scalar(v):
    return v.item() if np.ndim(v) == 0 else v


def _descr(dtype_str):
    """A dtype as JSON (compound types too)."""
    return np.lib.format.dtype_to_descr(np.dtype(dtype_str))


def _dtype(descr):
    if isinstance(descr, list):
        descr = [tuple(f) for f in descr]
    return np.lib.format.descr_to_dtype(descr)


def _boundary_inflow(disc: Discretisation, reactions: np.ndarray) -> float:
    """Net fluid rate into the model through drained boundaries (m^2/s per m thickness): the
    reactions of the standard pressure rows (they form a partition of unity)."""
    b = disc.blocks
    return float(np.sum(reactions[b.p]) + np.sum(reactions[b.pf]))


class Recorder:
    """One row of outputs per accepted step (and the in-situ state at t = 0), kept in memory
    (``rows``) or streamed to a result file (:meth:`stream`: then only the newest row is kept).

    Full fault profiles are kept at the rows the scene's ``[output]`` asks for (without it: at
    every row in memory, and by the automatic rule of :mod:`fault_screen.outputs` once streaming,
    so a run of any length writes a result of bounded size), the first row, the last row of a result and every row a caller marks
    (:meth:`keep_profile`, e.g. at a change of the screening level); the per-step series at
    every row. The newest row stays open to such a mark until the next row or a flush commits
    it to the file."""

    def __init__(self, disc: Discretisation, scene: Scene):
        self.disc = disc
        self.number_of_fractures = scene.injection.number_of_fractures
        output = scene.output
        self.rows: list[dict] = []
        self.last: dict | None = None     # the newest row
        self.count = 0                    # rows recorded, the in-situ row included
        self.writer = None                # ResultWriter when streaming
        self._open = False                # the newest row is not yet in the file
        self.profile_every = getattr(output, "profile_every", None)
        self.profile_interval = getattr(output, "profile_interval", None)
        # fluid stored in the rock and in the fault: linear in the unknowns, so weights formed once
        self.store_weights = {"rock": np.zeros(disc.n_dofs), "fault": np.zeros(disc.n_dofs)}
        self.nonlinear_stores = []
        for term in disc.physics.terms:
            if term.fluid_store is not None:
                w = term.stored_volume_weights(disc)
                if w is None:
                    self.nonlinear_stores.append(term)
                else:
                    self.store_weights[term.fluid_store] += w

    # -- rows ------------------------------------------------------------------------------
    def record(self, t, x, point, *, slip_rate, flow_rate, volume, leaked, iterations, cuts, dt,
               theta):
        disc = self.disc
        fp = disc.fault_points
        dp = disc.fault_overpressure(x)
        s_inj, o_inj = disc.injection_jump(x)
        p_inj = disc.injection_overpressure(x)
        ng = len(fp.s)
        aperture = point["hydraulic_aperture"]
        stored = {k: float(w @ x) for k, w in self.store_weights.items()}
        for term in self.nonlinear_stores:
            stored[term.fluid_store] += term.stored_volume(disc, x)
        row = dict(
            time=t, overpressure=dp, pressure=fp.p0 + dp, slip=point["slip"], opening=point["opening"],
            slip_rate=np.asarray(slip_rate, dtype=float) * np.ones(ng),
            shear_traction=point["shear_traction"], effective_normal_stress=point["effective_normal_stress"],
            friction=np.asarray(point["friction"], dtype=float).copy(), contact_state=point["contact_state"],
            hydraulic_aperture=aperture,
            inj_flow=flow_rate, inj_overpressure=p_inj, inj_pressure=disc.injection.p0 + p_inj,
            inj_slip=s_inj, inj_opening=o_inj, inj_volume=volume,
            inj_aperture=float(aperture[disc.injection.nearest_point]) if ng else 0.0,
            iterations=iterations, cuts=cuts, dt=dt, theta=theta,
            stored_rock=stored["rock"], stored_fault=stored["fault"], leaked=leaked,
        )
        self._commit()
        row["profile"] = self._profile_due(self.count, t, self.last["time"] if self.last else None)
        self.count += 1
        self.last = row
        if self.writer is None:
            self.rows.append(row)
        else:
            self._open = True

    def _profile_due(self, k: int, t: float, t_before: float | None) -> bool:
        """On a fixed grid (rows 0, N, 2N...; the first row at or after each multiple of T; or
        the automatic rule's rows), so the rows kept do not depend on where the level changed
        or the run was restarted."""
        every, interval = self.profile_every, self.profile_interval
        if t_before is None:
            return True
        if every is None and interval is None:
            # in memory every profile is held anyway: the rule is for results written as they go
            return self.writer is None or automatic_profile_due(k)
        return ((every is not None and k % every == 0)
                or (interval is not None and math.floor(t / interval) > math.floor(t_before / interval)))

    def keep_profile(self) -> None:
        """Keep the full fault profile of the newest row (a level changed there, the run ends)."""
        row = self.last
        if row is None or row["profile"]:
            return
        row["profile"] = True
        if self.writer is not None and not self._open:     # its series are already in the file
            self.writer.append("profiles", self.profile_record(row))

    def fork(self) -> "Recorder":
        """A recorder for a fork: the same layout, its rows in memory, beginning with the newest
        row of this one (which is left as it is, its file included)."""
        twin = object.__new__(type(self))
        twin.__dict__.update(self.__dict__)    # the layout (disc, store weights): read only
        twin.writer = None
        twin._open = False
        twin.last = dict(self.last) if self.last is not None else None
        twin.rows = [twin.last] if twin.last is not None else []
        return twin

    # -- the layout of the result -----------------------------------------------------------
    def series_record(self, row: dict) -> dict:
        """The per-step values of ``row`` by dataset path (the ``rows`` stream)."""
        g = self.disc.injection.nearest_point
        ng = len(self.disc.fault_points.s)
        out = {"/time": row["time"], "/injection/flow_rate": row["inj_flow"],
               "/injection/pressure": row["inj_pressure"], "/injection/overpressure": row["inj_overpressure"],
               "/injection/slip": row["inj_slip"], "/injection/opening": row["inj_opening"],
               "/injection/volume": row["inj_volume"], "/injection/hydraulic_aperture": row["inj_aperture"]}
        for key in ("slip_rate", "shear_traction", "effective_normal_stress", "friction"):
            out[f"/injection/{key}"] = row[key][g] if ng else 0.0
        # Eq. 29: inflow velocity into the single model fault, Q / (NoF 2h) (m/s); the model's
        # source is 2h times it, so the aperture cancels in the balance
        nof = self.number_of_fractures
        ap = row["inj_aperture"]
        out["/injection/fault_inflow_velocity"] = row["inj_flow"] / (nof * ap) if ap > 0 else 0.0
        out.update({"/balance/stored_rock": row["stored_rock"], "/balance/stored_fault": row["stored_fault"],
                    "/balance/leaked": row["leaked"], "/solver/iterations": row["iterations"],
                    "/solver/step_cuts": row["cuts"], "/solver/dt": row["dt"],
                    "/solver/theta": row["theta"]})
        return out

    @staticmethod
    def profile_record(row: dict) -> dict:
        """The fault profiles of ``row`` by dataset path (the ``profiles`` stream)."""
        out = {"/fault/time": row["time"]}
        out.update({f"/fault/{name}": row[name] for name in PROFILE_NAMES})
        return out

    def stream_specs(self) -> dict:
        """The ``rows`` and ``profiles`` streams: dataset path -> (dtype, record shape)."""
        row = self.last if self.last is not None else self.rows[-1]
        spec = lambda rec: {p: (np.asarray(v).dtype.str, np.shape(v)) for p, v in rec.items()}  # noqa: E731
        return {"rows": spec(self.series_record(row)), "profiles": spec(self.profile_record(row))}

    # -- streaming --------------------------------------------------------------------------
    def stream(self, writer) -> None:
        """From now on rows go to ``writer``; the rows kept so far are written to it first."""
        self.writer = writer
        rows, self.rows = self.rows, []
        for row in rows:
            writer.append("rows", self.series_record(row))
            if row["profile"]:
                writer.append("profiles", self.profile_record(row))
        self._open = False

    def _commit(self) -> None:
        """Hand the newest row to the writer (its profile mark is final from now on)."""
        if self.writer is not None and self._open:
            self.writer.append("rows", self.series_record(self.last))
            if self.last["profile"]:
                self.writer.append("profiles", self.profile_record(self.last))
            self._open = False

    def flush(self) -> None:
        if self.writer is not None:
            self._commit()
            self.writer.flush()

    def state(self) -> dict:
        return dict(count=self.count)

    def set_state(self, state: dict, last: dict | None) -> None:
        self.count = int(state["count"])
        self.last = last

    # -- in memory --------------------------------------------------------------------------
    def result(self, scene, meta) -> Result:
        rows = self.rows
        if self.writer is not None or not rows:
            raise RuntimeError("the rows of this run were streamed to "
                               f"{self.writer.path if self.writer else 'a file'}: read them with "
                               f"Result.load")
        records = [self.series_record(r) for r in rows]
        stack = lambda key: np.array([rec[key] for rec in records])  # noqa: E731
        kept = [r for i, r in enumerate(rows) if r["profile"] or i == len(rows) - 1]
        fault = {name: np.array([r[name] for r in kept]) for name in PROFILE_NAMES}
        group = lambda g: {p.rsplit("/", 1)[1]: stack(p) for p in records[0] if p.startswith(f"/{g}/")}  # noqa: E731
        fp = self.disc.fault_points
        time = stack("/time")
        fault_time = np.array([r["time"] for r in kept], dtype=float)
        return Result(scene=scene, time=time, fault_x=fp.s - self.disc.injection.s, fault_xy=fp.xy,
                      fault_weights=fp.weight, fault=fault, injection=group("injection"),
                      balance=group("balance"), solver=group("solver"), meta=dict(meta),
                      fault_time=None if len(kept) == len(rows) else fault_time)


class LeanRecorder(Recorder):
    """The newest row only, holding only what the screening (``MetricsTracker.row_metrics``) and
    a look-ahead read of it: the time, the fault's slip rate, contact state, shear traction and
    effective normal stress, the injection point's overpressure and slip, and the step's
    iterations, cuts and size, each computed as :class:`Recorder` computes it. For runs screened
    row by row and never written (an ensemble member's history and look-aheads): no result, no
    stream, no checkpoint."""

    def __init__(self, disc: Discretisation, scene: Scene):
        self.disc = disc
        self.number_of_fractures = scene.injection.number_of_fractures
        self.rows = collections.deque(maxlen=1)
        self.last: dict | None = None
        self.count = 0
        self.writer = None
        self._open = False
        self.profile_every = self.profile_interval = None

    def record(self, t, x, point, *, slip_rate, flow_rate, volume, leaked, iterations, cuts, dt,
               theta):
        disc = self.disc
        s_inj, _ = disc.injection_jump(x)
        row = dict(time=t, slip=point["slip"],
                   slip_rate=np.asarray(slip_rate, dtype=float) * np.ones(len(disc.fault_points.s)),
                   shear_traction=point["shear_traction"],
                   effective_normal_stress=point["effective_normal_stress"],
                   contact_state=point["contact_state"],
                   inj_overpressure=disc.injection_overpressure(x), inj_slip=s_inj,
                   iterations=iterations, cuts=cuts, dt=dt, theta=theta, profile=False)
        self.count += 1
        self.last = row
        self.rows.append(row)

    def keep_profile(self) -> None:
        pass

    def fork(self) -> "LeanRecorder":
        twin = super().fork()
        twin.rows = collections.deque(twin.rows, maxlen=1)
        return twin

    def _refuse(self, what: str):
        raise RuntimeError(f"a lean recording keeps the newest row only: no {what} "
                           f"(make the Simulation with recording='full')")

    def stream(self, writer) -> None:
        self._refuse("result file")

    def state(self) -> dict:
        self._refuse("checkpoint")

    def result(self, scene, meta) -> Result:
        self._refuse("result")


#: what ``Simulation(scene, recording=...)`` records of each step
RECORDINGS = {"full": Recorder, "lean": LeanRecorder}


def _recorder_type(recording: str) -> type:
    try:
        return RECORDINGS[recording]
    except KeyError:
        raise ValueError(f"recording {recording!r}: one of {', '.join(RECORDINGS)}") from None


#: the (time, x) fault profiles, in the schema's order
PROFILE_NAMES = tuple(o.name for o in SCHEMA if o.group == "fault" and o.shape == "(time, x)")

"""The stepper: a scene advanced step by step with data that may arrive later.

``Simulation(scene)`` builds the terms, the discretisation and the solver and records the
in-situ state at t = 0. ``advance(t_next, volume=...)`` (rate control) or
``advance(t_next, pressure=...)`` (pressure control) moves it to ``t_next`` with the scene's
step sequence (first step ``time.dt``, growing by ``time.growth`` up to ``time.dt_max``); a step
whose Newton iteration fails is halved and retried up to ``solver.max_step_cuts`` times.
``checkpoint(path)`` writes the complete state to HDF5 and ``Simulation.restore(path)``
continues bit-identically.

A run advanced in chunks takes the same steps as one advanced in one go when every chunk ends
on a step of the sequence, or always with ``align=True`` (then a chunk stops at the last whole
step that ends by ``t_next``, never shortening one): this is how a live stage follows data.
Without ``align``, the step that crosses ``t_next`` is shortened to end there and the sequence
continues from its natural size afterwards.
"""
from __future__ import annotations

import json
import time as _time
import tomllib
from pathlib import Path
from typing import Callable

import numpy as np

from . import __version__
from .discretisation import Discretisation, discretise
from .kernels.contact import H_SLIP
from .outputs import SCHEMA
from .result import Result, atomic_hdf5
from .scene import Scene
from .schedule import StepSchedule
from .solver import NewtonSolver, StepFailed, fault_at_rest

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


class SimulationError(RuntimeError):
    """The run could not continue (a step failed even after the allowed cuts)."""


class Simulation:
    """A scene advanced in time; see the module docstring."""

    def __init__(self, scene: Scene):
        wall0 = _time.perf_counter()
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
        self.stopped = None              # why the run stopped early (meta["stopped"]), or None
        # a quasi-static instability can only be told from the slip rate of a rate-dependent law
        self.watch_instability = contact is not None and contact.law.rate_dependent
        self.recorder = Recorder(self.disc)
        self.recorder.record(0.0, self.x, fault_at_rest(self.disc, self.x), slip_rate=0.0,
                             flow_rate=0.0, volume=0.0, leaked=0.0, iterations=0, cuts=0, dt=0.0)
        self.build_time = _time.perf_counter() - wall0
        self.wall_time = self.build_time

    # ------------------------------------------------------------------ stepping
    @property
    def last_row(self) -> dict:
        """The newest recorded output row (fault arrays at the Gauss points, scalars)."""
        return self.recorder.rows[-1]

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
        scene = self.scene
        ts = scene.time
        dt_max = ts.dt_max if ts.dt_max is not None else ts.dt
        injection = self.physics.injection
        nof = scene.injection.number_of_fractures
        contact = self.physics.contact
        wall0 = _time.perf_counter()
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
            while True:
                t1 = t + dt_try
                step_value = value(t, t1)
                try:
                    out = self._step(dt_try, step_value)
                    break
                except StepFailed as exc:
                    cuts += 1
                    if cuts > scene.solver.max_step_cuts:
                        raise SimulationError(f"step at t = {t:.6g} s failed after {cuts - 1} cuts "
                                              f"(dt = {dt_try:.3g} s): {exc}") from exc
                    dt_try *= 0.5
            th = self.solver.time_weight
            q_model = (injection.model_fault_rate(self.disc, out.x, self.x, step_value, dt_try, th)
                       if injection is not None else 0.0)
            self.injected += q_model * dt_try * nof
            self.leaked += -dt_try * _boundary_inflow(self.disc, out.reactions)
            old_slip = self.history[:, H_SLIP] if self.history is not None else out.point["slip"]
            slip_rate = (out.point["slip"] - old_slip) / dt_try
            self.x = out.x
            self.history = out.history
            self.steps += 1
            taken += 1
            self.time = t1
            self.recorder.record(t1, self.x, out.point, slip_rate=slip_rate, flow_rate=q_model * nof,
                                 volume=self.injected, leaked=self.leaked, iterations=out.iterations,
                                 cuts=cuts, dt=dt_try)
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
                self.dt = min(dt_try * ts.growth, dt_max)
                if self.recovery_hold > 0:
                    self.recovery_hold -= 1
                elif self.dt_recover > self.dt:  # after cuts: back to the sequence's size, not stuck
                    self.dt = min(dt_try * max(ts.growth, RECOVERY_GROWTH), self.dt_recover)
                if self.dt >= self.dt_recover:
                    self.dt_recover = 0.0
            if contact is not None:
                limit = contact.law.max_step(slip_rate)
                if limit < self.dt:
                    self.dt_recover = max(self.dt_recover, self.dt)  # grow back once it slows
                    self.dt = limit
        self.wall_time += _time.perf_counter() - wall0
        return taken

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

    def _step(self, dt, step_value):
        """One step of size dt: full Newton; if that fails a damped Newton (line search); if
        that fails the load continuation; then the caller halves the step."""
        if self.damped_ahead > 0:  # a recent step needed damping: its neighbours likely will
            self.damped_ahead -= 1
        else:
            try:
                return self.solver.step(self.x, self.history, dt, step_value)
            except StepFailed:
                self.damped_retries += 1
                self.damped_ahead = DAMPED_AHEAD
        try:
            return self.solver.step(self.x, self.history, dt, step_value, damped=True)
        except StepFailed:
            return self._continuation(dt, step_value)

    def _continuation(self, dt, step_value):
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
            guess = self.solver.step(self.x, self.history, dt, value, damped=True, x0=guess).x
        out = self.solver.step(self.x, self.history, dt, step_value, damped=True, x0=guess)
        self.continuation_steps += 1
        return out

    # ------------------------------------------------------------------ results
    def result(self) -> Result:
        """The Result of everything recorded so far."""
        disc = self.disc
        meta = dict(wall_time=self.wall_time, build_time=self.build_time, version=__version__,
                    dofs=disc.n_dofs, dof_counts=disc.dof_counts(),
                    number_of_fractures=self.scene.injection.number_of_fractures,
                    physics=self.physics.names(), factorizations=self.solver.factorizations,
                    damped_retries=self.damped_retries, continuation_steps=self.continuation_steps,
                    fault_shift=disc.fault.shift)
        if self.stopped is not None:
            meta["stopped"] = dict(self.stopped)
        return self.recorder.result(self.scene, meta)

    # ------------------------------------------------------------------ checkpoints
    def checkpoint(self, path) -> Path:
        """Write the complete state (unknowns, fault history, step size, time, recorded rows,
        scene, solver scaling) to HDF5, atomically (temporary file, then rename)."""
        path = Path(path)
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
                                                recovery_hold=self.recovery_hold,
                                                build_time=self.build_time, wall_time=self.wall_time))
            h5["x"] = self.x
            if self.history is not None:
                h5["history"] = self.history
            if self.solver.scale is not None:
                h5["solver_scale"] = self.solver.scale
            for key, value in self.solver.checkpoint_state().items():
                h5[f"solver/{key}"] = value
            rows = h5.create_group("rows")
            for key in self.recorder.rows[0]:
                rows[key] = np.array([r[key] for r in self.recorder.rows])
        return path

    @classmethod
    def restore(cls, path) -> "Simulation":
        """A Simulation continuing exactly from a checkpoint."""
        import h5py

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
            sim.build_time, sim.wall_time = state["build_time"], state["wall_time"]
            sim.x = h5["x"][()]
            sim.history = h5["history"][()] if "history" in h5 else None
            if "solver_scale" in h5:
                sim.solver.scale = h5["solver_scale"][()]
            if "solver" in h5:
                sim.solver.restore_state({k: h5["solver"][k][()] for k in h5["solver"]})
            rows = {k: h5["rows"][k][()] for k in h5["rows"]}
        n = len(next(iter(rows.values())))
        sim.recorder.rows = [{k: _scalar(v[i]) for k, v in rows.items()} for i in range(n)]
        return sim


def _scalar(v):
    return v.item() if np.ndim(v) == 0 else v


def _boundary_inflow(disc: Discretisation, reactions: np.ndarray) -> float:
    """Net fluid rate into the model through drained boundaries (m^2/s per m thickness): the
    reactions of the standard pressure rows (they form a partition of unity)."""
    b = disc.blocks
    return float(np.sum(reactions[b.p]) + np.sum(reactions[b.pf]))


class Recorder:
    """One row of outputs per accepted step (and the in-situ state at t = 0)."""

    def __init__(self, disc: Discretisation):
        self.disc = disc
        self.rows: list[dict] = []
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

    def record(self, t, x, point, *, slip_rate, flow_rate, volume, leaked, iterations, cuts, dt):
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
        self.rows.append(dict(
            time=t, overpressure=dp, pressure=fp.p0 + dp, slip=point["slip"], opening=point["opening"],
            slip_rate=np.asarray(slip_rate, dtype=float) * np.ones(ng),
            shear_traction=point["shear_traction"], effective_normal_stress=point["effective_normal_stress"],
            friction=np.asarray(point["friction"], dtype=float).copy(), contact_state=point["contact_state"],
            hydraulic_aperture=aperture,
            inj_flow=flow_rate, inj_overpressure=p_inj, inj_pressure=disc.injection.p0 + p_inj,
            inj_slip=s_inj, inj_opening=o_inj, inj_volume=volume,
            inj_aperture=float(aperture[disc.injection.nearest_point]) if ng else 0.0,
            iterations=iterations, cuts=cuts, dt=dt,
            stored_rock=stored["rock"], stored_fault=stored["fault"], leaked=leaked,
        ))

    def result(self, scene, meta) -> Result:
        rows = self.rows
        stack = lambda k: np.array([row[k] for row in rows])
        fault = {o.name: stack(o.name) for o in SCHEMA if o.group == "fault" and o.shape == "(time, x)"}
        injection = {
            "flow_rate": stack("inj_flow"), "pressure": stack("inj_pressure"),
            "overpressure": stack("inj_overpressure"), "slip": stack("inj_slip"),
            "opening": stack("inj_opening"), "volume": stack("inj_volume"),
            "hydraulic_aperture": stack("inj_aperture"),
        }
        g = self.disc.injection.nearest_point
        for key in ("slip_rate", "shear_traction", "effective_normal_stress", "friction"):
            injection[key] = fault[key][:, g] if fault[key].shape[1] else np.zeros(len(rows))
        # Eq. 29: inflow velocity into the single model fault, Q / (NoF 2h) (m/s); the model's
        # source is 2h times it, so the aperture cancels in the balance
        nof = scene.injection.number_of_fractures
        with np.errstate(divide="ignore", invalid="ignore"):
            injection["fault_inflow_velocity"] = np.where(
                injection["hydraulic_aperture"] > 0,
                injection["flow_rate"] / (nof * injection["hydraulic_aperture"]), 0.0)
        balance = {"stored_rock": stack("stored_rock"), "stored_fault": stack("stored_fault"),
                   "leaked": stack("leaked")}
        solver = {"iterations": stack("iterations"), "step_cuts": stack("cuts"), "dt": stack("dt")}
        fp = self.disc.fault_points
        return Result(scene=scene, time=stack("time"), fault_x=fp.s - self.disc.injection.s, fault_xy=fp.xy,
                      fault_weights=fp.weight, fault=fault, injection=injection, balance=balance,
                      solver=solver, meta=dict(meta))


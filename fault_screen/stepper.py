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
import os
import time as _time
import tomllib
from pathlib import Path
from typing import Callable

import numpy as np

from . import __version__
from .discretisation import Discretisation, discretise
from .kernels.contact import H_SLIP
from .outputs import SCHEMA
from .result import Result
from .scene import Scene
from .schedule import StepSchedule
from .solver import NewtonSolver, StepFailed, fault_at_rest

CHECKPOINT_FORMAT = 1


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
            return self.schedule.volume
        if callable(volume):
            return volume
        span = t_next - self.time
        return lambda t0, t1: float(volume) * (t1 - t0) / span

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
        wall0 = _time.perf_counter()
        taken = 0
        while self.time < t_next * (1 - 1e-12):
            if max_steps is not None and taken >= max_steps:
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
                    out = self.solver.step(self.x, self.history, dt_try, step_value)
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
            if cuts:
                self.dt = dt_try
            elif not shortened:
                self.dt = min(dt_try * ts.growth, dt_max)
        self.wall_time += _time.perf_counter() - wall0
        return taken

    # ------------------------------------------------------------------ results
    def result(self) -> Result:
        """The Result of everything recorded so far."""
        disc = self.disc
        meta = dict(wall_time=self.wall_time, build_time=self.build_time, version=__version__,
                    dofs=disc.n_dofs, dof_counts=disc.dof_counts(),
                    number_of_fractures=self.scene.injection.number_of_fractures,
                    physics=self.physics.names(), factorizations=self.solver.factorizations)
        return self.recorder.result(self.scene, meta)

    # ------------------------------------------------------------------ checkpoints
    def checkpoint(self, path) -> Path:
        """Write the complete state (unknowns, fault history, step size, time, recorded rows,
        scene, solver scaling) to HDF5, atomically (temporary file, then rename)."""
        import h5py

        path = Path(path)
        tmp = path.with_name(path.name + ".part")
        try:
            with h5py.File(tmp, "w") as h5:
                h5.attrs["format"] = CHECKPOINT_FORMAT
                h5.attrs["version"] = __version__
                h5.attrs["scene"] = self.scene.to_toml()
                h5.attrs["state"] = json.dumps(dict(time=self.time, steps=self.steps, dt=self.dt,
                                                    injected=self.injected, leaked=self.leaked,
                                                    build_time=self.build_time, wall_time=self.wall_time))
                h5["x"] = self.x
                if self.history is not None:
                    h5["history"] = self.history
                if self.solver.scale is not None:
                    h5["solver_scale"] = self.solver.scale
                rows = h5.create_group("rows")
                for key in self.recorder.rows[0]:
                    rows[key] = np.array([r[key] for r in self.recorder.rows])
                h5.flush()
                os.fsync(h5.id.get_vfd_handle())
            os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()
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
            sim.build_time, sim.wall_time = state["build_time"], state["wall_time"]
            sim.x = h5["x"][()]
            sim.history = h5["history"][()] if "history" in h5 else None
            if "solver_scale" in h5:
                sim.solver.scale = h5["solver_scale"][()]
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


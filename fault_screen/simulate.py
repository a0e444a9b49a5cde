"""Time stepping: advance a scene from its in-situ state to its end time.

A step whose Newton iteration fails is halved and retried (up to ``solver.max_step_cuts``
times) instead of returning garbage; the step size then grows back by ``time.growth``.
Rate control injects exactly the schedule's volume in each step (the step-average rate);
pressure control holds the injection-point overpressure through a Lagrange multiplier, which is
the injection rate.
"""
from __future__ import annotations

import time as _time
from typing import Callable

import numpy as np

from . import __version__
from .model import Model
from .postprocess import fluid_volumes
from .result import Result
from .scene import Scene
from .solver import ContactState, NewtonSolver, StepFailed


class SimulationError(RuntimeError):
    """The run could not continue (a step failed even after the allowed cuts)."""


def step_schedule_volume(schedule, t0: float, t1: float) -> float:
    """Volume (m^3) of a piecewise-constant rate schedule between t0 and t1."""
    times = np.array([p[0] for p in schedule] + [np.inf])
    rates = np.array([p[1] for p in schedule])
    lo = np.clip(times[:-1], t0, t1)
    hi = np.clip(times[1:], t0, t1)
    return float(np.sum(rates * (hi - lo)))


def step_schedule_value(schedule, t: float) -> float:
    """Value of a step schedule on the interval ending at t (0 before the first step)."""
    v = 0.0
    for ts, val in schedule:
        if ts < t:
            v = val
    return v


def simulate(scene: Scene, *, progress: Callable | None = None, injected_volume=None,
             model: Model | None = None, observer: Callable | None = None) -> Result:
    """Run ``scene``; ``injected_volume(t0, t1)`` (m^3 of the whole interval) overrides the scene's
    rate schedule (used for logs); ``progress(step, t, end, wall)`` is called after each step;
    ``observer(t, x, model)`` sees every accepted state vector (for checks on nodal fields)."""
    wall0 = _time.perf_counter()
    model = model or Model(scene)
    build_time = _time.perf_counter() - wall0
    solver = NewtonSolver(model)
    inj = scene.injection
    nof = inj.number_of_fractures
    if injected_volume is None and inj.log is not None:
        from .io.injection_log import read_injection_log

        log = read_injection_log(inj.log, flow_unit=inj.log_flow_unit, max_gap=inj.log_max_gap,
                                 policy=inj.log_policy)
        injected_volume = log.volume
    volume_fn = injected_volume or (lambda a, b: step_schedule_volume(inj.schedule, a, b))
    ts = scene.time
    dt_max = ts.dt_max if ts.dt_max is not None else ts.dt

    x = np.zeros(model.n_dofs)
    hist = ContactState.initial(model)
    rec = _Recorder(model, solver)
    rec.record(0.0, x, None, hist, 0.0, 0.0, 0.0, 0, 0)
    if observer is not None:
        observer(0.0, x, model)
    t, dt, step = 0.0, ts.dt, 0
    leaked = 0.0
    injected_total = 0.0
    while t < ts.end * (1 - 1e-12):
        dt_try = min(dt, ts.end - t)
        cuts = 0
        while True:
            t1 = t + dt_try
            if model.has_q:
                q_rate = 0.0
                prescribed = step_schedule_value(inj.schedule, t1)
            else:
                vol = volume_fn(t, t1)
                q_rate = vol / dt_try / nof
                prescribed = 0.0
            try:
                out = solver.step(x, hist, dt_try, model.load, q_rate, q_rate, prescribed)
                break
            except StepFailed as exc:
                cuts += 1
                if cuts > scene.solver.max_step_cuts:
                    raise SimulationError(f"step at t = {t:.6g} s failed after {cuts - 1} cuts "
                                          f"(dt = {dt_try:.3g} s): {exc}") from exc
                dt_try *= 0.5
        if model.has_q:
            lam = out.x[model.blocks.q.start]
            lam_n = x[model.blocks.q.start]
            q_model = solver.theta * lam + (1 - solver.theta) * lam_n
        else:
            q_model = q_rate
        injected_total += q_model * dt_try * nof
        leaked += -dt_try * _boundary_inflow(model, out.reactions)
        slip_rate = (out.slip - hist.slip) / dt_try
        x = out.x
        hist = out.history
        step += 1
        t = t1
        rec.record(t, x, out, hist, slip_rate, q_model * nof, injected_total, out.iterations, cuts,
                   leaked=leaked, dt=dt_try)
        if observer is not None:
            observer(t, x, model)
        if progress is not None:
            progress(step, t, ts.end, _time.perf_counter() - wall0)
        dt = min(dt_try * ts.growth, dt_max) if cuts == 0 else dt_try
    wall = _time.perf_counter() - wall0
    return rec.result(scene, wall_time=wall, build_time=build_time, version=__version__)


def _boundary_inflow(model: Model, reactions: np.ndarray) -> float:
    """Net fluid rate into the model through drained boundaries (m^2/s per m thickness): the
    reactions of the standard pressure rows (they form a partition of unity)."""
    b = model.blocks
    return float(np.sum(reactions[b.p]) + np.sum(reactions[b.pf]))


class _Recorder:
    def __init__(self, model: Model, solver: NewtonSolver):
        self.m = model
        self.solver = solver
        self.rows = []
        self.inj_gp = int(np.argmin(np.abs(model.fp.s - model.inj_s))) if len(model.fp.s) else 0

    def record(self, t, x, out, hist, slip_rate, flow_rate, volume, iterations, cuts, leaked=0.0, dt=0.0):
        m = self.m
        fp = m.fp
        dp = m.fault_overpressure(x)
        if out is None:
            ng = len(fp.s)
            slip, opening, slip_rate = np.zeros(ng), np.zeros(ng), np.zeros(ng)
            tau, sn = fp.tau0.copy(), fp.sigma_n0.copy()
            state = np.zeros(ng, dtype=np.int64)
            friction = np.full(ng, m.scene.fault.friction)
            aperture = np.full(ng, m.scene.fault.hydraulic_aperture)
        else:
            slip, opening, tau, sn, state = out.slip, out.opening, out.tau, out.sigma_n, out.state
            friction, aperture = out.friction, out.aperture
        s_inj, o_inj = m.injection_jump(x)
        p_inj = m.injection_overpressure(x)
        vols = fluid_volumes(m, x)
        self.rows.append(dict(
            time=t, overpressure=dp, pressure=fp.p0 + dp, slip=slip, opening=opening,
            slip_rate=np.asarray(slip_rate, dtype=float) * np.ones(len(fp.s)), shear_traction=tau,
            effective_normal_stress=sn, friction=friction, contact_state=state,
            hydraulic_aperture=aperture,
            inj_flow=flow_rate, inj_overpressure=p_inj, inj_pressure=m.inj_p0 + p_inj, inj_slip=s_inj,
            inj_opening=o_inj, inj_volume=volume,
            inj_aperture=float(aperture[self.inj_gp]) if len(aperture) else 0.0, iterations=iterations, cuts=cuts, dt=dt,
            stored_rock=vols["rock"], stored_fault=vols["fault"], leaked=leaked,
        ))

    def result(self, scene, **meta):
        r = self.rows
        stack = lambda k: np.array([row[k] for row in r])
        fault = {k: stack(k) for k in ("pressure", "overpressure", "slip", "opening", "slip_rate",
                                        "shear_traction", "effective_normal_stress", "friction",
                                        "contact_state", "hydraulic_aperture")}
        injection = {
            "flow_rate": stack("inj_flow"), "pressure": stack("inj_pressure"),
            "overpressure": stack("inj_overpressure"), "slip": stack("inj_slip"),
            "opening": stack("inj_opening"), "volume": stack("inj_volume"),
            "hydraulic_aperture": stack("inj_aperture"),
        }
        # contact quantities live at the fault's Gauss points: at the injection point, the
        # nearest one (within a quarter element)
        for key in ("slip_rate", "shear_traction", "effective_normal_stress", "friction"):
            injection[key] = fault[key][:, self.inj_gp] if fault[key].shape[1] else np.zeros(len(r))
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
        m = self.m
        meta = dict(meta)
        meta.update(dofs=m.n_dofs, dof_counts=m.dof_counts(),
                    number_of_fractures=scene.injection.number_of_fractures)
        return Result(scene=scene, time=stack("time"), fault_x=m.fp.s - m.inj_s, fault_xy=m.fp.xy,
                      fault_weights=m.fp.weight,
                      fault=fault, injection=injection, balance=balance, solver=solver, meta=meta)

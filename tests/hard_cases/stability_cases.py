"""The hard cases: scenes of configs/hard-cases/ and the variants the suite runs of them.

Used by the tests in this folder (one run per case per session, shared by its asserts) and by
``benchmarks/stability.py`` (steps, cuts, Newton iterations, smallest step, wall time).
"""
from __future__ import annotations

import copy
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
HARD = ROOT / "configs" / "hard-cases"

# the fluid-driven-slip family: fault-frame stresses (Pa) and the held overpressure
SIGMA_N, TAU_T04, SIGMA_T, DP, FRICTION = 10e6, 4.8e6, 12e6, 5e6, 0.6


def load(name: str, **changes):
    """Scene ``configs/hard-cases/<name>.toml`` with ``section__key=value`` changes."""
    from fault_screen import Scene

    data = copy.deepcopy(Scene.from_toml(HARD / f"{name}.toml").to_dict())
    for key, value in changes.items():
        section, k = key.split("__")
        data.setdefault(section, {})[k] = value
    return Scene.from_dict(data)


def rotated_stress(angle_deg: float, sigma_n=SIGMA_N, tau=TAU_T04, sigma_t=SIGMA_T) -> list:
    """[sxx', syy', sxy'] (tension +) giving normal compression sigma_n, shear tau (driving slip
    along +t) and along-fault compression sigma_t on a fault at ``angle_deg``."""
    a = np.deg2rad(angle_deg)
    t, n = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    s = -sigma_t * np.outer(t, t) - sigma_n * np.outer(n, n) + tau * (np.outer(t, n) + np.outer(n, t))
    return [float(s[0, 0]), float(s[1, 1]), float(s[0, 1])]


def ramp_volume(times, rates):
    """V(t0, t1) (m^3) of a log whose rate (m^3/s) is linear between samples: the exact integral."""
    times, rates = np.asarray(times, float), np.asarray(rates, float)

    def cumulative(t):
        t = np.clip(t, times[0], times[-1])
        k = min(int(np.searchsorted(times, t, side="right")) - 1, len(times) - 2)
        dt = t - times[k]
        slope = (rates[k + 1] - rates[k]) / (times[k + 1] - times[k])
        full = np.concatenate([[0.0], np.cumsum(0.5 * (rates[1:] + rates[:-1]) * np.diff(times))])
        return full[k] + rates[k] * dt + 0.5 * slope * dt * dt

    return lambda t0, t1: cumulative(t1) - cumulative(t0)


@dataclass
class Case:
    scene: Callable
    about: str
    volume: Callable | None = None       # V(t0, t1) replacing the schedule (a log)
    family: str = ""
    meta: dict = field(default_factory=dict)


def _point(offset, angle, control):
    extra = {}
    if control == "rate":
        extra = dict(injection__control="rate", injection__schedule=[[0.0, 1e-3]])
    return lambda: load("injection-point-anywhere", fault__point=[offset, offset], fault__angle=angle,
                        initial__effective_stress=rotated_stress(angle), **extra)


def _angle(angle, point=(0.37, 0.37)):
    return lambda: load("fault-geometry", fault__angle=angle, fault__point=list(point),
                        initial__effective_stress=rotated_stress(angle))


CASES: dict[str, Case] = {}
for _o, _label in ((0.0, "node"), (1e-6, "1e-6"), (1e-3, "1e-3"), (0.3, "0.3"), (0.5, "0.5")):
    CASES[f"point-{_label}-30deg-pressure"] = Case(_point(_o, 30.0, "pressure"), "injection point", family="point")
for _o, _label in ((1e-6, "1e-6"), (0.5, "0.5")):
    CASES[f"point-{_label}-0deg-pressure"] = Case(_point(_o, 0.0, "pressure"), "injection point", family="point")
for _o, _label, _a in ((0.0, "node", 30.0), (1e-6, "1e-6", 30.0), (0.5, "0.5", 30.0), (0.3, "0.3", 0.0)):
    CASES[f"point-{_label}-{_a:g}deg-rate"] = Case(_point(_o, _a, "rate"), "injection point", family="point-rate")
for _a in (0.0, 45.0, 63.0, 89.9, 90.0, 135.0):
    CASES[f"angle-{_a:g}"] = Case(_angle(_a), "fault angle", family="angle")
CASES["mesh-line-90"] = Case(_angle(90.0, (0.0, 0.37)), "fault along a mesh line", family="angle")
CASES["mesh-line-0"] = Case(_angle(0.0, (0.37, 0.0)), "fault along a mesh line", family="angle")
CASES["critically-stressed-T0.02"] = Case(lambda: load("critically-stressed"), "lambda(T = 0.02)")
CASES["far-from-failure-T0.98"] = Case(lambda: load("far-from-failure"), "no slip beyond the point")
CASES["hydraulic-jacking"] = Case(lambda: load("hydraulic-jacking"), "opens, closes after shut-in")
CASES["permeability-0-poroelastic"] = Case(lambda: load("impermeable-poroelastic"), "cut-row storage bound")
CASES["permeability-1e-12"] = Case(lambda: load("very-permeable"), "leak-off dominates")
for _k in (1e9, 1e12, 1e15):
    CASES[f"penalty-{_k:.0e}"] = Case(
        (lambda k: lambda: load("penalty-stiffness", fault__normal_stiffness=k, fault__shear_stiffness=k))(_k),
        "penalty stiffness", family="penalty")
CASES["dt-100s"] = Case(lambda: load("time-steps"), "end state independent of the step", family="dt")
CASES["dt-1e-3s-growing"] = Case(lambda: load("time-steps", time__dt=1e-3, time__growth=1.5, time__dt_max=100.0),
                                 "end state independent of the step", family="dt")
CASES["rate-jump-schedule"] = Case(lambda: load("rate-jump"), "x100 jump inside a step")
CASES["rate-jump-log"] = Case(lambda: load("rate-jump"), "x100 ramp between two samples",
                              volume=ramp_volume([0.0, 400.0, 500.0, 900.0, 900.0 + 1e-9, 1200.0],
                                                 np.array([0.5, 0.5, 50.0, 50.0, 0.0, 0.0]) / 60000.0))
CASES["flowback"] = Case(lambda: load("flowback"), "negative rates with allow_flowback")
for _a, _b in ((1e-4, 0.0), (0.05, 0.0), (1e-4, 5e-5)):
    CASES[f"rate-state-a{_a:g}-b{_b:g}"] = Case(
        (lambda a, b: lambda: load("rate-and-state", fault__rate_parameter=a, fault__state_parameter=b,
                                   effects__state_evolution=b > 0))(_a, _b),
        "rate-and-state a", family="rate-state")
CASES["velocity-weakening"] = Case(lambda: load("velocity-weakening"), "unstable: stops cleanly")
CASES["stick-slip-cycling"] = Case(lambda: load("stick-slip-cycling"), "runs to the end")
CASES["stick-slip-cycling-dilation"] = Case(lambda: load("stick-slip-cycling", effects__dilation=True),
                                            "cycles three times; opening = tan(psi) plastic slip")
CASES["finite-fault"] = Case(lambda: load("finite-fault"), "ends in the rock: elliptical slip", family="finite")

#: cases the benchmark runs but the tests do not: known open failures (README, Numerical stability)
OPEN_CASES: dict[str, Case] = {}


def _point_refined(offset, size):
    """The 30-degree rate-controlled point case with elements of ``size`` (m) around the point,
    the point ``offset`` of an element off the node."""
    return lambda: load("injection-point-anywhere", fault__point=[offset * size, offset * size],
                        fault__angle=30.0, initial__effective_stress=rotated_stress(30.0),
                        injection__control="rate", injection__schedule=[[0.0, 1e-3]],
                        mesh__refinement=dict(center=[0.0, 0.0], half_width=[6.0, 4.0], size=size,
                                              growth=1.35))


#: the rate-controlled point off the node under refinement (a slow test, not the benchmark):
#: "point-<offset>-30deg-rate-h<element size in m>"
REFINED_CASES: dict[str, Case] = {
    f"point-{_label}-30deg-rate-h{_h:g}": Case(_point_refined(_o, _h), "mesh convergence", family="refined")
    for _h in (1.0, 0.5, 0.25) for _o, _label in ((0.0, "node"), (0.3, "0.3"), (0.5, "0.5"))
}
#: the finite fault under refinement: "finite-fault-h<element size in m>"
REFINED_CASES.update({
    f"finite-fault-h{_h:g}": Case(
        (lambda h: lambda: load("finite-fault", mesh__refinement=dict(center=[0.0, 0.0], half_width=[5.0, 3.0],
                                                                     size=h, growth=1.3)))(_h),
        "mesh convergence", family="refined")
    for _h in (1.0, 0.5, 0.25)
})


@dataclass
class Run:
    scene: object
    sim: object
    result: object
    wall: float
    warnings: list


_RUNS: dict[str, Run] = {}


def run_case(name: str) -> Run:
    """Run a case once per process (later calls share the run)."""
    if name in _RUNS:
        return _RUNS[name]
    from fault_screen import Simulation

    case = {**CASES, **OPEN_CASES, **REFINED_CASES}[name]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = case.scene()
        t0 = time.perf_counter()
        sim = Simulation(scene)
        sim.advance(scene.time.end, volume=case.volume)
        wall = time.perf_counter() - t0
    out = Run(scene, sim, sim.result(), wall, [str(w.message) for w in caught])
    _RUNS[name] = out
    return out


def balance_error(result) -> float:
    """Largest |stored + drained - injected| over the run, relative to the largest injected
    volume (into the model fault: the interval's divided by NoF), as in
    tests/verification/test_verification_mass_balance.py."""
    nof = result.scene.injection.number_of_fractures
    injected = result.injection["volume"] / nof
    b = result.balance
    accounted = b["stored_fault"] + b["stored_rock"] + b["leaked"]
    return float(np.max(np.abs(accounted - injected)) / max(np.max(np.abs(injected)), 1e-300))


def all_finite(result) -> bool:
    groups = (result.fault, result.injection, result.balance, result.solver)
    return bool(np.all(np.isfinite(result.time))
                and all(np.all(np.isfinite(np.asarray(v, dtype=float))) for g in groups for v in g.values()))


def solver_stats(run: Run) -> dict:
    s = run.result.solver
    it = np.asarray(s["iterations"][1:], dtype=float)
    dt = np.asarray(s["dt"][1:], dtype=float)
    return dict(steps=len(it), cuts=int(np.sum(s["step_cuts"])), damped=run.result.meta.get("damped_retries", 0),
                it_mean=float(it.mean()) if it.size else 0.0, it_max=int(it.max()) if it.size else 0,
                dt_min=float(dt.min()) if dt.size else float("nan"), wall=run.wall,
                stopped=(run.result.meta.get("stopped") or {}).get("reason", ""))


#: issue 9: stored + drained within 1e-6 of the injected volume
BALANCE_TOL = 1e-6


def check_common(run, *, stopped=None):
    """Every hard case: ran to its end (or stopped for the documented physical reason), nothing
    non-finite, and the fluid volume balances."""
    import pytest

    r = run.result
    if stopped is None:
        assert "stopped" not in r.meta, r.meta.get("stopped")
        assert r.time[-1] == pytest.approx(run.scene.time.end, rel=1e-12)
    else:
        assert r.meta["stopped"]["reason"] == stopped
    assert all_finite(r)
    assert balance_error(r) < BALANCE_TOL

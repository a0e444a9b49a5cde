"""What accuracy costs: a ladder of discretisations (and effects switched off) of one scene, each
rung's cost and the error of the quantities an operator screens on.

Rungs: element size near the fault x2, x1, x1/2, ... (``levels`` of them; the graded mesh's
fine size, or nx and ny), time step x2, x1, x1/2, ... (dt and dt_max), and the scene with each
switchable effect off in turn (where the rest is a valid scene). A quantity is measured against
the exact solution when the scene belongs to a family whose solution is known in closed form
(``exact_family``: along-fault diffusion, self-similar fluid-driven slip; the formulas are in
``exact.py``) and the family gives that quantity, otherwise against Richardson extrapolation
from each ladder's three finest rungs with the observed order of convergence. Effect rungs are
compared with the full scene.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from .ensemble import Runner, Variant, default_summary
from .exact import fault_diffusion_pressure, fluid_driven_slip, slip_front_lambda
from .physics import SWITCHABLE, effects_on, terms_for
from .scene import Scene, SceneError

#: screened quantities (default_summary keys) and what they are
QUANTITIES = {
    "peak_overpressure": "peak injection overpressure (Pa)",
    "injection_slip": "slip at the injection point at the end (m)",
    "slipping_length": "length of fault slipping at the end (m)",
    "peak_slip_rate": "peak slip rate on the fault (m/s)",
    "max_utilisation": "peak |tau| / (mu0 sigma_n') on the fault, from the screening layer (-)",
    "time_first_yellow": "time the traffic light first turns yellow (s; empty if never)",
    "time_first_red": "time the traffic light first turns red (s; empty if never)",
}
#: quantities each exact family measures against its closed-form solution (the end state);
#: a ``*_l2`` quantity is itself the relative L2 error of an end profile, the others are end values
FAMILY_QUANTITIES = {
    "fault_diffusion": {
        "fault_overpressure_l2": "fault overpressure profile at the end, L2 error relative to dp",
        "injection_flow_rate": "injection flow rate at the end (m^3/s)",
    },
    "fluid_driven_slip": {
        "slip_l2": "slip profile at the end, L2 error relative to the exact profile's L2 norm",
        "injection_slip": "slip at the injection point at the end (m)",
        "slipping_length": "length of fault slipping at the end, exact 2 lambda sqrt(4 alpha t) (m)",
        "fault_overpressure_l2": "fault overpressure profile at the end, L2 error relative to dp",
        "injection_flow_rate": "injection flow rate at the end (m^3/s)",
    },
}
#: quantities that only mean something on a fault that slips somewhere
SLIP_QUANTITIES = ("injection_slip", "slipping_length", "peak_slip_rate")


# ---- the exact families ----------------------------------------------------------------------------
def exact_family(scene: Scene) -> str | None:
    """The closed-form family the scene belongs to, or None. Both hold a constant overpressure dp
    at the injection point from t = 0 on a fault in impermeable rock (poroelastic and leak-off
    off, constant aperture, a given fault storativity), with the pressure front sqrt(4 alpha t_end)
    well inside the domain:

    - 'fault_diffusion': rigid rock (mechanics off). p = dp erfc(|x| / sqrt(4 alpha t)),
      alpha = T / S, injected rate 2 T dp / sqrt(pi alpha t) (T the transmissivity).
    - 'fluid_driven_slip': elastic homogeneous rock (no zones, damage zone or gravity), constant
      friction f (rate friction and dilation off), 0 < T = (f sigma_n' - |tau0|) / (f dp) < 1
      with sigma_n', tau0 the initial effective stress on the fault (p0 = 0): the self-similar
      crack of Bhattacharya & Viesca (2019) / Viesca (2021), slip front a = lambda(T) sqrt(4 alpha t),
      alpha = T / (S + 1/kN) (a closed penalty fault also stores dp/kN by opening its springs).
    """
    on, inj, f = effects_on(scene), scene.injection, scene.fault
    if ("fault" not in on or on & {"poroelastic", "leak_off", "aperture_evolution"} or "fault_flow" not in on
            or inj.control != "pressure" or len(inj.schedule) != 1 or inj.schedule[0][0] != 0.0
            or inj.schedule[0][1] <= 0 or f.storativity is None or f.storativity <= 0 or inj.log is not None
            or f.length is not None):  # both solutions are for a fault through the whole model
        return None
    if "mechanics" not in on:
        family = "fault_diffusion"
    elif (on & {"rate_friction", "state_evolution", "dilation", "gravity", "damage_zone"} or scene.zones
          or scene.initial.pore_pressure != 0.0 or inj.position != 0.0
          or not 0.0 < _stress_injection_parameter(scene) < 1.0):
        return None
    else:
        family = "fluid_driven_slip"
    front = math.sqrt(4 * _diffusivity(scene, family) * scene.time.end)
    if family == "fluid_driven_slip":
        front *= slip_front_lambda(_stress_injection_parameter(scene))
    half = 0.5 * (scene.mesh.lx if f.angle % 180 == 0 else min(scene.mesh.lx, scene.mesh.ly))
    return family if 3 * front < half else None


def _transmissivity(scene):
    f = scene.fault
    return f.hydraulic_aperture ** 3 / (12 * scene.fluid.viscosity * f.kappa)


def _diffusivity(scene, family):
    f = scene.fault
    storage = f.storativity + (1.0 / f.normal_stiffness if family == "fluid_driven_slip" else 0.0)
    return _transmissivity(scene) / storage


def _fault_stress(scene):
    """(sigma_n', |tau0|) on the fault plane from the initial stress (Pa, compression positive);
    with p0 = 0 every stress kind reads the same."""
    sxx, syy, sxy = scene.initial.stress if scene.initial.stress is not None else (0.0, 0.0, 0.0)
    a = math.radians(scene.fault.angle)
    t, n = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
    stress = np.array([[sxx, sxy], [sxy, syy]])
    return float(-(n @ stress @ n)), float(abs(t @ stress @ n))


def _stress_injection_parameter(scene):
    """T = (f sigma_n' - |tau0|) / (f dp) (-): 1 - T measures how close to failure dp brings it."""
    sigma, tau = _fault_stress(scene)
    f = scene.fault.friction
    return (f * sigma - tau) / (f * scene.injection.schedule[0][1])


def exact_summary(result, family: str) -> dict:
    """Each family quantity of one run and its exact reference ``exact_<q>`` at the run's end
    time (an ``*_l2`` quantity is already the error: its reference is 0)."""
    scene = result.scene
    dp = scene.injection.schedule[0][1]
    t = float(result.time[-1])
    alpha = _diffusivity(scene, family)
    x, w = result.fault_x, result.fault_weights
    p_exact = fault_diffusion_pressure(x, t, dp=dp, alpha=alpha)
    out = {
        "fault_overpressure_l2": _l2(result.fault["overpressure"][-1] - p_exact, w, np.full_like(x, dp)),
        "injection_flow_rate": float(result.injection["flow_rate"][-1]),
        "exact_injection_flow_rate": 2 * _transmissivity(scene) * dp / math.sqrt(math.pi * alpha * t)
        * scene.injection.number_of_fractures,
    }
    if family == "fluid_driven_slip":
        T = _stress_injection_parameter(scene)
        rock = scene.rock
        shear_modulus = rock.youngs_modulus / (2 * (1 + rock.poissons_ratio))
        kw = dict(alpha=alpha, dp=dp, f=scene.fault.friction, T=T, shear_modulus=shear_modulus,
                  nu=rock.poissons_ratio)
        slip = np.abs(result.fault["slip"][-1])
        d_exact = fluid_driven_slip(x, t, **kw)
        a = slip_front_lambda(T) * math.sqrt(4 * alpha * t)
        out.update({
            "slip_l2": _l2(slip - d_exact, w, d_exact),
            # the values themselves are default_summary's injection_slip and slipping_length
            "exact_injection_slip": float(fluid_driven_slip(0.0, t, **kw)),
            "exact_slipping_length": 2 * a,
        })
    return out


def _l2(diff, w, ref) -> float:
    return float(math.sqrt(np.sum(w * diff ** 2) / np.sum(w * ref ** 2)))


def known_quantities(scene: Scene) -> list:
    """The quantities a study of ``scene`` can compare: its exact family's, then the screened ones."""
    family = exact_family(scene)
    exact = list(FAMILY_QUANTITIES[family]) if family else []
    return exact + [q for q in QUANTITIES if q not in exact]


def reference_of(scene: Scene, quantity: str) -> str:
    """'exact' when the scene's family has a closed form for the quantity, else 'richardson'."""
    family = exact_family(scene)
    return "exact" if family and quantity in FAMILY_QUANTITIES[family] else "richardson"


def rung_summary(result) -> dict:
    out = default_summary(result)
    out["element_size"] = _element_size(result.scene)
    family = exact_family(result.scene)
    if family:
        out.update(exact_summary(result, family))
    return out


def _element_size(scene) -> float:
    """Element size along the fault (m): the graded mesh's fine size, or the uniform spacing
    in the direction closest to the fault's."""
    m = scene.mesh
    if m.refinement is not None:
        return m.refinement.size
    a = math.radians(scene.fault.angle)
    return m.lx / m.nx if abs(math.cos(a)) >= abs(math.sin(a)) else m.ly / m.ny


# ---- the ladder --------------------------------------------------------------------------------------
@dataclass
class Rung:
    name: str
    kind: str
    """'space', 'time' or 'effect' (the base scene is the x1 rung of both ladders)."""
    overrides: dict
    factor: float = 1.0
    effect_off: str = ""


def _same_parity(x: float, n: int) -> int:
    """Nearest integer to x >= 1 with the parity of n (keeps the fault in the middle of an
    element row and the injection point on an element edge, as the scene placed them)."""
    lo = max(1, int(math.floor(x)))
    cands = [k for k in (lo - 1, lo, lo + 1, lo + 2) if k >= 1 and k % 2 == n % 2]
    return min(cands, key=lambda k: (abs(k - x), -k))


def ladder(scene: Scene, levels: int = 3, effects: bool = True,
           kinds=("space", "time")) -> tuple[list, list]:
    """(rungs, skipped): factors 2, 1, 1/2, ... (``levels`` of them) on the element size and on
    the time step, and each effect that is on turned off in turn. ``skipped`` lists (effect,
    reason) for effects whose removal leaves an invalid scene."""
    if levels < 2:
        raise ValueError(f"levels = {levels}: need at least 2 rungs per ladder")
    factors = [2.0 ** (1 - k) for k in range(levels)]
    rungs = [Rung("base", "space", {}, 1.0)]
    m, t = scene.mesh, scene.time
    for f in factors if "space" in kinds else ():
        if f == 1.0:
            continue
        if m.refinement is not None:
            over = {"mesh.refinement.size": m.refinement.size * f}
        else:
            over = {"mesh.nx": _same_parity(m.nx / f, m.nx), "mesh.ny": _same_parity(m.ny / f, m.ny)}
        rungs.append(Rung(f"h x{_fmt(f)}", "space", over, f))
    # the leak-off grading follows the first step (0.5 sqrt(c dt)): the time rungs keep the base's
    # grading, so that they change the time step only, on the base mesh
    graded = terms_for(scene).graded_cut_height(scene)
    for f in factors if "time" in kinds else ():
        if f == 1.0:
            continue
        over = {"time.dt": min(t.dt * f, t.end)}
        if t.dt_max is not None:
            over["time.dt_max"] = max(t.dt_max * f, over["time.dt"])
        if graded > 0 and m.fault_grading_size is None:
            over["mesh.fault_grading_size"] = graded
        rungs.append(Rung(f"dt x{_fmt(f)}", "time", over, f))
    skipped = []
    if effects:
        from .ensemble import scene_with

        on = effects_on(scene)
        for name in SWITCHABLE:
            if name not in on:
                continue
            over = {f"effects.{name}": False}
            try:
                scene_with(scene, over)
            except SceneError as exc:
                skipped.append((name, str(exc)))
                continue
            rungs.append(Rung(f"no {name}", "effect", over, 1.0, name))
    return rungs, skipped


def _fmt(f):
    return f"{f:g}" if f >= 1 else f"1/{1 / f:g}"


# ---- Richardson extrapolation ------------------------------------------------------------------------
@dataclass
class Extrapolation:
    value: float
    order: float
    asymptotic: bool
    note: str = ""


def richardson(h, q) -> Extrapolation:
    """From three (h, Q) pairs (any ratios): the order p with
    (Q1 - Q2) / (Q2 - Q3) = (h1^p - h2^p) / (h2^p - h3^p) and the extrapolated Q at h = 0.
    ``asymptotic`` is False when the differences change sign (oscillating), when they are at
    round-off, or when p falls outside [0.5, 6]."""
    h = np.asarray(h, dtype=float)
    q = np.asarray(q, dtype=float)
    order = np.argsort(-h)
    h, q = h[order], q[order]
    d1, d2 = q[0] - q[1], q[1] - q[2]
    scale = max(abs(q).max(), 1e-300)
    if abs(d1) <= 1e-12 * scale and abs(d2) <= 1e-12 * scale:
        return Extrapolation(float(q[2]), float("nan"), True, "converged to round-off")
    if d2 == 0 or d1 / d2 <= 0:
        return Extrapolation(float(q[2]), float("nan"), False, "differences change sign: not asymptotic")
    ratio = d1 / d2

    def g(p):
        return (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p) - ratio

    from scipy.optimize import brentq

    lo, hi = 0.05, 12.0
    if g(lo) * g(hi) > 0:
        return Extrapolation(float(q[2]), float("nan"), False, f"no order in [{lo}, {hi}]")
    p = brentq(g, lo, hi, xtol=1e-10)
    value = q[2] - d2 * h[2] ** p / (h[1] ** p - h[2] ** p)
    ok = 0.5 <= p <= 6.0
    return Extrapolation(float(value), float(p), ok, "" if ok else f"observed order {p:.2f} outside [0.5, 6]")


# ---- the study ---------------------------------------------------------------------------------------
@dataclass
class Study:
    rows: list
    """One dict per rung: rung, kind, element_size, dt, effect_off, wall_s, peak_memory_mb,
    unknowns, steps, newton_iterations, error_<quantity> (NaN: empty), failed error text."""
    quantities: list
    reference: str
    """'exact (<family>)' when the scene has a closed form (for the quantities in
    ``references`` marked 'exact'), else 'richardson'."""
    orders: dict
    """(ladder, quantity) -> Extrapolation (Richardson) or observed order from the exact errors."""
    skipped: list
    warnings: list = field(default_factory=list)
    references: dict = field(default_factory=dict)
    """quantity -> 'exact' (closed form of the scene's family) or 'richardson'."""
    uncertified: list = field(default_factory=list)
    """Richardson quantities of a ladder outside the asymptotic range: measured against its
    finest rung (whose own error is then unknown: an empty cell), so no rung meets a target on
    them."""

    def cheapest(self, target: float):
        """The rung of least wall time whose errors (non-empty) are all <= target, among the
        space and time rungs; None if none, or if a quantity is ``uncertified``."""
        if set(self.uncertified) & set(self.quantities):
            return None
        ok = [r for r in self.rows if r["kind"] in ("space", "time") and not r.get("failed")
              and all(not np.isfinite(r[f"error_{q}"]) or r[f"error_{q}"] <= target for q in self.quantities)
              and any(np.isfinite(r[f"error_{q}"]) for q in self.quantities)]
        return min(ok, key=lambda r: r["wall_s"]) if ok else None


def run_study(scene: Scene, runner: Runner, *, levels: int = 3, quantities=None, effects: bool = True,
              kinds=("space", "time"), progress=None, out=None) -> Study:
    """Run the ladder on ``runner`` and analyse it. ``quantities`` default: the exact family's
    (all exact-referenced) or else every screened quantity."""
    family = exact_family(scene)
    known = known_quantities(scene)
    if quantities is None:
        quantities = list(FAMILY_QUANTITIES[family]) if family else list(QUANTITIES)
    bad = [q for q in quantities if q not in known]
    if bad:
        raise ValueError(f"unknown quantity {bad[0]!r} for this scene; known: {', '.join(known)}")
    rungs, skipped = ladder(scene, levels, effects, kinds)
    outs = runner.run(scene, [Variant(r.name, r.overrides) for r in rungs], summarise=rung_summary,
                      warm=True, progress=progress, out=out)
    return analyse(scene, rungs, outs, quantities, kinds, skipped)


def analyse(scene: Scene, rungs, outs, quantities, kinds=("space", "time"), skipped=()) -> Study:
    """The study from the rungs' outcomes (a fresh run's, or ``ensemble.read_ensemble`` of a
    stored ``runs.h5``: rungs without an outcome are left out). A quantity of the scene's exact
    family is measured against the closed form on every rung; any other against each ladder's
    Richardson extrapolation."""
    family = exact_family(scene)
    by_name = {o.name: o for o in outs}
    pairs = [(r, by_name[r.name]) for r in rungs if r.name in by_name]
    rows = []
    for r, o in pairs:
        row = {"rung": r.name, "kind": r.kind, "factor": r.factor,
               "element_size": o.summary.get("element_size", float("nan")),
               "dt": r.overrides.get("time.dt", scene.time.dt), "effect_off": r.effect_off,
               "wall_s": o.wall_s, "peak_memory_mb": o.peak_memory_mb,
               "unknowns": o.summary.get("unknowns", 0), "steps": o.summary.get("steps", 0),
               "newton_iterations": o.summary.get("newton_iterations", 0),
               "failed": "" if o.ok else o.error, "values": o.summary}
        rows.append(row)
    base = rows[0]
    exact_qs = [q for q in quantities if reference_of(scene, q) == "exact"]
    orders, warnings, uncertified = {}, [], set()
    for r in rows:  # exact: every rung's own (whole) error, whatever ladder it is on
        if not r["failed"] and r["kind"] in ("space", "time"):
            for q in exact_qs:
                r[f"error_{q}"] = _exact_error(r["values"], q)
    for ladder_kind in kinds:
        lad = [base] + [r for r in rows if r["kind"] == ladder_kind and r is not base]
        lad = [r for r in lad if not r["failed"]]
        lad.sort(key=lambda r: -r["factor"])
        x = [r["element_size"] if ladder_kind == "space" else r["dt"] for r in lad]
        for q in quantities:
            if q in exact_qs:
                orders[(ladder_kind, q)] = _fitted_order(x[-3:], [r[f"error_{q}"] for r in lad[-3:]])
                continue
            vals = [r["values"].get(q, float("nan")) for r in lad]
            if q in SLIP_QUANTITIES and not any(r["values"].get("slipping_length", 0.0) > 0 for r in lad):
                # a fault that slips on no rung: the "slip" is the elastic give of its stuck
                # contact springs (1e-10 m), not a screened quantity: no error
                ref = Extrapolation(float("nan"), float("nan"), True, "the fault slips on no rung")
            elif not np.isfinite(vals).any():  # e.g. a traffic light that never turns yellow
                ref = Extrapolation(float("nan"), float("nan"), True, "undefined on every rung")
            elif len(lad) < 3 or not all(np.isfinite(vals[-3:])):
                ref = Extrapolation(float("nan"), float("nan"), False, "fewer than three finite rungs")
            else:
                ref = richardson(x[-3:], vals[-3:])
            orders[(ladder_kind, q)] = ref
            value = ref.value
            if not ref.asymptotic:
                warnings.append(f"{ladder_kind} ladder, {q}: {ref.note}; its errors are against "
                                f"the finest rung, whose own error is unknown")
                value = vals[-1]
            # a reference at round-off of the values' scale is a zero reference: no relative error
            zero = not np.isfinite(value) or abs(value) <= 1e-9 * np.nanmax(np.abs(vals))
            for r, v in zip(lad, vals):
                r.setdefault("partial", {})[(ladder_kind, q)] = (
                    abs(v - value) / abs(value) if not zero and np.isfinite(v) else float("nan"))
            if not ref.asymptotic and not zero:
                # the finest rung against itself would show 0; the others' errors against it are
                # lower bounds: --target certifies no rung on this quantity
                lad[-1]["partial"][(ladder_kind, q)] = float("nan")
                uncertified.add(q)
    _total_errors(rows, base, [q for q in quantities if q not in exact_qs], kinds)
    # effect rungs: the change from the full scene (none where the full scene's value is zero,
    # undefined or, for slip, the give of a fault that does not slip)
    base_slips = base["values"].get("slipping_length", 0.0) > 0
    for r in rows:
        if r["kind"] != "effect":
            continue
        for q in quantities:
            v, b = r["values"].get(q, float("nan")), base["values"].get(q, float("nan"))
            if q in SLIP_QUANTITIES and not base_slips:
                b = float("nan")
            r[f"error_{q}"] = abs(v - b) / abs(b) if np.isfinite(v) and np.isfinite(b) and b != 0 else float("nan")
    for r in rows:
        for q in quantities:
            r.setdefault(f"error_{q}", float("nan"))
    return Study(rows, list(quantities), f"exact ({family})" if family else "richardson", orders, list(skipped),
                 warnings, {q: ("exact" if q in exact_qs else "richardson") for q in quantities},
                 sorted(uncertified))


def _exact_error(values: dict, q: str) -> float:
    """Relative error of one rung's quantity against its exact reference (``*_l2``: the error
    itself); NaN when the reference is zero or missing."""
    v = values.get(q, float("nan"))
    if q.endswith("_l2"):
        return float(v)
    ref = values.get(f"exact_{q}", float("nan"))
    return abs(v - ref) / abs(ref) if np.isfinite(ref) and ref != 0 and np.isfinite(v) else float("nan")


def _total_errors(rows, base, quantities, kinds):
    """A rung's error is its own ladder's (against that ladder's extrapolation) plus the other
    ladder's error at x1, since a space rung keeps the base time step and a time rung the base
    mesh (to first order the two errors add); the x1 rung gets both."""
    for r in rows:
        if r["kind"] not in kinds or "partial" not in r:
            continue
        for q in quantities:
            parts = [r["partial"].get((r["kind"], q), float("nan"))]
            for other in kinds:
                if other != r["kind"]:
                    parts.append(base.get("partial", {}).get((other, q), float("nan")))
            finite = [e for e in parts if np.isfinite(e)]
            r[f"error_{q}"] = sum(finite) if np.isfinite(parts[0]) else float("nan")


def _fitted_order(x, errs):
    """Observed order from errors against an exact solution: slope of log error on log size."""
    x, e = np.asarray(x, float), np.asarray(errs, float)
    good = np.isfinite(e) & (e > 0)
    if good.sum() < 2:
        return Extrapolation(float("nan"), float("nan"), False, "fewer than two nonzero errors")
    p = float(np.polyfit(np.log(x[good]), np.log(e[good]), 1)[0])
    return Extrapolation(0.0, p, 0.5 <= p <= 6.0, "")


CSV_FIXED = ["rung", "kind", "element_size", "dt", "effect_off", "wall_s", "peak_memory_mb", "unknowns",
             "steps", "newton_iterations"]


def write_csv(study: Study, path) -> None:
    import csv

    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_FIXED + [f"error_{q}" for q in study.quantities] + ["failed"])
        for r in study.rows:
            cells = [r["rung"], r["kind"], f"{r['element_size']:.6g}", f"{r['dt']:.6g}", r["effect_off"],
                     f"{r['wall_s']:.4g}", f"{r['peak_memory_mb']:.4g}", r["unknowns"], r["steps"],
                     r["newton_iterations"]]
            cells += ["" if not np.isfinite(r[f"error_{q}"]) else f"{r[f'error_{q}']:.4g}" for q in study.quantities]
            w.writerow(cells + [r["failed"]])


def pareto(rows, quantities):
    """Rungs not dominated in (wall time, largest error): no other rung is as fast and as accurate."""
    pts = []
    for r in rows:
        errs = [r[f"error_{q}"] for q in quantities if np.isfinite(r[f"error_{q}"])]
        if errs and np.isfinite(r["wall_s"]):
            pts.append((r["wall_s"], max(errs), r))
    front = [p for p in pts if not any(o[0] <= p[0] and o[1] <= p[1] and (o[0] < p[0] or o[1] < p[1]) for o in pts)]
    return sorted(front, key=lambda p: p[0])


def plot_study(study: Study, path, title: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    disc = [r for r in study.rows if r["kind"] in ("space", "time") and not r["failed"]]
    for i, q in enumerate(study.quantities):
        for kind, marker in (("space", "o"), ("time", "s")):
            # in ladder order (coarse to fine), so the curve shows the refinement path
            pts = [(r["wall_s"], r[f"error_{q}"]) for r in sorted(disc, key=lambda r: -r["factor"])
                   if (r["kind"] == kind or r["rung"] == "base") and np.isfinite(r[f"error_{q}"])
                   and r[f"error_{q}"] > 1e-10]  # below: round-off, nothing to show on a log axis
            if pts:
                ax.plot(*zip(*pts), marker=marker, ls="-" if kind == "space" else "--", color=f"C{i}",
                        label=f"{q} ({kind}; {study.references.get(q, 'richardson')})", ms=4)
    front = pareto(disc, study.quantities)
    if front:
        ax.plot([p[0] for p in front], [p[1] for p in front], "k:", lw=1)
        ax.scatter([p[0] for p in front], [p[1] for p in front], s=80, facecolors="none", edgecolors="k",
                   label="Pareto front (largest error)")
        for p in front:
            ax.annotate(p[2]["rung"], (p[0], p[1]), fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("wall time per run (s)")
    ax.set_ylabel("relative error (against exact solution or Richardson limit)")
    ax.set_title(title if len(title) <= 70 else title[:67] + "...", fontsize=9)
    ax.legend(fontsize=6, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def with_scene_changes(scene: Scene, **sections) -> Scene:
    """Convenience for tests and scripts: replace fields of sections (``time={"end": 10}``)."""
    return scene.replace(**{k: dataclasses.replace(getattr(scene, k), **v) for k, v in sections.items()})

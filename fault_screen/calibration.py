"""Parameters with bounds, weighted least squares against observations, and the statistics of
the estimate (standard errors, correlation), with model runs on the ensemble runner.

The objective is PEST's: the sum of squared weighted residuals, each residual measured in its
group's unit (the paper: MPa for pressure, mm for shear and normal displacement) and multiplied
by its group's weight. Parameters are estimated in transformed form (log10 or linear) within
their bounds by scipy's trust-region reflective least squares (the bounded form of the
Levenberg-Marquardt step; ``scipy.optimize.least_squares(method="trf")``); the Jacobian's
columns are forward differences, run as one batch of tasks in parallel.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .ensemble import Runner, Variant, scene_with
from .scene import QUANTITY, Scene
from .units import UnitError, to_si

TRANSFORMS = ("log", "linear")


class ParametersError(ValueError):
    """A bad parameters file; the message names the file and the key."""


@dataclass(frozen=True)
class Parameter:
    key: str
    """Dotted scene key (``injection.number_of_fractures``); values SI."""
    mean: float
    lower: float
    upper: float
    transform: str = "linear"
    label: str = ""
    paper_rank: int | None = None

    def to_z(self, v):
        return np.log10(v) if self.transform == "log" else np.asarray(v, dtype=float)

    def from_z(self, z):
        return 10.0 ** np.asarray(z, dtype=float) if self.transform == "log" else np.asarray(z, dtype=float)

    @property
    def name(self):
        return self.label or self.key

    @property
    def sd(self) -> float:
        """One standard deviation: the paper's bounds are the mean -/+ one SD."""
        return 0.5 * (self.upper - self.lower)


@dataclass(frozen=True)
class ParameterSet:
    parameters: tuple
    weights: dict
    """group (pressure, shear, normal) -> weight multiplying the residual."""
    residual_units: dict
    """group -> SI value of one residual unit (1e6 for MPa)."""
    source: str = ""
    groups: tuple = ("pressure", "shear", "normal")
    """The observation groups the file declares (all three if it has no [observations])."""

    def __iter__(self):
        return iter(self.parameters)

    def __len__(self):
        return len(self.parameters)

    def select(self, keys) -> "ParameterSet":
        known = {p.key: p for p in self.parameters}
        bad = [k for k in keys if k not in known]
        if bad:
            raise ParametersError(f"{self.source}: no parameter {bad[0]!r}; known: {', '.join(known)}")
        return dataclasses.replace(self, parameters=tuple(known[k] for k in keys))

    def means(self) -> dict:
        return {p.key: p.mean for p in self.parameters}


def load_parameters(path) -> ParameterSet:
    """Read a parameters TOML (see configs/calibration/rustrel-2015-parameters.toml)."""
    path = Path(path)
    name = path.name
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ParametersError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ParametersError(f"{name}: not valid TOML: {exc}") from None
    weights, res_units = {}, {}
    declared = tuple(data.get("observations") or ()) or ("pressure", "shear", "normal")
    for group, spec in (data.get("observations") or {}).items():
        if group not in ("pressure", "shear", "normal") or not isinstance(spec, dict):
            raise ParametersError(f"{name}: observations.{group}: expected pressure, shear or normal "
                                  f"= {{ weight = w, unit = U }}")
        try:
            w = float(spec.get("weight", 1.0))
            unit = spec.get("unit", "MPa" if group == "pressure" else "mm")
            res_units[group] = to_si(1.0, unit, "pressure" if group == "pressure" else "length")
        except (TypeError, ValueError, UnitError) as exc:
            raise ParametersError(f"{name}: observations.{group}: {exc}") from None
        if not w > 0:
            raise ParametersError(f"{name}: observations.{group}.weight = {w!r}: must be > 0")
        weights[group] = w
    for group in ("pressure", "shear", "normal"):
        weights.setdefault(group, 1.0)
        res_units.setdefault(group, 1e6 if group == "pressure" else 1e-3)
    params = []
    entries = data.get("parameter")
    if not isinstance(entries, list) or not entries:
        raise ParametersError(f"{name}: no [[parameter]] tables")
    seen = set()
    for i, e in enumerate(entries):
        where = f"{name}: parameter[{i}]"
        key = e.get("key")
        if not isinstance(key, str) or not key:
            raise ParametersError(f"{where}: needs key = \"section.name\"")
        where = f"{name}: parameter {key!r}"
        if key in seen:
            raise ParametersError(f"{where}: given twice")
        seen.add(key)
        unknown = set(e) - {"key", "label", "unit", "mean", "lower", "upper", "transform", "paper_rank"}
        if unknown:
            raise ParametersError(f"{where}: unknown field {sorted(unknown)[0]!r}")
        vals = {}
        for f in ("mean", "lower", "upper"):
            v = e.get(f)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ParametersError(f"{where}: {f} = {v!r} must be a finite number")
            vals[f] = float(v)
        if "unit" in e:
            quantity = QUANTITY.get(key.rsplit(".", 1)[-1])
            try:
                if quantity is None:
                    raise UnitError(f"{key} takes no unit")
                vals = {f: to_si(v, e["unit"], quantity) for f, v in vals.items()}
                if quantity == "angle":
                    vals = {f: math.degrees(v) for f, v in vals.items()}
            except UnitError as exc:
                raise ParametersError(f"{where}: unit = {e['unit']!r}: {exc}") from None
        transform = e.get("transform", "linear")
        if transform not in TRANSFORMS:
            raise ParametersError(f"{where}: transform = {transform!r}: must be 'log' or 'linear'")
        if not vals["lower"] <= vals["mean"] <= vals["upper"] or vals["lower"] == vals["upper"]:
            raise ParametersError(f"{where}: needs lower <= mean <= upper and lower < upper, got "
                                  f"{vals['lower']!r}, {vals['mean']!r}, {vals['upper']!r}")
        if transform == "log" and vals["lower"] <= 0:
            raise ParametersError(f"{where}: transform = 'log' needs lower > 0, got {vals['lower']!r}")
        params.append(Parameter(key=key, transform=transform, label=str(e.get("label", "")),
                                paper_rank=e.get("paper_rank"), **vals))
    return ParameterSet(tuple(params), weights, res_units, str(path), declared)


def check_keys(scene: Scene, params: ParameterSet) -> None:
    """Every parameter key names a scene value (raises SceneError naming the key)."""
    scene_with(scene, params.means())


# ---- model output at the observation times -------------------------------------------------------
def sample_series(result, times, series) -> dict:
    """Injection-point series interpolated at ``times`` (picklable with functools.partial)."""
    return {group: np.interp(times, result.time, result.injection[key]) for group, key in series.items()}


def observation_layout(obs, params: ParameterSet):
    """(mask per group, weight per residual row, unit per residual row) for an observation set."""
    rows_w, rows_u = [], []
    masks = {}
    for group in obs.values:
        m = np.isfinite(obs.values[group])
        masks[group] = m
        rows_w.append(np.full(m.sum(), params.weights[group]))
        rows_u.append(np.full(m.sum(), params.residual_units[group]))
    return masks, np.concatenate(rows_w), np.concatenate(rows_u)


def stack(values: dict, masks: dict) -> np.ndarray:
    return np.concatenate([np.asarray(values[g])[masks[g]] for g in masks])


def r_squared(observed_w: np.ndarray, modelled_w: np.ndarray, group: np.ndarray | None = None) -> float:
    """Coefficient of determination of the weighted observations, 1 - SS_res / SS_tot, with
    SS_tot taken about each group's own mean: the offsets between groups (an absolute pore
    pressure of MPa next to displacements of tenths of mm) would otherwise make any model look
    good."""
    group = np.zeros(len(observed_w), dtype=int) if group is None else np.asarray(group)
    ss_tot = sum(np.sum((observed_w[group == g] - observed_w[group == g].mean()) ** 2) for g in np.unique(group))
    return float(1.0 - np.sum((observed_w - modelled_w) ** 2) / ss_tot) if ss_tot > 0 else float("nan")


class ModelRunError(RuntimeError):
    """A model run needed by the estimation failed (names the parameter values)."""


@dataclass
class CalibrationResult:
    params: ParameterSet
    values: dict
    """Calibrated parameter values (SI)."""
    initial: dict
    objective: float
    r2: float
    initial_objective: float
    initial_r2: float
    iterations: list
    """One dict per iteration: iteration, evaluations, objective, r2 and the parameter values."""
    std_error: dict
    """Standard error of each estimate in its own units (delta method through the transform)."""
    interval: dict
    """key -> (low, high): estimate -/+ two standard errors in the transformed space."""
    correlation: np.ndarray
    scene: Scene
    observed: dict
    modelled: dict
    modelled_initial: dict
    times: np.ndarray
    n_observations: int
    message: str = ""
    z_std_error: dict = field(default_factory=dict)

    def identifiable(self, fraction: float = 0.25) -> list:
        """Keys the observations determine: a standard error (transformed space) below
        ``fraction`` of the bound range. A parameter nearly degenerate with others (|correlation|
        near 1) gets a standard error far above its range and drops out."""
        out = []
        for p in self.params:
            width = float(p.to_z(p.upper) - p.to_z(p.lower))
            if self.z_std_error[p.key] < fraction * width:
                out.append(p.key)
        return out


def calibrate(scene: Scene, obs, params: ParameterSet, runner: Runner, *, start: dict | None = None,
              max_evaluations: int = 20, step: float = 0.01, progress=None) -> CalibrationResult:
    """Weighted least squares of the injection-point series against ``obs`` over ``params``,
    starting from ``start`` (default: the parameters' means), within the bounds."""
    from scipy.optimize import least_squares

    check_keys(scene, params)
    if obs.time[-1] > scene.time.end * (1 + 1e-9):
        raise ParametersError(f"{obs.source}: observations run to {obs.time[-1]:g} s, after the scene's "
                              f"end time {scene.time.end:g} s")
    plist = list(params)
    start = dict(params.means() if start is None else start)
    masks, w, unit = observation_layout(obs, params)
    observed = stack(obs.values, masks)
    group = np.concatenate([np.full(m.sum(), k) for k, m in enumerate(masks.values())])
    summarise = functools.partial(sample_series, times=obs.time, series=obs.series)
    zl = np.array([float(p.to_z(p.lower)) for p in plist])
    zu = np.array([float(p.to_z(p.upper)) for p in plist])
    # a linear parameter at a bound of 0 stays there; the log ones are bounded away from 0
    z0 = np.clip(np.array([float(p.to_z(start[p.key])) for p in plist]), zl, zu)
    cache: dict = {}

    def values_of(z):
        return {p.key: float(p.from_z(zj)) for p, zj in zip(plist, z)}

    def run_batch(zs, names):
        todo = [(tuple(z), n) for z, n in zip(zs, names) if tuple(z) not in cache]
        if todo:
            outs = runner.run(scene, [Variant(n, values_of(z)) for z, n in todo], summarise=summarise)
            for (z, n), o in zip(todo, outs):
                if not o.ok:
                    raise ModelRunError(f"model run {n} failed with {o.params}: {o.error}")
                cache[z] = stack(o.summary, masks)
        return [cache[tuple(z)] for z in zs]

    def residuals(z):
        model, = run_batch([z], ["point"])
        return w * (observed - model) / unit

    dz = step * (zu - zl)

    def jacobian(z):
        zs, signs = [], []
        for j in range(len(z)):
            sign = 1.0 if z[j] + dz[j] <= zu[j] else -1.0
            zj = z.copy()
            zj[j] += sign * dz[j]
            zs.append(zj)
            signs.append(sign)
        base = residuals(z)
        cols = run_batch(zs, [f"d/d {p.key}" for p in plist])
        J = np.empty((len(base), len(z)))
        for j, (col, sign) in enumerate(zip(cols, signs)):
            J[:, j] = (w * (observed - col) / unit - base) / (sign * dz[j])
        return J

    history, recorded = [], []

    def record(z, nfev):
        recorded.append(np.array(z))
        r = residuals(z)
        history.append({"iteration": len(history), "evaluations": nfev, "objective": float(r @ r),
                        "r2": r_squared(w * observed / unit, w * (observed - r * unit / w) / unit, group),
                        **values_of(z)})
        if progress is not None:
            progress(history[-1])

    record(z0, 1)
    fit = least_squares(residuals, z0, jac=jacobian, bounds=(zl, zu), method="trf", x_scale="jac", ftol=1e-3, xtol=1e-3,
                        max_nfev=max_evaluations, callback=lambda intermediate_result: record(
                            intermediate_result.x, int(getattr(intermediate_result, "nfev", 0) or 0)))
    z = fit.x
    if not np.array_equal(z, recorded[-1]):
        record(z, int(fit.nfev))
    r = residuals(z)
    J = jacobian(z)
    n, p = len(r), len(z)
    phi = float(r @ r)
    s2 = phi / max(n - p, 1)
    cov = s2 * np.linalg.pinv(J.T @ J)
    se_z = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        corr = cov / np.outer(se_z, se_z)
    values = values_of(z)
    std_error, interval, z_se = {}, {}, {}
    for j, prm in enumerate(plist):
        deriv = values[prm.key] * math.log(10.0) if prm.transform == "log" else 1.0
        std_error[prm.key] = float(abs(deriv) * se_z[j])
        z_se[prm.key] = float(se_z[j])
        interval[prm.key] = (float(prm.from_z(z[j] - 2 * se_z[j])), float(prm.from_z(z[j] + 2 * se_z[j])))
    r0 = residuals(z0)
    model_final = observed - r * unit / w
    model_initial = observed - r0 * unit / w
    unstack = lambda flat: _unstack(flat, masks, obs)
    return CalibrationResult(
        params=params, values=values, initial=values_of(z0), objective=phi,
        r2=r_squared(w * observed / unit, w * model_final / unit, group),
        initial_objective=float(r0 @ r0), initial_r2=r_squared(w * observed / unit, w * model_initial / unit, group),
        iterations=history, std_error=std_error, interval=interval, correlation=corr,
        scene=scene_with(scene, values), observed=obs.values, modelled=unstack(model_final),
        modelled_initial=unstack(model_initial), times=obs.time, n_observations=n,
        message=str(fit.message), z_std_error=z_se)


def _unstack(flat, masks, obs):
    out, k = {}, 0
    for g, m in masks.items():
        arr = np.full(len(obs.time), np.nan)
        arr[m] = flat[k:k + m.sum()]
        k += m.sum()
        out[g] = arr
    return out


# ---- outputs ------------------------------------------------------------------------------------
def write_outputs(res: CalibrationResult, out_dir, stem: str = "calibrated") -> list:
    """calibrated.toml, iterations.csv, parameters.csv, correlation.csv and the figure."""
    import csv

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    toml_path = out / f"{stem}.toml"
    toml_path.write_text(f"# calibrated by fault-screen calibrate: objective {res.objective:.6g}, "
                         f"R2 {res.r2:.4f}\n" + res.scene.to_toml())
    files.append(toml_path)
    keys = [p.key for p in res.params]
    with open(out / "iterations.csv", "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["iteration", "evaluations", "objective", "r2"] + keys)
        for it in res.iterations:
            wr.writerow([it["iteration"], it["evaluations"], f"{it['objective']:.10g}", f"{it['r2']:.6f}"]
                        + [f"{it[k]:.10g}" for k in keys])
    files.append(out / "iterations.csv")
    with open(out / "parameters.csv", "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["parameter", "label", "transform", "lower", "upper", "initial", "calibrated",
                     "std_error", "low_2se", "high_2se", "identifiable"])
        ident = set(res.identifiable())
        for p in res.params:
            lo, hi = res.interval[p.key]
            wr.writerow([p.key, p.label, p.transform, f"{p.lower:.6g}", f"{p.upper:.6g}",
                         f"{res.initial[p.key]:.6g}", f"{res.values[p.key]:.6g}",
                         f"{res.std_error[p.key]:.4g}", f"{lo:.6g}", f"{hi:.6g}", p.key in ident])
    files.append(out / "parameters.csv")
    with open(out / "correlation.csv", "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["parameter"] + keys)
        for k, row in zip(keys, res.correlation):
            wr.writerow([k] + [f"{v:.4f}" for v in row])
    files.append(out / "correlation.csv")
    files.append(plot_fit(res, out / "observed-vs-modelled.png"))
    return files


def plot_fit(res: CalibrationResult, path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = list(res.observed)
    scale = {"pressure": (1e-6, "MPa"), "shear": (1e3, "mm"), "normal": (1e3, "mm")}
    label = {"pressure": "pressure", "shear": "shear displacement", "normal": "normal displacement"}
    fig, axes = plt.subplots(len(groups), 1, figsize=(7, 2.4 * len(groups)), sharex=True, squeeze=False)
    for ax, g in zip(axes[:, 0], groups):
        f, u = scale[g]
        ax.plot(res.times, res.observed[g] * f, ".", ms=3, color="k", label="observed")
        ax.plot(res.times, res.modelled_initial[g] * f, "--", color="0.5", label="initial")
        ax.plot(res.times, res.modelled[g] * f, "-", color="C3", label="calibrated")
        ax.set_ylabel(f"{label[g]} ({u})")
    axes[0, 0].legend(loc="best", fontsize=8)
    axes[0, 0].set_title(f"objective {res.initial_objective:.3g} -> {res.objective:.3g}, "
                         f"R2 {res.initial_r2:.3f} -> {res.r2:.3f}", fontsize=9)
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


# ---- Monte Carlo samples ----------------------------------------------------------------------
def sample_parameters(params: ParameterSet, n: int, distribution: str = "normal", seed: int = 1) -> list:
    """``n`` random parameter sets (dicts of SI values).

    normal: each parameter normal around its mean with SD = (upper - lower) / 2 (the paper's
    bounds are -/+ 1 SD), in log10 for log parameters (log-normal), truncated at -/+ 2 SD and,
    for a linear parameter whose lower bound is >= 0, at 0; uniform: uniform between the
    bounds (in log10 for log parameters). Independent parameters."""
    if distribution not in ("normal", "uniform"):
        raise ValueError(f"distribution = {distribution!r}: must be 'normal' or 'uniform'")
    rng = np.random.default_rng(seed)
    columns = {}
    for p in params:
        zl, zu = float(p.to_z(p.lower)), float(p.to_z(p.upper))
        if distribution == "uniform":
            z = rng.uniform(zl, zu, n)
        else:
            zm, sd = float(p.to_z(p.mean)), 0.5 * (zu - zl)
            z = np.empty(n)
            todo = np.ones(n, dtype=bool)
            while todo.any():  # truncation by rejection: exact truncated normal
                z[todo] = rng.normal(zm, sd, todo.sum())
                todo = np.abs(z - zm) > 2 * sd
                if p.transform == "linear" and p.lower >= 0:
                    todo |= z < 0
        columns[p.key] = p.from_z(z)
    return [{k: float(v[i]) for k, v in columns.items()} for i in range(n)]

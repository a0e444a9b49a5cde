"""Which parameters matter: local composite scaled sensitivities (as PEST), the paper's
one-at-a-time +/- 1 SD changes, and global Morris / Sobol indices (SALib) on screened quantities.

Every model run goes through the ensemble runner, so the runs of one analysis run in parallel.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from .calibration import ParameterSet, sample_series
from .ensemble import Runner, Variant, default_summary, scene_with
from .scene import Scene

#: injection-point series and the observation group each one stands for
SERIES = {"pressure": "pressure", "shear": "slip", "normal": "opening"}
#: screened quantities of the global methods (default_summary keys)
SCREENED = ("peak_overpressure", "injection_slip", "slipping_length", "slip_onset", "time_first_yellow")


def _check(outcomes, what):
    bad = [o for o in outcomes if not o.ok]
    if bad:
        o = bad[0]
        raise RuntimeError(f"{len(bad)} of {len(outcomes)} {what} runs failed; first: {o.name} "
                           f"{o.params}: {o.error}")


def observation_times(scene: Scene) -> np.ndarray:
    """Without measurements: every first-step interval from dt to the end (the paper's 5 s)."""
    n = int(round(scene.time.end / scene.time.dt))
    return np.linspace(scene.time.dt, scene.time.dt * n, n)


def _weighted(params: ParameterSet, series: dict) -> np.ndarray:
    """The series of the parameters file's observation groups, scaled as residuals are (group
    unit, times group weight), as one flat vector."""
    return np.concatenate([params.weights[g] * np.asarray(series[g]) / params.residual_units[g]
                           for g in params.groups])


def spearman(ranks_a, ranks_b) -> float:
    from scipy.stats import spearmanr

    return float(spearmanr(ranks_a, ranks_b).statistic)


def ranks(scores) -> np.ndarray:
    """1 for the largest score."""
    order = np.argsort(-np.asarray(scores, dtype=float), kind="stable")
    out = np.empty(len(order), dtype=int)
    out[order] = np.arange(1, len(order) + 1)
    return out


@dataclass
class LocalSensitivity:
    keys: list
    labels: list
    composite: np.ndarray
    rank: np.ndarray
    paper_rank: list
    spearman_paper: float | None


def local(scene: Scene, params: ParameterSet, runner: Runner, *, times=None, step: float = 0.01,
          progress=None) -> LocalSensitivity:
    """Composite scaled sensitivities at the parameters' means: for parameter b_j,
    css_j = sqrt( (1/n) sum_i (w_i dy_i/db_j b_j)^2 ), y the injection-point pressure, shear and
    normal displacement series in their residual units with their group weights w (PEST's
    definition with weights multiplying residuals). Forward differences of ``step`` relative."""
    base = scene_with(scene, params.means())
    times = observation_times(base) if times is None else np.asarray(times)
    summarise = functools.partial(sample_series, times=times, series=SERIES)
    plist = list(params)
    variants = [Variant("base", {})]
    for p in plist:
        v = p.mean * (1 + step) if p.mean != 0 else step * (p.upper - p.lower)
        variants.append(Variant(p.key, {p.key: v}))
    outs = runner.run(base, variants, summarise=summarise, progress=progress)
    _check(outs, "sensitivity")
    y0 = _weighted(params, outs[0].summary)
    css = []
    for p, o in zip(plist, outs[1:]):
        dy = _weighted(params, o.summary) - y0
        # dy/db * b = dy / step for a relative step
        scaled = dy / step if p.mean != 0 else dy / (step * (p.upper - p.lower)) * p.mean
        css.append(math.sqrt(np.mean(scaled ** 2)))
    css = np.array(css)
    rk = ranks(css)
    paper = [p.paper_rank for p in plist]
    rho = spearman(rk, paper) if all(r is not None for r in paper) and len(plist) >= 2 else None
    return LocalSensitivity([p.key for p in plist], [p.name for p in plist], css, rk, paper, rho)


@dataclass
class OneAtATime:
    keys: list
    labels: list
    objective_lower: np.ndarray
    objective_upper: np.ndarray
    change: dict
    """quantity -> (lower, upper) arrays of relative changes of the screened quantity."""
    rank: np.ndarray
    paper_rank: list
    spearman_paper: float | None
    base: dict


def one_at_a_time(scene: Scene, params: ParameterSet, runner: Runner, *, times=None,
                  progress=None) -> OneAtATime:
    """The paper's Sect. 4.2 analysis without the measurements: each parameter to its lower and
    then upper value (mean -/+ 1 SD), the others at their means. The paper ranks by the change
    of its weighted misfit to the measurements; with no measurements, the measure here is the
    weighted objective between the changed run and the mean run (same weights and units), i.e.
    how far the parameter moves the observed series. Ranked by the larger of the two."""
    base = scene_with(scene, params.means())
    times = observation_times(base) if times is None else np.asarray(times)
    summarise = functools.partial(_series_and_screened, times=times)
    plist = list(params)
    variants = [Variant("mean", {})]
    for p in plist:
        variants += [Variant(f"{p.key} lower", {p.key: p.lower}), Variant(f"{p.key} upper", {p.key: p.upper})]
    outs = runner.run(base, variants, summarise=summarise, progress=progress)
    _check(outs, "one-at-a-time")
    y0 = _weighted(params, outs[0].summary)
    phi = np.array([float(np.sum((_weighted(params, o.summary) - y0) ** 2)) for o in outs[1:]])
    lo, hi = phi[0::2], phi[1::2]
    change = {}
    for q in ("peak_overpressure", "injection_slip"):
        ref = outs[0].summary[q]
        rel = np.array([(o.summary[q] - ref) / ref if ref else np.nan for o in outs[1:]])
        change[q] = (rel[0::2], rel[1::2])
    rk = ranks(np.maximum(lo, hi))
    paper = [p.paper_rank for p in plist]
    rho = spearman(rk, paper) if all(r is not None for r in paper) and len(plist) >= 2 else None
    return OneAtATime([p.key for p in plist], [p.name for p in plist], lo, hi, change, rk, paper, rho,
                      {q: outs[0].summary[q] for q in ("peak_overpressure", "injection_slip")})


def _series_and_screened(result, times):
    out = sample_series(result, times, SERIES)
    out.update(default_summary(result))
    return out


def _problem(params: ParameterSet):
    plist = list(params)
    return {"num_vars": len(plist), "names": [p.key for p in plist],
            "bounds": [[float(p.to_z(p.lower)), float(p.to_z(p.upper))] for p in plist]}


def _variants(params: ParameterSet, samples_z: np.ndarray):
    plist = list(params)
    return [Variant(f"sample {i}", {p.key: float(p.from_z(z)) for p, z in zip(plist, row)})
            for i, row in enumerate(samples_z)]


def _screened(outs, q, scene):
    """One screened quantity over the runs; a fault that never slipped (never turned yellow) has
    its onset (first yellow) at the end of the run."""
    Y = np.array([o.summary[q] for o in outs], dtype=float)
    return np.where(np.isfinite(Y), Y, scene.time.end)


def morris(scene: Scene, params: ParameterSet, runner: Runner, *, trajectories: int = 4, levels: int = 4,
           seed: int = 1, out=None, progress=None) -> dict:
    """Morris elementary effects over the bounds (log parameters sampled in log10):
    quantity -> {"mu_star", "mu_star_conf", "sigma"} arrays in parameter order. Runs
    (p + 1) * trajectories scenes."""
    from SALib.analyze import morris as morris_analyze
    from SALib.sample import morris as morris_sample

    problem = _problem(params)
    X = morris_sample.sample(problem, trajectories, num_levels=levels, seed=seed)
    outs = runner.run(scene, _variants(params, X), out=out, progress=progress)
    _check(outs, "Morris")
    result = {}
    for q in SCREENED:
        Y = _screened(outs, q, scene)
        if np.ptp(Y) == 0:  # the quantity does not move (e.g. no slip anywhere): no effects
            result[q] = {k: np.zeros(problem["num_vars"]) for k in ("mu_star", "mu_star_conf", "sigma")}
            continue
        a = morris_analyze.analyze(problem, X, Y, num_levels=levels, seed=seed)
        result[q] = {k: np.asarray(a[k]) for k in ("mu_star", "mu_star_conf", "sigma")}
    return result


def sobol(scene: Scene, params: ParameterSet, runner: Runner, *, base_samples: int = 16, seed: int = 1,
          out=None, progress=None) -> dict:
    """First-order and total Sobol indices (Saltelli sampling, no second order):
    quantity -> {"S1", "S1_conf", "ST", "ST_conf"}. Runs base_samples * (p + 2) scenes;
    base_samples must be a power of 2."""
    from SALib.analyze import sobol as sobol_analyze
    from SALib.sample import sobol as sobol_sample

    if base_samples < 2 or base_samples & (base_samples - 1):
        raise ValueError(f"samples = {base_samples}: Sobol sampling needs a power of 2")
    problem = _problem(params)
    X = sobol_sample.sample(problem, base_samples, calc_second_order=False, seed=seed)
    outs = runner.run(scene, _variants(params, X), out=out, progress=progress)
    _check(outs, "Sobol")
    result = {}
    for q in SCREENED:
        Y = _screened(outs, q, scene)
        if np.ptp(Y) == 0:  # the quantity does not move: no variance to apportion
            result[q] = {k: np.full(problem["num_vars"], np.nan) for k in ("S1", "S1_conf", "ST", "ST_conf")}
            continue
        a = sobol_analyze.analyze(problem, Y, calc_second_order=False, seed=seed)
        result[q] = {k: np.asarray(a[k]) for k in ("S1", "S1_conf", "ST", "ST_conf")}
    return result

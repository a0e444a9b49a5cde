"""``fault-screen ensemble SCENE --vary PARAMS.toml --samples N``: Monte Carlo screening."""
from __future__ import annotations

import csv
import time
from pathlib import Path

import click
import numpy as np

from ._options import FILE, RunFailed, version_option
from ._common import apply_sets, load_scene
from ._runner import TaskBar, open_runner, runner_options
from .calibrate import load_parameters_option

#: quantity -> (scale, unit) for the table and the figure
SHOWN = {"peak_overpressure": (1e-6, "MPa"), "injection_slip": (1e3, "mm"),
         "peak_fault_slip": (1e3, "mm"), "slipping_length": (1.0, "m"), "slip_onset": (1.0, "s"),
         "time_first_yellow": (1.0, "s"), "time_first_red": (1.0, "s")}


@click.command("ensemble")
@click.argument("scene_path", type=FILE, metavar="SCENE")
@click.option("--vary", "params_path", type=FILE, required=True, metavar="PARAMS.toml",
              help="Parameters to vary, with their means and bounds (mean -/+ 1 SD).")
@click.option("--samples", type=click.IntRange(min=1), required=True, help="Number of runs.")
@click.option("--distribution", type=click.Choice(["normal", "uniform"]), default="normal", show_default=True,
              help="normal: around the mean, SD from the bounds, truncated at 2 SD (log-normal "
                   "for log parameters); uniform: between the bounds.")
@click.option("--seed", type=int, default=1, show_default=True)
@click.option("--free", default=None, metavar="KEY,KEY", help="Vary only these parameters [default: all].")
@runner_options
@version_option
def ensemble(scene_path, params_path, samples, distribution, seed, free, out_dir, workers, scheduler, quiet, sets):
    """Run SCENE with N random parameter sets: the probability that the fault slips at the
    injection point and that the traffic light (the scene's [monitor] rules) reaches yellow and
    red, and the distributions of peak overpressure, slip and those times.

    Writes to --out-dir: runs.h5 (every run's parameters and summary, failures included),
    ensemble.csv (one row per run), distribution.csv (mean, SD, percentiles per quantity) and
    ensemble.png (histograms).
    """
    from ..calibration import sample_parameters
    from ..ensemble import Variant, reach_probabilities

    scene_path = Path(scene_path)
    scene = apply_sets(load_scene(scene_path), sets)
    params = load_parameters_option(params_path, scene, free)
    out = Path(out_dir) if out_dir is not None else Path.cwd() / f"ensemble-{scene_path.stem}"
    out.mkdir(parents=True, exist_ok=True)
    sets = sample_parameters(params, samples, distribution, seed)
    variants = [Variant(f"sample {i}", s) for i, s in enumerate(sets)]
    runner = open_runner(workers, scheduler)
    t0 = time.perf_counter()
    try:
        outs = runner.run(scene, variants, out=out / "runs.h5", progress=TaskBar("ensemble", quiet),
                          meta={"distribution": distribution, "seed": seed})
    finally:
        runner.close()
    elapsed = time.perf_counter() - t0
    ok = [o for o in outs if o.ok]
    keys = [p.key for p in params]
    quantities = list(SHOWN)
    with open(out / "ensemble.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["run", "ok", "error", *keys, *quantities])
        for o in outs:
            w.writerow([o.index, o.ok, o.error, *(f"{o.params[k]:.6g}" for k in keys),
                        *(f"{o.summary.get(q, float('nan')):.6g}" for q in quantities)])
    if not ok:
        raise RunFailed(f"all {len(outs)} runs failed; first: {outs[0].error} (see {out / 'ensemble.csv'})")
    rows = []
    for q in quantities:
        v = np.array([o.summary[q] for o in ok], dtype=float)
        f, unit = SHOWN[q]
        v = v[np.isfinite(v)] * f
        if v.size == 0:
            rows.append([q, unit, 0, *[""] * 5])
            continue
        rows.append([q, unit, v.size, *(f"{x:.4g}" for x in (v.mean(), v.std(ddof=1) if v.size > 1 else 0.0,
                                                             *np.percentile(v, [5, 50, 95])))])
    with open(out / "distribution.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["quantity", "unit", "runs", "mean", "sd", "p5", "p50", "p95"])
        w.writerows(rows)
    reached = reach_probabilities(ok)
    _figure(ok, out / "ensemble.png")
    click.echo(f"{len(outs)} runs in {elapsed:.1f} s ({60 * len(outs) / elapsed:.1f} runs/min), "
               f"{len(outs) - len(ok)} failed")
    for event, what in (("slip", "the fault slips at the injection point"),
                        ("yellow", "the traffic light reaches yellow"), ("red", "the traffic light reaches red")):
        p, half = reached[event]
        click.echo(f"probability that {what}: {p:.3f} (+/- {half:.3f}, 95 %)")
    click.echo(f"{'quantity':<18} {'unit':<4} {'runs':>5} {'mean':>10} {'sd':>10} {'p5':>10} {'p50':>10} {'p95':>10}")
    for r in rows:
        click.echo(f"{r[0]:<18} {r[1]:<4} {r[2]:>5} " + " ".join(f"{x:>10}" for x in r[3:]))
    for name in ("runs.h5", "ensemble.csv", "distribution.csv", "ensemble.png"):
        click.echo(f"wrote {out / name}")


def _figure(ok, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(8, 3))
    for ax, q in zip(axes, ("peak_overpressure", "injection_slip")):
        f, unit = SHOWN[q]
        v = np.array([o.summary[q] for o in ok], dtype=float) * f
        ax.hist(v[np.isfinite(v)], bins=max(5, min(30, len(v) // 3)), color="C0")
        ax.set_xlabel(f"{q.replace('_', ' ')} ({unit})")
        ax.set_ylabel("runs")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

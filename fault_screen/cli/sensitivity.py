"""``fault-screen sensitivity SCENE --parameters PARAMS.toml [--method local|oat|morris|sobol]``."""
from __future__ import annotations

import csv
from pathlib import Path

import click

from ._options import FILE, BadInput, version_option
from ._common import apply_sets, load_scene
from ._runner import TaskBar, open_runner, runner_options
from .calibrate import load_parameters_option


@click.command("sensitivity")
@click.argument("scene_path", type=FILE, metavar="SCENE")
@click.option("--parameters", "params_path", type=FILE, required=True, metavar="PARAMS.toml",
              help="Parameters with bounds (mean -/+ 1 SD) and observation-group weights.")
@click.option("--method", type=click.Choice(["local", "oat", "morris", "sobol"]), default="local",
              show_default=True,
              help="local: composite scaled sensitivities (PEST); oat: the paper's one-at-a-time "
                   "-/+ 1 SD; morris / sobol: global indices (SALib) of the screened quantities.")
@click.option("--free", default=None, metavar="KEY,KEY", help="Only these parameters [default: all].")
@click.option("--samples", type=click.IntRange(min=1), default=None,
              help="Morris trajectories [4] or Sobol base samples, a power of 2 [16].")
@click.option("--seed", type=int, default=1, show_default=True, help="Seed of the global samples.")
@runner_options
@version_option
def sensitivity(scene_path, params_path, method, free, samples, seed, out_dir, workers, scheduler, quiet, sets):
    """Rank the parameters of SCENE by their influence.

    local and oat run at the parameters' means (the paper's base case) and compare the ranking
    with the paper's Fig. 7 (Spearman rank correlation) when the parameters file gives
    paper_rank. Writes sensitivity.csv (local), sensitivity-oat.csv, morris.csv or sobol.csv
    (and the runs, runs.h5) to --out-dir.
    """
    from .. import sensitivity as sa

    scene_path = Path(scene_path)
    scene = apply_sets(load_scene(scene_path), sets)
    params = load_parameters_option(params_path, scene, free)
    if method == "sobol" and samples is not None and samples & (samples - 1):
        raise BadInput(f"--samples {samples}: Sobol sampling needs a power of 2 (8, 16, 32, ...)")
    if method in ("local", "oat") and samples is not None:
        raise BadInput(f"--samples: only for --method morris or sobol, not {method}")
    out = Path(out_dir) if out_dir is not None else Path.cwd() / f"sensitivity-{scene_path.stem}"
    out.mkdir(parents=True, exist_ok=True)
    bar = TaskBar(method, quiet)
    runner = open_runner(workers, scheduler)
    try:
        if method == "local":
            res = sa.local(scene, params, runner, progress=bar)
            rows = [[k, lab, f"{c:.6g}", int(r), pr if pr is not None else ""]
                    for k, lab, c, r, pr in zip(res.keys, res.labels, res.composite, res.rank, res.paper_rank)]
            path = _write(out / "sensitivity.csv",
                          ["parameter", "label", "composite_sensitivity", "rank", "paper_rank"], rows)
            _table(rows, ["parameter", "label", "css", "rank", "paper"])
            _spearman(res.spearman_paper)
        elif method == "oat":
            res = sa.one_at_a_time(scene, params, runner, progress=bar)
            rows = []
            for j, k in enumerate(res.keys):
                rows.append([k, res.labels[j], f"{res.objective_lower[j]:.6g}", f"{res.objective_upper[j]:.6g}",
                             *(f"{res.change[q][s][j]:.4g}" for q in ("peak_overpressure", "injection_slip")
                               for s in (0, 1)),
                             int(res.rank[j]), res.paper_rank[j] if res.paper_rank[j] is not None else ""])
            path = _write(out / "sensitivity-oat.csv",
                          ["parameter", "label", "objective_lower", "objective_upper",
                           "change_peak_overpressure_lower", "change_peak_overpressure_upper",
                           "change_injection_slip_lower", "change_injection_slip_upper", "rank", "paper_rank"],
                          rows)
            _table([[r[0], r[1], r[2], r[3], r[8], r[9]] for r in rows],
                   ["parameter", "label", "phi(-1 SD)", "phi(+1 SD)", "rank", "paper"])
            _spearman(res.spearman_paper)
        else:
            fn = sa.morris if method == "morris" else sa.sobol
            kw = ({"trajectories": samples or 4} if method == "morris" else {"base_samples": samples or 16})
            res = fn(scene, params, runner, seed=seed, out=out / "runs.h5", progress=bar, **kw)
            cols = ["mu_star", "mu_star_conf", "sigma"] if method == "morris" else ["S1", "S1_conf", "ST", "ST_conf"]
            rows = [[p.key, q, *(f"{res[q][c][j]:.4g}" for c in cols)]
                    for q in res for j, p in enumerate(params)]
            path = _write(out / f"{method}.csv", ["parameter", "quantity", *cols], rows)
            _table(rows, ["parameter", "quantity", *cols])
    except RuntimeError as exc:
        from ._options import RunFailed

        raise RunFailed(str(exc)) from None
    finally:
        runner.close()
    click.echo(f"wrote {path}")


def _write(path, header, rows):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


def _table(rows, header):
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    for r in [header, *rows]:
        click.echo("  ".join(str(x).ljust(wd) for x, wd in zip(r, widths)))


def _spearman(rho):
    if rho is not None:
        click.echo(f"Spearman rank correlation with the paper's Fig. 7 ranking: {rho:+.3f}")

"""``fault-screen calibrate SCENE --observations OBS.csv --parameters PARAMS.toml``."""
from __future__ import annotations

from pathlib import Path

import click

from ._options import FILE, BadInput, reading, version_option
from ._common import apply_sets, load_scene
from ._runner import open_runner, runner_options


def load_parameters_option(path, scene, keys=None):
    from ..calibration import check_keys, load_parameters

    with reading(path):
        params = load_parameters(path)
        if keys:
            params = params.select([k.strip() for k in keys.split(",") if k.strip()])
        check_keys(scene, params)
    return params


@click.command("calibrate")
@click.argument("scene_path", type=FILE, metavar="SCENE")
@click.option("--observations", "obs_path", type=FILE, required=True, metavar="OBS.csv",
              help="Observed series at the injection point: time + pressure/overpressure, "
                   "shear/slip, normal/opening columns with units in the headers.")
@click.option("--parameters", "params_path", type=FILE, required=True, metavar="PARAMS.toml",
              help="Parameters with bounds, transforms and observation-group weights "
                   "(e.g. configs/calibration/rustrel-2015-parameters.toml).")
@click.option("--free", default=None, metavar="KEY,KEY",
              help="Estimate only these parameters (dotted scene keys) [default: all].")
@click.option("--max-evaluations", type=click.IntRange(min=2), default=20, show_default=True,
              help="Most objective evaluations (each one run, plus one Jacobian per iteration).")
@runner_options
@version_option
def calibrate(scene_path, obs_path, params_path, free, max_evaluations, out_dir, workers, scheduler, quiet, sets):
    """Estimate scene parameters from observations by weighted least squares within bounds.

    Starts from the parameters' means; each iteration's Jacobian columns (forward differences
    in the log/linear transformed parameters) run in parallel. Writes to --out-dir: the calibrated
    scene (calibrated.toml), iterations.csv (objective and R2 per iteration), parameters.csv
    (estimates, standard errors, 2-SE intervals, identifiable), correlation.csv and
    observed-vs-modelled.png.
    """
    from ..calibration import calibrate as run_calibration
    from ..calibration import write_outputs
    from ..io.observations import read_observations

    scene_path = Path(scene_path)
    scene = apply_sets(load_scene(scene_path), sets)
    params = load_parameters_option(params_path, scene, free)
    with reading(obs_path):
        obs = read_observations(obs_path)
    if obs.time[-1] > scene.time.end * (1 + 1e-9):
        raise BadInput(f"{obs_path}: observations run to {obs.time[-1]:g} s, after the scene's end "
                       f"time {scene.time.end:g} s")
    out_dir = Path(out_dir) if out_dir is not None else Path.cwd() / f"calibrate-{scene_path.stem}"

    def show(it):
        if not quiet:
            click.echo(f"iteration {it['iteration']:>3}  objective {it['objective']:.6g}  R2 {it['r2']:.4f}")

    runner = open_runner(workers, scheduler)
    try:
        res = run_calibration(scene, obs, params, runner, max_evaluations=max_evaluations, progress=show)
    finally:
        runner.close()
    files = write_outputs(res, out_dir)
    ident = set(res.identifiable())
    click.echo(f"objective {res.initial_objective:.6g} -> {res.objective:.6g}, "
               f"R2 {res.initial_r2:.4f} -> {res.r2:.4f} ({res.message})")
    click.echo(f"{'parameter':<34} {'initial':>11} {'calibrated':>11} {'std error':>10}  identifiable")
    for p in params:
        click.echo(f"{p.key:<34} {res.initial[p.key]:>11.4g} {res.values[p.key]:>11.4g} "
                   f"{res.std_error[p.key]:>10.3g}  {'yes' if p.key in ident else 'no'}")
    for f in files:
        click.echo(f"wrote {f}")

"""``fault-screen run [SCENE]``: run a scene with its own injection schedule."""
from __future__ import annotations

from pathlib import Path

import click

from ._common import apply_sets, default_scene_path, load_scene, read_scene_log
from ._options import FILE, run_options, set_option, version_option
from ._verdict import conclude, fail_on_option


@click.command("run")
@click.argument("scene_path", type=FILE, required=False, metavar="[SCENE]")
@run_options
@set_option
@fail_on_option
@version_option
def run(scene_path, out, plot_dir, events, t0, quiet, sets, fail_on):
    """Run SCENE (TOML) with its own injection schedule and save the result (HDF5).

    Without SCENE, runs the bundled Rustrel 2015 calibrated scene in the paper's units
    (configs/rustrel-2015-calibrated-paper-units.toml: the paper's k_f read as a mobility, the
    reading that reproduces its pressures and slip; stand-in step-rate schedule). The SI reading
    is bundled as configs/rustrel-2015-calibrated.toml.
    """
    from ._running import run_scene   # here: numpy and the model only once a run is asked for

    path = Path(scene_path) if scene_path is not None else default_scene_path()
    scene = apply_sets(load_scene(path), sets)
    volume, extra, meta, start = None, None, {"command": "run"}, t0
    if scene.injection.log is not None and scene.injection.control == "rate":
        # read here, so that a bad log is bad input (exit 2) and the samples go to /log
        from ..io.replay import plan_replay

        log = read_scene_log(scene)
        click.echo(f"log: {log.summary}")
        for w in log.warnings:
            click.echo(f"Warning: {w}", err=True)
        plan = plan_replay(scene, log, scene.time.end, end_name="time.end")
        for note in plan.notes:
            click.echo(f"Warning: {note}", err=True)
        volume, extra = log.volume, {"log": plan.log_arrays}
        meta.update(plan.meta)
        start = t0 if t0 is not None else log.start
    result, _, screening = run_scene(scene, scene_label=str(path), out=out, plot_dir=plot_dir,
                                     events_path=events, start=start, quiet=quiet, stem=path.stem,
                                     meta=meta, injected_volume=volume, extra=extra)
    conclude(result, fail_on, screening)

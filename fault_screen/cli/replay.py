"""``fault-screen replay SCENE --log LOG``: run a scene driven by an operator's injection log."""
from __future__ import annotations

from pathlib import Path

import click

from ._options import (FILE, BadInput, check_log, log_options, reading, run_options, set_option,
                       version_option)
from ._common import apply_sets, load_scene
from ._running import run_scene
from ._verdict import conclude, fail_on_option


@click.command("replay")
@click.argument("scene_path", type=FILE, metavar="SCENE")
@log_options
@run_options
@set_option
@fail_on_option
@version_option
def replay(scene_path, log_path, flow_unit, pressure_unit, max_gap, policy, end, log_date, log_tz,
           time_column, flow_column, pressure_column, time_unit, volume_column,
           cumulative_volume_column, volume_unit, accept_implausible, out, plot_dir, events, t0,
           quiet, sets, fail_on):
    """Run SCENE (TOML) with the flow rate of the injection log LOG instead of its schedule.

    Model time 0 is the log's first stamp; the run ends at the log's last stamp unless --end
    is given (after the last sample the rate is 0).  Between samples the rate is linear; each
    time step receives exactly the log's volume over the step.  LOG is a text table with one
    header line, e.g.

    \b
        time,flow_rate[L/min],pressure[bar]
        2015-03-12T10:00:00+01:00,0.0,12.1
        2015-03-12T10:00:05+01:00,10.1,14.0

    Also read: ';' or tab separators with decimal commas, Latin-1 files, a second header row
    of units, separate date and time columns, elapsed seconds or hh:mm:ss, local times (--tz),
    times of day (--date, --tz).  The line 'log: ...' says what was detected.
    """
    from ..io.injection_log import CLI_OPTION_NAMES, read_injection_log
    from ..io.replay import plan_replay

    scene_path = Path(scene_path)
    scene = apply_sets(load_scene(scene_path), sets)
    if scene.injection.control != "rate":
        raise BadInput(f"{scene_path}: injection.control = {scene.injection.control!r}: a log "
                       f"replay drives the flow rate; use a scene with control = 'rate'")
    read = read_injection_log
    if isinstance(log_path, str):    # a HYDWS section's URL: read by the hydws source plugin
        from ..monitor.plugins import load

        read = load("source", "hydws").read_log
    with reading(log_path):
        log = read(log_path, flow_unit=flow_unit, pressure_unit=pressure_unit,
                   max_gap=max_gap, policy=policy, date=log_date, tz=log_tz,
                   time_column=time_column, flow_column=flow_column,
                   pressure_column=pressure_column, time_unit=time_unit,
                   volume_column=volume_column,
                   cumulative_volume_column=cumulative_volume_column,
                   volume_unit=volume_unit, option_names=CLI_OPTION_NAMES,
                   flowback=scene.injection.allow_flowback)
    click.echo(f"log: {log.summary}")
    check_log(log, scene, accept_implausible)
    for w in log.warnings:
        click.echo(f"Warning: {w}", err=True)
    with reading(scene_path):
        plan = plan_replay(scene, log, end, end_name="--end")
    for note in plan.notes:
        click.echo(f"Warning: {note}", err=True)

    meta = {"command": "replay", "log_policy": policy, "log_max_gap": max_gap, **plan.meta,
            "log_file": str(log_path)}
    result, _, screening = run_scene(plan.scene, scene_label=str(scene_path), out=out, plot_dir=plot_dir,
                          events_path=events, start=t0 if t0 is not None else log.start, quiet=quiet,
                          injected_volume=plan.injected_volume, meta=meta, extra={"log": plan.log_arrays},
                          stem=scene_path.stem)
    conclude(result, fail_on, screening)

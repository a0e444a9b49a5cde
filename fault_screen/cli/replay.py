"""``fault-screen replay SCENE --log LOG``: run a scene driven by an operator's injection log."""
from __future__ import annotations

from pathlib import Path

import click

from ._options import FILE, log_options, run_options, set_option, version_option
from ._common import apply_sets, load_scene, read_driving_log
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
    scene_path = Path(scene_path)
    scene = apply_sets(load_scene(scene_path), sets)
    log, plan = read_driving_log(scene, scene_path, log_path, end,
                                 accept_implausible=accept_implausible, flow_unit=flow_unit,
                                 pressure_unit=pressure_unit, max_gap=max_gap, policy=policy,
                                 date=log_date, tz=log_tz, time_column=time_column,
                                 flow_column=flow_column, pressure_column=pressure_column,
                                 time_unit=time_unit, volume_column=volume_column,
                                 cumulative_volume_column=cumulative_volume_column,
                                 volume_unit=volume_unit)

    meta = {"command": "replay", "log_policy": policy, "log_max_gap": max_gap, **plan.meta,
            "log_file": str(log_path)}
    result, _, screening = run_scene(plan.scene, scene_label=str(scene_path), out=out, plot_dir=plot_dir,
                          events_path=events, start=t0 if t0 is not None else log.start, quiet=quiet,
                          injected_volume=plan.injected_volume, meta=meta, extra={"log": plan.log_arrays},
                          stem=scene_path.stem)
    conclude(result, fail_on, screening)

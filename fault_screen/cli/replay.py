"""``fault-screen replay SCENE --log LOG``: run a scene driven by an operator's injection log."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import click
import numpy as np

from ._options import FILE, BadInput, log_options, reading, run_options, version_option
from .run import load_scene, run_scene
from .screen import conclude, fail_on_option


@click.command("replay")
@click.argument("scene_path", type=FILE, metavar="SCENE")
@log_options
@run_options
@fail_on_option
@version_option
def replay(scene_path, log_path, flow_unit, pressure_unit, max_gap, policy, end, out, plot_dir,
           events, t0, quiet, fail_on):
    """Run SCENE (TOML) with the flow rate of the injection log LOG instead of its schedule.

    Model time 0 is the log's first stamp; the run ends at the log's last stamp unless --end
    is given.  Between samples the rate is linear; each time step receives exactly the log's
    volume over the step.  LOG is CSV with one header line, e.g.

    \b
        time,flow_rate[L/min]
        2015-03-12T10:00:00+01:00,0.0
        2015-03-12T10:00:05+01:00,10.1

    (or an elapsed[s] column instead of timestamps; '#' lines are comments).
    """
    from ..io.injection_log import read_injection_log

    scene_path = Path(scene_path)
    scene = load_scene(scene_path)
    if scene.injection.control != "rate":
        raise BadInput(f"{scene_path}: injection.control = {scene.injection.control!r}: a log "
                       f"replay drives the flow rate; use a scene with control = 'rate'")
    with reading(log_path):
        log = read_injection_log(log_path, flow_unit=flow_unit, pressure_unit=pressure_unit,
                                 max_gap=max_gap, policy=policy)
    for w in log.warnings:
        click.echo(f"Warning: {w}", err=True)

    t_end = float(end) if end is not None else log.duration
    ts = scene.time
    with reading(scene_path):
        scene = scene.replace(time=dataclasses.replace(ts, end=t_end, dt=min(ts.dt, t_end)))

    # the samples the run uses: those inside [0, end] and the first one after it
    n = int(np.searchsorted(log.time, t_end, side="left")) + 1
    n = min(max(n, 2), log.time.size)
    used = {"time": np.array(log.time[:n]), "flow_rate": np.array(log.flow_rate[:n])}
    if log.pressure is not None:
        used["pressure"] = np.array(log.pressure[:n])
    start = t0 if t0 is not None else log.start
    meta = {
        "command": "replay",
        "log_file": str(log_path),
        "log_start": log.start.isoformat() if log.start is not None else None,
        "log_policy": policy,
        "log_max_gap": max_gap,
        "log_warnings": list(log.warnings),
        "log_volume": log.volume(0.0, t_end),
    }
    result, _ = run_scene(scene, scene_label=str(scene_path), out=out, plot_dir=plot_dir, events_path=events,
                          start=start, quiet=quiet, injected_volume=lambda a, b: log.volume(a, b),
                          meta=meta, extra={"log": used}, stem=scene_path.stem)
    conclude(result, fail_on)

"""``fault-screen screen RESULT.h5``: re-evaluate the screening rules on a saved result."""
from __future__ import annotations

from pathlib import Path

import click

from ._common import load_events, load_scene
from ._options import FILE, BadInput, events_option, parse_iso, reading, t0_option, version_option
from ._verdict import conclude, fail_on_option


@click.command("screen")
@click.argument("result_path", type=FILE, metavar="RESULT.h5")
@click.option("--scene", "scene_path", type=FILE, default=None, metavar="SCENE",
              help="Take the [monitor] thresholds and rules of this scene (its physics is not used: "
                   "the saved result is not re-run) [default: the result's own scene].")
@events_option
@t0_option
@fail_on_option
@click.option("--out", "-o", type=FILE, default=None, metavar="NEW.h5",
              help="Write the result with the new /screening/ group (and [monitor]) to NEW.h5.")
@version_option
def screen(result_path, scene_path, events, t0, fail_on, out):
    """Re-evaluate the screening rules on a saved RESULT.h5 without re-running the model: the
    metrics, the level at each output time, the level changes and the verdict.

    Events come from --events (placed relative to --t0, else the start stored in the result),
    else from those stored in the result.
    """
    from ..result import Result
    from ..screening import LEVEL_NAMES, screen_result

    result_path = Path(result_path)
    with reading(result_path):
        result = Result.load(result_path)
    if scene_path is not None:
        monitor = load_scene(Path(scene_path)).monitor
        with reading(scene_path):
            result.scene = result.scene.replace(monitor=monitor)
    catalog = None
    if events is not None:
        start = t0
        if start is None and result.meta.get("start"):
            start = parse_iso(result.meta["start"], f"{result_path}: meta start")
        catalog = load_events(events, start)
        result.extra["events"] = {"time": catalog.time, "magnitude": catalog.magnitude}
    screening = screen_result(result, events=catalog)
    source = scene_path if scene_path is not None else f"{result_path} (its own scene)"
    click.echo(f"screening {result_path}: {len(result.time)} output times, rules of {source}")
    for tr in screening.transitions:
        click.echo(f"  {tr.describe()}")
    if not screening.transitions:
        click.echo(f"  level {LEVEL_NAMES[0]} throughout")
    if out is not None:
        if Path(out).resolve() == result_path.resolve():
            raise BadInput(f"--out {out}: is RESULT.h5 itself; write to a new file")
        result.save(out)
        click.echo(f"  written {out}")
    conclude(result, fail_on, screening)

"""``fault-screen plot RESULT.h5``: figures from a saved result."""
from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from ._options import DIR, FILE, events_option, parse_iso, reading, t0_option, version_option
from .run import load_events


@click.command("plot")
@click.argument("result_path", type=FILE, metavar="RESULT.h5")
@click.option("--out", "-o", "out_dir", type=DIR, default=Path("."), show_default=True,
              metavar="DIR", help="Directory for the PNG figures (created if needed).")
@events_option
@t0_option
@version_option
def plot(result_path, out_dir, events, t0):
    """Draw the figures of a saved RESULT.h5: the injection point against time
    (<stem>-injection-point.png), space-time maps along the fault (<stem>-space-time.png) and,
    for a screened result, the screening metrics and levels (<stem>-screening.png).

    Events from --events are placed relative to --t0, else to the start stored in the result
    (the log's first stamp of a replay), else to the first event.  Without --events, events
    stored in the result by run/replay --events are drawn.
    """
    from ..io.events import EventCatalog
    from ..plotting import plot_result
    from ..result import Result

    result_path = Path(result_path)
    with reading(result_path):
        result = Result.load(result_path)
    start = t0
    if start is None and result.meta.get("start"):
        start = parse_iso(result.meta["start"], f"{result_path}: meta start")
    if events is not None:
        catalog = load_events(events, start)
    elif "events" in result.extra:
        ev = result.extra["events"]
        catalog = EventCatalog(np.asarray(ev["time"], dtype=float),
                               np.asarray(ev["magnitude"], dtype=float))
    else:
        catalog = None
    if out_dir.exists() and not out_dir.is_dir():
        from ._options import BadInput
        raise BadInput(f"--out {out_dir}: exists and is not a directory")
    for f in plot_result(result, out_dir, events=catalog, prefix=f"{result_path.stem}-"):
        click.echo(str(f))

"""``fault-screen plot RESULT.h5``: figures from a saved result."""
from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from ._options import (FILE, BadInput, events_option, out_dir_option, parse_iso, reading, t0_option,
                       version_option)
from ._common import events_report, load_events, load_result, stored_events

@click.command("plot")
@click.argument("result_path", type=FILE, metavar="RESULT.h5")
@out_dir_option(Path("."), "Folder for the PNG figures (created if needed) [default: the "
                           "current folder].")
@events_option
@t0_option
@version_option
def plot(result_path, out_dir, events, t0):
    """Draw the figures of a saved RESULT.h5: the injection point against time
    (<stem>-injection-point.png), space-time maps along the fault (<stem>-space-time.png) and,
    for a screened result, the screening metrics and levels (<stem>-screening.png).

    A result of any length is read in bounded pieces: a long series is drawn as its envelope
    (the smallest and largest value of each of about 5,000 spans, so no peak is lost), and at
    most 400 of the fault profiles, spread over the run.

    Events from --events are placed relative to --t0, else to the start stored in the result
    (the log's first stamp of a replay), else to the first event.  Without --events, events
    stored in the result by run/replay --events are drawn.  With a start time the figures show
    clock time as well.
    """
    from ..plotting import plot_result

    result_path = Path(result_path)
    result = load_result(result_path, view=True)   # bounded: long series as envelopes
    start = t0
    if start is None and result.meta.get("start"):
        start = parse_iso(result.meta["start"], f"{result_path}: meta start")
    if t0 is not None:
        result.meta["start"] = t0.isoformat()
    if events is not None:
        catalog = load_events(events, start, result.scene.site)
    else:
        catalog = stored_events(result)
    if catalog is not None:
        t_run = (float(result.time[0]), float(result.time[-1]))
        inside = int(np.count_nonzero((catalog.time >= t_run[0]) & (catalog.time <= t_run[1])))
        click.echo(f"seismic events: {len(catalog)} read, {inside} within the run")
        for line in events_report(catalog, float(result.time[0]), float(result.time[-1]), start):
            click.echo(line, err=line.startswith("Warning"))
    if out_dir.exists() and not out_dir.is_dir():
        raise BadInput(f"--out-dir {out_dir}: exists and is not a directory")
    with reading(out_dir):
        files = plot_result(result, out_dir, events=catalog, prefix=f"{result_path.stem}-")
    for f in files:
        click.echo(str(f))

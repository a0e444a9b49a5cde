"""``fault-screen screen RESULT.h5``: re-evaluate the screening rules on a saved result."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

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
    import numpy as np

    from .. import result as results
    from ..screening import LEVEL_NAMES, screen_file

    result_path = Path(result_path)
    if out is not None and Path(out).resolve() == result_path.resolve():
        raise BadInput(f"--out {out}: is RESULT.h5 itself; write to a new file")
    with reading(result_path):
        whole = results.ResultFile(result_path, read_rows=results.READ_ROWS)
    with whole:
        with reading(result_path):
            whole.check()
        scene = whole.scene
        if scene_path is not None:
            monitor = load_scene(Path(scene_path)).monitor
            with reading(scene_path):
                scene = scene.replace(monitor=monitor)
        catalog = None
        if events is not None:
            start = t0
            if start is None and whole.meta.get("start"):
                start = parse_iso(whole.meta["start"], f"{result_path}: meta start")
            catalog = load_events(events, start)
        with reading(result_path):
            if out is None:
                screening = screen_file(whole, scene.monitor, catalog)
            else:
                screening = _screen_into(whole, Path(out), scene, catalog)
        # what the exit code needs of the result: its meta and last time (an unstable stop)
        ended = SimpleNamespace(meta=whole.meta, time=np.array([whole.last("time")]))
        rows = whole.rows
    source = scene_path if scene_path is not None else f"{result_path} (its own scene)"
    click.echo(f"screening {result_path}: {rows} output times, rules of {source}")
    for tr in screening.transitions:
        click.echo(f"  {tr.describe()}")
    if not screening.transitions:
        click.echo(f"  level {LEVEL_NAMES[0]} throughout")
    if out is not None:
        click.echo(f"  written {out}")
    conclude(ended, fail_on, screening)


def _screen_into(whole, out: Path, scene, catalog):
    """Screen the open ResultFile ``whole`` and write it to ``out`` with the new ``/screening/``
    group (and ``scene``, whose ``[monitor]`` may be new, and the ``catalog``'s events), copied
    and screened in bounded pieces; the layout :meth:`fault_screen.Result.save` gives."""
    import numpy as np

    from ..outputs import unit
    from ..result import atomic_hdf5
    from ..rules import METRICS
    from ..screening import TRANSITION_DTYPE, screen_file
    from ..screening.stepwise import _transition_row

    skip = ("screening",) + (("events",) if catalog is not None else ())
    with atomic_hdf5(out) as h5:
        whole.copy_to(h5, skip=skip)
        h5.attrs["scene"] = scene.to_toml()
        if catalog is not None:
            grp = h5.create_group("events")
            for k, v in (("time", catalog.time), ("magnitude", catalog.magnitude)):
                grp.create_dataset(k, data=v).attrs["unit"] = unit("events", k)
        grp = h5.create_group("screening")
        for k, dtype in [(k, "f8") for k in METRICS] + [("level", "i1")]:
            grp.create_dataset(k, shape=(whole.rows,), dtype=dtype).attrs["unit"] = unit("screening", k)

        def sink(first, arrays):
            for k, v in arrays.items():
                grp[k][first:first + len(v)] = v

        screening = screen_file(whole, scene.monitor, catalog, sink=sink)
        tr = np.array([_transition_row(t) for t in screening.transitions], dtype=TRANSITION_DTYPE)
        grp.create_dataset("transitions", data=tr.reshape(-1)).attrs["unit"] = unit("screening", "transitions")
    return screening

"""Running a scene for ``run`` and ``replay``: the outputs checked before the run, the result
streamed to disk, the figures and the summary."""
from __future__ import annotations

import sys
from datetime import datetime
from pathlib import Path

import click
import numpy as np

from ..budget import fluid_budget
from ._common import events_report, load_events
from ._options import BadInput, check_size
from ._progress import Progress, format_duration


def _check_outputs(out: Path, plot_dir: Path | None) -> None:
    """Fail before a long run rather than after it."""
    if out.is_dir():
        raise BadInput(f"--out {out}: is a directory, expected a file name")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise BadInput(f"--out {out}: directory {parent} does not exist")
    if plot_dir is not None and plot_dir.exists() and not plot_dir.is_dir():
        raise BadInput(f"--plot {plot_dir}: exists and is not a directory")


def run_scene(scene, *, scene_label: str, out: Path | None, plot_dir: Path | None,
              events_path: Path | None, start: datetime | None, quiet: bool,
              injected_volume=None, meta: dict | None = None, extra: dict | None = None,
              stem: str = "result"):
    """Simulate ``scene`` streaming its result to ``out`` as it goes (under ``out.part``,
    renamed when complete; a failed run leaves no file), then the figures and the summary;
    returns (result read back, out path, screening)."""
    import os

    from ..api import run_streamed
    from ..result import Result

    out = Path(out) if out is not None else Path.cwd() / f"{stem}.h5"
    _check_outputs(out, plot_dir)
    check_size(scene, scene_label)
    catalog = load_events(events_path, start, scene.site) if events_path is not None else None

    if not quiet:
        m = scene.mesh
        size = "graded mesh" if m.refinement is not None else f"{m.nx} x {m.ny} elements"
        click.echo(f"running {scene_label} ({scene.title}; {size}; "
                   f"0 to {scene.time.end:g} s, dt {scene.time.dt:g} s)")
    progress = None if quiet else Progress(sys.stdout)
    part = out.with_name(out.name + ".part")
    try:
        try:
            sim, screening = run_streamed(scene, part, events=catalog, progress=progress,
                                          injected_volume=injected_volume)
        finally:
            if progress is not None:
                progress.close()
        meta = dict(meta or {})
        meta["scene_file"] = scene_label
        if start is not None:
            meta["start"] = start.isoformat()
        groups = dict(extra or {})
        if catalog is not None:
            meta["events_file"] = str(events_path)
            meta["events_start"] = catalog.start.isoformat() if catalog.start else None
            groups["events"] = catalog.to_arrays(0.0, float(sim.time))
            for line in events_report(catalog, 0.0, float(sim.time), start):
                click.echo(line, err=line.startswith("Warning"))
        sim.close_stream(meta=meta, groups=groups)
        os.replace(part, out)
    finally:
        if part.exists():
            part.unlink()
    result = Result.load(out)
    screening = screening.screening(result)

    figures = []
    if plot_dir is not None:
        from ..plotting import plot_result

        figures = plot_result(result, plot_dir, events=catalog, prefix=f"{out.stem}-")
    _summary(result, out, figures, catalog)
    return result, out, screening


def slip_split(result) -> tuple[float, float]:
    """(largest |slip| of the fault points that slid at some time (contact state 1 or 2), largest
    |slip| of the points that never did), m."""
    slip = np.abs(np.asarray(result.fault["slip"]))
    if not slip.size:
        return 0.0, 0.0
    slid = np.any(np.asarray(result.fault["contact_state"]) != 0, axis=0)
    return (float(slip[:, slid].max()) if slid.any() else 0.0,
            float(slip[:, ~slid].max()) if (~slid).any() else 0.0)


def _summary(result, out: Path, figures, catalog) -> None:
    inj = result.injection
    peak_p = float(np.max(inj["overpressure"])) * 1e-6
    slid, at_rest = slip_split(result)
    volume = float(inj["volume"][-1]) * 1e3
    rows = [
        ("peak injection overpressure", f"{peak_p:.4g} MPa"),
        ("peak slip on the fault", f"{slid * 1e3:.4g} mm" if slid > 0 else "0 mm (no point slid)"),
    ]
    if at_rest > 0:
        # the elastic give of locked penalty contact and the creep of a rate-and-state fault at
        # rest are not slip: shown apart so that they are not read as induced slip
        rows.append(("jump where it never slid", f"{at_rest * 1e3:.3g} mm (elastic give, creep at rest)"))
    stopped = (result.meta.get("stopped") or {}).get("message")
    if stopped:
        rows.append(("stopped", stopped))
    rows += [
        ("injected volume", f"{volume:.5g} L"),
        ("injected fluid went to", fluid_budget(result).summary()),
        ("steps", f"{len(result.time) - 1}"),
        ("wall time", format_duration(float(result.meta.get("wall_time", float("nan"))))),
        ("result", str(out)),
    ]
    if catalog is not None:
        inside = (catalog.time >= result.time[0]) & (catalog.time <= result.time[-1])
        rows.append(("seismic events", f"{len(catalog)} read, {int(inside.sum())} within the run"))
        d = catalog.distance_to_injection
        if d is not None and np.any(np.isfinite(d[inside])):
            rows.append(("nearest event in the run", f"{np.nanmin(d[inside]):.4g} m from the "
                                                     f"injection point"))
        elif d is None:
            rows.append(("event distances", "need a [site] table in the scene"))
    for f in figures:
        rows.append(("figure", str(f)))
    click.echo("summary:")
    for k, v in rows:
        click.echo(f"  {k:<28} {v}")

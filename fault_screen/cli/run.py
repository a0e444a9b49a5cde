"""``fault-screen run [SCENE]``: run a scene with its own injection schedule.

Also holds :func:`run_scene`, the part shared with ``replay`` (checks of the outputs, progress,
saving, figures, summary).
"""
from __future__ import annotations

import sys
from datetime import datetime
from pathlib import Path

import click
import numpy as np

from ..budget import fluid_budget
from ._options import FILE, BadInput, check_size, reading, run_options, version_option
from ._progress import Progress, format_duration
from .screen import conclude, fail_on_option

BUNDLED_SCENE = "rustrel-2015-calibrated.toml"


def default_scene_path() -> Path:
    from ..bundled import bundled_path

    path = bundled_path(BUNDLED_SCENE)
    if path is None:
        raise BadInput(f"the bundled scene {BUNDLED_SCENE} is not installed (the package was "
                       f"installed without its configs); pass a SCENE file")
    return path


def load_scene(path: Path):
    """The scene of ``path``; values outside their plausible range are printed as warnings."""
    import warnings

    from ..scene import Scene, SceneWarning

    with reading(path), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SceneWarning)
        scene = Scene.from_toml(path)
    for w in caught:
        if issubclass(w.category, SceneWarning):
            click.echo(f"Warning: {path}: {w.message}", err=True)
    return scene


def load_events(path: Path, start: datetime | None, site=None):
    from ..io.events import read_events

    with reading(path):
        return read_events(path, start, site=site)


#: how the scene's log keys are named in messages about a scene's injection.log
SCENE_LOG_NAMES = {"flow_unit": "injection.log_flow_unit", "max_gap": "injection.log_max_gap"}


def read_scene_log(scene):
    """The scene's own ``injection.log``, read as bad input (exit 2) when it is bad."""
    from ..io.injection_log import read_injection_log

    inj = scene.injection
    with reading(inj.log):
        return read_injection_log(inj.log, flow_unit=inj.log_flow_unit, max_gap=inj.log_max_gap,
                                  policy=inj.log_policy, option_names=SCENE_LOG_NAMES,
                                  flowback=inj.allow_flowback)


def events_report(catalog, t0: float, t1: float, start) -> list[str]:
    """Lines for the terminal about a catalogue and the run's window [t0, t1] (s)."""
    inside = int(np.count_nonzero((catalog.time >= t0) & (catalog.time <= t1)))
    lines = []
    if len(catalog) and inside == 0:
        when = (f" after {start.isoformat()}" if start is not None
                else " (event times relative to the first event: give --t0 to place them)")
        lines.append(f"Warning: none of the {len(catalog)} events of {catalog.source} is inside "
                     f"the run ({t0:g} to {t1:g} s{when}); first event at "
                     f"{float(catalog.time.min()):.6g} s, last at {float(catalog.time.max()):.6g} s")
    elif not len(catalog):
        lines.append(f"Warning: {catalog.source} holds no event with an origin time")
    lines += [f"Note: {catalog.source}: {n}" for n in catalog.notes]
    return lines


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
        from ..discretisation import mesh_shape

        nx, ny = mesh_shape(scene)  # as built: with the leak-off grading, as `scene check` prints
        size = f"{'graded mesh, ' if scene.mesh.refinement is not None else ''}{nx} x {ny} elements"
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


@click.command("run")
@click.argument("scene_path", type=FILE, required=False, metavar="[SCENE]")
@run_options
@fail_on_option
@version_option
def run(scene_path, out, plot_dir, events, t0, quiet, fail_on):
    """Run SCENE (TOML) with its own injection schedule and save the result (HDF5).

    Without SCENE, runs the bundled Rustrel 2015 calibrated scene
    (configs/rustrel-2015-calibrated.toml, stand-in step-rate schedule).
    """
    path = Path(scene_path) if scene_path is not None else default_scene_path()
    scene = load_scene(path)
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

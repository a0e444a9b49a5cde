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
from ._options import BadInput, check_size, leave_to_the_system
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
    returns (result read back, out path, screening). The result is read back in bounded pieces
    (:meth:`fault_screen.result.ResultFile.view`: a long run's series as envelopes, a bounded
    number of profiles, and none without ``plot_dir``); the summary's numbers are exact
    reductions over the whole file."""
    import os

    from ..api import run_streamed
    from ..result import ResultFile

    out = Path(out) if out is not None else Path.cwd() / f"{stem}.h5"
    _check_outputs(out, plot_dir)
    check_size(scene, scene_label)
    catalog = (load_events(events_path, start, scene.site, end=scene.time.end)
               if events_path is not None else None)

    if not quiet:
        from ..discretisation import mesh_shape

        nx, ny = mesh_shape(scene)  # as built: with the leak-off grading, as `scene check` prints
        size = f"{'graded mesh, ' if scene.mesh.refinement is not None else ''}{nx} x {ny} elements"
        click.echo(f"running {scene_label} ({scene.title}; {size}; "
                   f"0 to {scene.time.end:g} s, dt {scene.time.dt:g} s)")
        from ..run_estimate import estimate_run

        log_arrays = (extra or {}).get("log") or {}
        for line in estimate_run(scene, plot=plot_dir is not None,
                                 log_samples=len(log_arrays.get("time", ()))).lines():
            click.echo(line)
    from ..compile_ahead import compile_ahead

    compile_ahead()        # an empty numba cache: the kernels compiled by child processes
    leave_to_the_system()  # the imported modules' objects: out of the collector's walks
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
    with ResultFile(out) as whole:
        # the fault profiles only for the figures: the summary's slip is reduced over the file
        result = whole.view() if plot_dir is not None else whole.view(profiles=0)
        exact = {"steps": whole.rows - 1,
                 "peak_overpressure": whole.maximum("injection/overpressure"),
                 "slip_split": slip_split(whole)}
    screening = screening.screening(result)

    figures = []
    if plot_dir is not None:
        from ..plotting import plot_result

        figures = plot_result(result, plot_dir, events=catalog, prefix=f"{out.stem}-")
    _summary(result, out, figures, catalog, exact=exact)
    return result, out, screening


def slip_split(result) -> tuple[float, float]:
    """(largest |slip| of the fault points that slid at some time (contact state 1 or 2), largest
    |slip| of the points that never did), m. ``result``: a Result, or a ResultFile (then read in
    bounded pieces)."""
    from ..result import ResultFile

    if isinstance(result, ResultFile):
        if not result.profiles:
            return 0.0, 0.0
        slip = result.profile_reduce("slip", np.abs)
        slid = result.profile_reduce("contact_state", lambda a: a != 0, np.logical_or)
    else:
        profiles = np.abs(np.asarray(result.fault["slip"]))
        if not profiles.size:
            return 0.0, 0.0
        slip = profiles.max(axis=0)
        slid = np.any(np.asarray(result.fault["contact_state"]) != 0, axis=0)
    return (float(slip[slid].max()) if slid.any() else 0.0,
            float(slip[~slid].max()) if (~slid).any() else 0.0)


def unit_reading(scene) -> str | None:
    """One line saying how a Rustrel 2015 scene reads the paper's permeabilities (Table 3 gives
    k_f in m3 s/kg, a mobility), decided from the scene's own rock, so an edited copy says what
    it holds; None for other scenes."""
    if not str(scene.title).startswith("Rustrel 2015"):
        return None
    if scene.rock.mobility is not None:
        return ("k_f read as a mobility k/mu in m2/(Pa s) (its m3 s/kg), the "
                "reading that reproduces the paper's pressures and slip")
    return ("k_f read as a permeability in m2 divided by water's viscosity "
            "(SI); under this reading the fault barely pressurises, unlike the paper "
            "(rustrel-2015-calibrated-paper-units.toml reproduces it)")


def format_volume(volume: float) -> str:
    """A volume (m3) as an operator reads it: litres below 1 m3, cubic metres from 1 m3."""
    if abs(volume) < 1.0:
        return f"{volume * 1e3:.4g} L"
    return f"{volume:,.4g} m3" if abs(volume) < 1e4 else f"{volume:,.0f} m3"


def fluid_destinations(result) -> str:
    """Where the injected fluid is at the end, in plain words."""
    budget = fluid_budget(result)
    if not budget.percent:
        return "nothing injected"
    p = budget.percent
    line = f"{p['fault']:.3g} % in the fault, {p['rock']:.3g} % soaked into the rock"
    if p["leaked"] > 0.05:
        line += f", {p['leaked']:.2g} % flowed out of the modelled block"
    return line


def _summary(result, out: Path, figures, catalog, exact: dict | None = None) -> None:
    """The summary block; ``exact``: the numbers over the whole file (steps, peak_overpressure,
    slip_split) when ``result`` is a bounded view of it."""
    inj = result.injection
    exact = exact or {"steps": len(result.time) - 1,
                      "peak_overpressure": float(np.max(inj["overpressure"])),
                      "slip_split": slip_split(result)}
    peak_p = exact["peak_overpressure"] * 1e-6
    slid, _ = exact["slip_split"]
    rows = [("peak injection overpressure", f"{peak_p:.4g} MPa"),
            ("peak slip on the fault", f"{slid * 1e3:.4g} mm" if slid > 0 else "0 mm (no point slid)")]
    stopped = (result.meta.get("stopped") or {}).get("message")
    if stopped:
        rows.append(("stopped", stopped))
    rows += [
        ("injected volume", format_volume(float(inj["volume"][-1]))),
        ("injected fluid", fluid_destinations(result)),
        ("steps", f"{exact['steps']}"),
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
    reading = unit_reading(result.scene)
    if reading is not None:
        rows.append(("paper's units", reading))
    click.echo("summary:")
    for k, v in rows:
        click.echo(f"  {k:<28} {v}")

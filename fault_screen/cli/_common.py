"""Helpers shared by the commands: reading scenes, logs, event catalogues and saved results as
bad input (exit 2) when they are bad, and the lines about a catalogue."""
from __future__ import annotations

from datetime import datetime
from pathlib import Path

import click

from ._options import BadInput, check_log, reading

#: the scene ``fault-screen run`` runs without SCENE
BUNDLED_SCENE = "rustrel-2015-calibrated-paper-units.toml"


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

def load_events(path: Path | str, start: datetime | None, site=None, end: float | None = None):
    from ..io.events import read_events
    from ..io.fdsn_events import is_event_service, read_event_service

    with reading(path):
        if is_event_service(path):     # the window from start to end (s) of an FDSN event service
            return read_event_service(path, start, end=end, site=site)
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
    import numpy as np   # here: `fault-screen run --help` imports no numpy

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

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


def load_result(path: Path, *, view: bool = False):
    """A saved result, or one line saying why the file is not one (exit 2). ``view``: the
    bounded view to plot (:meth:`fault_screen.result.ResultFile.view`), not the whole file."""
    from ..result import Result, ResultFile

    if not path.exists():
        raise BadInput(f"file not found: {path}")
    if path.is_dir():
        raise BadInput(f"{path}: is a directory, expected a result file (.h5)")
    with open(path, "rb") as fh:
        head = fh.read(8)
    if head != HDF5_MAGIC:
        raise BadInput(f"{path}: not a fault_screen result (not an HDF5 file); results are "
                       f"written by 'fault-screen run' or 'replay'")
    try:
        if view:
            with ResultFile(path) as rf:
                return rf.view()
        return Result.load(path)
    except OSError:
        raise BadInput(f"{path}: truncated or damaged HDF5 file (was the run or the copy "
                       f"interrupted?); run it again") from None
    except Exception:  # noqa: BLE001 - any missing group or attribute: not one of ours
        raise BadInput(f"{path}: an HDF5 file but not a fault_screen result (no readable "
                       f"scene, /time, /fault or /injection)") from None


def stored_events(result):
    """The catalogue stored under /events by run/replay --events (None if there is none)."""
    import numpy as np

    from ..io.events import EventCatalog

    ev = result.extra.get("events")
    if not ev or "time" not in ev:
        return None
    kw = {k: np.asarray(ev[k], dtype=float) for k in
          ("latitude", "longitude", "depth", "x", "y", "z", "distance_to_injection",
           "distance_to_fault") if k in ev}
    types = tuple(t.decode() if isinstance(t, bytes) else str(t)
                  for t in np.asarray(ev.get("magnitude_type", []), dtype=object))
    return EventCatalog(np.asarray(ev["time"], dtype=float),
                        np.asarray(ev["magnitude"], dtype=float), types,
                        source=str(result.meta.get("events_file", "/events")), **kw)


def apply_sets(scene, sets):
    """The scene with ``--set KEY=VALUE`` changes (numbers, true/false or text)."""
    changes = {}
    for item in sets:
        key, eq, text = item.partition("=")
        if not eq or not key.strip():
            raise BadInput(f"--set {item!r}: expected KEY=VALUE, e.g. mesh.nx=26")
        text = text.strip()
        value = {"true": True, "false": False}.get(text.lower(), text)
        if isinstance(value, str):
            try:
                value = int(text)
            except ValueError:
                try:
                    value = float(text)
                except ValueError:
                    pass
        changes[key.strip()] = value
    if not changes:
        return scene
    from ..ensemble import scene_with   # here: a run without --set has no use for the ensemble

    with reading("--set"):
        return scene_with(scene, changes)


def read_driving_log(scene, scene_path: Path, log_path, end, *, accept_implausible: bool = False,
                     quiet: bool = False, what: str = "a log replay", **log_options):
    """The injection log ``log_path`` (a file, or a HYDWS section's URL read by the ``hydws``
    source plugin) that drives ``scene`` instead of its schedule, checked for plausibility, and
    the replay planned from it (:func:`fault_screen.io.replay.plan_replay`): ``(log, plan)``."""
    from ..io.injection_log import CLI_OPTION_NAMES, read_injection_log
    from ..io.replay import plan_replay

    if scene.injection.control != "rate":
        raise BadInput(f"{scene_path}: injection.control = {scene.injection.control!r}: "
                       f"{what} drives the flow rate; use a scene with control = 'rate'")
    read = read_injection_log
    if isinstance(log_path, str):    # a HYDWS section's URL: read by the hydws source plugin
        from ..monitor.plugins import load

        read = load("source", "hydws").read_log
    with reading(log_path):
        log = read(log_path, option_names=CLI_OPTION_NAMES,
                   flowback=scene.injection.allow_flowback, **log_options)
    if not quiet:
        click.echo(f"log: {log.summary}")
    check_log(log, scene, accept_implausible)
    for w in log.warnings:
        click.echo(f"Warning: {w}", err=True)
    with reading(scene_path):
        plan = plan_replay(scene, log, end, end_name="--end")
    for note in plan.notes:
        click.echo(f"Warning: {note}", err=True)
    return log, plan

"""Make the project's entry points visible to tests run from a source tree (not installed).

The entry points are copied from pyproject.toml into a ``*.dist-info/entry_points.txt`` on
``sys.path``, which is what installing the project does; so the tests also check that the
built-in plugins are declared there.  ``pythonpath()`` gives the same view to subprocesses.
"""
from __future__ import annotations

import os
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = ROOT / "plugins"


def write_dist_info(folder: Path) -> Path:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    info = folder / f"fault_screen_srctree-{project['version']}.dist-info"
    info.mkdir(parents=True, exist_ok=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: fault_screen_srctree\n"
                                   f"Version: {project['version']}\n")
    lines = []
    for group, eps in project["entry-points"].items():
        lines.append(f"[{group}]")
        lines += [f"{name} = {value}" for name, value in eps.items()]
        lines.append("")
    (info / "entry_points.txt").write_text("\n".join(lines))
    return folder


def activate(folder: Path) -> None:
    """Put the plugins and the entry points on this interpreter's path."""
    import importlib.util
    from importlib.metadata import entry_points

    if importlib.util.find_spec("fault_screen_plugins") is None and str(PLUGINS) not in sys.path:
        sys.path.append(str(PLUGINS))
    if any(ep.name == "csv" for ep in entry_points(group="fault_screen.sources")):
        return          # the project is installed (or its egg-info is here): its registration
    write_dist_info(folder)
    if str(folder) not in sys.path:
        sys.path.append(str(folder))


def pythonpath(folder: Path) -> dict:
    """Environment for a subprocess that sees the source tree, its plugins and entry points."""
    write_dist_info(folder)
    env = dict(os.environ)
    parts = [str(ROOT), str(PLUGINS), str(folder), str(ROOT / "tests")]
    if env.get("PYTHONPATH"):
        parts.append(env["PYTHONPATH"])
    env["PYTHONPATH"] = os.pathsep.join(parts)
    env["OPENBLAS_NUM_THREADS"] = "1"
    return env


def calibrated_scene_with_step(folder: Path, dt: float) -> Path:
    """``scene.toml`` in ``folder``: the bundled calibrated Rustrel scene with steps of ``dt`` s
    (fewer steps: faster monitor tests)."""
    import dataclasses

    from fault_screen import Scene

    s = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    s = s.replace(time=dataclasses.replace(s.time, dt=dt))
    path = folder / "scene.toml"
    path.write_text(s.to_toml())
    return path


def csv_follower(path, *, log_name: str = "test.csv", **options):
    """The monitor's csv source following ``path`` with a decoder of ``options``:
    ``(source, decoder)``."""
    import logging

    from fault_screen.io.log_stream import LogDecoder
    from fault_screen.monitor import plugins

    dec = LogDecoder(str(path), **options)
    src = plugins.instantiate("source", "csv", str(path), decoder=dec, poll_interval=0.01,
                              log=logging.getLogger(log_name))
    return src, dec

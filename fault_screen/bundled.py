"""The bundled scenes and logs: ``configs/`` at the top of the repository, installed by a wheel
as the package data ``fault_screen.configs`` and found through importlib.resources; in a
checkout or an editable install they are read from ``configs/`` beside the package.

``fault_screen.configs`` has no ``__init__.py`` (``configs/`` is a folder of data that users
edit), so an installed copy is a namespace package, for which ``resources.files`` returns a
``MultiplexedPath`` whose ``str()`` is not a path. Files are therefore looked up by joining the
parts of their name onto the resource root, which yields a real :class:`~pathlib.Path` for any
install on a file system (a wheel installed by pip, an editable install, a checkout).
"""
from __future__ import annotations

from importlib import resources
from pathlib import Path

PACKAGE = "fault_screen.configs"


def _installed(name: str, package: str) -> Path | None:
    """File ``name`` ("a/b.toml") of the resource package ``package`` as a real path, or None."""
    try:
        node = resources.files(package)
        for part in name.split("/"):
            node = node.joinpath(part)
    except (ModuleNotFoundError, FileNotFoundError, NotADirectoryError, ValueError):
        return None
    except Exception as exc:  # noqa: BLE001 - importlib's TraversalError has no public name
        if type(exc).__name__ == "TraversalError":
            return None
        raise
    # a zipped install gives zipfile.Path: not a file a scene's relative log path can sit beside
    return node if isinstance(node, Path) and node.is_file() else None


def _checkout() -> Path | None:
    folder = Path(__file__).resolve().parents[1] / "configs"
    return folder if folder.is_dir() else None


def bundled_path(name: str, package: str = PACKAGE) -> Path | None:
    """File path of a bundled config, e.g. ``"rustrel-2015-calibrated.toml"`` or
    ``"verification/terzaghi.toml"``; None if it is not installed."""
    path = _installed(name, package)
    if path is None and package == PACKAGE and _checkout() is not None:
        path = _checkout().joinpath(*name.split("/"))
    return path if path is not None and path.is_file() else None


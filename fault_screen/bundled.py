"""The bundled scenes and logs: ``configs/`` at the top of the repository, installed by a wheel
as the package data ``fault_screen.configs`` and found through importlib.resources; in a
checkout or an editable install they are read from ``configs/`` beside the package."""
from __future__ import annotations

from importlib import resources
from pathlib import Path


def configs_root() -> Path | None:
    """Folder of the bundled configs, or None if they are not installed."""
    try:
        root = Path(str(resources.files("fault_screen.configs")))
        if root.is_dir():
            return root
    except ModuleNotFoundError:
        pass
    checkout = Path(__file__).resolve().parents[1] / "configs"
    return checkout if checkout.is_dir() else None


def bundled_path(name: str) -> Path | None:
    """File path of a bundled config, e.g. ``"rustrel-2015-calibrated.toml"`` or
    ``"verification/terzaghi.toml"``; None if it is not installed."""
    root = configs_root()
    path = root / name if root is not None else None
    return path if path is not None and path.is_file() else None

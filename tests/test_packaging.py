"""A wheel carries every sub-package and every bundled config (the package list in
pyproject.toml is explicit because configs/ is mapped into the package)."""
import fnmatch
import tomllib

from conftest import CONFIGS, ROOT


def _setuptools():
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_every_sub_package_is_listed():
    listed = set(_setuptools()["packages"])
    on_disk = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "fault_screen").rglob("__init__.py")}
    assert on_disk <= listed, sorted(on_disk - listed)
    assert "fault_screen.configs" in listed and _setuptools()["package-dir"]["fault_screen.configs"] == "configs"


def test_every_bundled_config_matches_a_package_data_pattern():
    patterns = _setuptools()["package-data"]["fault_screen.configs"]
    files = [p.relative_to(CONFIGS).as_posix() for p in CONFIGS.rglob("*") if p.is_file()]
    missing = [f for f in files if not any(fnmatch.fnmatch(f, pat) and f.count("/") == pat.count("/")
                                           for pat in patterns)]
    assert files and not missing, missing


def test_the_bundled_scene_is_found():
    from fault_screen.bundled import bundled_path

    assert bundled_path("rustrel-2015-calibrated.toml").read_bytes() == (
        CONFIGS / "rustrel-2015-calibrated.toml").read_bytes()
    assert bundled_path("no-such-scene.toml") is None

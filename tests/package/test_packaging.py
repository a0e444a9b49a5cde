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


def test_a_bundled_file_of_a_namespace_package_is_a_real_path(tmp_path, monkeypatch):
    """An installed (non-editable) configs folder has no __init__.py: importlib.resources gives
    a MultiplexedPath for it, whose str() is not a path. The file found is the real one, byte for
    byte, in a top folder and in a sub-folder; a missing file is None."""
    import importlib
    import sys
    from pathlib import Path

    from fault_screen.bundled import bundled_path

    pkg = tmp_path / "fs_configs_namespace_probe"
    (pkg / "verification").mkdir(parents=True)
    (pkg / "scene.toml").write_bytes(b"title = 'probe'\n")
    (pkg / "verification" / "deep.toml").write_bytes(b"x = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    try:
        found = bundled_path("scene.toml", package=pkg.name)
        deep = bundled_path("verification/deep.toml", package=pkg.name)
        assert isinstance(found, Path) and found == pkg / "scene.toml"
        assert found.read_bytes() == b"title = 'probe'\n"
        assert deep == pkg / "verification" / "deep.toml"
        assert bundled_path("nothing.toml", package=pkg.name) is None
        assert bundled_path("scene.toml", package="fs_no_such_package_here") is None
    finally:
        sys.modules.pop(pkg.name, None)

"""One mesh size everywhere, the size estimate, the material laws in one place, and the layers of
the scene, physics and discretisation (no import cycle).

The mesh a run is built on is ``discretisation.model_mesh``: ``[mesh]`` refined by the physics
terms (the leak-off grading adds element rows across a fault along x). ``run`` and ``scene
check`` print its size, and ``estimate_size`` counts its elements, so the three agree with the
Discretisation's element count exactly.
"""
import ast
import warnings
from pathlib import Path

import pytest

from fault_screen import Scene
from fault_screen.discretisation import discretise, estimate_size, mesh_shape
from fault_screen.physics import effects_on, switches_implied_by, terms_for
from fault_screen.physics.materials import constrained_modulus, drained_bulk_modulus, storage_coefficient

from conftest import CONFIGS

PACKAGE = Path(__file__).resolve().parents[2] / "fault_screen"
#: a small scene with leak-off along x: the grading adds rows across the fault (10 x 11 as given)
SMALL = """title = "small"
[mesh]
nx = 10
ny = 11
[time]
end = 5.0
dt = 5.0
"""


def _quiet_discretise(scene):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return discretise(scene)


@pytest.mark.parametrize("name", ["rustrel-2015-calibrated", "rustrel-2015-calibrated-paper-units",
                                  "rustrel-2015-impermeable", "hard-cases/fault-geometry"])
def test_mesh_shape_is_the_discretisations(name):
    scene = Scene.from_toml(CONFIGS / f"{name}.toml")
    disc = _quiet_discretise(scene)
    assert mesh_shape(scene) == (disc.mesh.nx, disc.mesh.ny)
    assert estimate_size(scene)[0] == disc.mesh.n_elements


def test_run_and_scene_check_print_the_size_of_the_mesh_built(tmp_path, monkeypatch):
    """`scene check` printed the graded mesh (50 x 61) and `run` the mesh as given (50 x 51)."""
    from click.testing import CliRunner

    from fault_screen.cli import main

    path = tmp_path / "small.toml"
    path.write_text(SMALL)
    disc = _quiet_discretise(Scene.from_toml(path))
    nx, ny = disc.mesh.nx, disc.mesh.ny
    assert nx == 10 and ny > 11  # the leak-off grading added rows across the fault
    size = f"{nx} x {ny} elements"
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    check = runner.invoke(main, ["scene", "check", str(path)])
    assert check.exit_code == 0, check.output
    assert f"mesh {size}" in check.output
    run = runner.invoke(main, ["run", str(path), "--out", str(tmp_path / "r.h5")])
    assert run.exit_code == 0, run.output
    assert f"; {size};" in run.output


def test_estimate_size_bounds_an_absurd_graded_mesh_without_building_it():
    """1 um elements over 100 km: the lines are not built (10^11 of them); the estimate is the
    bound of mesh.graded_line (no element but the end ones below half the fine size)."""
    scene = Scene.from_dict({"mesh": {"lx": 1e5, "ly": 1e5, "refinement": {
        "center": [5e4, 5e4], "half_width": [10.0, 10.0], "size": 1e-6}}, "fault": {"point": [5e4, 5e4]}})
    elements, unknowns, memory = estimate_size(scene)
    lines = int(2.0 * 1e5 / 1e-6 + 2.0)
    assert elements == lines * lines
    assert unknowns > 3 * lines * lines
    assert memory > 1e24


def test_constrained_modulus_is_k_plus_four_thirds_g():
    """E = 30 GPa, nu = 0.25: K = 20 GPa, G = 12 GPa, K + 4G/3 = 36 GPa."""
    assert drained_bulk_modulus(30e9, 0.25) == pytest.approx(20e9, rel=1e-15)
    assert constrained_modulus(30e9, 0.25) == pytest.approx(36e9, rel=1e-15)
    props = {"E": 30e9, "nu": 0.25, "alpha": 0.5, "inv_M": 1e-10}
    assert storage_coefficient(props, mechanics=True) == pytest.approx(1e-10 + 0.25 / 36e9, rel=1e-15)
    assert storage_coefficient(props, mechanics=False) == 1e-10


def test_graded_cut_height_is_the_height_of_the_cut_elements():
    """The physics layer answers what the accuracy study pins for its time rungs: the paper-units
    scene's cut elements are 0.025 m high, as built."""
    scene = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated-paper-units.toml")
    height = terms_for(scene).graded_cut_height(scene)
    disc = _quiet_discretise(scene)
    built = disc.mesh.element_sizes[disc.cut_elements][:, 1]
    assert height == pytest.approx(0.025, rel=0.05)
    assert built.max() == pytest.approx(height, rel=1e-9)
    no_leak = Scene.from_dict({"effects": {"leak_off": False}})
    assert terms_for(no_leak).graded_cut_height(no_leak) == 0.0


def test_studies_ask_the_physics_layer_which_effects_are_on():
    scene = Scene()
    assert effects_on(scene) == {"fault", "mechanics", "poroelastic", "leak_off", "fault_flow"}
    assert switches_implied_by({"rate_parameter": 0.0}) == {"rate_friction": False, "state_evolution": False}
    assert switches_implied_by({"dilation_angle": 0.0, "rate_parameter": 0.01}) == {"dilation": False}
    assert switches_implied_by({}) == {}


def _imports(path: Path) -> set[str]:
    """Modules of fault_screen that ``path`` imports, anywhere in it (functions and
    TYPE_CHECKING blocks included)."""
    module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                target = f"{base}.{node.module}" if node.module else base
            else:
                target = node.module or ""
            names = [f"{target}.{a.name}" for a in node.names] + [target]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        out.update(n for n in names if n.startswith("fault_screen"))
    return out


def test_no_import_cycle_through_scene_physics_and_discretisation():
    """The material law lived in discretisation.py, which imports physics, while
    physics/leak_off_mesh.py imported it back."""
    files = {".".join(p.relative_to(PACKAGE.parent).with_suffix("").parts).removesuffix(".__init__"): p
             for p in PACKAGE.rglob("*.py")}
    graph = {m: {t for t in _imports(p) if t in files and t != m} for m, p in files.items()}
    area = {m for m in files if (m.split(".") + [""])[1] in {"scene", "units", "mesh", "xfem", "discretisation",
                                                    "physics", "accuracy", "ensemble", "budget"}}

    def reaches(start, goal, seen):
        for nxt in graph[start]:
            if nxt == goal:
                return True
            if nxt not in seen:
                seen.add(nxt)
                if reaches(nxt, goal, seen):
                    return True
        return False

    cycles = sorted(m for m in area if reaches(m, m, set()))
    assert cycles == []
    assert "fault_screen.discretisation" not in set().union(
        *(graph[m] for m in files if m.startswith("fault_screen.physics")))


def test_graded_line_without_growth_is_uniform():
    """growth = 1 on 100 km at 2.5 m: 40,000 elements of 2.5 m (the size estimate builds such lines;
    graded_line summed its list at every element, 10 s here, and now keeps a running sum)."""
    from fault_screen.mesh import graded_line

    lines = graded_line(0.0, 1e5, 5e4, 10.0, 2.5, 1.0)
    assert len(lines) == 40001
    assert lines[0] == 0.0 and lines[-1] == 1e5
    assert abs(lines[1:] - lines[:-1] - 2.5).max() < 1e-9

"""Leak-off does not depend on the element height across the fault (issue 10, part 2).

Reference: a fault held at a constant overpressure dp leaks into each wall as into a half-space,
1-D diffusion with c = (k/mu) / S and S = 1/M + alpha^2 / (K + 4G/3) (uniaxial strain: roller
side edges, constant total stress normal to the fault), so the rock has taken
2 dp S sqrt(c t / pi) per unit area of fault per wall at time t (the erfc solution).
"""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from fault_screen import Scene, simulate
from fault_screen.discretisation import discretise
from fault_screen.mesh import grade_across
from fault_screen.physics.leak_off_mesh import SIZE_FRACTION
from fault_screen.physics.materials import effective_rock, storage_coefficient
from fault_screen.scene import SceneWarning

from conftest import CONFIGS

ROCK = dict(youngs_modulus=31.3e9, poissons_ratio=0.3, biot_coefficient=0.77, porosity=0.148,
            permeability=1e-17)
VISCOSITY, FLUID_K = 8.9e-4, 2.15e9
DP, T_END = 1e6, 1000.0


def diffusion_constants():
    """(S 1/Pa, c m^2/s) of the rock, by hand."""
    E, nu, alpha, n, k = (ROCK[key] for key in ("youngs_modulus", "poissons_ratio", "biot_coefficient",
                                                 "porosity", "permeability"))
    K = E / (3 * (1 - 2 * nu))
    G = E / (2 * (1 + nu))
    Ks = K / (1 - alpha)
    S = (alpha - n) / Ks + n / FLUID_K + alpha ** 2 / (K + 4 * G / 3)
    return S, k / VISCOSITY / S


def half_space(height_over_length: float, grading: str = "auto", angle: float = 0.0) -> Scene:
    """A fault along x held at DP, in a box 30 leak-off lengths sqrt(c T_END) high whose
    elements are ``height_over_length`` of that length high (odd count: the fault crosses the
    middle of a row)."""
    S, c = diffusion_constants()
    ell = np.sqrt(c * T_END)
    height = 30 * ell
    ny = int(round(height / (height_over_length * ell))) | 1
    return Scene.from_dict({
        "mesh": {"nx": 2, "ny": ny, "lx": 2 * ell, "ly": height, "origin": [0.0, -height / 2],
                 "fault_grading": grading},
        "fault": {"point": [ell, 0.0], "angle": angle, "hydraulic_aperture": 1e-3, "kappa": 1.0},
        "rock": ROCK, "fluid": {"viscosity": VISCOSITY, "bulk_modulus": FLUID_K},
        "initial": {"stress": [-10e6, -10e6, 0.0], "stress_kind": "fault_effective", "pore_pressure": 0.0},
        "boundary": {"left": {"mechanical": "roller"}, "right": {"mechanical": "roller"},
                     "bottom": {"mechanical": "roller"}, "top": {"mechanical": "free"}},
        "injection": {"control": "pressure", "schedule": [[0.0, DP]]},
        "time": {"end": T_END, "dt": 1.0, "growth": 1.2, "dt_max": 100.0},
        "effects": {"mechanics": True, "poroelastic": True, "leak_off": True, "fault_flow": True,
                    "dilation": False, "aperture_evolution": False, "gravity": False,
                    "damage_zone": False},
    })


def vertical_half_space(height_over_length: float) -> Scene:
    """The same with the fault along y (the grading then acts on the x lines)."""
    d = half_space(height_over_length).to_dict()
    m = d["mesh"]
    m["nx"], m["ny"], m["lx"], m["ly"] = m["ny"], m["nx"], m["ly"], m["lx"]
    m["origin"] = [m["origin"][1], m["origin"][0]]
    d["fault"]["point"] = [0.0, d["fault"]["point"][0]]
    d["fault"]["angle"] = 90.0
    d["boundary"] = {"bottom": {"mechanical": "roller"}, "top": {"mechanical": "roller"},
                     "left": {"mechanical": "roller"}, "right": {"mechanical": "free"}}
    return Scene.from_dict(d)


def leaked_error(result) -> tuple[np.ndarray, np.ndarray]:
    """(time, relative error of the fluid stored in the rock against the erfc solution)."""
    S, c = diffusion_constants()
    t = result.time[1:]
    width = result.scene.mesh.lx
    reference = 2 * width * 2 * DP * S * np.sqrt(c * t / np.pi)  # two walls
    return t, result.balance["stored_rock"][1:] / reference - 1


@pytest.fixture(scope="module")
def runs():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        return {(ratio, grading): simulate(half_space(ratio, grading))
                for ratio, grading in ((10, "auto"), (1, "auto"), (0.1, "auto"), (10, "off"))}


def test_storage_coefficient_matches_hand_computation():
    props = effective_rock(Scene.from_dict({"rock": ROCK}).rock, FLUID_K, VISCOSITY)
    S, _ = diffusion_constants()
    assert storage_coefficient(props, mechanics=True) == pytest.approx(S, rel=1e-12)
    assert S == pytest.approx(8.84e-11, rel=2e-3)   # 1/M = 7.43e-11, alpha^2/(K + 4G/3) = 1.41e-11


@pytest.mark.parametrize("ratio", [10, 1, 0.1])
def test_leaked_volume_matches_erfc_at_any_element_height(runs, ratio):
    """Eq. 3-7 (modified level set, leak-off): element heights 10, 1 and 0.1 times sqrt(c t_end):
    within 2 % of the erfc leaked volume from 20 s (20 first steps; before that the implicit step's
    own error dominates: -11 % after one step, as for any mesh)."""
    r = runs[(ratio, "auto")]
    assert r.injection["overpressure"][-1] == pytest.approx(DP, rel=1e-9)
    t, err = leaked_error(r)
    late = t >= 20.0
    assert np.max(np.abs(err[late])) < 0.02, (ratio, err[late])
    assert abs(err[-1]) < 0.02


def test_fault_along_y_is_graded_too():
    """Element width 10 sqrt(c t_end) across a fault along y: the x lines are graded and the
    leaked volume is within 2 % of the erfc solution (width of the fault: ly)."""
    scene = vertical_half_space(10)
    r = simulate(scene)
    assert discretise(scene).mesh.nx > 3 * scene.mesh.nx
    S, c = diffusion_constants()
    t = r.time[1:]
    reference = 2 * scene.mesh.ly * 2 * DP * S * np.sqrt(c * t / np.pi)
    err = r.balance["stored_rock"][1:] / reference - 1
    assert np.max(np.abs(err[t >= 20.0])) < 0.02, err


def test_results_do_not_depend_on_element_height(runs):
    """The graded meshes store the same volume whatever the height given (to 0.1 %)."""
    stored = [runs[(ratio, "auto")].balance["stored_rock"][-1] for ratio in (10, 1, 0.1)]
    assert np.ptp(stored) / np.mean(stored) < 1e-3


def test_ungraded_coarse_mesh_overstores(runs):
    """Without the grading a cut element 10 sqrt(c t) high stores the fault's fluid in its whole
    strip: +50 % at t_end (what the grading removes)."""
    _, err = leaked_error(runs[(10, "off")])
    assert err[-1] > 0.3


def test_grade_across_geometry():
    lines = np.linspace(0.0, 250.0, 52)
    graded = grade_across(lines, 125.0, 0.01, 1.2)
    h = np.diff(graded)
    k = np.searchsorted(graded, 125.0) - 1
    assert graded[k] == pytest.approx(124.995) and graded[k + 1] == pytest.approx(125.005)
    assert h.min() == pytest.approx(0.01)
    inner = slice(k - 20, k + 20)   # the graded part grows by 1.2 per element
    assert np.allclose(np.maximum(h[inner][1:] / h[inner][:-1], h[inner][:-1] / h[inner][1:]), 1.2)
    assert graded[0] == 0.0 and graded[-1] == 250.0
    assert h.max() < 1.5 * 250.0 / 51     # no element grows beyond 1.5 times the given height
    assert grade_across(lines, 125.0, 10.0, 1.2) is lines   # already fine enough: unchanged


def test_grading_follows_the_damage_zone():
    """Rustrel: the fault lies in the damage zone, so the cut element is 0.5 sqrt(c dt) of the
    damage zone's rock (1.67 m with dt = 5 s), not of the intact rock (7 mm)."""
    scene = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    disc = discretise(scene)
    dz = effective_rock(Scene.from_dict({"rock": {"youngs_modulus": 16.2e9, "poissons_ratio": 0.34,
                                                  "biot_coefficient": 0.77, "porosity": 0.1425,
                                                  "permeability": 4.93e-14}}).rock, 2.15e9, 8.9e-4)
    c = dz["mobility"] / storage_coefficient(dz, mechanics=True)
    heights = disc.mesh.element_sizes[disc.cut_elements, 1]
    assert np.allclose(heights, SIZE_FRACTION * np.sqrt(c * scene.time.dt), rtol=1e-9)
    assert heights[0] == pytest.approx(0.835, rel=0.01)


def test_inclined_fault_on_a_coarse_mesh_is_warned():
    with pytest.warns(SceneWarning, match="does not run along x or y"):
        discretise(half_space(1, angle=10.0))


def test_grading_off_on_a_coarse_mesh_is_warned():
    with pytest.warns(SceneWarning, match="fault_grading = 'off'"):
        discretise(half_space(10, "off"))


def test_scene_check_prints_the_leak_off_warning(tmp_path):
    """`scene check` of the issue-10 scene turned to 10 degrees (a mesh that cannot be graded
    across it) says so on stderr and still succeeds."""
    from click.testing import CliRunner

    from fault_screen.cli import main

    text = (CONFIGS / "verification" / "leak-off-convergence.toml").read_text()
    path = tmp_path / "inclined.toml"
    path.write_text(text.replace("angle = 0.0", "angle = 10.0", 1))
    r = CliRunner().invoke(main, ["scene", "check", str(path)], catch_exceptions=False)
    assert r.exit_code == 0
    assert "Warning:" in r.stderr and "does not run along x or y" in r.stderr
    assert "times the leak-off length" in r.stderr



def test_coarse_grading_size_is_warned():
    scene = half_space(10)
    scene = scene.replace(mesh=dataclasses.replace(scene.mesh, fault_grading_size=1.0))
    with pytest.warns(SceneWarning, match="fault_grading_size = 1 m"):
        discretise(scene)

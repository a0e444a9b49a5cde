"""HDF5 layout of results (the contract other layers and users rely on)."""
import tomllib

import h5py
import numpy as np
import pytest

from fault_screen import Result, Scene, simulate

FAULT_KEYS = ["pressure", "overpressure", "slip", "opening", "slip_rate", "shear_traction",
              "effective_normal_stress", "friction"]


@pytest.fixture(scope="module")
def result():
    scene = Scene.from_dict({
        "mesh": {"nx": 10, "ny": 11, "lx": 50.0, "ly": 50.0},
        "initial": {"effective_stress": [-5.649e6, -3.351e6, 0.964e6], "pore_pressure": 2.764e6},
        "injection": {"number_of_fractures": 10, "schedule": [[0.0, 1e-3]]},
        "time": {"end": 20.0, "dt": 5.0},
    })
    return simulate(scene)


def test_layout_units_and_shapes(result, tmp_path):
    path = result.save(tmp_path / "r.h5")
    assert not (tmp_path / "r.h5.part").exists()
    with h5py.File(path, "r") as h5:
        nt = len(h5["time"])
        nx = len(h5["fault/x"])
        assert nt == 5 and h5["time"].attrs["unit"] == "s"
        for k in FAULT_KEYS:
            assert h5[f"fault/{k}"].shape == (nt, nx), k
        assert h5["fault/pressure"].attrs["unit"] == "Pa"
        assert h5["fault/slip_rate"].attrs["unit"] == "m/s"
        for k in ("flow_rate", "pressure", "slip", "opening", "volume"):
            assert h5[f"injection/{k}"].shape == (nt,)
        scene = Scene.from_dict(tomllib.loads(h5.attrs["scene"]))
        assert scene == result.scene
        # x is measured from the injection point: it changes sign there
        x = h5["fault/x"][()]
        assert x.min() < 0 < x.max()
        # pressure = initial pore pressure + overpressure
        assert np.allclose(h5["fault/pressure"][()] - h5["fault/overpressure"][()], 2.764e6)
        # volume is the time integral of the flow rate (1 L/s for 20 s)
        assert h5["injection/volume"][-1] == pytest.approx(20.0 * 1e-3, rel=1e-12)


def test_round_trip(result, tmp_path):
    path = result.save(tmp_path / "r.h5")
    back = Result.load(path)
    assert back.scene == result.scene
    for k in FAULT_KEYS:
        assert np.array_equal(back.fault[k], result.fault[k])
    assert np.array_equal(back.injection["volume"], result.injection["volume"])


def test_injection_point_values_come_from_the_nearest_fault_point(result):
    k = int(np.argmin(np.abs(result.fault_x)))
    assert abs(result.fault_x[k]) <= 0.25 * 5.0  # within a quarter of the 5 m elements
    for key in ("slip_rate", "shear_traction", "effective_normal_stress", "friction"):
        assert np.array_equal(result.injection[key], result.fault[key][:, k])


def test_readme_results_table_is_the_output_schema():
    """Units live in one place: the README's table is generated from fault_screen.outputs."""
    from conftest import ROOT
    from fault_screen.outputs import markdown_table

    readme = (ROOT / "README.md").read_text()
    block = readme.split("<!-- outputs table: begin -->\n", 1)[1].split("\n<!-- outputs table: end -->", 1)[0]
    assert block == markdown_table()

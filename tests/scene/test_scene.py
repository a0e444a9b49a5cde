"""Scene loading and validation: clear errors naming the key and the value."""
import re
import tomllib

import pytest

from conftest import CONFIGS
from fault_screen import Scene, SceneError


def test_defaults_round_trip_through_toml():
    scene = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    again = Scene.from_dict(tomllib.loads(scene.to_toml()))
    assert again == scene


@pytest.mark.parametrize("data,needle", [
    ({"mesh": {"nz": 3}}, "unknown key mesh.nz = 3"),
    ({"rock": {"poissons_ratio": 0.5}}, "rock.poissons_ratio = 0.5"),
    ({"rock": {"permeability": -1e-15}}, "rock.permeability = -1e-15"),
    ({"mesh": {"nx": "ten"}}, "mesh.nx = 'ten' must be an integer"),
    ({"fault": {"point": [500.0, 10.0]}}, "fault.point"),
    ({"injection": {"position": 400.0}}, None),  # checked below: off the fault at build time
    ({"effects": {"poroelastic": False, "leak_off": True}}, "effects.leak_off"),
    ({"time": {"theta": 0.2}}, "time.theta = 0.2"),
    ({"boundary": {"top": {"mechanical": "glued"}}}, "boundary.top.mechanical = 'glued'"),
    ({"zones": [{"band": 5.0, "rock": {"youngs_modulus": -1.0}}]}, "zones[0].rock.youngs_modulus"),
    ({"injection": {"schedule": [[10.0, 1e-3], [5.0, 0.0]]}}, "times must increase"),
])
def test_bad_values_are_refused_with_key_and_value(data, needle):
    if needle is None:
        from fault_screen.discretisation import discretise
        with pytest.raises(ValueError, match="off the fault"):
            discretise(Scene.from_dict(data))
        return
    with pytest.raises(SceneError) as err:
        Scene.from_dict(data)
    assert needle in str(err.value)


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(SceneError, match="not found"):
        Scene.from_toml(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[mesh\nnx = 3")
    with pytest.raises(SceneError, match="not valid TOML"):
        Scene.from_toml(bad)


def test_scenes_are_frozen():
    scene = Scene()
    with pytest.raises(Exception):
        scene.mesh.nx = 3  # type: ignore[misc]


def test_values_may_carry_field_units():
    s = Scene.from_dict({
        "rock": {"youngs_modulus[GPa]": 29.2, "permeability": "100 mD"},
        "fault": {"normal_stiffness": "27.7 GPa/m", "angle[rad]": 0.5},
        "injection": {"schedule[L/min]": [[0, 60], [150, 0]]},
        "time": {"end": "2 h"},
        "zones": [{"band": "5 m", "rock": {"youngs_modulus[GPa]": 15.0}}],
    })
    assert s.rock.youngs_modulus == 29.2e9
    assert s.rock.permeability == pytest.approx(9.869233e-14, rel=1e-12)
    assert s.fault.normal_stiffness == 27.7e9
    assert s.fault.angle == pytest.approx(28.64788975654116, rel=1e-12)  # stored in degrees
    assert s.injection.schedule[0][1] == pytest.approx(1e-3, rel=1e-12)  # 60 L/min in m3/s
    assert s.time.end == 7200.0
    assert s.zones[0].rock["youngs_modulus"] == 15.0e9
    # pressure control: the schedule is in pressure units
    p = Scene.from_dict({"injection": {"control": "pressure", "schedule[MPa]": [[0, 2.5]]}})
    assert p.injection.schedule[0][1] == 2.5e6


@pytest.mark.parametrize("data,needle", [
    ({"rock": {"youngs_modulus": "29.2 furlongs"}}, "unknown pressure unit 'furlongs'"),
    ({"rock": {"youngs_modulus": "29.2 L/min"}}, "is a flow_rate unit, not a pressure unit"),
    ({"rock": {"porosity[%]": 14.0}}, "porosity takes no unit"),
    ({"rock": {"youngs_modulus[GPa]": "29.2 GPa"}}, "already given in the key"),
    ({"rock": {"youngs_modulus": 1e9, "youngs_modulus[GPa]": 1.0}}, "given twice"),
])
def test_bad_units_are_refused(data, needle):
    with pytest.raises(SceneError, match=re.escape(needle)):
        Scene.from_dict(data)


def test_a_scene_can_take_a_log_instead_of_a_schedule(tmp_path):
    """injection.log (relative to the scene file) drives the run; the injected volume is the
    log's trapezoidal volume: 0 -> 60 L/min over 30 s, 60 L/min for 30 s, 0 after 90 s."""
    import numpy as np

    from fault_screen import simulate

    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "q.csv").write_text(
        "elapsed,flow_rate[L/min]\n0,0\n30,60\n60,60\n90,0\n")
    (tmp_path / "s.toml").write_text(
        '[mesh]\nnx = 8\nny = 9\nlx = 40.0\nly = 40.0\n'
        '[injection]\nlog = "logs/q.csv"\nnumber_of_fractures = 10\n'
        '[time]\nend = 100.0\ndt = 7.0\n')
    scene = Scene.from_toml(tmp_path / "s.toml")
    assert scene.injection.log == str(tmp_path / "logs" / "q.csv")
    r = simulate(scene)
    litres = (0.5 * 30 * 60 + 30 * 60 + 0.5 * 30 * 60) / 60.0  # L
    assert r.injection["volume"][-1] == pytest.approx(litres * 1e-3, rel=1e-12)
    # Eq. 29 output: flow / (NoF 2h) at the injection point
    k = np.argmax(r.injection["flow_rate"])
    assert r.injection["fault_inflow_velocity"][k] == pytest.approx(
        r.injection["flow_rate"][k] / (10 * r.injection["hydraulic_aperture"][k]), rel=1e-12)
    with pytest.raises(SceneError, match="injection.log"):
        Scene.from_dict({"injection": {"log": "missing.csv"}}, base_dir=tmp_path)


def test_moved_slip_rate_threshold_key_points_to_the_monitor_table():
    with pytest.raises(SceneError) as err:
        Scene.from_dict({"fault": {"slip_rate_threshold": 1e-9}})
    assert "fault.slip_rate_threshold" in str(err.value) and "[monitor]" in str(err.value)

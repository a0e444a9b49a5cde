"""Rock flow given as permeability (m^2, divided by the viscosity) or as mobility (m^2/(Pa s))."""
from __future__ import annotations

import numpy as np
import pytest

from fault_screen.budget import fluid_budget
from fault_screen.discretisation import discretise
from fault_screen.scene import Scene, SceneError
from fault_screen.units import to_si

MU = 8.9e-4


def small(**over):
    data = {"mesh": {"nx": 4, "ny": 5, "lx": 10.0, "ly": 10.0}, "fluid": {"viscosity": MU},
            "effects": {"damage_zone": True}, "damage_zone": {"width": 2.0}}
    for key, value in over.items():
        data.setdefault(key, {}).update(value)
    return Scene.from_dict(data)


def test_mobility_units():
    assert to_si(1.0, "m3 s/kg", "mobility") == 1.0          # the paper's unit of k_f
    assert to_si(2.0, "m2/(Pa s)") == 2.0
    assert to_si(1.0, "mD/cP") == pytest.approx(9.869233e-13, rel=1e-12)   # 1e-3 D / 1e-3 Pa s
    with pytest.raises(ValueError, match="not a mobility unit"):
        to_si(1.0, "m2", "mobility")


def test_mobility_or_permeability_gives_the_same_rock():
    by_k = small(rock={"permeability": 1e-15})
    by_m = small(rock={"mobility[m2/(Pa s)]": 1e-15 / MU})
    assert by_m.rock.permeability is None
    assert by_k.rock.mobility_at(MU) == pytest.approx(by_m.rock.mobility_at(MU), rel=1e-15)
    # a mobility does not depend on the fluid
    assert by_m.rock.mobility_at(1.0) == pytest.approx(1e-15 / MU, rel=1e-15)


@pytest.mark.parametrize("data, key", [
    ({"rock": {"permeability": 1e-15, "mobility": 1e-12}}, r"\[rock\] gives both"),
    ({"damage_zone": {"permeability": 1e-15, "mobility[mD/cP]": 1.0}}, r"\[damage_zone\] gives both"),
    ({"zones": [{"band": 1.0, "rock": {"permeability": 1e-15, "mobility": 1e-12}}]}, r"zones\[0\].rock\] gives both"),
    ({"rock": {"mobility": -1e-12}}, r"rock.mobility = -1e-12"),
    ({"rock": {"mobility": "3 m2"}}, r"rock.mobility = '3 m2'.*not a mobility unit"),
])
def test_bad_flow_property_refused(data, key):
    with pytest.raises(SceneError, match=key):
        Scene.from_dict(data)


def test_zone_overrides_replace_the_other_kind():
    rock = small(rock={"mobility": 1e-12}).rock
    assert rock.with_overrides({"permeability": 1e-15}).mobility_at(MU) == pytest.approx(1e-15 / MU)
    rock = small(rock={"permeability": 1e-15}).rock
    assert rock.with_overrides({"mobility": 1e-12}).mobility_at(MU) == 1e-12
    assert rock.with_overrides({"porosity": 0.2}).mobility_at(MU) == pytest.approx(1e-15 / MU)


def test_resolved_scene_round_trips_a_mobility():
    s = small(rock={"mobility": 1e-12}, damage_zone={"mobility": 3e-11})
    text = s.to_toml()
    assert "mobility = 1e-12" in text and "permeability" not in text.split("[damage_zone]")[0]
    import tomllib
    back = Scene.from_dict(tomllib.loads(text))
    assert back == s


def test_model_uses_the_given_mobilities():
    """Intact rock, damage zone and a box zone, each given its own way: the element mobilities
    are exactly those values (k / mu where a permeability is given)."""
    s = Scene.from_dict({
        "mesh": {"nx": 4, "ny": 5, "lx": 10.0, "ly": 10.0}, "fluid": {"viscosity": MU},
        "rock": {"mobility": 1e-12}, "effects": {"damage_zone": True},
        "damage_zone": {"width": 1.0, "permeability": 1e-15},
        "zones": [{"box": [0.0, 2.5, 0.0, 2.5], "rock": {"mobility": 7e-13}}]})
    m = discretise(s)
    values = {float(v) for v in np.unique(m.el_mobility)}
    expected = {1e-12, 1e-15 / MU, 7e-13}
    assert len(values) == 3
    for v in expected:
        assert any(abs(v - w) <= 1e-12 * v for w in values)


class _FakeResult:
    def __init__(self, volume, nof, fault, rock, leaked):
        from types import SimpleNamespace

        self.injection = {"volume": np.array([0.0, volume])}
        self.balance = {"stored_fault": np.array([0.0, fault]), "stored_rock": np.array([0.0, rock]),
                        "leaked": np.array([0.0, leaked])}
        self.scene = SimpleNamespace(injection=SimpleNamespace(number_of_fractures=nof))


def test_fluid_budget_shares_of_the_model_fault():
    # 1 m3 over 4 fractures: the model fault takes 0.25 m3
    b = fluid_budget(_FakeResult(1.0, 4, fault=0.05, rock=0.15, leaked=0.049))
    assert b.model_fault == 0.25
    assert b.percent == pytest.approx({"fault": 20.0, "rock": 60.0, "leaked": 19.6})
    assert b.unaccounted_percent == pytest.approx(0.4)
    assert b.summary() == "fault 20 %, rock 60 %, leaked through edges 19.6 %"
    nothing = fluid_budget(_FakeResult(0.0, 1, 0.0, 0.0, 0.0))
    assert nothing.percent == {} and nothing.unaccounted_percent is None
    assert nothing.summary() == "nothing injected"


def test_flow_summary_prints_both_ways():
    s = small(rock={"mobility": 1e-12}, damage_zone={"permeability": 8.9e-16})
    rock, dz = s.flow_summary()
    assert rock.startswith("rock: permeability 8.9e-16 m2, mobility 1e-12 m2/(Pa s) (given as mobility")
    assert dz.startswith("damage_zone: permeability 8.9e-16 m2, mobility 1e-12 m2/(Pa s) (given as permeability")

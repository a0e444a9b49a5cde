"""`scene show`: every value line names its unit, and the units are those the scene's field
docstrings give (one source), consistent with the range table and the unit parser.

`slip_rate_yellow = 1e-06  # -` named no unit: the screening thresholds had none in the range
table the command read. Now the unit comes from each field's docstring, "-" only for pure
numbers, printed with the word "dimensionless".
"""
import dataclasses
import re

import pytest

from fault_screen import scene as scene_module
from fault_screen.scene import DOC_UNITS, QUANTITY, RANGES, Scene, field_unit
from fault_screen.units import SI_UNIT

from conftest import CONFIGS

#: what a value line of `scene show` may give after its "#": a unit, or what the value is
#: the range table, the unit parser and `scene show` write units without ^ and angles as deg
COMPACT = {"degrees": "deg", "degrees north": "deg", "degrees east": "deg"}
SHOWN = ({COMPACT.get(u, u.replace("^", "")) for u in DOC_UNITS if u != "-"}
         | {"- (dimensionless)", "text", "true/false", "[s, m3/s]", "[s, Pa]", "units of [rock]"})


def _sections():
    return list(scene_module._SECTIONS.values()) + [scene_module.Zone, Scene]


def _is_value(cls, f) -> bool:
    base = str(f.type).replace(" | None", "")
    return base not in scene_module._SECTIONS and not base.startswith(("tuple[Zone", "tuple[MonitorRule"))


def test_every_number_field_documents_its_si_unit():
    missing = [f"{cls.__name__}.{f.name}" for cls in _sections() for f in dataclasses.fields(cls)
               if _is_value(cls, f) and not any(t in str(f.type) for t in ("str", "bool", "dict"))
               and f.name != "schedule" and field_unit(cls, f.name) is None]
    assert missing == []
    assert field_unit(scene_module.MonitorSpec, "slip_rate_yellow") == "m/s"
    assert field_unit(scene_module.MonitorSpec, "utilisation_yellow") == "-"
    assert field_unit(scene_module.RockSpec, "mobility") == "m^2/(Pa s)"


@pytest.mark.parametrize("cls", _sections(), ids=lambda c: c.__name__)
def test_docstring_units_agree_with_the_range_table_and_the_unit_parser(cls):
    """A wrong unit in a docstring (e.g. MPa for a modulus, m for an area) fails here."""
    section = {"MeshSpec": "mesh", "FaultSpec": "fault", "RockSpec": "rock", "FluidSpec": "fluid",
               "InitialSpec": "initial", "InjectionSpec": "injection", "TimeSpec": "time",
               "SolverSpec": "solver", "DamageZoneSpec": "damage_zone", "SiteSpec": "site"}.get(cls.__name__)
    for f in dataclasses.fields(cls):
        unit = field_unit(cls, f.name)
        if unit is None:
            continue
        compact = COMPACT.get(unit, unit.replace("^", ""))
        key = f"{section}.{f.name}"
        if key in RANGES:
            assert RANGES[key][0] == compact, key
        q = QUANTITY.get(f.name)
        if q is not None and q != "angle":
            assert SI_UNIT[q].replace("^", "") == compact, f"{cls.__name__}.{f.name}"


def _value_lines(text):
    for line in text.splitlines():
        derived_or_unset = re.match(r"^# \S+ = |^# \S+: not set", line) is not None
        if line and not line.startswith("[") and (derived_or_unset or not line.startswith("#")):
            yield line


@pytest.mark.parametrize("name", ["rustrel-2015-calibrated", "hard-cases/rate-and-state"])
def test_every_line_of_scene_show_names_a_unit(name):
    from click.testing import CliRunner

    from fault_screen.cli import main

    res = CliRunner().invoke(main, ["scene", "show", str(CONFIGS / f"{name}.toml")])
    assert res.exit_code == 0, res.output
    lines = list(_value_lines(res.output))
    assert len(lines) > 100
    for line in lines:
        note = line.rsplit(" # ", 1)[1]
        assert any(note.startswith(f"{unit}, ") for unit in SHOWN), line
    assert any(re.match(r"^slip_rate_yellow = 1e-06 +# m/s, default$", line) for line in lines)
    assert any(re.match(r"^utilisation_yellow = 0.9 +# - \(dimensionless\), default$", line) for line in lines)

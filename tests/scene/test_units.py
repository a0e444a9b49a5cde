import math

import numpy as np
import pytest

from fault_screen.units import UnitError, factor, parse_header, to_si


@pytest.mark.parametrize(
    "unit, quantity, expected",
    [
        ("Pa", "pressure", 1.0),
        ("kPa", "pressure", 1e3),
        ("MPa", "pressure", 1e6),
        ("GPa", "pressure", 1e9),
        ("bar", "pressure", 1e5),
        ("psi", "pressure", 6894.757293168),
        ("m3/s", "flow_rate", 1.0),
        ("L/s", "flow_rate", 1e-3),
        ("L/min", "flow_rate", 1e-3 / 60),
        ("m3/h", "flow_rate", 1 / 3600),
        ("bbl/min", "flow_rate", 0.0026497882488),
        ("m", "length", 1.0),
        ("mm", "length", 1e-3),
        ("um", "length", 1e-6),
        ("km", "length", 1e3),
        ("Pa/m", "stiffness", 1.0),
        ("MPa/m", "stiffness", 1e6),
        ("GPa/m", "stiffness", 1e9),
        ("m2", "permeability", 1.0),
        ("mD", "permeability", 9.869233e-16),
        ("D", "permeability", 9.869233e-13),
        ("s", "time", 1.0),
        ("min", "time", 60.0),
        ("h", "time", 3600.0),
        ("day", "time", 86400.0),
        ("m3", "volume", 1.0),
        ("L", "volume", 1e-3),
        ("bbl", "volume", 0.158987294928),
        ("Pa s", "viscosity", 1.0),
        ("cP", "viscosity", 1e-3),
        ("mPa s", "viscosity", 1e-3),
        ("deg", "angle", math.pi / 180),
        ("rad", "angle", 1.0),
    ],
)
def test_factors(unit, quantity, expected):
    assert factor(unit, quantity) == pytest.approx(expected, rel=1e-12)
    assert factor(unit) == pytest.approx(expected, rel=1e-12)  # unambiguous without quantity


def test_reference_values():
    assert to_si(1.0, "bbl/min") == pytest.approx(0.0026497882488, rel=1e-12)
    assert to_si(1.0, "psi") == pytest.approx(6894.757293168, rel=1e-12)
    assert to_si(1.0, "mD") == pytest.approx(9.869233e-16, rel=1e-12)
    assert to_si(61.0, "L/min") == pytest.approx(61e-3 / 60, rel=1e-14)
    assert to_si(30.0, "deg") == pytest.approx(math.pi / 6)


def test_aliases_and_whitespace():
    for u in ("L/min", "l/min", "lpm", "LPM", " L / min ", "L/min\t"):
        assert factor(u, "flow_rate") == pytest.approx(1e-3 / 60, rel=1e-14)
    assert factor("Pa.s") == factor("Pa·s") == factor("Pa*s") == 1.0
    assert factor("m^3/s") == factor("m³/s") == 1.0
    assert factor("µm") == 1e-6
    assert factor(" MPa ", "stress") == 1e6


def test_case_sensitive():
    assert factor("d", "time") == 86400.0
    assert factor("D", "permeability") == pytest.approx(9.869233e-13)
    assert factor("mPa s") == 1e-3
    with pytest.raises(UnitError):
        factor("mpa", "pressure")  # not guessed as MPa
    with pytest.raises(UnitError):
        factor("mPa", "pressure")  # millipascal is not in the table: refused, not MPa


def test_array_and_scalar_return():
    out = to_si([1.0, 2.0], "MPa")
    assert isinstance(out, np.ndarray) and out.dtype == np.float64
    np.testing.assert_allclose(out, [1e6, 2e6])
    assert isinstance(to_si(3, "bar"), float)
    assert to_si(3, "bar") == 3e5


def test_unit_error_messages():
    with pytest.raises(UnitError) as ei:
        to_si(1.0, "furlong/fortnight", "flow_rate")
    msg = str(ei.value)
    assert "furlong/fortnight" in msg and "L/min" in msg and "bbl/min" in msg
    assert isinstance(ei.value, ValueError)
    with pytest.raises(UnitError) as ei:
        factor("MPa", "flow_rate")
    assert "pressure" in str(ei.value) and "m3/s" in str(ei.value)
    with pytest.raises(UnitError) as ei:
        factor("xyz")
    assert "xyz" in str(ei.value) and "psi" in str(ei.value)
    with pytest.raises(UnitError):
        factor("Pa", "temperature")


def test_parse_header():
    assert parse_header("flow_rate[L/min]") == ("flow_rate", "L/min")
    assert parse_header("pressure [MPa]") == ("pressure", "MPa")
    assert parse_header("  elapsed [ min ] ") == ("elapsed", "min")
    assert parse_header("depth (m)") == ("depth", "m")
    assert parse_header("time") == ("time", None)
    assert parse_header("q[]") == ("q", None)


@pytest.mark.parametrize("unit, quantity, expected", [
    ("gpm", "flow_rate", 3.785411784e-3 / 60),       # US gallon = 231 in^3 = 3.785411784 L
    ("gal/min", "flow_rate", 3.785411784e-3 / 60),
    ("µD", "permeability", 9.869233e-19),
    ("uD", "permeability", 9.869233e-19),
    ("nD", "permeability", 9.869233e-22),
])
def test_field_units_of_issue_13(unit, quantity, expected):
    assert factor(unit, quantity) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("text, value, unit", [
    ("100mD", 100.0, "mD"), ("100 mD", 100.0, "mD"), ("2.5e-3MPa", 2.5e-3, "MPa"),
    ("-4 deg", -4.0, "deg"), (" 7 ", 7.0, None), ("5 µD", 5.0, "µD"),
])
def test_split_value_with_or_without_a_space(text, value, unit):
    from fault_screen.units import split_value

    assert split_value(text) == (value, unit)


def test_split_value_refuses_text_without_a_number():
    from fault_screen.units import split_value

    with pytest.raises(ValueError, match="not a number"):
        split_value("mD 100")


def test_scene_permeability_without_space_and_in_microdarcy():
    from fault_screen import Scene

    assert Scene.from_dict({"rock": {"permeability": "100mD"}}).rock.permeability == \
        pytest.approx(9.869233e-14, rel=1e-12)
    assert Scene.from_dict({"rock": {"permeability": "250 nD"}}).rock.permeability == \
        pytest.approx(250 * 9.869233e-22, rel=1e-12)

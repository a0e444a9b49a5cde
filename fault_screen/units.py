"""Conversion of engineering units to SI.

Every supported unit belongs to one *quantity* (pressure, flow_rate, length,
stiffness, permeability, time, volume, viscosity, angle) and has a
multiplicative factor to the SI unit of that quantity::

    >>> to_si(61.0, "L/min")          # -> m3/s
    0.0010166666666666668
    >>> to_si(2.5, "MPa", "pressure")  # -> Pa
    2500000.0

Unit strings
------------
* Surrounding and inner whitespace is ignored (``" MPa "``, ``"Pa s"``).
* ``^``, ``·``, ``*`` and ``.`` between symbols are ignored, superscript
  digits and the micro sign are normalised (``m^3/s``, ``m³/s``, ``µm``,
  ``Pa·s``, ``Pa.s`` all work).
* Matching is **case-sensitive** (``MPa`` and ``mPa s`` are different units,
  ``D`` is the darcy and ``d`` the day).  The only case-insensitive spellings
  are the explicit aliases listed in the table (e.g. ``l/min``, ``lpm``,
  ``LPM``, ``psi``, ``PSI``, ``md``, ``bpm``) -- there is no generic
  lower-casing, so ``mpa`` is refused rather than guessed.

Temperature is deliberately not supported (it is not multiplicative).
"""

from __future__ import annotations

import math
import re
from typing import Dict, Optional, Tuple

import numpy as np

__all__ = [
    "UnitError",
    "UNITS",
    "SI_UNIT",
    "QUANTITIES",
    "to_si",
    "factor",
    "canonical",
    "quantity_of",
    "accepted_units",
    "parse_header",
    "BARREL_M3",
    "DARCY_M2",
    "PSI_PA",
    "US_GALLON_M3",
    "split_value",
]


class UnitError(ValueError):
    """Unknown unit, unknown quantity, or unit of the wrong quantity."""


#: US oil barrel (42 US gallons) in m3.
BARREL_M3 = 0.158987294928
#: 1 darcy in m2.
DARCY_M2 = 9.869233e-13
#: US liquid gallon (231 cubic inches) in m3.
US_GALLON_M3 = 3.785411784e-3
#: 1 psi (pound-force per square inch) in Pa.
PSI_PA = 6894.757293168361

# quantity -> {canonical unit: (factor to SI, (aliases...))}
# Aliases are written as a user would type them; they are normalised with
# ``_canon`` before lookup, so spacing variants need not be listed.
_TABLE: Dict[str, Dict[str, Tuple[float, Tuple[str, ...]]]] = {
    "pressure": {
        "Pa": (1.0, ()),
        "kPa": (1e3, ()),
        "MPa": (1e6, ()),
        "GPa": (1e9, ()),
        "bar": (1e5, ("bars",)),
        "psi": (PSI_PA, ("PSI", "Psi", "lbf/in2")),
    },
    "flow_rate": {
        "m3/s": (1.0, ("m3s-1",)),
        "m3/min": (1.0 / 60.0, ()),
        "m3/h": (1.0 / 3600.0, ("m3/hr",)),
        "m3/day": (1.0 / 86400.0, ("m3/d",)),
        "L/s": (1e-3, ("l/s", "lps", "LPS")),
        "L/min": (1e-3 / 60.0, ("l/min", "lpm", "LPM", "Lpm")),
        "L/h": (1e-3 / 3600.0, ("l/h",)),
        "bbl/min": (BARREL_M3 / 60.0, ("bpm", "BPM")),
        "bbl/day": (BARREL_M3 / 86400.0, ("bbl/d", "bpd", "BPD")),
        "gpm": (US_GALLON_M3 / 60.0, ("GPM", "gal/min", "USgal/min", "usgpm", "USgpm")),
    },
    "length": {
        "m": (1.0, ()),
        "mm": (1e-3, ()),
        "um": (1e-6, ()),
        "km": (1e3, ()),
    },
    "stiffness": {
        "Pa/m": (1.0, ()),
        "kPa/m": (1e3, ()),
        "MPa/m": (1e6, ()),
        "GPa/m": (1e9, ()),
    },
    "permeability": {
        "m2": (1.0, ()),
        "mD": (DARCY_M2 * 1e-3, ("md", "millidarcy")),
        "D": (DARCY_M2, ("darcy",)),
        # tight rock (shales, granite, salt): micro- and nanodarcy; µ is normalised to u
        "µD": (DARCY_M2 * 1e-6, ("uD", "microdarcy")),
        "nD": (DARCY_M2 * 1e-9, ("nanodarcy",)),
    },
    # mobility k/mu (Darcy flux per pressure gradient); the paper writes it m3 s/kg
    "mobility": {
        "m2/(Pa s)": (1.0, ("m2/Pa/s", "m3 s/kg", "m3/(Pa s)/m")),
        "mD/cP": (DARCY_M2,  # 1e-3 D over 1e-3 Pa s
                ("md/cp", "mD/(mPa s)")),
        "D/cP": (DARCY_M2 / 1e-3, ("darcy/cP",)),
    },
    "time": {
        "s": (1.0, ("sec",)),
        "min": (60.0, ()),
        "h": (3600.0, ("hr",)),
        "day": (86400.0, ("d", "days")),
    },
    "volume": {
        "m3": (1.0, ()),
        "L": (1e-3, ("l",)),
        "bbl": (BARREL_M3, ()),
        "gal": (US_GALLON_M3, ("USgal",)),
    },
    "viscosity": {
        "Pa s": (1.0, ()),
        "mPa s": (1e-3, ()),
        "cP": (1e-3, ("cp", "centipoise")),
        "P": (0.1, ()),
    },
    "angle": {
        "deg": (math.pi / 180.0, ("degree", "degrees")),
        "rad": (1.0, ("radian", "radians")),
    },
}

#: SI unit of each quantity.
SI_UNIT = {
    "pressure": "Pa",
    "flow_rate": "m3/s",
    "length": "m",
    "stiffness": "Pa/m",
    "permeability": "m2",
    "mobility": "m2/(Pa s)",
    "time": "s",
    "volume": "m3",
    "viscosity": "Pa s",
    "angle": "rad",
}

QUANTITIES = tuple(_TABLE)

_QUANTITY_ALIASES = {
    "stress": "pressure",
    "flow": "flow_rate",
    "rate": "flow_rate",
    "flowrate": "flow_rate",
    "distance": "length",
    "stiffness_per_length": "stiffness",
    "duration": "time",
}

_TRANS = str.maketrans({"³": "3", "²": "2", "µ": "u", "μ": "u"})
_DROP = re.compile(r"[\s\^·*]|(?<=[A-Za-z])\.(?=[A-Za-z])")


def _canon(unit: str) -> str:
    return _DROP.sub("", unit.translate(_TRANS))


# (quantity, canonical key) lookup: canon(alias) -> {quantity: (name, factor)}
_LOOKUP: Dict[str, Dict[str, Tuple[str, float]]] = {}
for _q, _units in _TABLE.items():
    for _name, (_f, _aliases) in _units.items():
        for _a in (_name,) + _aliases:
            _LOOKUP.setdefault(_canon(_a), {})[_q] = (_name, _f)

#: quantity -> {canonical unit name: factor}
UNITS = {q: {n: f for n, (f, _) in u.items()} for q, u in _TABLE.items()}


def _norm_quantity(quantity: Optional[str]) -> Optional[str]:
    if quantity is None:
        return None
    q = str(quantity).strip().lower().replace(" ", "_").replace("-", "_")
    q = _QUANTITY_ALIASES.get(q, q)
    if q not in _TABLE:
        raise UnitError(
            f"unknown quantity {quantity!r}; known quantities: {', '.join(QUANTITIES)}"
        )
    return q


def accepted_units(quantity: Optional[str] = None) -> str:
    """Human-readable list of accepted units (for one quantity, or all)."""
    q = _norm_quantity(quantity)
    if q is not None:
        return ", ".join(_TABLE[q])
    return "; ".join(f"{k}: {', '.join(v)}" for k, v in _TABLE.items())


def _resolve(unit: str, quantity: Optional[str]) -> Tuple[str, str, float]:
    """Return (quantity, canonical unit name, factor)."""
    q = _norm_quantity(quantity)
    if not isinstance(unit, str):
        raise UnitError(f"unit must be a string, got {unit!r}")
    hits = _LOOKUP.get(_canon(unit), {})
    if q is not None:
        if q in hits:
            name, f = hits[q]
            return q, name, f
        if hits:
            other = ", ".join(sorted(hits))
            raise UnitError(
                f"unit {unit!r} is a {other} unit, not a {q} unit; "
                f"accepted {q} units: {accepted_units(q)}"
            )
        raise UnitError(
            f"unknown {q} unit {unit!r}; accepted {q} units: {accepted_units(q)}"
        )
    if not hits:
        raise UnitError(f"unknown unit {unit!r}; accepted units: {accepted_units()}")
    if len(hits) > 1:
        raise UnitError(
            f"unit {unit!r} is ambiguous ({', '.join(sorted(hits))}); pass quantity="
        )
    (qq, (name, f)), = hits.items()
    return qq, name, f


def factor(unit: str, quantity: Optional[str] = None) -> float:
    """Multiplicative factor converting a value in ``unit`` to SI.

    ``quantity`` (e.g. ``"pressure"``, ``"flow_rate"``) restricts the lookup
    and gives a clearer error; without it the unit must be unambiguous.
    Raises :class:`UnitError` naming the unit and listing accepted units.
    """
    return _resolve(unit, quantity)[2]


def canonical(unit: str, quantity: Optional[str] = None) -> str:
    """The table's spelling of a unit (``"l/min" -> "L/min"``, ``"uD" -> "µD"``)."""
    return _resolve(unit, quantity)[1]


def quantity_of(unit: str) -> str:
    """Quantity a unit belongs to (raises UnitError if unknown/ambiguous)."""
    return _resolve(unit, None)[0]


def to_si(value, unit: str, quantity: Optional[str] = None):
    """Convert ``value`` (scalar or array-like) from ``unit`` to SI.

    Returns a Python float for scalar input, a float64 ndarray otherwise.
    """
    f = factor(unit, quantity)
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        return float(arr) * f
    return arr * f


def parse_header(name: str) -> Tuple[str, Optional[str]]:
    """Split a column header into ``(base_name, unit or None)``.

    ``"flow_rate[L/min]" -> ("flow_rate", "L/min")``,
    ``"pressure [MPa]" -> ("pressure", "MPa")``,
    ``"depth (m)" -> ("depth", "m")``, ``"time" -> ("time", None)``.
    The unit is returned as written (stripped), not validated.  The unit is what the last
    bracket pair holds: from the first opening bracket after any earlier closing one.  A scan,
    not a regular expression: time linear in the header's length whatever it holds.
    """
    s = str(name).strip()
    if not s or s[-1] not in "])":
        return s, None
    opening = "[" if s[-1] == "]" else "("
    body = s[:-1]
    start = body.rfind(s[-1]) + 1          # after the last closing bracket before the end
    k = body.find(opening, start)
    if k < 0 or "\n" in body[:k].rstrip():
        return s, None
    unit = body[k + 1:].strip()
    return body[:k].strip(), (unit if unit else None)


_VALUE = re.compile(r"^\s*([+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?)\s*(.*?)\s*$")


def split_value(text: str) -> Tuple[float, Optional[str]]:
    """``"100 mD" -> (100.0, "mD")``, ``"100mD" -> (100.0, "mD")``, ``"2.5e-3" -> (0.0025, None)``.

    The space between number and unit is optional, as people write it both ways.
    Raises ValueError when the text does not start with a number.
    """
    m = _VALUE.match(str(text))
    if m is None:
        raise ValueError(f"not a number with an optional unit: {text!r}")
    return float(m.group(1)), (m.group(2) or None)

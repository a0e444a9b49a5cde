"""Injection-rate logs as operators export them.

File format
-----------
A text table with one header line; lines whose first non-blank character
is ``#`` and blank lines are ignored everywhere (comments).  The dialect is
detected and reported in ``InjectionLog.summary``:

* encoding: UTF-8 (with or without BOM), UTF-16 with BOM, else Latin-1
  (Windows-1252); a binary file (NUL bytes, control characters: a
  spreadsheet, a PDF) is refused with the file name;
* separator: the most frequent of comma, semicolon, tab and ``|`` in the
  header line (blank-aligned columns if none); with a separator other than
  a comma, decimal commas (``12,5``) are read as decimal points;
* units: in the header, in brackets or parentheses (``flow_rate[L/min]``,
  ``WHP (bar)``), or in a second header row holding only units
  (``;l/min;bar``), or from ``flow_unit=``/``pressure_unit=``.

Columns are matched on the header without its unit, case and accents
(``Débit`` -> ``debit``), or named with ``time_column=``,
``flow_column=``, ``pressure_column=`` (header or 1-based position):

* time: ``time``, ``elapsed``, ``timestamp``, ``datetime``, ``zeit``,
  ``heure``..., holding one of
  - elapsed numbers, seconds unless a unit is given (``elapsed[min]``);
  - elapsed ``hh:mm:ss`` in a column named ``elapsed...``/``duration...``;
  - date-times: ISO 8601 (``2015-03-12T10:00:05+01:00``, ``...Z``,
    ``2015-03-12 10:00:05``) or ``12.03.2015 10:00:05``; without an
    offset they are local times of the zone ``tz=`` (zoneinfo), and
    refused without it: the instant is unknown;
  - times of day (``08:50:05``) with a ``date`` column, or with ``date=``
    for the first row: a time going back by more than 12 h is the next day
    (midnight roll-over, a warning); ``tz=`` is required.
* flow rate: ``flow_rate``, ``flowrate``, ``flow``, ``rate``, ``q``,
  ``q_inj``, ``debit``, ``durchfluss``...
* pressure (optional): ``pressure``, ``p``, ``whp``, ``p_inj``, ``druck``,
  ``pression``...
Other columns are ignored.  Units are resolved with
:mod:`fault_screen.units`; a unit in the file and a conflicting argument, or
no unit at all, is an error naming the column and the argument.  Rates
above 10 m3/s and pressures outside -1 to 1000 MPa are refused as bad
cells with the plausible range in the column's unit (a unit mix-up).
A last row with a stamp but all value cells empty (loggers write one when
they stop) is dropped with a warning, under every policy.

Interpolation
-------------
Samples may be irregular.  Between two samples the rate varies linearly;
before the first and after the last sample the rate is 0.  Volumes are the
exact integral of that piecewise-linear rate (trapezoidal rule on the
samples, plus the exact partial trapezoid inside a segment).

Problems and policies
---------------------
Detected problems (checked per row in this order): unparseable/empty time
cell, time going backwards, duplicate time stamp, non-numeric/empty/non-
finite or negative flow rate, non-numeric/empty/non-finite pressure, gap
longer than ``max_gap`` seconds since the last kept sample; after reading:
fewer than two usable rows.  Each raises :class:`InjectionLogError`
(``.line`` = 1-based line in the file, ``.column`` = the column header as
written, or None) unless the policy says otherwise:

``"stop"`` (default)
    raise at the first problem.
``"skip"``
    drop the offending row.  A *gap* is not in one row (dropping the row
    after it would only widen it), so under ``skip`` the row after the gap
    is kept and the gap is bridged by the usual linear interpolation.
``"hold"``
    a bad flow/pressure value is replaced by the last good value of that
    column (if there is none yet, the row is dropped).  Time problems
    (bad/backwards/duplicate stamps) cannot be held: the row is dropped.
    For a gap ``t_prev -> t_next`` the last rate (and pressure) is held
    constant: a sample ``(t_next - HOLD_EPS, q_prev, p_prev)`` is inserted,
    ``HOLD_EPS = 1e-6`` s, so the rate is ``q_prev`` on
    ``[t_prev, t_next - 1e-6]`` and ramps linearly to ``q_next`` during the
    last microsecond (volume error <= 0.5e-6 s * |q_next - q_prev|).

Every skip/hold is recorded in ``InjectionLog.warnings`` with the file name,
line and column -- nothing is changed silently.

Step schedules
--------------
:meth:`InjectionLog.from_steps` turns a piecewise-constant schedule into the
same piecewise-linear representation: each rate change at ``t_i`` becomes a
ramp from ``(t_i - eps, q_{i-1})`` to ``(t_i, q_i)`` with
``eps = max(1e-9 s, 64 ulp(t_i))`` (see :data:`STEP_RAMP`), so
``rate_at(t_i) == q_i`` as for ``[t_i, t_{i+1})`` steps and every volume
differs from the exact step integral by at most ``eps/2 * |q_i - q_{i-1}|``
per rate change (1e-9 s * rate: far below 1e-9 relative for steps of a
second or more).  The arrays ``time``/``flow_rate`` therefore always mean
"piecewise linear", whichever constructor was used.
"""

from __future__ import annotations

import csv
import math
import os
import re
import unicodedata
from dataclasses import dataclass, field, replace
from datetime import date, datetime, timedelta, timezone, tzinfo
from typing import List, Optional, Sequence, Tuple
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

import numpy as np

from fault_screen import units as _units

__all__ = [
    "InjectionLog",
    "InjectionLogError",
    "read_injection_log",
    "HOLD_EPS",
    "STEP_RAMP",
    "POLICIES",
    "FLOW_RATE_RANGE",
    "PRESSURE_RANGE",
    "CLI_OPTION_NAMES",
]

#: Width (s) of the ramp closing a held gap (policy "hold").
HOLD_EPS = 1e-6
#: Minimum width (s) of the ramp representing a rate step (from_steps).
STEP_RAMP = 1e-9
POLICIES = ("stop", "skip", "hold")



class InjectionLogError(ValueError):
    """A problem in an injection log, located by ``line`` and ``column``.

    ``line`` is the 1-based line number in the file (None if not tied to a
    line), ``column`` the column header as written (None if not tied to a
    column), ``source`` the file name and ``problem`` the bare description.
    """

    def __init__(self, source: str, line: Optional[int], column: Optional[str], problem: str):
        self.source = source
        self.line = line
        self.column = column
        self.problem = problem
        super().__init__(_where(source, line, column) + problem)


def _where(source: str, line: Optional[int], column: Optional[str]) -> str:
    s = os.path.basename(str(source)) or str(source)
    if line is not None:
        s += f" line {line}"
    if column is not None:
        s += f", column {column}"
    return s + ": "


# ---------------------------------------------------------------------------
# The log object
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class InjectionLog:
    """A flow-rate history, piecewise linear between samples, 0 outside.

    Attributes
    ----------
    time : float64 array, s since the first stamp, strictly increasing
    flow_rate : float64 array, m3/s, >= 0
    pressure : float64 array in Pa, or None
    start : timezone-aware datetime of ``time == 0`` (None for elapsed logs)
    source : where the log came from (path as str)
    warnings : tuple of str, every skip/hold/drop applied while reading
    flow_unit, pressure_unit : the units the file was written in (for figures and reports;
        the arrays are SI whatever they are)
    summary : one line saying what the reader detected (dialect, columns, units)
    """

    time: np.ndarray
    flow_rate: np.ndarray
    pressure: Optional[np.ndarray] = None
    start: Optional[datetime] = None
    source: str = ""
    warnings: Tuple[str, ...] = ()
    flow_unit: str = "m3/s"
    pressure_unit: Optional[str] = None
    summary: str = ""
    flowback: bool = False
    """Negative rates (fluid flowing back out) are allowed (a scene's injection.allow_flowback)."""
    _cum: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        t = np.array(self.time, dtype=np.float64).reshape(-1)
        q = np.array(self.flow_rate, dtype=np.float64).reshape(-1)
        if t.size < 2:
            raise ValueError("an InjectionLog needs at least two samples")
        if q.shape != t.shape:
            raise ValueError(f"time has {t.size} samples but flow_rate has {q.size}")
        if not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)):
            raise ValueError("time must be finite and strictly increasing")
        if not np.all(np.isfinite(q)) or (not self.flowback and np.any(q < 0)):
            raise ValueError("flow_rate must be finite and >= 0 (negative only with flowback)")
        p = None
        if self.pressure is not None:
            p = np.array(self.pressure, dtype=np.float64).reshape(-1)
            if p.shape != t.shape:
                raise ValueError(f"time has {t.size} samples but pressure has {p.size}")
            if not np.all(np.isfinite(p)):
                raise ValueError("pressure must be finite")
            p.setflags(write=False)
        if self.start is not None:
            if not isinstance(self.start, datetime) or self.start.utcoffset() is None:
                raise ValueError("start must be a timezone-aware datetime")
        cum = np.concatenate(([0.0], np.cumsum(0.5 * (q[1:] + q[:-1]) * np.diff(t))))
        for a in (t, q, cum):
            a.setflags(write=False)
        object.__setattr__(self, "time", t)
        object.__setattr__(self, "flow_rate", q)
        object.__setattr__(self, "pressure", p)
        object.__setattr__(self, "source", str(self.source))
        object.__setattr__(self, "warnings", tuple(str(w) for w in self.warnings))
        object.__setattr__(self, "_cum", cum)

    # -- constructors -------------------------------------------------------

    @classmethod
    def from_steps(cls, times_s: Sequence[float], rates_m3s: Sequence[float], *,
                   source: str = "<steps>") -> "InjectionLog":
        """Piecewise-constant schedule: ``rates[i]`` holds on ``[t[i], t[i+1])``.

        Either ``len(times) == len(rates) + 1`` (the last time ends the last
        step; the rate is 0 afterwards), or ``len(times) == len(rates)`` with
        ``rates[-1] == 0`` (a final shut-in at ``times[-1]``; a non-zero final
        rate would have an unknown duration and is refused).  Times are kept
        as given (not shifted to start at 0).  Representation: see the module
        docstring (ramps of ``max(1e-9 s, 64 ulp)`` ending at each change).
        """
        t = np.asarray(times_s, dtype=np.float64).reshape(-1)
        r = np.asarray(rates_m3s, dtype=np.float64).reshape(-1)
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(r))):
            raise ValueError("times and rates must be finite")
        if np.any(r < 0):
            raise ValueError("rates must be >= 0")
        if t.size < 2 or np.any(np.diff(t) <= 0):
            raise ValueError("need at least two strictly increasing times")
        if t.size == r.size + 1:
            bounds, rates = t, r
            end_rate = r[-1]          # value of the last step up to t[-1]
        elif t.size == r.size:
            if r[-1] != 0:
                raise ValueError(
                    "len(times) == len(rates) but the last rate is not 0: its duration "
                    "is unknown; pass an end time (len(times) == len(rates) + 1)")
            bounds, rates = t, r[:-1]
            end_rate = 0.0
        else:
            raise ValueError(
                f"need len(times) == len(rates) + 1 or == len(rates); got {t.size} and {r.size}")
        ts: List[float] = [bounds[0]]
        qs: List[float] = [rates[0]]
        for i in range(1, bounds.size):
            ti = bounds[i]
            new = rates[i] if i < rates.size else end_rate
            eps = max(STEP_RAMP, 64.0 * float(np.spacing(abs(ti))))
            if ti - eps <= ts[-1] + eps:
                raise ValueError(f"step starting at t={bounds[i - 1]!r} s is too short")
            if new != qs[-1]:
                ts.append(ti - eps)
                qs.append(qs[-1])
            ts.append(ti)
            qs.append(new)
        return cls(np.array(ts), np.array(qs), None, None, source, ())

    # -- evaluation -----------------------------------------------------------

    def rate_at(self, t):
        """Flow rate (m3/s) at time(s) ``t`` (s); 0 outside the log."""
        ta = np.asarray(t, dtype=np.float64)
        out = np.interp(ta, self.time, self.flow_rate, left=0.0, right=0.0)
        return float(out) if out.ndim == 0 else out

    def _cumulative(self, t) -> np.ndarray:
        """Exact volume injected from -inf up to ``t`` (array)."""
        ta = np.asarray(t, dtype=np.float64)
        tt, qq, cum = self.time, self.flow_rate, self._cum
        i = np.clip(np.searchsorted(tt, ta, side="right") - 1, 0, tt.size - 2)
        tc = np.clip(ta, tt[0], tt[-1])
        dt = tc - tt[i]
        slope = (qq[i + 1] - qq[i]) / (tt[i + 1] - tt[i])
        inside = cum[i] + dt * (qq[i] + 0.5 * slope * dt)
        return np.where(ta >= tt[-1], cum[-1], inside)

    def volume(self, t0: float = -math.inf, t1: float = math.inf) -> float:
        """Exact integral (m3) of the rate from ``t0`` to ``t1`` (s).

        The rate is 0 outside the log; ``t1 < t0`` gives the negative of
        ``volume(t1, t0)`` (signed integral).
        """
        v = self._cumulative(np.array([t0, t1], dtype=np.float64))
        return float(v[1] - v[0])

    def step_volumes(self, times) -> np.ndarray:
        """Volumes (m3) injected between consecutive entries of ``times``.

        ``times`` must be non-decreasing; returns an array of ``len(times)-1``.
        """
        ta = np.asarray(times, dtype=np.float64).reshape(-1)
        if np.any(np.isnan(ta)):
            raise ValueError("times contain NaN")
        if np.any(np.diff(ta) < 0):
            raise ValueError("times must be non-decreasing")
        return np.diff(self._cumulative(ta))

    @property
    def total_volume(self) -> float:
        """Total injected volume (m3) (a property, not a method)."""
        return float(self._cum[-1])

    @property
    def duration(self) -> float:
        """Time span of the log (s)."""
        return float(self.time[-1] - self.time[0])

    # -- output ---------------------------------------------------------------

    def to_csv(self, path) -> None:
        """Write the log in a form :func:`read_injection_log` reads back.

        ISO 8601 timestamps (zone of ``start``, microsecond resolution) when
        ``start`` is known, else ``elapsed[s]``; ``flow_rate[m3/s]`` and
        ``pressure[Pa]`` with full float precision; source and warnings as
        ``#`` comments.  Note: a log with held gaps or long steps has
        intervals longer than the default ``max_gap``; read it back with
        ``max_gap=None``.
        """
        cols = ["time" if self.start is not None else "elapsed[s]", "flow_rate[m3/s]"]
        if self.pressure is not None:
            cols.append("pressure[Pa]")
        with open(path, "w", newline="", encoding="utf-8") as fh:
            fh.write("# injection log written by fault_screen.io.injection_log\n")
            fh.write(f"# source: {self.source}\n")
            for w in self.warnings:
                fh.write("# warning: " + w.replace("\n", " ") + "\n")
            wr = csv.writer(fh, lineterminator="\n")
            wr.writerow(cols)
            for k in range(self.time.size):
                t = float(self.time[k])
                if self.start is not None:
                    tcell = (self.start + timedelta(seconds=t)).isoformat()
                else:
                    tcell = repr(t)
                row = [tcell, repr(float(self.flow_rate[k]))]
                if self.pressure is not None:
                    row.append(repr(float(self.pressure[k])))
                wr.writerow(row)


# ---------------------------------------------------------------------------
# Reader
# ---------------------------------------------------------------------------

#: Largest flow rate (m3/s) taken as a measurement: 10 m3/s is ten times the largest
#: hydraulic-fracturing spreads; anything above is a unit mix-up or a logger fault.
FLOW_RATE_RANGE = (0.0, 10.0)
#: Plausible injection pressures (Pa): a gauge reads a little below zero at worst, and
#: no well or laboratory cell holds 1 GPa.
PRESSURE_RANGE = (-1.0e6, 1.0e9)

#: Names the reader's keywords are given in messages; the CLI passes its option names.
KEYWORD_NAMES = {k: k + "=" for k in ("flow_unit", "pressure_unit", "max_gap", "date", "tz",
                                      "time_column", "flow_column", "pressure_column")}
#: The same names on the command line.
CLI_OPTION_NAMES = {k: "--" + k.replace("_", "-") for k in KEYWORD_NAMES}

# Column names, compared after _norm (lower case, accents dropped, non-alphanumerics -> "_").
_TIME_EXACT = ("time", "elapsed", "timestamp", "datetime", "date_time", "time_of_day", "clock",
               "zeit", "uhrzeit", "heure", "temps", "t")
_TIME_PREFIXES = ("time", "elapsed", "timestamp", "datetime", "date_time", "zeit", "uhrzeit")
_ELAPSED_PREFIXES = ("elapsed", "duration", "runtime", "run_time", "dauer", "t_")
_DATE_EXACT = ("date", "datum", "day")
_FLOW_EXACT = ("flow_rate", "flowrate", "flow", "rate", "q", "q_inj", "qinj", "injection_rate",
               "pump_rate", "debit", "durchfluss", "durchflussrate")
_FLOW_PREFIXES = ("flow", "q_", "rate", "injection_rate", "pump_rate", "debit", "durchfluss")
_PRESSURE_EXACT = ("pressure", "p", "p_inj", "pinj", "whp", "bhp", "injection_pressure",
                   "wellhead_pressure", "druck", "pression")
_PRESSURE_PREFIXES = ("pressure", "p_", "whp", "bhp", "druck", "pression")

_DELIMITERS = {",": "comma", ";": "semicolon", "\t": "tab", "|": "pipe"}
_CLOCK = re.compile(r"^(\d{1,3}):([0-5]\d)(?::([0-5]\d(?:[.,]\d*)?))?$")
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$")
_DATE_FORMATS = ("%Y-%m-%d", "%d.%m.%Y", "%Y/%m/%d", "%d.%m.%y")
_STAMP_FORMATS = ("%d.%m.%Y %H:%M:%S", "%d.%m.%Y %H:%M", "%Y/%m/%d %H:%M:%S", "%Y/%m/%d %H:%M",
                  "%d.%m.%Y %H:%M:%S.%f", "%Y/%m/%d %H:%M:%S.%f")
_BINARY_SIGNS = {b"PK\x03\x04": " (a zip archive or an Excel .xlsx workbook? export it as CSV)",
                 b"\xd0\xcf\x11\xe0": " (an Excel .xls workbook? export it as CSV)",
                 b"%PDF": " (a PDF document)",
                 b"\x89HDF": " (an HDF5 file)"}


def _arg(name: str, value: str) -> str:
    """``flow_unit='gpm'`` for a keyword, ``--flow-unit 'gpm'`` for an option."""
    return f"{name}{value}" if name.endswith("=") else f"{name} {value}"


def _norm(name: str) -> str:
    """Column name as compared: ``"Débit (l/min)" -> "debit"`` once the unit is split off."""
    flat = unicodedata.normalize("NFKD", str(name))
    flat = "".join(c for c in flat if not unicodedata.combining(c)).lower()
    return re.sub(r"[^0-9a-z]+", "_", flat).strip("_")


def _decode(raw: bytes, src: str) -> Tuple[str, str]:
    """(text, encoding name) of a log's bytes; a clear error for anything but text."""
    if not raw.strip():
        raise InjectionLogError(src, None, None, "the file is empty")
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return raw.decode("utf-16"), "UTF-16"
        except UnicodeDecodeError:
            pass
    if b"\x00" in raw[:65536]:
        sign = next((why for magic, why in _BINARY_SIGNS.items() if raw.startswith(magic)), "")
        raise InjectionLogError(
            src, None, None,
            f"not a text file{sign}: an injection log is a CSV text file (time, flow rate, "
            f"optional pressure)")
    try:
        text, enc = raw.decode("utf-8-sig"), "UTF-8"
    except UnicodeDecodeError:
        # Windows loggers write cp1252 ("Latin-1"); its few undefined bytes fall back to ISO 8859-1
        try:
            text, enc = raw.decode("cp1252"), "Latin-1 (Windows-1252)"
        except UnicodeDecodeError:
            text, enc = raw.decode("latin-1"), "Latin-1 (ISO 8859-1)"
    control = sum(1 for c in text[:65536] if (ord(c) < 32 and c not in "\t\r\n\f\v") or c == "\x7f")
    if control > max(2, 0.01 * min(len(text), 65536)):
        raise InjectionLogError(
            src, None, None,
            f"not a text file ({control} control characters; binary data or an unknown "
            f"encoding): an injection log is a CSV text file")
    return text, enc


def _delimiter(header: str, sample: Sequence[str]) -> str:
    """The separator: the candidate most frequent in the header line (which has no decimal
    commas), ties broken by how consistently it appears in the first data lines."""
    best, best_key = ",", (0, 0)
    for d in _DELIMITERS:
        n = header.count(d)
        if n == 0:
            continue
        steady = sum(1 for line in sample if line.count(d) >= n)
        if (n, steady) > best_key:
            best, best_key = d, (n, steady)
    if best_key[0] == 0 and len(header.split()) > 1 and all(len(s.split()) > 1 for s in sample):
        return " "           # columns aligned with blanks
    return best


def _split(text: str, delim: str) -> List[str]:
    if delim == " ":
        return text.split()
    return [c.strip() for c in next(csv.reader([text], delimiter=delim))]


def _unit_for(src, line, col_raw, header_unit, arg_unit, quantity, argname):
    """(factor to SI, canonical unit name)."""
    if header_unit is not None and arg_unit is not None:
        try:
            same = _units.factor(header_unit, quantity) == _units.factor(arg_unit, quantity)
        except _units.UnitError as e:
            raise InjectionLogError(src, line, col_raw, str(e)) from None
        if not same:
            raise InjectionLogError(
                src, line, col_raw,
                f"the file's unit {header_unit!r} conflicts with {_arg(argname, repr(arg_unit))}")
    unit = header_unit if header_unit is not None else arg_unit
    if unit is None:
        raise InjectionLogError(
            src, line, col_raw,
            f"column needs a unit: write it in the header (e.g. '{col_raw}[...]' or "
            f"'{col_raw} (...)') or pass {argname}; accepted {quantity} units: "
            f"{_units.accepted_units(quantity)}")
    try:
        return _units.factor(unit, quantity), _units.canonical(unit, quantity)
    except _units.UnitError as e:
        raise InjectionLogError(src, line, col_raw, str(e)) from None


def _same_unit(a: str, b: str) -> bool:
    if a == b:
        return True
    try:
        return _units.factor(a) == _units.factor(b)
    except _units.UnitError:
        return False


def _bare_unit(cell: str) -> Optional[str]:
    """A unit cell of a units row: ``"[l/min]"``, ``"(bar)"`` or ``"l/min"``."""
    c = cell.strip()
    if len(c) >= 2 and c[0] + c[-1] in ("[]", "()"):
        c = c[1:-1].strip()
    return c or None


class _Numbers:
    """Reads numeric cells; decimal commas are accepted when the separator is not a comma."""

    def __init__(self, delim: str):
        self.comma_ok = delim != ","
        self.comma_seen = False

    def __call__(self, cell: str):
        """(value, problem)."""
        if cell == "":
            return None, "empty cell"
        txt = cell
        if self.comma_ok and _DECIMAL_COMMA.match(cell):
            txt = cell.replace(",", ".")
            self.comma_seen = True
        try:
            v = float(txt)
        except ValueError:
            return None, f"non-numeric value {cell!r}"
        if not math.isfinite(v):
            return None, f"non-finite value {cell!r}"
        return v, None

    def ok(self, cell: str) -> bool:
        return self(cell)[0] is not None


def _clock_seconds(cell: str) -> Optional[float]:
    """Seconds of ``h:mm:ss(.f)`` / ``h:mm`` (hours may exceed 24), else None."""
    m = _CLOCK.match(cell)
    if m is None:
        return None
    sec = float(m.group(3).replace(",", ".")) if m.group(3) else 0.0
    return int(m.group(1)) * 3600.0 + int(m.group(2)) * 60.0 + sec


def _parse_date(cell: str) -> Optional[date]:
    for fmt in _DATE_FORMATS:
        try:
            return datetime.strptime(cell.strip(), fmt).date()
        except ValueError:
            pass
    return None


def _parse_stamp(cell: str) -> Optional[datetime]:
    """An ISO 8601 date-time (``Z`` accepted), or ``dd.mm.yyyy hh:mm[:ss]``; None if neither."""
    txt = cell.strip()
    if txt[-1:] in ("Z", "z"):
        txt = txt[:-1] + "+00:00"
    try:
        dt = datetime.fromisoformat(txt)
    except ValueError:
        dt = None
        for fmt in _STAMP_FORMATS:
            try:
                dt = datetime.strptime(txt, fmt)
                break
            except ValueError:
                pass
    if dt is None or (len(txt) <= 10 and ":" not in txt):
        return None          # a bare date is not an instant
    return dt


def _zone(tz, src, name):
    if tz is None or isinstance(tz, tzinfo):
        return tz
    try:
        return ZoneInfo(str(tz))
    except (ZoneInfoNotFoundError, ValueError):
        raise InjectionLogError(src, None, None,
                                f"{_arg(name, repr(tz))}: unknown time zone (use an IANA name such as "
                                f"Europe/Zurich, America/Denver or UTC)") from None


def _as_date(value, src, name) -> Optional[date]:
    if value is None or (isinstance(value, date) and not isinstance(value, datetime)):
        return value
    d = _parse_date(str(value))
    if d is None:
        raise InjectionLogError(src, None, None, f"{_arg(name, repr(value))}: not a date (YYYY-MM-DD)")
    return d


@dataclass
class _Table:
    """A log's text split into cells, before any cell is interpreted."""

    src: str
    encoding: str
    delim: str
    hline: int                                    # line of the header
    header: List[str]
    cols: List[Tuple[str, Optional[str], str]]    # (normalised name, unit or None, as written)
    rows: List[Tuple[int, List[str]]]             # (line, cells) of the data rows
    units_line: Optional[int] = None              # line of a second header row of units

    @classmethod
    def read(cls, path, src: str) -> "_Table":
        with open(path, "rb") as fh:
            text, encoding = _decode(fh.read(), src)
        lines = [(n, t) for n, t in enumerate(text.splitlines(), start=1)
                 if t.strip() and not t.strip().startswith("#")]
        if not lines:
            raise InjectionLogError(src, max(1, text.count("\n")), None,
                                    "no header line and no data")
        hline, htext = lines[0]
        delim = _delimiter(htext, [t for _, t in lines[1:6]])
        header = _split(htext, delim)
        cols = []
        for h in header:
            base, unit = _units.parse_header(h)
            cols.append((_norm(base), unit, h))
        return cls(src, encoding, delim, hline, header, cols,
                   [(n, _split(t, delim)) for n, t in lines[1:]])

    def error(self, line, column, text) -> InjectionLogError:
        return InjectionLogError(self.src, line, column, text)

    def named(self, spec, option) -> int:
        """Index of the column the user named (header as written or without its unit, or a
        1-based position)."""
        txt = str(spec).strip()
        if txt.isdigit():
            k = int(txt)
            if not 1 <= k <= len(self.header):
                raise self.error(self.hline, None, f"{_arg(option, repr(txt))}: the header has "
                                 f"{len(self.header)} columns ({', '.join(self.header)})")
            return k - 1
        for i, (b, _, h) in enumerate(self.cols):
            if txt.lower() in (h.lower(), _units.parse_header(h)[0].strip().lower()) or _norm(txt) == b:
                return i
        raise self.error(self.hline, None, f"{_arg(option, repr(txt))}: no such column; columns: "
                         f"{', '.join(self.header)}")

    def detected(self, kind, exact, prefixes, option, required, exclude=()) -> Optional[int]:
        """Index of the one column whose name is one of ``exact`` (else starts with one of
        ``prefixes``); several candidates or none (when required) are errors naming ``option``."""
        hits = [i for i, (b, _, _) in enumerate(self.cols) if b in exact and i not in exclude]
        if not hits:
            hits = [i for i, (b, _, _) in enumerate(self.cols)
                    if b.startswith(prefixes) and i not in exclude]
        if len(hits) > 1:
            raise self.error(self.hline, None, f"several {kind} columns "
                             f"({', '.join(self.cols[i][2] for i in hits)}): choose one with {option}")
        if not hits and required:
            raise self.error(self.hline, None,
                             f"no {kind} column in header {self.header!r} (expected one of: "
                             f"{', '.join(exact[:6] + tuple(p + '...' for p in prefixes[:3]))}; "
                             f"or name it with {option})")
        return hits[0] if hits else None

    def take_units_row(self, num: "_Numbers", iq: int) -> List[Optional[str]]:
        """Units of a second header row (removed from the rows), or [] if there is none: the
        flow column's cell of the first row is a flow-rate unit, not a number."""
        if not self.rows:
            return []
        n1, r1 = self.rows[0]
        cell = _bare_unit(r1[iq]) if iq < len(r1) else None
        if cell is None or num.ok(r1[iq]):
            return []
        try:
            _units.factor(cell, "flow_rate")
        except _units.UnitError:
            return []
        self.units_line = n1
        self.rows = self.rows[1:]
        return [_bare_unit(c) for c in r1] + [None] * (len(self.header) - len(r1))

    def drop_partial_last_row(self, value_columns) -> Optional[str]:
        """Drop a last row with a stamp but no values (a logger stopping); the warning, or None."""
        if len(self.rows) < 2:
            return None
        line, cells = self.rows[-1]
        if any(i < len(cells) and cells[i] != "" for i in value_columns):
            return None
        self.rows = self.rows[:-1]
        return (_where(self.src, line, None) + "last row has a time stamp but no values "
                "(a partial row written when the logger stopped); dropped")


#: time-column cells of a units row that describe a format, not a unit
_TIME_FORMAT_HINTS = ("hh_mm_ss", "hh_mm", "iso", "iso_8601", "utc", "local", "date_time",
                      "datetime", "yyyy_mm_dd_hh_mm_ss")


class _Clock:
    """Reads a log's time cells as seconds since its first stamp, in one of five modes:
    ``elapsed`` numbers, ``elapsed_clock`` (hh:mm:ss), ``stamp`` (date-times), ``time_of_day``
    (with the ``date`` argument; midnight roll-overs) and ``date_column`` (times of day with a
    date column)."""

    def __init__(self, table: _Table, it: int, idate: Optional[int], t_unit: Optional[str],
                 num: "_Numbers", day0: Optional[date], zone, names: dict, warnings: List[str]):
        self.table, self.it, self.idate, self.num = table, it, idate, num
        self.day0, self.zone, self.names, self.warnings = day0, zone, names, warnings
        self.col = table.cols[it][2]
        self.t_unit, self.factor = t_unit, 1.0
        self.t_ref = None        # first instant read (UTC): differences are taken from it
        self.day_shift = 0       # days added after midnight roll-overs
        self.rollovers = 0
        first = next(((n, c[it]) for n, c in table.rows if it < len(c) and c[it] != ""), None)
        if t_unit is not None:
            try:
                self.factor = _units.factor(t_unit, "time")
            except _units.UnitError as e:
                raise table.error(table.units_line or table.hline, self.col, str(e)) from None
            self.mode = "elapsed"
        elif first is None or num.ok(first[1]):
            self.mode = "elapsed"
        elif _clock_seconds(first[1]) is not None:
            if table.cols[it][0].startswith(_ELAPSED_PREFIXES):
                self.mode = "elapsed_clock"
            else:
                self.mode = "date_column" if idate is not None else "time_of_day"
        else:
            self.mode = "stamp"
        if self.mode == "time_of_day" and day0 is None:
            raise table.error(first[0], self.col,
                              f"time of day {first[1]!r} without a date: pass {_arg(names['date'], 'YYYY-MM-DD')} "
                              f"(the day of the first row) and {_arg(names['tz'], 'ZONE')}")
        if self.mode in ("time_of_day", "date_column") and zone is None:
            raise table.error(first[0], self.col,
                              f"local times of day {first[1]!r}: the time zone is unknown; pass "
                              f"{_arg(names['tz'], 'ZONE')} (e.g. Europe/Zurich, or UTC)")

    @property
    def is_clock(self) -> bool:
        return self.mode in ("stamp", "time_of_day", "date_column")

    def seconds(self, line: int, cells: List[str], last: Optional[float]):
        """(seconds or None, problem or None, aware datetime or None) of a row; ``last`` is the
        last kept time (s), which tells a midnight roll-over."""
        cell = cells[self.it]
        if cell == "":
            return None, "empty cell", None
        if self.mode == "elapsed":
            v, why = self.num(cell)
            return (None if v is None else v * self.factor), why, None
        if self.mode == "elapsed_clock":
            sec = _clock_seconds(cell)
            if sec is None:
                return None, f"not an elapsed time {cell!r} (hh:mm:ss)", None
            if cell.count(":") != 2:
                return None, f"elapsed time {cell!r} is ambiguous (mm:ss or hh:mm): write hh:mm:ss", None
            return sec, None, None
        dt, why = self._instant(line, cell, cells, last)
        if dt is None:
            return None, why, None
        # differences in UTC: aware datetimes of one zone subtract as wall clocks
        utc = dt.astimezone(timezone.utc)
        if self.t_ref is None:
            self.t_ref = utc
        return (utc - self.t_ref).total_seconds(), None, dt

    def _instant(self, line, cell, cells, last):
        if self.mode == "stamp":
            dt = _parse_stamp(cell)
            if dt is None:
                return None, f"not a date-time {cell!r} (ISO 8601, e.g. 2015-03-12T10:00:00+01:00)"
            if dt.utcoffset() is None:
                if self.zone is None:
                    # never held/skipped: the instant itself is unknown
                    raise self.table.error(
                        line, self.col, f"timestamp without time zone {cell!r} (add an offset such "
                        f"as +01:00 or Z, or give the zone with {_arg(self.names['tz'], 'ZONE')})")
                dt = dt.replace(tzinfo=self.zone)
            return dt, None
        sec = _clock_seconds(cell)
        if sec is None or sec >= 86400.0:
            return None, f"not a time of day {cell!r} (hh:mm:ss)"
        if self.mode == "date_column":
            dcell = cells[self.idate]
            d = _parse_date(dcell)
            if d is None:
                return None, (f"not a date {dcell!r} in column {self.table.cols[self.idate][2]} "
                              f"(YYYY-MM-DD)")
            return datetime.combine(d, datetime.min.time(), self.zone) + timedelta(seconds=sec), None
        day = self.day0 + timedelta(days=self.day_shift)
        dt = datetime.combine(day, datetime.min.time(), self.zone) + timedelta(seconds=sec)
        if last is not None and self.t_ref is not None and \
                (dt.astimezone(timezone.utc) - self.t_ref).total_seconds() < last - 43200.0:
            # back by more than half a day: the clock passed midnight
            self.day_shift += 1
            self.rollovers += 1
            dt += timedelta(days=1)
            self.warnings.append(_where(self.table.src, line, self.col) +
                                 f"time of day went back from the previous row to {cell}: taken "
                                 f"as the next day, {(day + timedelta(days=1)).isoformat()} "
                                 f"(midnight roll-over)")
        return dt, None

    def describe(self) -> str:
        if self.mode == "elapsed":
            return f"elapsed {_units.canonical(self.t_unit, 'time') if self.t_unit else 's'}"
        if self.mode == "elapsed_clock":
            return "elapsed hh:mm:ss"
        if self.mode == "stamp":
            return "date-time" + (f", zone {self.zone}" if self.zone is not None else "")
        if self.mode == "date_column":
            return f"time of day with date column '{self.table.cols[self.idate][2]}', zone {self.zone}"
        text = f"time of day on {self.day0.isoformat()}, zone {self.zone}"
        if self.rollovers:
            text += f", {self.rollovers} midnight roll-over{'s' * (self.rollovers > 1)}"
        return text


def _column_units(tab, row_units, it: int) -> list:
    """Each column's unit: the header's, or the units row's (which must agree with a header
    unit; a time-format hint such as hh:mm:ss in the time column is not a unit)."""
    units = [u for _, u, _ in tab.cols]
    for i, u in enumerate(row_units):
        if u is None or (i == it and _norm(u) in _TIME_FORMAT_HINTS):
            continue
        if units[i] is not None and not _same_unit(units[i], u):
            raise tab.error(tab.units_line, tab.cols[i][2],
                            f"the units row says {u!r} but the header says {units[i]!r}")
        units[i] = u
    return units


def flow_rate_cell(num, cell: str, q_hi: float, qname: str, flowback: bool):
    """(value in the log's unit, problem) of a flow-rate cell: a number, not negative unless
    flowback is allowed, within the plausible range (``q_hi`` in the log's unit)."""
    v, why = num(cell)
    if v is not None and v < 0 and not flowback:
        why = f"negative flow rate {cell} (flowback: set injection.allow_flowback = true in the scene)"
    elif v is not None and abs(v) > q_hi:
        why = (f"flow rate {cell} {qname} is outside the plausible range 0 to {q_hi:.6g} {qname} "
               f"(0 to {FLOW_RATE_RANGE[1]:g} m3/s); check the unit")
    return v, why


def _locate_columns(tab, names, time_column, flow_column, pressure_column):
    """(time, flow-rate, pressure, date) column indices of a log's table: the named ones, else
    detected from the headers; pressure and date may be None. One place for the file reader and
    the live stream decoder, so both accept and refuse the same headers."""
    it = (tab.named(time_column, names["time_column"]) if time_column is not None else
          tab.detected("time", _TIME_EXACT, _TIME_PREFIXES, names["time_column"], True))
    iq = (tab.named(flow_column, names["flow_column"]) if flow_column is not None else
          tab.detected("flow-rate", _FLOW_EXACT, _FLOW_PREFIXES, names["flow_column"], True, (it,)))
    ip = (tab.named(pressure_column, names["pressure_column"]) if pressure_column is not None else
          tab.detected("pressure", _PRESSURE_EXACT, _PRESSURE_PREFIXES, names["pressure_column"],
                       False, (it, iq)))
    used = [i for i in (it, iq, ip) if i is not None]
    if len(set(used)) < len(used):
        raise tab.error(tab.hline, None, "the time, flow-rate and pressure columns must be "
                        "different columns")
    idate = next((i for i, (b, _, _) in enumerate(tab.cols) if b in _DATE_EXACT and i not in used), None)
    return it, iq, ip, idate


def read_injection_log(path, *, flow_unit: Optional[str] = None,
                       pressure_unit: Optional[str] = None,
                       max_gap: Optional[float] = 600.0,
                       policy: str = "stop",
                       date: Optional[object] = None,
                       tz: Optional[object] = None,
                       time_column: Optional[object] = None,
                       flow_column: Optional[object] = None,
                       pressure_column: Optional[object] = None,
                       option_names: Optional[dict] = None,
                       flowback: bool = False) -> InjectionLog:
    """Read an operator's injection log (CSV and its dialects) into an :class:`InjectionLog`.

    ``max_gap`` (s): longest accepted interval between kept samples (None or inf disables the
    check).  ``policy``: "stop", "skip" or "hold" (see the module docstring).  ``date``
    (``YYYY-MM-DD`` or a :class:`datetime.date`): the day of a log whose stamps are times of
    day.  ``tz`` (IANA name such as ``"Europe/Zurich"`` or a tzinfo): zone of stamps written
    without an offset.  ``time_column``/``flow_column``/``pressure_column``: a column by its
    header (as written, or without its unit) or by its 1-based position, instead of the
    automatic choice.  ``option_names`` maps these keywords to the names used in messages
    (the CLI passes :data:`CLI_OPTION_NAMES`).  What was detected is in ``log.summary``.
    Raises :class:`InjectionLogError` for problems.
    """
    names = dict(KEYWORD_NAMES)
    names.update(option_names or {})
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {POLICIES}, got {policy!r}")
    if max_gap is None:
        max_gap = math.inf
    max_gap = float(max_gap)
    if not max_gap > 0:
        raise ValueError(f"{_arg(names['max_gap'], repr(max_gap))}: must be > 0 s")
    src = str(path)
    zone = _zone(tz, src, names["tz"])
    day0 = _as_date(date, src, names["date"])

    # -- columns and units ----------------------------------------------------------------------
    tab = _Table.read(path, src)
    num = _Numbers(tab.delim)
    it, iq, ip, idate = _locate_columns(tab, names, time_column, flow_column, pressure_column)
    tcol, qcol = tab.cols[it][2], tab.cols[iq][2]
    pcol = tab.cols[ip][2] if ip is not None else None

    units = _column_units(tab, tab.take_units_row(num, iq), it)
    unit_line = tab.units_line or tab.hline
    qf, qname = _unit_for(src, unit_line, qcol, units[iq], flow_unit, "flow_rate",
                          names["flow_unit"])
    pf = pname = None
    if ip is not None:
        pf, pname = _unit_for(src, unit_line, pcol, units[ip], pressure_unit, "pressure",
                              names["pressure_unit"])

    warnings: List[str] = []
    dropped = tab.drop_partial_last_row([i for i in (iq, ip) if i is not None])
    if dropped:
        warnings.append(dropped)
    clock = _Clock(tab, it, idate, units[it], num, day0, zone, names, warnings)

    # -- rows -----------------------------------------------------------------------------------
    T: List[float] = []
    Q: List[float] = []
    P: List[float] = []
    L: List[int] = []   # line of each kept sample (inserted samples: line of the next row)
    start = None        # instant of the first kept row, in the zone it was written in
    last_q: Optional[float] = None
    last_p: Optional[float] = None
    q_hi = FLOW_RATE_RANGE[1] / qf
    p_lo, p_hi = (PRESSURE_RANGE[0] / pf, PRESSURE_RANGE[1] / pf) if pf else (None, None)
    ncol = len(tab.header)

    def problem(line, column, text, action=None):
        """Raise under 'stop'; otherwise record what was done and return."""
        if policy == "stop" or action is None:
            raise InjectionLogError(src, line, column, text)
        warnings.append(_where(src, line, column) + f"{text}; {action} (policy '{policy}')")

    for line, cells in tab.rows:
        if len(cells) > ncol and any(cells[ncol:]):
            problem(line, None, f"row has {len(cells)} cells but the header has {ncol}",
                    "row dropped")
            continue
        cells = cells + [""] * (ncol - len(cells))

        # -- time -----------------------------------------------------------
        tcell = cells[it]
        t, why, row_dt = clock.seconds(line, cells, T[-1] if T else None)
        if t is None:
            problem(line, tcol, f"bad time stamp: {why}", "row dropped")
            continue
        if T and t < T[-1]:
            problem(line, tcol, f"time going backwards: {tcell} is before the stamp on "
                    f"line {L[-1]}", "row dropped")
            continue
        if T and t == T[-1]:
            problem(line, tcol, f"duplicate time stamp {tcell} (same as line {L[-1]})",
                    "row dropped")
            continue

        # -- flow rate --------------------------------------------------------
        v, why = flow_rate_cell(num, cells[iq], q_hi, qname, flowback)
        if why is not None:
            if policy == "hold" and last_q is not None:
                problem(line, qcol, why, f"held previous rate {last_q / qf!r}")
                q = last_q
            else:
                problem(line, qcol, why, "row dropped" if policy == "skip" else
                        "row dropped (no previous value to hold)")
                continue
        else:
            q = v * qf

        # -- pressure ---------------------------------------------------------
        p = None
        if ip is not None:
            v, why = num(cells[ip])
            if v is not None and not p_lo <= v <= p_hi:
                why = (f"pressure {cells[ip]} {pname} is outside the plausible range "
                       f"{p_lo:.6g} to {p_hi:.6g} {pname} (-1 to 1000 MPa); check the unit")
            if why is not None:
                if policy == "hold" and last_p is not None:
                    problem(line, pcol, why, f"held previous pressure {last_p / pf!r}")
                    p = last_p
                else:
                    problem(line, pcol, why, "row dropped" if policy == "skip" else
                            "row dropped (no previous value to hold)")
                    continue
            else:
                p = v * pf

        # -- gap --------------------------------------------------------------
        if T and t - T[-1] > max_gap:
            gap = t - T[-1]
            text = f"gap of {gap:g} s since line {L[-1]} exceeds {_arg(names['max_gap'], f'{max_gap:g}')} s"
            if policy == "hold":
                t_ins = t - HOLD_EPS
                if not (T[-1] < t_ins < t):
                    t_ins = float(np.nextafter(t, -math.inf))
                problem(line, tcol, text,
                        f"rate held at {Q[-1] / qf!r} until {HOLD_EPS:g} s before this stamp")
                T.append(t_ins)
                Q.append(Q[-1])
                if ip is not None:
                    P.append(P[-1])
                L.append(line)
            else:
                problem(line, tcol, text, "gap bridged by linear interpolation")

        if not T:
            start = row_dt
        T.append(t)
        Q.append(q)
        if ip is not None:
            P.append(p)
        L.append(line)
        last_q = q
        last_p = p

    if len(T) < 2:
        last_line = tab.rows[-1][0] if tab.rows else unit_line
        raise InjectionLogError(src, last_line, None,
                                f"too few data rows ({len(T)} usable, need at least 2)")

    time = np.asarray(T, dtype=np.float64)
    time = time - time[0]   # s since the first kept stamp
    log = InjectionLog(time, np.asarray(Q), np.asarray(P) if ip is not None else None,
                       start, src, tuple(warnings), flow_unit=qname, pressure_unit=pname,
                       flowback=flowback)

    # -- one line saying what was understood ----------------------------------------------------
    dialect = [tab.encoding, f"{_DELIMITERS.get(tab.delim, 'blank')}-separated"]
    if num.comma_seen:
        dialect.append("decimal comma")
    if tab.units_line is not None:
        dialect.append(f"units row (line {tab.units_line})")
    used = [f"time '{tcol}' ({clock.describe()})", f"flow '{qcol}' ({qname})",
            f"pressure '{pcol}' ({pname})" if ip is not None else "no pressure column"]
    summary = (f"{os.path.basename(src)}: {', '.join(dialect)}; {', '.join(used)}; "
               f"{time.size} samples over {_duration(log.duration)}, {log.total_volume:.6g} m3")
    return replace(log, summary=summary)


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:g} s"
    if seconds < 7200:
        return f"{seconds / 60:.4g} min"
    return f"{seconds / 3600:.4g} h"

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
* instead of a rate (no rate column, or ``volume_column=`` /
  ``cumulative_volume_column=``): the volume injected since the previous row
  (``dV``, ``volume``...) or since the start (``V_cumulative``,
  ``cumulative_volume``...), unit in brackets, as a word of the name
  (``V_cumulative_m3``) or ``volume_unit=``; the rate is constant over each
  interval (see :mod:`fault_screen.io.log_stream`).
Elapsed times take their unit from the header (``elapsed[min]``), from a word
of the name (``t_days_since_2006-12-02T00:00``: days; with ``tz=`` the date
after ``since`` is the start), or from ``time_unit=``.  Lines end with LF,
CR LF or a lone CR.
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
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta
from typing import List, Optional, Sequence, Tuple

import numpy as np

from .log_format import (
    CLI_OPTION_NAMES, FLOW_RATE_RANGE, HOLD_EPS, POLICIES, PRESSURE_RANGE, InjectionLogError,
    LineSplitter, decode_text,
)
from .log_stream import STEP_RAMP, LogDecoder, step_ramp
from .volume import PiecewiseLinearVolume

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
    _volume: PiecewiseLinearVolume = field(init=False, repr=False, compare=False)

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
        for a in (t, q):
            a.setflags(write=False)
        object.__setattr__(self, "time", t)
        object.__setattr__(self, "flow_rate", q)
        object.__setattr__(self, "pressure", p)
        object.__setattr__(self, "source", str(self.source))
        object.__setattr__(self, "warnings", tuple(str(w) for w in self.warnings))
        object.__setattr__(self, "_volume", PiecewiseLinearVolume(t, q))

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
            eps = step_ramp(ti)
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
        return self._volume.rate_at(t)

    def volume(self, t0: float = -math.inf, t1: float = math.inf) -> float:
        """Exact integral (m3) of the rate from ``t0`` to ``t1`` (s).

        The rate is 0 outside the log; ``t1 < t0`` gives the negative of
        ``volume(t1, t0)`` (signed integral).
        """
        return self._volume.volume(t0, t1)

    def step_volumes(self, times) -> np.ndarray:
        """Volumes (m3) injected between consecutive entries of ``times``.

        ``times`` must be non-decreasing; returns an array of ``len(times)-1``.
        """
        return self._volume.step_volumes(times)

    @property
    def total_volume(self) -> float:
        """Total injected volume (m3) (a property, not a method)."""
        return self._volume.total

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



def read_injection_log(path, *, flow_unit: Optional[str] = None,
                       pressure_unit: Optional[str] = None,
                       max_gap: Optional[float] = 600.0,
                       policy: str = "stop",
                       date: Optional[object] = None,
                       tz: Optional[object] = None,
                       time_column: Optional[object] = None,
                       flow_column: Optional[object] = None,
                       pressure_column: Optional[object] = None,
                       time_unit: Optional[str] = None,
                       volume_column: Optional[object] = None,
                       cumulative_volume_column: Optional[object] = None,
                       volume_unit: Optional[str] = None,
                       option_names: Optional[dict] = None,
                       flowback: bool = False) -> InjectionLog:
    """Read an operator's injection log (CSV and its dialects) into an :class:`InjectionLog`.

    ``max_gap`` (s): longest accepted interval between kept samples (None or inf disables the
    check).  ``policy``: "stop", "skip" or "hold" (see the module docstring).  ``date``
    (``YYYY-MM-DD`` or a :class:`datetime.date`): the day of a log whose stamps are times of
    day.  ``tz`` (IANA name such as ``"Europe/Zurich"`` or a tzinfo): zone of stamps written
    without an offset.  ``time_column``/``flow_column``/``pressure_column``: a column by its
    header (as written, or without its unit) or by its 1-based position, instead of the
    automatic choice.  ``time_unit``: unit of elapsed-time numbers (when the header names
    none).  ``volume_column``/``cumulative_volume_column``: a column of volumes injected since
    the previous row, or since the start, instead of a rate; ``volume_unit`` their unit.
    ``option_names`` maps these keywords to the names used in messages (the CLI passes
    :data:`CLI_OPTION_NAMES`).  What was detected is in ``log.summary``.
    Raises :class:`InjectionLogError` for problems.

    The file is read by :class:`~fault_screen.io.log_stream.LogDecoder` fed every line of it:
    the monitor reads a growing log with the same decoder, so both agree bit for bit.
    """
    src = str(path)
    decoder = LogDecoder(src, flow_unit=flow_unit, pressure_unit=pressure_unit, max_gap=max_gap,
                         policy=policy, date=date, tz=tz, time_column=time_column,
                         flow_column=flow_column, pressure_column=pressure_column,
                         time_unit=time_unit, volume_column=volume_column,
                         cumulative_volume_column=cumulative_volume_column,
                         volume_unit=volume_unit, option_names=option_names, flowback=flowback)
    with open(path, "rb") as fh:
        raw = fh.read()
    decode_text(raw, src)      # refuses an empty or binary file with its name
    # the lines as the monitor's sources split and decode them
    splitter = LineSplitter()
    lines = splitter.push(raw) + splitter.rest()
    decoder.encoding = splitter.encoding
    samples = decoder.feed_lines(lines)
    samples += decoder.end()
    content = [n for n, t in lines if t.strip() and not t.strip().startswith("#")]
    if not content:
        raise InjectionLogError(src, max(1, len(lines)), None, "no header line and no data")
    if len(samples) < 2:
        raise InjectionLogError(src, content[-1], None,
                                f"too few data rows ({len(samples)} usable, need at least 2)")
    time = np.array([s.time for s in samples], dtype=np.float64)
    pressure = None
    if samples[0].pressure is not None:
        pressure = np.array([s.pressure for s in samples], dtype=np.float64)
    log = InjectionLog(time, np.array([s.flow_rate for s in samples], dtype=np.float64),
                       pressure, decoder.start, src, tuple(decoder.warnings),
                       flow_unit=decoder.qname if decoder.volume_mode == "rate" else "m3/s",
                       pressure_unit=decoder.pname, flowback=flowback)
    dialect, used = decoder.describe()
    summary = (f"{os.path.basename(src)}: {dialect}; {used}; "
               f"{_samples(time.size, decoder.rows_kept)} over {_duration(log.duration)}, "
               f"{log.total_volume:.6g} m3")
    return replace(log, summary=summary)


def _samples(samples: int, rows: int) -> str:
    if samples == rows:
        return f"{samples} samples"
    return f"{rows} rows ({samples} samples with the ramps of rate steps and held gaps)"


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:g} s"
    if seconds < 7200:
        return f"{seconds / 60:.4g} min"
    return f"{seconds / 3600:.4g} h"


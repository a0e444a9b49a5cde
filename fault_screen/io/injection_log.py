"""Injection-rate logs as operators export them.

File format
-----------
CSV with one header line.  Lines whose first non-blank character is ``#``
and blank lines are ignored everywhere (comments).  Columns, matched on the
header name without its unit and case-insensitively:

* time: ``time`` / ``elapsed`` or a name starting with one of those
  (``timestamp``, ``elapsed_time``).  Either ISO 8601 timestamps **with**
  a zone (``2015-03-12T10:00:05+01:00``, ``...Z``) or elapsed numbers,
  in seconds unless the header gives a unit (``elapsed[min]``).  Which of
  the two is decided from the header unit (a unit -> numbers) or else from
  the first time cell (a number -> elapsed seconds).  A timestamp without a
  zone is always an error, whatever the policy: its instant is unknown.
* flow rate: ``flow_rate``, ``flowrate``, ``rate`` or ``q``; unit from the
  header (``flow_rate[L/min]``) or the ``flow_unit=`` argument.
* pressure (optional): ``pressure`` or a name starting with ``pressure``;
  unit from the header or ``pressure_unit=``.
Other columns are ignored.  Units are resolved with
:mod:`fault_screen.units`; a header unit and a conflicting argument, or no
unit at all, is an error naming the column.

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
from dataclasses import dataclass, field
from datetime import datetime, timedelta
from typing import List, Optional, Sequence, Tuple

import numpy as np

from fault_screen import units as _units

__all__ = [
    "InjectionLog",
    "InjectionLogError",
    "read_injection_log",
    "HOLD_EPS",
    "STEP_RAMP",
    "POLICIES",
]

#: Width (s) of the ramp closing a held gap (policy "hold").
HOLD_EPS = 1e-6
#: Minimum width (s) of the ramp representing a rate step (from_steps).
STEP_RAMP = 1e-9
POLICIES = ("stop", "skip", "hold")

_TIME_NAMES = ("time", "elapsed")
_FLOW_NAMES = ("flow_rate", "flowrate", "rate", "q")


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
    warnings : tuple of str, every skip/hold applied while reading
    """

    time: np.ndarray
    flow_rate: np.ndarray
    pressure: Optional[np.ndarray] = None
    start: Optional[datetime] = None
    source: str = ""
    warnings: Tuple[str, ...] = ()
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
        if not np.all(np.isfinite(q)) or np.any(q < 0):
            raise ValueError("flow_rate must be finite and >= 0")
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


def _pick(cols, exact: Tuple[str, ...], prefixes: Tuple[str, ...]):
    """Index of the column matching exact names first, then prefixes."""
    hits = [i for i, (b, _, _) in enumerate(cols) if b in exact]
    if not hits:
        hits = [i for i, (b, _, _) in enumerate(cols) if b.startswith(prefixes)]
    return hits


def _unit_for(src, hline, col_raw, header_unit, arg_unit, quantity, argname):
    if header_unit is not None and arg_unit is not None:
        try:
            same = _units.factor(header_unit, quantity) == _units.factor(arg_unit, quantity)
        except _units.UnitError as e:
            raise InjectionLogError(src, hline, col_raw, str(e)) from None
        if not same:
            raise InjectionLogError(
                src, hline, col_raw,
                f"header unit {header_unit!r} conflicts with {argname}={arg_unit!r}")
    unit = header_unit if header_unit is not None else arg_unit
    if unit is None:
        raise InjectionLogError(
            src, hline, col_raw,
            f"column needs a unit: write it in the header (e.g. '{col_raw}[...]') "
            f"or pass {argname}=; accepted {quantity} units: {_units.accepted_units(quantity)}")
    try:
        return _units.factor(unit, quantity)
    except _units.UnitError as e:
        raise InjectionLogError(src, hline, col_raw, str(e)) from None


def _number(cell: str):
    """(value, problem) for a numeric cell."""
    if cell == "":
        return None, "empty cell"
    try:
        v = float(cell)
    except ValueError:
        return None, f"non-numeric value {cell!r}"
    if not math.isfinite(v):
        return None, f"non-finite value {cell!r}"
    return v, None


def _is_number(cell: str) -> bool:
    try:
        float(cell)
        return True
    except ValueError:
        return False


def read_injection_log(path, *, flow_unit: Optional[str] = None,
                       pressure_unit: Optional[str] = None,
                       max_gap: Optional[float] = 600.0,
                       policy: str = "stop") -> InjectionLog:
    """Read an operator's injection log (CSV) into an :class:`InjectionLog`.

    ``max_gap`` (s): longest accepted interval between kept samples (None or
    inf disables the check).  ``policy``: "stop", "skip" or "hold" (see the
    module docstring).  Raises :class:`InjectionLogError` for problems.
    """
    if policy not in POLICIES:
        raise ValueError(f"policy must be one of {POLICIES}, got {policy!r}")
    if max_gap is None:
        max_gap = math.inf
    max_gap = float(max_gap)
    if not max_gap > 0:
        raise ValueError(f"max_gap must be > 0 s, got {max_gap!r}")
    src = str(path)

    with open(path, "r", encoding="utf-8-sig", newline="") as fh:
        raw_lines = fh.read().splitlines()

    rows = []  # (line number, cells)
    for n, text in enumerate(raw_lines, start=1):
        s = text.strip()
        if not s or s.startswith("#"):
            continue
        rows.append((n, [c.strip() for c in next(csv.reader([text]))]))
    if not rows:
        raise InjectionLogError(src, max(1, len(raw_lines)), None, "no header line and no data")

    hline, header = rows[0]
    data = rows[1:]
    cols = []
    for h in header:
        base, unit = _units.parse_header(h)
        cols.append((base.strip().lower().replace(" ", "_"), unit, h))

    def one(kind, exact, prefixes, required):
        hits = _pick(cols, exact, prefixes)
        if len(hits) > 1:
            raise InjectionLogError(
                src, hline, None,
                f"several {kind} columns ({', '.join(cols[i][2] for i in hits)}); keep one")
        if not hits:
            if required:
                raise InjectionLogError(
                    src, hline, None,
                    f"no {kind} column in header {header!r} "
                    f"(expected one of: {', '.join(exact + tuple(p + '...' for p in prefixes))})")
            return None
        return hits[0]

    it = one("time", _TIME_NAMES, _TIME_NAMES, True)
    iq = one("flow-rate", _FLOW_NAMES, (), True)
    ip = one("pressure", ("pressure",), ("pressure",), False)
    tcol, qcol = cols[it][2], cols[iq][2]
    pcol = cols[ip][2] if ip is not None else None

    qf = _unit_for(src, hline, qcol, cols[iq][1], flow_unit, "flow_rate", "flow_unit")
    pf = None
    if ip is not None:
        pf = _unit_for(src, hline, pcol, cols[ip][1], pressure_unit, "pressure", "pressure_unit")
    t_unit = cols[it][1]
    if t_unit is not None:
        try:
            tf = _units.factor(t_unit, "time")
        except _units.UnitError as e:
            raise InjectionLogError(src, hline, tcol, str(e)) from None
        iso = False
    else:
        tf = 1.0
        first = next((c[it] for _, c in data if it < len(c) and c[it] != ""), None)
        iso = first is not None and not _is_number(first)

    warnings: List[str] = []
    T: List[float] = []
    Q: List[float] = []
    P: List[float] = []
    L: List[int] = []   # line of each kept sample (inserted samples: line of the next row)
    t_ref = None        # first parsed timestamp (iso): reference for differences
    start = None        # timestamp of the first kept row (iso)
    last_q: Optional[float] = None
    last_p: Optional[float] = None
    ncol = len(header)

    def problem(line, column, text, action=None):
        """Raise under 'stop'; otherwise record what was done and return."""
        if policy == "stop" or action is None:
            raise InjectionLogError(src, line, column, text)
        warnings.append(_where(src, line, column) + f"{text}; {action} (policy '{policy}')")

    for line, cells in data:
        if len(cells) > ncol and any(cells[ncol:]):
            problem(line, None, f"row has {len(cells)} cells but the header has {ncol}",
                    "row dropped")
            continue
        cells = cells + [""] * (ncol - len(cells))

        # -- time -----------------------------------------------------------
        tcell = cells[it]
        t = None
        if iso:
            if tcell == "":
                why = "empty cell"
            else:
                try:
                    txt = tcell[:-1] + "+00:00" if tcell[-1:] in ("Z", "z") else tcell
                    dt = datetime.fromisoformat(txt)
                    why = None
                except ValueError:
                    why = f"not an ISO 8601 timestamp {tcell!r}"
                else:
                    if dt.utcoffset() is None:
                        # never held/skipped: the instant itself is unknown
                        raise InjectionLogError(
                            src, line, tcol,
                            f"timestamp without time zone {tcell!r} "
                            f"(add an offset such as +01:00 or Z)")
                    if t_ref is None:
                        t_ref = dt
                    t = (dt - t_ref).total_seconds()
        else:
            v, why = _number(tcell)
            if v is not None:
                t = v * tf
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
        v, why = _number(cells[iq])
        if v is not None and v < 0:
            why = f"negative flow rate {cells[iq]}"
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
            v, why = _number(cells[ip])
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
            text = (f"gap of {gap:g} s since line {L[-1]} exceeds max_gap={max_gap:g} s")
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

        if not T and iso:
            start = dt
        T.append(t)
        Q.append(q)
        if ip is not None:
            P.append(p)
        L.append(line)
        last_q = q
        last_p = p

    if len(T) < 2:
        last_line = data[-1][0] if data else hline
        raise InjectionLogError(src, last_line, None,
                                f"too few data rows ({len(T)} usable, need at least 2)")

    time = np.asarray(T, dtype=np.float64)
    time = time - time[0]   # s since the first kept stamp
    return InjectionLog(time, np.asarray(Q), np.asarray(P) if ip is not None else None,
                        start, src, tuple(warnings))

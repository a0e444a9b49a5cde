"""Injection logs that grow: the replay's log format read one line at a time.

:class:`LogDecoder` turns the lines of an injection log into samples as they arrive, with the
dialect pieces of :mod:`fault_screen.io.log_format` doing the interpretation (table, clock and
number readers: separators, decimal commas, units in the header or in a units row, ISO stamps,
local times with ``tz``, times of day with ``date`` and midnight roll-overs, elapsed numbers or
``hh:mm:ss``, column options) and the same checks and ``stop``/``skip``/``hold`` policies, so
that the samples of a complete log are exactly (bit for bit) those of a replay: seconds since
the first kept stamp, m3/s, Pa.

What a stream adds to a file:

* **Setup on the first data rows.**  The separator, the column choice, a units row and the
  time format are decided when the header and the first data rows are there: up to five rows
  of the lines handed over together (:meth:`LogDecoder.feed_lines`; the file reader hands over
  the whole file, so :func:`~fault_screen.io.injection_log.read_injection_log` is this decoder
  fed every line of the file).
* **A trailing partial row** (a stamp without values, what a logger writes when it stops) is
  held back until the next row comes (then it is read as any row) or the stream ends (then it is
  dropped with a warning, as the file reader does).
* **New files.**  After a rotation or truncation the source calls :meth:`LogDecoder.new_file`;
  the next non-comment line is a new header if it is the same header text, else data under the
  old header.  The time origin and the last sample carry over.
* **Resume.**  ``LogDecoder(..., resume=state)`` with a :meth:`state` saved earlier continues
  after that state's last sample: rows up to it (the log read again from its start after a
  restart) are dropped silently, the first row after it is checked against it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Callable, Iterable, List, Optional, Tuple

import numpy as np

from .. import units as _units
from .plausibility import FASTEST_SAMPLING, LARGEST_RATE
from .log_format import (
    DELIMITERS, FLOW_RATE_RANGE, HOLD_EPS, KEYWORD_NAMES, POLICIES, PRESSURE_RANGE, CellError, Clock,
    InjectionLogError, Numbers, Table, arg, as_date, column_units, detect_delimiter,
    flow_rate_cell, locate_columns, norm_name, origin_in_name, split_cells, unit_for,
    unit_in_name, where, zone_of,
)

__all__ = ["LogDecoder", "Sample", "STEP_RAMP"]

#: Minimum width (s) of the ramp representing a rate step (volume columns, from_steps).
STEP_RAMP = 1e-9
#: data rows looked at to choose the separator
_LOOKAHEAD = 5


def step_ramp(t: float) -> float:
    """Width (s) of the ramp of a rate step at ``t``: 1 ns, or 64 ulp of ``t`` if wider."""
    return max(STEP_RAMP, 64.0 * float(np.spacing(abs(t))))


@dataclass(frozen=True)
class Sample:
    """One injection sample: ``time`` (s since the log's first stamp), ``flow_rate`` (m3/s, the
    whole interval), ``pressure`` (Pa or None)."""

    time: float
    flow_rate: float
    pressure: Optional[float] = None


class LogDecoder:
    """Incremental reader of an injection log (see the module docstring).

    Keyword arguments as :func:`~fault_screen.io.injection_log.read_injection_log`.
    ``feed_line(text, line)`` returns the samples the line adds (0, 1, or 2 when a held gap or
    a volume step inserts a sample); ``feed_lines`` the samples of several lines; ``end()``
    those of a row held back at the end.  Problems raise :class:`InjectionLogError` under
    ``stop`` (kept in :attr:`error` with ``defer_errors``) and go to ``on_warning`` (and
    ``warnings``) under ``skip``/``hold``.
    """

    def __init__(self, source: str = "<stream>", *, flow_unit: Optional[str] = None,
                 pressure_unit: Optional[str] = None, max_gap: Optional[float] = 600.0,
                 policy: str = "stop", date=None, tz=None, time_column=None, flow_column=None,
                 pressure_column=None, time_unit: Optional[str] = None, volume_column=None,
                 cumulative_volume_column=None, volume_unit: Optional[str] = None,
                 option_names: Optional[dict] = None, resume: Optional[dict] = None,
                 on_warning: Optional[Callable[[str], None]] = None, flowback: bool = False,
                 defer_errors: bool = False, accept_implausible: bool = True):
        self.names = dict(KEYWORD_NAMES)
        self.names.update(option_names or {})
        if policy not in POLICIES:
            raise ValueError(f"policy must be one of {POLICIES}, got {policy!r}")
        max_gap = math.inf if max_gap is None else float(max_gap)
        if not max_gap > 0:
            raise ValueError(f"{arg(self.names['max_gap'], repr(max_gap))}: must be > 0 s")
        self.source = str(source)
        self.flow_unit, self.pressure_unit = flow_unit, pressure_unit
        self.time_unit, self.volume_unit = time_unit, volume_unit
        for name, value, quantity in (("time_unit", time_unit, "time"),
                                      ("volume_unit", volume_unit, "volume")):
            if value is not None:
                try:
                    _units.factor(value, quantity)
                except _units.UnitError as exc:
                    raise InjectionLogError(self.source, None, None,
                                            f"{arg(self.names[name], repr(value))}: {exc}") from None
        self.max_gap, self.policy = max_gap, policy
        self.flowback = flowback   # negative rates allowed (the scene's injection.allow_flowback)
        self.zone = zone_of(tz, self.source, self.names["tz"])
        self.day0 = as_date(date, self.source, self.names["date"])
        self.columns = (time_column, flow_column, pressure_column, volume_column,
                        cumulative_volume_column)
        self.on_warning = on_warning
        self.defer_errors = defer_errors
        # the first rows' spacing and every rate are checked unless accepted (the command line
        # checks; see fault_screen.io.plausibility)
        self.accept_implausible = accept_implausible
        self._first_rows: List[float] = []
        self.rows_kept = 0
        self.error: Optional[InjectionLogError] = None
        self.warnings: List[str] = []
        self.replayed = 0          # rows dropped because a resumed state already holds them
        self.encoding = "UTF-8"    # what the lines were decoded from (set by the file reader)
        self.summary_parts: Tuple[str, ...] = ()
        self._header = None        # (line, text)
        self._pending = []         # (line, text) read before the setup
        self._expect_header = True
        self._tab = None
        self._held = None          # a row with a stamp and no values, held back
        self._reported = 0
        self.offset: Optional[float] = None       # raw time of the first kept row
        self.last: Optional[tuple] = None         # (raw time, q, p, line) of the last kept row
        self.last_q: Optional[float] = None
        self.last_p: Optional[float] = None
        self.last_volume: Optional[float] = None  # cumulative volume (m3) of the last kept row
        self._start: Optional[datetime] = None
        self._t_ref = None
        self._resume_after: Optional[float] = None
        self._replay_last: Optional[float] = None
        if resume:
            self._t_ref = datetime.fromisoformat(resume["t_ref"]) if resume.get("t_ref") else None
            self._start = datetime.fromisoformat(resume["start"]) if resume.get("start") else None
            self.offset = resume.get("offset")
            last = resume.get("last")
            if last is not None:
                self.last = (float(last[0]), float(last[1]),
                             None if last[2] is None else float(last[2]), None)
                self.last_q, self.last_p = self.last[1], self.last[2]
                self._resume_after = self.last[0]
            self.last_volume = resume.get("last_volume")

    # -- state ------------------------------------------------------------------------------
    @property
    def start(self) -> Optional[datetime]:
        """Date-time of model time 0 (the first kept stamp) for logs with date-times, else None."""
        return self._start

    @property
    def has_clock(self) -> Optional[bool]:
        """True for date-time stamps, False for elapsed times, None before the first row."""
        return None if self._tab is None else self.clock.is_clock

    def state(self) -> dict:
        """JSON-able state for ``LogDecoder(resume=...)``."""
        t_ref = self.clock.t_ref if self._tab is not None else self._t_ref
        return {"t_ref": t_ref.isoformat() if t_ref else None,
                "start": self._start.isoformat() if self._start else None,
                "offset": self.offset,
                "last": None if self.last is None else [self.last[0], self.last[1], self.last[2]],
                "last_volume": self.last_volume}

    def new_file(self) -> None:
        """The source now reads a new file (rotation) or the file was truncated."""
        self._expect_header = True

    # -- lines ------------------------------------------------------------------------------
    def _problem(self, line, column, text, action=None):
        if self.policy == "stop" or action is None:
            raise InjectionLogError(self.source, line, column, text)
        self._warn(where(self.source, line, column) + f"{text}; {action} (policy '{self.policy}')")

    def _warn(self, msg: str) -> None:
        self.warnings.append(msg)
        self._flush_warnings()

    def _flush_warnings(self) -> None:
        while self._reported < len(self.warnings):
            if self.on_warning is not None:
                self.on_warning(self.warnings[self._reported])
            self._reported += 1

    def feed_line(self, text: str, line: Optional[int] = None) -> List[Sample]:
        """Samples added by one line of the log (without its line end)."""
        return self.feed_lines([(line, text)])

    def feed_lines(self, lines: Iterable[Tuple[Optional[int], str]]) -> List[Sample]:
        """Samples added by ``(line number, text)`` pairs; before the setup, up to five data
        rows among them choose the separator."""
        out: List[Sample] = []
        if self.error is not None:
            return out
        try:
            for line, text in lines:
                s = text.strip()
                if not s or s.startswith("#"):
                    continue
                if self._expect_header:
                    self._expect_header = False
                    if self._header is None:
                        self._header = (line, text)
                        continue
                    if s == self._header[1].strip():
                        continue          # the same header at the top of a new file
                if self._tab is None:
                    self._pending.append((line, text))
                    if len(self._pending) >= _LOOKAHEAD:
                        out += self._setup()
                    continue
                out += self._rows([(line, text)])
            if self._tab is None and self._pending:
                out += self._setup()
        except InjectionLogError as exc:
            if not self.defer_errors:
                raise
            self.error = exc
        self._flush_warnings()
        return out

    def end(self) -> List[Sample]:
        """The stream ended: a held-back partial row is dropped with a warning."""
        if self._held is not None and self.error is None:
            line, _ = self._held
            self._held = None
            self._warn(where(self.source, line, None) + "last row has a time stamp but no "
                       "values (a partial row written when the logger stopped); dropped")
        return []

    # -- setup: what is decided from the header and the first rows ---------------------------
    def _setup(self) -> List[Sample]:
        hline, htext = self._header
        src, names = self.source, self.names
        delim = detect_delimiter(htext, [t for _, t in self._pending[:_LOOKAHEAD]])
        try:
            header = split_cells(htext, delim)
        except CellError as exc:
            raise InjectionLogError(src, hline, None, f"header: {exc}") from None
        cols = []
        for h in header:
            base, unit = _units.parse_header(h)
            cols.append((norm_name(base), unit, h))
        rows = []
        for k, (n, t) in enumerate(self._pending):
            try:
                rows.append((n, split_cells(t, delim), k))
            except CellError:
                pass                         # a bad row: reported when it is read
        index = [k for _, _, k in rows]
        tab = Table(src, self.encoding, delim, hline, header, cols, [r[:2] for r in rows])
        num = Numbers(delim)
        (time_column, flow_column, pressure_column, volume_column,
         cumulative_column) = self.columns
        c = locate_columns(tab, names, time_column, flow_column, pressure_column, volume_column,
                           cumulative_column)
        it, iq, ip = c.time, c.value, c.pressure
        row_units = tab.take_units_row(num, iq)
        if not tab.rows:
            # only a units row so far: decide again when a data row comes
            return []
        units = column_units(tab, row_units, it)
        unit_line = tab.units_line or tab.hline
        qcol = tab.cols[iq][2]
        self.volume_mode = "rate" if c.flow is not None else (
            "interval" if c.volume is not None else "cumulative")
        if self.volume_mode == "rate":
            self.qf, self.qname = unit_for(src, unit_line, qcol, units[iq], self.flow_unit,
                                           "flow_rate", names["flow_unit"])
        else:
            vu = units[iq] if units[iq] is not None else unit_in_name(tab.cols[iq][2], "volume")
            self.qf, self.qname = unit_for(src, unit_line, qcol, vu, self.volume_unit,
                                           "volume", names["volume_unit"])
        self.pf = self.pname = None
        if ip is not None:
            self.pf, self.pname = unit_for(src, unit_line, tab.cols[ip][2], units[ip],
                                           self.pressure_unit, "pressure",
                                           names["pressure_unit"])
        t_unit = units[it]
        if t_unit is None:
            t_unit = unit_in_name(tab.cols[it][2], "time")
        if self.time_unit is not None:
            if t_unit is not None and _units.factor(t_unit, "time") != \
                    _units.factor(self.time_unit, "time"):
                raise InjectionLogError(src, unit_line, tab.cols[it][2],
                                        f"the file's unit {t_unit!r} conflicts with "
                                        f"{arg(names['time_unit'], repr(self.time_unit))}")
            t_unit = self.time_unit
        self.clock = Clock(tab, it, c.date, t_unit, num, self.day0, self.zone, names,
                           self.warnings)
        if t_unit is not None and self.clock.mode == "elapsed" and self._start is None:
            origin = origin_in_name(tab.cols[it][2])
            self.origin = origin
        else:
            self.origin = None
        if self._t_ref is not None:
            self.clock.t_ref = self._t_ref    # the clock of the run resumed (or before rotation)
        self._tab, self.num = tab, num
        self.it, self.iq, self.ip = it, iq, ip
        self.tcol, self.qcol = tab.cols[it][2], qcol
        self.pcol = tab.cols[ip][2] if ip is not None else None
        self.q_hi = FLOW_RATE_RANGE[1] / self.qf
        self.p_lo, self.p_hi = ((PRESSURE_RANGE[0] / self.pf, PRESSURE_RANGE[1] / self.pf)
                                if self.pf else (None, None))
        pending, self._pending = self._pending, []
        if tab.units_line is not None and row_units:
            del pending[index[0]]              # the units row is no data row
        return self._rows(pending)

    def describe(self) -> Tuple[str, ...]:
        """What was understood: dialect and columns (for the log's summary line)."""
        if self._tab is None:
            return ()
        tab = self._tab
        dialect = [self.encoding, f"{DELIMITERS.get(tab.delim, 'blank')}-separated"]
        if self.num.comma_seen:
            dialect.append("decimal comma")
        if tab.units_line is not None:
            dialect.append(f"units row (line {tab.units_line})")
        what = {"rate": "flow", "interval": "volume per interval",
                "cumulative": "cumulative volume"}[self.volume_mode]
        used = [f"time '{self.tcol}' ({self.clock.describe()})",
                f"{what} '{self.qcol}' ({self.qname})",
                f"pressure '{self.pcol}' ({self.pname})" if self.ip is not None
                else "no pressure column"]
        return ", ".join(dialect), ", ".join(used)

    # -- rows: the checks and policies, one row at a time ------------------------------------
    def _rows(self, rows) -> List[Sample]:
        out: List[Sample] = []
        for line, text in rows:
            try:
                cells = split_cells(text, self._tab.delim)
            except CellError as exc:
                self._problem(line, None, str(exc), "row dropped")
                continue
            if self._held is not None:
                held, self._held = self._held, None
                out += self._row(*held)
            if self._is_partial(cells):
                self._held = (line, cells)
                continue
            out += self._row(line, cells)
        return out

    def _is_partial(self, cells) -> bool:
        it = self.it
        has_stamp = it < len(cells) and cells[it] != ""
        values = [i for i in (self.iq, self.ip) if i is not None]
        return has_stamp and not any(i < len(cells) and cells[i] != "" for i in values)

    def _value(self, line, cells, t, last):
        """(rate in m3/s or None, problem) of a row's value cell."""
        cell = cells[self.iq]
        if self.volume_mode == "rate":
            v, why = flow_rate_cell(self.num, cell, self.q_hi, self.qname, self.flowback)
            return (None if why is not None else v * self.qf), why
        v, why = self.num(cell)
        if why is not None:
            return None, why
        volume = v * self.qf
        if self.volume_mode == "cumulative":
            if self.last_volume is None:
                return 0.0, None          # the first row: the volume counts from it
            dv = volume - self.last_volume
        else:
            dv = volume
            if last is None:
                if volume != 0:
                    self._warn(where(self.source, line, self.qcol) + f"volume {cell} "
                               f"{self.qname} of the first row is before the log's first "
                               f"stamp: not injected in the run")
                return 0.0, None
        if dv < 0 and not self.flowback:
            return None, (f"negative volume {dv / self.qf:g} {self.qname} over the interval "
                          f"(flowback: set injection.allow_flowback = true in the scene)")
        q = dv / (t - last[0])
        if not abs(q) <= FLOW_RATE_RANGE[1]:
            return None, (f"volume {cell} {self.qname} over {t - last[0]:g} s is a rate of "
                          f"{q:.6g} m3/s, outside the plausible range 0 to "
                          f"{FLOW_RATE_RANGE[1]:g} m3/s; check the units")
        return q, None

    def _row(self, line, cells) -> List[Sample]:
        ncol = len(self._tab.header)
        if len(cells) > ncol and any(cells[ncol:]):
            self._problem(line, None, f"row has {len(cells)} cells but the header has {ncol}",
                          "row dropped")
            return []
        cells = cells + [""] * (ncol - len(cells))
        tcell = cells[self.it]
        last = self.last
        # the clock tells a midnight roll-over from the previous time (while a resumed decoder
        # reads the rows it already holds: the previous of those)
        prev = self._replay_last if self._resume_after is not None else (
            last[0] if last is not None else None)
        t, why, row_dt = self.clock.seconds(line, cells, prev)
        if self._resume_after is not None and t is not None and t <= self._resume_after:
            self.replayed += 1
            self._replay_last = t
            return []
        if t is None:
            self._problem(line, self.tcol, f"bad time stamp: {why}", "row dropped")
            return []
        self._resume_after = None
        if last is not None and t < last[0]:
            self._problem(line, self.tcol, f"time going backwards: {tcell} is before the stamp "
                          f"on line {last[3]}", "row dropped")
            return []
        if last is not None and t == last[0]:
            self._problem(line, self.tcol, f"duplicate time stamp {tcell} (same as line "
                          f"{last[3]})", "row dropped")
            return []

        q, why = self._value(line, cells, t, last)
        if why is not None:
            if self.policy == "hold" and self.last_q is not None:
                self._problem(line, self.qcol, why, f"held previous rate {self._rate_text(self.last_q)}")
                q = self.last_q
            else:
                self._problem(line, self.qcol, why, "row dropped" if self.policy == "skip" else
                              "row dropped (no previous value to hold)")
                return []

        p = None
        if self.ip is not None:
            v, why = self.num(cells[self.ip])
            if v is not None and not self.p_lo <= v <= self.p_hi:
                why = (f"pressure {cells[self.ip]} {self.pname} is outside the plausible range "
                       f"{self.p_lo:.6g} to {self.p_hi:.6g} {self.pname} (-1 to 1000 MPa); check "
                       f"the unit")
            if why is not None:
                if self.policy == "hold" and self.last_p is not None:
                    self._problem(line, self.pcol, why,
                                  f"held previous pressure {self.last_p / self.pf!r}")
                    p = self.last_p
                else:
                    self._problem(line, self.pcol, why, "row dropped" if self.policy == "skip"
                                  else "row dropped (no previous value to hold)")
                    return []
            else:
                p = v * self.pf

        out: List[Sample] = []
        inserted = False
        if last is not None and t - last[0] > self.max_gap:
            gap = t - last[0]
            text = (f"gap of {gap:g} s since line {last[3]} exceeds "
                    f"{arg(self.names['max_gap'], f'{self.max_gap:g}')} s")
            if self.policy == "hold":
                t_ins = t - HOLD_EPS
                if not (last[0] < t_ins < t):
                    t_ins = float(math.nextafter(t, -math.inf))
                self._problem(line, self.tcol, text, f"rate held at {self._rate_text(last[1])} until "
                              f"{HOLD_EPS:g} s before this stamp")
                out.append(self._keep(t_ins, last[1], last[2], line))
                inserted = True
            else:
                self._problem(line, self.tcol, text, "gap bridged by linear interpolation")
        if self.volume_mode != "rate" and last is not None and not inserted and q != last[1]:
            # the interval's constant rate starts with a ramp from the previous one
            t_ramp = last[0] + step_ramp(last[0])
            if last[0] < t_ramp < t:
                out.append(self._keep(t_ramp, q, p if p is not None else last[2], line))
        if self.offset is None:
            self._start = row_dt
            if row_dt is None and self.origin is not None and self.zone is not None:
                self._start = self._origin_start(t)
        if not self.accept_implausible:
            self._check_plausible(line, t, q)
        out.append(self._keep(t, q, p, line))
        self.rows_kept += 1
        self.last_q, self.last_p = q, p
        if self.volume_mode == "cumulative":
            v, _ = self.num(cells[self.iq])
            self.last_volume = v * self.qf if v is not None else self.last_volume
        return out

    def _check_plausible(self, line, t: float, q: float) -> None:
        """Stop at a rate beyond any plausible injection, and after the first 11 rows if they
        come faster than any logger writes (a time unit mistake)."""
        option = self.names.get("accept_implausible", "accept_implausible=True")
        if abs(q) > LARGEST_RATE:
            raise InjectionLogError(self.source, line, self.qcol, (
                f"a rate of {q:.6g} m3/s is beyond what one fault interval takes (plausible up "
                f"to {LARGEST_RATE:g} m3/s); check the unit ({self.names['flow_unit']}), or add "
                f"{option} to go on"))
        if len(self._first_rows) <= 10:
            self._first_rows.append(t)
            if len(self._first_rows) == 11:
                median = float(np.median(np.diff(self._first_rows)))
                if median < FASTEST_SAMPLING:
                    raise InjectionLogError(self.source, line, self.tcol, (
                        f"the first 11 rows are {median * 1e3:.3g} ms apart (median): faster "
                        f"than any injection logger; if the time column is not in seconds give "
                        f"its unit with {self.names['time_unit']} (e.g. min or d), or add "
                        f"{option} to go on"))

    def _rate_text(self, q: float) -> str:
        """A rate as the log writes it (its unit), or in m3/s for a volume column."""
        return f"{q / self.qf!r}" if self.volume_mode == "rate" else f"{q!r} m3/s"

    def _origin_start(self, t: float) -> Optional[datetime]:
        """Date-time of the first row of an elapsed log whose time column names its origin
        (``t_days_since_2006-12-02T00:00``) in the zone ``tz``."""
        try:
            origin = datetime.fromisoformat(self.origin.replace(" ", "T"))
            return origin.replace(tzinfo=self.zone) + timedelta(seconds=t)
        except (ValueError, OverflowError):
            return None

    def _keep(self, t, q, p, line) -> Sample:
        if self.offset is None:
            self.offset = t
        self.last = (t, q, p, line)
        # seconds since the first kept stamp, computed as a replay does (time - time[0])
        return Sample(t - self.offset, q, p)

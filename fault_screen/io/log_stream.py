"""Injection logs that grow: the replay's log format read one line at a time.

:class:`LogDecoder` turns the lines of an injection log into samples as they arrive, with the
reader of :mod:`fault_screen.io.injection_log` doing the interpretation (its table, clock and
number readers: separators, decimal commas, units in the header or in a units row, ISO stamps,
local times with ``tz``, times of day with ``date`` and midnight roll-overs, elapsed numbers or
``hh:mm:ss``, column options) and the same checks and ``stop``/``skip``/``hold`` policies, so
that the samples of a complete log are exactly (bit for bit) those of a replay: seconds since
the first kept stamp, m3/s, Pa.

What a stream adds to a file:

* **Setup on the first data row.**  The separator, the column choice, a units row and the
  time format are decided when the header and the first data row are there (the file reader
  may look at up to five rows to choose the separator; for the formats loggers write the two
  agree).
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
from datetime import datetime
from typing import Callable, List, Optional

from .. import units as _units
from .injection_log import (
    FLOW_RATE_RANGE, HOLD_EPS, KEYWORD_NAMES, POLICIES,
    PRESSURE_RANGE, InjectionLogError, _arg, _as_date, _Clock, _delimiter, _norm, _Numbers,
    _column_units, _locate_columns, _split, _Table, _unit_for, _where, _zone, flow_rate_cell,
)

__all__ = ["LogDecoder", "Sample"]


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
    ``feed_line(text, line)`` returns the samples the line adds (0, 1, or 2 when a held gap
    inserts its closing sample); ``end()`` those of a row held back at the end.  Problems raise
    :class:`InjectionLogError` under ``stop`` and go to ``on_warning`` (and ``warnings``) under
    ``skip``/``hold``.
    """

    def __init__(self, source: str = "<stream>", *, flow_unit: Optional[str] = None,
                 pressure_unit: Optional[str] = None, max_gap: Optional[float] = 600.0,
                 policy: str = "stop", date=None, tz=None, time_column=None, flow_column=None,
                 pressure_column=None, option_names: Optional[dict] = None,
                 resume: Optional[dict] = None,
                 on_warning: Optional[Callable[[str], None]] = None, flowback: bool = False):
        self.names = dict(KEYWORD_NAMES)
        self.names.update(option_names or {})
        if policy not in POLICIES:
            raise ValueError(f"policy must be one of {POLICIES}, got {policy!r}")
        max_gap = math.inf if max_gap is None else float(max_gap)
        if not max_gap > 0:
            raise ValueError(f"{_arg(self.names['max_gap'], repr(max_gap))}: must be > 0 s")
        self.source = str(source)
        self.flow_unit, self.pressure_unit = flow_unit, pressure_unit
        self.max_gap, self.policy = max_gap, policy
        self.flowback = flowback   # negative rates allowed (the scene's injection.allow_flowback)
        self.zone = _zone(tz, self.source, self.names["tz"])
        self.day0 = _as_date(date, self.source, self.names["date"])
        self.columns = (time_column, flow_column, pressure_column)
        self.on_warning = on_warning
        self.warnings: List[str] = []
        self.replayed = 0          # rows dropped because a resumed state already holds them
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
                "last": None if self.last is None else [self.last[0], self.last[1], self.last[2]]}

    def new_file(self) -> None:
        """The source now reads a new file (rotation) or the file was truncated."""
        self._expect_header = True

    # -- lines ------------------------------------------------------------------------------
    def _problem(self, line, column, text, action=None):
        if self.policy == "stop" or action is None:
            raise InjectionLogError(self.source, line, column, text)
        self._warn(_where(self.source, line, column) + f"{text}; {action} (policy '{self.policy}')")

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
        s = text.strip()
        if not s or s.startswith("#"):
            return []
        if self._expect_header:
            self._expect_header = False
            if self._header is None:
                self._header = (line, text)
                return []
            if text.strip() == self._header[1].strip():
                return []          # the same header at the top of a new file
        if self._tab is None:
            self._pending.append((line, text))
            return self._setup()
        return self._rows([(line, _split(text, self._tab.delim))])

    def end(self) -> List[Sample]:
        """The stream ended: a held-back partial row is dropped with a warning."""
        if self._held is not None:
            line, _ = self._held
            self._held = None
            self._warn(_where(self.source, line, None) + "last row has a time stamp but no "
                       "values (a partial row written when the logger stopped); dropped")
        return []

    # -- setup: what read_injection_log decides from the header and the first rows -----------
    def _setup(self) -> List[Sample]:
        hline, htext = self._header
        src, names = self.source, self.names
        delim = _delimiter(htext, [t for _, t in self._pending[:5]])
        header = _split(htext, delim)
        cols = []
        for h in header:
            base, unit = _units.parse_header(h)
            cols.append((_norm(base), unit, h))
        tab = _Table(src, "UTF-8", delim, hline, header, cols,
                     [(n, _split(t, delim)) for n, t in self._pending])
        num = _Numbers(delim)
        time_column, flow_column, pressure_column = self.columns
        it, iq, ip, idate = _locate_columns(tab, names, time_column, flow_column, pressure_column)
        row_units = tab.take_units_row(num, iq)
        if not tab.rows:
            # only a units row so far: decide again when a data row comes
            return []
        units = _column_units(tab, row_units, it)
        unit_line = tab.units_line or tab.hline
        qcol = tab.cols[iq][2]
        self.qf, self.qname = _unit_for(src, unit_line, qcol, units[iq], self.flow_unit,
                                        "flow_rate", names["flow_unit"])
        self.pf = self.pname = None
        if ip is not None:
            self.pf, self.pname = _unit_for(src, unit_line, tab.cols[ip][2], units[ip],
                                            self.pressure_unit, "pressure",
                                            names["pressure_unit"])
        self.clock = _Clock(tab, it, idate, units[it], num, self.day0, self.zone, names,
                            self.warnings)
        if self._t_ref is not None:
            self.clock.t_ref = self._t_ref    # the clock of the run resumed (or before rotation)
        self._tab, self.num = tab, num
        self.it, self.iq, self.ip = it, iq, ip
        self.tcol, self.qcol = tab.cols[it][2], qcol
        self.pcol = tab.cols[ip][2] if ip is not None else None
        self.q_hi = FLOW_RATE_RANGE[1] / self.qf
        self.p_lo, self.p_hi = ((PRESSURE_RANGE[0] / self.pf, PRESSURE_RANGE[1] / self.pf)
                                if self.pf else (None, None))
        rows, tab.rows, self._pending = tab.rows, [], []
        return self._rows(rows)

    # -- rows: the checks and policies of read_injection_log, one row at a time --------------
    def _rows(self, rows) -> List[Sample]:
        out: List[Sample] = []
        for line, cells in rows:
            if self._held is not None:
                held, self._held = self._held, None
                out += self._row(*held)
            if self._is_partial(cells):
                self._held = (line, cells)
                continue
            out += self._row(line, cells)
        self._flush_warnings()
        return out

    def _is_partial(self, cells) -> bool:
        it = self.it
        has_stamp = it < len(cells) and cells[it] != ""
        values = [i for i in (self.iq, self.ip) if i is not None]
        return has_stamp and not any(i < len(cells) and cells[i] != "" for i in values)

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

        v, why = flow_rate_cell(self.num, cells[self.iq], self.q_hi, self.qname, self.flowback)
        if why is not None:
            if self.policy == "hold" and self.last_q is not None:
                self._problem(line, self.qcol, why, f"held previous rate {self.last_q / self.qf!r}")
                q = self.last_q
            else:
                self._problem(line, self.qcol, why, "row dropped" if self.policy == "skip" else
                              "row dropped (no previous value to hold)")
                return []
        else:
            q = v * self.qf

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
        if last is not None and t - last[0] > self.max_gap:
            gap = t - last[0]
            text = (f"gap of {gap:g} s since line {last[3]} exceeds "
                    f"{_arg(self.names['max_gap'], f'{self.max_gap:g}')} s")
            if self.policy == "hold":
                t_ins = t - HOLD_EPS
                if not (last[0] < t_ins < t):
                    t_ins = float(math.nextafter(t, -math.inf))
                self._problem(line, self.tcol, text, f"rate held at {last[1] / self.qf!r} until "
                              f"{HOLD_EPS:g} s before this stamp")
                out.append(self._keep(t_ins, last[1], last[2], line))
            else:
                self._problem(line, self.tcol, text, "gap bridged by linear interpolation")
        if self.offset is None:
            self._start = row_dt
        out.append(self._keep(t, q, p, line))
        self.last_q, self.last_p = q, p
        return out

    def _keep(self, t, q, p, line) -> Sample:
        if self.offset is None:
            self.offset = t
        self.last = (t, q, p, line)
        # seconds since the first kept stamp, computed as a replay does (time - time[0])
        return Sample(t - self.offset, q, p)

"""Injection logs that grow: the replay format read one line at a time.

:class:`LogDecoder` turns the lines of an injection log (the CSV format of
:mod:`fault_screen.io.injection_log`: header, ``#`` comments, ISO or elapsed
time column, flow rate and optional pressure with units) into samples as
they arrive, applying the same checks and the same ``stop``/``skip``/``hold``
policies as :func:`~fault_screen.io.injection_log.read_injection_log`, so
that the samples of a complete log are exactly (bit for bit) those of a
replay: times in seconds since the first kept stamp, rates in m3/s,
pressures in Pa.

What a stream adds to a file:

* **New files.**  After a rotation or truncation the source calls
  :meth:`LogDecoder.new_file`; the next non-comment line is taken as a new
  header if it names the same time column as the first header, else as data
  under the old header.  The time origin and the last sample carry over, so
  a rotated log continues the same clock and the same checks.
* **Resume.**  ``LogDecoder(..., resume=state)`` with a :meth:`state` saved
  by an earlier decoder continues after that state's last sample: rows up to
  it (a replay of the log from its start after a restart) are dropped
  silently, the first row after it is checked against it, and ISO stamps
  keep the original origin.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from datetime import datetime
from typing import Callable, List, Optional

from .. import units as _units
from .injection_log import (
    HOLD_EPS, POLICIES, InjectionLogError, _FLOW_NAMES, _TIME_NAMES, _number, _pick, _unit_for,
    _where,
)

__all__ = ["LogDecoder", "Sample"]


@dataclass(frozen=True)
class Sample:
    """One injection sample: ``time`` (s since the log's first stamp), ``flow_rate`` (m3/s, the
    whole interval), ``pressure`` (Pa or None)."""

    time: float
    flow_rate: float
    pressure: Optional[float] = None


def _parse_iso(cell: str) -> datetime:
    txt = cell[:-1] + "+00:00" if cell[-1:] in ("Z", "z") else cell
    return datetime.fromisoformat(txt)


class LogDecoder:
    """Incremental reader of an injection log (see the module docstring).

    ``feed_line(text, line)`` returns the samples the line adds (0, 1, or 2 when a held gap
    inserts its closing sample); problems raise :class:`InjectionLogError` under ``stop`` and
    are passed to ``on_warning`` (and kept in ``warnings``) under ``skip``/``hold``.
    """

    def __init__(self, source: str = "<stream>", *, flow_unit: Optional[str] = None,
                 pressure_unit: Optional[str] = None, max_gap: Optional[float] = 600.0,
                 policy: str = "stop", resume: Optional[dict] = None,
                 on_warning: Optional[Callable[[str], None]] = None):
        if policy not in POLICIES:
            raise ValueError(f"policy must be one of {POLICIES}, got {policy!r}")
        max_gap = math.inf if max_gap is None else float(max_gap)
        if not max_gap > 0:
            raise ValueError(f"max_gap must be > 0 s, got {max_gap!r}")
        self.source = str(source)
        self.flow_unit, self.pressure_unit = flow_unit, pressure_unit
        self.max_gap, self.policy = max_gap, policy
        self.on_warning = on_warning
        self.warnings: List[str] = []
        self.replayed = 0          # rows dropped because a resumed state already holds them
        self._header_seen = False
        self._expect_header = True
        self._time_name: Optional[str] = None
        self.iso: Optional[bool] = None
        self.t_ref: Optional[datetime] = None     # first parsed stamp (ISO logs)
        self.offset: Optional[float] = None       # raw time of the first kept row
        self.last: Optional[tuple] = None         # (raw time, q, p, line) of the last kept row
        self.last_q: Optional[float] = None
        self.last_p: Optional[float] = None
        self._resume_after: Optional[float] = None
        if resume:
            self.iso = resume.get("iso")
            self.t_ref = _parse_iso(resume["t_ref"]) if resume.get("t_ref") else None
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
        """Date-time of model time 0 (ISO logs), else None."""
        if self.t_ref is None or self.offset is None:
            return None
        from datetime import timedelta
        return self.t_ref + timedelta(seconds=self.offset)

    def state(self) -> dict:
        """JSON-able state for ``LogDecoder(resume=...)``."""
        last = None
        if self.last is not None:
            last = [self.last[0], self.last[1], self.last[2]]
        return {"iso": self.iso, "t_ref": self.t_ref.isoformat() if self.t_ref else None,
                "offset": self.offset, "last": last}

    def new_file(self) -> None:
        """The source now reads a new file (rotation) or the file was truncated."""
        self._expect_header = True

    # -- lines ------------------------------------------------------------------------------
    def _problem(self, line, column, text, action=None):
        if self.policy == "stop" or action is None:
            raise InjectionLogError(self.source, line, column, text)
        msg = _where(self.source, line, column) + f"{text}; {action} (policy '{self.policy}')"
        self.warnings.append(msg)
        if self.on_warning is not None:
            self.on_warning(msg)

    def _read_header(self, cells, line) -> None:
        cols = []
        for h in cells:
            base, unit = _units.parse_header(h)
            cols.append((base.strip().lower().replace(" ", "_"), unit, h))
        src = self.source

        def one(kind, exact, prefixes, required):
            hits = _pick(cols, exact, prefixes)
            if len(hits) > 1:
                raise InjectionLogError(src, line, None, f"several {kind} columns "
                                        f"({', '.join(cols[i][2] for i in hits)}); keep one")
            if not hits:
                if required:
                    raise InjectionLogError(
                        src, line, None, f"no {kind} column in header {cells!r} (expected one "
                        f"of: {', '.join(exact + tuple(p + '...' for p in prefixes))})")
                return None
            return hits[0]

        it = one("time", _TIME_NAMES, _TIME_NAMES, True)
        iq = one("flow-rate", _FLOW_NAMES, (), True)
        ip = one("pressure", ("pressure",), ("pressure",), False)
        self.it, self.iq, self.ip = it, iq, ip
        self.tcol, self.qcol = cols[it][2], cols[iq][2]
        self.pcol = cols[ip][2] if ip is not None else None
        self.qf = _unit_for(src, line, self.qcol, cols[iq][1], self.flow_unit, "flow_rate",
                            "flow_unit")
        self.pf = None
        if ip is not None:
            self.pf = _unit_for(src, line, self.pcol, cols[ip][1], self.pressure_unit,
                                "pressure", "pressure_unit")
        t_unit = cols[it][1]
        if t_unit is not None:
            try:
                self.tf = _units.factor(t_unit, "time")
            except _units.UnitError as e:
                raise InjectionLogError(src, line, self.tcol, str(e)) from None
            iso = False
        else:
            self.tf, iso = 1.0, None     # decided by the first time cell
        if self.iso is not None and iso is not None and iso != self.iso:
            raise InjectionLogError(src, line, self.tcol, "the new header changes the time "
                                    "column from ISO stamps to elapsed numbers")
        if iso is not None:
            self.iso = iso
        self._time_name = cols[it][0]
        self.ncol = len(cells)
        self._header_seen = True

    def _looks_like_header(self, cells) -> bool:
        for h in cells:
            base, _ = _units.parse_header(h)
            if base.strip().lower().replace(" ", "_") == self._time_name:
                return True
        return False

    def feed_line(self, text: str, line: Optional[int] = None) -> List[Sample]:
        """Samples added by one line of the log (without its line end)."""
        s = text.strip()
        if not s or s.startswith("#"):
            return []
        cells = [c.strip() for c in next(csv.reader([text]))]
        if self._expect_header:
            self._expect_header = False
            if not self._header_seen or self._looks_like_header(cells):
                self._read_header(cells, line)
                return []
        return self._row(cells, line)

    def _row(self, cells, line) -> List[Sample]:
        ncol = self.ncol
        if len(cells) > ncol and any(cells[ncol:]):
            self._problem(line, None, f"row has {len(cells)} cells but the header has {ncol}",
                          "row dropped")
            return []
        cells = cells + [""] * (ncol - len(cells))
        tcell = cells[self.it]
        if self.iso is None and tcell != "":
            try:
                float(tcell)
                self.iso = False
            except ValueError:
                self.iso = True
        t, why = None, None
        if self.iso:
            if tcell == "":
                why = "empty cell"
            else:
                try:
                    dt = _parse_iso(tcell)
                except ValueError:
                    why = f"not an ISO 8601 timestamp {tcell!r}"
                else:
                    if dt.utcoffset() is None:
                        raise InjectionLogError(self.source, line, self.tcol,
                                                f"timestamp without time zone {tcell!r} "
                                                f"(add an offset such as +01:00 or Z)")
                    if self.t_ref is None:
                        self.t_ref = dt
                    t = (dt - self.t_ref).total_seconds()
        else:
            v, why = _number(tcell)
            if v is not None:
                t = v * self.tf
        if self._resume_after is not None and t is not None and t <= self._resume_after:
            self.replayed += 1
            return []
        if t is None:
            self._problem(line, self.tcol, f"bad time stamp: {why}", "row dropped")
            return []
        self._resume_after = None
        last = self.last
        if last is not None and t < last[0]:
            self._problem(line, self.tcol, f"time going backwards: {tcell} is before the stamp "
                          f"on line {last[3]}", "row dropped")
            return []
        if last is not None and t == last[0]:
            self._problem(line, self.tcol, f"duplicate time stamp {tcell} (same as line "
                          f"{last[3]})", "row dropped")
            return []

        v, why = _number(cells[self.iq])
        if v is not None and v < 0:
            why = f"negative flow rate {cells[self.iq]}"
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
            v, why = _number(cells[self.ip])
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
            text = f"gap of {gap:g} s since line {last[3]} exceeds max_gap={self.max_gap:g} s"
            if self.policy == "hold":
                t_ins = t - HOLD_EPS
                if not (last[0] < t_ins < t):
                    t_ins = float(math.nextafter(t, -math.inf))
                self._problem(line, self.tcol, text, f"rate held at {last[1] / self.qf!r} until "
                              f"{HOLD_EPS:g} s before this stamp")
                out.append(self._keep(t_ins, last[1], last[2], line))
            else:
                self._problem(line, self.tcol, text, "gap bridged by linear interpolation")
        out.append(self._keep(t, q, p, line))
        self.last_q, self.last_p = q, p
        return out

    def _keep(self, t, q, p, line) -> Sample:
        if self.offset is None:
            self.offset = t
        self.last = (t, q, p, line)
        # seconds since the first kept stamp, computed as a replay does (time - time[0])
        return Sample(t - self.offset, q, p)

"""The dialects of injection logs: decoding, separators, columns, units, numbers and stamps.

The pieces :class:`~fault_screen.io.log_stream.LogDecoder` interprets a log with (one line at a
time); :func:`~fault_screen.io.injection_log.read_injection_log` is that decoder fed every line
of a file, so the file reader and the live monitor read the same dialects the same way.  The
formats themselves are described in :mod:`fault_screen.io.injection_log`.
"""

from __future__ import annotations

import codecs
import csv
import math
import os
import re
import unicodedata
from dataclasses import dataclass
from datetime import date, datetime, timedelta, timezone, tzinfo
from typing import List, Optional, Sequence, Tuple
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from fault_screen import units as _units

#: Width (s) of the ramp closing a held gap (policy "hold").
HOLD_EPS = 1e-6
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
        super().__init__(where(source, line, column) + problem)


def where(source: str, line: Optional[int], column: Optional[str]) -> str:
    s = os.path.basename(str(source)) or str(source)
    if line is not None:
        s += f" line {line}"
    if column is not None:
        s += f", column {column}"
    return s + ": "


# ---------------------------------------------------------------------------
# Reader
# ---------------------------------------------------------------------------

#: Largest flow rate (m3/s) taken as a measurement: 10 m3/s is ten times the largest
#: hydraulic-fracturing spreads; anything above is a unit mix-up or a logger fault.
FLOW_RATE_RANGE = (0.0, 10.0)
#: Plausible injection pressures (Pa): a gauge reads a little below zero at worst, and
#: no well or laboratory cell holds 1 GPa.
PRESSURE_RANGE = (-1.0e6, 1.0e9)

#: Years of the stamps taken as instants of an injection.
STAMP_YEARS = (1800, 2300)

#: Names the reader's keywords are given in messages; the CLI passes its option names.
KEYWORD_NAMES = {k: k + "=" for k in ("flow_unit", "pressure_unit", "max_gap", "date", "tz",
                                      "time_unit", "volume_column", "cumulative_volume_column",
                                      "volume_unit", "accept_implausible",
                                      "time_column", "flow_column", "pressure_column")}
#: The same names on the command line.
CLI_OPTION_NAMES = {k: "--" + k.replace("_", "-") for k in KEYWORD_NAMES}
KEYWORD_NAMES["accept_implausible"] = "accept_implausible=True"

# Column names, compared after norm_name (lower case, accents dropped, non-alphanumerics -> "_").
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

DELIMITERS = {",": "comma", ";": "semicolon", "\t": "tab", "|": "pipe"}
_CLOCK = re.compile(r"^(\d{1,3}):([0-5]\d)(?::([0-5]\d(?:[.,]\d*)?))?$")
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$")
_DATE_FORMATS = ("%Y-%m-%d", "%d.%m.%Y", "%Y/%m/%d", "%d.%m.%y")
_STAMP_FORMATS = ("%d.%m.%Y %H:%M:%S", "%d.%m.%Y %H:%M", "%Y/%m/%d %H:%M:%S", "%Y/%m/%d %H:%M",
                  "%d.%m.%Y %H:%M:%S.%f", "%Y/%m/%d %H:%M:%S.%f")
_BINARY_SIGNS = {b"PK\x03\x04": " (a zip archive or an Excel .xlsx workbook? export it as CSV)",
                 b"\xd0\xcf\x11\xe0": " (an Excel .xls workbook? export it as CSV)",
                 b"%PDF": " (a PDF document)",
                 b"\x89HDF": " (an HDF5 file)"}


def arg(name: str, value: str) -> str:
    """``flow_unit='gpm'`` for a keyword, ``--flow-unit 'gpm'`` for an option."""
    return f"{name}{value}" if name.endswith("=") else f"{name} {value}"


def norm_name(name: str) -> str:
    """Column name as compared: ``"Débit (l/min)" -> "debit"`` once the unit is split off."""
    flat = unicodedata.normalize("NFKD", str(name))
    flat = "".join(c for c in flat if not unicodedata.combining(c)).lower()
    return re.sub(r"[^0-9a-z]+", "_", flat).strip("_")


def decode_text(raw: bytes, src: str) -> Tuple[str, str]:
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


def detect_delimiter(header: str, sample: Sequence[str]) -> str:
    """The separator: the candidate most frequent in the header line (which has no decimal
    commas), ties broken by how consistently it appears in the first data lines."""
    best, best_key = ",", (0, 0)
    for d in DELIMITERS:
        n = header.count(d)
        if n == 0:
            continue
        steady = sum(1 for line in sample if line.count(d) >= n)
        if (n, steady) > best_key:
            best, best_key = d, (n, steady)
    if best_key[0] == 0 and len(header.split()) > 1 and all(len(s.split()) > 1 for s in sample):
        return " "           # columns aligned with blanks
    return best


class CellError(ValueError):
    """A line that cannot be split into cells (an unbalanced quote, a cell beyond any size)."""


#: longest cell (characters) taken as a cell; beyond it the line is a bad row
MAX_CELL = 65536


def split_cells(text: str, delim: str) -> List[str]:
    """The cells of one line (stripped); :class:`CellError` for a line that is not a table row."""
    if delim == " ":
        cells = text.split()
    else:
        try:
            cells = [c.strip() for c in next(csv.reader([text], delimiter=delim, strict=True))]
        except (csv.Error, StopIteration) as exc:
            raise CellError(f"the line cannot be split into cells ({exc})") from None
    if any(len(c) > MAX_CELL for c in cells):
        raise CellError(f"a cell of more than {MAX_CELL} characters")
    return cells


_LINE_END = re.compile(r"\r\n|\r|\n")
_LINE_END_BYTES = re.compile(rb"\r\n|\r|\n")


def split_lines(text: str) -> List[str]:
    """The lines of a text, ended by LF, CR LF or a lone CR (old Mac files): the ends the
    live reader (:class:`LineSplitter`) knows, so both number lines alike."""
    lines = _LINE_END.split(text)
    if lines and lines[-1] == "":
        lines.pop()
    return lines


class LineSplitter:
    """Complete lines of a byte stream, numbered from 1, decoded as the file reader decodes.

    A UTF-16 stream is known by its byte-order mark; otherwise each line is UTF-8 (a BOM at
    the start dropped), else Windows-1252, else ISO 8859-1, so a Latin-1 header reads as it does
    from a file.  Lines end with LF, CR LF or a lone CR; a CR at the end of the data waits for
    the next piece (it may be the first half of CR LF).  A line longer than ``max_line``
    characters is cut there (the decoder then finds a bad row), so memory stays bounded.
    """

    def __init__(self, max_line: int = 4 * MAX_CELL):
        self.max_line = max_line
        self.reset()

    def reset(self) -> None:
        self.buf = bytearray()   # bytes of the partial last line (no line end but a final CR)
        self.parts: List[str] = []   # decoded pieces of the partial last line (UTF-16)
        self.size = 0                # characters in parts
        self.number = 0
        self.utf16 = None        # incremental decoder once a UTF-16 BOM is seen
        self.started = False
        self.encodings = set()

    def push(self, data: bytes):
        """(number, text) of the lines completed by ``data``."""
        if not self.started:
            self.buf += data
            if len(self.buf) < 3 and b"\n" not in self.buf and b"\r" not in self.buf:
                return []
            self._start()
            data, self.buf = bytes(self.buf), bytearray()
        if self.utf16 is not None:
            return self._text_piece(self.utf16.decode(data), final=False)
        return self._byte_piece(data, final=False)

    def rest(self):
        """The lines left when no more data comes (a partial last line taken as complete)."""
        if not self.started:
            if not self.buf:
                return []
            self._start()
            data, self.buf = bytes(self.buf), bytearray()
        else:
            data = b""
        if self.utf16 is not None:
            return self._text_piece(self.utf16.decode(data, final=True), final=True)
        return self._byte_piece(data, final=True)

    @property
    def encoding(self) -> str:
        if self.utf16 is not None:
            return "UTF-16"
        for name in ("Latin-1 (ISO 8859-1)", "Latin-1 (Windows-1252)"):
            if name in self.encodings:
                return name
        return "UTF-8"

    def _start(self) -> None:
        self.started = True
        if self.buf.startswith((b"\xff\xfe", b"\xfe\xff")):
            self.utf16 = codecs.getincrementaldecoder("utf-16")(errors="replace")
        elif self.buf.startswith(b"\xef\xbb\xbf"):
            del self.buf[:3]

    def _byte_piece(self, data: bytes, final: bool):
        # the partial line is scanned again only when a line end arrives: linear in the data
        # however small the pieces it comes in
        scan = final or b"\n" in data or b"\r" in data or self.buf.endswith(b"\r")
        self.buf += data
        out = []
        if scan:
            parts = _LINE_END_BYTES.split(bytes(self.buf))
            keep = parts.pop()
            if not final and self.buf.endswith(b"\r") and parts:
                keep = parts.pop() + b"\r"      # perhaps CR LF split between two reads
            out = [self._line(self._decode(b)) for b in parts]
            if final:
                if keep.strip():
                    out.append(self._line(self._decode(keep.rstrip(b"\r"))))
                keep = b""
            self.buf = bytearray(keep)
        while len(self.buf) > self.max_line:
            out.append(self._line(self._decode(bytes(self.buf[:self.max_line]))))
            del self.buf[:self.max_line]
        return out

    def _text_piece(self, text: str, final: bool):
        scan = final or "\n" in text or "\r" in text or (
            bool(self.parts) and self.parts[-1].endswith("\r"))
        self.parts.append(text)
        self.size += len(text)
        out = []
        keep = None
        if scan:
            whole = "".join(self.parts)
            parts = _LINE_END.split(whole)
            keep = parts.pop()
            if not final and whole.endswith("\r") and parts:
                keep = parts.pop() + "\r"
            out = [self._line(t) for t in parts]
            if final:
                if keep.strip():
                    out.append(self._line(keep.rstrip("\r")))
                keep = ""
        if self.size > self.max_line:
            keep = "".join(self.parts) if keep is None else keep
            while len(keep) > self.max_line:
                out.append(self._line(keep[:self.max_line]))
                keep = keep[self.max_line:]
        if keep is not None:
            self.parts, self.size = [keep], len(keep)
        return out

    def _decode(self, b: bytes) -> str:
        for enc, name in (("utf-8", "UTF-8"), ("cp1252", "Latin-1 (Windows-1252)")):
            try:
                text = b.decode(enc)
            except UnicodeDecodeError:
                continue
            self.encodings.add(name)
            return text
        self.encodings.add("Latin-1 (ISO 8859-1)")
        return b.decode("latin-1")

    def _line(self, text: str):
        self.number += 1
        if self.number == 1 and text.startswith("\ufeff"):
            text = text[1:]
        return self.number, text


def unit_for(src, line, col_raw, header_unit, arg_unit, quantity, argname):
    """(factor to SI, canonical unit name)."""
    if header_unit is not None and arg_unit is not None:
        try:
            same = _units.factor(header_unit, quantity) == _units.factor(arg_unit, quantity)
        except _units.UnitError as e:
            raise InjectionLogError(src, line, col_raw, str(e)) from None
        if not same:
            raise InjectionLogError(
                src, line, col_raw,
                f"the file's unit {header_unit!r} conflicts with {arg(argname, repr(arg_unit))}")
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


def _is_unit(text: str, quantity: str) -> bool:
    try:
        _units.factor(text, quantity)
    except _units.UnitError:
        return False
    return True


def _bare_unit(cell: str) -> Optional[str]:
    """A unit cell of a units row: ``"[l/min]"``, ``"(bar)"`` or ``"l/min"``."""
    c = cell.strip()
    if len(c) >= 2 and c[0] + c[-1] in ("[]", "()"):
        c = c[1:-1].strip()
    return c or None


class Numbers:
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


def clock_seconds(cell: str) -> Optional[float]:
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


def parse_stamp(cell: str) -> Optional[datetime]:
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


def zone_of(tz, src, name):
    if tz is None or isinstance(tz, tzinfo):
        return tz
    try:
        return ZoneInfo(str(tz))
    except (ZoneInfoNotFoundError, ValueError):
        raise InjectionLogError(src, None, None,
                                f"{arg(name, repr(tz))}: unknown time zone (use an IANA name such as "
                                f"Europe/Zurich, America/Denver or UTC)") from None


def as_date(value, src, name) -> Optional[date]:
    if value is None or (isinstance(value, date) and not isinstance(value, datetime)):
        return value
    d = _parse_date(str(value))
    if d is None:
        raise InjectionLogError(src, None, None, f"{arg(name, repr(value))}: not a date (YYYY-MM-DD)")
    return d


@dataclass
class Table:
    """A log's text split into cells, before any cell is interpreted."""

    src: str
    encoding: str
    delim: str
    hline: int                                    # line of the header
    header: List[str]
    cols: List[Tuple[str, Optional[str], str]]    # (normalised name, unit or None, as written)
    rows: List[Tuple[int, List[str]]]             # (line, cells) of the data rows
    units_line: Optional[int] = None              # line of a second header row of units

    def error(self, line, column, text) -> InjectionLogError:
        return InjectionLogError(self.src, line, column, text)

    def named(self, spec, option) -> int:
        """Index of the column the user named (header as written or without its unit, or a
        1-based position)."""
        txt = str(spec).strip()
        if txt.isdigit():
            k = int(txt)
            if not 1 <= k <= len(self.header):
                raise self.error(self.hline, None, f"{arg(option, repr(txt))}: the header has "
                                 f"{len(self.header)} columns ({', '.join(self.header)})")
            return k - 1
        for i, (b, _, h) in enumerate(self.cols):
            if txt.lower() in (h.lower(), _units.parse_header(h)[0].strip().lower()) or norm_name(txt) == b:
                return i
        raise self.error(self.hline, None, f"{arg(option, repr(txt))}: no such column; columns: "
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

    def take_units_row(self, num: "Numbers", iq: int) -> List[Optional[str]]:
        """Units of a second header row (removed from the rows), or [] if there is none: the
        flow column's cell of the first row is a flow-rate unit, not a number."""
        if not self.rows:
            return []
        n1, r1 = self.rows[0]
        cell = _bare_unit(r1[iq]) if iq < len(r1) else None
        if cell is None or num.ok(r1[iq]):
            return []
        if not any(_is_unit(cell, q) for q in ("flow_rate", "volume")):
            return []
        self.units_line = n1
        self.rows = self.rows[1:]
        return [_bare_unit(c) for c in r1] + [None] * (len(self.header) - len(r1))


#: time-column cells of a units row that describe a format, not a unit
_TIME_FORMAT_HINTS = ("hh_mm_ss", "hh_mm", "iso", "iso_8601", "utc", "local", "date_time",
                      "datetime", "yyyy_mm_dd_hh_mm_ss")


class Clock:
    """Reads a log's time cells as seconds since its first stamp, in one of five modes:
    ``elapsed`` numbers, ``elapsed_clock`` (hh:mm:ss), ``stamp`` (date-times), ``time_of_day``
    (with the ``date`` argument; midnight roll-overs) and ``date_column`` (times of day with a
    date column)."""

    def __init__(self, table: Table, it: int, idate: Optional[int], t_unit: Optional[str],
                 num: "Numbers", day0: Optional[date], zone, names: dict, warnings: List[str]):
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
        elif clock_seconds(first[1]) is not None:
            if table.cols[it][0].startswith(_ELAPSED_PREFIXES):
                self.mode = "elapsed_clock"
            else:
                self.mode = "date_column" if idate is not None else "time_of_day"
        else:
            self.mode = "stamp"
        if self.mode == "time_of_day" and day0 is None:
            raise table.error(first[0], self.col,
                              f"time of day {first[1]!r} without a date: pass {arg(names['date'], 'YYYY-MM-DD')} "
                              f"(the day of the first row) and {arg(names['tz'], 'ZONE')}")
        if self.mode in ("time_of_day", "date_column") and zone is None:
            raise table.error(first[0], self.col,
                              f"local times of day {first[1]!r}: the time zone is unknown; pass "
                              f"{arg(names['tz'], 'ZONE')} (e.g. Europe/Zurich, or UTC)")

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
            if v is not None and not math.isfinite(v * self.factor):
                return None, f"elapsed time {cell!r} beyond any calendar", None
            return (None if v is None else v * self.factor), why, None
        if self.mode == "elapsed_clock":
            sec = clock_seconds(cell)
            if sec is None:
                return None, f"not an elapsed time {cell!r} (hh:mm:ss)", None
            if cell.count(":") != 2:
                return None, f"elapsed time {cell!r} is ambiguous (mm:ss or hh:mm): write hh:mm:ss", None
            return sec, None, None
        try:
            dt, why = self._instant(line, cell, cells, last)
            if dt is None:
                return None, why, None
            # differences in UTC: aware datetimes of one zone subtract as wall clocks
            utc = dt.astimezone(timezone.utc)
        except OverflowError:
            return None, f"date-time {cell!r} at the edge of the calendar (out of range)", None
        if not STAMP_YEARS[0] <= utc.year <= STAMP_YEARS[1]:
            # a logger whose clock was never set; and times near the calendar's edges overflow
            # where they are shifted later (alert times, plots)
            return None, (f"date-time {cell!r} outside the years {STAMP_YEARS[0]} to "
                          f"{STAMP_YEARS[1]} (a logger clock not set?)"), None
        if self.t_ref is None:
            self.t_ref = utc
        return (utc - self.t_ref).total_seconds(), None, dt

    def _instant(self, line, cell, cells, last):
        if self.mode == "stamp":
            dt = parse_stamp(cell)
            if dt is None:
                return None, f"not a date-time {cell!r} (ISO 8601, e.g. 2015-03-12T10:00:00+01:00)"
            if dt.utcoffset() is None:
                if self.zone is None:
                    # never held/skipped: the instant itself is unknown
                    raise self.table.error(
                        line, self.col, f"timestamp without time zone {cell!r} (add an offset such "
                        f"as +01:00 or Z, or give the zone with {arg(self.names['tz'], 'ZONE')})")
                dt = dt.replace(tzinfo=self.zone)
            return dt, None
        sec = clock_seconds(cell)
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
            self.warnings.append(where(self.table.src, line, self.col) +
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


def column_units(tab, row_units, it: int) -> list:
    """Each column's unit: the header's, or the units row's (which must agree with a header
    unit; a time-format hint such as hh:mm:ss in the time column is not a unit)."""
    units = [u for _, u, _ in tab.cols]
    for i, u in enumerate(row_units):
        if u is None or (i == it and norm_name(u) in _TIME_FORMAT_HINTS):
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


_NAME_TIME_UNIT = re.compile(r"(?:t|time|elapsed|elapsed_time)_([a-z]+)(?:_since(?:_|$)|$)")
_CUMULATIVE = ("cumulative_volume", "volume_cumulative", "v_cumulative", "v_cum", "cum_volume",
               "cumulative", "v_total", "total_volume")
_CUMULATIVE_PREFIXES = ("cumulative", "v_cum", "cum_vol", "volume_cum", "total_vol")
_INTERVAL_VOLUME = ("dv", "delta_v", "volume", "interval_volume", "vol", "v")


def unit_in_name(name: str, quantity: str) -> Optional[str]:
    """The unit written inside a column name, as in ``t_days_since_2006-12-02T00:00`` (time)
    or ``V_cumulative_m3`` (volume): the one word of the name that is a unit of ``quantity``;
    None if no word, or several, are."""
    words = norm_name(name).split("_")
    if quantity == "time":
        m = _NAME_TIME_UNIT.match(norm_name(name))
        words = [m.group(1)] if m else []
    hits = set()
    for w in words:
        try:
            hits.add(_units.canonical(w, quantity))
        except _units.UnitError:
            pass
    return hits.pop() if len(hits) == 1 else None


def origin_in_name(name: str) -> Optional[str]:
    """The date-time after ``since`` in a time column's name (``..._since_2006-12-02T00:00``),
    as written; None without one."""
    m = re.search(r"since[ _]+(\d{4}-\d{2}-\d{2}(?:[T ]\d{2}:\d{2}(?::\d{2})?)?)", str(name))
    return m.group(1) if m else None


@dataclass(frozen=True)
class Columns:
    """Indices of a log's columns: ``time``; one of ``flow`` (rate), ``volume`` (volume of the
    interval since the previous row) or ``cumulative`` (volume since the start); ``pressure``
    and ``date`` (or None)."""

    time: int
    flow: Optional[int]
    volume: Optional[int]
    cumulative: Optional[int]
    pressure: Optional[int]
    date: Optional[int]

    @property
    def value(self) -> int:
        """The column the rate comes from."""
        return next(i for i in (self.flow, self.volume, self.cumulative) if i is not None)


def locate_columns(tab, names, time_column, flow_column, pressure_column,
                   volume_column=None, cumulative_volume_column=None) -> Columns:
    """The columns of a log's table: the named ones, else detected from the headers (a rate
    column first, else a cumulative volume, else a volume per interval). One place for the file
    reader and the live stream decoder, so both accept and refuse the same headers."""
    if time_column is not None:
        it = tab.named(time_column, names["time_column"])
    else:
        it = tab.detected("time", _TIME_EXACT, _TIME_PREFIXES, names["time_column"], False)
        if it is None:
            hits = [i for i, (b, _, _) in enumerate(tab.cols) if _NAME_TIME_UNIT.match(b)]
            it = hits[0] if len(hits) == 1 else None
        if it is None:
            tab.detected("time", _TIME_EXACT, _TIME_PREFIXES, names["time_column"], True)
    given = [(k, v) for k, v in (("flow", flow_column), ("volume", volume_column),
                                 ("cumulative", cumulative_volume_column)) if v is not None]
    if len(given) > 1:
        raise tab.error(tab.hline, None, "give one of " + ", ".join(
            names[k] for k in ("flow_column", "volume_column", "cumulative_volume_column")))
    found = {"flow": None, "volume": None, "cumulative": None}
    if given:
        kind, spec = given[0]
        found[kind] = tab.named(spec, names[{"flow": "flow_column", "volume": "volume_column",
                                             "cumulative": "cumulative_volume_column"}[kind]])
    else:
        found["flow"] = tab.detected("flow-rate", _FLOW_EXACT, _FLOW_PREFIXES,
                                     names["flow_column"], False, (it,))
        if found["flow"] is None:
            found["cumulative"] = tab.detected("cumulative volume", _CUMULATIVE, _CUMULATIVE_PREFIXES,
                                               names["cumulative_volume_column"], False, (it,))
        if found["flow"] is None and found["cumulative"] is None:
            found["volume"] = tab.detected("volume", _INTERVAL_VOLUME, ("dv_", "volume_"),
                                           names["volume_column"], False, (it,))
        if all(v is None for v in found.values()):
            tab.detected("flow-rate", _FLOW_EXACT, _FLOW_PREFIXES, names["flow_column"] +
                         f" (or {names['volume_column']}, {names['cumulative_volume_column']})",
                         True, (it,))
    iq = next(v for v in found.values() if v is not None)
    ip = (tab.named(pressure_column, names["pressure_column"]) if pressure_column is not None else
          tab.detected("pressure", _PRESSURE_EXACT, _PRESSURE_PREFIXES, names["pressure_column"],
                       False, (it, iq)))
    used = [i for i in (it, iq, ip) if i is not None]
    if len(set(used)) < len(used):
        raise tab.error(tab.hline, None, "the time, flow-rate and pressure columns must be "
                        "different columns")
    idate = next((i for i, (b, _, _) in enumerate(tab.cols) if b in _DATE_EXACT and i not in used), None)
    return Columns(it, found["flow"], found["volume"], found["cumulative"], ip, idate)

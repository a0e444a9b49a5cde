"""Seismic event catalogues: QuakeML (and the other formats obspy reads), CSV and FDSN text.

:func:`read_events` returns the events' origin times as seconds relative to a reference
date-time (model time 0: the injection log's first stamp), their magnitudes with the magnitude
type kept per event (ML and mb are different scales), and their locations where the catalogue
has them.  With a ``site`` (the scene's ``[site]`` table: the injection point in the
catalogue's frame and the fault's strike and dip) each event also gets its distance to the
injection point and to the modelled fault plane.

CSV catalogues: one header line, separator detected as for injection logs.  Columns (case and
accents ignored, units in brackets or parentheses): time ``isotime``, ``time``,
``origin_time``, ``datetime`` (ISO 8601; without an offset the time is UTC, the seismological
convention); magnitude ``mag``/``magnitude`` (or ``ml``, ``mw``, ``mb``...: the column name is
then the type) with ``mag_type``/``magnitude_type``/``magtype``; location either
``latitude``/``longitude`` (degrees) with ``depth`` (km unless the header gives a unit, as in
USGS and FDSN exports), or local ``x``/``y``/``z`` in metres (x east, y north, z up; or
``depth`` in metres, positive down).  FDSN text (``#EventID|Time|Latitude|Longitude|Depth/km|
...|MagType|Magnitude|...``) is recognised by its header.  obspy is imported only for QuakeML
and the other obspy formats.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Optional, Tuple

import numpy as np

from .. import units as _units

__all__ = ["EventCatalog", "EventsError", "read_events", "fault_normal"]


class EventsError(ValueError):
    """A catalogue that cannot be read; the message names the file."""


_ARRAYS = ("time", "magnitude", "latitude", "longitude", "depth", "x", "y", "z",
           "distance_to_injection", "distance_to_fault")


@dataclass(frozen=True, eq=False)
class EventCatalog:
    """Events sorted by origin time.

    time : float64 array, s relative to ``start`` (negative before it)
    magnitude : float64 array, NaN where an event has no magnitude (negative values are normal:
        micro-seismicity)
    magnitude_type : str per event ("" if unknown)
    start : aware UTC datetime of ``time == 0`` (None for an empty catalogue without a start)
    source : the file read
    skipped : number of events without an origin time (not included)
    latitude, longitude (degrees), depth (m, positive down) : geographic locations, or
    x, y, z (m, local frame, z up) : local locations; NaN where unknown, None if the
        catalogue has no such columns
    distance_to_injection, distance_to_fault : m, NaN where unknown, None without a site
    notes : what the reader assumed or could not do (for the user)
    """

    time: np.ndarray
    magnitude: np.ndarray
    magnitude_type: Tuple[str, ...] = ()
    start: Optional[datetime] = None
    source: str = ""
    skipped: int = 0
    latitude: Optional[np.ndarray] = None
    longitude: Optional[np.ndarray] = None
    depth: Optional[np.ndarray] = None
    x: Optional[np.ndarray] = None
    y: Optional[np.ndarray] = None
    z: Optional[np.ndarray] = None
    distance_to_injection: Optional[np.ndarray] = None
    distance_to_fault: Optional[np.ndarray] = None
    notes: Tuple[str, ...] = field(default=())

    def __len__(self) -> int:
        return int(self.time.size)

    def origin_times(self):
        """Origin times as aware UTC datetimes."""
        if self.start is None:
            return []
        return [self.start + timedelta(seconds=float(t)) for t in self.time]

    def _subset(self, keep) -> "EventCatalog":
        arrays = {k: getattr(self, k)[keep] for k in _ARRAYS if getattr(self, k) is not None}
        types = tuple(m for m, k in zip(self.magnitude_type, keep) if k)
        return replace(self, magnitude_type=types, **arrays)

    def window(self, t0: float, t1: float) -> "EventCatalog":
        """The events with ``t0 <= time <= t1`` (s)."""
        return self._subset((self.time >= t0) & (self.time <= t1))

    def to_arrays(self, t0: float, t1: float) -> dict:
        """The ``/events`` group of a result: every event read, ``in_run`` 1 for those with
        ``t0 <= time <= t1`` (s), locations and distances where known (NaN otherwise)."""
        out = {"time": self.time, "magnitude": self.magnitude,
               "magnitude_type": np.array([m.encode() for m in self.magnitude_type], dtype="S16"),
               "in_run": ((self.time >= t0) & (self.time <= t1)).astype(np.uint8)}
        for k in _ARRAYS[2:]:
            if getattr(self, k) is not None:
                out[k] = getattr(self, k)
        return out


def _to_utc(dt: datetime) -> datetime:
    if dt.utcoffset() is None:
        raise EventsError(f"start {dt.isoformat()} has no time zone")
    return dt.astimezone(timezone.utc)


# ---- site geometry -----------------------------------------------------------------------
def fault_normal(strike_deg: float, dip_deg: float) -> np.ndarray:
    """Unit normal (east, north, up) of a plane of strike (clockwise from north) and dip (down
    to the right of the strike direction)."""
    s, d = math.radians(strike_deg), math.radians(dip_deg)
    # strike (sin s, cos s, 0) and down-dip (cos d cos s, -cos d sin s, -sin d) span the plane
    return np.array([math.sin(d) * math.cos(s), -math.sin(d) * math.sin(s), math.cos(d)])


def _site_frame(site) -> Optional[str]:
    if site is None:
        return None
    if getattr(site, "latitude", None) is not None:
        return "geographic"
    if getattr(site, "x", None) is not None:
        return "local"
    return None


def _offsets(cat: EventCatalog, site) -> Tuple[Optional[np.ndarray], str]:
    """(n, 3) east/north/up offsets (m) of the events from the injection point, or None and
    why not."""
    frame = _site_frame(site)
    if frame is None:
        return None, "event distances need the injection point's location: add a [site] table " \
                     "(latitude/longitude/depth or x/y/z in the catalogue's frame)"
    up0 = -float(site.depth) if getattr(site, "depth", None) is not None else float(getattr(site, "z", 0.0) or 0.0)
    if frame == "geographic":
        if cat.latitude is None:
            return None, "the catalogue has no latitude/longitude but [site] is geographic: " \
                         "distances left empty"
        from pyproj import Geod

        n = len(cat)
        lat0 = np.full(n, float(site.latitude))
        lon0 = np.full(n, float(site.longitude))
        az, _, dist = Geod(ellps="WGS84").inv(lon0, lat0, cat.longitude, cat.latitude)
        az, dist = np.asarray(az, float), np.asarray(dist, float)
        up = -cat.depth if cat.depth is not None else np.full(n, np.nan)
        return np.column_stack([dist * np.sin(np.radians(az)), dist * np.cos(np.radians(az)),
                                up - up0]), ""
    if cat.x is None:
        return None, "the catalogue has no local x/y but [site] gives x/y: distances left empty"
    up = cat.z if cat.z is not None else (-cat.depth if cat.depth is not None
                                          else np.full(len(cat), np.nan))
    return np.column_stack([cat.x - float(site.x), cat.y - float(site.y), up - up0]), ""


def with_distances(cat: EventCatalog, site) -> EventCatalog:
    """The catalogue with its distances to the injection point (straight line, m) and to the
    fault plane through it (m, needs ``site.strike`` and ``site.dip``)."""
    off, why = _offsets(cat, site)
    if off is None:
        return replace(cat, notes=cat.notes + (why,))
    d_inj = np.sqrt(np.sum(off ** 2, axis=1))
    notes = cat.notes
    if getattr(site, "strike", None) is not None and getattr(site, "dip", None) is not None:
        d_fault = np.abs(off @ fault_normal(float(site.strike), float(site.dip)))
    else:
        d_fault = np.full(len(cat), np.nan)
        notes += ("distances to the fault plane need [site] strike and dip",)
    return replace(cat, distance_to_injection=d_inj, distance_to_fault=d_fault, notes=notes)


# ---- readers -------------------------------------------------------------------------------
_TIME = ("isotime", "time", "origin_time", "origintime", "datetime", "date_time", "event_time")
_MAG = ("mag", "magnitude", "preferred_magnitude")
_MAG_NAMED = ("ml", "mw", "mb", "ms", "md", "mc", "mwr", "mlv", "mlhc")
_MAG_TYPE = ("mag_type", "magtype", "magnitude_type", "magnitudetype", "type_mag")
_LAT, _LON = ("latitude", "lat"), ("longitude", "lon", "long", "lng")


def _parse_time(cell: str) -> Optional[datetime]:
    from .log_format import parse_stamp

    dt = parse_stamp(cell) if cell else None
    if dt is None:
        return None
    try:
        return dt.replace(tzinfo=timezone.utc) if dt.utcoffset() is None else \
            dt.astimezone(timezone.utc)
    except OverflowError:        # an offset pushing the instant past the calendar's edge
        return None


def _read_table(p: Path, src: str):
    """(header, rows, kind) of a CSV or FDSN text catalogue; rows are (line, cells), with cells
    None for a line that cannot be split."""
    from .log_format import (CellError, InjectionLogError, decode_text, detect_delimiter,
                             split_cells, split_lines)

    try:
        text, _ = decode_text(p.read_bytes(), src)
    except InjectionLogError as exc:
        raise EventsError(f"{src}: {exc.problem}") from None
    lines = [(n, ln) for n, ln in enumerate(split_lines(text), start=1) if ln.strip()]
    if lines and lines[0][1].lstrip().lower().startswith("#eventid"):
        header = [c.strip() for c in lines[0][1].lstrip()[1:].split("|")]
        rows = [(n, [c.strip() for c in ln.split("|")]) for n, ln in lines[1:]
                if not ln.startswith("#")]
        return header, rows, "FDSN text"
    lines = [(n, ln) for n, ln in lines if not ln.lstrip().startswith("#")]
    if not lines:
        raise EventsError(f"{src}: empty catalogue (no header line)")
    delim = detect_delimiter(lines[0][1], [ln for _, ln in lines[1:6]])
    try:
        header = split_cells(lines[0][1], delim)
    except CellError as exc:
        raise EventsError(f"{src} line {lines[0][0]}: header: {exc}") from None
    rows = []
    for n, ln in lines[1:]:
        try:
            rows.append((n, split_cells(ln, delim)))
        except CellError:
            rows.append((n, None))
    return header, rows, "CSV"


def _read_csv(p: Path, src: str, bad_rows: str = "raise"):
    """Per-event lists from a CSV/FDSN text catalogue (times as aware UTC datetimes).  A bad
    row raises :class:`EventsError`, or with ``bad_rows="skip"`` is left out with a note naming
    it."""
    from .log_format import norm_name

    header, rows, kind = _read_table(p, src)
    cols = {}
    for i, h in enumerate(header):
        base, unit = _units.parse_header(h)
        name = norm_name(base)
        if name.startswith("depth_"):        # FDSN "Depth/km"
            name, unit = "depth", unit or h.split("/", 1)[-1].strip()
        cols.setdefault(name, (i, unit, h))

    def find(names):
        return next((cols[n] for n in names if n in cols), None)

    tcol = find(_TIME)
    if tcol is None:
        raise EventsError(f"{src}: no origin-time column in the header ({', '.join(header)[:200]}); "
                          f"expected one of: {', '.join(_TIME[:4])}")
    mcol = find(_MAG)
    mtype_fixed = ""
    if mcol is None:
        named = next((n for n in _MAG_NAMED if n in cols), None)
        if named is not None:
            mcol, mtype_fixed = cols[named], cols[named][2]
    tycol = find(_MAG_TYPE)
    lat, lon = find(_LAT), find(_LON)
    xc, yc, zc = cols.get("x"), cols.get("y"), cols.get("z")
    dc = cols.get("depth")
    geographic = lat is not None and lon is not None
    local = xc is not None and yc is not None
    notes = []

    def factor(col, default, quantity="length"):
        if col is None or col[1] is None:
            return default
        try:
            return _units.factor(col[1], quantity)
        except _units.UnitError as exc:
            raise EventsError(f"{src}: column {col[2]}: {exc}") from None

    depth_f = factor(dc, 1e3 if geographic else 1.0)
    if geographic and dc is not None and dc[1] is None:
        notes.append(f"depth column '{dc[2]}' without a unit taken in km (USGS/FDSN convention)")
    xyz_f = factor(xc, 1.0)
    z_f = factor(zc, 1.0)

    def num(cells, col, what, line):
        if col is None or col[0] >= len(cells) or cells[col[0]] == "":
            return math.nan
        try:
            v = float(cells[col[0]])
        except ValueError:
            raise EventsError(f"{src} row {line}, column {col[2]}: not a number "
                              f"{cells[col[0]][:40]!r} ({what})") from None
        if not math.isfinite(v):
            # an infinite magnitude would fire every magnitude rule
            raise EventsError(f"{src} row {line}, column {col[2]}: not a finite number "
                              f"{cells[col[0]]!r} ({what})")
        return v

    out = {k: [] for k in ("time", "mag", "mtype", "lat", "lon", "depth", "x", "y", "z")}
    skipped = 0
    naive = False
    for line, cells in rows:
        try:
            if cells is None:
                raise EventsError(f"{src} row {line}: the line cannot be split into cells")
            cell = cells[tcol[0]] if tcol[0] < len(cells) else ""
            when = _parse_time(cell)
            if when is None:
                if cell:
                    raise EventsError(f"{src} row {line}, column {tcol[2]}: not an ISO 8601 "
                                      f"time {cell[:40]!r}")
                skipped += 1
                continue
            event = {"time": when, "mag": num(cells, mcol, "magnitude", line),
                     "mtype": (cells[tycol[0]] if tycol is not None and tycol[0] < len(cells)
                               else mtype_fixed)}
            if geographic:
                event["lat"] = num(cells, lat, "latitude", line)
                event["lon"] = num(cells, lon, "longitude", line)
            if local:
                event["x"] = num(cells, xc, "x", line) * xyz_f
                event["y"] = num(cells, yc, "y", line) * xyz_f
                event["z"] = num(cells, zc, "z", line) * z_f
            event["depth"] = num(cells, dc, "depth", line) * depth_f
        except EventsError as exc:
            if bad_rows != "skip":
                raise
            notes.append(f"{exc}: row skipped")
            continue
        naive |= not any(c in cell[10:] for c in "Zz+-")
        for k, v in event.items():
            out[k].append(v)
    if naive:
        notes.append("origin times without a zone taken as UTC")
    if mcol is None:
        notes.append("no magnitude column: magnitudes left empty")
    locs = {}
    if geographic:
        locs.update(latitude=out["lat"], longitude=out["lon"], depth=out["depth"])
    elif local:
        locs.update(x=out["x"], y=out["y"])
        if zc is not None:
            locs["z"] = out["z"]
        elif dc is not None:
            locs["depth"] = out["depth"]
    return out["time"], out["mag"], out["mtype"], locs, skipped, notes, kind


def _read_obspy(p: Path, src: str, format):
    import obspy

    try:
        cat = obspy.read_events(str(p), format=format)
    except Exception as exc:  # obspy raises TypeError/ValueError/XML errors for bad files
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise EventsError(f"{src}: cannot read as an event catalogue (QuakeML, CSV or FDSN "
                          f"text): {why}") from None
    times, mags, mtypes, lat, lon, dep, skipped = [], [], [], [], [], [], 0
    for ev in cat:
        org = ev.preferred_origin() or (ev.origins[0] if ev.origins else None)
        if org is None or org.time is None:
            skipped += 1
            continue
        mag = ev.preferred_magnitude() or (ev.magnitudes[0] if ev.magnitudes else None)
        times.append(org.time.datetime.replace(tzinfo=timezone.utc))
        if mag is not None and mag.mag is not None and math.isfinite(float(mag.mag)):
            mags.append(float(mag.mag))
            mtypes.append(mag.magnitude_type or "")
        else:
            mags.append(math.nan)
            mtypes.append("")
        lat.append(math.nan if org.latitude is None else float(org.latitude))
        lon.append(math.nan if org.longitude is None else float(org.longitude))
        dep.append(math.nan if org.depth is None else float(org.depth))   # QuakeML: m
    locs = {}
    if any(math.isfinite(v) for v in lat):
        locs = {"latitude": lat, "longitude": lon, "depth": dep}
    return times, mags, mtypes, locs, skipped, [], "QuakeML"


def _looks_like_xml(p: Path) -> bool:
    with open(p, "rb") as fh:
        head = fh.read(512).lstrip(b"\xef\xbb\xbf \t\r\n")
    return head.startswith(b"<")


def read_events(path, start: Optional[datetime] = None, *, format: Optional[str] = None,
                site=None, bad_rows: str = "raise") -> EventCatalog:
    """Read an event catalogue: QuakeML (and obspy's formats), CSV or FDSN text.

    ``start``: timezone-aware datetime of model time 0; event times are seconds after it.
    Without ``start`` the times are relative to the earliest event (which is then at 0 s).
    QuakeML: each event's preferred origin (else its first) and preferred magnitude (else its
    first).  Events without an origin time are skipped and counted.  ``site``: anything with
    the attributes of the scene's ``[site]`` table (latitude, longitude, depth, x, y, z,
    strike, dip); with it each event gets its distances (see :func:`with_distances`).
    ``format``: "CSV", "FDSN text" or an obspy format name; detected when None.
    ``bad_rows``: "raise" (a row that cannot be read is an error) or "skip" (CSV and FDSN
    text: the row is left out and named in ``notes``; what a monitor following a growing
    catalogue does).
    Raises ``FileNotFoundError`` for a missing file and :class:`EventsError` otherwise.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(path))
    if p.is_dir():
        raise EventsError(f"{path}: is a directory, expected a catalogue file")
    if start is not None:
        start = _to_utc(start)
    src = str(path)
    if format in ("CSV", "FDSN text") or (format is None and not _looks_like_xml(p)):
        times, mags, mtypes, locs, skipped, notes, kind = _read_csv(p, src, bad_rows)
    else:
        times, mags, mtypes, locs, skipped, notes, kind = _read_obspy(p, src, format)

    order = sorted(range(len(times)), key=lambda i: times[i])
    if start is None and times:
        start = times[order[0]]
    if start is not None:
        t = np.array([(times[i] - start).total_seconds() for i in order], dtype=np.float64)
    else:
        t = np.zeros(0)
    arrays = {k: np.array([v[i] for i in order], dtype=np.float64) for k, v in locs.items()}
    cat = EventCatalog(t, np.array([mags[i] for i in order], dtype=np.float64),
                       tuple(mtypes[i] for i in order), start, src, skipped,
                       notes=tuple(notes), **arrays)
    if site is not None or locs:
        cat = with_distances(cat, site)
    return cat

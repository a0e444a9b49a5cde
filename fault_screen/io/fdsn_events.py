"""FDSN event web services (what SeisComP and the data centres serve) as seismic catalogues.

``--events URL`` takes the service's query URL, e.g.
``http://127.0.0.1:8080/fdsnws/event/1/query`` (or the service root ``.../fdsnws/event/1``, or
the server ``http://host``); parameters written in the URL's query (``minmagnitude=-1``,
``minlatitude=...``) are sent with every request.  The events are fetched with obspy's FDSN
client as QuakeML and read by :func:`~fault_screen.io.events.read_events`, the reader of
catalogue files, so they reach the result and the rules exactly as a catalogue file would.

* :func:`read_event_service`: the events of a past window (``run``, ``replay``, ``screen``).
* :class:`EventServiceFollower`: the events of the run's window asked for again at each poll;
  what is new, what was revised (same public id, other origin time, magnitude or location)
  and what disappeared (deleted by the service).

With a ``site`` in geographic coordinates the requests are limited to a box of
``box_half_width`` metres around the injection point (unless the URL sets its own bounds).
Every problem (unreachable server, HTTP error, an answer that is not QuakeML) raises
:class:`EventServiceError` with one line naming the URL.
"""
from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass, replace
from datetime import datetime, timedelta, timezone
from typing import Dict, List, Optional, Tuple
from urllib.parse import parse_qsl, urlsplit, urlunsplit

import numpy as np

from .events import EventCatalog, EventsError, read_events

__all__ = ["EventServiceError", "EventServiceFollower", "ServiceChanges", "is_event_service",
           "read_event_service", "parse_quakeml", "check_event_service", "site_box",
           "BOX_HALF_WIDTH"]

#: half width (m) of the box around the [site] injection point the service is asked about
BOX_HALF_WIDTH = 20_000.0
_EARTH_RADIUS = 6_371_000.0
_BOX_KEYS = ("minlatitude", "maxlatitude", "minlongitude", "maxlongitude", "latitude",
             "longitude", "maxradius")


class EventServiceError(EventsError):
    """An event service that cannot be used; the message names the URL and what was wrong."""


def is_event_service(ref) -> bool:
    """Whether ``--events`` names a web service (an http(s) URL) rather than a file."""
    return isinstance(ref, str) and ref.lower().startswith(("http://", "https://"))


def _service(url: str) -> Tuple[str, str, dict]:
    """``(server base, event service root, the URL's own query parameters)``."""
    try:
        parts = urlsplit(url)
    except ValueError as exc:          # e.g. an unclosed IPv6 bracket
        raise EventServiceError(f"{url}: not a URL ({exc})") from None
    if parts.scheme not in ("http", "https") or not parts.netloc:
        raise EventServiceError(f"{url}: not an http(s) URL of an FDSN event service")
    path = parts.path.rstrip("/")
    if path.endswith("/query"):
        path = path[: -len("/query")]
    if not path:
        path = "/fdsnws/event/1"
    base = urlunsplit((parts.scheme, parts.netloc, "", "", ""))
    return base, base + path, dict(parse_qsl(parts.query))


def site_box(site, half_width: float = BOX_HALF_WIDTH) -> dict:
    """``minlatitude``... of a box of ``half_width`` m around a geographic site; {} for a site
    in local coordinates (or none)."""
    lat = getattr(site, "latitude", None)
    lon = getattr(site, "longitude", None)
    if lat is None or lon is None:
        return {}
    dlat = math.degrees(half_width / _EARTH_RADIUS)
    dlon = math.degrees(half_width / (_EARTH_RADIUS * max(math.cos(math.radians(lat)), 1e-6)))
    return {"minlatitude": max(-90.0, lat - dlat), "maxlatitude": min(90.0, lat + dlat),
            "minlongitude": max(-180.0, lon - dlon), "maxlongitude": min(180.0, lon + dlon)}


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    line = text.splitlines()[0].strip() if text else type(exc).__name__
    return line[:300]


def _fetch(url: str, starttime: datetime, endtime: Optional[datetime], box: dict,
           timeout: float, path: str) -> bool:
    """Write the service's QuakeML answer for the window to ``path``; False when the service
    has no events there (HTTP 204)."""
    from obspy import UTCDateTime
    from obspy.clients.fdsn import Client
    from obspy.clients.fdsn.header import FDSNException, FDSNNoDataException

    base, root, own = _service(url)
    params = dict(own)
    if not any(k in own for k in _BOX_KEYS):
        params.update(box)
    params.setdefault("starttime", UTCDateTime(starttime.astimezone(timezone.utc)
                                               .replace(tzinfo=None)))
    if endtime is not None:
        params.setdefault("endtime", UTCDateTime(endtime.astimezone(timezone.utc)
                                                 .replace(tzinfo=None)))
    try:
        client = Client(base, service_mappings={"event": root}, timeout=timeout,
                        _discover_services=False)
        client.get_events(filename=path, **params)
    except FDSNNoDataException:
        return False
    except FDSNException as exc:
        why = _first_line(exc)
        if "urlopen error" in why.lower() or "refused" in why.lower() or "timed out" in why.lower():
            raise EventServiceError(f"{url}: event service unreachable ({why})") from None
        raise EventServiceError(f"{url}: event service answered with an error ({why})") from None
    except (OSError, ValueError) as exc:
        raise EventServiceError(f"{url}: event service unreachable ({_first_line(exc)})") from None
    return True


def _public_ids(path: str) -> List[str]:
    """Public ids of the events of a QuakeML file in the order read_events sorts them (origin
    time, stable; events without an origin time left out as it leaves them out)."""
    import obspy

    keyed = []
    for ev in obspy.read_events(path, format="QUAKEML"):
        org = ev.preferred_origin() or (ev.origins[0] if ev.origins else None)
        if org is None or org.time is None:
            continue
        keyed.append((org.time.datetime.replace(tzinfo=timezone.utc), str(ev.resource_id)))
    order = sorted(range(len(keyed)), key=lambda i: keyed[i][0])
    return [keyed[i][1] for i in order]


def parse_quakeml(data: bytes, url: str, start: Optional[datetime], site=None) \
        -> Tuple[EventCatalog, List[str]]:
    """The catalogue and the public ids (in its row order) of a service's answer, read as
    :func:`~fault_screen.io.events.read_events` reads a QuakeML file.  Raises
    :class:`EventServiceError` naming ``url`` when the answer is not QuakeML."""
    head = bytes(data[:512]).lstrip(b"\xef\xbb\xbf \t\r\n")
    if not head.startswith(b"<") or b"quakeml" not in bytes(data[:4096]).lower():
        raise EventServiceError(f"{url}: the answer is not QuakeML (it starts with "
                                f"{head[:40].decode('utf-8', 'replace')!r})")
    fd, tmp = tempfile.mkstemp(suffix=".xml", prefix="fdsn-events-")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        try:
            cat = read_events(tmp, start, format="QUAKEML", site=site)
            ids = _public_ids(tmp)
        except Exception as exc:  # noqa: BLE001 - obspy's XML and schema errors: a bad answer
            why = _first_line(exc).replace(tmp, url).replace(os.path.basename(tmp), url)
            raise EventServiceError(f"{url}: the answer is not readable QuakeML ({why})") \
                from None
    finally:
        os.unlink(tmp)
    if len(ids) != len(cat):
        raise EventServiceError(f"{url}: the answer's events could not be matched to their "
                                f"public ids")
    return replace(cat, source=url), ids


def _read(url: str, start: Optional[datetime], window: Tuple[datetime, Optional[datetime]],
          site, box: dict, timeout: float) -> Tuple[EventCatalog, List[str]]:
    fd, tmp = tempfile.mkstemp(suffix=".xml", prefix="fdsn-answer-")
    os.close(fd)
    try:
        if not _fetch(url, window[0], window[1], box, timeout, tmp):
            return _empty(url, start or window[0]), []
        with open(tmp, "rb") as fh:
            data = fh.read()
    finally:
        os.unlink(tmp)
    return parse_quakeml(data, url, start, site)


def _empty(url: str, start: datetime) -> EventCatalog:
    return EventCatalog(np.zeros(0), np.zeros(0), (), start, url)


def read_event_service(url: str, start: Optional[datetime], *, end: Optional[float] = None,
                       site=None, timeout: float = 60.0) -> EventCatalog:
    """The events of the service from ``start`` (model time 0) to ``end`` seconds after it
    (None: up to now), as :func:`~fault_screen.io.events.read_events` reads a catalogue (a
    ``site`` also limits the request to a box around the injection point).  Without ``start``
    the service's events of the last 30 days are asked for."""
    if start is not None and start.utcoffset() is None:
        raise EventServiceError(f"{url}: start {start.isoformat()} has no time zone")
    t0 = start if start is not None else datetime.now(timezone.utc) - timedelta(days=30)
    t1 = None if end is None or start is None else start + timedelta(seconds=float(end))
    cat, _ = _read(url, start, (t0, t1), site, site_box(site), timeout)
    return cat


@dataclass
class ServiceChanges:
    """What one poll found: the new and revised events (the rows of ``catalog``, with their
    public ``ids`` in the same order), the public ids of the ``revised`` ones among them, and
    the public ids of the events ``deleted`` since the last poll."""

    catalog: EventCatalog
    ids: List[str]
    revised: List[str]
    deleted: List[str]


def _fingerprint(cat: EventCatalog, k: int) -> tuple:
    # NaN (unknown) as None: NaN != NaN would make an event without a depth "revised" each poll
    cols = [cat.time, cat.magnitude, cat.latitude, cat.longitude, cat.depth, cat.x, cat.y, cat.z]
    values = (None if c is None or not math.isfinite(c[k]) else float(c[k]) for c in cols)
    return tuple(values) + (cat.magnitude_type[k],)


class EventServiceFollower:
    """Poll an event service for the events of the run's window (model time 0 on; a box around
    a geographic ``site``).  Each poll asks for the whole window again, so that a revised event
    (same public id, another origin, magnitude or location) and a deleted one are seen."""

    def __init__(self, url: str, start: datetime, *, site=None, timeout: float = 30.0):
        if start.utcoffset() is None:
            raise EventServiceError(f"{url}: start {start.isoformat()} has no time zone")
        _service(url)
        self.url, self.start, self.site, self.timeout = url, start, site, float(timeout)
        self.box = site_box(site)
        self.known: Dict[str, tuple] = {}    # public id -> fingerprint of what was handed on

    def poll(self) -> ServiceChanges:
        """Ask the service again; raises :class:`EventServiceError` when it cannot."""
        cat, ids = _read(self.url, self.start, (self.start, None), self.site, self.box,
                         self.timeout)
        seen, keep, revised = {}, [], []
        for k, pid in enumerate(ids):
            fp = _fingerprint(cat, k)
            seen[pid] = fp
            if self.known.get(pid) != fp:
                keep.append(k)
                if pid in self.known:
                    revised.append(pid)
        deleted = [pid for pid in self.known if pid not in seen]
        self.known = seen
        mask = np.zeros(len(cat), dtype=bool)
        mask[keep] = True
        return ServiceChanges(cat._subset(mask), [ids[k] for k in keep], revised, deleted)


def check_event_service(url: str, timeout: float = 10.0) -> None:
    """Ask the service about the last day once: raises :class:`EventServiceError` (naming the
    URL and what was wrong) when it cannot be used (at the start of a monitor)."""
    now = datetime.now(timezone.utc)
    _read(url, None, (now - timedelta(days=1), now), None, {}, timeout)

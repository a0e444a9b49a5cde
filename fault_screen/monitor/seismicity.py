"""Seismicity beside the model: catalogues that grow, STA/LTA detections, association.

* :class:`CatalogFollower` polls a catalogue file that grows (every format
  :func:`fault_screen.io.events.read_events` reads: QuakeML, CSV, FDSN text) and returns the
  events it has not returned before, placed with the scene's ``[site]``.
* :class:`SdsDetector` reads an SDS waveform archive (``obspy.clients.filesystem.sds``) as it
  fills, runs classic STA/LTA (``obspy.signal.trigger.classic_sta_lta`` and ``trigger_onset``)
  chunk by chunk with an LTA lead-in (so a chunked run finds the onsets of a whole-trace run),
  and returns detections (time, no magnitude, no location).
* :class:`Site` places hypocentres in the model plane (from the reader's offsets, or a local
  flat-earth projection for events given by latitude and longitude) and :func:`associate`
  attaches the model state
  at an event's time: distance to the injection point and to the nearest slipping fault point,
  slip rate and utilisation at the fault point nearest to the event.

Times are model seconds: seconds after ``start``, the date-time of model time 0.
"""
from __future__ import annotations

import fnmatch
import logging
import math
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import List, Optional

import numpy as np

__all__ = ["SeismicEvent", "CatalogFollower", "SdsDetector", "SeedLinkDetector", "SeedLinkBuffer",
           "Site", "associate",
           "EARTH_RADIUS"]

#: mean Earth radius (m) of the local projection
EARTH_RADIUS = 6_371_000.0


@dataclass(frozen=True)
class SeismicEvent:
    """An event or a detection.  ``time`` s of model time; ``magnitude`` NaN if unknown;
    ``latitude``/``longitude`` deg and ``depth`` m (None if unknown); ``kind`` "event" or
    "detection"; ``id`` unique within its feed; ``offset`` (east, north, up) m and
    ``distance`` m from the injection point when the catalogue reader placed it."""

    time: float
    magnitude: float = math.nan
    latitude: Optional[float] = None
    longitude: Optional[float] = None
    depth: Optional[float] = None
    kind: str = "event"
    id: str = ""
    offset: Optional[tuple] = None       # (east, north, up) m from the injection point
    distance: Optional[float] = None     # m to the injection point (the catalogue reader's)

    def to_dict(self) -> dict:
        return {"time": self.time, "magnitude": self.magnitude, "latitude": self.latitude,
                "longitude": self.longitude, "depth": self.depth, "kind": self.kind,
                "id": self.id, "offset": None if self.offset is None else list(self.offset),
                "distance": self.distance}


def _utc(start: datetime):
    from obspy import UTCDateTime

    if start.utcoffset() is None:
        raise ValueError(f"start {start.isoformat()} has no time zone")
    return UTCDateTime(start.astimezone(timezone.utc).replace(tzinfo=None))


def events_from_catalog(cat, site=None, source: Optional[str] = None) -> List[SeismicEvent]:
    """SeismicEvents of an :class:`~fault_screen.io.events.EventCatalog` (as
    :func:`~fault_screen.io.events.read_events` returns it, distances included when it was read
    with a site), with their east/north/up offsets from the injection point when ``site``
    places them."""
    from ..io.events import _offsets

    n = len(cat)
    off = _offsets(cat, site)[0] if site is not None and n else None
    col = lambda a, k: None if a is None or not np.isfinite(a[k]) else float(a[k])  # noqa: E731
    out = []
    for k in range(n):
        t, m = float(cat.time[k]), float(cat.magnitude[k])
        o = off[k] if off is not None and np.all(np.isfinite(off[k])) else None
        out.append(SeismicEvent(
            time=t, magnitude=m, latitude=col(cat.latitude, k), longitude=col(cat.longitude, k),
            depth=col(cat.depth, k), kind="event",
            id=f"{source or cat.source}@{t!r}/{m!r}",   # the reader has no ids: time and size
            offset=None if o is None else (float(o[0]), float(o[1]), float(o[2])),
            distance=col(cat.distance_to_injection, k)))
    return out


class CatalogFollower:
    """New events of a growing catalogue file, by polling: every format
    :func:`~fault_screen.io.events.read_events` reads (QuakeML and obspy's formats, CSV, FDSN
    text), placed with the scene's ``[site]``.

    The file is read again when its size or modification time changes; a text catalogue is
    read up to its last complete line, and a file that does not parse yet (being written) is
    tried again at the next poll.  Each event is returned once.
    """

    def __init__(self, path, start: datetime, *, site=None, format: Optional[str] = None,
                 log: Optional[logging.Logger] = None):
        self.path = os.fspath(path)
        self.start = start
        self.site = site
        self.format = format
        self.log = log or logging.getLogger("fault_screen.monitor.seismicity")
        self.seen: set = set()
        self.reported: set = set()     # bad rows already named in a warning
        self._sig = None
        self._failed = None

    def poll(self) -> List[SeismicEvent]:
        import tempfile

        from ..io.events import EventsError, read_events

        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            return []
        sig = (st.st_size, st.st_mtime_ns, st.st_ino)
        if sig == self._sig:
            return []
        with open(self.path, "rb") as fh:
            data = fh.read()
        path, tmp = self.path, None
        if data.lstrip()[:1] != b"<" and not data.endswith(b"\n"):
            # a text catalogue with its last line being written: read the complete lines
            cut = data.rfind(b"\n")
            if cut < 0:
                return []
            tmp = tempfile.NamedTemporaryFile(suffix=os.path.splitext(self.path)[1],
                                              delete=False)
            tmp.write(data[:cut + 1])
            tmp.close()
            path = tmp.name
        try:
            cat = read_events(path, self.start, format=self.format, site=self.site,
                              bad_rows="skip")
        except (EventsError, OSError) as exc:
            # not readable as a whole (a header being written, a damaged file): said once per
            # version of the file, tried again when it changes
            if sig != self._failed:
                self.log.warning("%s: cannot read the catalogue (%s); trying again when it "
                                 "changes", self.path, exc)
                self._failed = sig
            return []
        finally:
            if tmp is not None:
                os.unlink(tmp.name)
        for note in cat.notes:
            if note.endswith("row skipped") and note not in self.reported:
                self.reported.add(note)      # a bad row is named once, the rows after it read
                self.log.warning("%s", note)
        if tmp is None:
            self._sig = sig
        new = [e for e in events_from_catalog(cat, self.site, self.path) if e.id not in self.seen]
        self.seen.update(e.id for e in new)
        return new


class SdsDetector:
    """Classic STA/LTA detections on an SDS archive, chunk by chunk as the archive fills.

    ``sta``/``lta`` window lengths (s), ``on``/``off`` trigger thresholds of the STA/LTA ratio,
    ``channels`` a ``NET.STA.LOC.CHA`` glob (default all).  Onsets of several channels closer
    than ``merge`` seconds are one detection; a detection needs ``min_channels`` channels.
    ``client``: where the waveforms come from instead of the archive ``root`` (anything with
    obspy's ``get_all_nslc()`` and ``get_waveforms(net, sta, loc, cha, t0, t1)``; the SeedLink
    detector passes its buffer of received records), so every source takes one STA/LTA path.
    """

    def __init__(self, root, start: datetime, *, sta: float = 0.5, lta: float = 10.0,
                 on: float = 3.5, off: float = 1.0, channels: str = "*", merge: float = 2.0,
                 min_channels: int = 1, log: Optional[logging.Logger] = None, client=None):
        if not 0 < sta < lta:
            raise ValueError(f"need 0 < sta < lta, got sta={sta} lta={lta}")
        if client is None:
            from obspy.clients.filesystem.sds import Client

            if not os.path.isdir(root):
                raise FileNotFoundError(2, "SDS archive folder not found", os.fspath(root))
            client = Client(os.fspath(root))
        self.client = client
        self.start = start
        self.ref = _utc(start)
        self.sta, self.lta, self.on, self.off = float(sta), float(lta), float(on), float(off)
        self.channels, self.merge, self.min_channels = channels, float(merge), int(min_channels)
        self.log = log or logging.getLogger("fault_screen.monitor.seismicity")
        self.done: dict = {}     # nslc -> UTCDateTime up to which onsets were reported
        self.n_detections = 0

    def _nslc(self):
        found = [".".join(x) for x in self.client.get_all_nslc()]
        return sorted(c for c in found if fnmatch.fnmatch(c, self.channels))

    def onsets(self, until: float) -> List[float]:
        """New trigger onsets (model s) of every channel, up to model time ``until``."""
        from obspy.signal.trigger import classic_sta_lta, trigger_onset

        t_end = self.ref + until
        complete = getattr(self.client, "complete_until", lambda: None)()
        if complete is not None:
            # a live stream: only as far as every channel has data, so that the onsets of one
            # arrival on several channels come in the same call and merge into one detection
            t_end = min(t_end, complete)
        out = []
        for code in self._nslc():
            done = self.done.get(code, self.ref)
            if done >= t_end:
                continue
            # lead-in of two LTA windows: the ratio before 'done' is valid, so a trigger that
            # was on at the end of the last chunk shows its (already reported) onset again
            st = self.client.get_waveforms(*code.split("."), done - 2 * self.lta, t_end)
            if not st:
                continue
            st.merge(method=0)
            reached = done
            for tr in st.split():
                df = tr.stats.sampling_rate
                nsta, nlta = int(round(self.sta * df)), int(round(self.lta * df))
                if tr.stats.npts <= nlta:
                    continue
                cft = classic_sta_lta(tr.data.astype(np.float64), nsta, nlta)
                for i_on, _ in trigger_onset(cft, self.on, self.off):
                    t_on = tr.stats.starttime + i_on / df
                    if i_on >= nlta - 1 and done <= t_on:   # obspy zeroes the first nlta - 1
                        out.append(float(t_on - self.ref))
                # the last samples lack their successors' check only for 'off'; onsets stand
                reached = max(reached, tr.stats.endtime + 1.0 / df)
            self.done[code] = min(reached, t_end)
        if self.done and hasattr(self.client, "forget_before"):
            # a live buffer keeps only the lead-in the next chunk needs: memory stays bounded
            self.client.forget_before(min(self.done.values()) - 2 * self.lta - 1.0)
        return sorted(out)

    def poll(self, until: float) -> List[SeismicEvent]:
        """New detections up to model time ``until`` (merged across channels)."""
        times = self.onsets(until)
        dets, group = [], []
        for t in times + [math.inf]:
            if group and t - group[0] > self.merge:
                if len(group) >= self.min_channels:
                    self.n_detections += 1
                    dets.append(SeismicEvent(time=group[0], kind="detection",
                                             id=f"stalta-{(self.ref + group[0]).isoformat()}"))
                group = []
            if math.isfinite(t):
                group.append(t)
        return dets

    def state(self) -> dict:
        return {code: float(t - self.ref) for code, t in self.done.items()}

    def restore(self, state: dict) -> None:
        self.done = {code: self.ref + float(t) for code, t in state.items()}


class SeedLinkBuffer:
    """Waveform records received from a SeedLink server, for :class:`SdsDetector` to read like
    an archive.

    A thread runs obspy's SeedLink connection (multi-station mode: ``HELLO``, then ``STATION``,
    ``SELECT`` and ``DATA`` for each stream, ``END``; reconnecting by itself) to ``address``
    (``HOST:PORT``) for ``streams`` in obspy's stream-list form (``NET_STA[:SELECTORS],...``,
    e.g. ``BW_RJOB:EH?``) and keeps each record's trace until :meth:`forget_before`."""

    def __init__(self, address: str, streams: str, *, log: Optional[logging.Logger] = None):
        import threading

        from obspy.clients.seedlink.client.seedlinkconnection import SeedLinkConnection

        class Connection(SeedLinkConnection):
            # no collect() timeout (a quiet network is not an end), but the socket check of
            # connect() needs one
            def is_connected(self, timeout=1.0):
                return super().is_connected(10.0 if timeout is None else timeout)

        self.address, self.streams = address, streams
        self.log = log or logging.getLogger("fault_screen.monitor.seedlink")
        self.conn = Connection()
        self.conn.set_sl_address(address)
        self.conn.set_net_delay(1)            # s between reconnection attempts
        if self.conn.parse_stream_list(streams, "") < 1:
            raise ValueError(f"SeedLink streams {streams!r}: expected NET_STA[:SELECTORS],... "
                             f"(e.g. BW_RJOB:EH?)")
        self.traces: dict = {}                # NET.STA.LOC.CHA -> received traces, in order
        self.records = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="seedlink", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from obspy.clients.seedlink.slpacket import SLPacket

        while not self._stop.is_set():
            try:
                packet = self.conn.collect()
            except Exception as exc:          # noqa: BLE001 - a network thread must not die silently
                self.log.warning("SeedLink %s: %s", self.address, exc)
                return
            if packet == SLPacket.SLTERMINATE:
                if self._stop.is_set():
                    return
                self.log.warning("SeedLink %s: the server ended the stream; reconnecting",
                                 self.address)
                continue
            if packet == SLPacket.SLERROR or packet is None:
                continue
            if packet.get_type() in (SLPacket.TYPE_SLINF, SLPacket.TYPE_SLINFT):
                continue                      # in-stream INFO: not waveforms
            try:
                trace = packet.get_trace()
            except Exception as exc:          # noqa: BLE001 - one bad record, not the stream
                self.log.warning("SeedLink %s: unreadable record skipped: %s", self.address, exc)
                continue
            with self._lock:
                self.traces.setdefault(trace.id, []).append(trace)
                self.records += 1

    # the two methods of obspy's archive clients that SdsDetector uses
    def get_all_nslc(self):
        with self._lock:
            return [tuple(code.split(".")) for code in self.traces]

    def get_waveforms(self, network, station, location, channel, starttime, endtime):
        from obspy import Stream

        with self._lock:
            kept = list(self.traces.get(".".join((network, station, location, channel)), ()))
        return Stream([tr.slice(starttime, endtime) for tr in kept
                       if tr.stats.endtime >= starttime and tr.stats.starttime <= endtime])

    def complete_until(self):
        """Stream time (UTCDateTime) up to which every live channel has sent its records; a
        channel silent for more than ``STALE`` seconds behind the newest is left out."""
        with self._lock:
            ends = [kept[-1].stats.endtime for kept in self.traces.values() if kept]
        if not ends:
            return None
        newest = max(ends)
        return min(e for e in ends if newest - e <= self.STALE)

    #: s a channel may lag the newest before detections go on without it
    STALE = 60.0

    def forget_before(self, t) -> None:
        """Drop the records that end before ``t`` (UTCDateTime)."""
        with self._lock:
            for code, kept in self.traces.items():
                self.traces[code] = [tr for tr in kept if tr.stats.endtime >= t]

    def close(self) -> None:
        import socket

        self._stop.set()
        # collect() clears the termination flag when it starts, and may wait in a read: ask
        # and wake it until the thread is out
        for _ in range(25):
            self.conn.terminate()
            sock = self.conn.socket
            if sock is not None:
                try:
                    sock.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
            self._thread.join(timeout=0.2)
            if not self._thread.is_alive():
                break
        try:
            self.conn.close()
        except Exception:                     # noqa: BLE001 - closing in the way out
            pass


class SeedLinkDetector(SdsDetector):
    """Classic STA/LTA detections on the waveforms of a SeedLink server as they arrive: the
    records go to a :class:`SeedLinkBuffer`, read by the same STA/LTA path as an SDS archive
    (options as :class:`SdsDetector`)."""

    def __init__(self, address: str, streams: str, start: datetime, **options):
        buffer = SeedLinkBuffer(address, streams, log=options.get("log"))
        super().__init__(None, start, client=buffer, **options)

    def close(self) -> None:
        self.client.close()


@dataclass(frozen=True)
class Site:
    """Where the model sits: the injection point's ``latitude``, ``longitude`` (deg) and
    ``depth`` (m below the datum), and the ``azimuth`` (deg clockwise from north) of the model's
    x axis, which is horizontal in the model plane; the model's y axis points up.  Events
    placed by the catalogue reader (``SeismicEvent.offset``) need only the azimuth."""

    latitude: Optional[float] = None
    longitude: Optional[float] = None
    depth: Optional[float] = None
    azimuth: float = 90.0
    spec: object = field(default=None, compare=False)   # the scene's [site], for the reader

    @classmethod
    def from_spec(cls, spec) -> Optional["Site"]:
        """From the scene's ``[site]`` table: the model plane is the fault's dip section, so its
        x axis points down-dip, at strike + 90 deg (east without a strike)."""
        if spec is None:
            return None
        strike = getattr(spec, "strike", None)
        return cls(getattr(spec, "latitude", None), getattr(spec, "longitude", None),
                   getattr(spec, "depth", None),
                   (float(strike) + 90.0) % 360.0 if strike is not None else 90.0, spec)

    def local(self, ev: SeismicEvent):
        """(along-section, up, off-section) offsets (m) of a hypocentre from the injection
        point, or None if it cannot be placed."""
        if ev.offset is not None:
            east, north, up = ev.offset
        elif None not in (ev.latitude, ev.longitude, self.latitude, self.longitude):
            # a local flat-earth projection: good to ~0.1 % within tens of km
            lat0 = math.radians(self.latitude)
            north = math.radians(ev.latitude - self.latitude) * EARTH_RADIUS
            east = math.radians(ev.longitude - self.longitude) * EARTH_RADIUS * math.cos(lat0)
            up = -((ev.depth if ev.depth is not None else self.depth or 0.0)
                   - (self.depth or 0.0))
        else:
            return None
        az = math.radians(self.azimuth)
        along = east * math.sin(az) + north * math.cos(az)
        off = east * math.cos(az) - north * math.sin(az)
        return along, up, off


@dataclass
class Association:
    """An event with the model state at its time."""

    event: SeismicEvent
    model_time: float                 # time of the model state used (s)
    distance_injection: float = math.nan    # m, hypocentre to the injection point
    distance_slipping: float = math.nan     # m, to the nearest slipping fault point (inf: none)
    slip_rate: float = math.nan             # m/s at the fault point nearest to the event
    utilisation: float = math.nan           # |tau| / (mu sigma'_n) there
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = self.event.to_dict()
        d.update(model_time=self.model_time, distance_injection=self.distance_injection,
                 distance_slipping=self.distance_slipping, slip_rate=self.slip_rate,
                 utilisation=self.utilisation)
        return d


def utilisation(shear_traction, effective_normal_stress, friction: float) -> np.ndarray:
    """|tau| / (mu sigma'_n) per fault point; an open point (sigma'_n <= 0) counts as 1."""
    tau = np.abs(np.asarray(shear_traction, dtype=float))
    sn = np.asarray(effective_normal_stress, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(sn > 0, tau / (friction * sn), 1.0)


def associate(ev: SeismicEvent, row: dict, *, site: Optional[Site], fault_xy, injection_xy,
              friction: float) -> Association:
    """Attach the model state ``row`` (a recorded row: ``time`` and the fault arrays
    ``slip_rate``, ``contact_state``, ``shear_traction``, ``effective_normal_stress``) to
    ``ev``; distances need ``site`` and a located event."""
    a = Association(ev, float(row["time"]))
    pos = site.local(ev) if site is not None else None
    if pos is None:
        return a
    along, up, off = pos
    a.distance_injection = (ev.distance if ev.distance is not None
                            else math.sqrt(along * along + up * up + off * off))
    xy = np.asarray(fault_xy, dtype=float).reshape(-1, 2)
    if xy.size == 0:
        return a
    # the event projected into the model plane, in model coordinates
    ex, ey = injection_xy[0] + along, injection_xy[1] + up
    d2 = (xy[:, 0] - ex) ** 2 + (xy[:, 1] - ey) ** 2 + off * off
    near = int(np.argmin(d2))
    state = np.asarray(row.get("contact_state", np.zeros(len(xy))))
    slipping = state == 1
    a.distance_slipping = float(np.sqrt(d2[slipping].min())) if slipping.any() else math.inf
    if "slip_rate" in row:
        a.slip_rate = float(np.asarray(row["slip_rate"]).reshape(-1)[near])
    if "shear_traction" in row and "effective_normal_stress" in row:
        u = utilisation(row["shear_traction"], row["effective_normal_stress"], friction)
        a.utilisation = float(np.asarray(u).reshape(-1)[near])
    return a

"""Local stand-ins of a HYDWS server and an FDSN event service, bound to 127.0.0.1 only.

``python -m fault_screen.testing.servers`` serves, on one port:

* HYDWS: ``/hydws/v1/boreholes/BH1/sections/S1/hydraulics`` with the samples of a bundled log
  (``configs/logs/rustrel-2015-standin.csv`` unless ``--log``) in HYDWS JSON (``topflow`` and
  ``bottomflow`` in m3/s, ``toppressure``/``bottompressure`` in Pa when the log has pressures),
  revealed a few at a time once it is first asked for (``--grow-by`` samples every
  ``--grow-every`` seconds; all at once with ``--grow-by 0``), and down (connections refused)
  for ``--down-for`` seconds after ``--down-after`` requests.  ``?starttime=``/``?endtime=``
  select a window (inclusive).
* FDSN event: ``/fdsnws/event/1/query`` answering QuakeML with three small events during the
  log (public ids ``smi:local/fault-screen-test/event/1`` to ``/3``); after ``--revise-after``
  queries the magnitude of event 2 is revised to 3.1 and event 3 is deleted.
* Bad answers for trying the error messages: ``/broken/...`` (malformed JSON and HTML instead
  of QuakeML) and unknown sections (HTTP 404).

In tests: ``with FakeServices(...) as srv: srv.hydws_url, srv.fdsn_url``.
"""
from __future__ import annotations

import argparse
import io
import json
import threading
import time
from datetime import datetime, timedelta, timezone
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

__all__ = ["FakeServices", "TestEvent", "default_events", "main"]

HOST = "127.0.0.1"
BOREHOLE, SECTION = "BH1", "S1"
HYDWS_PATH = f"/hydws/v1/boreholes/{BOREHOLE}/sections/{SECTION}/hydraulics"
FDSN_PATH = "/fdsnws/event/1/query"
EVENT_ID = "smi:local/fault-screen-test/event/{}"


class TestEvent:
    """An event of the fake FDSN service: ``time`` s after the log's first stamp, ``magnitude``
    (ML), position in degrees and m below the surface."""

    __test__ = False          # not a pytest class

    def __init__(self, number: int, time: float, magnitude: float, latitude: float = 43.9411,
                 longitude: float = 5.4834, depth: float | None = 280.0):
        self.id = EVENT_ID.format(number)
        self.time, self.magnitude = float(time), float(magnitude)
        self.latitude, self.longitude, self.depth = latitude, longitude, depth
        self.updated = 0.0       # wall time of the last change (for ?updatedafter=)


def default_events():
    """Three small events during the bundled log: at 400, 700 and 1000 s, ML 0.6, 1.2, 0.9."""
    return [TestEvent(1, 400.0, 0.6), TestEvent(2, 700.0, 1.2), TestEvent(3, 1000.0, 0.9)]


def _bundled_log() -> Path:
    from ..bundled import bundled_path

    return bundled_path("logs/rustrel-2015-standin.csv")


def _stamp(dt: datetime) -> str:
    return dt.astimezone(timezone.utc).replace(tzinfo=None).isoformat()


def _query_time(text: str) -> datetime:
    dt = datetime.fromisoformat(text.replace("Z", "+00:00"))
    return dt.replace(tzinfo=timezone.utc) if dt.utcoffset() is None else dt


class FakeServices:
    """The HYDWS and FDSN stand-ins (see the module docstring), started by ``start()`` or a
    ``with`` block.  ``visible`` samples are served; ``reveal(n)`` shows more, ``grow_per_request``
    shows that many more before each hydraulics answer; ``go_down(seconds)`` refuses
    connections for a while; ``down_after`` (a count of hydraulics requests) does it once by
    itself for ``down_for`` seconds.  ``revise_after`` (FDSN queries): then event 2 gets
    magnitude ``revised_magnitude`` and event 3 is deleted."""

    def __init__(self, log=None, *, port: int = 0, visible: int | None = None,
                 grow_per_request: int = 0, down_after: int | None = None,
                 down_for: float = 1.0, events=None, revise_after: int | None = None,
                 revised_magnitude: float = 3.1):
        from ..io.injection_log import read_injection_log

        self.log = read_injection_log(log or _bundled_log())
        t0 = self.log.start or datetime(2015, 3, 12, 9, tzinfo=timezone.utc)
        self.origin = t0       # date-time of the log's first stamp
        self.stamps = [t0 + timedelta(seconds=float(t)) for t in self.log.time]
        self.visible = len(self.stamps) if visible is None else int(visible)
        self.grow_per_request = int(grow_per_request)
        self.down_after, self.down_for = down_after, float(down_for)
        self.events = list(default_events() if events is None else events)
        self.revise_after, self.revised_magnitude = revise_after, float(revised_magnitude)
        self.hydws_requests = self.fdsn_requests = 0
        self.hydws_queries: list = []     # the query parameters of each hydraulics request
        self.answer = "ok"                # or "malformed", "404", "html": the section and the
                                          # event service answer badly (while a monitor runs)
        self.outages = 0
        self.port = int(port)
        self._lock = threading.Lock()
        self._httpd = None
        self._thread = None
        self._down = threading.Event()

    # -- addresses ----------------------------------------------------------------------------
    @property
    def base(self) -> str:
        return f"http://{HOST}:{self.port}"

    @property
    def hydws_url(self) -> str:
        """URL of the section (what ``--follow`` and ``replay --log`` take)."""
        return self.base + HYDWS_PATH

    @property
    def fdsn_url(self) -> str:
        """URL of the event service (what ``--events`` takes)."""
        return self.base + FDSN_PATH

    # -- control ------------------------------------------------------------------------------
    def reveal(self, n: int) -> None:
        with self._lock:
            self.visible = min(len(self.stamps), self.visible + int(n))

    def go_down(self, seconds: float) -> None:
        """Refuse connections for ``seconds`` (in a background thread)."""
        if self._down.is_set():
            return
        self._down.set()
        self.outages += 1
        threading.Thread(target=self._outage, args=(float(seconds),), daemon=True).start()

    def _outage(self, seconds: float) -> None:
        httpd, self._httpd = self._httpd, None
        httpd.shutdown()
        httpd.server_close()
        time.sleep(seconds)
        self._serve()
        self._down.clear()

    def start(self) -> "FakeServices":
        self._serve()
        return self

    def _serve(self) -> None:
        owner = self

        class Handler(_Handler):
            services = owner

        httpd = ThreadingHTTPServer((HOST, self.port), Handler)
        httpd.daemon_threads = True
        self.port = httpd.server_address[1]
        self._httpd = httpd
        self._thread = threading.Thread(target=httpd.serve_forever, name="fake-services",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        while self._down.is_set():
            time.sleep(0.05)
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
            self._httpd = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    # -- answers ------------------------------------------------------------------------------
    def hydraulics(self, query: dict):
        """The JSON text of the visible samples in the query's window; None to drop the
        connection (the server going down now)."""
        with self._lock:
            self.hydws_requests += 1
            self.hydws_queries.append(dict(query))
            if self.down_after is not None and self.hydws_requests == self.down_after:
                self.go_down(self.down_for)
                return None
            self.visible = min(len(self.stamps), self.visible + self.grow_per_request)
            n = self.visible
        lo = _query_time(query["starttime"]) if "starttime" in query else None
        hi = _query_time(query["endtime"]) if "endtime" in query else None
        p = self.log.pressure
        out = []
        for k in range(n):
            dt = self.stamps[k]
            if (lo is not None and dt < lo) or (hi is not None and dt > hi):
                continue
            q = float(self.log.flow_rate[k])
            s = {"datetime": {"value": _stamp(dt)}, "topflow": {"value": q},
                 "bottomflow": {"value": q}}
            if p is not None:
                s["toppressure"] = {"value": float(p[k])}
                s["bottompressure"] = {"value": float(p[k])}
            out.append(s)
        return json.dumps(out)

    def quakeml(self, query: dict) -> bytes | None:
        """QuakeML of the events in the query's window; None when there are none (HTTP 204)."""
        from obspy import UTCDateTime
        from obspy.core.event import (Catalog, Event, Magnitude, Origin, ResourceIdentifier)

        with self._lock:
            self.fdsn_requests += 1
            if self.revise_after is not None and self.fdsn_requests == self.revise_after + 1:
                now = time.time()
                for ev in self.events:
                    if ev.id == EVENT_ID.format(2):
                        ev.magnitude, ev.updated = self.revised_magnitude, now
                self.events = [e for e in self.events if e.id != EVENT_ID.format(3)]
            events = list(self.events)
        lo = _query_time(query["starttime"]) if "starttime" in query else None
        hi = _query_time(query["endtime"]) if "endtime" in query else None
        cat = Catalog(resource_id=ResourceIdentifier("smi:local/fault-screen-test/catalog"))
        for e in events:
            when = self.origin + timedelta(seconds=e.time)
            if (lo is not None and when < lo) or (hi is not None and when > hi):
                continue
            if not _in_box(e, query):
                continue
            org = Origin(resource_id=ResourceIdentifier(e.id + "/origin"),
                         time=UTCDateTime(when.astimezone(timezone.utc).replace(tzinfo=None)),
                         latitude=e.latitude, longitude=e.longitude, depth=e.depth)
            mag = Magnitude(resource_id=ResourceIdentifier(e.id + "/magnitude"),
                            mag=e.magnitude, magnitude_type="ML")
            ev = Event(resource_id=ResourceIdentifier(e.id), origins=[org], magnitudes=[mag])
            ev.preferred_origin_id, ev.preferred_magnitude_id = org.resource_id, mag.resource_id
            cat.append(ev)
        if not len(cat):
            return None
        buf = io.BytesIO()
        cat.write(buf, format="QUAKEML")
        return buf.getvalue()


def _in_box(e: TestEvent, query: dict) -> bool:
    for key, value, keep in (("minlatitude", e.latitude, lambda v, b: v >= b),
                             ("maxlatitude", e.latitude, lambda v, b: v <= b),
                             ("minlongitude", e.longitude, lambda v, b: v >= b),
                             ("maxlongitude", e.longitude, lambda v, b: v <= b)):
        if key in query and not keep(value, float(query[key])):
            return False
    return True


class _Handler(BaseHTTPRequestHandler):
    services: FakeServices = None

    def log_message(self, *args):     # quiet: the monitor's log is what is being tried
        pass

    def _send(self, code: int, body: bytes = b"", ctype: str = "application/json") -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def do_GET(self):
        parts = urlsplit(self.path)
        query = {k: v[-1] for k, v in parse_qs(parts.query).items()}
        srv = self.services
        if parts.path in (HYDWS_PATH, FDSN_PATH) and srv.answer != "ok":
            self._send(*{"malformed": (200, b'[{"datetime": '), "404": (404, b"not found"),
                         "html": (200, b"<html>maintenance</html>", "text/html")}[srv.answer])
        elif parts.path == HYDWS_PATH:
            body = srv.hydraulics(query)
            if body is None:
                self.close_connection = True
                return
            self._send(200, body.encode())
        elif parts.path.startswith("/broken/hydws/"):
            self._send(200, b'[{"datetime": {"value": "2015-03-12T09:00:00"}, "topflow": ')
        elif parts.path.startswith("/hydws/"):
            self._send(404, b'{"detail": "borehole section not found"}')
        elif parts.path == FDSN_PATH:
            body = srv.quakeml(query)
            if body is None:
                self._send(204)
            else:
                self._send(200, body, "application/xml")
        elif parts.path == "/fdsnws/event/1/version":
            self._send(200, b"1.2.0", "text/plain")
        elif parts.path.startswith("/broken/fdsnws/"):
            self._send(200, b"<html><body>Service moved</body></html>", "text/html")
        else:
            self._send(404, b"not found", "text/plain")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m fault_screen.testing.servers",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--port", type=int, default=8080, help="port on 127.0.0.1 [8080]")
    ap.add_argument("--log", default=None, help="injection log to serve [bundled stand-in]")
    ap.add_argument("--grow-by", type=int, default=10,
                    help="samples revealed every --grow-every seconds; 0: all at once [10]")
    ap.add_argument("--grow-every", type=float, default=1.0, help="seconds [1]")
    ap.add_argument("--down-after", type=int, default=None,
                    help="hydraulics requests after which the server goes down once")
    ap.add_argument("--down-for", type=float, default=3.0, help="seconds down [3]")
    ap.add_argument("--revise-after", type=int, default=3,
                    help="event queries after which event 2 is revised and event 3 deleted [3]")
    a = ap.parse_args(argv)
    srv = FakeServices(a.log, port=a.port, visible=2 if a.grow_by else None,
                       down_after=a.down_after, down_for=a.down_for,
                       revise_after=a.revise_after).start()
    print(f"HYDWS section:  {srv.hydws_url}\nFDSN events:    {srv.fdsn_url}", flush=True)
    try:
        while True:
            time.sleep(a.grow_every)
            if a.grow_by and srv.hydws_requests:      # the section grows once it is followed
                srv.reveal(a.grow_by)
    except KeyboardInterrupt:
        srv.stop()


if __name__ == "__main__":
    main()

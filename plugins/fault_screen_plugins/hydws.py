"""HYDWS source: the hydraulic samples of one borehole section of a HYDWS server.

HYDWS (the hydraulic web service of the Swiss Seismological Service) serves a section's samples
at ``.../hydws/v1/boreholes/<borehole>/sections/<section>/hydraulics?starttime=&endtime=`` as a
JSON list of samples, each a dict of ``{"value": ...}`` quantities: ``datetime`` (ISO 8601, UTC),
``topflow``/``bottomflow`` (m3/s) and ``toppressure``/``bottompressure`` (Pa).

The samples become lines of the replay format (``time,flow_rate[m3/s],pressure[Pa]``, numbers
written with ``repr`` so they read back as the same floats) handed to the monitor's decoder, so
the checks, the ``stop``/``skip``/``hold`` policies, the origin of model time and a resumed
state are the ones of a CSV log; :func:`read_log` reads a past window into the
:class:`~fault_screen.io.injection_log.InjectionLog` of ``fault-screen replay`` through the same
lines, so a replay of the samples the monitor received takes the same steps with the same
volumes.

Which flow and pressure: ``position`` ``top`` (default) or ``bottom`` of the section, as an
option (``--source hydws:position=bottom``) or as the URL's fragment (``...#bottom``).
"""
from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import tempfile
import time
from datetime import datetime, timedelta, timezone
from urllib.parse import parse_qsl, urlsplit, urlunsplit

import requests

__all__ = ["HydwsSource", "HydwsError", "parse_hydraulics", "hydraulics_url", "read_log",
           "replay_lines"]

POSITIONS = ("top", "bottom")
#: the header of the replay-format lines the samples become
HEADER = "time,flow_rate[m3/s],pressure[Pa]"


class HydwsError(ValueError):
    """A HYDWS URL that cannot be used or an answer that cannot be read (the message names the
    URL and what was wrong)."""


def hydraulics_url(url: str, position: str | None = None):
    """``(hydraulics URL without query, query dict, position)`` of a URL naming a section
    (``.../sections/<id>`` or ``.../sections/<id>/hydraulics``, optionally with a query and a
    ``#top``/``#bottom`` fragment)."""
    try:
        parts = urlsplit(str(url))
    except ValueError as exc:          # e.g. an unclosed IPv6 bracket
        raise HydwsError(f"{url}: not a URL ({exc})") from None
    if parts.scheme not in ("http", "https") or not parts.netloc:
        raise HydwsError(f"{url}: not an http(s) URL of a HYDWS borehole section")
    segs = [s for s in parts.path.split("/") if s]
    if segs and segs[-1] == "hydraulics":
        segs = segs[:-1]
    if len(segs) < 4 or segs[-2] != "sections" or segs[-4] != "boreholes":
        raise HydwsError(f"{url}: expected a HYDWS section URL ending in "
                         f"/boreholes/<borehole>/sections/<section>[/hydraulics]")
    fragment = parts.fragment.lower()
    if fragment and fragment not in POSITIONS:
        raise HydwsError(f"{url}: fragment #{parts.fragment}: expected #top or #bottom")
    position = position or fragment or "top"
    if position not in POSITIONS:
        raise HydwsError(f"position {position!r}: expected 'top' or 'bottom'")
    base = urlunsplit((parts.scheme, parts.netloc, "/" + "/".join(segs + ["hydraulics"]), "", ""))
    return base, dict(parse_qsl(parts.query)), position


def _value(sample: dict, key: str):
    q = sample.get(key)
    if q is None:
        return None
    if not isinstance(q, dict) or "value" not in q:
        raise ValueError(f"{key} is {q!r}, expected an object with a 'value'")
    return q["value"]


def _number(sample: dict, key: str):
    v = _value(sample, key)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f"{key} value {v!r} is not a finite number")
    return float(v)


def _stamp(text) -> datetime:
    if not isinstance(text, str):
        raise ValueError(f"datetime value {text!r} is not a string")
    dt = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    # HYDWS stamps are UTC; a stamp written without an offset is UTC
    if dt.utcoffset() is None:
        return dt.replace(tzinfo=timezone.utc)
    return dt.astimezone(timezone.utc)


def parse_hydraulics(data: bytes | str, url: str, position: str = "top"):
    """The samples of a HYDWS hydraulics answer: a list of ``(datetime (aware UTC), flow m3/s
    or None, pressure Pa or None)`` sorted by time.  Also takes the borehole answer (a dict, or
    a list of them, with ``sections`` holding ``hydraulics``).  Raises :class:`HydwsError`
    naming the URL for anything else."""
    try:
        doc = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise HydwsError(f"{url}: malformed JSON in the HYDWS answer ({exc})") from None
    samples = _samples_of(doc)
    if samples is None:
        raise HydwsError(f"{url}: not a HYDWS hydraulics answer (expected a JSON list of "
                         f"samples, got {type(doc).__name__})")
    out = []
    for k, s in enumerate(samples):
        try:
            if not isinstance(s, dict):
                raise ValueError(f"is {type(s).__name__}, expected an object")
            dt = _stamp(_value(s, "datetime"))
            out.append((dt, _number(s, f"{position}flow"), _number(s, f"{position}pressure")))
        except (ValueError, TypeError, OverflowError) as exc:
            raise HydwsError(f"{url}: sample {k + 1} of the HYDWS answer: {exc}") from None
    out.sort(key=lambda r: r[0])
    return out


def _samples_of(doc):
    if isinstance(doc, list) and all(isinstance(s, dict) and "sections" in s for s in doc) and doc:
        found = [_samples_of(b) for b in doc]
        return None if any(f is None for f in found) else [s for f in found for s in f]
    if isinstance(doc, dict) and isinstance(doc.get("sections"), list):
        out = []
        for sec in doc["sections"]:
            hyd = sec.get("hydraulics", []) if isinstance(sec, dict) else None
            if not isinstance(hyd, list):
                return None
            out += hyd
        return out
    return doc if isinstance(doc, list) else None


def replay_lines(samples, with_pressure: bool):
    """The replay-format lines of samples (without the header)."""
    out = []
    for dt, q, p in samples:
        cells = [dt.isoformat(), "" if q is None else repr(q)]
        if with_pressure:
            cells.append("" if p is None else repr(p))
        out.append(",".join(cells))
    return out


def _header(with_pressure: bool) -> str:
    return HEADER if with_pressure else HEADER.rsplit(",", 1)[0]


def _get(session, url: str, params: dict, timeout: float) -> bytes:
    full = url + ("?" + "&".join(f"{k}={v}" for k, v in params.items()) if params else "")
    try:
        r = session.get(url, params=params, timeout=timeout)
    except requests.RequestException as exc:
        reason = type(exc).__name__
        text = str(exc).lower()
        if "refused" in text:
            reason = "connection refused"
        elif "without response" in text or "aborted" in text or "reset" in text:
            reason = "connection closed without an answer"
        elif isinstance(exc, requests.Timeout):
            reason = f"no answer within {timeout:g} s"
        raise HydwsError(f"{full}: HYDWS server unreachable ({reason})") from None
    if r.status_code == 204:
        return b"[]"
    if r.status_code == 404:
        raise HydwsError(f"{full}: HTTP 404 Not Found (no such borehole section on this "
                         f"HYDWS server)")
    if r.status_code >= 400:
        raise HydwsError(f"{full}: HTTP {r.status_code} {r.reason}")
    return r.content


def _stamp_param(dt: datetime) -> str:
    # HYDWS takes whole seconds; the samples at or before the last one received are dropped
    return dt.astimezone(timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")


def _resumed_last(decoder) -> datetime | None:
    """Stamp of the last sample of a decoder resumed from a checkpoint (None otherwise): its
    model time 0 plus the sample's seconds after it."""
    state = decoder.state() if hasattr(decoder, "state") else {}
    if not state.get("start") or not state.get("last") or state.get("offset") is None:
        return None
    start = datetime.fromisoformat(state["start"])
    return (start + timedelta(seconds=state["last"][0] - state["offset"])).astimezone(timezone.utc)


class HydwsSource:
    """Follow a HYDWS borehole section (``--source hydws --follow URL``).

    Every ``poll_interval`` seconds the section's samples from the last one received on are
    asked for, and those after it are handed on, each once (after a restart with ``--state``:
    from the checkpoint's last sample on).  ``position``: ``top`` or ``bottom`` flow and
    pressure.  A server that cannot be reached or gives a bad answer is logged once and asked
    again with a doubling wait (up to ``max_backoff`` s); its return is logged.  At the start
    the section must answer (else :class:`HydwsError`: exit code 2).
    """

    main_option = "position"

    def __init__(self, target: str, *, decoder, poll_interval: float = 0.5,
                 log: logging.Logger | None = None, position: str | None = None,
                 timeout: float = 10.0, max_backoff: float = 60.0):
        self.url, self.query, self.position = hydraulics_url(target, position)
        self.target = str(target)
        self.decoder = decoder
        self.poll_interval = float(poll_interval)
        self.timeout, self.max_backoff = float(timeout), float(max_backoff)
        self.log = log or logging.getLogger("fault_screen.sources.hydws")
        self.session = requests.Session()
        self.finished = False
        self.last: datetime | None = None     # stamp of the last sample handed on
        self.failures = 0                     # consecutive failed requests
        self.outages = 0                      # times the server went away
        self._next_try = 0.0
        self._line = 0
        self._with_pressure = None
        self.last = _resumed_last(decoder)    # a restart asks from the checkpoint's sample on
        self._pending = self._fetch()         # the section must answer at the start

    def _fetch(self):
        params = dict(self.query)
        if self.last is not None:
            params["starttime"] = _stamp_param(self.last)
        data = _get(self.session, self.url, params, self.timeout)
        rows = parse_hydraulics(data, self.url, self.position)
        return [r for r in rows if self.last is None or r[0] > self.last]

    def _poll(self):
        now = time.monotonic()
        if now < self._next_try:
            return []
        try:
            rows = self._fetch()
        except HydwsError as exc:
            if self.failures == 0:
                self.outages += 1
                self.log.warning("%s; asking again with backoff", exc)
            self.failures += 1
            self._next_try = now + min(self.poll_interval * 2 ** self.failures, self.max_backoff)
            return []
        if self.failures:
            self.log.info("%s: HYDWS server answers again (after %d failed request(s))",
                          self.url, self.failures)
            self.failures = 0
        return rows

    def _decode(self, rows):
        out = []
        if not rows:
            return out
        if self._with_pressure is None:
            self._with_pressure = any(p is not None for _, _, p in rows)
            self._line += 1
            out += self.decoder.feed_line(_header(self._with_pressure), self._line)
        for text in replay_lines(rows, self._with_pressure):
            self._line += 1
            out += self.decoder.feed_line(text, self._line)
        self.last = rows[-1][0]
        return out

    def read(self, timeout: float):
        deadline = time.monotonic() + max(0.0, timeout)
        while True:
            rows, self._pending = self._pending or self._poll(), []
            out = self._decode(rows)
            left = deadline - time.monotonic()
            if out or left <= 0:
                return out
            time.sleep(min(self.poll_interval, left))

    def flush(self):
        return []

    def close(self):
        self.session.close()

    @staticmethod
    def read_log(url: str, **options):
        """A past window of a section, as ``fault-screen replay`` reads a log (:func:`read_log`)."""
        return read_log(url, **options)


def read_log(url: str, *, position: str | None = None, timeout: float = 30.0, **log_options):
    """The :class:`~fault_screen.io.injection_log.InjectionLog` of the samples of a HYDWS
    section (the window is the URL's ``starttime``/``endtime``); ``log_options`` as
    :func:`~fault_screen.io.injection_log.read_injection_log`.  Messages name the URL."""
    from fault_screen.io.injection_log import InjectionLogError, read_injection_log

    base, query, position = hydraulics_url(url, position)
    with requests.Session() as sess:
        rows = parse_hydraulics(_get(sess, base, query, timeout), base, position)
    if not rows:
        raise HydwsError(f"{url}: the HYDWS section has no samples in this window")
    with_p = any(p is not None for _, _, p in rows)
    fd, tmp = tempfile.mkstemp(suffix=".csv", prefix="hydws-")

    def named(text):       # messages name the URL, not the temporary file
        return text.replace(tmp, str(url)).replace(os.path.basename(tmp), str(url))

    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write("\n".join([_header(with_p)] + replay_lines(rows, with_p)) + "\n")
        try:
            log = read_injection_log(tmp, **log_options)
        except InjectionLogError as exc:
            raise HydwsError(named(str(exc))) from None
    finally:
        os.unlink(tmp)
    return dataclasses.replace(log, source=str(url), summary=named(log.summary),
                               warnings=tuple(named(w) for w in log.warnings))

"""Seismic event catalogues (QuakeML and the other formats obspy reads).

:func:`read_events` returns the origin times of the events as seconds relative to a reference
date-time (model time 0: the injection log's first stamp) and their magnitudes.  obspy is
imported only when a catalogue is read.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from typing import Optional, Tuple

import numpy as np

__all__ = ["EventCatalog", "EventsError", "read_events"]


class EventsError(ValueError):
    """A catalogue that cannot be read; the message names the file."""


@dataclass(frozen=True, eq=False)
class EventCatalog:
    """Events sorted by origin time.

    time : float64 array, s relative to ``start`` (negative before it)
    magnitude : float64 array, NaN where an event has no magnitude
    magnitude_type : str per event ("" if unknown)
    start : aware UTC datetime of ``time == 0`` (None for an empty catalogue without a start)
    source : the file read
    skipped : number of events without an origin time (not included)
    """

    time: np.ndarray
    magnitude: np.ndarray
    magnitude_type: Tuple[str, ...] = ()
    start: Optional[datetime] = None
    source: str = ""
    skipped: int = 0

    def __len__(self) -> int:
        return int(self.time.size)

    def origin_times(self):
        """Origin times as aware UTC datetimes."""
        if self.start is None:
            return []
        return [self.start + timedelta(seconds=float(t)) for t in self.time]

    def window(self, t0: float, t1: float) -> "EventCatalog":
        """The events with ``t0 <= time <= t1`` (s)."""
        keep = (self.time >= t0) & (self.time <= t1)
        return EventCatalog(self.time[keep], self.magnitude[keep],
                            tuple(m for m, k in zip(self.magnitude_type, keep) if k),
                            self.start, self.source, self.skipped)


def _to_utc(dt: datetime) -> datetime:
    if dt.utcoffset() is None:
        raise EventsError(f"start {dt.isoformat()} has no time zone")
    return dt.astimezone(timezone.utc)


def read_events(path, start: Optional[datetime] = None, *, format: Optional[str] = None
                ) -> EventCatalog:
    """Read an event catalogue (QuakeML by default detection) with obspy.

    ``start``: timezone-aware datetime of model time 0; event times are seconds after it.
    Without ``start`` the times are relative to the earliest event (which is then at 0 s).
    Each event's preferred origin (else its first origin) and preferred magnitude (else its
    first magnitude) are used; events without any origin time are skipped and counted.
    Raises ``FileNotFoundError`` for a missing file and :class:`EventsError` otherwise.
    """
    import obspy
    from pathlib import Path

    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(path))
    if start is not None:
        start = _to_utc(start)
    try:
        cat = obspy.read_events(str(p), format=format)
    except Exception as exc:  # obspy raises TypeError/ValueError/XML errors for bad files
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise EventsError(f"{path}: cannot read as an event catalogue (QuakeML): {why}") from None

    origins, mags, mtypes, skipped = [], [], [], 0
    for ev in cat:
        org = ev.preferred_origin() or (ev.origins[0] if ev.origins else None)
        if org is None or org.time is None:
            skipped += 1
            continue
        mag = ev.preferred_magnitude() or (ev.magnitudes[0] if ev.magnitudes else None)
        origins.append(org.time)
        if mag is not None and mag.mag is not None and math.isfinite(float(mag.mag)):
            mags.append(float(mag.mag))
            mtypes.append(mag.magnitude_type or "")
        else:
            mags.append(math.nan)
            mtypes.append("")

    order = sorted(range(len(origins)), key=lambda i: origins[i])
    origins = [origins[i] for i in order]
    mags = np.array([mags[i] for i in order], dtype=np.float64)
    mtypes = tuple(mtypes[i] for i in order)
    if start is None and origins:
        start = origins[0].datetime.replace(tzinfo=timezone.utc)
    if start is not None:
        ref = obspy.UTCDateTime(start.replace(tzinfo=None))   # start is UTC here
        times = np.array([float(o - ref) for o in origins], dtype=np.float64)
    else:
        times = np.zeros(0)
    return EventCatalog(times, mags, mtypes, start, str(path), skipped)

"""Seismic events of an FDSN event web service, for the monitor.

:class:`EventServiceFeed` polls the service (at most every ``interval`` seconds) through
:class:`~fault_screen.io.fdsn_events.EventServiceFollower` and hands the stage what a growing
catalogue file would give (:class:`~fault_screen.monitor.seismicity.SeismicEvent`, placed with
the scene's ``[site]``, ``id`` the event's public id), plus the public ids of the events the
service revised or deleted since (:meth:`EventServiceFeed.take_withdrawn`): the stage forgets
those before the revised ones come in again, so each event is kept once with its latest values.
What was handed on is part of the monitor's checkpoint (:meth:`EventServiceFeed.state`), so a
restarted monitor sees the revisions and deletions made while it was down.
A service that fails while the monitor runs is logged once and asked again at the next polls.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from datetime import datetime
from typing import List, Optional

from ..io.fdsn_events import EventServiceError, EventServiceFollower, is_event_service
from .seismicity import CatalogFollower, SeismicEvent, events_from_catalog

__all__ = ["EventServiceFeed", "follower_for", "POLL_INTERVAL"]

#: shortest wall time (s) between two requests to an event service
POLL_INTERVAL = 2.0


class EventServiceFeed:
    """New and revised events of an FDSN event service (see the module docstring)."""

    def __init__(self, url: str, start: datetime, *, site=None, interval: Optional[float] = None,
                 log: Optional[logging.Logger] = None):
        self.url, self.site = url, site
        self.follower = EventServiceFollower(url, start, site=site)
        self.interval = POLL_INTERVAL if interval is None else float(interval)
        self.log = log or logging.getLogger("fault_screen.monitor.events")
        self.failing = False
        self.revised = self.deleted = 0
        self._withdrawn: List[str] = []
        self._last = -float("inf")

    def poll(self) -> List[SeismicEvent]:
        now = time.monotonic()
        if now - self._last < self.interval:
            return []
        self._last = now
        try:
            ch = self.follower.poll()
        except EventServiceError as exc:
            if not self.failing:
                self.log.warning("%s; asking again at the next polls", exc)
                self.failing = True
            return []
        if self.failing:
            self.log.info("%s: event service answers again", self.url)
            self.failing = False
        for what, ids in (("revised", ch.revised), ("deleted", ch.deleted)):
            if ids:
                self.log.info("%s: %d event(s) %s: %s", self.url, len(ids), what, ", ".join(ids))
        self.revised += len(ch.revised)
        self.deleted += len(ch.deleted)
        self._withdrawn += ch.revised + ch.deleted
        events = events_from_catalog(ch.catalog, self.site, self.url)
        return [dataclasses.replace(e, id=pid) for e, pid in zip(events, ch.ids)]

    def state(self) -> dict:
        """JSON-able state for a checkpoint: what was handed on, per public id."""
        return {"known": {pid: list(fp) for pid, fp in self.follower.known.items()}}

    def restore(self, state: dict) -> None:
        """Continue after a checkpoint: an event revised or deleted meanwhile is seen as such."""
        self.follower.known = {pid: tuple(fp) for pid, fp in state.get("known", {}).items()}

    def take_withdrawn(self) -> List[str]:
        """Public ids of the events revised or deleted since the last call."""
        out, self._withdrawn = self._withdrawn, []
        return out


def follower_for(events, start: datetime, *, site=None):
    """The follower of ``--events``: an event service for an http(s) URL, else the file."""
    if is_event_service(events):
        return EventServiceFeed(events, start, site=site)
    return CatalogFollower(events, start, site=site)

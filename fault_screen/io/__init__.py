"""Operators' files: injection logs (CSV dialects), seismic event catalogues (QuakeML, CSV,
FDSN text) and the replay of a log through the model.

``read_injection_log(path, ...) -> InjectionLog`` (see :mod:`fault_screen.io.injection_log`),
``read_events(path, start, site=...) -> EventCatalog`` (:mod:`fault_screen.io.events`),
``replay(scene, log) -> Result`` (:mod:`fault_screen.io.replay`).
"""
from .events import EventCatalog, EventsError, read_events
from .injection_log import InjectionLog, InjectionLogError, read_injection_log
from .replay import ReplayPlan, plan_replay, replay

__all__ = ["InjectionLog", "InjectionLogError", "read_injection_log", "EventCatalog",
           "EventsError", "read_events", "ReplayPlan", "plan_replay", "replay"]

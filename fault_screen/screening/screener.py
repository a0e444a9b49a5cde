"""The traffic light: rules of ``[monitor]`` evaluated step by step, with hold times.

:class:`Screener` is streaming: the live monitor calls :meth:`Screener.update` once per output time
with that time's metrics and any new seismic events; :func:`fault_screen.screening.screen_result`
drives the same object over a whole result, so both give the same levels.

Semantics
---------
* A rule is *in force* from the first update at which its condition holds until the first update
  at least ``hold`` seconds after the last one at which it held (``hold = 0``: only while it holds).
* The level is the highest level of the rules in force (0 green, 1 yellow, 2 red); among rules of
  that level, the first in the list names it.  A raise is immediate; a fall waits for the holds.
* A quasi-static instability (the run stopped because the slip rate exceeded the scene's limit)
  is red for good, through the built-in rule ``unstable``.
* Seismic events count at the first update whose time is at or after their origin time (events
  before the first update are background and ignored by the rules).  A rule that names
  ``event_magnitude`` or ``event_distance`` holds if it holds for one of the events counted at
  this update, each with its own magnitude and distance; with no such event, or an event without
  a distance, those values are missing: their comparisons are unknown and a rule holds only when
  its condition is true (``not event_magnitude < 2`` does not hold without an event; see
  :mod:`fault_screen.rules`).  ``event_rate`` counts
  the events received so far whose origin times lie in the trailing ``event_rate_window``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from ..rules import METRICS, parse_condition

GREEN, YELLOW, RED = 0, 1, 2
LEVEL_NAMES = ("green", "yellow", "red")
LEVELS = {name: i for i, name in enumerate(LEVEL_NAMES)}
#: name and action of the built-in rule for a run stopped by an unstable fault
UNSTABLE_RULE = "unstable"
UNSTABLE_ACTION = ("stop injection and bleed off: the modelled fault became unstable (slip rate "
                   "beyond the scene's limit; the quasi-static model cannot follow it further)")


@dataclass(frozen=True)
class Transition:
    """A change of level at ``time`` (s), caused by ``rule`` (for a fall: the rule released)."""
    time: float
    from_level: int
    to_level: int
    rule: str
    action: str = ""
    metrics: dict = field(default_factory=dict, compare=False)

    def describe(self) -> str:
        verb = "raised" if self.to_level > self.from_level else "lowered"
        return (f"t = {self.time:.6g} s: {LEVEL_NAMES[self.from_level]} -> "
                f"{LEVEL_NAMES[self.to_level]} ({verb} by rule {self.rule!r})")


@dataclass
class Verdict:
    """The highest level reached, when it was first reached, by which rule, what to do, and the
    metrics then (an unstable stop names the verdict even when red came earlier);
    ``final_level`` is the level at the last update."""
    level: int = GREEN
    time: float | None = None
    rule: str | None = None
    action: str = ""
    metrics: dict = field(default_factory=dict)
    final_level: int = GREEN

    @property
    def level_name(self) -> str:
        return LEVEL_NAMES[self.level]


class Events:
    """Seismic events: origin times (s of model time), magnitudes, distances from the injection
    point (m; NaN where unknown).  Built from anything with ``.time`` and ``.magnitude`` (and
    optionally ``.distance``) or from a dict with those keys."""

    def __init__(self, time, magnitude, distance=None):
        self.time = np.atleast_1d(np.asarray(time, dtype=float))
        self.magnitude = np.atleast_1d(np.asarray(magnitude, dtype=float))
        if distance is None:
            distance = np.full(self.time.shape, np.nan)
        self.distance = np.atleast_1d(np.asarray(distance, dtype=float))
        if not (self.time.shape == self.magnitude.shape == self.distance.shape):
            raise ValueError(f"events: {self.time.size} times, {self.magnitude.size} magnitudes and "
                             f"{self.distance.size} distances: they must match")

    @classmethod
    def coerce(cls, events) -> "Events | None":
        if events is None or isinstance(events, Events):
            return events
        get = events.get if isinstance(events, dict) else lambda k, d=None: getattr(events, k, d)
        return cls(get("time"), get("magnitude"), get("distance", None))

    def __len__(self):
        return int(self.time.size)


def event_metrics(time: float, new_events, known_times, window: float) -> dict:
    """The event metrics at ``time`` (s): ``event_magnitude`` and ``event_distance`` of the
    largest of ``new_events`` ((time, magnitude, distance) tuples; an event without a magnitude
    counts below every magnitude; NaN when there is none), ``event_rate`` the number of
    ``known_times`` in ``(time - window, time]`` per hour.  The one definition the screener and
    the monitor stage use."""
    recent = sum(1 for t in known_times if time - window < t <= time)
    biggest = max(new_events, key=lambda e: -math.inf if math.isnan(e[1]) else e[1], default=None)
    return {"event_rate": recent * 3600.0 / window,
            "event_magnitude": float(biggest[1]) if biggest else math.nan,
            "event_distance": float(biggest[2]) if biggest else math.nan}


class _Rule:
    def __init__(self, spec, index, known):
        self.name = spec.name or f"rules[{index}]"
        self.level = LEVELS[spec.level]
        self.hold = float(spec.hold)
        self.action = spec.action
        self.condition = parse_condition(spec.when, known)
        self.last_true = None


def _plain(metrics: dict) -> dict:
    return {str(k): float(v) for k, v in metrics.items()}


def thresholds_of(spec) -> dict:
    """The named thresholds of a :class:`~fault_screen.scene.MonitorSpec` (rules may use them)."""
    return {f.name: float(getattr(spec, f.name)) for f in fields(spec) if f.name != "rules"}


class Screener:
    """Streaming evaluation of the rules of a ``[monitor]`` spec (``scene.monitor``)."""

    def __init__(self, spec):
        self.spec = spec
        self.thresholds = thresholds_of(spec)
        known = set(METRICS) | set(self.thresholds)
        self.rules = [_Rule(r, i, known) for i, r in enumerate(spec.rules)]
        self.level = GREEN
        self.rule = None            # the rule that names the current level
        self.unstable = False
        self.transitions: list[Transition] = []
        self.verdict = Verdict()
        self._start = None
        self._pending: list[tuple[float, float, float]] = []   # (time, magnitude, distance)
        self._known_times: list[float] = []

    def state(self) -> dict:
        """What the screener has seen so far, as plain data (JSON-able; the rules come from the
        spec given to :meth:`from_state`)."""
        tr = [dict(time=t.time, from_level=t.from_level, to_level=t.to_level, rule=t.rule,
                   action=t.action, metrics=_plain(t.metrics)) for t in self.transitions]
        v = self.verdict
        return {"level": self.level, "rule": self.rule, "unstable": self.unstable,
                "transitions": tr, "start": self._start,
                "verdict": dict(level=v.level, time=v.time, rule=v.rule, action=v.action,
                                metrics=_plain(v.metrics), final_level=v.final_level),
                "pending": [list(e) for e in self._pending], "known_times": list(self._known_times),
                "last_true": [r.last_true for r in self.rules]}

    @classmethod
    def from_state(cls, spec, state: dict) -> "Screener":
        """The screener of ``spec`` continuing from :meth:`state`."""
        out = cls(spec)
        if len(state["last_true"]) != len(out.rules):
            raise ValueError(f"screener state of {len(state['last_true'])} rules for a spec of "
                             f"{len(out.rules)} rules")
        out.level, out.rule, out.unstable = int(state["level"]), state["rule"], bool(state["unstable"])
        out.transitions = [Transition(float(d["time"]), int(d["from_level"]), int(d["to_level"]),
                                      str(d["rule"]), str(d["action"]), dict(d["metrics"]))
                           for d in state["transitions"]]
        out.verdict = Verdict(**state["verdict"])
        out._start = state["start"]
        out._pending = [(float(t), float(m), float(d)) for t, m, d in state["pending"]]
        out._known_times = [float(t) for t in state["known_times"]]
        for rule, last in zip(out.rules, state["last_true"]):
            rule.last_true = last
        return out

    def add_events(self, events) -> None:
        """Events to take into account from now on (each once, at its origin time)."""
        ev = Events.coerce(events)
        if ev is None:
            return
        for t, m, d in zip(ev.time, ev.magnitude, ev.distance):
            self._pending.append((float(t), float(m), float(d)))
            self._known_times.append(float(t))

    def forget_events(self, times) -> None:
        """Forget events given earlier (a revised or deleted event of an event service): each
        origin time leaves the events still to count and the ``event_rate`` history once."""
        for t in map(float, times):
            if t in self._known_times:
                self._known_times.remove(t)
            pending = next((e for e in self._pending if e[0] == t), None)
            if pending is not None:
                self._pending.remove(pending)

    def update(self, time: float, metrics: dict, events=None, unstable: bool = False) -> list[Transition]:
        """Evaluate the rules at ``time`` (s) with ``metrics`` (name -> SI value, NaN = missing)
        and the new ``events``; ``unstable``: the run stopped here on an unstable fault.
        Returns the level changes (at most one).  ``metrics`` gets the event metrics added."""
        time = float(time)
        if self._start is None:
            self._start = time
        self.add_events(events)
        now = [e for e in self._pending if e[0] <= time]
        self._pending = [e for e in self._pending if e[0] > time]
        now = [e for e in now if e[0] >= self._start]
        window = self.spec.event_rate_window
        self._known_times = [t for t in self._known_times if t > time - window]  # time only grows
        values = dict(self.thresholds)
        values.update(metrics)
        values.update(event_metrics(time, now, self._known_times, window))
        metrics.update({k: values[k] for k in ("event_rate", "event_magnitude", "event_distance")})

        in_force = []
        for rule in self.rules:
            if rule.condition.uses_events and now:
                holds = any(rule.condition.evaluate({**values, "event_magnitude": m, "event_distance": d})
                            for _, m, d in now)
            else:
                holds = rule.condition.evaluate(values)
            if holds:
                rule.last_true = time
            if rule.last_true is not None and (holds or time - rule.last_true < rule.hold):
                in_force.append(rule)
        self.unstable = self.unstable or bool(unstable)

        level, governing = GREEN, None
        if self.unstable:
            level = RED
        else:
            for rule in in_force:
                if rule.level > level:
                    level, governing = rule.level, rule
        name = UNSTABLE_RULE if self.unstable else (governing.name if governing else None)
        action = UNSTABLE_ACTION if self.unstable else (governing.action if governing else "")
        out = []
        if level != self.level or (self.unstable and self.rule != UNSTABLE_RULE):
            cause = name if level >= self.level else self.rule
            tr = Transition(time, self.level, level, cause, action if level >= self.level else "",
                            dict(metrics))
            self.transitions.append(tr)
            out.append(tr)
        self.level, self.rule = level, name
        v = self.verdict
        if level > v.level or (self.unstable and v.rule != UNSTABLE_RULE):
            v.level, v.time, v.rule, v.action, v.metrics = level, time, name, action, dict(metrics)
        v.final_level = level
        return out

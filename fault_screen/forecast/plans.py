"""Injection plans: what the injection does from "now" on, for a look-ahead.

A plan is written as one of

* ``scene``: the run's own drive continues (the scene's schedule, or the log a replay follows);
* ``hold``: the last rate (pressure control: the last overpressure) continues;
* ``stop``: rate 0, a shut-in (pressure control: overpressure 0, a bleed-off);
* ``rate:30 L/min``: a constant rate in any flow-rate unit the logs accept (rate control);
* ``pressure:4 MPa``: a constant overpressure in any pressure unit (pressure control);
* ``scale:1.2``: the ``scene`` plan times 1.2;
* a file: an injection log in any format ``replay`` reads; date-time stamps are placed on the
  run's clock (its start date-time is needed), an ``elapsed`` column counts from "now".
  After the log's last sample the rate is 0.

:func:`parse_plan` turns the text into a :class:`Plan` or raises :class:`PlanError` saying what
is wrong; :meth:`Plan.drive` gives what ``Simulation.advance`` takes to follow it from "now".
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Optional

import numpy as np

from ..units import UnitError, split_value, to_si

__all__ = ["Plan", "PlanError", "parse_plan", "parse_duration", "largest_rate_so_far", "PLAN_HELP"]

PLAN_HELP = ("scene, hold, stop, rate:<value unit> (e.g. rate:30 L/min), pressure:<value unit>, "
             "scale:<factor> (e.g. scale:1.2), or an injection log file")


class PlanError(ValueError):
    """A plan (or a duration) that cannot be read; the message says why and what is accepted."""


@dataclass(frozen=True)
class Plan:
    """One injection plan. ``kind``: scene, hold, stop, rate, pressure, scale or log; ``value``:
    the rate (m3/s), the overpressure (Pa) or the factor (-); ``log``: the InjectionLog of a
    file plan. ``name``: the plan as written (the label of its forecast)."""

    name: str
    kind: str
    value: Optional[float] = None
    log: object = None

    @classmethod
    def constant(cls, value: float, control: str = "rate") -> "Plan":
        """A constant rate (m3/s) or, under pressure control, overpressure (Pa)."""
        unit = "m3/s" if control == "rate" else "Pa"
        kind = "rate" if control == "rate" else "pressure"
        return cls(f"{kind}:{value:.6g} {unit}", kind, float(value))

    def check(self, control: str) -> "Plan":
        """This plan, if a scene with ``injection.control = control`` can follow it."""
        if control == "pressure" and self.kind in ("rate", "log"):
            raise PlanError(f"plan {self.name!r}: this scene is pressure-controlled; use "
                            f"pressure:<value unit>, hold, stop, scale:<factor> or scene")
        if control != "pressure" and self.kind == "pressure":
            raise PlanError(f"plan {self.name!r}: a pressure plan needs a pressure-controlled scene "
                            f"(this one has injection.control = {control!r}); use rate:<value unit>")
        return self

    def drive(self, sim, drive=None, start: Optional[datetime] = None) -> dict:
        """The keyword arguments of ``sim.advance`` that follow this plan from ``sim.time`` on.
        ``drive``: what drove the run so far (an object with ``volume(t0, t1)`` and
        ``rate_at(t)``, e.g. an InjectionLog), None for the scene's own schedule; ``start``:
        the date-time of model time 0 (for a log plan with date-times)."""
        control = sim.scene.injection.control
        self.check(control)
        now = float(sim.time)
        if control == "pressure":
            return {"pressure": self._pressure(sim, now)}
        base = drive.volume if drive is not None else sim.schedule.volume
        if self.kind == "scene":
            return {"volume": drive.volume if drive is not None else None}
        if self.kind == "stop":
            return {"volume": lambda t0, t1: 0.0}
        if self.kind == "scale":
            f = self.value
            return {"volume": lambda t0, t1: f * base(t0, t1)}
        if self.kind in ("hold", "rate"):
            q = self.value if self.kind == "rate" else _rate_now(sim, drive, now)
            return {"volume": lambda t0, t1: q * (t1 - t0)}
        log = self.log
        shift = now
        if log.start is not None:
            if start is None:
                raise PlanError(f"plan {self.name!r}: the log has date-times but the run's start "
                                f"date-time is not known (give --t0, or write the log with an "
                                f"elapsed column counted from now)")
            shift = (log.start - start).total_seconds()
        return {"volume": lambda t0, t1: log.volume(t0 - shift, t1 - shift)}

    def _pressure(self, sim, now):
        schedule = sim.schedule
        if self.kind == "scene":
            return None
        if self.kind == "stop":
            return 0.0
        if self.kind == "pressure":
            return self.value
        if self.kind == "hold":
            return schedule.value_at(now) if now > 0 else schedule.value_at(math.ulp(0.0))
        f = self.value
        return lambda t: f * schedule.value_at(t)


def _rate_now(sim, drive, now) -> float:
    """The last rate (m3/s): that of the schedule's interval ending now, or the drive's."""
    if drive is not None:
        return float(drive.rate_at(now))
    return sim.schedule.value_at(now) if now > 0 else sim.schedule.value_at(math.ulp(0.0))


def largest_rate_so_far(sim, drive=None) -> float:
    """The largest injection rate (m3/s; pressure control: overpressure, Pa) up to ``sim.time``
    under the run's drive (the scene's schedule, or a log with ``time`` and ``flow_rate``)."""
    now = float(sim.time)
    if drive is None or sim.scene.injection.control == "pressure":
        sch = sim.schedule
        before = sch.values[sch.times <= now] if now > 0 else sch.values[:1]
        return float(np.max(before)) if before.size else 0.0
    times = getattr(drive, "time", None)
    rates = getattr(drive, "flow_rate", None)
    best = float(drive.rate_at(now))
    if times is not None and rates is not None:
        seen = np.asarray(rates)[np.asarray(times) <= now]
        if seen.size:
            best = max(best, float(np.max(seen)))
    return best


def _quantity(text: str, quantity: str, what: str) -> float:
    try:
        value, unit = split_value(text)
    except ValueError:
        raise PlanError(f"plan {what!r}: {text.strip()!r} is not a number with a unit "
                        f"(e.g. {'30 L/min' if quantity == 'flow_rate' else '4 MPa'})") from None
    if unit is None:
        raise PlanError(f"plan {what!r}: give the unit (e.g. {'30 L/min' if quantity == 'flow_rate' else '4 MPa'})")
    try:
        si = to_si(value, unit, quantity)
    except UnitError as exc:
        raise PlanError(f"plan {what!r}: {exc}") from None
    if not math.isfinite(si) or si < 0:
        raise PlanError(f"plan {what!r}: the value must be finite and >= 0")
    return si


def parse_plan(text: str, *, log_options: Optional[dict] = None) -> Plan:
    """The plan ``text`` names (see the module docstring). ``log_options``: keywords of
    ``read_injection_log`` for a file plan (units, time zone, policy...)."""
    if not isinstance(text, str):
        raise PlanError(f"plan {text!r}: expected text ({PLAN_HELP})")
    name = text.strip()
    word = name.lower()
    if word in ("scene", "hold", "stop"):
        return Plan(word, word)
    head, sep, rest = name.partition(":")
    key = head.strip().lower()
    if sep and key == "rate":
        return Plan(name, "rate", _quantity(rest, "flow_rate", name))
    if sep and key == "pressure":
        return Plan(name, "pressure", _quantity(rest, "pressure", name))
    if sep and key == "scale":
        try:
            factor = float(rest.strip())
        except ValueError:
            raise PlanError(f"plan {name!r}: the factor {rest.strip()!r} is not a number "
                            f"(e.g. scale:1.2)") from None
        if not math.isfinite(factor) or factor < 0:
            raise PlanError(f"plan {name!r}: the factor must be finite and >= 0")
        return Plan(name, "scale", factor)
    try:
        is_file = bool(name) and "\x00" not in name and Path(name).is_file()
    except (OSError, ValueError):
        is_file = False
    if not is_file:
        raise PlanError(f"unknown plan {name!r}: expected {PLAN_HELP} (no such file)")
    from ..io.injection_log import read_injection_log

    try:
        log = read_injection_log(name, **(log_options or {}))
    except (ValueError, OSError) as exc:
        raise PlanError(f"plan {name!r}: {exc}") from None
    return Plan(name, "log", log=log)


def parse_duration(text, what: str = "duration") -> float:
    """Seconds from a bare number (s) or a number with a time unit (``2h``, ``30 min``, ``1.5 day``);
    must be finite and >= 0."""
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        seconds = float(text)
    else:
        try:
            value, unit = split_value(str(text))
            seconds = value if unit is None else to_si(value, unit, "time")
        except (ValueError, UnitError) as exc:
            raise PlanError(f"{what} {text!r}: not a duration (seconds, or a number with a unit: "
                            f"2h, 30 min): {exc}") from None
    if not math.isfinite(seconds) or seconds < 0:
        raise PlanError(f"{what} {text!r}: must be a finite duration >= 0")
    return float(seconds)

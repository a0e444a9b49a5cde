"""Advice: the largest constant rate whose look-ahead stays below a level over the horizon.

Bisection on forks between 0 and ``max_rate`` (default: twice the largest rate so far), to
``tolerance`` (2 %) of the rate found: the advised rate's look-ahead stays below the level and
a rate ``1 + tolerance`` times it (or more) reaches it, as far as the level grows with the
rate. Under pressure control the same is done with a constant overpressure. When even rate 0
reaches the level (a rule's hold keeping it counts), the fault is going there whatever the
injection does next (Basel 2006: the largest event came after the shut-in); the advice says so
and advises 0. The evaluations share the fork point, and with a step ladder its factorisations;
a rate's look-ahead stops once it reaches the level.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from ..screening import LEVEL_NAMES, YELLOW
from .lookahead import Forecast, LookAhead
from .plans import Plan, largest_rate_so_far

__all__ = ["Advice", "advise"]

#: the bisection stops after this many look-aheads whatever the bracket
MAX_EVALUATIONS = 40

#: steps down from a rate that reaches the level before the bracket's lower end is taken as 0
BRACKET_STEPS = 6


@dataclass
class Advice:
    """The advised constant ``rate`` (m3/s; Pa under pressure control) for ``level`` over
    ``horizon`` (s) from ``made_at``; ``upper``: the smallest rate found to reach the level
    (None when even ``max_rate`` stays below); ``even_zero_reaches``: shut-in reaches it too."""

    made_at: float
    horizon: float
    level: int
    control: str
    rate: float
    upper: Optional[float]
    max_rate: float
    even_zero_reaches: bool
    evaluations: int
    forecasts: list = field(default_factory=list, repr=False)

    @property
    def below(self) -> Forecast:
        """The look-ahead of the advised rate."""
        return next(f for f in self.forecasts if f.plan == Plan.constant(self.rate, self.control).name)

    def describe(self) -> str:
        name = LEVEL_NAMES[self.level]
        what = "rate" if self.control == "rate" else "overpressure"
        value = (f"{self.rate * 60e3:.4g} L/min ({self.rate:.4g} m3/s)" if self.control == "rate"
                 else f"{self.rate / 1e6:.4g} MPa")
        span = f"{self.horizon / 3600:.3g} h" if self.horizon >= 3600 else f"{self.horizon:.4g} s"
        if self.even_zero_reaches:
            return (f"advice at t = {self.made_at:.6g} s: even {'shut-in' if self.control == 'rate' else 'overpressure 0'} "
                    f"is at {name} within {span} (the rules' holds count): the fault is going there whatever "
                    f"the injection does")
        if self.upper is None:
            return (f"advice at t = {self.made_at:.6g} s: every {what} up to the largest tried, {value}, "
                    f"stays below {name} for {span}")
        return f"advice at t = {self.made_at:.6g} s: largest constant {what} below {name} for {span}: {value}"


def advise(lookahead: LookAhead, horizon: float, *, level: int = YELLOW, max_rate: Optional[float] = None,
           tolerance: float = 0.02, near: Optional[float] = None) -> Advice:
    """Bisect for the largest constant rate (overpressure) in [0, ``max_rate``] whose look-ahead
    from ``lookahead``'s state stays below ``level`` over ``horizon`` (s). ``near``: a rate
    expected close to the answer (the last advice of a live run): the bracket is first sought
    around it, widening 2 ``tolerance``, then twice that, ... until one side stays below and the
    other reaches the level (the same bracket, in fewer look-aheads when the answer moved little)."""
    control = lookahead.control
    if max_rate is None:
        max_rate = 2.0 * largest_rate_so_far(lookahead.state, lookahead.drive)
    if not max_rate > 0:
        raise ValueError("advice: the largest rate so far is 0: give the largest rate to try "
                         "(--max-rate)")
    forecasts = []

    def reaches(value: float) -> bool:
        # a rate above 0 stops at the level (whether it is reached is all the bisection asks);
        # shut-in runs the whole horizon: when it reaches the level, its forecast is the advice
        f = lookahead.run(Plan.constant(value, control), horizon, until=level if value > 0 else None)
        forecasts.append(f)
        return f.reaches(level)

    out = dict(made_at=lookahead.made_at, horizon=float(horizon), level=level, control=control,
               max_rate=float(max_rate), forecasts=forecasts)
    if reaches(0.0):
        return Advice(rate=0.0, upper=0.0, even_zero_reaches=True, evaluations=1, **out)
    max_rate = float(max_rate)
    if near is not None and 0.0 < near < max_rate:
        lo, hi = _bracket(reaches, float(near), max_rate, 2.0 * tolerance)
        if hi is None:
            return Advice(rate=max_rate, upper=None, even_zero_reaches=False,
                          evaluations=len(forecasts), **out)
    elif not reaches(max_rate):
        return Advice(rate=max_rate, upper=None, even_zero_reaches=False, evaluations=2, **out)
    else:
        lo, hi = 0.0, max_rate
    while hi - lo > tolerance * lo and len(forecasts) < MAX_EVALUATIONS:
        mid = 0.5 * (lo + hi)
        if reaches(mid):
            hi = mid
        else:
            lo = mid
    return Advice(rate=lo, upper=hi, even_zero_reaches=False, evaluations=len(forecasts), **out)


def _bracket(reaches, near, max_rate, widen):
    """(lo, hi) around ``near``: lo stays below the level (0 is known to), hi reaches it (None:
    not even ``max_rate`` does); each step away from ``near`` is ``widen`` times it, doubling
    (after BRACKET_STEPS down, lo is 0 and the bisection does the rest)."""
    if reaches(near):
        hi = near
        for _ in range(BRACKET_STEPS):
            value = hi / (1.0 + widen)
            if not reaches(value):
                return value, hi
            hi = value
            widen *= 2.0
        return 0.0, hi
    lo = near
    while True:
        value = min(lo * (1.0 + widen), max_rate)
        if reaches(value):
            return lo, value
        if value >= max_rate:
            return max_rate, None
        lo = value
        widen *= 2.0

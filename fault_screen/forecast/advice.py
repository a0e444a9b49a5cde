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
           tolerance: float = 0.02) -> Advice:
    """Bisect for the largest constant rate (overpressure) in [0, ``max_rate``] whose look-ahead
    from ``lookahead``'s state stays below ``level`` over ``horizon`` (s)."""
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
    if not reaches(max_rate):
        return Advice(rate=float(max_rate), upper=None, even_zero_reaches=False, evaluations=2, **out)
    lo, hi = 0.0, float(max_rate)
    while hi - lo > tolerance * lo and len(forecasts) < MAX_EVALUATIONS:
        mid = 0.5 * (lo + hi)
        if reaches(mid):
            hi = mid
        else:
            lo = mid
    return Advice(rate=lo, upper=hi, even_zero_reaches=False, evaluations=len(forecasts), **out)

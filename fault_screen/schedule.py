"""A scene's own injection schedule: steps (time s, value) that hold until the next one."""
from __future__ import annotations

import numpy as np


class StepSchedule:
    """Piecewise-constant schedule; the value before the first step is 0."""

    def __init__(self, steps):
        self.times = np.array([t for t, _ in steps], dtype=float)
        self.values = np.array([v for _, v in steps], dtype=float)

    def volume(self, t0: float, t1: float) -> float:
        """Integral of the schedule over [t0, t1] (m^3 for a flow-rate schedule)."""
        ends = np.append(self.times, np.inf)
        lo = np.clip(ends[:-1], t0, t1)
        hi = np.clip(ends[1:], t0, t1)
        return float(np.sum(self.values * (hi - lo)))

    def value_at(self, t: float) -> float:
        """Value on the interval ending at t (the last step starting before t)."""
        v = 0.0
        for ts, val in zip(self.times, self.values):
            if ts < t:
                v = float(val)
        return v

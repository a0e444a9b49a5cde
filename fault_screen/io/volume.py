"""The volume injected by a sampled flow rate: linear between samples, zero outside them.

:class:`PiecewiseLinearVolume` is the one place where a replay (a whole
:class:`~fault_screen.io.injection_log.InjectionLog`) and the monitor (samples arriving one by
one) integrate a rate, so that both hand the model the same volume for the same step, bit for
bit: the cumulative volume at each sample is the trapezoid sum of the samples before it, and the
volume up to a time inside an interval adds the exact partial trapezoid.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["PiecewiseLinearVolume"]


class PiecewiseLinearVolume:
    """Exact integral of a rate that is linear between samples and zero outside them.

    ``time`` (s, strictly increasing) and ``flow_rate`` (m3/s) are the samples; ``cumulative``
    (m3) the volume injected up to each sample (default: from 0 at the first).  Samples may be
    appended in time order (:meth:`append`) and the oldest forgotten (:meth:`drop_before`); the
    cumulative volume stays absolute.
    """

    def __init__(self, time=(), flow_rate=(), cumulative=None):
        t = np.array(time, dtype=np.float64).reshape(-1)
        q = np.array(flow_rate, dtype=np.float64).reshape(-1)
        if q.shape != t.shape:
            raise ValueError(f"time has {t.size} samples but flow_rate has {q.size}")
        if cumulative is None:
            # the trapezoid of each interval, summed in order (append does the same operations)
            c = np.concatenate(([0.0], np.cumsum(0.5 * (q[1:] + q[:-1]) * np.diff(t)))) \
                if t.size else np.zeros(0)
        else:
            c = np.array(cumulative, dtype=np.float64).reshape(-1)
            if c.shape != t.shape:
                raise ValueError(f"time has {t.size} samples but cumulative has {c.size}")
        self._t, self._q, self._c = t, q, c
        self._n = t.size

    # -- the samples ------------------------------------------------------------------------
    def __len__(self) -> int:
        return self._n

    @property
    def time(self) -> np.ndarray:
        """Sample times (s), a view."""
        return self._t[:self._n]

    @property
    def flow_rate(self) -> np.ndarray:
        """Sample rates (m3/s), a view."""
        return self._q[:self._n]

    @property
    def cumulative(self) -> np.ndarray:
        """Volume (m3) injected up to each sample, a view."""
        return self._c[:self._n]

    def append(self, t: float, q: float) -> None:
        """Add a sample after the last one."""
        n = self._n
        if n == self._t.size:
            grow = max(16, 2 * n)
            self._t, self._q, self._c = (np.resize(a, grow) for a in (self._t, self._q, self._c))
        if n:
            # the operations of the constructor's cumsum, for one more interval
            self._c[n] = self._c[n - 1] + 0.5 * (q + self._q[n - 1]) * (t - self._t[n - 1])
        else:
            self._c[n] = 0.0
        self._t[n], self._q[n] = t, q
        self._n = n + 1

    def drop_before(self, t: float) -> None:
        """Forget the samples wholly before ``t`` (the one at or just before it is kept)."""
        k = int(np.searchsorted(self.time, t, side="right")) - 1
        if k > 0:
            n = self._n - k
            for a in (self._t, self._q, self._c):
                a[:n] = a[k:self._n].copy()
            self._n = n

    # -- evaluation -------------------------------------------------------------------------
    def rate_at(self, t):
        """Rate (m3/s) at time(s) ``t`` (s); 0 outside the samples."""
        ta = np.asarray(t, dtype=np.float64)
        if self._n == 0:
            out = np.zeros_like(ta)
        else:
            out = np.interp(ta, self.time, self.flow_rate, left=0.0, right=0.0)
        return float(out) if out.ndim == 0 else out

    def volume_to(self, t) -> np.ndarray:
        """Volume (m3) injected up to time(s) ``t`` (s), on the scale of :attr:`cumulative`."""
        ta = np.asarray(t, dtype=np.float64)
        tt, qq, cum = self.time, self.flow_rate, self.cumulative
        if tt.size == 0:
            raise ValueError("no samples yet")
        if tt.size == 1:
            return np.full(ta.shape, cum[0])
        i = np.clip(np.searchsorted(tt, ta, side="right") - 1, 0, tt.size - 2)
        tc = np.clip(ta, tt[0], tt[-1])
        dt = tc - tt[i]
        slope = (qq[i + 1] - qq[i]) / (tt[i + 1] - tt[i])
        inside = cum[i] + dt * (qq[i] + 0.5 * slope * dt)
        return np.where(ta >= tt[-1], cum[-1], inside)

    def volume(self, t0: float = -math.inf, t1: float = math.inf) -> float:
        """Exact integral (m3) of the rate from ``t0`` to ``t1`` (s); signed when ``t1 < t0``."""
        v = self.volume_to(np.array([t0, t1], dtype=np.float64))
        return float(v[1] - v[0])

    def step_volumes(self, times) -> np.ndarray:
        """Volumes (m3) between consecutive entries of ``times`` (non-decreasing)."""
        ta = np.asarray(times, dtype=np.float64).reshape(-1)
        if np.any(np.isnan(ta)):
            raise ValueError("times contain NaN")
        if np.any(np.diff(ta) < 0):
            raise ValueError("times must be non-decreasing")
        return np.diff(self.volume_to(ta))

    @property
    def total(self) -> float:
        """Volume (m3) up to the last sample."""
        return float(self._c[self._n - 1]) if self._n else 0.0

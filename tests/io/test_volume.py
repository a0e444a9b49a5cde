"""The one volume class of replay and monitor: exact integrals of a piecewise-linear rate, the
same bits whether the samples come at once or one by one."""
from __future__ import annotations

import numpy as np
import pytest

from fault_screen.io.injection_log import InjectionLog
from fault_screen.io.volume import PiecewiseLinearVolume
from fault_screen.monitor.stage import SampleBuffer


def samples(n=200, seed=3):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.1, 30.0, n))
    q = rng.uniform(0.0, 0.05, n)
    return t, q


def test_linear_rate_volume_is_the_closed_form():
    # q = a + b t on [2, 50]: V(t0, t1) = a (t1 - t0) + b (t1^2 - t0^2) / 2
    a, b = 1e-3, 2e-5
    t = np.linspace(2.0, 50.0, 17)
    vol = PiecewiseLinearVolume(t, a + b * t)
    for t0, t1 in ((2.0, 50.0), (3.3, 7.9), (10.0, 10.5), (-5.0, 2.5), (49.0, 80.0)):
        c0, c1 = np.clip([t0, t1], 2.0, 50.0)
        exact = a * (c1 - c0) + b * (c1 ** 2 - c0 ** 2) / 2
        assert vol.volume(t0, t1) == pytest.approx(exact, rel=1e-13, abs=1e-18)


def test_appended_samples_give_the_bits_of_the_whole_log():
    t, q = samples()
    whole = InjectionLog(t - t[0], q)
    grown = PiecewiseLinearVolume()
    for ti, qi in zip(t - t[0], q):
        grown.append(ti, qi)
    assert np.array_equal(grown.cumulative, whole._volume.cumulative)
    edges = np.sort(np.random.default_rng(4).uniform(-10, whole.duration + 10, 301))
    got = [grown.volume(a, b) for a, b in zip(edges[:-1], edges[1:])]
    want = [whole.volume(a, b) for a, b in zip(edges[:-1], edges[1:])]
    assert np.array_equal(got, want)


def test_the_monitors_buffer_keeps_absolute_volumes_after_dropping_samples():
    t, q = samples()
    t = t - t[0]
    whole = InjectionLog(t, q)
    buf = SampleBuffer()
    got = []
    for k in range(t.size):
        buf.append(t[k], q[k], None)
        if k > 3:
            got.append((buf.volume(t[k - 2], t[k]), whole.volume(t[k - 2], t[k])))
            buf.drop_before(t[k - 2])
    assert len(buf.t) <= 4
    assert all(a == b for a, b in got)
    restored = SampleBuffer.from_state(buf.state())
    assert restored.volume(t[-2], t[-1]) == whole.volume(t[-2], t[-1])
    assert restored.flow.cumulative[-1] == whole.total_volume

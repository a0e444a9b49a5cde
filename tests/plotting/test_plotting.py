"""Figures from a result: files written, readable PNGs, events, time units, zoom."""
from __future__ import annotations

import numpy as np
import pytest

from fault_screen import Scene
from fault_screen.io.events import EventCatalog
from fault_screen.plotting import (active_half_width, plot_injection_point, plot_result,
                                   plot_space_time, time_scale)
from fault_screen.result import Result

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def synthetic_result(t_end=1400.0, nt=60, nx=41, spread=20.0, with_log=True) -> Result:
    """A diffusion-like pressure pulse and a growing slip patch (no simulation needed)."""
    t = np.linspace(0.0, t_end, nt)
    x = np.linspace(-125.0, 125.0, nx)
    front = spread * np.sqrt(t / t_end)[:, None] + 1e-9
    dp = 1.5e5 * np.sqrt(t / t_end)[:, None] * np.exp(-(x[None, :] / (front + 1.0)) ** 2)
    slip = 2e-4 * (t / t_end)[:, None] * np.sign(x)[None, :] * np.exp(-(x[None, :] / 30.0) ** 2)
    opening = 4e-6 * dp / 1.5e5
    q = np.where(t < 0.9 * t_end, 1e-3 * np.ceil(5 * t / t_end) / 5, 0.0)
    fault = {"pressure": 2.764e6 + dp, "overpressure": dp, "slip": slip, "opening": opening,
             "slip_rate": np.gradient(slip, axis=0), "shear_traction": np.zeros_like(dp),
             "effective_normal_stress": np.zeros_like(dp), "friction": np.full_like(dp, 0.68),
             "contact_state": np.zeros(dp.shape, dtype=np.int64)}
    i0 = nx // 2
    injection = {"flow_rate": q, "overpressure": dp[:, i0], "pressure": 2.764e6 + dp[:, i0],
                 "slip": slip[:, i0 + 1], "opening": opening[:, i0],
                 "volume": np.concatenate(([0.0], np.cumsum(q[1:] * np.diff(t))))}
    extra = {"log": {"time": t, "flow_rate": q}} if with_log else {}
    return Result(scene=Scene(title="synthetic"), time=t, fault_x=x,
                  fault_xy=np.c_[x, np.zeros_like(x)], fault_weights=np.full(nx, x[1] - x[0]),
                  fault=fault, injection=injection, balance={}, solver={}, meta={}, extra=extra)


def is_png(path):
    data = path.read_bytes()
    return data[:8] == PNG_MAGIC and len(data) > 10_000


def test_plot_result_writes_both_pngs(tmp_path):
    paths = plot_result(synthetic_result(), tmp_path / "new" / "dir", prefix="syn-")
    assert [p.name for p in paths] == ["syn-injection-point.png", "syn-space-time.png"]
    assert all(is_png(p) for p in paths)
    assert not list((tmp_path / "new" / "dir").glob("*.part"))


def test_plots_with_events_inside_and_outside_the_run(tmp_path):
    ev = EventCatalog(np.array([-50.0, 100.0, 700.0, 1300.0, 5000.0]),
                      np.array([0.1, -1.0, np.nan, 0.4, 1.0]), ("Mw",) * 5)
    r = synthetic_result()
    assert is_png(plot_injection_point(r, tmp_path / "a.png", ev))
    assert is_png(plot_space_time(r, tmp_path / "b.png", ev))
    # events without any magnitude: no magnitude panel, still drawn
    ev = EventCatalog(np.array([100.0, 200.0]), np.array([np.nan, np.nan]))
    assert is_png(plot_injection_point(r, tmp_path / "c.png", ev))
    # an empty catalogue is fine
    assert is_png(plot_injection_point(r, tmp_path / "d.png", EventCatalog(np.zeros(0), np.zeros(0))))


def test_long_runs_use_hours_and_a_result_without_log(tmp_path):
    r = synthetic_result(t_end=3 * 86400.0, with_log=False)
    assert is_png(plot_injection_point(r, tmp_path / "a.png"))
    assert is_png(plot_space_time(r, tmp_path / "b.png", xlim=(-50.0, 50.0)))


@pytest.mark.parametrize("t_end, unit", [(60.0, "s"), (3600.0, "s"), (7200.0, "min"),
                                         (86400.0, "h"), (30 * 86400.0, "d")])
def test_time_scale(t_end, unit):
    f, u = time_scale(t_end)
    assert u == unit and 1.0 <= t_end * f <= 3600.0


def test_active_half_width_zooms_on_the_pulse_only():
    r = synthetic_result(spread=5.0)
    r.fault["slip"][:] = 1e-20          # numerical noise does not count
    lim = active_half_width(r)
    assert lim is not None and 5.0 < lim < 60.0
    r = synthetic_result(spread=200.0)   # activity along the whole fault: no zoom
    assert active_half_width(r) is None



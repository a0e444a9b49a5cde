"""What the figures show, read from the drawn artists: every threshold inside its axis, values
below a floor drawn as "below" (not at the floor), the level band in the legend and on an axis
of its own, labels that never overprint, and space-time maps that leave noise uncoloured."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

import fault_screen.plotting.injection_point as injection_point
import fault_screen.plotting.screening as screening_fig
import fault_screen.plotting.space_time as space_time
from fault_screen.screening import TRANSITION_DTYPE


def drawn(module, monkeypatch):
    """The figures ``module`` would save, kept instead (no file written)."""
    figs = []
    monkeypatch.setattr(module, "_save", lambda fig, path: figs.append(fig) or Path(path))
    return figs


def by_ylabel(fig):
    return {ax.get_ylabel(): ax for ax in fig.axes}


@pytest.fixture(scope="module")
def si_run(bundled_run):
    return bundled_run("rustrel-2015-calibrated")


def test_every_threshold_is_inside_its_axis_and_rest_is_drawn_below_the_floor(si_run,
                                                                             monkeypatch):
    """SI Rustrel scene: the slip rate stays at rest (stored values far below 1e-12 m/s) and the
    thresholds are 1e-6 and 1e-3 m/s, utilisation 0.9: each lies within its axis' limits; the
    slip-rate line has no point at the floor (the values below it are gaps, shown by the grey
    'below 1e-12 m/s: at rest' band in the legend)."""
    figs = drawn(screening_fig, monkeypatch)
    screening_fig.plot_screening(si_run, "s.png")
    (fig,) = figs
    axes = by_ylabel(fig)
    rate_ax = axes["peak slip rate (m/s)"]
    lo, hi = rate_ax.get_ylim()
    for value in (1e-6, 1e-3, 1e-12):
        assert lo < value < hi, (value, lo, hi)
    util = axes["max |tau| / (mu0 sigma'n) (-)"]
    assert util.get_ylim()[0] < 0.9 < util.get_ylim()[1]
    assert util.get_ylim()[0] < 1.0 < util.get_ylim()[1]

    stored = np.asarray(si_run.extra["screening"]["peak_slip_rate"])
    (line,) = [ln for ln in rate_ax.get_lines() if ln.get_label() == "peak slip rate"]
    y = np.asarray(line.get_ydata(), dtype=float)
    assert np.count_nonzero(np.isnan(y)) == np.count_nonzero(stored < 1e-12) > 0
    assert np.all(y[np.isfinite(y)] >= 1e-12)       # nothing flat at the clip floor
    labels = rate_ax.get_legend_handles_labels()[1]
    assert "below 1e-12 m/s: at rest" in labels
    # the band: its own axis, its level in the figure legend
    legend_labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert legend_labels == ["screening level green"]


def test_many_level_changes_never_overprint(si_run, monkeypatch):
    """40 level changes 35 s apart on a 1400 s axis: each label placed lies in the band axis'
    width and no two placed labels overlap; the ones left out are counted on the figure."""
    result = copy.copy(si_run)
    sc = dict(si_run.extra["screening"])
    t = np.asarray(si_run.time, dtype=float)
    when = np.arange(1, 41) * 35.0
    level = np.zeros(t.size, dtype=np.int8)
    tr = np.zeros(when.size, dtype=TRANSITION_DTYPE)
    for i, w in enumerate(when):
        level[t >= w] = (i + 1) % 2
        tr[i] = (w, i % 2, (i + 1) % 2, "near failure" if i % 2 == 0 else "back below")
    sc["level"], sc["transitions"] = level, tr
    result.extra = {**si_run.extra, "screening": sc}
    figs = drawn(screening_fig, monkeypatch)
    screening_fig.plot_screening(result, "s.png")
    (fig,) = figs
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    band = fig.axes[-1] if fig.axes[-1].get_ylabel() == "level" else by_ylabel(fig)["level"]
    right = band.get_window_extent(renderer).x1
    texts = [tx for tx in band.texts if tx.get_text().startswith(" ")]
    boxes = [tx.get_window_extent(renderer) for tx in texts]
    assert 2 <= len(boxes) < 40
    for i, a in enumerate(boxes):
        assert a.x1 <= right + 0.5
        for b in boxes[i + 1:]:
            assert not a.overlaps(b), (a, b)
    assert band.get_xlabel() == (f"time (s); {40 - len(boxes)} level changes not labelled "
                                 f"('fault-screen screen' lists them all)")


def test_injection_point_band_has_its_own_axis_and_a_legend_entry(si_run, monkeypatch):
    """The traffic light hides no data: no patch on the data axes, a thin 'level' axis below,
    and 'screening level green' in the figure legend."""
    figs = drawn(injection_point, monkeypatch)
    injection_point.plot_injection_point(si_run, "i.png")
    (fig,) = figs
    axes = by_ylabel(fig)
    assert "level" in axes and len(axes["level"].patches) >= 1
    for label in ("overpressure at injection point (MPa)", "slip, opening at injection point (mm)"):
        assert not axes[label].patches
    legend_labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert "screening level green" in legend_labels


def test_space_time_maps_leave_noise_uncoloured(si_run, monkeypatch):
    """SI scene: no point slides and the largest |slip| is ~1.5e-7 mm of penalty give, far below
    the 1 um floor: the slip map colours no cell (all masked) and says so; overpressure cells
    below 1 kPa are masked and the rest coloured; each colour bar names its floor."""
    figs = drawn(space_time, monkeypatch)
    space_time.plot_space_time(si_run, "st.png")
    (fig,) = figs
    maps = {ax.get_title(loc="left"): ax.collections[0] for ax in fig.axes
            if ax.collections and ax.get_title(loc="left")}
    slip = maps["slip"].get_array()
    assert np.ma.count(slip) == 0
    dp = np.asarray(si_run.fault["overpressure"], dtype=float)
    over = maps["fault overpressure"].get_array()
    assert np.ma.count(over) == np.count_nonzero(np.abs(dp) >= 1e3) > 0
    assert np.ma.min(np.abs(over)) >= 1e-3               # MPa: nothing within 1 kPa of 0 coloured
    bars = [ax.get_ylabel() for ax in fig.axes if "grey:" in ax.get_ylabel()]
    assert sorted(bars) == ["fault overpressure (MPa); grey: |overpressure| < 0.001 MPa",
                            "opening (mm); grey: |opening| < 0.001 mm",
                            "slip (mm); grey: |slip| < 0.001 mm"]

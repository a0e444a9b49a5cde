"""An ensemble member's run records lean (``Simulation(recording="lean")``, the newest row only,
what the screening and the look-aheads read; forecast.ensemble.MEMBER_RECORDING): its forecasts
must equal those of a full recording bit for bit, every array, and every column of forecast.csv
must still be filled.

Scenes: the impermeable Rustrel scene made at 300 s, 100 s ahead on the scene's own steps (it
turns yellow at 390 s, so the screening's level changes within the look-ahead), and the SI
calibrated scene (rock pore pressure) on a 20 x 21 mesh, 60 s of history then 60 s ahead on a
step ladder to 40 s (steps of 5, 10, 20, 20 and 5 s), with draws of the friction and the
aperture."""
import dataclasses

import numpy as np
import pytest

from conftest import CONFIGS
from fault_screen import Scene
from fault_screen.ensemble import scene_with
from fault_screen.forecast import COLUMNS, parse_plan
from fault_screen.forecast import ensemble as forecast_ensemble
from fault_screen.forecast.ensemble import LiveEnsemble, lookaheads
from fault_screen.screening.metrics import FAULT_FIELDS
from fault_screen.stepper import Simulation

IMPERMEABLE = CONFIGS / "rustrel-2015-impermeable.toml"
PLANS = [parse_plan(p) for p in ("scene", "hold", "stop")]
DRAWS = [{}, {"fault.friction": 0.62}, {"fault.hydraulic_aperture": 2.0e-5}]


@pytest.fixture(scope="module")
def small_si():
    s = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    return s.replace(mesh=dataclasses.replace(s.mesh, nx=20, ny=21),
                     time=dataclasses.replace(s.time, end=120.0))


def _forecasts(scene, at, horizon, steps=None):
    return [next(lookaheads(scene, [at], steps=steps)).run(plan, horizon) for plan in PLANS]


def _both(monkeypatch, make):
    """``make()`` with the members' recording full, then lean (the default)."""
    assert forecast_ensemble.MEMBER_RECORDING == "lean"
    with monkeypatch.context() as m:
        m.setattr(forecast_ensemble, "MEMBER_RECORDING", "full")
        full = make()
    return full, make()


def _assert_equal(full, lean):
    assert len(full) == len(lean) > 0
    for a, b in zip(full, lean):
        ra, rb = a.row(), b.row()
        ra.pop("wall_s"), rb.pop("wall_s")
        assert ra == rb
        assert np.array_equal(a.time, b.time) and np.array_equal(a.level, b.level)
        assert a.metrics.keys() == b.metrics.keys() and len(a.metrics) >= 8
        for k in a.metrics:
            assert np.array_equal(a.metrics[k], b.metrics[k], equal_nan=True), k
        assert a.iterations == b.iterations > 0


def test_lean_forecasts_equal_full_ones_where_the_level_changes(monkeypatch):
    scene = Scene.from_toml(IMPERMEABLE)
    full, lean = _both(monkeypatch, lambda: _forecasts(scene, 300.0, 100.0))
    _assert_equal(full, lean)
    # the scene turns yellow at 390 s: 90 s after 300 s, under its own schedule
    assert lean[0].time_to_yellow == 90.0 and lean[0].level_now == 0
    # every column of forecast.csv but the advice (not asked) is filled
    assert [c for c in COLUMNS if lean[0].row()[c] is None] == ["time_to_red", "advised_rate"]


@pytest.mark.parametrize("draw", DRAWS, ids=["scene", "friction", "aperture"])
def test_lean_members_on_a_ladder_equal_full_ones(monkeypatch, small_si, draw):
    scene = scene_with(small_si, draw)
    full, lean = _both(monkeypatch, lambda: _forecasts(scene, 60.0, 60.0, steps={"ladder": 40.0}))
    _assert_equal(full, lean)
    # 60 s on the ladder from the history's 5-s step, doubling, ending on the horizon
    assert np.array_equal(np.diff(lean[1].time), [5.0, 10.0, 20.0, 20.0, 5.0])


def test_a_lean_live_ensemble_equals_a_full_one(monkeypatch, small_si):
    def make():
        live = LiveEnsemble(small_si, DRAWS[1:])
        live.advance(60.0, align=True)
        made, _ = live.run(PLANS[1:], 60.0)
        return [f for m in made for f in m.forecasts] + [f for m in made for f in [m.base]]

    full, lean = _both(monkeypatch, make)
    assert len(lean) == 6
    for a, b in zip(full, lean):
        assert np.array_equal(a.time, b.time) and np.array_equal(a.level, b.level)
        assert a.metrics.keys() == b.metrics.keys()
        for k in a.metrics:
            assert np.array_equal(a.metrics[k], b.metrics[k], equal_nan=True), k


def test_a_lean_row_holds_what_the_screening_reads_as_the_full_row_does():
    scene = Scene.from_toml(IMPERMEABLE)
    full, lean = Simulation(scene), Simulation(scene, recording="lean")
    read = set(FAULT_FIELDS) | {"time", "inj_overpressure", "inj_slip", "iterations", "cuts", "dt"}
    for t in (5.0, 10.0, 400.0):
        full.advance(t)
        lean.advance(t)
        a, b = full.last_row, lean.last_row
        assert read <= b.keys() <= a.keys()
        for k in b.keys() - {"profile"}:
            assert np.array_equal(a[k], b[k]), k
    # the whole run in memory, one row in the lean one
    assert len(full.recorder.rows) == full.recorder.count == lean.recorder.count > 80
    assert len(lean.recorder.rows) == 1
    assert len(lean.fork().recorder.rows) == 1


def test_a_lean_run_refuses_a_result_a_stream_and_a_checkpoint(tmp_path):
    sim = Simulation(Scene.from_toml(IMPERMEABLE), recording="lean")
    sim.advance(5.0)
    with pytest.raises(RuntimeError, match="lean recording keeps the newest row only: no result"):
        sim.result()
    with pytest.raises(RuntimeError, match="no checkpoint"):
        sim.checkpoint(tmp_path / "c.h5")
    with pytest.raises(ValueError, match="recording 'thin': one of full, lean"):
        Simulation(Scene.from_toml(IMPERMEABLE), recording="thin")

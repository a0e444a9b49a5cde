"""Live advice that reuses the work of the refreshes before it: the bisection seeks its bracket
around the previous advice first (``advise(..., near=)``) and keeps the 2 % of a fresh bisection;
a monitor that looks ahead on a step ladder keeps one ladder for the whole run, so the
factorisations of its step sizes are made once."""
from __future__ import annotations

import pytest

import monitor_env
from fault_screen import Scene
from fault_screen.forecast import advise
from fault_screen.forecast.ensemble import lookaheads
from fault_screen.forecast.lookahead import StepLadder
from fault_screen.monitor import Stage
from fault_screen.monitor.lookahead import LiveLookAhead
from test_monitor_lookahead import live_run

HORIZON, EVERY = 300.0, 120.0
TOLERANCE = 0.02          # advise()'s default: the advised rate to 2 % of itself


@pytest.fixture(scope="module")
def advised(scene_file, log):
    """The impermeable scene followed live to 250 s with the advice at every refresh (120 and
    240 s), and fresh bisections made independently at the same times on the same log."""
    scene = Scene.from_toml(scene_file)
    la = LiveLookAhead(plans=["hold"], horizon=HORIZON, every=EVERY, advise=True)
    stage, _ = live_run(scene, log, lookahead=la, end=250.0)
    fresh = [advise(ahead, HORIZON) for ahead in lookaheads(scene, [EVERY, 2 * EVERY], drive=log,
                                                            start=log.start)]
    return stage, fresh


def test_a_reused_advice_equals_a_fresh_one_within_its_tolerance(advised):
    stage, (fresh_120, fresh_240) = advised
    rows = stage.lookahead.rows
    assert [r["made_at"] for r in rows] == [EVERY, 2 * EVERY]
    # the first refresh has nothing to reuse: the fresh bisection, bit for bit
    assert rows[0]["advised_rate"] == fresh_120.rate
    # the second looked around the first's rate: within 2 % of a fresh bisection from scratch
    live = rows[1]["advised_rate"]
    assert abs(live - fresh_240.rate) <= TOLERANCE * fresh_240.rate
    assert live != fresh_240.rate        # (another bracket, so not the same bits)
    forecaster = stage.lookahead.forecaster
    assert forecaster.last_advice.rate == live and forecaster.near == live


def test_the_reused_bisection_takes_fewer_look_aheads(advised, scene_file, log):
    """At 240 s the fresh bisection needs 10 look-aheads, the one started around the advice of
    120 s (15 % higher) 8; its rate is the live one."""
    stage, (fresh_120, fresh_240) = advised
    ahead = next(lookaheads(Scene.from_toml(scene_file), [2 * EVERY], drive=log, start=log.start))
    reused = advise(ahead, HORIZON, near=fresh_120.rate)
    assert (fresh_240.evaluations, reused.evaluations) == (10, 8)
    assert reused.rate == stage.lookahead.rows[1]["advised_rate"]
    assert stage.lookahead.forecaster.last_advice.evaluations == 8


def test_one_step_ladder_serves_every_refresh_of_the_run(tmp_path, log):
    """The calibrated scene (7-s steps, rock pore pressure: the bulk's factors depend on the step
    size) looked ahead on a ladder up to 28 s: its sizes 1 (the first step), 7, 14 and 28 s; the
    three the forks step on beyond the live step size are factorised at the first refresh and
    by no later one."""
    scene = Scene.from_toml(monitor_env.calibrated_scene_with_step(tmp_path, 7.0))
    la = LiveLookAhead(plans=["hold", "stop"], horizon=120.0, every=60.0, ladder=28.0)
    ladder = la.forecaster.ladder
    assert isinstance(ladder, StepLadder) and ladder.dt_max == 28.0
    counts = []
    stage = None
    for end in (70.0, 130.0, 190.0):
        stage, _ = live_run(scene, log, lookahead=la, stage=stage, end=end)
        counts.append(ladder.factorizations)
    assert stage.lookahead.made == 3 and la.forecaster.ladder is ladder
    assert counts == [3, 3, 3]
    assert sorted(ladder._systems) == [1.0, 7.0, 14.0, 28.0]


def test_the_ladder_setting_is_kept_in_the_checkpoint(scene_file, log, tmp_path):
    scene = Scene.from_toml(scene_file)
    la = LiveLookAhead(plans=["stop"], horizon=60.0, every=600.0, ladder=40.0)
    stage, _ = live_run(scene, log, lookahead=la, end=30.0)
    stage.checkpoint(tmp_path / "state.h5")
    restored, _ = Stage.restore(tmp_path / "state.h5", scene=scene)
    assert restored.lookahead.ladder == 40.0 and restored.lookahead.forecaster.ladder.dt_max == 40.0
    # a ladder serves the forks of one model: the restored one (its own discretisation) a new one
    assert restored.lookahead.forecaster.ladder is not stage.lookahead.forecaster.ladder


@pytest.mark.parametrize("value", [0.0, -5.0, float("inf"), float("nan")])
def test_a_bad_ladder_is_refused_with_its_value(value):
    with pytest.raises(ValueError, match="look-ahead ladder .*: must be > 0 s"):
        LiveLookAhead(plans=["hold"], ladder=value)


def test_only_an_advice_bracketed_on_both_sides_is_reused():
    """An advice of 0 (even shut-in reaches the level) or of the largest rate tried (nothing
    reached it: a higher bound next time, after a larger rate came in) starts the next
    bisection afresh; one bracketed on both sides is where the next looks first."""
    from fault_screen.forecast.advice import Advice
    from fault_screen.monitor.lookahead import LookAheadForecaster

    forecaster = LookAheadForecaster(advise=True)
    assert forecaster.near is None
    common = dict(made_at=60.0, horizon=300.0, level=1, control="rate", max_rate=4e-4, evaluations=8)
    for rate, upper, zero, near in ((3e-4, 3.05e-4, False, 3e-4), (4e-4, None, False, None),
                                    (0.0, 0.0, True, None)):
        forecaster.last_advice = Advice(rate=rate, upper=upper, even_zero_reaches=zero, **common)
        assert forecaster.near == near
    assert LookAheadForecaster(advise=True, reuse=False).near is None

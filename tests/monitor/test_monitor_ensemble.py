"""The ensemble look-ahead of the live monitor (``--vary PARAMS.toml --members N``): the members
step with the data in the look-ahead worker and their forecasts are those of the ensemble run
independently (``forecast.ensemble.run_member``, each draw's history from time 0 driven by the
log) at the same model times; the live model is not disturbed; a restart rebuilds the members
from the samples kept in the checkpoint and makes the same forecasts.

The draws vary the friction coefficient of the impermeable Rustrel scene (10 s steps, the
stand-in log fed sample by sample, a refresh every 180 s of model time, 300 s ahead under hold
and stop); with seed 3 the three draws are 0.632, 0.653 and 0.732: at 360 s one of the three
turns yellow within 300 s even after a shut-in (P(yellow) = 1/3 under stop)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import CONFIGS
from fault_screen import Result, Scene
from fault_screen.calibration import load_parameters, sample_parameters
from fault_screen.cli import main
from fault_screen.forecast import parse_plan
from fault_screen.forecast.ensemble import run_member, time_percentile
from fault_screen.monitor import Stage
from fault_screen.monitor.lookahead import (ENSEMBLE_LOOKAHEAD_COLUMNS, LiveLookAhead, chance,
                                            forecast_text)
from fault_screen.screening import RED, YELLOW
# the friction coefficient drawn uniformly in [0.62, 0.76] (the fixture friction_file)
from test_forecast_ensemble import friction_file  # noqa: F401
from test_monitor_lookahead import _arrays, live_run, log_written_up_to

MEMBERS, SEED = 3, 3
HORIZON, EVERY, END = 300.0, 180.0, 370.0
CHECKPOINT_AT = 250.0
PLANS = ("hold", "stop")


@pytest.fixture(scope="module")
def draws(friction_file):
    """The draws `--vary friction.toml --members 3 --distribution uniform --seed 3` makes."""
    return sample_parameters(load_parameters(friction_file), MEMBERS, "uniform", SEED)


def ensemble_lookahead(draws):
    return LiveLookAhead(plans=list(PLANS), horizon=HORIZON, every=EVERY, ensemble={"draws": draws})


@pytest.fixture(scope="module")
def shared(scene_file, log, draws, tmp_path_factory):
    """The live run with the ensemble look-ahead (every refresh waited for), its checkpoint
    after 250 s, and the independent runs of the three members to the forecast times."""
    scene = Scene.from_toml(scene_file)
    ckpt = tmp_path_factory.mktemp("ckpt") / "state.h5"
    stage, events = live_run(scene, log, lookahead=ensemble_lookahead(draws), checkpoint=ckpt, end=END)
    plans = [parse_plan(p) for p in PLANS]
    times = [EVERY, 2 * EVERY]
    runs = [run_member(i, scene.to_dict(), d, times, plans, HORIZON, drive=log, start=log.start)
            for i, d in enumerate(draws)]
    assert all(r.ok for r in runs), [r.error for r in runs]
    return scene, stage, events, ckpt, runs


def _independent(runs, k):
    """The forecasts of the k-th (time, plan) of every member run independently."""
    return [r.forecasts[k] for r in runs]


def test_lookahead_rows_are_the_ensemble_of_the_same_draws_at_the_same_time(shared):
    _, stage, _, _, runs = shared
    rows = stage.result().extra["lookahead"]
    assert list(rows) == list(ENSEMBLE_LOOKAHEAD_COLUMNS)
    assert list(rows["made_at"]) == [EVERY, EVERY, 2 * EVERY, 2 * EVERY]
    assert [p.decode() for p in rows["plan"]] == list(PLANS) * 2
    assert list(rows["members"]) == [MEMBERS] * 4
    fractions = []
    for k in range(rows["made_at"].size):
        member = _independent(runs, k)
        assert {f.made_at for f in member} == {rows["made_at"][k]} and member[0].plan == rows["plan"][k].decode()
        p_yellow = np.mean([f.max_level >= YELLOW for f in member])
        p_red = np.mean([f.max_level >= RED for f in member])
        assert rows["p_yellow"][k] == p_yellow and rows["p_red"][k] == p_red
        tty = [math.inf if f.time_to_yellow is None else f.time_to_yellow for f in member]
        for q in (10, 50, 90):
            want = time_percentile(np.array(tty), q)
            got = rows[f"time_to_yellow_p{q}"][k]
            assert (math.isnan(got) if want is None else got == want), (k, q, got, want)
        fractions.append(float(p_yellow))
    # the draws make the probabilities informative: all, none and one of the three
    assert fractions == [1.0, 0.0, 1.0, 1 / 3]


def test_the_deterministic_columns_are_the_live_models_own(shared):
    """Without the ensemble the same refreshes give the same deterministic columns (the live
    model's fork): the hold plan at 180 s turns yellow 220 s ahead (at 400 s)."""
    scene, stage, _, _, _ = shared
    rows = stage.result().extra["lookahead"]
    assert rows["time_to_yellow"][0] == 220.0 and math.isnan(rows["time_to_yellow"][1])
    assert [v.decode() for v in rows["max_level"]] == ["yellow", "green", "yellow", "green"]


def test_members_do_not_disturb_the_live_model(shared, log):
    scene, stage, _, _, _ = shared
    plain, _ = live_run(scene, log, end=END)
    a, b = _arrays(stage.result()), _arrays(plain.result())
    assert sorted(a) == sorted(b) and len(a) > 20
    for key in a:
        nan = np.asarray(a[key]).dtype.kind == "f"
        assert np.array_equal(a[key], b[key], equal_nan=nan), key


def test_the_forecast_alerts_carry_the_probabilities(shared):
    _, _, events, _, _ = shared
    alerts = [a for kind, a in events if kind == "forecast"]
    assert [a["model_time"] for a in alerts] == [EVERY, 2 * EVERY]
    assert alerts[0]["summary"] == [["yellow", "<15 min", ">=90 %"], ["green", "none", "0"]]
    assert alerts[1]["summary"][1] == ["green", "none", "10-50 %"]
    assert ("P(yellow within 5 min) = 1.00 under plan hold, 0.33 under plan stop (3 members)"
            in alerts[1]["text"])
    assert alerts[1]["forecasts"][1]["p_yellow"] == pytest.approx(1 / 3, rel=1e-15)


def test_a_restart_rebuilds_the_members_and_makes_the_same_forecasts(shared, log, draws):
    """The checkpoint after 250 s keeps every sample; the restored stage rebuilds the members
    from time 0 in the worker at its next refresh (360 s): the same rows, the same alert id."""
    scene, stage, events, ckpt, _ = shared
    restored, _ = Stage.restore(ckpt, scene=scene)
    resumed_at = restored.time
    assert resumed_at == CHECKPOINT_AT and restored.lookahead.ensemble["draws"] == draws
    assert restored.received.time[0] == 0.0 and restored.received.time[-1] == restored.last_sample_time
    _, again = live_run(scene, log, stage=restored, end=END)
    mine, ref = restored.result().extra["lookahead"], stage.result().extra["lookahead"]
    new, late = (np.flatnonzero(rows["made_at"] > resumed_at) for rows in (mine, ref))
    assert list(mine["made_at"][new]) == list(ref["made_at"][late]) == [2 * EVERY] * 2
    for c in ENSEMBLE_LOOKAHEAD_COLUMNS:
        if c not in ("wall_s", "made_at_utc"):
            nan = ref[c].dtype.kind == "f"
            assert np.array_equal(mine[c][new], ref[c][late], equal_nan=nan), c
    before = [a["id"] for kind, a in events if kind == "forecast" and a["model_time"] > CHECKPOINT_AT]
    assert [a["id"] for kind, a in again if kind == "forecast"] == before and len(before) == 1


def test_a_state_without_the_samples_cannot_rebuild_members(scene_file, log, draws, tmp_path):
    scene = Scene.from_toml(scene_file)
    stage = Stage(scene, start=log.start)
    stage.feed_samples(log.time[:3], log.flow_rate[:3])
    stage.checkpoint(tmp_path / "plain.h5")
    with pytest.raises(ValueError, match="without a look-ahead ensemble: its members cannot be rebuilt"):
        Stage.restore(tmp_path / "plain.h5", scene=scene, lookahead=ensemble_lookahead(draws))


def test_the_text_says_how_many_members_are_left():
    row = dict(made_at=600.0, plan="hold", horizon=3600.0, level_now="green",
               level_at_horizon="green", max_level="green", time_to_yellow=None, time_to_red=None,
               advised_rate=20e-3 / 60, p_yellow=0.25, p_red=0.0, members=4, members_set_aside=1)
    stop = dict(row, plan="stop", p_yellow=0.0)
    text = forecast_text([row, stop], None, confidence=0.9)
    assert text == ("forecast: stays green for 1 h under plan hold; plan stop stays green for 1 h; "
                    "P(yellow within 1 h) = 0.25 under plan hold, 0.00 under plan stop "
                    "(4 members, 1 set aside (failed)); "
                    "largest rate with P(yellow within 1 h) <= 10 %: 20 L/min")
    assert [chance(p) for p in (0.0, 0.05, 0.1, 0.49, 0.5, 0.9, 1.0, math.nan)] == \
        ["0", "<10 %", "10-50 %", "10-50 %", "50-90 %", ">=90 %", ">=90 %", "none"]


def test_monitor_command_runs_the_ensemble(scene_file, draws, friction_file, tmp_path, dist):
    """``fault-screen monitor --vary --members 3`` on the log written up to 450 s (read at once):
    the refresh at 180 s (the worker is idle then) is stored with the ensemble columns, equal to
    the ensemble run independently on the same draws."""
    live = log_written_up_to(tmp_path / "live.csv", "2015-03-12T10:07:30")
    r = CliRunner().invoke(main, ["monitor", str(scene_file), "--follow", str(live),
                                  "--idle-exit", "0.5", "--out", str(tmp_path / "live.h5"),
                                  "--plan", "hold", "--plan", "stop", "--horizon", "5min",
                                  "--lookahead-every", "3min", "--vary", str(friction_file),
                                  "--members", "3", "--distribution", "uniform", "--seed", str(SEED)])
    assert r.exit_code == 0, r.output
    rows = Result.load(tmp_path / "live.h5").extra["lookahead"]
    assert sorted(rows) == sorted(ENSEMBLE_LOOKAHEAD_COLUMNS)       # (the file's order: by name)
    first = np.flatnonzero(rows["made_at"] == EVERY)
    assert [rows["plan"][i].decode() for i in first] == list(PLANS)
    assert [rows["members"][i] for i in first] == [MEMBERS] * 2
    assert [rows["p_yellow"][i] for i in first] == [1.0, 0.0]       # as the stage's rows above


@pytest.mark.parametrize("args, message", [
    (["--members", "3"], "--members needs --vary"),
    (["--vary", "{vary}"], "--vary needs --members"),
    (["--vary", "{vary}", "--members", "0"], "--members 0: must be >= 1"),
    (["--vary", "{vary}", "--members", "2", "--confidence", "0.9"], "add --advise"),
    (["--confidence", "0.9"], "--confidence is for an ensemble"),
    (["--vary", "{vary}", "--members", "2", "--free", "rock.porosity"], "rock.porosity"),
    (["--ladder", "0"], "--ladder 0.0: must be a finite duration > 0"),
])
def test_monitor_checks_the_ensemble_options_as_forecast_does(args, message, friction_file, tmp_path):
    log = tmp_path / "live.csv"
    log.write_text("elapsed[s],flow_rate[L/min]\n0,10\n")
    args = [a.replace("{vary}", str(friction_file)) for a in args]
    r = CliRunner().invoke(main, ["monitor", str(CONFIGS / "rustrel-2015-impermeable.toml"),
                                  "--follow", str(log), "--idle-exit", "1", *args])
    assert r.exit_code == 2 and message in r.output, r.output


def test_the_live_ensemble_advice_is_that_of_the_members_own_bisections(scene_file, log, draws):
    """--advise --confidence 0.6 with three members: at the first refresh (180 s; no earlier
    advice to start from) the advised rate is the second smallest of the members' own advised
    rates (at most floor(0.4 * 3) = 1 member may reach yellow), each bisected as
    ``forecast --vary --advise`` bisects it, bit for bit."""
    scene = Scene.from_toml(scene_file)
    la = LiveLookAhead(plans=["hold"], horizon=120.0, every=EVERY, advise=True,
                       ensemble={"draws": draws, "confidence": 0.6})
    stage, _ = live_run(scene, log, lookahead=la, end=EVERY)
    runs = [run_member(i, scene.to_dict(), d, [EVERY], [parse_plan("hold")], 120.0, drive=log,
                       start=log.start, advice=dict(level=YELLOW, max_rate=None))
            for i, d in enumerate(draws)]
    own = sorted(r.advice[0].rate for r in runs)
    assert own[0] < own[1] < own[2]
    (row,) = la.rows
    assert row["advised_rate"] == own[1]
    assert forecast_text([row], None, confidence=0.6).endswith(
        f"largest rate with P(yellow within 2 min) <= 40 %: {own[1] * 60e3:.3g} L/min")

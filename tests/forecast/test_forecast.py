"""Forecasts (issue 29): plans, look-aheads on forks, advice.

Rustrel impermeable (the bundled scene) first reaches yellow at 390 s ("near failure"); the
forecasts below are made at 300 s, on a step of its 5 s sequence."""
import dataclasses
import json
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import fault_screen
from conftest import CONFIGS, VERIFICATION
from fault_screen import Scene, Simulation
from fault_screen.screening.stepwise import StepScreening
from fault_screen.forecast import LookAhead, Plan, PlanError, StepLadder, advise, parse_duration, parse_plan
from fault_screen.forecast.lookahead import screening_of
from fault_screen.screening import GREEN, YELLOW

IMPERMEABLE = "rustrel-2015-impermeable"
NOW = 300.0


def run_to(scene, t, volume=None):
    """A run advanced to ``t`` on its step sequence, screened at every row."""
    sim = Simulation(scene)
    fp = sim.disc.fault_points
    screening = StepScreening.for_scene(scene, fp.s - sim.disc.injection.s, fp.weight)
    screening.screen_simulation(sim)
    while sim.advance(t, volume=volume, align=True, max_steps=1):
        screening.screen_simulation(sim)
    return sim, screening


@pytest.fixture(scope="module")
def rustrel_run():
    """The run at 300 s and its screening (left untouched by every look-ahead)."""
    return run_to(Scene.from_toml(CONFIGS / f"{IMPERMEABLE}.toml"), NOW)


@pytest.fixture(scope="module")
def rustrel_now(rustrel_run):
    return LookAhead(*rustrel_run)


# ---- plans ----------------------------------------------------------------------------------
@pytest.mark.parametrize("text, kind, value", [
    ("rate:30 L/min", "rate", 30e-3 / 60), ("rate: 1.8 m3/h", "rate", 1.8 / 3600),
    ("RATE:2 bbl/min", "rate", 2 * 0.158987294928 / 60), ("pressure:4 MPa", "pressure", 4e6),
    ("scale:1.2", "scale", 1.2), (" hold ", "hold", None), ("stop", "stop", None), ("scene", "scene", None)])
def test_plans_are_read_in_si(text, kind, value):
    plan = parse_plan(text)
    assert plan.kind == kind
    if value is None:
        assert plan.value is None
    else:
        assert plan.value == pytest.approx(value, rel=1e-12)


@pytest.mark.parametrize("text, message", [
    ("rate:30", "give the unit"), ("rate:30 MPa", "not a flow_rate unit"), ("hurry", "unknown plan"),
    ("scale:fast", "not a number"), ("rate:-3 L/min", ">= 0"), ("scale:inf", "finite")])
def test_bad_plans_say_what_is_wrong(text, message):
    with pytest.raises(PlanError, match=message):
        parse_plan(text)


@pytest.mark.parametrize("text, seconds", [("90", 90.0), ("2h", 7200.0), ("30 min", 1800.0),
                                           ("1.5 day", 129600.0), (45, 45.0)])
def test_durations_take_seconds_or_units(text, seconds):
    assert parse_duration(text) == seconds


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=40))
def test_any_text_is_a_plan_or_a_plan_error(text):
    try:
        plan = parse_plan(text)
    except PlanError as exc:
        assert str(exc)
    else:
        assert plan.kind in ("scene", "hold", "stop", "rate", "pressure", "scale", "log")
        assert plan.value is None or (math.isfinite(plan.value) and plan.value >= 0)


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.text(max_size=30), st.floats(allow_nan=True, allow_infinity=True)))
def test_any_duration_is_seconds_or_a_plan_error(text):
    try:
        seconds = parse_duration(text, "--horizon")
    except PlanError as exc:
        assert "--horizon" in str(exc)
    else:
        assert math.isfinite(seconds) and seconds >= 0


# ---- look-ahead -----------------------------------------------------------------------------
def test_the_scene_plan_reproduces_the_uninterrupted_run(bundled_run, rustrel_now):
    """Made at 300 s, the plan ``scene`` reaches yellow when the whole run does (390 s), and its
    metrics and levels are the whole run's rows from 300 s on, exactly (the same steps)."""
    reference = bundled_run(IMPERMEABLE)
    sc = reference.extra["screening"]
    t_first_yellow = float(reference.time[np.argmax(sc["level"] >= YELLOW)])
    assert t_first_yellow == 390.0
    f = rustrel_now.run(parse_plan("scene"), 150.0)
    assert f.made_at == NOW and f.level_now == GREEN
    assert f.time_to_yellow == t_first_yellow - NOW
    assert f.time_to_red is None
    i0 = int(np.searchsorted(reference.time, NOW))
    rows = slice(i0, i0 + len(f.time))
    assert np.array_equal(f.time, reference.time[rows]) and f.time[-1] == NOW + 150.0
    assert np.array_equal(f.level, sc["level"][rows])
    for name in ("peak_slip_rate", "max_utilisation", "min_coulomb_margin", "delta_cff",
                 "injection_overpressure", "induced_slip"):
        assert np.array_equal(f.metrics[name], sc[name][rows]), name
    assert f.induced_slip_at_horizon == sc["induced_slip"][rows][-1]
    # the Newton iterations of its steps: the whole run's over the same steps (rows after now)
    ahead = slice(i0 + 1, i0 + len(f.time))
    assert f.iterations == int(np.sum(reference.solver["iterations"][ahead])) > len(f.time) - 1


def test_stop_never_gives_a_higher_injection_pressure_than_hold(rustrel_now):
    hold = rustrel_now.run(parse_plan("hold"), 150.0)
    stop = rustrel_now.run(parse_plan("stop"), 150.0)
    assert np.array_equal(hold.time, stop.time)
    p_hold, p_stop = hold.metrics["injection_overpressure"], stop.metrics["injection_overpressure"]
    assert p_hold[0] == p_stop[0]                       # the same "now"
    assert np.all(p_stop <= p_hold)
    # impermeable rock: shut in, the fault keeps its fluid (pressure falls only as the fault
    # spreads it); held at 22 L/min, the pressure keeps rising (by more than 0.1 MPa in 150 s)
    assert p_hold[-1] - p_stop[-1] > 1e5
    assert stop.max_level == GREEN and hold.time_to_yellow == 90.0


def test_a_log_file_plan_counts_from_now(rustrel_now, tmp_path):
    """A log with an elapsed column, ramping from 0 to 30 L/min over its first minute: its
    forecast is that of the same rate given as a function of the time since now (to the
    rounding of the log's integral). Counted from model time 0 instead, the rate would be
    30 L/min throughout."""
    log = tmp_path / "plan.csv"
    log.write_text("elapsed[s],flow_rate[L/min]\n0,0\n60,30\n600,30\n")
    f = rustrel_now.run(parse_plan(str(log)), 120.0)
    q = 30e-3 / 60

    def injected(tau):          # m3 from now to tau s after now
        return q * tau ** 2 / 120 if tau <= 60 else q * 30 + q * (tau - 60)

    ref = rustrel_now.state.fork()
    ref.advance(NOW + 120.0, volume=lambda t0, t1: injected(t1 - NOW) - injected(t0 - NOW))
    assert f.metrics["injection_overpressure"][-1] == pytest.approx(ref.last_row["inj_overpressure"], rel=1e-9)
    assert f.time[-1] == ref.time == NOW + 120.0
    full = rustrel_now.run(parse_plan("rate:30 L/min"), 120.0)
    assert full.metrics["injection_overpressure"][-1] - f.metrics["injection_overpressure"][-1] > 1e4


def test_a_log_drive_equal_to_the_schedule_gives_its_forecasts(rustrel_now):
    """The run driven by a log of the scene's own steps: ``scene`` and ``hold`` (the log's rate at
    300 s, 22 L/min) forecast what the schedule does, to the rounding of the log's ramps."""
    from fault_screen.io.injection_log import InjectionLog

    scene = Scene.from_toml(CONFIGS / f"{IMPERMEABLE}.toml")
    times, rates = zip(*scene.injection.schedule)
    log = InjectionLog.from_steps(times, rates)
    ahead = LookAhead(*run_to(scene, NOW, volume=log.volume), drive=log)
    for name in ("scene", "hold"):
        by_log = ahead.run(parse_plan(name), 120.0)
        by_schedule = rustrel_now.run(parse_plan(name), 120.0)
        assert by_log.time_to_yellow == by_schedule.time_to_yellow == 90.0, name
        assert np.allclose(by_log.metrics["injection_overpressure"],
                           by_schedule.metrics["injection_overpressure"], rtol=1e-9, atol=0), name


def test_a_forecast_from_a_checkpoint_restored_in_another_process_is_the_same(rustrel_run, rustrel_now, tmp_path):
    before = rustrel_now.run(parse_plan("hold"), 60.0)
    path = rustrel_run[0].checkpoint(tmp_path / "state.h5")
    code = ("import json, sys; from fault_screen import Simulation; "
            "from fault_screen.forecast import LookAhead, parse_plan; "
            "from fault_screen.forecast.lookahead import screening_of; "
            "sim = Simulation.restore(sys.argv[1]); "
            "f = LookAhead(sim, screening_of(sim)).run(parse_plan('hold'), 60.0); "
            "print(json.dumps(dict(row=f.row(), time=f.time.tolist(), level=f.level.tolist(), "
            "metrics={k: v.tolist() for k, v in f.metrics.items()})))")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True)
    after = json.loads(out.stdout.strip().splitlines()[-1])
    row = before.row()
    for k in row:
        if k != "wall_s":
            assert after["row"][k] == row[k], k
    assert after["time"] == before.time.tolist() and after["level"] == before.level.tolist()
    for k, v in before.metrics.items():
        assert np.array_equal(np.array(after["metrics"][k], dtype=float), v, equal_nan=True), k


def test_rows_so_far_screened_again_give_the_live_screening_state(rustrel_run, rustrel_now):
    """``screening_of`` (used after a restore) gives the level and tracker of the live screening;
    a fork (its earlier rows are not its own) is refused."""
    sim, screening = rustrel_run
    again = screening_of(sim)
    assert again.screener.level == screening.screener.level
    assert again.tracker.induced_slip_signed == screening.tracker.induced_slip_signed
    assert again.tracker._cff0 == screening.tracker._cff0
    with pytest.raises(ValueError, match="not all in memory"):
        screening_of(rustrel_now.state)


# ---- advice ---------------------------------------------------------------------------------
def _rate_after(schedule_volume, t_now, rate):
    def volume(t0, t1):
        a, b = min(t0, t_now), min(t1, t_now)
        return schedule_volume(a, b) + rate * (max(t1, t_now) - max(t0, t_now))
    return volume


def test_advice_bracket_on_impermeable_rustrel(rustrel_now):
    """Replayed from t = 0 as whole runs (no fork): the advised rate stays green for the horizon,
    1.05 times it reaches yellow."""
    horizon = 120.0
    advice = advise(rustrel_now, horizon)
    assert not advice.even_zero_reaches and advice.upper is not None
    assert advice.upper - advice.rate <= 0.02 * advice.rate
    assert 0 < advice.rate < 22e-3 / 60          # below the rate that reaches yellow at 390 s
    # a rate's look-ahead that reaches yellow ends at its first yellow row
    reached = [f for f in advice.forecasts if f.reaches(YELLOW)]
    assert reached
    for f in reached:
        assert np.flatnonzero(f.level[1:] >= YELLOW).tolist() == [len(f.level) - 2]
        assert f.time[-1] - NOW == f.time_to_yellow < horizon and "reached yellow" in f.stopped
    # from a hint 10 % above (a live run's last advice) the same bracket in fewer look-aheads:
    # down 4 % (still reaching), down 8 % more (below), then bisection to 2 %
    again = advise(rustrel_now, horizon, near=1.1 * advice.rate)
    assert again.upper - again.rate <= 0.02 * again.rate
    assert again.rate < advice.upper and advice.rate < again.upper      # the brackets overlap
    assert again.evaluations < advice.evaluations
    scene = Scene.from_toml(CONFIGS / f"{IMPERMEABLE}.toml")
    scene = scene.replace(time=dataclasses.replace(scene.time, end=NOW + horizon))
    from fault_screen.schedule import StepSchedule

    base = StepSchedule(scene.injection.schedule).volume
    for factor, reaches in ((1.0, False), (1.05, True)):
        result = fault_screen.simulate(scene, injected_volume=_rate_after(base, NOW, factor * advice.rate))
        ahead = result.extra["screening"]["level"][result.time > NOW]
        assert (ahead.max() >= YELLOW) == reaches, factor


def fluid_driven_slip():
    s = Scene.from_toml(VERIFICATION / "fluid-driven-slip-T0.4-horizontal.toml")
    coarse = dataclasses.replace(s.mesh.refinement, size=4.0)
    return s.replace(mesh=dataclasses.replace(s.mesh, refinement=coarse),
                     time=dataclasses.replace(s.time, end=0.05))


def test_advice_bracket_on_fluid_driven_slip():
    """Pressure control: the largest constant overpressure that stays below yellow for 0.05 s from
    the in-situ state. The fault is at utilisation u0 = 0.8 with sigma'_n = 10 MPa (T = 0.4 at
    5 MPa): below sigma'_n (1 - u0 / 0.9) = 1.11 MPa no fault point can pass 0.9, so the advice
    is at least that; replayed as whole runs, it stays green and 1.05 times it reaches yellow."""
    scene = fluid_driven_slip()
    sim, screening = run_to(scene, 0.0)
    row = sim.last_row
    ahead = LookAhead(sim, screening)
    now = ahead.run(parse_plan("stop"), 0.002)
    u0 = now.metrics["max_utilisation"][0]
    sigma = float(np.max(row["effective_normal_stress"]))
    assert u0 == pytest.approx(0.8, rel=1e-9) and sigma == pytest.approx(10e6, rel=1e-9)
    advice = advise(ahead, 0.05)
    assert advice.control == "pressure" and advice.max_rate == 10e6   # twice the scene's 5 MPa
    assert advice.rate >= 0.98 * sigma * (1 - u0 / 0.9)
    assert advice.upper - advice.rate <= 0.02 * advice.rate
    for factor, reaches in ((1.0, False), (1.05, True)):
        p = factor * advice.rate
        run = scene.replace(injection=dataclasses.replace(scene.injection, schedule=((0.0, p),)))
        result = fault_screen.simulate(run)
        assert (result.extra["screening"]["level"].max() >= YELLOW) == reaches, factor


def test_even_shut_in_reaching_the_level_is_said():
    """At 400 s the fault has been near failure since 390 s (yellow). Shut in, its utilisation
    falls below 0.9 at once, but the rule "near failure" holds yellow for 10 min after it last
    held: even rate 0 keeps yellow over a 30 s horizon. The advice says so and advises 0 after
    one look-ahead."""
    scene = Scene.from_toml(CONFIGS / f"{IMPERMEABLE}.toml")
    ahead = LookAhead(*run_to(scene, 400.0))
    assert ahead.level_now == YELLOW
    advice = advise(ahead, 30.0)
    assert advice.even_zero_reaches and advice.rate == 0.0 and advice.evaluations == 1
    shut_in = advice.forecasts[0]
    assert shut_in.max_utilisation < 0.9 and shut_in.peak_slip_rate < 1e-6
    assert shut_in.time_to_yellow == 0.0 and shut_in.level_at_horizon == YELLOW
    assert "whatever the injection does" in advice.describe()


def test_a_constant_plan_is_named_in_si():
    assert Plan.constant(5e-4).name == "rate:0.0005 m3/s"
    assert Plan.constant(2e6, "pressure").name == "pressure:2e+06 Pa"


def test_longer_steps_grow_from_the_run_step_and_stay_within_a_step(rustrel_run):
    """growth 1.2 up to 60 s from the run's 5 s step: steps 5 * 1.2^k (the last shortened to end
    on the horizon); time to yellow within one of those steps of the exact 90 s."""
    sim, screening = rustrel_run
    f = LookAhead(sim, screening, growth=1.2, dt_max=60.0).run(parse_plan("hold"), 180.0)
    steps = np.diff(f.time)
    expected, t = [], 0.0
    while t < 180.0 * (1 - 1e-12):
        dt = min(5.0 * 1.2 ** len(expected), 60.0, 180.0 - t)
        expected.append(dt)
        t += dt
    assert np.allclose(steps, expected, rtol=1e-12)
    i = int(np.searchsorted(f.time - NOW, f.time_to_yellow))
    assert abs(f.time_to_yellow - 90.0) <= steps[i - 1]
    with pytest.raises(ValueError, match="growth"):
        LookAhead(sim, screening, growth=0.5)


def test_a_step_ladder_finds_yellow_within_its_step(rustrel_run):
    """Doubling from the run's 5 s step up to 40 s (5, 10, 20, 40, 40...): the plan hold reaches
    yellow within the step that holds the exact 90 s (a step ends at 75 s, the next at 115 s)."""
    sim, screening = rustrel_run
    f = LookAhead(sim, screening, ladder=StepLadder(40.0)).run(parse_plan("hold"), 180.0)
    steps = np.diff(f.time)
    assert np.array_equal(steps[:4], [5.0, 10.0, 20.0, 40.0]) and set(steps) <= {5.0, 10.0, 20.0, 40.0}
    assert f.time[-1] == NOW + 180.0
    assert 90.0 <= f.time_to_yellow <= 115.0
    with pytest.raises(ValueError, match="not both"):
        LookAhead(sim, screening, ladder=StepLadder(40.0), growth=1.2)

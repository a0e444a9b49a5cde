"""Screening: rule language, metrics, traffic light with hold, /screening/ in results, CLI verdict.

The reference numbers are computed here from the stored fields by the definitions of issue 11,
not by the screening code."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

import fault_screen
from fault_screen import Result, Scene, SceneError
from fault_screen.cli import main
from fault_screen.plotting import rule_thresholds, screening_figures
from fault_screen.rules import METRICS, RuleError, parse_condition
from fault_screen.scene import MonitorRule, MonitorSpec
from fault_screen.screening import (MetricsTracker, Screener, read_transitions, screen_result,
                                    stopped_unstable)

ROOT = Path(__file__).resolve().parents[2]
IMPERMEABLE = ROOT / "configs" / "rustrel-2015-impermeable.toml"
CALIBRATED = ROOT / "configs" / "rustrel-2015-calibrated.toml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


# ---- the rule language ----------------------------------------------------------------------
@pytest.mark.parametrize("text, values, expected", [
    ("peak_slip_rate > 1e-6", {"peak_slip_rate": 2e-6}, True),
    ("peak_slip_rate > 1E-6", {"peak_slip_rate": 1e-6}, False),
    ("peak_slip_rate >= .1e-5", {"peak_slip_rate": 1e-6}, True),
    ("delta_cff > -2.5e+5", {"delta_cff": -2e5}, True),
    ("delta_cff != -2e5", {"delta_cff": -2e5}, False),
    ("0.9 < max_utilisation", {"max_utilisation": 0.95}, True),
    # 'and' binds tighter than 'or'
    ("a > 1 or b > 1 and c > 1", {"a": 2, "b": 0, "c": 0}, True),
    ("(a > 1 or b > 1) and c > 1", {"a": 2, "b": 0, "c": 0}, False),
    ("not a > 1 and b > 1", {"a": 0, "b": 2}, True),
    ("not (a > 1 and b > 1)", {"a": 2, "b": 2}, False),
    ("not not a == 3", {"a": 3}, True),
    # a missing value (absent or NaN) makes its comparison unknown, whatever the operator, and
    # a rule holds only when its condition is true (three-valued logic)
    ("event_magnitude >= 1", {}, False),
    ("event_magnitude < 1", {"event_magnitude": math.nan}, False),
    ("event_magnitude != 1", {"event_magnitude": math.nan}, False),
    ("not event_magnitude >= 1", {}, False),
    ("not event_magnitude < 2", {"event_magnitude": math.nan}, False),
    ("not event_magnitude < 2", {"event_magnitude": 2.0}, True),
    ("a > 1 and not event_magnitude > 1", {"a": 2}, False),
    ("not (a > 1 and event_magnitude > 1)", {"a": 0}, True),
    ("a > 1 or event_magnitude > 1", {"a": 2}, True),
])
def test_conditions_evaluate_with_precedence_and_missing_values(text, values, expected):
    assert parse_condition(text).evaluate(values) is expected


@pytest.mark.parametrize("text, token, column", [
    ("peak_slip_rate >> 1e-6", ">", 17),
    ("peak_slip_rate > 1e-6 and", "<end>", 26),
    ("(max_utilisation > 0.9", "<end>", 23),
    ("max_utilisation > 0.9)", ")", 22),
    ("peak_slip_rate > 1um", "1um", 18),
    ("peak_slip_rate", "<end>", 15),
    ("__import__('os') > 1", "'os')", 12),
    ("max_utilisation > 0.9 ; x", ";", 23),
    ("0.1 < max_utilisation < 0.9", "<", 23),
    ("peak_slip_rate > - slip_rate_red", "slip_rate_red", 20),
    ("", "<end>", 1),
])
def test_bad_conditions_name_the_token_and_column(text, token, column):
    with pytest.raises(RuleError) as err:
        parse_condition(text, set(METRICS) | {"slip_rate_red", "__import__"})
    assert (err.value.token, err.value.column) == (token, column)
    assert f"column {column}" in str(err.value)


@pytest.mark.parametrize("rule, words", [
    ({"level": "red", "name": "mine", "when": "peak_slip_rate >> 1e-6"},
     ["monitor.rules[1] ('mine').when", "column 17", "'>'"]),
    ({"level": "red", "when": "peak_sliprate > 1e-6"},
     ["monitor.rules[1].when", "unknown name 'peak_sliprate'", "peak_slip_rate"]),
    ({"level": "red", "name": "x", "when": "event_magnitude >= magnitude_red and"},
     ["monitor.rules[1] ('x').when", "the end of the expression"]),
    ({"level": "orange", "name": "x", "when": "max_utilisation > 0.5"},
     ["monitor.rules[1] ('x').level", "'orange'", "'yellow' or 'red'"]),
    ({"level": "red", "name": "x", "when": "max_utilisation > 0.5", "hold": -1.0},
     ["monitor.rules[1] ('x').hold", "must be >= 0 s"]),
    ({"level": "red", "name": "first", "when": "max_utilisation > 0.5"},
     ["monitor.rules[1] ('first').name", "two rules have this name"]),
    ({"level": "red", "name": "n" * 65, "when": "max_utilisation > 0.5"},
     ["monitor.rules[1]", ".name", "1 to 64 bytes"]),
])
def test_bad_rules_are_refused_at_scene_load_naming_rule_and_token(rule, words):
    ok = {"level": "yellow", "name": "first", "when": "max_utilisation > utilisation_yellow"}
    with pytest.raises(SceneError) as err:
        Scene.from_dict({"monitor": {"rules": [ok, rule]}})
    for w in words:
        assert w in str(err.value)


def test_monitor_table_units_round_trip_and_defaults():
    s = Scene.from_dict({"monitor": {"utilisation_yellow": 0.8, "rules": [
        {"level": "yellow", "when": "max_utilisation > utilisation_yellow", "hold": "10 min",
         "action": "reduce rate"}]}})
    assert s.monitor.rules[0].hold == 600.0 and s.monitor.utilisation_yellow == 0.8
    import tomllib

    assert Scene.from_dict(tomllib.loads(s.to_toml())) == s
    d = MonitorSpec()
    assert (d.slip_rate_yellow, d.slip_rate_red, d.utilisation_yellow, d.magnitude_yellow,
            d.magnitude_red) == (1e-6, 1e-3, 0.9, 2.0, 2.9)
    # the defaults' thresholds, as drawn on the screening figure: (metric, value, level)
    assert [t[:3] for t in rule_thresholds(d)] == [
        ("peak_slip_rate", 1e-3, 2), ("event_magnitude", 2.9, 2), ("peak_slip_rate", 1e-6, 1),
        ("max_utilisation", 0.9, 1), ("event_magnitude", 2.0, 1)]


# ---- metrics on hand-made fields -------------------------------------------------------------
def test_metrics_of_one_row_by_hand():
    mu0 = 0.6
    x = np.array([-2.0, -1.0, 0.1, 1.0, 2.0])
    w = np.array([1.0, 1.0, 0.5, 1.0, 1.0])
    row = {"slip_rate": np.array([0.0, -3e-6, 1e-6, 0.0, 0.0]),
           "contact_state": np.array([0, 1, 1, 2, 0]),
           "shear_traction": np.array([0.3e6, -0.6e6, 0.6e6, 0.0, 0.1e6]),
           "effective_normal_stress": np.array([1e6, 1e6, 1e6, 0.0, 2e6])}
    tr = MetricsTracker(x, w, mu0)
    inj0 = {"shear_traction": 0.2e6, "effective_normal_stress": 1e6, "slip": 0.0, "overpressure": 0.0}
    m0 = tr.update({**row, "contact_state": np.zeros(5, int), "slip_rate": np.zeros(5)}, inj0)
    assert math.isnan(m0["x_peak_slip_rate"]) and m0["induced_slip"] == 0.0
    m = tr.update(row, {"shear_traction": 0.6e6, "effective_normal_stress": 1e6, "slip": 2e-5,
                        "overpressure": 3e5})
    assert m["peak_slip_rate"] == 3e-6 and m["x_peak_slip_rate"] == -1.0
    assert m["slipping_length"] == 1.5                     # weights of the two sliding points
    assert m["max_utilisation"] == 1.0                     # sliding and the open point
    assert m["min_coulomb_margin"] == pytest.approx(0.0, abs=1e-9)
    # delta CFF = (0.6 - 0.6*1) - (0.2 - 0.6*1) MPa = 0.4 MPa
    assert m["delta_cff"] == pytest.approx(0.4e6, rel=1e-12)
    assert m["induced_slip"] == 2e-5 and m["injection_overpressure"] == 3e5
    # locked again: the slip increment is elastic, not induced; the earlier slip stays
    m = tr.update({**row, "contact_state": np.zeros(5, int)},
                  {"shear_traction": 0.5e6, "effective_normal_stress": 1e6, "slip": 2.5e-5,
                   "overpressure": 3e5})
    assert m["induced_slip"] == 2e-5
    assert m["max_utilisation"] == pytest.approx(0.6e6 / 0.6e6)
    assert m["slipping_length"] == 0.0


# ---- the traffic light -----------------------------------------------------------------------
def spec(*rules, **thresholds):
    return MonitorSpec(rules=tuple(MonitorRule(**r) for r in rules), **thresholds)


def stream(sc, times, series, events_at=None):
    levels = []
    for i, t in enumerate(times):
        metrics = {k: v[i] for k, v in series.items()}
        sc.update(t, metrics, events=(events_at or {}).get(t))
        levels.append(sc.level)
    return levels


def test_hold_keeps_a_level_and_a_new_crossing_extends_it():
    times = np.arange(0.0, 130.0, 10.0)
    util = [0.5, 0.95, 0.5, 0.5, 0.5, 0.5, 0.95, 0.5, 0.5, 0.96, 0.5, 0.5, 0.5]
    rule = dict(level="yellow", name="near failure", when="max_utilisation > 0.9", action="slow")
    flicker = stream(Screener(spec({**rule, "hold": 0.0})), times, {"max_utilisation": util})
    assert flicker == [0, 1, 0, 0, 0, 0, 1, 0, 0, 1, 0, 0, 0]
    sc = Screener(spec({**rule, "hold": 25.0}))
    held = stream(sc, times, {"max_utilisation": util})
    # true at 10 -> in force while t - 10 < 25, i.e. up to 30; at 60 -> up to 80, renewed at 90 -> 110
    assert held == [0, 1, 1, 1, 0, 0, 1, 1, 1, 1, 1, 1, 0]
    assert [(t.time, t.from_level, t.to_level, t.rule) for t in sc.transitions] == [
        (10.0, 0, 1, "near failure"), (40.0, 1, 0, "near failure"),
        (60.0, 0, 1, "near failure"), (120.0, 1, 0, "near failure")]
    assert sc.verdict.level == 1 and sc.verdict.time == 10.0 and sc.verdict.action == "slow"
    assert sc.verdict.metrics["max_utilisation"] == 0.95 and sc.verdict.final_level == 0


def test_red_released_falls_back_to_a_yellow_still_in_force():
    s = spec(dict(level="red", name="fast", when="peak_slip_rate > slip_rate_red", hold=15.0),
             dict(level="yellow", name="sliding", when="peak_slip_rate > slip_rate_yellow", hold=100.0))
    sc = Screener(s)
    times = np.arange(0.0, 60.0, 10.0)
    rates = [0.0, 2e-6, 5e-3, 2e-6, 0.0, 0.0]
    assert stream(sc, times, {"peak_slip_rate": rates}) == [0, 1, 2, 2, 1, 1]
    assert [(t.time, t.from_level, t.to_level, t.rule) for t in sc.transitions] == [
        (10.0, 0, 1, "sliding"), (20.0, 1, 2, "fast"), (40.0, 2, 1, "fast")]
    assert (sc.verdict.level, sc.verdict.time, sc.verdict.rule) == (2, 20.0, "fast")


def test_event_rules_hold_event_by_event_and_missing_distances_are_false():
    s = spec(dict(level="red", name="near event", when="event_magnitude >= 1.0 and event_distance < 500",
                  hold=0.0),
             dict(level="yellow", name="swarm", when="event_rate >= 3", hold=0.0),
             event_rate_window=1800.0)
    sc = Screener(s)
    times = [0.0, 100.0, 200.0, 300.0, 400.0]
    events = {
        # before the first update: background, ignored by the magnitude rule
        0.0: {"time": [-50.0], "magnitude": [3.0], "distance": [10.0]},
        # one strong but far, one near but small: no single event satisfies the rule
        100.0: {"time": [60.0, 90.0], "magnitude": [2.0, 0.5], "distance": [1000.0, 100.0]},
        # strong, near but without a distance: its comparison is false
        200.0: {"time": [150.0], "magnitude": [2.0], "distance": [math.nan]},
        300.0: {"time": [250.0], "magnitude": [1.5], "distance": [300.0]},
    }
    levels = stream(sc, times, {"max_utilisation": [0.0] * 5}, events)
    # event_rate (per hour over 1800 s): 1, 3, 4, 5, 5 events known -> 2, 6, 8, 10, 10 /h
    assert levels == [0, 1, 1, 2, 1]
    assert [(t.time, t.to_level, t.rule) for t in sc.transitions] == [
        (100.0, 1, "swarm"), (300.0, 2, "near event"), (400.0, 1, "near event")]
    assert sc.transitions[0].metrics["event_rate"] == 6.0
    assert sc.transitions[1].metrics["event_magnitude"] == 1.5


# ---- runs --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def impermeable(tmp_path_factory):
    """The bundled impermeable scene up to 430 s (its utilisation reaches 0.9 at 390 s and the
    fault starts sliding at 410 s), run once through the public API, and saved."""
    s = Scene.from_toml(IMPERMEABLE)
    s = s.replace(time=dataclasses.replace(s.time, end=430.0))
    result = fault_screen.simulate(s)
    path = tmp_path_factory.mktemp("screening") / "impermeable.h5"
    result.save(path)
    return result, path


def utilisation_from_fields(result):
    f = result.fault
    mu0 = result.scene.fault.friction
    sn = f["effective_normal_stress"]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.abs(f["shear_traction"]) / (mu0 * sn)
    u[(f["contact_state"] == 2) | (sn <= 0)] = 1.0
    return u.max(axis=1)


def test_impermeable_scene_turns_yellow_when_its_utilisation_reaches_the_threshold(impermeable):
    result, path = impermeable
    stored = Result.load(path)
    util = utilisation_from_fields(stored)
    threshold = stored.scene.monitor.utilisation_yellow
    first = int(np.argmax(util > threshold))
    assert util[first] > threshold >= util[first - 1] and stored.time[first] == 390.0
    level = stored.extra["screening"]["level"]
    assert np.all(level[:first] == 0) and np.all(level[first:] >= 1)
    assert read_transitions(stored.extra["screening"])[0] == (390.0, 0, 1, "near failure")
    np.testing.assert_allclose(stored.extra["screening"]["max_utilisation"], util, rtol=1e-12)
    # sliding at the injection point from 410 s: induced slip is the slip gained since
    sliding = stored.fault["contact_state"][:, np.argmin(np.abs(stored.fault_x))] == 1
    k = int(np.argmax(sliding))
    assert stored.time[k] == 410.0 and np.all(sliding[k:])
    slip = stored.injection["slip"]
    np.testing.assert_allclose(stored.extra["screening"]["induced_slip"][-1], abs(slip[-1] - slip[k - 1]),
                               rtol=1e-12)
    assert np.all(stored.extra["screening"]["induced_slip"][:k] == 0.0)


def test_screening_group_units_in_the_file(impermeable):
    _, path = impermeable
    with h5py.File(path) as h5:
        g = h5["screening"]
        for name, (unit, _) in METRICS.items():
            assert g[name].attrs["unit"] == unit and g[name].shape == h5["time"].shape
        assert g["transitions"].dtype.names == ("time", "from", "to", "rule")
        assert g["level"].dtype == np.int8


def test_streamed_screening_equals_the_whole_result_evaluation(impermeable):
    result, _ = impermeable
    whole = screen_result(result, store=False)
    tracker, sc = MetricsTracker.for_result(result), Screener(result.scene.monitor)
    levels = []
    for i, t in enumerate(result.time):
        m = tracker.row(result, i)
        sc.update(t, m)
        levels.append(sc.level)
        for k, v in m.items():
            w = whole.metrics[k][i]
            assert (math.isnan(v) and math.isnan(w)) or v == w, (k, i)
    assert levels == list(whole.level)
    assert sc.transitions == whole.transitions


def test_rescreening_a_saved_result_gives_the_live_levels_and_new_thresholds_apply(impermeable, tmp_path):
    result, path = impermeable
    live = result.extra["screening"]
    out = tmp_path / "again.h5"
    r = invoke("screen", path, "--out", out)
    assert r.exit_code == 0, r.output
    assert "verdict: YELLOW" in r.output and "near failure" in r.output and "t = 390 s" in r.output
    again = Result.load(out).extra["screening"]
    np.testing.assert_array_equal(again["level"], live["level"])
    assert read_transitions(again) == read_transitions(live)
    # new thresholds from another scene: yellow from the first utilisation above 0.8
    scene = tmp_path / "stricter.toml"
    scene.write_text('[monitor]\nutilisation_yellow = 0.8\n[[monitor.rules]]\nlevel = "yellow"\n'
                     'name = "watch"\nwhen = "max_utilisation > utilisation_yellow"\nhold = 0\n')
    r = invoke("screen", path, "--scene", scene, "--out", out, "--fail-on", "yellow")
    assert r.exit_code == 4, r.output
    util = utilisation_from_fields(result)
    first = int(np.argmax(util > 0.8))
    stricter = Result.load(out)
    assert read_transitions(stricter.extra["screening"])[0] == (float(result.time[first]), 0, 1, "watch")
    assert stricter.scene.monitor.utilisation_yellow == 0.8


def test_an_unstable_stop_is_red_with_its_own_reason_and_exit_code_3(impermeable, tmp_path):
    result, _ = impermeable
    result = dataclasses.replace(result, meta={**result.meta, "stopped": {"reason": "unstable", "time": 100.0}},
                                 extra={})
    assert stopped_unstable(result) == 100.0
    sc = screen_result(result)
    i = int(np.searchsorted(result.time, 100.0))
    assert np.all(sc.level[:i] == 0) and np.all(sc.level[i:] == 2)
    assert (sc.transitions[0].time, sc.transitions[0].to_level, sc.transitions[0].rule) == (100.0, 2, "unstable")
    path = result.save(tmp_path / "unstable.h5")
    r = invoke("screen", path, "--fail-on", "yellow")
    assert r.exit_code == 3 and "verdict: RED" in r.output and "unstable" in r.output


def test_zero_rate_log_stays_green_with_no_induced_slip(tmp_path):
    """Rate-and-state (the calibrated scene) creeps at rest: the slip at the injection point grows
    by ~5e-12 m in 100 s without any injection.  None of it is induced."""
    s = Scene.from_toml(CALIBRATED)
    s = s.replace(mesh=dataclasses.replace(s.mesh, nx=10, ny=11), time=dataclasses.replace(s.time, dt=10.0))
    scene = tmp_path / "small.toml"
    scene.write_text(s.to_toml())
    log = tmp_path / "zero.csv"
    log.write_text("elapsed[s],flow_rate[L/min]\n" + "".join(f"{t},0.0\n" for t in range(0, 101, 20)))
    out = tmp_path / "zero.h5"
    r = invoke("replay", scene, "--log", log, "--out", out, "--quiet", "--fail-on", "yellow")
    assert r.exit_code == 0, r.output
    assert "verdict: GREEN" in r.output
    res = Result.load(out)
    assert np.all(res.extra["screening"]["induced_slip"] == 0.0)
    assert np.all(res.extra["screening"]["level"] == 0)
    assert res.injection["slip"][-1] > 1e-12          # the creep the definition leaves out (~5e-12 m)


def test_run_prints_the_verdict_and_fail_on_gives_4(tmp_path):
    s = Scene.from_toml(CALIBRATED)
    s = s.replace(mesh=dataclasses.replace(s.mesh, nx=10, ny=11),
                  time=dataclasses.replace(s.time, end=30.0, dt=10.0),
                  monitor=spec(dict(level="yellow", name="pressure up", when="injection_overpressure > 2e3",
                                    action="call the engineer")))
    scene = tmp_path / "s.toml"
    scene.write_text(s.to_toml())
    out = tmp_path / "r.h5"
    r = invoke("run", scene, "--out", out, "--quiet", "--fail-on", "red")
    assert r.exit_code == 0, r.output
    assert "verdict: YELLOW" in r.output and "call the engineer" in r.output
    assert "injection_overpressure" in r.output and "rule                         pressure up" in r.output
    r = invoke("run", scene, "--out", out, "--quiet", "--fail-on", "yellow", "--plot", tmp_path / "figs")
    assert r.exit_code == 4 and out.is_file()
    # plot_result draws the screening figure beside the other two
    assert sorted(p.name for p in (tmp_path / "figs").iterdir()) == [
        "r-injection-point.png", "r-screening.png", "r-space-time.png"]
    res = Result.load(out)
    first = int(np.argmax(res.injection["overpressure"] > 2e3))
    assert 0 < first < len(res.time) - 1
    assert read_transitions(res.extra["screening"])[0][:3] == (float(res.time[first]), 0, 1)
    assert f"reached at                   t = {res.time[first]:.6g} s" in r.output


def test_the_screening_figure_is_drawn_for_screened_results_only(impermeable, tmp_path):
    result, _ = impermeable
    (png,) = screening_figures(result, tmp_path, prefix="a-")
    assert png.name == "a-screening.png" and png.read_bytes()[:8] == PNG_MAGIC
    assert screening_figures(dataclasses.replace(result, extra={}), tmp_path) == []


def test_rescreening_reads_the_stored_event_distances():
    """The results' /events group stores distance_to_injection (the output schema's name)."""
    from types import SimpleNamespace

    from fault_screen.screening import _stored_events

    stored = SimpleNamespace(extra={"events": {"time": np.array([10.0]), "magnitude": np.array([1.5]),
                                               "distance_to_injection": np.array([420.0])}})
    assert np.asarray(_stored_events(stored).distance).tolist() == [420.0]


def test_screen_refuses_a_result_whose_arrays_disagree_in_length(tmp_path):
    """5 output times but 135 rows of injection overpressure: one line, exit 2, no verdict."""
    from click.testing import CliRunner

    from fault_screen import Result
    from fault_screen.cli import main

    n, x = 5, np.linspace(-10.0, 10.0, 4)
    fault = {k: np.zeros((n, x.size)) for k in ("slip_rate", "shear_traction",
                                                "effective_normal_stress", "slip")}
    fault["contact_state"] = np.zeros((n, x.size), dtype=np.int64)
    fault["effective_normal_stress"] += 1e6          # a locked fault, far from failure
    good = dict(scene=Scene.from_dict({}), time=np.arange(n, dtype=float), fault_x=x,
                fault_xy=np.column_stack([x, 0 * x]), fault_weights=np.full(x.size, 5.0),
                fault=fault, balance={}, solver={})
    inj = {k: np.zeros(n) for k in ("overpressure", "slip", "shear_traction", "volume", "flow_rate")}
    inj["effective_normal_stress"] = np.full(n, 1e6)
    Result(injection=inj, **good).save(tmp_path / "good.h5")
    Result(injection=dict(inj, overpressure=np.zeros(135)), **good).save(tmp_path / "bad.h5")
    ok = CliRunner().invoke(main, ["screen", str(tmp_path / "good.h5")])
    assert ok.exit_code == 0 and "verdict: GREEN" in ok.output, ok.output
    r = CliRunner().invoke(main, ["screen", str(tmp_path / "bad.h5")])
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and "verdict" not in r.output
    assert "/injection/overpressure has 135 rows for 5 output times" in lines[0]
    assert "bad.h5" in lines[0]

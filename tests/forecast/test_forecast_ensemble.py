"""Forecasts over parameter draws (``fault-screen forecast --vary --members``, LiveEnsemble).

The draws vary the friction coefficient mu0 of the impermeable Rustrel scene. While every point
of the fault sticks, mu0 enters nothing but the strength, so each member's utilisation
|tau| / (mu0 sigma'_n) is the scene's times 0.68 / mu0 row for row, and a member turns yellow
("near failure": utilisation > 0.9) within the horizon exactly when its mu0 is below
0.68 U / 0.9, U the scene's largest utilisation over the horizon. That gives P(yellow) from
the draws alone."""
import csv
import math
import pickle

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import CONFIGS
from fault_screen import Scene
from fault_screen.calibration import load_parameters, sample_parameters
from fault_screen.cli import main
from fault_screen.forecast import COLUMNS, Plan, parse_plan
from fault_screen.forecast.ensemble import (ENSEMBLE_COLUMNS, LiveEnsemble, MemberRun, ensemble_advice,
                                            lookaheads, run_member, summarise, time_percentile)
from fault_screen.forecast.advice import Advice
from fault_screen.screening import YELLOW

IMPERMEABLE = str(CONFIGS / "rustrel-2015-impermeable.toml")
MU0 = 0.68           # the scene's friction coefficient
MEMBERS, SEED = 6, 3
FRICTION = """[[parameter]]
key = "fault.friction"
mean = 0.69
lower = 0.62
upper = 0.76
"""


def _rows(path):
    with open(path, newline="") as fh:
        table = csv.DictReader(fh)
        return table.fieldnames, list(table)


@pytest.fixture(scope="module")
def friction_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("vary") / "friction.toml"
    path.write_text(FRICTION)
    return path


@pytest.fixture(scope="module")
def draws(friction_file):
    """The draws the command makes, from the same file, sampler and seed."""
    return [d["fault.friction"] for d in sample_parameters(load_parameters(friction_file), MEMBERS,
                                                               "uniform", SEED)]


@pytest.fixture(scope="module")
def made(tmp_path_factory, friction_file):
    """Six members made at 300 s, 100 s ahead (the scene turns yellow at 390 s and sticks until
    after 400 s), plans scene and stop, advice at confidence 0.75, in this process, on the
    scene's own steps (exact: the default with --members is a step ladder)."""
    out = tmp_path_factory.mktemp("ens") / "f.csv"
    res = CliRunner().invoke(main, ["forecast", IMPERMEABLE, "--at", "300", "--horizon", "100",
                                    "--scene-steps",
                                    "--plan", "scene", "--plan", "stop", "--vary", str(friction_file),
                                    "--members", str(MEMBERS), "--distribution", "uniform",
                                    "--seed", str(SEED), "--workers", "0", "--advise",
                                    "--confidence", "0.75", "--out", str(out)])
    assert res.exit_code == 0, res.output
    header, rows = _rows(out)
    return res, header, {r["plan"]: r for r in rows}


def test_the_csv_has_the_forecast_columns_then_exactly_the_ensemble_columns(made):
    _, header, rows = made
    assert header == list(COLUMNS) + ["p_yellow", "p_red", "time_to_yellow_p10", "time_to_yellow_p50",
                                      "time_to_yellow_p90", "members"]
    assert list(ENSEMBLE_COLUMNS) == header[len(COLUMNS):]
    assert list(rows) == ["scene", "stop"]
    # the deterministic columns are the scene's own forecast (turns yellow at 390 s)
    assert float(rows["scene"]["time_to_yellow"]) == 90.0 and rows["stop"]["time_to_yellow"] == ""
    assert all(r["members"] == str(MEMBERS) for r in rows.values())


def test_p_yellow_is_the_fraction_of_draws_below_the_critical_friction(made, draws):
    res, _, rows = made
    base = next(lookaheads(Scene.from_toml(IMPERMEABLE), [300.0])).run(parse_plan("scene"), 100.0)
    util = base.metrics["max_utilisation"]
    assert util.max() < 1.0                       # the scene sticks over the whole horizon
    critical = MU0 * util.max() / 0.9
    assert min(abs(d - critical) for d in draws) > 1e-6 * critical   # no draw on the edge
    expected = np.mean([d < critical for d in draws])
    assert 0 < expected < 1
    assert float(rows["scene"]["p_yellow"]) == expected
    assert float(rows["stop"]["p_yellow"]) == 0.0          # shut-in relieves every member
    assert float(rows["scene"]["p_red"]) == float(rows["stop"]["p_red"]) == 0.0
    # the percentiles: the member's first row with utilisation above 0.9 (+inf if none), the
    # smallest time by which at least 10/50/90 % of the six members are yellow
    t = base.time - 300.0
    first = sorted(float(t[np.argmax(util * MU0 / d > 0.9)]) if np.any(util * MU0 / d > 0.9) else math.inf
                   for d in draws)
    for q, k in ((10, 0), (50, 2), (90, 5)):       # ceil(q/100 * 6) - 1
        cell = rows["scene"][f"time_to_yellow_p{q}"]
        assert (cell == "") if math.isinf(first[k]) else (float(cell) == first[k]), (q, cell, first)


def test_the_advised_rate_brackets_the_confidence(made, draws):
    """At the advised rate at most 25 % of the members reach yellow within 100 s, at 1.05 times
    it more than 25 % do (each member's look-ahead run again at both rates)."""
    res, _, rows = made
    advised = float(rows["scene"]["advised_rate"])
    assert rows["stop"]["advised_rate"] == rows["scene"]["advised_rate"]
    assert "P(yellow within 100 s) <= 25 %" in res.output
    live = LiveEnsemble(Scene.from_toml(IMPERMEABLE), [{"fault.friction": d} for d in draws], base=False)
    live.advance(300.0)
    assert live.time == 300.0
    made_live, _ = live.run([Plan.constant(advised), Plan.constant(1.05 * advised)], 100.0)
    at, above = made_live
    assert at.members == above.members == MEMBERS
    reached = [[f.reaches(YELLOW) for f in m.forecasts] for m in made_live]
    assert np.mean(reached[0]) <= 0.25 < np.mean(reached[1])
    assert at.p_yellow == np.mean(reached[0])           # green now: reaching = yellow within


def test_the_default_ladder_gives_p_yellow_of_the_members_own_ladder_lookaheads(tmp_path, friction_file, draws):
    """With --members and neither --ladder nor --scene-steps the look-aheads take a step ladder
    to ENSEMBLE_LADDER (160 s); the ensemble's P(yellow) and percentiles are those of each
    member's own look-ahead on such a ladder (its history on the scene's steps)."""
    from fault_screen.ensemble import scene_with
    from fault_screen.forecast.ensemble import ENSEMBLE_LADDER

    out = tmp_path / "f.csv"
    res = CliRunner().invoke(main, ["forecast", IMPERMEABLE, "--at", "300", "--horizon", "100",
                                    "--plan", "scene", "--plan", "stop", "--vary", str(friction_file),
                                    "--members", str(MEMBERS), "--distribution", "uniform",
                                    "--seed", str(SEED), "--workers", "0", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert ENSEMBLE_LADDER == 160.0 and "step ladder to 160 s" in res.output
    rows = {r["plan"]: r for r in _rows(out)[1]}
    scene = Scene.from_toml(IMPERMEABLE)
    plans = [parse_plan("scene"), parse_plan("stop")]
    own = []
    for d in draws:
        ahead = next(lookaheads(scene_with(scene, {"fault.friction": d}), [300.0], steps={"ladder": 160.0}))
        own.append([ahead.run(p, 100.0) for p in plans])
    for k, plan in enumerate(("scene", "stop")):
        fs = [member[k] for member in own]
        assert len(fs[0].time) < 21             # a ladder's steps, not the scene's 20 of 5 s
        expected = sum(f.max_level >= YELLOW for f in fs) / MEMBERS
        assert float(rows[plan]["p_yellow"]) == expected, plan
        tty = np.array([math.inf if f.time_to_yellow is None else f.time_to_yellow for f in fs])
        for q in (10, 50, 90):
            cell, want = rows[plan][f"time_to_yellow_p{q}"], time_percentile(tty, q)
            assert (cell == "") if want is None else float(cell) == want, (plan, q)
    assert 0 < float(rows["scene"]["p_yellow"]) < 1 and float(rows["stop"]["p_yellow"]) == 0.0


@pytest.fixture(scope="module")
def degenerate():
    """Three members with the scene's own friction (all draws equal), live: stepped to 300 s
    with the scene's schedule, then 120 s ahead under scene and stop."""
    scene = Scene.from_toml(IMPERMEABLE)
    live = LiveEnsemble(scene, [{"fault.friction": MU0}] * 3)
    live.advance(150.0)
    live.advance(300.0)
    plans = [parse_plan("scene"), parse_plan("stop")]
    return live, plans, live.forecast(None, plans, 120.0, None)


def test_equal_draws_give_probabilities_0_or_1_and_the_deterministic_times(degenerate):
    live, plans, rows = degenerate
    scene_row, stop_row = rows
    # the deterministic forecast: the scene turns yellow at 390 s, 90 s after 300 s
    assert scene_row["time_to_yellow"] == 90.0 and stop_row["time_to_yellow"] is None
    assert scene_row["p_yellow"] == 1.0 and stop_row["p_yellow"] == 0.0
    assert scene_row["p_red"] == stop_row["p_red"] == 0.0
    for q in (10, 50, 90):
        assert scene_row[f"time_to_yellow_p{q}"] == 90.0
        assert stop_row[f"time_to_yellow_p{q}"] is None
    assert scene_row["members"] == stop_row["members"] == 3
    assert set(scene_row) == set(COLUMNS) | set(ENSEMBLE_COLUMNS) | {"made_at_utc"}


def test_a_live_member_that_fails_is_set_aside_and_not_counted(degenerate):
    live, plans, _ = degenerate
    index, params, sim, screening = live.members[-1]
    # one member whose step fails: only it is set aside, with its error (the rows of the
    # fixture were made before)
    live.members[-1] = (index, params, _FailingSim(sim), screening)
    live.advance(305.0)
    assert live.failed == [(index, "RuntimeError: pump log lost")]
    assert [m[0] for m in live.members] == [-1, 0, 1]
    rows = live.forecast(None, plans[:1], 10.0, None)
    assert rows[0]["members"] == 2


class _FailingSim:
    def __init__(self, sim):
        self.sim = sim

    def advance(self, *args, **kwargs):
        raise RuntimeError("pump log lost")


def test_a_failed_member_is_reported_not_dropped():
    """A draw the scene refuses (mu0 < 0) fails in its task with the scene's message; the
    summary counts only the others and keeps the failure."""
    scene = Scene.from_toml(IMPERMEABLE)
    bad = run_member(4, scene.to_dict(), {"fault.friction": -0.1}, [300.0], [parse_plan("stop")], 60.0)
    assert not bad.ok and "friction" in bad.error and bad.params == {"fault.friction": -0.1}
    good = MemberRun(index=0, params={}, ok=True, forecasts=[_forecast(90.0, 1)])
    made = summarise([good, bad])
    assert made[0].members == 1 and made[0].failed == [(4, bad.error)]
    assert made[0].p_yellow == 1.0
    # the call and what comes back go to and from Dask workers: they pickle
    pickle.loads(pickle.dumps((scene.to_dict(), [parse_plan("hold"), Plan.constant(1e-4)], bad)))


def _forecast(time_to_yellow, max_level):
    from fault_screen.forecast.lookahead import Forecast

    return Forecast(made_at=0.0, plan="p", horizon=100.0, level_now=0, level_at_horizon=max_level,
                    max_level=max_level, time_to_yellow=time_to_yellow, time_to_red=None,
                    peak_slip_rate=0.0, max_utilisation=0.0, induced_slip_at_horizon=0.0, wall_s=0.0)


def test_percentiles_count_members_that_stay_green_as_later_than_any():
    times = np.array([30.0, math.inf, 10.0, math.inf, 20.0])
    assert time_percentile(times, 10) == 10.0      # 1 of 5 by 10 s
    assert time_percentile(times, 50) == 30.0      # 3 of 5 by 30 s
    assert time_percentile(times, 60) == 30.0
    assert time_percentile(times, 61) is None      # only 3 of 5 ever reach yellow
    assert time_percentile(np.array([]), 50) is None


def _advice(rate, even_zero=False, upper=1.0):
    return Advice(made_at=0.0, horizon=60.0, level=YELLOW, control="rate", rate=rate, upper=upper,
                  max_rate=2.0, even_zero_reaches=even_zero, evaluations=1)


def test_ensemble_advice_is_the_member_rate_that_leaves_the_allowed_fraction_above():
    members = [_advice(r) for r in (0.5, 0.2, 0.9, 0.4, 0.7, 0.3, 0.8, 0.6, 1.0, 0.1)]
    found = ensemble_advice(members, 0.9)       # 1 of 10 may reach yellow
    assert found.rate == 0.2 and found.probability == 0.1
    assert found.reaching(0.2 * 1.05) == 0.2
    assert ensemble_advice(members, 0.75).rate == 0.3     # floor(2.5) = 2 may
    # four members are yellow even at shut-in: more than 10 %, advice 0, said so
    zero = ensemble_advice([_advice(0.0, True, 0.0)] * 4 + members[:6], 0.9)
    assert zero.rate == 0.0 and zero.even_zero == 0.4 and zero.even_zero_too_likely
    assert "whatever the injection does" in zero.describe()
    with pytest.raises(ValueError, match="between 0 and 1"):
        ensemble_advice(members, 1.0)


@pytest.mark.parametrize("args, message", [
    (["--members", "3"], "--members needs --vary"),
    (["--vary", "{vary}"], "--vary needs --members"),
    (["--vary", "{vary}", "--members", "0"], "--members 0: must be >= 1"),
    (["--vary", "{vary}", "--members", "2", "--confidence", "0.9"], "add --advise"),
    (["--vary", "{vary}", "--members", "2", "--advise", "--confidence", "1.5"], "between 0 and 1"),
    (["--confidence", "0.9", "--advise"], "--confidence is for an ensemble"),
    (["--scheduler", "tcp://127.0.0.1:1"], "--scheduler is for an ensemble"),
    (["--vary", "{vary}", "--members", "2", "--free", "rock.porosity"], "rock.porosity"),
    (["--vary", "{vary}", "--members", "2", "--scene-steps", "--ladder", "40"], "--scene-steps or --ladder"),
])
def test_bad_ensemble_options_exit_2_with_a_message(args, message, tmp_path, friction_file):
    args = [a.replace("{vary}", str(friction_file)) for a in args]
    res = CliRunner().invoke(main, ["forecast", IMPERMEABLE, "--at", "1e9", "--horizon", "60",
                                    "--out", str(tmp_path / "f.csv"), *args])
    assert res.exit_code == 2, res.output
    assert message in res.output


_toml_value = st.one_of(st.integers(-10, 10), st.floats(allow_nan=True, allow_infinity=True),
                        st.text(max_size=5), st.booleans())


@st.composite
def _vary_files(draw):
    """PARAMS.toml texts: arbitrary text, or parameter tables with any keys and values."""
    if draw(st.booleans()):
        return draw(st.text(st.characters(blacklist_categories=("Cs",)), max_size=80))
    lines = []
    for _ in range(draw(st.integers(0, 2))):
        lines.append("[[parameter]]")
        for field in draw(st.lists(st.sampled_from(["key", "mean", "lower", "upper", "transform", "unit",
                                                     "colour"]), max_size=6, unique=True)):
            value = draw(st.one_of(_toml_value, st.sampled_from(["fault.friction", "rock.porosity",
                                                                 "fault.nothing", "log", "GPa"])))
            lines.append(f"{field} = {_toml(value)}")
    return "\n".join(lines) + "\n"


def _toml(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    return str(value)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=_vary_files(), members=st.one_of(st.integers(-3, 40).map(str), st.text(max_size=6)))
def test_any_vary_file_and_members_value_ends_in_exit_2_with_a_message(text, members, tmp_path):
    """Nothing runs: a good file and count are refused for the forecast time after the run."""
    path = tmp_path / "params.toml"
    path.write_text(text, encoding="utf-8")
    res = CliRunner().invoke(main, ["forecast", IMPERMEABLE, "--at", "1e9", "--horizon", "60",
                                    "--vary", str(path), "--members", members, "--workers", "0",
                                    "--out", str(tmp_path / "f.csv")])
    assert res.exit_code == 2, (res.output, repr(res.exception))
    assert "Error" in res.output and "Traceback" not in res.output

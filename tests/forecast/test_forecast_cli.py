"""``fault-screen forecast``: the table, forecast.csv (exactly the issue's columns), the figure,
bad input (exit 2 with a message), and a run driven by a log."""
import csv
import dataclasses

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import CONFIGS
from fault_screen import Scene
from fault_screen.cli import main
from fault_screen.forecast import COLUMNS

IMPERMEABLE = str(CONFIGS / "rustrel-2015-impermeable.toml")
ISSUE_COLUMNS = ["made_at", "plan", "horizon", "level_now", "level_at_horizon", "max_level",
                 "time_to_yellow", "time_to_red", "peak_slip_rate", "max_utilisation",
                 "induced_slip_at_horizon", "advised_rate", "wall_s"]


def _rows(path):
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader)
        return header, [dict(zip(header, r)) for r in reader]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """One command: made at 5 min (on a step: 300 s), 2 min ahead, three plans, advice, figure."""
    d = tmp_path_factory.mktemp("forecast")
    out = d / "f.csv"
    res = CliRunner().invoke(main, ["forecast", IMPERMEABLE, "--at", "5min", "--horizon", "2 min",
                                    "--plan", "scene", "--plan", "stop", "--plan", "rate:30 L/min",
                                    "--advise", "--out", str(out), "--plot", str(d / "figs")])
    assert res.exit_code == 0, res.output
    return res, out, d / "figs"


def test_the_csv_has_exactly_the_issue_columns_and_the_forecasts(made):
    res, out, _ = made
    header, rows = _rows(out)
    assert header == ISSUE_COLUMNS == list(COLUMNS)
    by_plan = {r["plan"]: r for r in rows}
    assert list(by_plan) == ["scene", "stop", "rate:30 L/min"]
    scene, stop, rate = by_plan["scene"], by_plan["stop"], by_plan["rate:30 L/min"]
    assert all(float(r["made_at"]) == 300.0 and float(r["horizon"]) == 120.0 for r in rows)
    # impermeable Rustrel first reaches yellow at 390 s: 90 s after 300 s; 30 L/min is sooner
    assert float(scene["time_to_yellow"]) == 90.0 and scene["max_level"] == "yellow"
    assert float(rate["time_to_yellow"]) == 30.0
    assert stop["time_to_yellow"] == "" and stop["max_level"] == stop["level_at_horizon"] == "green"
    assert all(r["level_now"] == "green" and r["time_to_red"] == "" for r in rows)
    assert float(stop["induced_slip_at_horizon"]) == 0.0 and float(stop["max_utilisation"]) < 0.8
    # the advice is on every row, below the 22 L/min that reaches yellow within the 2 minutes
    advised = {r["advised_rate"] for r in rows}
    assert len(advised) == 1 and 0 < float(advised.pop()) < 22e-3 / 60
    assert "largest constant rate below yellow for 120 s" in res.output
    assert "1 min 30 s" in res.output


def test_the_figure_is_written(made):
    _, _, figs = made
    png = figs / "rustrel-2015-impermeable-forecast.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_without_advice_the_advised_rate_is_empty_and_every_gives_the_times(tmp_path):
    """The impermeable scene cut at 450 s: a forecast every 150 s."""
    scene = Scene.from_toml(IMPERMEABLE)
    short = tmp_path / "short.toml"
    short.write_text(scene.replace(time=dataclasses.replace(scene.time, end=450.0)).to_toml())
    out = tmp_path / "f.csv"
    res = CliRunner().invoke(main, ["forecast", str(short), "--every", "2.5 min", "--horizon", "10",
                                    "--plan", "hold", "--out", str(out), "-q"])
    assert res.exit_code == 0, res.output
    _, rows = _rows(out)
    assert [float(r["made_at"]) for r in rows] == [150.0, 300.0, 450.0]
    assert all(r["advised_rate"] == "" for r in rows)
    # yellow from 390 s on
    assert [r["level_now"] for r in rows] == ["green", "green", "yellow"]


def test_a_log_drives_the_run_and_the_times_fall_on_its_steps(tmp_path):
    """Replay of the stand-in log: --at 62 s is made at 60 s (the last 5 s step ending by then);
    ``hold`` continues the log's rate at 60 s, ``scale:0`` is a shut-in: the same as ``stop``."""
    out = tmp_path / "f.csv"
    res = CliRunner().invoke(main, ["forecast", IMPERMEABLE, "--log", str(CONFIGS / "logs" / "rustrel-2015-standin.csv"),
                                    "--at", "62", "--horizon", "30", "--plan", "stop", "--plan", "scale:0",
                                    "--out", str(out), "-q"])
    assert res.exit_code == 0, res.output
    _, rows = _rows(out)
    assert [float(r["made_at"]) for r in rows] == [60.0, 60.0]
    stop, zero = rows
    for k in ("max_utilisation", "peak_slip_rate", "induced_slip_at_horizon"):
        assert stop[k] == zero[k], k


@pytest.mark.parametrize("args, message", [
    (["--horizon", "60"], "--at T"),
    (["--at", "60", "--every", "60", "--horizon", "60"], "not both"),
    (["--at", "60", "--horizon", "2 kg"], "--horizon"),
    (["--at", "60", "--horizon", "0"], "--horizon must be > 0"),
    (["--at", "60", "--horizon", "60", "--ladder", "0"], "--ladder must be > 0"),
    (["--at", "2h", "--horizon", "60"], "after the end of the run"),
    (["--at", "60", "--horizon", "60", "--plan", "faster"], "unknown plan"),
    (["--at", "60", "--horizon", "60", "--plan", "pressure:3 MPa"], "pressure plan"),
    (["--at", "60", "--horizon", "60", "--advise", "--max-rate", "80"], "give the unit"),
])
def test_bad_input_exits_2_with_a_message(args, message, tmp_path):
    res = CliRunner().invoke(main, ["forecast", IMPERMEABLE, "--out", str(tmp_path / "f.csv"), *args])
    assert res.exit_code == 2, res.output
    assert message in res.output


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.text(min_size=1, max_size=20).filter(lambda s: not s.startswith("-")))
def test_any_horizon_text_is_accepted_or_refused_with_exit_2(text):
    """Only the option parsing runs (an --at after the run's end stops before any step)."""
    res = CliRunner().invoke(main, ["forecast", IMPERMEABLE, "--at", "1e9", "--horizon", text])
    assert res.exit_code == 2, res.output
    assert "Error:" in res.output
    assert ("--horizon" in res.output) or ("after the end of the run" in res.output) or ("> 0" in res.output)


def test_a_step_ladder_finds_yellow_late_by_at_most_its_largest_step(tmp_path):
    """--ladder 40: steps doubling from the run's 10 s up to 40 s, so the forecast's first
    yellow (exactly 90 s after 300 s on the scene's own steps) comes at most 40 s late and
    never early; shut-in stays green either way (a ladder that reused one size's factors for
    another, or skipped the horizon's end, would miss these)."""
    out = tmp_path / "ladder.csv"
    res = CliRunner().invoke(main, ["forecast", IMPERMEABLE, "--at", "5min", "--horizon", "10 min",
                                    "--plan", "scene", "--plan", "stop", "--ladder", "40",
                                    "--out", str(out), "-q"])
    assert res.exit_code == 0, res.output
    _, rows = _rows(out)
    by_plan = {r["plan"]: r for r in rows}
    assert 90.0 <= float(by_plan["scene"]["time_to_yellow"]) <= 90.0 + 40.0
    assert by_plan["stop"]["max_level"] == "green" and by_plan["stop"]["time_to_yellow"] == ""
    assert float(by_plan["stop"]["horizon"]) == 600.0


def test_a_stuck_faults_round_off_slip_rate_is_not_printed_as_a_number():
    """The table shows slip rates below SLIP_RATE_SHOWN_ABOVE (1e-15 m/s) as a bound, since a
    sticking fault's computed rate is round-off (the impermeable scene's stop plan: ~1e-21 m/s),
    and every rate from the bound up as a number with three digits."""
    from fault_screen.cli.forecast import SLIP_RATE_SHOWN_ABOVE, _slip_rate_text

    assert SLIP_RATE_SHOWN_ABOVE == 1e-15
    assert _slip_rate_text(7.62e-22) == "< 1e-15 m/s"
    assert _slip_rate_text(-3e-16) == "< 1e-15 m/s"
    assert _slip_rate_text(1e-15) == "1e-15 m/s"
    assert _slip_rate_text(3.891e-08) == "3.89e-08 m/s"

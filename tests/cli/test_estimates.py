"""Estimates before a run: ``scene check --log`` (the replay of that log) and the monitor's
start-up estimate per day of operation."""
from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

from fault_screen import Result, Scene
from fault_screen.cli import main

#: a 4 x 5 mesh: the estimates count its steps and bytes as for any scene
TINY = {
    "mesh": {"nx": 4, "ny": 5, "lx": 50.0, "ly": 50.0},
    "initial": {"effective_stress": [-5.649e6, -3.351e6, 0.964e6], "pore_pressure": 2.764e6},
    "injection": {"number_of_fractures": 10, "schedule": [[0.0, 1e-3]]},
    "time": {"end": 100.0, "dt": 5.0},
}


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("tiny") / "tiny.toml"
    path.write_text(Scene.from_dict(TINY).to_toml())
    return path


def _log(path, rows: int, every: float, unit: str = "s"):
    """A steady 0.06 m3/min log of ``rows`` samples ``every`` s apart (elapsed times)."""
    path.write_text(f"elapsed[{unit}],flow_rate[L/min]\n" + "".join(
        f"{k * every / (60.0 if unit == 'min' else 1.0):g},60\n" for k in range(rows)))
    return path


def _estimate(output: str) -> str:
    (line,) = [x.strip() for x in output.splitlines() if x.strip().startswith("estimate:")]
    return line


def test_scene_check_with_a_log_estimates_the_replay_of_it(tiny_scene, tmp_path):
    """A 170-s log (35 samples) on the 5-s steps of the scene: check counts 34 steps, the
    estimate line replay prints at its start, and the replay takes 34 steps; with --end 60 (the
    replay's option) 12 steps; the scene's own 100 s (no --log) 20."""
    log = _log(tmp_path / "q.csv", 35, 5.0)
    r = invoke("scene", "check", tiny_scene, "--log", log)
    assert r.exit_code == 0, r.output
    line = _estimate(r.output)
    assert line.startswith("estimate: 34 steps,") and f"replay of {log}: 0 to 170 s" in r.output
    out = tmp_path / "r.h5"
    rep = invoke("replay", tiny_scene, "--log", log, "--out", out)
    assert rep.exit_code == 0, rep.output
    assert _estimate(rep.output) == line
    assert len(Result.load(out).time) == 35
    r = invoke("scene", "check", tiny_scene, "--log", log, "--end", 60)
    assert r.exit_code == 0 and _estimate(r.output).startswith("estimate: 12 steps,"), r.output
    r = invoke("scene", "check", tiny_scene)
    assert r.exit_code == 0 and _estimate(r.output).startswith("estimate: 20 steps,"), r.output


def test_scene_check_reads_the_log_with_replays_options(tiny_scene, tmp_path):
    """A log whose flow column names no unit: refused without --flow-unit with replay's message
    (exit 2); with --flow-unit L/min, 100 samples a minute apart: 99 min, 1,188 steps of 5 s."""
    log = tmp_path / "m.csv"
    log.write_text("elapsed[min],flow_rate\n" + "".join(f"{k},60\n" for k in range(100)))
    bad = invoke("scene", "check", tiny_scene, "--log", log)
    rep = invoke("replay", tiny_scene, "--log", log, "--out", tmp_path / "r.h5")
    assert bad.exit_code == rep.exit_code == 2
    assert bad.output.strip().splitlines()[-1] == rep.output.strip().splitlines()[-1]
    assert bad.output.strip().splitlines()[-1].startswith("Error: ")
    assert "pass --flow-unit" in bad.output and "ok --" not in bad.output
    r = invoke("scene", "check", tiny_scene, "--log", log, "--flow-unit", "L/min")
    assert r.exit_code == 0, r.output
    assert _estimate(r.output).startswith("estimate: 1,188 steps,")


hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from input_strategies import LOG_HEADERS, mutated, tables  # noqa: E402


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                 HealthCheck.function_scoped_fixture])
@given(data=st.one_of(tables(LOG_HEADERS), tables(LOG_HEADERS).flatmap(mutated),
                      st.binary(max_size=400)),
       options=st.lists(st.sampled_from([["--policy", "skip"], ["--policy", "hold"],
                                         ["--time-unit", "min"], ["--flow-unit", "L/min"],
                                         ["--tz", "Europe/Zurich"], ["--accept-implausible"],
                                         ["--end", "50"]]), max_size=3))
def test_scene_check_of_any_log_gives_an_estimate_or_one_error_line(tiny_scene, tmp_path, data,
                                                                    options):
    """Random bytes, broken tables and mutated ones as --log: the estimate (exit 0) or exit 2
    with one line 'Error: ...' naming the problem, never a traceback or another exit code."""
    log = tmp_path / "log.csv"
    log.write_bytes(data)
    r = invoke("scene", "check", tiny_scene, "--log", log, *[x for o in options for x in o])
    assert r.exit_code in (0, 2), (r.exit_code, r.output, r.exc_info)
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exc_info
    assert "Traceback" not in r.output
    if r.exit_code == 0:
        assert _estimate(r.output).startswith("estimate: ")
    else:
        errors = [x for x in r.output.splitlines() if x.startswith("Error: ")]
        assert len(errors) == 1 and len(errors[0]) > len("Error: ") + 10 and "ok --" not in r.output


# ---------------------------------------------------------------------------------------------
# the monitor: per day of operation
# ---------------------------------------------------------------------------------------------
#: 4,096 steps a day: a day's series fill exactly one chunk of the streamed file (4,096 rows),
#: so a day's growth is the difference of two files, one step long and a day long
DAY_DT = 86400.0 / 4096


def test_monitor_prints_its_estimate_per_day_at_start(tiny_scene, tmp_path, monkeypatch):
    """The monitor's first lines: the estimate of estimate_monitor (4,096 steps a day at
    21.1-s steps; 17,280 at the tiny scene's 5 s), before it follows the log."""
    from fault_screen.run_estimate import estimate_monitor

    monkeypatch.chdir(tmp_path)
    log = _log(tmp_path / "q.csv", 4, 5.0)
    r = invoke("monitor", tiny_scene, "--follow", log, "--idle-exit", "0.5", "--out", tmp_path / "m.h5")
    assert r.exit_code == 0, r.output
    want = estimate_monitor(Scene.from_toml(tiny_scene)).lines()
    assert want[0].startswith("estimate per day of operation: 17,280 steps of about ")
    assert r.stdout.splitlines()[:len(want)] == want
    day = Scene.from_dict({**TINY, "time": {"end": 100.0, "dt": DAY_DT}})
    assert estimate_monitor(day).steps_per_day == 4096


def test_monitor_estimate_advises_when_a_day_is_large():
    """The bundled scene at its 5-s steps: 17,280 steps and 1,807 profiles a day (the automatic
    rule), 22.6 MB, no advice; every profile kept: 178 MB a day and the advice to thin them;
    steps growing by 1.2 to 600 s: 27 growing steps (3,415 s) and 139 of 600 s, 166; an
    800 x 801 mesh (1.9 million unknowns): over 4 GB of model and the advice to coarsen it,
    and not a 400 x 401 one (486,012 unknowns: the memory measured at 200 x 201, 615 MB,
    grows to about 2 GB)."""
    import dataclasses
    from pathlib import Path

    from fault_screen.run_estimate import estimate_monitor

    scene = Scene.from_toml(Path(__file__).resolve().parents[2] / "configs" / "rustrel-2015-calibrated.toml")
    plain = estimate_monitor(scene)
    assert (plain.steps_per_day, plain.profiles_per_day) == (17_280, 1_807)
    assert round(plain.file_bytes_per_day / 1e6, 1) == 22.6 and len(plain.lines()) == 1
    every = estimate_monitor(scene.replace(output=scene.output.__class__(profile_every=1)))
    assert every.profiles_per_day == 17_281 and 175e6 < every.file_bytes_per_day < 182e6
    assert every.lines()[1].startswith("advice: the result file grows fast") and \
        "profile_interval" in every.lines()[1]
    growing = estimate_monitor(scene.replace(time=dataclasses.replace(scene.time, growth=1.2,
                                                                      dt_max=600.0)))
    assert growing.steps_per_day == 166 and len(growing.lines()) == 1
    big = estimate_monitor(scene.replace(mesh=dataclasses.replace(scene.mesh, nx=800, ny=801)))
    assert big.memory_bytes > 4e9 and "coarsen the mesh" in big.lines()[-1]
    middle = estimate_monitor(scene.replace(mesh=dataclasses.replace(scene.mesh, nx=400, ny=401)))
    assert 1.5e9 < middle.memory_bytes < 2.5e9
    assert not any("coarsen the mesh" in line for line in middle.lines())


def test_monitor_file_growth_per_day_against_a_replayed_day(tmp_path):
    """The per-day growth of the monitor's estimate against a replay of a steady day-long log
    (1,441 samples a minute apart) on the tiny mesh with [output] profile_interval = "1 h":
    the file of the day minus that of its first step, the log's samples set aside (16 B each
    without pressure), within 1.1x (the series, stored uncompressed, 31 values a step, are
    most of it); the day's profiles are the estimate's 26 (every hour and the last), and its
    steps 4,096."""
    from fault_screen.run_estimate import estimate_monitor

    scene = Scene.from_dict({**TINY, "time": {"end": 100.0, "dt": DAY_DT},
                             "output": {"profile_interval": 3600.0}})
    path = tmp_path / "day.toml"
    path.write_text(scene.to_toml())
    log = _log(tmp_path / "day.csv", 1441, 60.0)
    sizes = {}
    for name, end in (("step", DAY_DT), ("day", 86400.0)):
        out = tmp_path / f"{name}.h5"
        r = invoke("replay", path, "--log", log, "--end", end, "--out", out, "--quiet")
        assert r.exit_code == 0, r.output
        sizes[name] = out.stat().st_size - 16 * len(Result.load(out).extra["log"]["time"])
    day = Result.load(tmp_path / "day.h5")
    assert len(day.time) == 4097
    est = estimate_monitor(scene)
    assert est.steps_per_day == 4096 and est.profiles_per_day == 26 == len(day.profile_time)
    grown = sizes["day"] - sizes["step"]
    assert est.file_bytes_per_day / 1.1 <= grown <= 1.1 * est.file_bytes_per_day, (grown, est)

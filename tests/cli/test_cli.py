"""The ``fault-screen`` command line: run, replay, plot; exit codes and error messages."""
from __future__ import annotations

import dataclasses
import json
from datetime import datetime, timedelta, timezone
from pathlib import Path

import click
import h5py
import numpy as np
import pytest
from click.testing import CliRunner

import fault_screen
from fault_screen import Scene, SimulationError
from fault_screen.cli import main
from fault_screen.cli._progress import Progress

ROOT = Path(__file__).resolve().parents[2]
BUNDLED = ROOT / "configs" / "rustrel-2015-calibrated.toml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
CET = timezone(timedelta(hours=1))


def small_scene(**time) -> Scene:
    s = Scene.from_toml(BUNDLED)
    t = dict(end=60.0, dt=7.0)
    t.update(time)
    return s.replace(mesh=dataclasses.replace(s.mesh, nx=10, ny=11),
                     time=dataclasses.replace(s.time, **t))


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "small.toml"
    path.write_text(small_scene().to_toml())
    return path


def invoke(*args, cwd=None):
    runner = CliRunner()
    return runner.invoke(main, [str(a) for a in args], catch_exceptions=False)


def leftovers(folder: Path):
    return sorted(p.name for p in folder.rglob("*") if p.suffix in (".h5", ".part", ".png")
                  or p.name.endswith(".h5.part"))


def write_quakeml(path: Path, origins, mags):
    from obspy import UTCDateTime
    from obspy.core.event import Catalog, Event, Magnitude, Origin

    cat = Catalog()
    for when, mag in zip(origins, mags):
        ev = Event(origins=[Origin(time=UTCDateTime(when), latitude=43.9, longitude=5.5)])
        if mag is not None:
            ev.magnitudes = [Magnitude(mag=mag, magnitude_type="Mw")]
        cat.append(ev)
    cat.write(str(path), format="QUAKEML")
    return path


# ---- help, version ------------------------------------------------------------------------
@pytest.mark.parametrize("cmd", [[], ["run"], ["replay"], ["plot"]])
def test_help_and_version_on_every_command(cmd):
    r = invoke(*cmd, "--help")
    assert r.exit_code == 0, r.output
    assert "Usage:" in r.output
    r = invoke(*cmd, "--version")
    assert r.exit_code == 0
    assert fault_screen.__version__ in r.output


def test_help_lists_the_commands_and_exit_codes():
    r = invoke("--help")
    for word in ("run", "replay", "plot", "Exit codes"):
        assert word in r.output
    r = invoke("replay", "--help")
    for opt in ("--log", "--out", "--plot", "--events", "--flow-unit", "--pressure-unit",
                "--max-gap", "--policy", "--end", "--t0"):
        assert opt in r.output


# ---- run ----------------------------------------------------------------------------------
def test_run_small_scene_writes_result_figures_and_summary(tmp_path, scene_file):
    out = tmp_path / "r.h5"
    figs = tmp_path / "figs"
    r = invoke("run", scene_file, "--out", out, "--plot", figs)
    assert r.exit_code == 0, r.output
    assert out.is_file() and not out.with_name("r.h5.part").exists()
    for key in ("peak injection overpressure", "MPa", "peak slip", "mm", "injected volume",
                " L", "wall time", str(out)):
        assert key in r.output
    # not a terminal: plain progress lines, the last at 100 %
    assert "100%" in r.output and "\r" not in r.output
    pngs = sorted(figs.glob("*.png"))
    assert [p.name for p in pngs] == ["r-injection-point.png", "r-screening.png", "r-space-time.png"]
    assert all(p.read_bytes()[:8] == PNG_MAGIC for p in pngs)
    with h5py.File(out, "r") as h5:
        meta = json.loads(h5.attrs["meta"])
        assert h5["time"][-1] == pytest.approx(60.0)
        vol = h5["injection/volume"][-1]
    assert meta["version"] == fault_screen.__version__
    assert meta["wall_time"] > 0
    assert meta["command"] == "run"
    # stand-in schedule: 10 L/min over 60 s = 10 L
    assert vol == pytest.approx(10e-3, rel=1e-9)


def test_run_default_bundled_scene(tmp_path, monkeypatch):
    """Without SCENE, run runs the paper-units calibrated Rustrel scene, which reproduces the
    paper's behaviour: the fault comes near failure and the screening turns yellow at 705 s (the
    step that raises the rate to 48 L/min at 700 s, within one 5 s step); the SI reading stays
    green. The summary names the reading of the paper's units, and the volume is in litres."""
    import re

    monkeypatch.chdir(tmp_path)
    r = invoke("run", "--quiet")
    assert r.exit_code == 0, r.output
    out = tmp_path / "rustrel-2015-calibrated-paper-units.h5"
    assert out.is_file()
    assert "%  step" not in r.output    # --quiet: no progress (the summary has a % budget)
    res = fault_screen.Result.load(out)
    assert res.time[-1] == pytest.approx(1400.0)
    assert res.injection["volume"][-1] * 1e3 == pytest.approx(938.0, rel=1e-3)
    assert "verdict: YELLOW" in r.output
    reached = float(re.search(r"reached at\s+t = ([0-9.]+) s", r.output).group(1))
    assert reached == pytest.approx(705.0, abs=5.0)
    assert "rule                         near failure" in r.output
    assert re.search(r"paper's units\s+k_f read as a mobility k/mu in m2/\(Pa s\)", r.output)
    assert re.search(r"injected volume\s+938\.3 L\n", r.output)


def test_run_failure_exit_1_without_result_or_figures(tmp_path, scene_file, monkeypatch):
    # the first step is taken and streamed to the result file; the second fails
    real = fault_screen.Simulation.advance
    calls = []

    def failing(self, t_next, **kw):
        if calls:
            raise SimulationError("step at t = 7 s failed after 8 cuts")
        calls.append(t_next)
        return real(self, t_next, **kw)

    monkeypatch.setattr(fault_screen.Simulation, "advance", failing)
    out, figs = tmp_path / "r.h5", tmp_path / "figs"
    r = invoke("run", scene_file, "--out", out, "--plot", figs)
    assert r.exit_code == 1
    assert "Error: simulation failed: step at t = 7 s failed" in r.output
    assert "Traceback" not in r.output
    assert not out.exists() and not figs.exists()
    assert leftovers(tmp_path) == []


def test_run_output_directory_missing_fails_before_running(tmp_path, scene_file):
    r = invoke("run", scene_file, "--out", tmp_path / "nowhere" / "r.h5")
    assert r.exit_code == 2
    assert "Error: --out" in r.output and "does not exist" in r.output
    assert "running" not in r.output


# ---- replay -------------------------------------------------------------------------------
def test_replay_volume_equals_log_volume(tmp_path):
    # irregular samples; the scene's steps (4.3 s) never land on a sample
    times = [0.0, 3.5, 11.2, 19.0, 26.4, 37.9, 45.0, 52.3, 61.7]
    lpm = [0.0, 12.0, 12.5, 30.0, 31.0, 30.0, 45.5, 20.0, 0.0]
    log = tmp_path / "elapsed.csv"
    log.write_text("# test log\nelapsed[s],flow_rate[L/min],pressure[MPa]\n" + "".join(
        f"{t},{q},{2.8 + 0.01 * i}\n" for i, (t, q) in enumerate(zip(times, lpm))))
    # trapezoids by hand (L/min * s / 60 = L):
    # 3.5*6 + 7.7*12.25 + 7.8*21.25 + 7.4*30.5 + 11.5*30.5 + 7.1*37.75 + 7.3*32.75 + 9.4*10
    litres = (21.0 + 94.325 + 165.75 + 225.7 + 350.75 + 268.025 + 239.075 + 94.0) / 60.0
    assert litres == pytest.approx(np.trapezoid(lpm, times) / 60.0, rel=1e-12)
    scene = tmp_path / "s.toml"
    scene.write_text(small_scene(end=1400.0, dt=4.3).to_toml())
    steps = np.arange(0, 61.7, 4.3)
    assert not np.any(np.isclose(steps[:, None], np.array(times)[None, 1:], atol=1e-3))
    out = tmp_path / "replay.h5"
    r = invoke("replay", scene, "--log", log, "--out", out)
    assert r.exit_code == 0, r.output
    with h5py.File(out, "r") as h5:
        vol = h5["injection/volume"][-1]
        t = h5["time"][()]
        used_t, used_q = h5["log/time"][()], h5["log/flow_rate"][()]
        used_p = h5["log/pressure"][()]
        meta = json.loads(h5.attrs["meta"])
    assert vol * 1e3 == pytest.approx(litres, rel=1e-3)
    assert vol * 1e3 == pytest.approx(litres, rel=1e-9)      # in fact exact
    assert t[-1] == pytest.approx(61.7)                      # end = log duration
    assert not np.any(np.isclose(np.diff(t)[:-1], np.diff(times)[0]))
    np.testing.assert_allclose(used_t, times)
    np.testing.assert_allclose(used_q, np.array(lpm) / 60e3)
    np.testing.assert_allclose(used_p, 2.8e6 + 1e4 * np.arange(len(times)))
    assert meta["log_start"] is None                          # elapsed log
    assert meta["log_volume"] * 1e3 == pytest.approx(litres, rel=1e-12)
    assert meta["command"] == "replay" and meta["log_file"] == str(log)


def test_replay_iso_log_with_events_and_plot(tmp_path, scene_file):
    start = datetime(2015, 3, 12, 10, 0, 0, tzinfo=CET)
    rows = [(0, 0.0), (5, 10.0), (17, 10.2), (30, 22.0), (44, 21.8), (50, 0.0)]
    log = tmp_path / "iso.csv"
    log.write_text("time,flow_rate[L/min]\n" + "".join(
        f"{(start + timedelta(seconds=s)).isoformat()},{q}\n" for s, q in rows))
    # events given in UTC: 09:00:12Z = 12 s after 10:00:00+01:00
    quakeml = write_quakeml(tmp_path / "events.xml",
                            ["2015-03-12T09:00:12Z", "2015-03-12T09:00:40.5Z", "2015-03-12T09:05:00Z"],
                            [-1.2, -0.4, 0.3])
    out, figs = tmp_path / "iso.h5", tmp_path / "figs"
    r = invoke("replay", scene_file, "--log", log, "--events", quakeml, "--plot", figs,
               "--out", out)
    assert r.exit_code == 0, r.output
    assert "seismic events" in r.output and "3 read, 2 within the run" in r.output
    res = fault_screen.Result.load(out)
    assert res.time[-1] == pytest.approx(50.0)
    assert datetime.fromisoformat(res.meta["log_start"]) == start
    assert datetime.fromisoformat(res.meta["start"]) == start
    np.testing.assert_allclose(res.extra["events"]["time"], [12.0, 40.5, 300.0], atol=1e-6)
    np.testing.assert_allclose(res.extra["events"]["magnitude"], [-1.2, -0.4, 0.3])
    assert len(list(figs.glob("*.png"))) == 3
    # the stored start is the reference of `plot --events`
    r = invoke("plot", out, "--out-dir", tmp_path / "again", "--events", quakeml)
    assert r.exit_code == 0, r.output
    assert len(list((tmp_path / "again").glob("iso-*.png"))) == 3


def test_replay_policy_skip_warns_and_end_option(tmp_path, scene_file):
    log = ROOT / "configs" / "logs" / "standin-with-gaps.csv"
    out = tmp_path / "gaps.h5"
    r = invoke("replay", scene_file, "--log", log, "--policy", "skip", "--end", 100, "--out", out)
    assert r.exit_code == 0, r.output
    assert "Warning: standin-with-gaps.csv line 21" in r.output
    res = fault_screen.Result.load(out)
    assert res.time[-1] == pytest.approx(100.0)
    assert len(res.meta["log_warnings"]) == 2
    # the stop policy refuses the same log at the duplicate stamp
    r = invoke("replay", scene_file, "--log", log, "--out", tmp_path / "stop.h5")
    assert r.exit_code == 2
    assert "line 21" in r.output and "duplicate time stamp" in r.output


LOG_HEAD = "elapsed[s],flow_rate[L/min]\n"
BAD_LOGS = {
    "gap": (LOG_HEAD + "0,10\n30,10\n730,10\n740,0\n", [], "line 4, column elapsed[s]: gap of 700 s"),
    "backwards": (LOG_HEAD + "0,10\n30,10\n20,10\n40,0\n", [], "line 4, column elapsed[s]: time going backwards"),
    "duplicate": (LOG_HEAD + "0,10\n30,10\n30,12\n40,0\n", [], "line 4, column elapsed[s]: duplicate time stamp"),
    "negative": (LOG_HEAD + "0,10\n30,-1\n40,0\n", [], "line 3, column flow_rate[L/min]: negative flow rate"),
    "non-numeric": (LOG_HEAD + "0,10\n30,abc\n40,0\n", [], "line 3, column flow_rate[L/min]: non-numeric value 'abc'"),
    "unknown header unit": ("elapsed[s],flow_rate[furlong/min]\n0,1\n10,1\n", [],
                            "line 1, column flow_rate[furlong/min]: unknown flow_rate unit 'furlong/min'"),
    "unknown unit option": ("elapsed[s],flow_rate\n0,1\n10,1\n", ["--flow-unit", "gal/fortnight"],
                            "--flow-unit 'gal/fortnight': unknown flow_rate unit"),
    "unknown pressure unit": (LOG_HEAD + "0,1\n10,1\n", ["--pressure-unit", "atmospheres"],
                              "--pressure-unit 'atmospheres': unknown pressure unit"),
    "no unit": ("elapsed[s],flow_rate\n0,1\n10,1\n", [], "column flow_rate: column needs a unit"),
    "zone-less stamp": ("time,flow_rate[L/min]\n2015-03-12T10:00:00,1\n2015-03-12T10:00:10,1\n", [],
                        "timestamp without time zone"),
}


@pytest.mark.parametrize("case", sorted(BAD_LOGS))
def test_replay_bad_log_exit_2_names_line_and_leaves_nothing(tmp_path, scene_file, case):
    text, extra, message = BAD_LOGS[case]
    log = tmp_path / "bad.csv"
    log.write_text(text)
    r = invoke("replay", scene_file, "--log", log, "--out", tmp_path / "bad.h5",
               "--plot", tmp_path / "figs", *extra)
    assert r.exit_code == 2, r.output
    assert f"Error: {message}" in r.output or ("Error: " in r.output and message in r.output)
    assert "bad.csv" in r.output or "--" in message
    assert "Traceback" not in r.output
    assert len([ln for ln in r.output.splitlines() if ln.startswith("Error:")]) == 1
    assert leftovers(tmp_path) == []
    assert not (tmp_path / "figs").exists()


def test_bad_gap_limit_option_is_usage_error(tmp_path, scene_file):
    log = tmp_path / "ok.csv"
    log.write_text(LOG_HEAD + "0,1\n10,1\n")
    r = invoke("replay", scene_file, "--log", log, "--max-gap", 0)
    assert r.exit_code == 2 and "Error: --max-gap 0.0: must be > 0" in r.output
    r = invoke("replay", scene_file, "--log", log, "--policy", "ignore")
    assert r.exit_code == 2 and "Invalid value for '--policy'" in r.output
    r = invoke("replay", scene_file)
    assert r.exit_code == 2 and "Missing option '--log'" in r.output


def test_missing_scene_file_exit_2(tmp_path):
    log = tmp_path / "ok.csv"
    log.write_text(LOG_HEAD + "0,1\n10,1\n")
    missing = tmp_path / "nope.toml"
    for args in (["run", missing], ["replay", missing, "--log", log]):
        r = invoke(*args, "--out", tmp_path / "x.h5")
        assert r.exit_code == 2
        assert f"Error: scene file not found: {missing}" in r.output
        assert "Traceback" not in r.output
    assert leftovers(tmp_path) == []


def test_missing_log_file_exit_2(tmp_path, scene_file):
    r = invoke("replay", scene_file, "--log", tmp_path / "nolog.csv", "--out", tmp_path / "x.h5")
    assert r.exit_code == 2
    assert "Error: file not found:" in r.output and "nolog.csv" in r.output
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("text, message", [
    ("[mesh]\nnx = 10\nfoo = 1\n", "unknown key mesh.foo = 1"),
    ("[time]\ndt = -1.0\n", "time.dt = -1.0"),
    ("[mesh\nnx = 1\n", "not valid TOML"),
])
def test_bad_scene_exit_2_names_file_and_key(tmp_path, text, message):
    scene = tmp_path / "bad.toml"
    scene.write_text(text)
    r = invoke("run", scene, "--out", tmp_path / "bad.h5")
    assert r.exit_code == 2
    line = [ln for ln in r.output.splitlines() if ln.startswith("Error:")]
    assert len(line) == 1 and message in line[0] and "bad.toml" in line[0]
    assert leftovers(tmp_path) == []


def test_replay_refuses_pressure_controlled_scene(tmp_path):
    s = small_scene()
    s = s.replace(injection=dataclasses.replace(s.injection, control="pressure",
                                                schedule=((0.0, 1e6),)))
    scene = tmp_path / "p.toml"
    scene.write_text(s.to_toml())
    log = tmp_path / "ok.csv"
    log.write_text(LOG_HEAD + "0,1\n10,1\n")
    r = invoke("replay", scene, "--log", log, "--out", tmp_path / "p.h5")
    assert r.exit_code == 2 and "injection.control = 'pressure'" in r.output


def test_bad_events_file_exit_2(tmp_path, scene_file):
    bad = tmp_path / "events.xml"
    bad.write_text("this is not QuakeML\n")
    r = invoke("run", scene_file, "--events", bad, "--out", tmp_path / "e.h5")
    assert r.exit_code == 2
    assert "Error:" in r.output and "events.xml" in r.output
    assert leftovers(tmp_path) == []
    r = invoke("run", scene_file, "--t0", "2015-03-12T10:00:00", "--out", tmp_path / "e.h5")
    assert r.exit_code == 2 and "without time zone" in r.output


# ---- plot ---------------------------------------------------------------------------------
def test_plot_command_writes_pngs(tmp_path, scene_file):
    out = tmp_path / "r.h5"
    assert invoke("run", scene_file, "--out", out, "--quiet").exit_code == 0
    # events relative to --t0 (run has no log start)
    t0 = "2015-03-12T10:00:00+01:00"
    quakeml = write_quakeml(tmp_path / "ev.xml", ["2015-03-12T09:00:20Z", "2015-03-12T09:00:33Z"],
                            [0.1, None])
    r = invoke("plot", out, "--out-dir", tmp_path / "figs", "--events", quakeml, "--t0", t0)
    assert r.exit_code == 0, r.output
    names = sorted(p.name for p in (tmp_path / "figs").glob("*.png"))
    assert names == ["r-injection-point.png", "r-screening.png", "r-space-time.png"]
    for n in names:
        data = (tmp_path / "figs" / n).read_bytes()
        assert data[:8] == PNG_MAGIC and len(data) > 10_000


def test_plot_bad_inputs_exit_2(tmp_path):
    r = invoke("plot", tmp_path / "none.h5")
    assert r.exit_code == 2 and "Error: file not found:" in r.output and "none.h5" in r.output
    junk = tmp_path / "junk.h5"
    junk.write_text("not hdf5")
    r = invoke("plot", junk, "--out-dir", tmp_path / "figs")
    assert r.exit_code == 2 and "Error:" in r.output and "junk.h5" in r.output
    assert "Traceback" not in r.output
    assert not (tmp_path / "figs").exists()


# ---- events -------------------------------------------------------------------------------
def test_read_events_relative_times_and_magnitudes(tmp_path):
    from fault_screen.io.events import read_events

    path = write_quakeml(tmp_path / "cat.xml",
                         ["2015-03-12T09:10:00.25Z", "2015-03-12T09:00:30Z", "2015-03-12T08:59:50Z"],
                         [0.5, None, -1.0])
    start = datetime(2015, 3, 12, 10, 0, 0, tzinfo=CET)       # = 09:00:00Z
    cat = read_events(path, start)
    np.testing.assert_allclose(cat.time, [-10.0, 30.0, 600.25], atol=1e-6)   # sorted by time
    assert cat.magnitude[0] == -1.0 and np.isnan(cat.magnitude[1]) and cat.magnitude[2] == 0.5
    assert cat.magnitude_type == ("Mw", "", "Mw")
    assert cat.origin_times()[1] == datetime(2015, 3, 12, 9, 0, 30, tzinfo=timezone.utc)
    assert len(cat.window(0.0, 100.0)) == 1
    # without a start: relative to the first event
    cat = read_events(path)
    np.testing.assert_allclose(cat.time, [0.0, 40.0, 610.25], atol=1e-6)
    assert cat.start == datetime(2015, 3, 12, 8, 59, 50, tzinfo=timezone.utc)


def test_read_events_errors(tmp_path):
    from fault_screen.io.events import EventsError, read_events

    with pytest.raises(FileNotFoundError):
        read_events(tmp_path / "missing.xml")
    bad = tmp_path / "bad.xml"
    bad.write_text("<xml>nothing</xml>")
    with pytest.raises(EventsError, match="bad.xml"):
        read_events(bad)


# ---- progress -----------------------------------------------------------------------------
class _Stream:
    def __init__(self, tty):
        self.text, self.tty = "", tty

    def write(self, s):
        self.text += s

    def flush(self):
        pass

    def isatty(self):
        return self.tty


def test_progress_plain_lines_every_ten_percent():
    s = _Stream(False)
    p = Progress(s)
    for k in range(1, 101):
        p(k, 14.0 * k, 1400.0, 0.01 * k)
    p.close()
    lines = s.text.splitlines()
    assert len(lines) == 10 and "\r" not in s.text
    assert lines[0].startswith(" 10%  step 10  t = 140 s of 1400 s")
    assert lines[-1].startswith("100%") and "left ~0.0 s" in lines[-1]


def test_progress_bar_on_a_terminal():
    s = _Stream(True)
    p = Progress(s, interval=0.0)
    p(1, 100.0, 1400.0, 5.0)            # the first step includes the set-up: no estimate yet
    assert s.text.startswith("\r[") and "step 1" in s.text and "left ~?" in s.text
    p(2, 700.0, 1400.0, 7.0)
    assert " 50.0%" in s.text and "step 2" in s.text
    assert "left ~2.3 s" in s.text and "wall 7.0 s" in s.text
    p(3, 1400.0, 1400.0, 9.0)
    assert s.text.endswith("\n") and "100.0%" in s.text


def test_scene_show_prints_the_resolved_scene_in_si(tmp_path):
    import tomllib

    from click.testing import CliRunner

    from fault_screen import Scene
    from fault_screen.cli import main

    path = tmp_path / "s.toml"
    path.write_text('[rock]\n"youngs_modulus[GPa]" = 20.0\n')
    res = CliRunner().invoke(main, ["scene", "show", str(path)])
    assert res.exit_code == 0, res.output
    shown = tomllib.loads(res.output)
    assert shown["rock"]["youngs_modulus"] == 20e9          # converted to SI
    assert shown["fault"]["friction"] == Scene().fault.friction  # defaults included
    assert Scene.from_dict(shown) == Scene.from_toml(path)


def test_scene_check_reports_unknowns_and_refuses_bad_scenes(tmp_path):
    from click.testing import CliRunner

    from fault_screen.cli import main

    runner = CliRunner()
    good = tmp_path / "good.toml"
    good.write_text("[mesh]\nnx = 10\nny = 11\nfault_grading = \"off\"\n")  # the mesh as given
    res = runner.invoke(main, ["scene", "check", str(good)])
    assert res.exit_code == 0 and "unknowns" in res.output
    # 11 x 12 nodes: u 264, a 2 x 22, p 132, c 22
    assert "u 264, a 44, p 132, c 22" in res.output
    bad = tmp_path / "bad.toml"
    bad.write_text("[injection]\nposition = 500.0\n")
    res = runner.invoke(main, ["scene", "check", str(bad)])
    assert res.exit_code == 2 and "injection.position = 500.0" in res.output


# ---- one vocabulary ---------------------------------------------------------------------------
FOLDER_COMMANDS = ("plot", "accuracy", "calibrate", "sensitivity", "ensemble")
FILE_COMMANDS = ("run", "replay", "screen", "monitor")


@pytest.mark.parametrize("command", FOLDER_COMMANDS + FILE_COMMANDS)
def test_out_is_a_file_and_out_dir_a_folder_on_every_command(command):
    """--out names a file (metavar RESULT.h5 / NEW.h5) wherever it is shown; the commands that
    write a folder show --out-dir DIR and hide the old --out."""
    from fault_screen.cli import main as group

    cmd = group.get_command(None, command)
    shown = {opt: p for p in cmd.params if isinstance(p, click.Option) and not p.hidden
             for opt in p.opts}
    if command in FOLDER_COMMANDS:
        assert shown["--out-dir"].metavar == "DIR" and "--out" not in shown
        hidden = [p for p in cmd.params if "--out" in getattr(p, "opts", ()) and p.hidden]
        assert len(hidden) == 1
    else:
        assert "--out-dir" not in shown
        assert shown["--out"].metavar.endswith(".h5") and isinstance(shown["--out"].type, click.Path)
        assert shown["--out"].type.dir_okay is False


def test_plot_out_dir_and_the_old_spelling_with_a_warning(tmp_path, scene_file):
    out = tmp_path / "r.h5"
    assert invoke("run", scene_file, "--out", out, "--quiet").exit_code == 0
    r = invoke("plot", out, "--out-dir", tmp_path / "new")
    assert r.exit_code == 0, r.output
    assert len(list((tmp_path / "new").glob("*.png"))) == 3
    r = invoke("plot", out, "--out", tmp_path / "old")
    assert r.exit_code == 0, r.output
    assert len(list((tmp_path / "old").glob("*.png"))) == 3
    assert "Warning: --out" in r.stderr and "now --out-dir" in r.stderr
    r = invoke("plot", out, "--out", tmp_path / "a", "--out-dir", tmp_path / "b")
    assert r.exit_code == 2 and "give --out-dir only" in r.stderr


@pytest.mark.parametrize("command", ["run", "replay", "accuracy", "calibrate", "sensitivity",
                                     "ensemble"])
def test_every_command_that_takes_a_scene_has_set(command):
    from fault_screen.cli import main as group

    (opt,) = [p for p in group.get_command(None, command).params if "--set" in getattr(p, "opts", ())]
    assert opt.multiple and opt.metavar == "KEY=VALUE"


def test_run_set_changes_the_scene(tmp_path, scene_file):
    """--set time.end=21 on a scene of 60 s in 7 s steps: the run ends at 21 s after 3 steps,
    and the result's scene holds the value; a key that does not exist is bad input (exit 2)."""
    out = tmp_path / "r.h5"
    r = invoke("run", scene_file, "--out", out, "--quiet", "--set", "time.end=21")
    assert r.exit_code == 0, r.output
    res = fault_screen.Result.load(out)
    assert res.time[-1] == pytest.approx(21.0, abs=1e-12)
    assert len(res.time) - 1 == 3
    assert res.scene.time.end == 21.0
    r = invoke("run", scene_file, "--out", tmp_path / "x.h5", "--set", "time.no_such_key=1")
    assert r.exit_code == 2 and "no_such_key" in r.stderr


def test_documented_exit_codes_and_synopsis_match_the_code():
    """The exit codes --help documents are exactly those the code raises (0 to 4), with the
    meanings the constants name; the synopsis of --help names every command."""
    import re

    from fault_screen.cli import _options, main as group

    text = invoke("--help").output
    block = " ".join(text[text.index("Exit codes:") + 11:text.index("Options:")].split())
    documented = {int(c): m for c, m in re.findall(r"(\d) ([^,]+)", block.rstrip("."))}
    assert set(documented) == {0, 1, 2, 3, 4}
    codes = {_options.EXIT_OK: "success", _options.EXIT_FAILURE: "run failed",
             _options.EXIT_BAD_INPUT: "bad usage", _options.EXIT_UNSTABLE: "unstable",
             _options.EXIT_LEVEL_REACHED: "--fail-on"}
    assert sorted(codes) == [0, 1, 2, 3, 4]
    for code, word in codes.items():
        assert word in documented[code], (code, documented[code])
    assert _options.BadInput.exit_code == 2 and _options.RunFailed.exit_code == 1
    # the module docstring that decides them lists the same five
    assert re.findall(r"^\* (\d) --", _options.__doc__, flags=re.M) == ["0", "1", "2", "3", "4"]
    synopsis = text[:text.index("Exit codes:")]
    for name in group.list_commands(None):
        assert f"fault-screen {name} " in synopsis, name

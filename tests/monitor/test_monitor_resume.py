"""``fault-screen monitor`` with the real stepper on a coarse Rustrel scene: a run over a complete
log equals ``fault-screen replay`` of it (every array, ``/log`` and ``/screening`` included), the
result file it streams can be read while it runs, and a monitor killed with SIGKILL at a random
moment while the log is being written resumes from its last checkpoint (cutting the streamed file
back to it) to the very same arrays."""
from __future__ import annotations

import dataclasses
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import monitor_env
from fault_screen import Result, Scene
from fault_screen.scene import MonitorRule
from fault_screen.cli import main

ROOT = Path(__file__).resolve().parents[2]
STANDIN = ROOT / "configs" / "logs" / "rustrel-2015-standin.csv"
N_LINES = 70            # comment and header lines plus the first 65 samples (625 s)
GROUPS = ("fault", "injection", "balance", "solver")


@pytest.fixture(scope="module")
def case(tmp_path_factory, dist):
    """A coarse scene, a 600-s log and its replay (the reference of every monitor run)."""
    folder = tmp_path_factory.mktemp("case")
    s = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    # rules the 625-s log crosses (the injection overpressure reaches 45 kPa): alerts to compare
    rules = (MonitorRule(level="yellow", name="pressure up", when="injection_overpressure > 2e4",
                         hold=0.0, action="reduce rate"),
             MonitorRule(level="red", name="pressure high", when="injection_overpressure > 4e4",
                         hold=0.0, action="stop injection"))
    s = s.replace(mesh=dataclasses.replace(s.mesh, nx=10, ny=11),
                  time=dataclasses.replace(s.time, dt=7.0),
                  monitor=dataclasses.replace(s.monitor, rules=rules))
    scene = folder / "small.toml"
    scene.write_text(s.to_toml())
    log = folder / "log.csv"
    lines = STANDIN.read_bytes().splitlines(keepends=True)[:N_LINES]
    log.write_bytes(b"".join(lines))
    r = CliRunner().invoke(main, ["replay", str(scene), "--log", str(log), "--out",
                                  str(folder / "replay.h5"), "--quiet"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    return dict(scene=scene, lines=lines, replay=Result.load(folder / "replay.h5"))


def same_arrays(got: Result, want: Result):
    assert np.array_equal(got.time, want.time)
    assert np.array_equal(got.profile_time, want.profile_time)
    for group in GROUPS:
        assert getattr(got, group).keys() == getattr(want, group).keys(), group
        for key, arr in getattr(want, group).items():
            assert np.array_equal(getattr(got, group)[key], arr), (group, key)
    # the samples that drove the model: every one of the log, as replay stores them
    assert got.extra["log"].keys() == want.extra["log"].keys() == {"time", "flow_rate"}
    for key, arr in want.extra["log"].items():
        assert len(arr) == 65 and np.array_equal(got.extra["log"][key], arr), key
    if "screening" in want.extra:
        for key, arr in want.extra["screening"].items():
            nan = arr.dtype.kind == "f"       # missing event metrics are NaN in both
            assert np.array_equal(got.extra["screening"][key], arr, equal_nan=nan), key


def test_monitor_over_a_complete_log_equals_replay(case, tmp_path):
    log = tmp_path / "log.csv"
    log.write_bytes(b"".join(case["lines"]))
    r = CliRunner().invoke(main, ["monitor", str(case["scene"]), "--follow", str(log), "--out",
                                  str(tmp_path / "m.h5"), "--state", str(tmp_path / "s.h5"),
                                  "--idle-exit", "0.3", "--poll", "0.05", "--alert",
                                  f"jsonl:{tmp_path / 'alerts.jsonl'}"],
                           catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert "monitor stopped (no new sample for 0.3 s): 90 steps to t = 625 s from 65 samples; " \
           "level red, 2 alert(s)" in r.output
    got = Result.load(tmp_path / "m.h5")
    same_arrays(got, case["replay"])
    # the live alerts are the level changes of the replay's screening
    alerts = [json.loads(x) for x in (tmp_path / "alerts.jsonl").read_text().splitlines()]
    want = case["replay"].extra["screening"]["transitions"]
    assert [(a["model_time"], a["previous_level_code"], a["level_code"], a["rule"])
            for a in alerts] == [(float(t), int(f), int(to), r.decode())
                                 for t, f, to, r in want.tolist()]
    assert alerts[1]["action"] == "stop injection"
    assert alerts[1]["metrics"]["injection_overpressure"] > 4e4


def test_kill_9_while_following_then_resume_equals_replay(case, dist, tmp_path):
    live = tmp_path / "live.csv"
    live.write_bytes(b"")
    args = ["monitor", str(case["scene"]), "--follow", str(live), "--state", str(tmp_path / "s.h5"),
            "--out", str(tmp_path / "m.h5"), "--idle-exit", "60", "--poll", "0.02",
            "--checkpoint-every", "4", "--alert", f"jsonl:{tmp_path / 'alerts.jsonl'}", "--quiet"]
    proc = subprocess.Popen([sys.executable, "-c", "from fault_screen.cli import main; main()",
                             *args], env=monitor_env.pythonpath(dist), stderr=subprocess.PIPE)
    lines = case["lines"]
    rng = np.random.default_rng(time.time_ns() % 2**32)
    cut = int(rng.integers(25, N_LINES - 10))
    try:
        with open(live, "ab") as fh:
            for line in lines[:cut]:
                fh.write(line)
                fh.flush()
                time.sleep(0.005)
        deadline = time.monotonic() + 120
        while not (tmp_path / "s.h5").exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        # a reader opens the result file while the monitor writes it (HDF5 SWMR): what it sees
        # is the start of the replay, at least the rows of the first checkpoint (4 steps)
        seen = Result.load(tmp_path / "m.h5")
        n = len(seen.time)
        assert n >= 5 and np.array_equal(seen.time, case["replay"].time[:n])
        assert np.array_equal(seen.injection["overpressure"], case["replay"].injection["overpressure"][:n])
        assert np.array_equal(seen.fault["slip"], case["replay"].fault["slip"][:len(seen.fault["slip"])])
        time.sleep(float(rng.uniform(0.0, 0.3)))
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read().decode()[-3000:]
    with open(live, "ab") as fh:
        fh.write(b"".join(lines[cut:]))
    r = CliRunner().invoke(main, [*args[:-9], "--alert", f"jsonl:{tmp_path / 'alerts.jsonl'}",
                                  "--idle-exit", "0.3", "--poll", "0.05"],
                           catch_exceptions=False)
    assert r.exit_code == 0, r.output
    same_arrays(Result.load(tmp_path / "m.h5"), case["replay"])
    ids = [json.loads(x)["id"] for x in (tmp_path / "alerts.jsonl").read_text().splitlines()]
    assert len(set(ids)) == 2            # none lost, none under a second id


def test_monitor_out_never_destroys_an_earlier_result(case, tmp_path):
    """An existing --out is refused (exit 2, the file untouched) unless --overwrite; without
    --state the results stream to OUT.part and replace OUT only when complete."""
    out = tmp_path / "m.h5"
    out.write_bytes(b"an earlier result")
    log = tmp_path / "log.csv"
    log.write_bytes(b"".join(case["lines"]))
    args = ["monitor", str(case["scene"]), "--follow", str(log), "--out", str(out),
            "--idle-exit", "0.3", "--poll", "0.05"]
    r = CliRunner().invoke(main, args, catch_exceptions=False)
    assert r.exit_code == 2, r.output
    assert f"--out {out}: the file exists; give --overwrite" in r.output
    assert out.read_bytes() == b"an earlier result"
    r = CliRunner().invoke(main, args + ["--overwrite"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    same_arrays(Result.load(out), case["replay"])
    assert not out.with_name("m.h5.part").exists()

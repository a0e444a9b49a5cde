"""``fault-screen monitor`` with the real stepper on a coarse Rustrel scene: a run over a complete
log equals ``fault-screen replay`` of it, and a monitor killed with SIGKILL at a random moment
while the log is being written resumes from its last checkpoint to the very same arrays."""
from __future__ import annotations

import dataclasses
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
from fault_screen.cli import main

ROOT = Path(__file__).resolve().parents[1]
STANDIN = ROOT / "configs" / "logs" / "rustrel-2015-standin.csv"
N_LINES = 70            # comment and header lines plus the first 65 samples (625 s)
GROUPS = ("fault", "injection", "balance", "solver")


@pytest.fixture(scope="module")
def dist(tmp_path_factory):
    folder = tmp_path_factory.mktemp("dist")
    monitor_env.activate(folder)
    return folder


@pytest.fixture(scope="module")
def case(tmp_path_factory, dist):
    """A coarse scene, a 600-s log and its replay (the reference of every monitor run)."""
    folder = tmp_path_factory.mktemp("case")
    s = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    s = s.replace(mesh=dataclasses.replace(s.mesh, nx=10, ny=11),
                  time=dataclasses.replace(s.time, dt=7.0))
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
    for group in GROUPS:
        for key, arr in getattr(want, group).items():
            assert np.array_equal(getattr(got, group)[key], arr), (group, key)
    if "screening" in want.extra:
        for key, arr in want.extra["screening"].items():
            assert np.array_equal(got.extra["screening"][key], arr), ("screening", key)


def test_monitor_over_a_complete_log_equals_replay(case, tmp_path):
    log = tmp_path / "log.csv"
    log.write_bytes(b"".join(case["lines"]))
    r = CliRunner().invoke(main, ["monitor", str(case["scene"]), "--follow", str(log), "--out",
                                  str(tmp_path / "m.h5"), "--state", str(tmp_path / "s.h5"),
                                  "--idle-exit", "0.3", "--poll", "0.05"],
                           catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert "monitor stopped (no new sample for 0.3 s): 90 steps to t = 625 s from 65 samples" \
        in r.output
    same_arrays(Result.load(tmp_path / "m.h5"), case["replay"])


def test_kill_9_while_following_then_resume_equals_replay(case, dist, tmp_path):
    live = tmp_path / "live.csv"
    live.write_bytes(b"")
    args = ["monitor", str(case["scene"]), "--follow", str(live), "--state", str(tmp_path / "s.h5"),
            "--out", str(tmp_path / "m.h5"), "--idle-exit", "60", "--poll", "0.02",
            "--checkpoint-every", "4", "--quiet"]
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
        time.sleep(float(rng.uniform(0.0, 0.3)))
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read().decode()[-3000:]
    assert not (tmp_path / "m.h5").exists()
    with open(live, "ab") as fh:
        fh.write(b"".join(lines[cut:]))
    r = CliRunner().invoke(main, [*args[:-7], "--idle-exit", "0.3", "--poll", "0.05"],
                           catch_exceptions=False)
    assert r.exit_code == 0, r.output
    same_arrays(Result.load(tmp_path / "m.h5"), case["replay"])

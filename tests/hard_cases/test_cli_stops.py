"""End to end through the command line: an unstable fault exits with code 3 and keeps its
result; creep at rest is not reported as slip."""
import h5py
import numpy as np
from click.testing import CliRunner

from stability_cases import HARD, load
from fault_screen.cli import main
from fault_screen.cli._running import slip_split


def test_run_of_an_unstable_fault_exits_3_and_keeps_the_result(tmp_path):
    out = tmp_path / "vw.h5"
    r = CliRunner().invoke(main, ["run", str(HARD / "velocity-weakening.toml"), "--out", str(out), "--quiet"],
                           catch_exceptions=False)
    assert r.exit_code == 3, r.output
    assert "fault became unstable at t = " in r.output
    with h5py.File(out, "r") as h5:
        t = h5["time"][()]
        level = h5["screening/level"][()]
    assert 200.0 < t[-1] < 400.0      # stopped before the end (1400 s), results up to then saved
    assert level[-1] == 2


def test_creep_at_rest_is_not_reported_as_slip(tmp_path):
    """Rate-and-state fault, no injection: nothing slides, every point creeps imperceptibly."""
    scene = load("rate-and-state", fault__rate_parameter=0.0269, injection__schedule=[[0.0, 0.0]],
                 time__end=200.0)
    path = tmp_path / "rest.toml"
    path.write_text(scene.to_toml())
    out = tmp_path / "rest.h5"
    r = CliRunner().invoke(main, ["run", str(path), "--out", str(out), "--quiet"], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    assert "0 mm (no point slid)" in r.output
    from fault_screen import Result

    res = Result.load(out)
    slid, at_rest = slip_split(res)
    assert slid == 0.0 and 0.0 <= at_rest < 1e-9
    assert np.all(res.extra["screening"]["induced_slip"] == 0.0)

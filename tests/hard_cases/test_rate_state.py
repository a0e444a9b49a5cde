"""Rate-and-state friction: a from 1e-4 to 0.05, velocity weakening (a < b) stopping cleanly as
unstable, stick-slip cycling, and no creep counted as slip."""
import numpy as np
import pytest

from stability_cases import CASES, check_common, run_case

RATE_STATE = [n for n, c in CASES.items() if c.family == "rate-state"]


@pytest.mark.parametrize("name", RATE_STATE + ["stick-slip-cycling"])
def test_completes_finite_and_balanced(name):
    check_common(run_case(name))


def test_small_a_behaves_as_coulomb_with_a_log_rate_term():
    """a = 1e-4: friction while sliding is mu0 + a ln(V/V0) (the law in logarithms): with
    |ln(V/V0)| < 20, within 2e-3 of mu0 = 0.68; a = 0.05 strengthens more and slips less."""
    small = run_case("rate-state-a0.0001-b0").result
    large = run_case("rate-state-a0.05-b0").result
    sliding = small.fault["contact_state"] == 1
    assert sliding.any()
    assert np.all(np.abs(small.fault["friction"][sliding] - 0.68) < 2e-3)
    assert np.max(np.abs(large.fault["slip"])) < np.max(np.abs(small.fault["slip"]))


def test_velocity_weakening_stops_cleanly_as_unstable():
    run = run_case("velocity-weakening")
    r = run.result
    check_common(run, stopped="unstable")
    stop = r.meta["stopped"]
    assert stop["time"] == r.time[-1] < run.scene.time.end
    assert stop["message"].startswith(f"fault became unstable at t = {stop['time']:.6g} s")
    peak = np.max(np.abs(r.fault["slip_rate"]), axis=1)
    limit = run.scene.solver.unstable_slip_rate
    assert peak[-1] > limit and np.all(peak[:-1] <= limit)   # every result up to that moment
    assert stop["slip_rate"] == pytest.approx(peak[-1])
    # it accelerated into it: the slip rate grew by orders of magnitude over the last steps
    assert peak[-1] > 100 * peak[-10]
    # the steps followed the acceleration (half of Dc of slip per step at the peak rate)
    dc = run.scene.fault.critical_slip_distance
    assert np.all(r.solver["dt"][2:] * peak[1:-1] <= 0.5 * dc * 1.0001)


def test_unstable_result_saves_and_screens_red(tmp_path):
    from fault_screen import Result
    from fault_screen.screening import screen_result

    r = run_case("velocity-weakening").result
    out = screen_result(r)
    assert out.level[-1] == 2
    assert out.verdict.rule == "unstable"
    r.save(tmp_path / "unstable.h5")
    back = Result.load(tmp_path / "unstable.h5")
    assert back.meta["stopped"]["reason"] == "unstable"
    assert np.array_equal(back.time, r.time)


def test_stick_slip_cycling_runs_to_the_end_and_cycles():
    """The patch at the injection point goes stick -> slip -> stick three times."""
    r = run_case("stick-slip-cycling").result
    state = r.fault["contact_state"][:, np.argmin(np.abs(r.fault_x))]
    sliding = (state == 1).astype(int)
    starts = np.count_nonzero(np.diff(sliding) == 1)
    stops = np.count_nonzero(np.diff(sliding) == -1)
    assert starts >= 3 and stops >= 3

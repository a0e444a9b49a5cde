"""Long runs at default settings: the automatic profile rule, bounded reads of a result, the
size estimates. Long record streams are synthetic (rows recorded from one state), so the
counts are exact and the tests fast."""
import h5py
import numpy as np
import pytest

from fault_screen import Result, Scene
from fault_screen.outputs import AUTO_PROFILE_STEPS, automatic_profile_count, automatic_profile_due
from fault_screen.solver import fault_at_rest

TINY = {
    "mesh": {"nx": 4, "ny": 5, "lx": 50.0, "ly": 50.0},
    "initial": {"effective_stress": [-5.649e6, -3.351e6, 0.964e6], "pore_pressure": 2.764e6},
    "injection": {"number_of_fractures": 10, "schedule": [[0.0, 1e-3]]},
    "time": {"end": 100.0, "dt": 5.0},
}


def test_automatic_rule_counts():
    """Every row below 512, then one in 2 up to 1024, one in 4 up to 2048...: 512 + 256 per
    doubling of the run."""
    first = AUTO_PROFILE_STEPS
    assert first == 512
    kept = [k for k in range(8 * first) if automatic_profile_due(k)]
    assert kept[:first] == list(range(first))
    assert kept[first:first + 3] == [512, 514, 516]          # one in 2 from row 512
    assert [k for k in kept if 1024 <= k < 1040] == [1024, 1028, 1032, 1036]
    assert [k for k in kept if 2048 <= k < 2080] == [2048, 2056, 2064, 2072]
    assert len(kept) == first + 3 * first // 2 == 1280     # 512 + 256 x 3 doublings
    for rows in (1, 511, 512, 513, 1023, 1024, 1025, 3000, 111_709, 10**6):
        assert automatic_profile_count(rows) == sum(map(automatic_profile_due, range(rows))), rows
    # a year of 5-s steps keeps under 4,000 profiles
    assert automatic_profile_count(365 * 86400 // 5) == 3969


def _synthetic_stream(path, rows: int, marks=(), output=None):
    """A real Recorder streaming ``rows`` rows (the in-situ row included) to ``path``, the
    rows in ``marks`` marked as level changes; the flow rate row k is k (m3/s)."""
    from fault_screen.stepper import Simulation

    scene = Scene.from_dict({**TINY, **({"output": output} if output else {})})
    sim = Simulation(scene)
    sim.stream_to(path)
    rec = sim.recorder
    point = fault_at_rest(sim.disc, sim.x)
    for k in range(1, rows):
        rec.record(5.0 * k, sim.x, point, slip_rate=0.0, flow_rate=float(k), volume=0.0, leaked=0.0,
                   iterations=1, cuts=0, dt=5.0)
        if k in marks:
            rec.keep_profile()
    assert rec.rows == []
    sim.close_stream()
    return Result.load(path)


def test_streamed_long_run_keeps_the_series_whole_and_profiles_by_the_rule(tmp_path):
    rows = 3001
    marks = (701, 1501, 1502, 2999)       # all off the rule's grid (one in 2, then one in 4)
    got = _synthetic_stream(tmp_path / "r.h5", rows, marks)
    # the series: every row
    assert len(got.time) == rows
    assert np.array_equal(got.injection["flow_rate"], np.arange(rows, dtype=float))
    # the profiles: the rule's rows (the last, 3000, is on its grid) and the level changes
    want = sorted({k for k in range(rows) if automatic_profile_due(k)} | set(marks))
    assert len(want) == automatic_profile_count(rows) + 4 == 1148
    assert np.array_equal(got.profile_time, 5.0 * np.array(want))
    assert got.fault["slip"].shape[0] == 1148


def test_user_output_table_wins_over_the_automatic_rule(tmp_path):
    got = _synthetic_stream(tmp_path / "r.h5", 1200, output={"profile_every": 1})
    assert len(got.profile_time) == 1200               # every step, as asked
    got = _synthetic_stream(tmp_path / "s.h5", 1200, output={"profile_every": 100})
    assert np.array_equal(got.profile_time, 5.0 * np.r_[np.arange(0, 1200, 100), 1199])

"""Long runs at default settings: the automatic profile rule, bounded reads of a result, the
size estimates. Long record streams are synthetic (rows recorded from one state), so the
counts are exact and the tests fast."""
from pathlib import Path

import numpy as np
import pytest

from fault_screen import Result, Scene
from fault_screen.outputs import AUTO_PROFILE_STEPS, automatic_profile_count, automatic_profile_due
from fault_screen.solver import fault_at_rest

ROOT = Path(__file__).resolve().parents[2]
BASEL = ROOT.parent / "shared" / "data" / "basel-2006" / "basel-2006-injection-1min.csv"
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


def _synthetic_stream(path, rows: int, marks=(), output=None, flow=float):
    """A real Recorder streaming ``rows`` rows (the in-situ row included) to ``path``, the
    rows in ``marks`` marked as level changes; the flow rate of row k is ``flow(k)`` (m3/s)."""
    from fault_screen.stepper import Simulation

    scene = Scene.from_dict({**TINY, **({"output": output} if output else {})})
    sim = Simulation(scene)
    sim.stream_to(path)
    rec = sim.recorder
    point = fault_at_rest(sim.disc, sim.x)
    for k in range(1, rows):
        rec.record(5.0 * k, sim.x, point, slip_rate=0.0, flow_rate=flow(k), volume=0.0, leaked=0.0,
                   iterations=1, cuts=0, dt=5.0, theta=1.0)
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


def test_a_result_in_memory_keeps_every_profile():
    """The rule is for streamed results: in memory (fault_screen.simulate) every row is held
    anyway, and in-memory screening reads the profiles of every step."""
    from fault_screen.stepper import Simulation

    sim = Simulation(Scene.from_dict(TINY))
    point = fault_at_rest(sim.disc, sim.x)
    for k in range(1, 600):
        sim.recorder.record(5.0 * k, sim.x, point, slip_rate=0.0, flow_rate=0.0, volume=0.0,
                            leaked=0.0, iterations=1, cuts=0, dt=5.0, theta=1.0)
    res = sim.result()
    assert res.fault_time is None and res.fault["slip"].shape[0] == len(res.time) == 600


def test_user_output_table_wins_over_the_automatic_rule(tmp_path):
    got = _synthetic_stream(tmp_path / "r.h5", 1200, output={"profile_every": 1})
    assert len(got.profile_time) == 1200               # every step, as asked
    got = _synthetic_stream(tmp_path / "s.h5", 1200, output={"profile_every": 100})
    assert np.array_equal(got.profile_time, 5.0 * np.r_[np.arange(0, 1200, 100), 1199])


# ---------------------------------------------------------------------------------------------
# bounded reads
# ---------------------------------------------------------------------------------------------
def _spiky(k: int) -> float:
    """A slow wave with one spike (row 1234) and one dip (row 2345) a plot must not lose."""
    return {1234: 1e6, 2345: -1e6}.get(k, float(np.sin(k / 300.0)))


@pytest.fixture(scope="module")
def long_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("long") / "r.h5"
    _synthetic_stream(path, 3001, flow=_spiky)
    return path


def _brute_envelope(v: np.ndarray, size: int) -> np.ndarray:
    """First row, each bucket of ``size`` rows after it (the last row excluded): its min and
    max in the order they come, last row; one bucket at a time."""
    out = [v[0]]
    for r0 in range(1, len(v) - 1, size):
        b = v[r0:min(len(v) - 1, r0 + size)]
        i, j = int(np.argmin(b)), int(np.argmax(b))
        out += [b[i], b[j]] if i <= j else [b[j], b[i]]
    return np.array(out + [v[-1]])


@pytest.mark.parametrize("read_rows", [100, 7])      # 7: each 30-row bucket spans reads
def test_view_of_a_long_result_is_an_envelope_read_in_bounded_pieces(long_file, read_rows):
    from fault_screen.result import ResultFile

    full = Result.load(long_file)
    q = full.injection["flow_rate"]
    assert len(q) == 3001 and q[1234] == 1e6
    with ResultFile(long_file, read_rows=read_rows) as rf:
        view = rf.view(points=200, profiles=50)
        peak = rf.maximum("injection/flow_rate")
        assert rf.largest_read <= read_rows
    # 2,999 inner rows in buckets of 30: 100 buckets, two values each, and the first and last
    assert len(view.time) == 202
    assert np.array_equal(view.injection["flow_rate"], _brute_envelope(q, 30))
    assert np.array_equal(view.time, _brute_envelope(full.time, 30))
    assert view.injection["flow_rate"].max() == peak == 1e6
    assert view.injection["flow_rate"].min() == -1e6
    assert view.time[-1] == 15000.0 and view.injection["flow_rate"][-1] == q[-1]
    # the screening level is an envelope too; the profiles: 50 spread evenly, first and last
    assert len(view.profile_time) == 50 == view.fault["slip"].shape[0]
    assert view.profile_time[0] == 0.0 and view.profile_time[-1] == 15000.0
    assert np.all(np.isin(view.profile_time, full.profile_time))


def test_view_of_a_short_result_is_the_result(long_file):
    from fault_screen.result import ResultFile

    full = Result.load(long_file)
    with ResultFile(long_file, read_rows=500) as rf:
        view = rf.view(points=5000, profiles=5000)
        assert rf.largest_read <= 500
    assert np.array_equal(view.time, full.time)
    assert np.array_equal(view.profile_time, full.profile_time)
    for group in ("injection", "balance", "solver"):
        for k, v in getattr(full, group).items():
            assert np.array_equal(getattr(view, group)[k], v), (group, k)
    for k, v in full.fault.items():
        assert np.array_equal(view.fault[k], v), k


def test_view_without_profiles_has_the_series_of_the_full_view(long_file):
    """What ``run`` reads back for its summary without --plot: the same 202-value envelopes
    of every series and group, no fault profile (0 of 50), the fault's geometry."""
    from fault_screen.result import ResultFile

    with ResultFile(long_file, read_rows=100) as rf:
        full, bare = rf.view(points=200, profiles=50), rf.view(points=200, profiles=0)
    assert len(bare.time) == 202 and np.array_equal(bare.time, full.time)
    for group in ("injection", "balance", "solver"):
        assert getattr(bare, group).keys() == getattr(full, group).keys()
        for k, v in getattr(full, group).items():
            assert np.array_equal(getattr(bare, group)[k], v), (group, k)
    assert bare.extra.keys() == full.extra.keys()
    for g, arrays in full.extra.items():
        assert all(np.array_equal(bare.extra[g][k], v) for k, v in arrays.items()), g
    assert len(bare.profile_time) == 0 and len(full.profile_time) == 50
    assert bare.fault.keys() == full.fault.keys()
    assert all(v.shape == (0, full.fault_x.size) for v in bare.fault.values())
    assert np.array_equal(bare.fault_x, full.fault_x)


def test_profile_reductions_read_a_bounded_number_of_values(long_file):
    from fault_screen.result import ResultFile

    full = Result.load(long_file)
    n_x = full.fault["pressure"].shape[1]
    with ResultFile(long_file, read_rows=10 * n_x) as rf:
        got = rf.profile_reduce("pressure", np.abs)
        assert rf.largest_read <= 10
    assert np.array_equal(got, np.abs(full.fault["pressure"]).max(axis=0))


# ---------------------------------------------------------------------------------------------
# estimates
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("time, output", [
    ({"end": 100.0, "dt": 5.0}, None),                                   # 20 fixed steps
    ({"end": 400.0, "dt": 5.0, "growth": 1.3, "dt_max": 40.0}, None),    # growing, then 40 s
    ({"end": 100.0, "dt": 5.0}, {"profile_every": 3}),
])
def test_estimate_of_a_short_run_against_the_run(tmp_path, time, output):
    """Steps exact (no cuts), profiles exact but for the level changes (kept besides the
    rule); the file within 1.3x."""
    from fault_screen.api import run_streamed
    from fault_screen.run_estimate import estimate_run

    scene = Scene.from_dict({**TINY, "time": time, **({"output": output} if output else {})})
    est = estimate_run(scene)
    sim, screening = run_streamed(scene, tmp_path / "r.h5")
    sim.close_stream()
    got = Result.load(tmp_path / "r.h5")
    assert est.steps == len(got.time) - 1
    changes = len(screening.transitions)
    assert est.profiles <= len(got.profile_time) <= est.profiles + changes
    assert est.file_bytes / 1.3 <= (tmp_path / "r.h5").stat().st_size <= 1.3 * est.file_bytes


def test_estimate_of_the_basel_replay_and_its_advice():
    """The Basel 2006 log (6.4646 days) on the bundled calibrated scene: 111,708 steps of 5 s
    (the measured run's count). Kept every step's profile (profile_every = 1) the file was
    measured at 1.034 GB (its profiles at 0.56 of their raw size): the estimate (1.15 GB) is
    within 1.25x and advises thinning; by the automatic rule it is under 100 MB and gives no
    advice."""
    from fault_screen.run_estimate import estimate_run

    from fault_screen.io import read_injection_log
    from fault_screen.io.replay import plan_replay

    if not BASEL.exists():
        pytest.skip(f"{BASEL} is not beside the checkout")
    base = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    scene = plan_replay(base, read_injection_log(BASEL)).scene     # as replay plans it
    auto = estimate_run(scene, log_samples=9310)
    assert auto.steps == 111_708 and auto.profiles == 2486
    assert auto.file_bytes < 100e6
    assert not any(line.startswith("advice") for line in auto.lines())
    full = estimate_run(scene.replace(output=scene.output.__class__(profile_every=1)), log_samples=9310)
    assert 1.034e9 / 1.25 <= full.file_bytes <= 1.25 * 1.034e9
    assert any("profile_interval" in line for line in full.lines())
    # 5-s steps for 30 days: 518,400 steps of about 1.75 ms, 15 min, under the hour that earns
    # advice; for 150 days 76 min, and the advice to let the steps grow
    month = estimate_run(scene.replace(time=base.time.__class__(end=30 * 86400.0, dt=5.0)))
    assert 600 < month.wall_seconds < 3600 and not any("growth" in x for x in month.lines())
    months = estimate_run(scene.replace(time=base.time.__class__(end=150 * 86400.0, dt=5.0)))
    assert months.wall_seconds > 3600 and any("growth" in line for line in months.lines())


@pytest.mark.parametrize("name, within", [("rustrel-2015-calibrated", 0),
                                          ("hard-cases/fault-geometry", 0.05)])
def test_estimated_fault_points_are_the_models(name, within):
    """The profiles' width in the file estimate (four Gauss points per cut element): the built
    model's fault points, exactly for the bundled scene; within 5 % for a 45-degree fault moved
    off the nodes, whose cut elements may hold more (188 for 192)."""
    import warnings

    from fault_screen.discretisation import discretise
    from fault_screen.run_estimate import fault_points

    scene = Scene.from_toml(ROOT / "configs" / f"{name}.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        disc = discretise(scene)
    points = len(disc.fault_points.s)
    assert abs(fault_points(scene) - points) <= within * points


def test_summary_numbers_from_bounded_reads_are_the_whole_files(bundled_run, tmp_path):
    """The run summary's peak overpressure and slip split (points that slid, points that did
    not), read two profiles at a time, are those of the result loaded whole (the calibrated
    Rustrel run: no point slides, the others creep by 0.15 nm)."""
    from fault_screen.cli._running import slip_split
    from fault_screen.result import ResultFile

    path = bundled_run("rustrel-2015-calibrated").save(tmp_path / "r.h5")
    full = Result.load(path)
    n_x = full.fault["slip"].shape[1]
    with ResultFile(path, read_rows=2 * n_x) as rf:
        split = slip_split(rf)
        peak = rf.maximum("injection/overpressure")
        assert rf.largest_read <= 2 * n_x
    assert split == slip_split(full) and split[0] == 0.0 and split[1] > 1e-10
    assert peak == full.injection["overpressure"].max() > 1e5          # 0.15 MPa


# ---------------------------------------------------------------------------------------------
# `fault-screen screen` from bounded reads
# ---------------------------------------------------------------------------------------------
#: two pulses of injection; yellow above 4.5 MPa at the injection point, red above 5.2 MPa for
#: at least 10 s after, red for 5 s for a magnitude 2 event (at 32 s, counted at the step
#: ending at 35 s, row 7): the level changes eight times
SCREENED = {**TINY, "injection": {"number_of_fractures": 10, "schedule": [
    [0.0, 1e-3], [30.0, 0.0], [60.0, 1e-3], [80.0, 0.0]]},
    "time": {"end": 135.0, "dt": 5.0},
    "monitor": {"rules": [
        {"level": "red", "name": "pressure high", "when": "injection_overpressure > 5.2e6", "hold": 10.0},
        {"level": "red", "name": "felt event", "when": "event_magnitude >= 2", "hold": 5.0},
        {"level": "yellow", "name": "pressure up", "when": "injection_overpressure > 4.5e6", "hold": 0.0}]}}
EVENTS = {"time": np.array([32.0, 101.0]), "magnitude": np.array([2.5, 0.4])}


@pytest.fixture(scope="module")
def screened_results(tmp_path_factory):
    """The scene above run in memory (a profile every row: screen reads the metrics from the
    profiles) and streamed with a profile every 4th step (screen reads the stored metrics)."""
    import fault_screen
    from fault_screen.api import run_streamed

    d = tmp_path_factory.mktemp("screen")
    scene = Scene.from_dict(SCREENED)
    whole = fault_screen.simulate(scene)
    whole.extra["events"] = dict(EVENTS)
    whole.save(d / "every-profile.h5")
    sim, _ = run_streamed(scene.replace(output=scene.output.__class__(profile_every=4)), d / "thinned.h5")
    sim.close_stream(groups={"events": dict(EVENTS)})
    # stopped unstable between two output times (red from the next), and after the last one
    # (red at the last)
    for name, stopped in (("unstable", {"reason": "unstable", "time": 97.5}),
                          ("unstable-at-end", {"reason": "unstable", "time": 1000.0})):
        res = Result.load(d / "thinned.h5")
        res.meta["stopped"] = stopped
        res.save(d / f"{name}.h5")
    return d


def _whole_screen_output(path: Path, out: Path):
    """What `screen RESULT --out OUT` printed when it loaded the result whole, and the result it
    wrote (the screening of the whole result, kept in ``extra``)."""
    from fault_screen.cli._verdict import verdict_lines
    from fault_screen.screening import screen_result

    res = Result.load(path)
    sc = screen_result(res)
    lines = [f"screening {path}: {len(res.time)} output times, rules of {path} (its own scene)"]
    lines += [f"  {tr.describe()}" for tr in sc.transitions] or ["  level green throughout"]
    lines += [f"  written {out}"] + verdict_lines(sc)
    return "\n".join(lines) + "\n", res, sc


def _same(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind == "f" and b.dtype.kind == "f":
        return a.shape == b.shape and np.array_equal(a, b, equal_nan=True)
    return a.dtype == b.dtype and np.array_equal(a, b)


@pytest.mark.parametrize("name", ["every-profile", "thinned", "unstable", "unstable-at-end"])
@pytest.mark.parametrize("read_rows", [7, 7 * 16, 65536])
def test_screen_from_bounded_reads_prints_and_writes_what_the_whole_load_did(
        screened_results, tmp_path, monkeypatch, name, read_rows):
    """Blocks of 7 rows (the streamed file, one value a row; the in-memory one with 16 fault
    points at read_rows 7 * 16), of one row (read_rows 7 and 16 points), and the whole file in
    one block: the same text to the character, the same exit code (4, red reached; 3 after an
    unstable stop), and a
    written file equal array for array, NaN for NaN, to the whole result screened and saved."""
    from click.testing import CliRunner

    import fault_screen.result
    from fault_screen.cli import main

    path = screened_results / f"{name}.h5"
    out = tmp_path / "again.h5"
    want, res, sc = _whole_screen_output(path, out)
    changes = [int(np.searchsorted(res.time, tr.time)) for tr in sc.transitions]
    levels = [tr.to_level for tr in sc.transitions]
    # yellow from row 4 goes on into the second 7-row block, whose first row turns red
    if name == "unstable":                  # red for good from 100 s, row 20
        assert changes == [4, 7, 8, 9, 13, 15, 18, 20] and levels == [1, 2, 1, 0, 1, 2, 1, 2]
    elif name == "unstable-at-end":        # red at the last row, 135 s
        assert changes == [4, 7, 8, 9, 13, 15, 18, 26, 27] and levels == [1, 2, 1, 0, 1, 2, 1, 0, 2]
    else:
        assert changes == [4, 7, 8, 9, 13, 15, 18, 26] and levels == [1, 2, 1, 0, 1, 2, 1, 0]
    monkeypatch.setattr(fault_screen.result, "READ_ROWS", read_rows)
    r = CliRunner().invoke(main, ["screen", str(path), "--out", str(out), "--fail-on", "red"])
    assert r.exit_code == (3 if name.startswith("unstable") else 4), r.output
    assert r.stdout == want
    got = Result.load(out)
    assert got.scene == res.scene and got.meta == res.meta
    for group in ("injection", "balance", "solver"):
        for k, v in getattr(res, group).items():
            assert _same(getattr(got, group)[k], v), (group, k)
    for k, v in res.fault.items():
        assert _same(got.fault[k], v), k
    assert _same(got.time, res.time) and _same(got.profile_time, res.profile_time)
    assert sorted(got.extra) == sorted(res.extra)
    for g, arrays in res.extra.items():
        assert sorted(got.extra[g]) == sorted(arrays), g
        for k, v in arrays.items():
            assert _same(got.extra[g][k], v), (g, k)


def test_screen_file_reads_at_most_read_rows(screened_results):
    """The screening of the file read seven rows at a time: the level changes and verdict of the
    result loaded whole, no read above seven rows."""
    from fault_screen.result import ResultFile
    from fault_screen.screening import screen_file, screen_result

    path = screened_results / "thinned.h5"
    whole = screen_result(Result.load(path), store=False)
    with ResultFile(path, read_rows=7) as rf:
        got = screen_file(rf)
        assert rf.largest_read == 7
    # repr: every number to the last digit, NaN (no event distance) equal to NaN
    assert len(got.transitions) == 8
    assert repr(got.transitions) == repr(whole.transitions)
    assert repr(got.verdict) == repr(whole.verdict)


LONG_ROWS = 30_001


@pytest.fixture(scope="module")
def long_screened(screened_results):
    """The streamed result above grown to 30,001 output times (a 5-s step for 1.7 days): every
    series extended in place, block by block; the injection overpressure stored for the
    screening swings across both thresholds, one period every 10,000 rows."""
    import shutil

    import h5py

    path = screened_results / "long.h5"
    shutil.copy(screened_results / "thinned.h5", path)
    with h5py.File(path, "r+") as h5:
        n0 = h5["time"].shape[0]
        series = [f"{g}/{k}" for g in ("injection", "balance", "solver", "screening") for k in h5[g]
                  if h5[g][k].shape == (n0,)] + ["time"]
        for p in series:
            ds = h5[p]
            ds.resize(LONG_ROWS, axis=0)
            for i0 in range(n0, LONG_ROWS, 50_000):
                k = np.arange(i0, min(LONG_ROWS, i0 + 50_000))
                if p == "time":
                    ds[k[0]:k[-1] + 1] = 5.0 * k
                elif p == "screening/injection_overpressure":
                    ds[k[0]:k[-1] + 1] = 4.8e6 + 0.6e6 * np.sin(2 * np.pi * k / 10_000)
                else:
                    ds[k[0]:k[-1] + 1] = ds[n0 - 1]
    return path


def test_screen_of_a_long_result_holds_a_bounded_memory(long_screened, tmp_path, monkeypatch):
    """Loading the 30,001-row result whole takes over 6 MB (tracemalloc peak: ~36 series of
    240 kB); `screen --out` of it, read 256 rows at a time, stays below 1.5 MB, and finds the
    level changes of the first 28 rows (9, the last back to yellow) and four per period of the
    swings (yellow -> red above 5.2 MPa, back, green below 4.5 MPa, yellow): 21. (The rows are
    few to keep the test fast, the screener's rules being evaluated row by row; what the
    bounded reads hold does not grow with them.)"""
    import tracemalloc

    from click.testing import CliRunner

    import fault_screen.result
    from fault_screen.cli import main

    tracemalloc.start()
    try:
        Result.load(long_screened)
        whole = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        monkeypatch.setattr(fault_screen.result, "READ_ROWS", 256)
        out = tmp_path / "again.h5"
        r = CliRunner().invoke(main, ["screen", str(long_screened), "--out", str(out)])
        bounded = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert r.exit_code == 0, r.output
    assert f"{LONG_ROWS} output times" in r.output
    assert whole > 6e6 and bounded < 1.5e6, (whole, bounded)
    import h5py

    with h5py.File(out) as h5:
        assert h5["screening/level"].shape == (LONG_ROWS,) and len(h5["screening/transitions"]) == 21

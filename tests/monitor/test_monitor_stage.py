"""The monitor stage's data handling, driven through a fake stepper (tests/monitor_fakes.py):
steps never run ahead of the data, every step receives exactly a replay's volume, chunking and
restarts change nothing, alerts keep their ids."""
from __future__ import annotations

import dataclasses
import math
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest

from fault_screen import Scene
from fault_screen.io.injection_log import read_injection_log
from fault_screen.monitor import SeismicEvent, Site, Stage
from fault_screen.monitor.stage import SampleBuffer, alert_id
from monitor_fakes import V_FAIL, FakeSimulation, ThresholdScreener

ROOT = Path(__file__).resolve().parents[2]
LOG = ROOT / "configs" / "logs" / "rustrel-2015-standin.csv"


@pytest.fixture(scope="module")
def scene():
    s = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    return s.replace(time=dataclasses.replace(s.time, dt=7.0))


@pytest.fixture(scope="module")
def log():
    return read_injection_log(LOG)


def make_stage(scene, log, **kw):
    return Stage(scene, start=log.start, simulation=FakeSimulation(scene),
                 screener=ThresholdScreener(), **kw)


def run_in_chunks(stage, log, sizes):
    k = 0
    for n in sizes:
        stage.feed_samples(log.time[k:k + n], log.flow_rate[k:k + n])
        assert stage.time <= stage.last_sample_time            # never ahead of the data
        assert stage.last_sample_time - stage.time < stage.sim.dt   # but every whole step taken
        k += n
        if k >= log.time.size:
            break
    return stage


def step_volumes(stage):
    rows = stage.sim.rows
    return np.array([r["time"] for r in rows]), np.diff([r["volume"] for r in rows])


def test_sample_buffer_volumes_are_a_replays_bit_for_bit(log):
    buf = SampleBuffer()
    rng = np.random.default_rng(3)
    for t, q in zip(log.time, log.flow_rate):
        buf.append(float(t), float(q), None)
    a = np.sort(rng.uniform(0, log.duration, 200))
    b = np.minimum(a + rng.uniform(0, 40, 200), log.duration)
    got = np.array([buf.volume(x, y) for x, y in zip(a, b)])
    want = np.array([log.volume(x, y) for x, y in zip(a, b)])
    assert np.array_equal(got, want)
    with pytest.raises(ValueError, match="beyond the last sample"):
        buf.volume(0.0, log.duration + 1.0)


def test_steps_and_volumes_equal_a_replay_whatever_the_chunking(scene, log):
    dt = scene.time.dt
    n_whole = int(math.floor(log.duration / dt))
    t_replay = np.append(np.arange(n_whole + 1) * dt, log.duration)
    v_replay = log.step_volumes(t_replay)
    rng = np.random.default_rng(7)
    runs = {
        "one by one": [1] * log.time.size,
        "random chunks": list(rng.integers(1, 12, size=log.time.size)),
        "all at once": [log.time.size],
    }
    for name, sizes in runs.items():
        st = run_in_chunks(make_stage(scene, log), log, sizes)
        assert st.steps == n_whole, name
        st.finish()
        t, v = step_volumes(st)
        assert np.array_equal(t, t_replay), name
        assert np.array_equal(v, v_replay), name           # bit for bit
    # the total is the log's: 950.63 L (configs/logs/README.md)
    assert abs(v.sum() - 0.95063) < 5e-6


def test_levels_change_when_the_logged_volume_crosses_the_thresholds(scene, log):
    st = make_stage(scene, log)
    alerts = []
    for k in range(log.time.size):
        alerts += st.feed_samples(log.time[k], log.flow_rate[k]).alerts
    alerts += st.finish().alerts
    # fake fault: utilisation 0.5 + V / V_FAIL at the injection point -> yellow at V = 0.2 m3,
    # red at V = 0.25 m3; the first step end at which the log's volume passes each
    t_steps = np.array([r["time"] for r in st.sim.rows])
    vol = np.array([log.volume(0.0, t) for t in t_steps])
    t_yellow = t_steps[np.argmax(vol >= (0.9 - 0.5) * V_FAIL)]
    t_red = t_steps[np.argmax(vol >= (1.0 - 0.5) * V_FAIL)]
    assert [(a["previous_level"], a["level"], a["model_time"]) for a in alerts] == [
        ("green", "yellow", t_yellow), ("yellow", "red", t_red)]
    assert alerts[1]["action"] == "stop injection"
    assert alerts[1]["model_datetime"] == (log.start + timedelta(seconds=t_red)).isoformat()
    assert alerts[1]["metrics"]["max_utilisation"] >= 1.0
    assert st.level == 2
    # stable ids: another run computes the same ones; a different log origin changes them
    again = make_stage(scene, log)
    ids = [a["id"] for a in again.feed_samples(log.time, log.flow_rate).alerts]
    assert ids == [a["id"] for a in alerts] and len(set(ids)) == 2
    other = Stage(scene, start=log.start + timedelta(hours=1), simulation=FakeSimulation(scene),
                  screener=ThresholdScreener())
    assert other.run_key != st.run_key


def test_restart_from_a_checkpoint_equals_an_uninterrupted_run(scene, log, tmp_path):
    ref = make_stage(scene, log)
    ref.feed_samples(log.time, log.flow_rate)
    for cut in (1, 37, 100):
        st = make_stage(scene, log)
        got = []
        for k in range(cut):
            got += st.feed_samples(log.time[k], log.flow_rate[k]).alerts
        st.checkpoint(tmp_path / "state.h5")
        # a kill after more samples: those after the checkpoint are lost with the process
        st.feed_samples(log.time[cut:cut + 20], log.flow_rate[cut:cut + 20])
        back, _ = Stage.restore(tmp_path / "state.h5", simulation_class=FakeSimulation,
                              screener=ThresholdScreener())
        # the restarted source replays the log from its start: earlier samples are ignored
        for k in range(log.time.size):
            got += back.feed_samples(log.time[k], log.flow_rate[k]).alerts
        assert back.ignored == cut
        assert back.samples.count == log.time.size
        t, v = step_volumes(back)
        t_ref, v_ref = step_volumes(ref)
        assert np.array_equal(t, t_ref) and np.array_equal(v, v_ref), cut
        assert back.transitions == ref.transitions, cut
        assert [a["id"] for a in got] == [
            alert_id(ref.run_key, d["time"], d["previous"], d["level"], d["rule"])
            for d in ref.transitions], cut


def test_checkpoint_is_atomic(scene, log, tmp_path):
    st = make_stage(scene, log)
    st.feed_samples(log.time[:30], log.flow_rate[:30])
    path = tmp_path / "state.h5"
    st.checkpoint(path)
    before = path.read_bytes()
    st.feed_samples(log.time[30:60], log.flow_rate[30:60])

    def dies_while_writing(p):
        Path(p).write_bytes(b"half a file")
        raise KeyboardInterrupt
    st.sim.checkpoint = dies_while_writing
    with pytest.raises(KeyboardInterrupt):
        st.checkpoint(path)
    assert path.read_bytes() == before
    assert not list(tmp_path.glob("*.tmp"))
    back, _ = Stage.restore(path, simulation_class=FakeSimulation,
                              screener=ThresholdScreener())
    assert back.samples.count == 30


def test_samples_must_be_finite_and_non_negative(scene, log):
    st = make_stage(scene, log)
    with pytest.raises(ValueError, match="finite"):
        st.feed_samples([0.0, 1.0], [0.0, -1e-4])
    with pytest.raises(ValueError, match="same length"):
        st.feed_samples([0.0, 1.0], [0.0])
    cfg = scene.replace(injection=dataclasses.replace(scene.injection, control="pressure"))
    with pytest.raises(ValueError, match="control"):
        Stage(cfg, simulation=FakeSimulation(scene))


def test_events_enter_the_step_containing_them(scene, log):
    site = Site(latitude=43.9, longitude=5.5, depth=280.0, azimuth=90.0)
    st = make_stage(scene, log, site=site, event_window=600.0)
    # 0.01 deg north of the injection point and 100 m deeper: 1111.95 m and 100 m away
    north = math.radians(0.01) * 6_371_000.0
    ev = [SeismicEvent(time=30.0, magnitude=0.4, latitude=43.91, longitude=5.5, depth=380.0,
                       id="a"),
          SeismicEvent(time=33.0, magnitude=2.3, latitude=43.9, longitude=5.5, depth=280.0,
                       id="b"),
          SeismicEvent(time=300.0, magnitude=-0.5, id="c")]
    st.feed_events(ev)
    st.feed_events(ev[:1])                     # the same event again: counted once
    metrics = {}
    for k in range(log.time.size):
        upd = st.feed_samples(log.time[k], log.flow_rate[k])
        for row in [upd.state] if upd.state else []:
            metrics[row["time"]] = upd.metrics
        if st.time > 320:
            break
    # dt = 7 s: events at 30 s and 33 s fall in the step ending at 35 s
    m35 = metrics[35.0]
    assert m35["event_magnitude"] == 2.3
    assert m35["event_distance"] == pytest.approx(0.0, abs=1e-9)
    assert m35["event_rate"] == pytest.approx(2 / (600 / 3600))
    a = {d["id"]: d for d in st.associations}
    assert a["a"]["distance_injection"] == pytest.approx(math.hypot(north, 100.0), rel=1e-9)
    assert a["a"]["model_time"] == 35.0
    assert math.isnan(metrics[28.0]["event_magnitude"])
    # the level went red through the magnitude rule at 35 s
    assert st.transitions[0]["rule"] == "event_magnitude >= 2" and st.transitions[0]["time"] == 35.0


def test_dense_samples_let_the_model_take_its_own_longer_steps(tmp_path):
    """Samples every 5 s, a scene whose steps grow from 5 s by 1.5 up to 120 s: the stage takes
    the scene's steps (up to 24 samples each), each receiving the exact integral of the samples
    over it, never ahead of the data, screened at every step; the rows equal a replay's."""
    from fault_screen import Result
    from fault_screen.api import simulate

    s = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    scene = s.replace(mesh=dataclasses.replace(s.mesh, nx=10, ny=11),
                      time=dataclasses.replace(s.time, end=1500.0, dt=5.0, growth=1.5, dt_max=120.0))
    t = np.arange(0.0, 1500.0 + 1e-9, 5.0)
    q = np.where(t < 600.0, 2e-4, np.where(t < 1000.0, 4e-4, 1e-4))   # m3/s, two rate changes
    stage = Stage(scene, out=tmp_path / "m.h5")
    rng = np.random.default_rng(7)
    k = 0
    while k < t.size:
        n = int(rng.integers(1, 4))
        upd = stage.feed_samples(t[k:k + n], q[k:k + n])
        k = min(k + n, t.size)
        assert stage.time <= t[k - 1]                     # never ahead of the data
        assert upd.steps <= 1 or stage.sim.dt >= 5.0
    stage.close()
    got = Result.load(tmp_path / "m.h5")
    dt = got.solver["dt"][1:]
    assert dt.max() == 120.0 and np.count_nonzero(dt == 120.0) >= 8
    assert len(got.time) - 1 < t.size / 10                # far fewer steps than samples
    # each step received the samples' integral: trapezoid of the linear rate over the step
    def integral(a, b):
        grid = np.union1d(t[(t > a) & (t < b)], [a, b])
        return np.trapezoid(np.interp(grid, t, q), grid)
    want = np.cumsum([0.0] + [integral(a, b) for a, b in zip(got.time[:-1], got.time[1:])])
    assert np.allclose(got.injection["volume"], want, rtol=1e-12, atol=1e-15)
    # screened at every model step (and at t = 0)
    assert got.extra["screening"]["level"].shape == got.time.shape
    # a replay of the same samples takes the same steps to the same arrays
    every = SampleBuffer()
    for tk, qk in zip(t, q):
        every.append(float(tk), float(qk), None)
    ref = simulate(scene.replace(time=dataclasses.replace(scene.time, end=float(got.time[-1]))),
                   injected_volume=every.volume)
    assert np.array_equal(ref.time, got.time)
    assert np.array_equal(ref.fault["slip"], got.fault["slip"])


def _rules_stage(scene, log):
    """A stage screening with the scene's own rules (the one per-step path)."""
    return Stage(scene, start=log.start, simulation=FakeSimulation(scene))


def test_the_scenes_rules_resume_from_a_checkpoint_of_plain_data(scene, log, tmp_path):
    """The per-step screening (tracker and screener) checkpoints as numbers and strings and
    continues exactly: the same transitions, levels and verdict as an uninterrupted stage."""
    import json

    import h5py

    ref = _rules_stage(scene, log)
    ref.feed_samples(log.time, log.flow_rate)
    assert len(ref.transitions) >= 1          # the fake's fault reaches the scene's thresholds
    st = _rules_stage(scene, log)
    st.feed_samples(log.time[:40], log.flow_rate[:40])
    st.checkpoint(tmp_path / "state.h5")
    with h5py.File(tmp_path / "state.h5", "r") as h5:
        record = json.loads(h5.attrs["fault_screen_monitor"])

    def leaves(v):
        if isinstance(v, dict):
            assert all(isinstance(k, str) for k in v)
            for x in v.values():
                yield from leaves(x)
        elif isinstance(v, list):
            for x in v:
                yield from leaves(x)
        else:
            yield v
    assert all(v is None or isinstance(v, (int, float, str, bool)) for v in leaves(record))
    text = json.dumps(record)
    assert "pickle" not in text and "fault_screen." not in text    # no code, no import paths
    back, _ = Stage.restore(tmp_path / "state.h5", simulation_class=FakeSimulation)
    back.feed_samples(log.time, log.flow_rate)
    assert back.transitions == ref.transitions
    # as JSON: equal NaN metrics compare equal
    assert json.dumps(back.screening.state()) == json.dumps(ref.screening.state())


def test_a_crafted_state_file_never_runs_code(scene, log, tmp_path):
    """A state file whose record names a pickle or a class to import is refused with a
    ValueError; the payload (touching a file) never runs."""
    import base64
    import json
    import pickle

    import h5py

    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (Path.touch, (marker,))
    st = _rules_stage(scene, log)
    st.feed_samples(log.time[:20], log.flow_rate[:20])
    path = tmp_path / "state.h5"
    st.checkpoint(path)
    with h5py.File(path, "a") as h5:
        record = json.loads(h5.attrs["fault_screen_monitor"])
        record["screener"] = {"pickle": base64.b64encode(pickle.dumps(Payload())).decode()}
        record["metrics"] = {"class": "pathlib:Path.touch", "state": str(marker)}
        h5.attrs["fault_screen_monitor"] = json.dumps(record)
    with pytest.raises(ValueError, match="own screener"):
        Stage.restore(path, simulation_class=FakeSimulation)
    assert not marker.exists()
    with h5py.File(path, "a") as h5:       # a state of the old layout (with a pickle)
        record["version"], record["screener"], record["metrics"] = 1, None, None
        h5.attrs["fault_screen_monitor"] = json.dumps(record)
    with pytest.raises(ValueError, match="layout 1"):
        Stage.restore(path, simulation_class=FakeSimulation)
    assert not marker.exists()


def test_no_module_of_the_package_imports_pickle():
    """Checkpoints hold data only: nothing in the package can unpickle."""
    import ast

    found = []
    for path in (ROOT / "fault_screen").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            found += [f"{path.name}: {n}" for n in names if n.split(".")[0] in ("pickle", "dill", "marshal")]
    assert found == []

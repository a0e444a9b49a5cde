"""The theta ladder's next rung: its bulk factors made ahead in a thread beside the current rung's
steps (``CondensedSystem.factorise_ahead``, ``Simulation._next_rung``). The results never depend
on the prediction: the factors made ahead equal those made in place bit for bit, a wrong guess
is dropped, and no thread outlives a run."""

import dataclasses
import threading

import numpy as np
import pytest

from conftest import CONFIGS
from fault_screen import Scene, Simulation
import fault_screen.linear_system as ls
import fault_screen.stepper as stepper
from fault_screen.solver import NewtonSolver, StepFailed

THREAD = "fault_screen rung ahead"


def _ladder_scene(**time):
    """The calibrated Rustrel scene, coarse, steps growing by 1.1 from 2 s, theta_min 2/3: rungs
    of 3-5 steps."""
    s = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    changes = dict(end=300.0, dt=2.0, growth=1.1, dt_max=20.0, theta_min=2 / 3) | time
    return s.replace(mesh=dataclasses.replace(s.mesh, nx=20, ny=21),
                     time=dataclasses.replace(s.time, **changes))


def _arrays(obj, seen=None):
    """Every array an object holds (its attributes, in tuples and lists too), by path."""
    out = {}

    def walk(v, path):
        if isinstance(v, np.ndarray):
            out[path] = v
        elif isinstance(v, (tuple, list)):
            for i, w in enumerate(v):
                walk(w, f"{path}[{i}]")
        elif hasattr(v, "__dict__") and type(v).__module__.startswith("fault_screen"):
            for k, w in vars(v).items():
                walk(w, f"{path}.{k}")

    walk(obj, "lu")
    return out


def _series(sim):
    r = sim.result()
    return {"slip": r.fault["slip"], "pressure": r.fault["pressure"], "dt": r.solver["dt"],
            "theta": r.solver["theta"], "x": sim.x}


def _assert_equal_runs(a, b):
    for k in a:
        assert np.array_equal(a[k], b[k]), f"{k}: largest difference {np.max(np.abs(a[k] - b[k])):.3e}"


class _Counts:
    """Factors made ahead that were taken and dropped (``CondensedSystem._take_ahead``)."""

    def __init__(self, monkeypatch):
        self.taken = self.dropped = self.started = 0
        take, start = ls.CondensedSystem._take_ahead, ls._Ahead.__init__

        def counted_take(system, dt):
            had = system._ahead is not None
            made = take(system, dt)
            if had:
                self.taken += made is not None
                self.dropped += made is None
            return made

        def counted_start(ahead, dt, make):
            self.started += 1
            start(ahead, dt, make)

        monkeypatch.setattr(ls.CondensedSystem, "_take_ahead", counted_take)
        monkeypatch.setattr(ls._Ahead, "__init__", counted_start)


def _no_ahead(monkeypatch):
    monkeypatch.setattr(stepper.Simulation, "_next_rung", lambda self, *a: None)


@pytest.fixture(scope="module")
def reference():
    """The ladder scene run with the next rung's factors made in place (no thread)."""
    with pytest.MonkeyPatch.context() as mp:
        _no_ahead(mp)
        sim = Simulation(_ladder_scene())
        sim.advance(sim.scene.time.end)
    return _series(sim)


def _alive():
    return [t for t in threading.enumerate() if t.name == THREAD]


def test_the_factors_made_ahead_equal_those_made_in_place_bit_for_bit():
    scene = _ladder_scene()
    sim = Simulation(scene)
    sim.advance(scene.time.end, max_steps=6)   # (the fixed pattern made, factors at hand)
    system = sim.solver.system
    dt = 1.37 * system._factored_dt
    system.factorise_ahead(dt)
    assert system.making_ahead == dt
    ahead = system._take_ahead(dt)
    in_place = system._factorise_symmetric(dt)
    a, b = _arrays(ahead), _arrays(in_place)
    assert a.keys() == b.keys() and len(a) >= 3
    for k in a:
        assert a[k].shape == b[k].shape, k
        assert np.array_equal(a[k], b[k]), k
    assert not _alive()


def test_a_growing_run_takes_the_predicted_factors_and_equals_the_run_without(reference, monkeypatch):
    counts = _Counts(monkeypatch)
    sim = Simulation(_ladder_scene())
    sim.advance(sim.scene.time.end)
    _assert_equal_runs(_series(sim), reference)
    # the climb from 2 s to 20 s by 1.1 starts a rung every 4-5 steps; each one's successor
    # is predicted, and only the last (the plateau's rung, or past the end) is not taken
    assert counts.taken >= 4 and counts.dropped == 0
    assert counts.started == counts.taken
    assert not _alive()


def test_a_wrong_prediction_is_dropped_and_the_run_is_unchanged(reference, monkeypatch):
    counts = _Counts(monkeypatch)
    predict = stepper.Simulation._next_rung
    monkeypatch.setattr(stepper.Simulation, "_next_rung",
                        lambda self, *a: None if (p := predict(self, *a)) is None else 1.01 * p)
    sim = Simulation(_ladder_scene())
    sim.advance(sim.scene.time.end)
    _assert_equal_runs(_series(sim), reference)
    assert counts.started >= 4 and counts.taken == 0 and counts.dropped >= counts.started - 1
    assert not _alive()


def test_a_cut_drops_the_prediction_and_the_run_equals_the_cut_run_without(monkeypatch):
    """The first step whose next rung was predicted fails (each try): halved, it starts a rung
    at half its size, not the predicted one, so the factors made ahead are dropped; the run
    equals one that makes none and fails at the same step."""
    prepare = NewtonSolver._prepare
    target = []

    def failing(self, dt, x_n, history, rung=None):
        prepare(self, dt, x_n, history, rung)
        key = (dt, hash(x_n.tobytes()))
        if not target and self.system.making_ahead is not None:
            target.append(key)
        if target and key == target[0]:
            raise StepFailed("made to fail")

    monkeypatch.setattr(NewtonSolver, "_prepare", failing)
    runs = []
    for ahead in (True, False):
        with pytest.MonkeyPatch.context() as mp:
            counts = _Counts(mp)
            if not ahead:
                _no_ahead(mp)
            sim = Simulation(_ladder_scene(end=120.0))
            sim.advance(sim.scene.time.end)
        runs.append(_series(sim))
        assert target and np.count_nonzero(sim.result().solver["step_cuts"]) == 1
        if ahead:
            assert counts.dropped == 1 and counts.taken >= 1
        else:
            assert counts.started == 0
    _assert_equal_runs(*runs)
    assert not _alive()


def test_an_error_in_the_thread_reaches_the_caller_and_no_thread_is_left(monkeypatch):
    make = ls.CondensedSystem._factorise_symmetric

    def failing_in_the_thread(self, dt):
        if threading.current_thread().name == THREAD:
            raise FloatingPointError("made to fail in the thread")
        return make(self, dt)

    monkeypatch.setattr(ls.CondensedSystem, "_factorise_symmetric", failing_in_the_thread)
    sim = Simulation(_ladder_scene())
    with pytest.raises(FloatingPointError, match="made to fail in the thread"):
        sim.advance(sim.scene.time.end)
    assert not _alive()


def test_no_thread_is_left_after_a_run_that_ends_inside_a_rung(monkeypatch):
    counts = _Counts(monkeypatch)
    sim = Simulation(_ladder_scene())
    for _ in range(12):   # (one step a call: each call's end settles what it started)
        sim.advance(sim.scene.time.end, max_steps=1)
        assert not _alive() and sim.solver.system.making_ahead is None
    # one step a call: no step after this call's last to make factors for
    assert counts.started == 0


@pytest.mark.parametrize("what", ["no ladder", "fixed steps", "elastic bulk", "pressure control"])
def test_no_thread_where_it_cannot_help(what, monkeypatch):
    counts = _Counts(monkeypatch)
    if what == "no ladder":
        scene = _ladder_scene(theta_min=None, end=60.0)
    elif what == "fixed steps":
        scene = _ladder_scene(growth=1.0, end=30.0)
    elif what == "elastic bulk":
        s = Scene.from_toml(CONFIGS / "rustrel-2015-impermeable.toml")
        scene = s.replace(mesh=dataclasses.replace(s.mesh, nx=20, ny=21),
                          time=dataclasses.replace(s.time, end=60.0, dt=2.0, growth=1.1,
                                                   dt_max=20.0, theta_min=2 / 3))
    else:
        s = _ladder_scene(end=60.0)
        scene = s.replace(injection=dataclasses.replace(s.injection, control="pressure",
                                                             schedule=((0.0, 2e5),)))
    sim = Simulation(scene)
    sim.advance(scene.time.end)
    assert counts.started == 0


def _fork_and_checkpoint_in_observer(tmp_path, at_step):
    """The ladder run with a fork and a checkpoint made by the observer after step ``at_step``
    (inside ``advance``: the stepper's next size not yet set, so they continue from there as
    such), each taken to the end: (run, fork, restored run) series, and whether factors were
    in the making then."""
    made = {}

    def observer(t, x, disc):
        if sim.steps == at_step:
            made["ahead"] = sim.solver.system.making_ahead is not None
            made["fork"] = sim.fork()
            made["path"] = sim.checkpoint(tmp_path / f"state-{len(list(tmp_path.iterdir()))}.h5")

    sim = Simulation(_ladder_scene())
    sim.advance(sim.scene.time.end, observer=observer)
    twin = made["fork"]
    twin.advance(twin.scene.time.end)
    restored = Simulation.restore(made["path"])
    restored.advance(restored.scene.time.end)
    return [_series(s) for s in (sim, twin, restored)], made["ahead"]


def test_a_fork_and_a_checkpoint_while_the_thread_runs_equal_those_without(tmp_path, monkeypatch):
    """Made while the next rung's factors are in the making (the fork shares the fixed pattern
    and the symbolic analyses that thread reads): the run, the fork and the restored run equal
    those made the same way in a run without the thread."""
    at_step = 10
    with_thread, ahead = _fork_and_checkpoint_in_observer(tmp_path, at_step)
    assert ahead
    _no_ahead(monkeypatch)
    without, ahead = _fork_and_checkpoint_in_observer(tmp_path, at_step)
    assert not ahead
    for a, b in zip(with_thread, without):
        _assert_equal_runs(a, b)
    assert not _alive()


def test_the_factors_made_ahead_take_one_thread(reference, monkeypatch):
    """The thread beside the steps factorises in one thread (``ldl.one_thread``), where every
    other factorisation of the run takes two (THREADS_ABOVE lowered to 0): no third thread on
    two cores; the same run bit for bit."""
    import fault_screen.ldl as ldl

    monkeypatch.setattr(ldl, "THREADS_ABOVE", 0.0)
    seen, numeric = [], ldl._numeric

    def watched(*args, **kwargs):
        seen.append((threading.current_thread().name, getattr(ldl._in_this_thread, "one", False)))
        return numeric(*args, **kwargs)

    monkeypatch.setattr(ldl, "_numeric", watched)
    sim = Simulation(_ladder_scene())
    sim.advance(sim.scene.time.end)
    _assert_equal_runs(_series(sim), reference)
    ahead = [one for name, one in seen if name == THREAD]
    elsewhere = [one for name, one in seen if name != THREAD]
    assert len(ahead) >= 4 and all(ahead)
    assert elsewhere and not any(elsewhere)
    assert not _alive()

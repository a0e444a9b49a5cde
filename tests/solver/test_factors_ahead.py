"""The bulk's factors for the next step size made ahead, in a thread beside the current step
(``CondensedSystem.factorise_ahead``): taken only by a step at the size they were made for,
dropped by any other (a cut), bit for bit what factorising in place gives, no thread left once
the steps end (normally or by an exception), a failure in the thread raised by the step that
takes the factors, and no thread at all where no step size changes or the factors serve every
size (an elastic bulk)."""
import dataclasses
import threading

import numpy as np
import pytest

from fault_screen import Simulation
from fault_screen import linear_system as ls
from fault_screen.solver import StepFailed
from test_stepper import _assert_identical, hard_rustrel, poroelastic_growing

THREAD = "fault_screen factors ahead"


def _growing(end=150.0, **time):
    s = poroelastic_growing()
    return s.replace(time=dataclasses.replace(s.time, end=end, **time))


@pytest.fixture
def counted(monkeypatch):
    """Counts of the factors made ahead: started, taken by their step, dropped."""
    count = dict(started=0, taken=0, dropped=0)
    init, factors, discard = ls._Ahead.__init__, ls._Ahead.factors, ls._Ahead.discard

    def counting(name, fn):
        def wrapper(self, *args):
            count[name] += 1
            return fn(self, *args)
        return wrapper

    monkeypatch.setattr(ls._Ahead, "__init__", counting("started", init))
    monkeypatch.setattr(ls._Ahead, "factors", counting("taken", factors))
    monkeypatch.setattr(ls._Ahead, "discard", counting("dropped", discard))
    return count


def _in_place(monkeypatch):
    """Every step factorises its own size (no factors made ahead)."""
    monkeypatch.setattr(ls.CondensedSystem, "factorise_ahead", lambda self, dt: None)


def _run(scene, **advance):
    sim = Simulation(scene)
    sim.advance(scene.time.end, **advance)
    return sim


def _no_thread_left():
    return not any(t.name == THREAD and t.is_alive() for t in threading.enumerate())


def test_a_run_with_factors_made_ahead_equals_one_factorising_in_place(counted, monkeypatch):
    scene = _growing()
    ahead = _run(scene)
    # the steps grow from 2 s by 1.05 to 12 s: every step of the climb but the first takes the
    # factors the step before it made (36 sizes; the first is factorised in place, the last
    # size's steps need none)
    sizes = np.asarray(ahead.result().solver["dt"])[1:]
    changes = int(np.count_nonzero(sizes[1:] != sizes[:-1]))
    assert changes > 30
    assert counted == dict(started=changes, taken=changes, dropped=0)
    assert _no_thread_left()
    _in_place(monkeypatch)
    in_place = _run(scene)
    assert counted["started"] == changes   # (none in the second run)
    assert ahead.solver.factorizations == in_place.solver.factorizations
    _assert_identical(ahead.result(), in_place.result())


def _prepared(sim):
    """A run's system after a few steps (its fixed pattern made) and a fork of it, on which
    ``prepare`` at a new size factorises in place."""
    system = sim.solver.system
    assert not system.factors_any_dt and system._bulk is not None
    return system, system.fork()


def _assert_same_factors(system, fresh):
    """The same condensation and the same sweeps through the bulk's factors, bit for bit."""
    assert system.dt == fresh.dt
    assert np.array_equal(system.P, fresh.P)
    rng = np.random.default_rng(3)
    nB, nN = len(system.B), len(system.N)
    r_B, r_N = rng.standard_normal(nB), rng.standard_normal(nN)
    for a, b in zip(system.lu.forward(r_B, r_N), fresh.lu.forward(r_B, r_N)):
        assert np.array_equal(a, b)
    assert np.array_equal(system.lu.backward(None, r_N), fresh.lu.backward(None, r_N))


@pytest.mark.parametrize("taken", [True, False], ids=["at their size", "at another size"])
def test_factors_made_ahead_serve_only_their_own_size(counted, taken):
    sim = Simulation(_growing(end=20.0))
    sim.advance(20.0)
    system, fresh = _prepared(sim)
    before = dict(counted)
    made_for, next_size = system.dt * 1.5, system.dt * (1.5 if taken else 0.5)
    system.factorise_ahead(made_for)
    assert system._ahead.dt == made_for
    system.prepare(next_size, None)
    fresh.prepare(next_size, None)
    assert {k: counted[k] - before[k] for k in counted} == dict(
        started=1, taken=int(taken), dropped=int(not taken))
    assert system._ahead is None
    assert _no_thread_left()
    _assert_same_factors(system, fresh)
    # (and the factors made ahead differ from those of the other size: the comparison can fail)
    other = system.fork()
    other.prepare(made_for if not taken else system.dt * 0.5, None)
    assert not np.array_equal(other.P, system.P)


def test_a_cut_step_drops_the_factors_made_for_the_size_it_did_not_take(counted, monkeypatch):
    """A step that fails at its planned size is halved: the factors made ahead for the step
    after it (the planned size times the growth) are dropped when the halved size is prepared;
    the run equals the same run (the same cut) factorising in place."""
    scene = _growing(end=60.0)
    take = Simulation._step
    failed = []

    def step(self, dt, step_value):
        if self.steps == 10 and not failed:
            failed.append(dt)
            raise StepFailed("made to fail once")
        return take(self, dt, step_value)

    monkeypatch.setattr(Simulation, "_step", step)
    ahead = _run(scene)
    assert failed and np.asarray(ahead.result().solver["step_cuts"]).sum() == 1
    assert counted["dropped"] >= 1 and counted["taken"] > 10
    started = counted["started"]
    failed.clear()
    _in_place(monkeypatch)
    in_place = _run(scene)
    assert counted["started"] == started
    _assert_identical(ahead.result(), in_place.result())


def test_no_thread_outlives_the_steps_when_they_end_by_an_exception(counted):
    scene = _growing(end=60.0)
    sim = Simulation(scene)

    def progress(step, t, end, wall):
        if step == 5:
            raise KeyboardInterrupt   # (between steps, a thread making the next size's factors)

    with pytest.raises(KeyboardInterrupt):
        sim.advance(scene.time.end, progress=progress)
    assert counted["started"] >= 4 and counted["dropped"] == 1
    assert sim.solver.system._ahead is None and _no_thread_left()


def test_a_failure_making_factors_ahead_surfaces_on_the_step_that_takes_them(monkeypatch):
    make = ls.CondensedSystem._factorise_symmetric

    def failing(self, dt):
        if threading.current_thread().name == THREAD:
            raise ArithmeticError(f"no factors at {dt}")
        return make(self, dt)

    monkeypatch.setattr(ls.CondensedSystem, "_factorise_symmetric", failing)
    sim = Simulation(_growing(end=20.0))
    with pytest.raises(ArithmeticError, match="no factors at"):
        sim.advance(20.0)
    assert sim.steps == 1   # (the second step takes the first factors made ahead)
    assert _no_thread_left()
    # at another size the failure is dropped with the factors: that step factorises its own
    system, fresh = _prepared(sim)
    system.factorise_ahead(system.dt * 1.5)
    system.prepare(system.dt * 0.5, None)
    fresh.prepare(fresh.dt * 0.5, None)
    _assert_same_factors(system, fresh)


@pytest.mark.parametrize("scene", [
    lambda: _growing(end=40.0, growth=1.0),                       # one step size
    lambda: hard_rustrel().replace(time=dataclasses.replace(hard_rustrel().time, end=300.0)),
], ids=["fixed steps", "elastic bulk, growing steps"])
def test_no_thread_where_no_factors_are_needed_ahead(counted, scene):
    sim = _run(scene())
    assert sim.steps > 5
    assert counted == dict(started=0, taken=0, dropped=0)

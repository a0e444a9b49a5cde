"""Simulation.fork: a fork continues exactly as the run would, and advancing it never changes the
run it was forked from (that run then continues bit for bit as one that never forked)."""
import numpy as np
import pytest

from fault_screen import Simulation
from fault_screen.simulate import simulate
from test_stepper import CASES, _arrays, _assert_identical


@pytest.fixture(scope="module", params=list(CASES))
def case(request):
    scene = CASES[request.param]()
    return scene, simulate(scene)


def _assert_rows_from(result, reference, steps):
    """``result``'s rows are the uninterrupted run's rows from step ``steps`` on (every array)."""
    forked = _arrays(result)
    for k, ref in _arrays(reference).items():
        assert np.array_equal(forked[k], ref[steps:]), k


def test_a_fork_never_changes_the_original_and_takes_the_same_steps(case):
    scene, reference = case
    n = len(reference.time) - 1
    steps = n // 2
    sim = Simulation(scene)
    sim.advance(scene.time.end, max_steps=steps)
    x, history, dt, t = sim.x.copy(), None if sim.history is None else sim.history.copy(), sim.dt, sim.time
    fork = sim.fork()
    fork.advance(scene.time.end)
    # the original's state is untouched by the fork's steps
    assert np.array_equal(sim.x, x) and sim.dt == dt and sim.time == t and sim.steps == steps
    if history is not None:
        assert np.array_equal(sim.history, history)
    assert len(sim.result().time) == steps + 1
    # the fork's rows are the uninterrupted run's rows from the fork on (every array, exactly)
    _assert_rows_from(fork.result(), reference, steps)
    # a fork of a fork that has not stepped yet (a look-ahead's state) takes the same steps too
    twice = sim.fork().fork()
    twice.advance(scene.time.end)
    _assert_rows_from(twice.result(), reference, steps)
    # and the original continues bit-identically to a run that never forked
    sim.advance(scene.time.end)
    _assert_identical(sim.result(), reference)

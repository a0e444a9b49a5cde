"""Simulation.fork: a fork continues exactly as the run would, and advancing it never changes the
run it was forked from (that run then continues bit for bit as one that never forked)."""
import numpy as np
import pytest

from fault_screen import Simulation
from fault_screen.simulate import simulate
from test_stepper import CASES, _arrays, _assert_identical, poroelastic_growing


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


def test_a_fork_shares_the_factors_and_makes_its_own_for_other_steps(case):
    """The fork starts on the original's factorisations (the same objects: none is redone for
    the steps the original would take), and a fork whose steps are of other sizes (steps
    growing 1.5 times to 8 times the run's, which a bulk with rock pore pressure must factorise
    again) makes its own: the original then still continues bit-identically to a run that
    never forked."""
    import dataclasses

    scene, reference = case
    steps = (len(reference.time) - 1) // 2
    sim = Simulation(scene)
    sim.advance(scene.time.end, max_steps=steps)
    system = sim.solver.system
    lu, P, made = system.lu, system.P, sim.solver.factorizations
    fork = sim.fork()
    assert fork.solver.system.lu is lu and fork.solver.system.P is P
    fork.advance(sim.time + 3 * sim.dt, max_steps=1)          # a step of the run's own size
    if system.factors_any_dt or system.dt == sim.dt:
        assert fork.solver.factorizations == made               # the shared factors served
    longer = sim.fork()
    dt = sim.dt
    longer.scene = scene.replace(time=dataclasses.replace(scene.time, growth=1.5, dt_max=8 * dt))
    longer.advance(scene.time.end)
    if not system.factors_any_dt:
        assert longer.solver.factorizations > made      # its own factors for the new sizes
    assert system.lu is lu and system.P is P and sim.solver.factorizations == made
    sim.advance(scene.time.end)
    _assert_identical(sim.result(), reference)


def test_a_step_ladder_factorises_each_size_once_for_every_look_ahead():
    """The poroelastic scene (its bulk factors depend on the step size) at 2 s steps, looked
    ahead 100 s on a ladder up to 16 s: steps 2, 4, 8, then 16 s, ending on the horizon with the
    largest sizes that fit (94 s + 4 + 2); three sizes factorised (4, 8, 16 s; the run's 2 s
    factors are shared), none for a second plan or a later look-ahead on the same ladder, and
    the run continues bit-identically to one that never looked ahead."""
    import dataclasses

    from fault_screen.forecast import LookAhead, StepLadder, parse_plan
    from test_forecast import run_to

    scene = poroelastic_growing()
    scene = scene.replace(time=dataclasses.replace(scene.time, end=160.0, growth=1.0, dt_max=2.0))
    reference = simulate(scene)
    sim, screening = run_to(scene, 40.0)
    ladder = StepLadder(16.0)
    hold = LookAhead(sim, screening, ladder=ladder).run(parse_plan("hold"), 100.0)
    assert np.array_equal(np.diff(hold.time), [2, 4, 8, 16, 16, 16, 16, 16, 4, 2])
    assert hold.time[-1] == 140.0 and ladder.factorizations == 3
    LookAhead(sim, screening, ladder=ladder).run(parse_plan("stop"), 100.0)
    sim.advance(50.0, align=True)
    later = LookAhead(sim, screening, ladder=ladder).run(parse_plan("scale:2"), 50.0)
    assert later.time[-1] == 100.0 and ladder.factorizations == 3
    sim.advance(scene.time.end)
    _assert_identical(sim.result(), reference)

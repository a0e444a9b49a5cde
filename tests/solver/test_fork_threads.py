"""A run and its fork stepped at the same time in two threads (the monitor's look-ahead beside the
live steps) take exactly the steps each takes alone: the fork shares only what neither writes.

The race: scipy's getrs wrapper shifts the pivots it is given to 1-based in place for the
duration of the call, so two solves with the same factors at once (the run's and the fork's
condensed solver) shifted them twice. Without the pivots' copy in ``lu_solve``, 7 of 12 runs of
the elastic cases' tests below failed, 4 of them aborting the interpreter ("Fatal Python error:
Aborted"); two threads solving 50 right-hand sides 100 times each with one LU got a wrong answer
in 25-40 % of the solves (relative error up to 1.8). Without the process-wide BLAS limit, the
test of the BLAS threads failed 2 of 2."""
import dataclasses
import threading

import numpy as np
import pytest
import scipy.linalg

from fault_screen import Simulation
from fault_screen.bordered_lu import lu_solve
from fault_screen.linear_system import _blas_controller
from fault_screen.simulate import simulate
from test_stepper import _arrays, _assert_identical, hard_rustrel, poroelastic_growing, pressure_controlled


def _short(make, end):
    def scene():
        s = make()
        return s.replace(time=dataclasses.replace(s.time, end=end))
    return scene


#: elastic bulks (SuperLU factors, one factorisation for every step size) and a poroelastic one
#: (L D L^T factors made again for each step size), each a couple of seconds at most
CASES = {"rate-and-state, elastic bulk": _short(hard_rustrel, 300.0),
         "pressure control, elastic bulk": pressure_controlled,
         "poroelastic bulk, growing steps": _short(poroelastic_growing, 100.0)}


@pytest.fixture(scope="module", params=list(CASES))
def case(request):
    scene = CASES[request.param]()
    return scene, simulate(scene)


def _together(*jobs):
    """Run the jobs in threads released at the same moment; re-raise the first error."""
    start = threading.Barrier(len(jobs))
    errors = []

    def run(job):
        try:
            start.wait()
            job()
        except BaseException as exc:   # (handed to the test's thread)
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(job,)) for job in jobs]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]


def _in_lockstep(sim, end):
    """Advance one step at a time (the threads' steps interleave more finely than in one call)."""
    def job():
        while sim.time < end * (1 - 1e-12) and sim.advance(end, max_steps=1):
            pass
    return job


def _assert_rows_from(result, reference, steps):
    forked = _arrays(result)
    for k, ref in _arrays(reference).items():
        assert np.array_equal(forked[k], ref[steps:]), k


@pytest.mark.parametrize("lockstep", [False, True], ids=["whole advance", "step by step"])
def test_a_run_and_its_fork_stepped_at_once_take_their_own_steps_exactly(case, lockstep):
    """Forked at a third of the run, both go to the end in two threads at once: the run's arrays
    are the uninterrupted run's (every array, bit for bit), and so are the fork's rows from the
    fork on; two rounds, the second with a fork of a fork that has not stepped yet."""
    scene, reference = case
    end = scene.time.end
    steps = (len(reference.time) - 1) // 3
    for round_ in range(2):
        sim = Simulation(scene)
        sim.advance(end, max_steps=steps)
        fork = sim.fork() if round_ == 0 else sim.fork().fork()
        if lockstep:
            _together(_in_lockstep(sim, end), _in_lockstep(fork, end))
        else:
            _together(lambda: sim.advance(end), lambda: fork.advance(end))
        _assert_identical(sim.result(), reference)
        _assert_rows_from(fork.result(), reference, steps)


def test_a_fork_making_new_factors_beside_the_run_changes_neither(case):
    """The fork takes steps growing 1.5 times up to 8 times the run's (new condensed blocks; with
    rock pore pressure, new bulk factors on the shared symbolic analysis) while the run steps on
    its shared factors: the run is the uninterrupted run bit for bit, the fork's rows are those
    of the same fork stepped alone, and the run's factors are the objects it had."""
    scene, reference = case
    end = scene.time.end
    steps = (len(reference.time) - 1) // 3

    def forked():
        sim = Simulation(scene)
        sim.advance(end, max_steps=steps)
        fork = sim.fork()
        fork.scene = scene.replace(time=dataclasses.replace(scene.time, growth=1.5, dt_max=8 * sim.dt))
        return sim, fork

    alone = forked()[1]
    alone.advance(end)
    sim, fork = forked()
    system = sim.solver.system
    lu, P, made = system.lu, system.P, sim.solver.factorizations
    _together(lambda: sim.advance(end), lambda: fork.advance(end))
    _assert_identical(sim.result(), reference)
    _assert_identical(fork.result(), alone.result())
    assert len(fork.result().time) < len(reference.time) - steps     # (it did take longer steps)
    assert fork.solver.factorizations == alone.solver.factorizations
    if system.factors_any_dt:   # one factorisation serves every step size: still the shared one
        assert system.lu is lu and system.P is P and fork.solver.system.lu is lu
    else:                       # the fork factorised its own sizes
        assert fork.solver.factorizations > made


def test_two_threads_solving_with_the_same_lu_factors_get_the_serial_answers():
    """The root cause on its own: 50 right-hand sides solved 100 times in each of two threads
    with one LU (n = 400) equal the serial solves exactly; the factors and pivots are unchanged."""
    rng = np.random.default_rng(0)
    n = 400
    factors = scipy.linalg.lu_factor(rng.standard_normal((n, n)) + n * np.eye(n))
    lu0, piv0 = factors[0].copy(), factors[1].copy()
    rhs = [rng.standard_normal(n) for _ in range(50)]
    serial = [lu_solve(factors, b) for b in rhs]
    wrong = [0, 0]

    def job(k):
        def run():
            for _ in range(100):
                for b, x in zip(rhs, serial):
                    wrong[k] += not np.array_equal(lu_solve(factors, b), x)
        return run

    _together(job(0), job(1))
    assert wrong == [0, 0]
    assert np.array_equal(factors[0], lu0) and np.array_equal(factors[1], piv0)


def test_the_blas_thread_limit_holds_while_either_steps_and_is_restored_after_both():
    """Under 2 BLAS threads, a run and its fork stepping at once each see 1 thread at every step
    (one's last step no longer restores the threads under the other), and afterwards the process
    has its 2 threads back (not the limit the last one out had found, 1)."""
    from threadpoolctl import threadpool_limits

    scene = CASES["pressure control, elastic bulk"]()
    end = scene.time.end
    with threadpool_limits(limits=2, user_api="blas"):
        sim = Simulation(scene)
        sim.advance(end, max_steps=3)
        fork = sim.fork()
        seen = []

        def blas_threads(t, x, disc):
            seen.extend(lib["num_threads"] for lib in _blas_controller().info()
                        if lib["user_api"] == "blas")

        # several calls each: limits taken and given back many times, interleaved
        def job(s):
            def run():
                while s.time < end * (1 - 1e-12):
                    s.advance(min(end, s.time + 4 * s.dt), observer=blas_threads)
            return run

        _together(job(sim), job(fork))
        assert seen and set(seen) == {1}
        after = {lib["num_threads"] for lib in _blas_controller().info() if lib["user_api"] == "blas"}
        assert after == {2}

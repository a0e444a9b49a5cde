"""The parts of a split block swept by two threads (``bordered_lu._each_part``): the same bits as
one thread sweeping them all, for the elastic bulk (SuperLU's factors, L and D) and the
poroelastic one in its symmetric form (L D L^T factors), each split into halves bordered by the
separator and the fault's unknowns; also with several callers sweeping the same factors at once
(a run and its forks stepping in threads), where the one worker serves one caller at a time
and the others sweep their parts themselves. And the threaded sweeps solve the system: against
numpy's dense solves to 1e-11 (tests/solver/test_bordered_lu.py's check)."""
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import scipy.sparse as sp

from fault_screen import bordered_lu, ldl
from fault_screen.bordered_lu import SplitBorderedLU

from test_bordered_lu import _check_against_dense
from test_ldl import _free_block, elastic, poroelastic  # noqa: F401  (fixtures)


@pytest.fixture(params=["elastic, SuperLU", "poroelastic 600 s, L D L^T"])
def split(request, elastic, poroelastic, monkeypatch):  # noqa: F811
    """A split block whose parts are shared between two threads (THREADS_ABOVE lowered)."""
    monkeypatch.setattr(bordered_lu, "THREADS_ABOVE", 1)
    if request.param.startswith("elastic"):
        M, nB = _free_block(elastic, elastic.system.dt, False)
        lu = SplitBorderedLU(M, nB, elastic.system.split)
        assert not any(part.quasi_definite for part in lu._parts)
    else:
        M, nB = _free_block(poroelastic, 600.0, True)
        lu = SplitBorderedLU(M, nB, poroelastic.system.split, ldl.SymbolicAnalyses())
        assert all(part.quasi_definite for part in lu._parts)
    assert lu._halves is not None and all(lu._halves)
    return lu, M.toarray(), nB


def _serial(lu):
    """The same factors swept by this thread alone."""
    alone = SplitBorderedLU.__new__(SplitBorderedLU)
    alone.__dict__.update(lu.__dict__, _halves=None)
    return alone


def _sweeps(lu, seed):
    r = np.random.default_rng(seed).standard_normal(lu.n)
    nB = lu.n_linear
    swept, condensed = lu.forward(r[:nB], r[nB:])
    return swept, condensed, lu.backward(swept, r[nB:]), lu.backward(None, r[nB:])


def test_two_threads_sweep_the_same_bits_as_one(split):
    lu, M, nB = split
    where = {}
    for i, part in enumerate(lu._parts):   # (which thread sweeps each part)
        def forward(*args, _i=i, _forward=part.forward):
            where[_i] = threading.current_thread().name
            return _forward(*args)
        part.forward = forward
    lu.forward(np.zeros(nB), np.zeros(lu.n - nB))
    for part in lu._parts:
        del part.forward
    mine, theirs = lu._halves
    assert {where[i] for i in mine} == {threading.current_thread().name}
    assert all(where[i].startswith("fault-screen-sweep") for i in theirs)
    for seed in range(3):
        for threaded, alone in zip(_sweeps(lu, seed), _sweeps(_serial(lu), seed)):
            assert np.array_equal(threaded, alone)
    _check_against_dense(lu, M, nB, 7)


def test_callers_at_once_each_get_their_own_answer(split):
    """Four threads sweeping the same factors twenty times each, each with its own right-hand
    sides: every answer equals the one-thread sweep of those right-hand sides bit for bit."""
    lu, M, nB = split
    expected = {seed: _sweeps(_serial(lu), seed) for seed in range(4)}
    start, wrong, errors = threading.Barrier(4), [], []

    def caller(seed):
        try:
            start.wait()
            for _ in range(20):
                if not all(np.array_equal(a, b) for a, b in zip(_sweeps(lu, seed), expected[seed])):
                    wrong.append(seed)
        except BaseException as exc:   # (handed to the test's thread)
            errors.append(exc)

    threads = [threading.Thread(target=caller, args=(seed,)) for seed in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and not wrong


def test_a_worker_that_takes_no_work_leaves_the_sweeps_to_the_caller(split, monkeypatch):
    """A worker shut down (the interpreter exiting while a thread still steps): the caller sweeps
    every part itself, the same bits."""
    lu, M, nB = split
    stopped = ThreadPoolExecutor(1)
    stopped.shutdown()
    monkeypatch.setattr(bordered_lu, "_sweeper", stopped)
    for threaded, alone in zip(_sweeps(lu, 5), _sweeps(_serial(lu), 5)):
        assert np.array_equal(threaded, alone)
    assert not bordered_lu._sweeper_busy.locked()


def test_small_parts_stay_in_one_thread():
    """Below THREADS_ABOVE values in a share, no worker: the two shares of the parts' sizes."""
    assert bordered_lu._split_in_two([10, 10]) is None
    big = bordered_lu.THREADS_ABOVE
    assert bordered_lu._split_in_two([3 * big, 3 * big, 4 * big, 4 * big]) == ([0, 2], [1, 3])
    assert bordered_lu._split_in_two([5 * big, big, big, big, big]) == ([0], [1, 2, 3, 4])

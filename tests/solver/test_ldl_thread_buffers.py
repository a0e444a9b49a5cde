"""ldl.py's second thread makes no buffer of its own (issue 28): memory a thread other than the
calling one allocates is freed into that thread's own malloc arena, which keeps it resident
(~9 MB of the fine scene's peak: 477-479 MB against 468-470 MB in one thread)."""
import threading

import numpy as np
import pytest
from numba.core.runtime import _nrt_python, rtsys

from fault_screen import ldl
from fault_screen.bordered_lu import BorderedLU

from test_ldl import _free_block, poroelastic  # noqa: F401 (a fixture)


@pytest.mark.parametrize("shared", [False, True])
def test_the_second_thread_allocates_no_buffer_of_its_own(poroelastic, monkeypatch, shared):  # noqa: F811
    """A refactorisation in two threads (the tree's two parts; ``shared``: and the top's last
    front split between them): every ``_eliminate`` work array is made by ``_front_buffers`` in
    the calling thread, the kernels allocate nothing (numba's allocation count, across the
    factorisation, rises by their arguments' wrappers alone), the second part did run in a thread of its own, and the
    factors equal one thread's bit for bit."""
    monkeypatch.setattr(ldl, "SPLIT_FRONT_ABOVE", 0.0 if shared else np.inf)
    M, nB = _free_block(poroelastic, 600.0, symmetric_form=True)
    analyses = ldl.SymbolicAnalyses()
    BorderedLU(M, nB, analyses)     # (the first factorisation: kernels loaded, front not shared)
    one = BorderedLU(M, nB, analyses)
    monkeypatch.setattr(ldl, "THREADS_ABOVE", 0.0)
    made_in, kernel_calls, numeric = [], [], []
    make = ldl._front_buffers
    kernels = {k: getattr(ldl, k) for k in ("_eliminate", "_front_by_halves", "_await_part")}
    factorise = ldl._numeric

    def making(*args):
        made_in.append(threading.get_ident())
        return make(*args)

    def recording(name):
        def call(*args):
            # (numba wraps each array argument at the call: one allocation each, its MemInfo)
            kernel_calls.append((name, threading.get_ident(),
                                 sum(isinstance(a, np.ndarray) for a in args)))
            return kernels[name](*args)
        return call

    def counting(*args, **kwargs):
        # (numba's count is the process's: the two threads' kernels counted together)
        before = rtsys.get_allocation_stats().alloc
        try:
            return factorise(*args, **kwargs)
        finally:
            numeric.append(rtsys.get_allocation_stats().alloc - before)

    monkeypatch.setattr(ldl, "_front_buffers", making)
    monkeypatch.setattr(ldl, "_numeric", counting)
    for name in kernels:
        monkeypatch.setattr(ldl, name, recording(name))
    enabled = _nrt_python.memsys_stats_enabled()
    _nrt_python.memsys_enable_stats()
    try:
        two = BorderedLU(M, nB, analyses)
    finally:
        if not enabled:
            _nrt_python.memsys_disable_stats()
    caller = threading.get_ident()
    eliminations = [c for c in kernel_calls if c[0] == "_eliminate"]
    assert len(eliminations) == 3 and made_in == [caller] * 3
    assert caller in {c[1] for c in eliminations} and len({c[1] for c in eliminations}) == 2
    assert numeric == [sum(c[2] for c in kernel_calls)]   # (nothing allocated by a kernel)
    assert any(c[0] == "_front_by_halves" for c in kernel_calls) == shared
    assert two.quasi_definite and np.array_equal(two.schur, one.schur)
    assert np.array_equal(two._D, one._D)
    assert all(np.array_equal(x, y) for x, y in zip(two._L.arrays, one._L.arrays))

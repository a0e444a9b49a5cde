"""The condensed block's dense solver (``linear_system.CondensedSolver``): every way it solves M x = b
(a fresh LU; a step-size change through the storage rows; a slip front's Woodbury update and
iteration on top of that) meets CONDENSED_RTOL against M itself (formed densely here) and
numpy's solve, on a small block given like the Newton solver's: M(1/dt) = A + C/dt + H - P + T,
C nonzero only in the flow rows, T a contact tangent on the mechanical rows (triplets)."""
import mmap
import sys

import numpy as np
import pytest
import scipy.sparse as sp

from fault_screen.linear_system import CONDENSED_RTOL, LOW_RANK_FRACTION, CondensedSolver

N_MECH, N_FLOW = 60, 20
N = N_MECH + N_FLOW
FLOW = np.arange(N_MECH, N)


@pytest.fixture(scope="module")
def blocks():
    rng = np.random.default_rng(7)
    A = sp.random(N, N, density=0.15, random_state=rng) + sp.diags(np.full(N, 8.0))
    A = sp.csr_matrix(A + A.T)
    # storage: flow rows only, reaching the mechanical columns too (the opening's storage)
    C = sp.lil_matrix((N, N))
    for i in FLOW:
        C[i, i] = 0.03
        C[i, rng.integers(0, N_MECH, 3)] = 0.004 * rng.standard_normal(3)
    C = C.tocsr()
    H = sp.csr_matrix(sp.random(N, N, density=0.05, random_state=rng))
    P = 0.1 * rng.standard_normal((N, N))
    return A, C, H, P


def _linear(blocks, inv_dt):
    """L_NN's entries (rows, columns, values) at step size 1/inv_dt."""
    A, C, H, _ = blocks
    L = (A + C * inv_dt + H).tocoo()
    return L.row.astype(np.int64), L.col.astype(np.int64), L.data


def _tangent(points, stiffness):
    """A contact tangent on the mechanical rows ``points`` (rows, columns, values)."""
    rows = np.repeat(points, 2)
    cols = np.concatenate([[p, (p + 1) % N_MECH] for p in points])
    vals = np.tile([stiffness, -0.5 * stiffness], len(points))
    return rows, cols, vals


def _on(pattern, tangent):
    """``tangent`` listed on the triplets of ``pattern`` (zeros where it has none), as the
    nonlinear terms list theirs: the same positions at every iteration."""
    rows, cols, _ = pattern
    vals = np.zeros(len(rows))
    for r, c, v in zip(*tangent):
        vals[np.flatnonzero((rows == r) & (cols == c))[0]] += v
    return rows, cols, vals


#: every triplet position the tangents below use (one triplet may be listed twice)
PATTERN = tuple(np.concatenate(parts) for parts in zip(
    _tangent(np.arange(N_MECH), 1.0), (np.arange(N_MECH), np.arange(N_MECH), np.zeros(N_MECH)),
    ([FLOW[3]], [FLOW[3]], [0.0]), ([12], [13], [0.0])))


def _block(blocks, inv_dt, tangent):
    """M = L_NN - P + T, dense."""
    A, C, H, P = blocks
    M = (A + C * inv_dt + H).toarray() - P
    np.add.at(M, (tangent[0], tangent[1]), tangent[2])
    return M


def _set(dense, blocks, inv_dt, tangent, base=1):
    dense.set(blocks[3], _linear(blocks, inv_dt), _on(PATTERN, tangent), 1.0 / inv_dt, base=base)
    return _block(blocks, inv_dt, tangent)


def _check(dense, M, rng):
    b = rng.standard_normal(len(M))
    x = dense.solve(b)
    assert np.linalg.norm(M @ x - b) <= CONDENSED_RTOL * np.linalg.norm(b)
    assert np.allclose(x, np.linalg.solve(M, b), rtol=1e-8, atol=1e-12 * np.abs(x).max())


def test_each_path_solves_the_block_of_its_step_size_and_tangent(blocks):
    rng = np.random.default_rng(1)
    dense = CondensedSolver(blocks[1])
    contact = _tangent(np.arange(10, 20), 50.0)
    # a fresh LU
    inv0 = 1.0 / 1e-3
    M = _set(dense, blocks, inv0, contact)
    _check(dense, M, rng)
    assert (dense.factorizations, dense.updates) == (1, 0)
    # a longer step: only the storage rows changed, through the update on them (steps 5 times
    # longer: the storage, most of the flow rows' diagonal, falls by 4/5, so that an update that
    # is not exact misses the tolerance after the refinement it is allowed and M is factorised)
    inv1 = 1.0 / 5e-3
    M = _set(dense, blocks, inv1, contact)
    _check(dense, M, rng)
    assert (dense.factorizations, dense.updates) == (1, 1)
    # and a slip front moved by a few points: Woodbury on the changed rows, on top of it
    # (and an aperture's conduction in a flow row: a change inside the storage pattern)
    moved = _tangent(np.arange(10, 23), 50.0)
    moved = moved[0], moved[1], moved[2] * np.where(moved[0] >= 18, 3.0, 1.0)
    moved = tuple(np.append(a, v) for a, v in zip(moved, (FLOW[3], FLOW[3], 0.5)))
    M = _set(dense, blocks, inv1, moved)
    changed = dense._tangent_change()[1]
    assert 0 < len(changed) * LOW_RANK_FRACTION <= N
    _check(dense, M, rng)
    assert (dense.factorizations, dense.updates) == (1, 2)
    # a change spread over most rows but small, at yet another step size: iteration on top of it
    inv2 = 1.0 / 5.3e-3
    spread = (np.arange(N_MECH), np.arange(N_MECH), np.full(N_MECH, 0.01))
    both = tuple(np.concatenate([a, b]) for a, b in zip(contact, spread))
    M = _set(dense, blocks, inv2, both)
    iterations = dense.iterations
    _check(dense, M, rng)
    assert dense.factorizations == 1 and dense.iterations > iterations
    # a spread change that refinement contracts slowly (to 2e-2 a step, short of
    # REFINEMENT_GAIN): GMRES takes over from where refinement stopped
    gmres_calls = []
    gmres = dense._gmres
    dense._gmres = lambda *args: gmres_calls.append(1) or gmres(*args)
    stiffer = tuple(np.concatenate([a, b]) for a, b in zip(contact, spread[:2] + (30 * spread[2],)))
    M = _set(dense, blocks, inv2, stiffer)
    _check(dense, M, rng)
    assert dense.factorizations == 1 and gmres_calls
    # a large spread change: M is factorised anew and becomes the base
    M = _set(dense, blocks, inv2, (spread[0], spread[1], 100 * spread[2]))
    _check(dense, M, rng)
    assert dense.factorizations == 2 and dense.factored_inv_dt == inv2


def test_the_tangent_change_is_read_off_the_triplets_exactly(blocks):
    """M - M1 is T - T0 entry by entry: nothing where the triplets are equal (a step-size change
    alone is none), the rows and columns of every entry that changed, a change inside the
    storage pattern included, and its dense K x K block."""
    dense = CondensedSolver(blocks[1])
    contact = _tangent(np.arange(10, 20), 50.0)
    _set(dense, blocks, 1e3, contact)
    _set(dense, blocks, 1e3 / 1.06, contact)
    dense._step_size_update()
    D, K, DK, largest = dense._tangent_change()
    assert len(K) == 0 and largest == 0.0 and not D.any()
    moved = _tangent(np.arange(10, 20), 50.0)
    moved = moved[0], moved[1], moved[2] * np.where(moved[0] < 14, 1.2, 1.0)
    moved = tuple(np.append(a, v) for a, v in zip(moved, (FLOW[3], FLOW[3], 0.5)))
    _set(dense, blocks, 1e3 / 1.06, moved)
    D, K, DK, largest = dense._tangent_change()
    expected = _block(blocks, 1e3, moved) - _block(blocks, 1e3, contact)
    assert np.array_equal(K, np.flatnonzero(np.abs(expected).sum(axis=0) + np.abs(expected).sum(axis=1)))
    assert np.array_equal(K, np.append(np.arange(10, 15), FLOW[3]))
    assert np.allclose(DK, expected[np.ix_(K, K)], rtol=0, atol=1e-12) and largest == 10.0


def test_a_new_condensation_or_pattern_is_factorised(blocks):
    rng = np.random.default_rng(3)
    dense = CondensedSolver(blocks[1])
    contact = _tangent(np.arange(10, 20), 50.0)
    _set(dense, blocks, 1e3, contact)
    M = _set(dense, blocks, 1e3, contact, base=2)
    _check(dense, M, rng)
    assert dense.factorizations == 2
    dense.set(blocks[3], _linear(blocks, 1e3), contact, 1e-3, base=2)  # (triplets listed anew)
    _check(dense, _block(blocks, 1e3, contact), rng)
    assert dense.factorizations == 3


def test_without_a_storage_block_a_new_step_size_is_factorised(blocks):
    rng = np.random.default_rng(2)
    dense = CondensedSolver()
    for k, inv_dt in enumerate((1e3, 1e3 / 1.06)):
        M = _set(dense, blocks, inv_dt, _tangent(np.arange(10, 20), 50.0))
        _check(dense, M, rng)
        assert dense.factorizations == k + 1


def _gmres_by_arnoldi_columns(A, b, m):
    """m iterations of unpreconditioned GMRES from zero by ``_arnoldi_column``: the iterate, the
    basis and the rotated right-hand side."""
    from fault_screen.linear_system import _arnoldi_column

    n = len(b)
    V, H = np.empty((m + 1, n)), np.zeros((m + 1, m))
    cs, sn, g = np.zeros(m), np.zeros(m), np.zeros(m + 1)
    g[0] = np.linalg.norm(b)
    V[0] = b / g[0]
    for j in range(m):
        w = A @ V[j]
        V[j + 1] = w / _arnoldi_column(V, H, cs, sn, g, j, w)
    y = np.linalg.solve(np.triu(H[:m, :m]), g[:m])
    return y @ V[:m], V, g


@pytest.mark.parametrize("m", [5, 40])
def test_arnoldi_columns_give_the_gmres_iterate(m):
    """The Arnoldi kernel of the condensed iteration against numpy: its basis is orthonormal to
    round-off (1e-13), the residual it estimates (the last entry of the rotated right-hand side)
    is the true residual of its iterate (1e-9 relative), and with as many iterations as unknowns
    the iterate is numpy's solve (1e-10 relative)."""
    n = 40
    rng = np.random.default_rng(11)
    A = 3.0 * np.eye(n) + rng.standard_normal((n, n)) / np.sqrt(n)   # unsymmetric, regular
    b = rng.standard_normal(n)
    x, V, g = _gmres_by_arnoldi_columns(A, b, m)
    k = min(m + 1, n)   # (with m = n the last basis row is made of round-off)
    assert np.max(np.abs(V[:k] @ V[:k].T - np.eye(k))) < 1e-13
    true = np.linalg.norm(b - A @ x)
    if m < n:
        assert true > 1e-6 * np.linalg.norm(b)   # (far from converged: the estimate means something)
        assert abs(abs(g[m]) - true) <= 1e-9 * true
    else:
        exact = np.linalg.solve(A, b)
        assert np.max(np.abs(x - exact)) < 1e-10 * np.max(np.abs(exact))


def _front_solve(dense, blocks, contact, points, stiffness, inv_dt, rng):
    """A slip front at ``points`` (``stiffness + p`` on each diagonal) on top of ``contact``,
    solved: K must be the points, and the first application (one product with P: no
    refinement hides an error) the dense solve of M to 1e-12 relative."""
    moved = contact
    for p in points:
        moved = tuple(np.append(a, v) for a, v in zip(moved, (p, p, stiffness + p)))
    M = _set(dense, blocks, inv_dt, moved)
    K = dense._tangent_change()[1]
    assert np.array_equal(K, np.unique(points)) and len(K) * LOW_RANK_FRACTION <= N
    products = []
    times = dense._times
    dense._times = lambda v: products.append(1) or times(v)
    b = rng.standard_normal(N)
    x = dense.solve(b)
    del dense._times
    exact = np.linalg.solve(M, b)
    assert np.linalg.norm(x - exact) <= 1e-12 * np.linalg.norm(exact)
    assert len(products) == 1 and dense.factorizations == 1


def test_low_rank_update_over_a_gappy_span_is_the_dense_solve_in_one_application(blocks):
    """The Woodbury solve reads M0^-1's columns over K's span (the columns between that are not
    in K: solved for an earlier K, or never) and makes the step size's correction with one solve
    of its capacitance: at a new step size, with a K whose span holds columns of an earlier K and
    unsolved ones, its first application is the dense solve of the updated M to 1e-12 relative
    (a column between taken as part of K, or a correction missing T_K's share (1e-11 here),
    misses it; the refinement that could hide it is counted: none)."""
    rng = np.random.default_rng(3)
    dense = CondensedSolver(blocks[1])
    contact = _tangent(np.arange(10, 20), 50.0)
    _set(dense, blocks, 1.0 / 1e-3, contact)
    inv1 = 1.0 / 1.7e-3
    for points in ([11, 12, 13], [12, 40], [5, 12, 44, 45]):   # spans 11-14, 12-41, 5-46
        _front_solve(dense, blocks, contact, points, 30.0, inv1, rng)
    assert dense.updates == 3 and not dense._have[20:40].all() and dense._have[40:47].all()


def test_a_slip_fronts_set_up_is_kept_while_k_and_the_step_size_are(blocks):
    """K's set-up (Z_K less the step size's share, the shift columns) is made once for a K and a
    step size: a Newton iteration whose front did not move (other tangent values at the same K)
    reuses it; a front that grew past three missing pages of shift columns (made in one solve),
    or the same K at another step size, makes it anew. Each first application is the dense
    solve of its M to 1e-12 relative: a set-up kept across the step size (its share changes by
    1e-4 of Z_K here) or a page's columns placed wrong misses it."""
    rng = np.random.default_rng(5)
    dense = CondensedSolver(blocks[1])
    contact = _tangent(np.arange(10, 20), 50.0)
    _set(dense, blocks, 1.0 / 1e-3, contact)

    def front(points, stiffness, inv_dt):
        _front_solve(dense, blocks, contact, points, stiffness, inv_dt, rng)
        return dense._front

    inv1 = 1.0 / 1.7e-3
    first = front([12, 13], 30.0, inv1)
    again = front([12, 13], 45.0, inv1)          # the same K and step size: kept
    assert all(a is b for a, b in zip(first, again))
    assert not dense._have1[16:].any()
    grown = front([12, 13, 20, 40, 52], 30.0, inv1)   # three pages of shift columns at once
    assert grown[3] is not first[3] and dense._have1[:64].all() and not dense._have1[64:].any()
    other = front([12, 13, 20, 40, 52], 30.0, 1.0 / 2.3e-3)   # another step size: anew
    assert other[3] is not grown[3]
    share = np.abs(other[3] - grown[3]).max() / np.abs(grown[3]).max()
    assert share > 1e-5    # (what a set-up kept across step sizes would have got wrong)
    assert dense.updates == 4


def _resident_pages(a):
    """Which memory pages of ``a``'s buffer are resident (Linux mincore), from its first page."""
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    libc.mincore.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_char_p]
    start = a.__array_interface__["data"][0]
    assert start % mmap.PAGESIZE == 0
    pages = -(-a.nbytes // mmap.PAGESIZE)
    vec = ctypes.create_string_buffer(pages)
    assert libc.mincore(ctypes.c_void_p(start), ctypes.c_size_t(a.nbytes), vec) == 0
    return np.frombuffer(vec.raw, dtype=np.uint8) & 1 == 1


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="mincore as Linux has it")
def test_the_kept_columns_take_memory_only_where_they_are_filled(blocks):
    """The columns of M0^-1 kept for slip fronts (``_Z``, n x n) and their shares of a step-size
    change (``_T``, |R| x n) are zero pages until a front reaches them (on the fine 30 deg scene
    a few hundred columns of 2059 are ever solved): after a front at points 11-13 at a new step
    size, the memory pages of ``_Z`` wholly in the columns never solved (16-79: the first
    COLUMN_PAGE holds 11-13) are not resident, those of the columns solved are, and every column
    not solved reads zero. (np.zeros from heap memory freed earlier would be resident whole.)
    A fork's copies are the same, bit for bit, and as resident."""
    rng = np.random.default_rng(5)
    dense = CondensedSolver(blocks[1])
    contact = _tangent(np.arange(10, 20), 50.0)
    _set(dense, blocks, 1.0 / 1e-3, contact)
    _front_solve(dense, blocks, contact, [11, 12, 13], 30.0, 1.0 / 1.7e-3, rng)
    Z, T = dense._Z, dense._T
    twin = dense.fork()
    # (first: reading a page never written maps the zero page, which mincore counts)
    solved_pages = -(-16 * N * 8 // mmap.PAGESIZE)          # the pages holding columns 0-15
    for kept in (Z, twin._Z):
        resident = _resident_pages(kept)
        assert resident[:solved_pages].all()
        assert not resident[solved_pages:].any(), np.flatnonzero(resident)
    assert twin._Z is not Z and twin._T is not T and twin._have is not dense._have
    assert np.array_equal(twin._Z, Z) and np.array_equal(twin._T, T)
    assert np.array_equal(twin._have, dense._have) and np.array_equal(twin._have1, dense._have1)
    assert Z.flags.f_contiguous and T.flags.f_contiguous
    assert np.flatnonzero(dense._have).tolist() == list(range(16))
    assert not Z[:, 16:].any() and not T[:, 16:].any() and Z[:, 11:14].any() and T[:, 11:14].any()


def test_a_stalled_refinement_goes_on_by_gmres_with_sparse_products(blocks, monkeypatch):
    """A spread change that refinement contracts slowly: its estimate of the residual starts
    GMRES (no check with P: it misses by far), whose first cycle takes M z_j as v_j + D z_j;
    the one product with the dense P is the final check, and the result is the dense solve's
    to CONDENSED_RTOL (an M z_j missing its v_j, or D z_j, or a wrong sign of the estimate
    leave a residual of order 1e-2 |b|, or the check fails and more products follow)."""
    from fault_screen import linear_system

    products = []
    times = linear_system.condensation_times
    monkeypatch.setattr(linear_system, "condensation_times",
                        lambda *args: products.append(1) or times(*args))
    rng = np.random.default_rng(5)
    dense = CondensedSolver(blocks[1])
    contact = _tangent(np.arange(10, 20), 50.0)
    _set(dense, blocks, 1.0 / 1e-3, contact)
    spread = (np.arange(N_MECH), np.arange(N_MECH), np.full(N_MECH, 0.3))
    stiffer = tuple(np.concatenate([a, b]) for a, b in zip(contact, spread))
    for inv_dt in (1.0 / 1e-3, 1.0 / 5.3e-3):   # (M0's step size, then the storage's update)
        M = _set(dense, blocks, inv_dt, stiffer)
        iterations, products[:] = dense.iterations, []
        b = rng.standard_normal(len(M))
        x = dense.solve(b)
        exact = np.linalg.solve(M, b)
        assert np.linalg.norm(M @ x - b) <= CONDENSED_RTOL * np.linalg.norm(b)
        # (the residual's bound times M's condition number: 8 here)
        assert (np.linalg.norm(x - exact)
                <= np.linalg.cond(M) * CONDENSED_RTOL * np.linalg.norm(exact))
        assert dense.factorizations == 1
        assert dense.iterations - iterations >= 4   # (a refinement step and GMRES iterations)
        assert len(products) == 1


def _stuck_then_slipping(patch_end):
    """A contact tangent with every point stuck (stiff), and one whose points 10 to
    ``patch_end`` slip (no tangent): the two blocks differ in over 1/LOW_RANK_FRACTION of the
    rows, by more than SMALL_CHANGE, so neither serves the other."""
    stuck = _tangent(np.arange(N_MECH), 50.0)
    slipping = _tangent(np.setdiff1d(np.arange(N_MECH), np.arange(10, patch_end)), 50.0)
    return stuck, slipping


def test_a_block_that_returns_is_recalled_not_factorised(blocks):
    """Constant friction's Newton iterations alternate between a stuck fault and a slipping patch
    whose front moves by a point a step: after the first two LUs every block is solved with the
    factors of one of them (the stuck block exactly, the patch by a low-rank change of the
    last one), each solve to CONDENSED_RTOL of M and to numpy's solve."""
    rng = np.random.default_rng(11)
    dense = CondensedSolver(blocks[1])
    for step in range(6):
        stuck, slipping = _stuck_then_slipping(40 + step)
        for tangent in (stuck, slipping):
            _check(dense, _set(dense, blocks, 1e3, tangent), rng)
    assert (dense.factorizations, dense.recalls) == (2, 10)
    # the last block is the patch factorised first (to point 40) but for its front's six points
    assert dense._tangent_change()[1].tolist() == list(range(40, 46))

    # a block from another condensation recalls nothing: it is factorised and the one before goes
    _check(dense, _set(dense, blocks, 1e3, _stuck_then_slipping(46)[0], base=2), rng)
    assert dense.factorizations == 3 and dense._recalled is None


def test_a_large_block_keeps_one_set_of_factors(blocks, monkeypatch):
    """Beyond RECALL_UP_TO rows (memory: the fine 30 deg scene's 2059) the block before is not
    kept: every return is factorised, and the solves are the same to CONDENSED_RTOL."""
    import fault_screen.linear_system as ls

    monkeypatch.setattr(ls, "RECALL_UP_TO", N - 1)
    rng = np.random.default_rng(12)
    dense = CondensedSolver(blocks[1])
    for step in range(3):
        for tangent in _stuck_then_slipping(40 + step):
            _check(dense, _set(dense, blocks, 1e3, tangent), rng)
    assert (dense.factorizations, dense.recalls) == (6, 0) and dense._recalled is None


def test_a_fork_recalls_as_its_run_does(blocks):
    """A fork made while a block is recalled solves the next blocks bit for bit as its run does,
    with its own copies of the columns solved with either block."""
    rng = np.random.default_rng(13)
    dense = CondensedSolver(blocks[1])
    for tangent in _stuck_then_slipping(40) + _stuck_then_slipping(41):
        _check(dense, _set(dense, blocks, 1.0 / 1e-3, tangent), rng)
    twin = dense.fork()
    assert twin._Z is not dense._Z and twin._recalled is not dense._recalled
    b = rng.standard_normal(N)
    for tangent in _stuck_then_slipping(42):
        solved = [(_set(solver, blocks, 1.0 / 1.3e-3, tangent), solver.solve(b))[1]
                  for solver in (dense, twin)]
        assert np.array_equal(*solved)
    assert dense.recalls == twin.recalls == 4 and dense.factorizations == twin.factorizations == 2

"""The condensed block's dense solver (``solver._CondensedSolver``): every way it solves M x = b
(a fresh LU; a step-size change through the storage rows; a slip front's Woodbury update and
GMRES on top of that) meets CONDENSED_RTOL against M itself and numpy's solve, on a small block
built like the Newton solver's: M(1/dt) = A + C/dt + H - P + T, C nonzero only in the flow rows,
T a contact tangent on the mechanical rows."""
import numpy as np
import pytest
import scipy.sparse as sp

from fault_screen.solver import CONDENSED_RTOL, LOW_RANK_FRACTION, _CondensedSolver

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


def _schur(blocks, inv_dt):
    A, C, H, P = blocks
    return (A + C * inv_dt + H).toarray() - P


def _tangent(points, stiffness):
    """A contact tangent on the mechanical rows ``points`` (flat positions, values)."""
    rows = np.repeat(points, 2)
    cols = np.concatenate([[p, (p + 1) % N_MECH] for p in points])
    vals = np.tile([stiffness, -0.5 * stiffness], len(points))
    return rows * N + cols, vals


def _block(blocks, inv_dt, tangent):
    M = _schur(blocks, inv_dt)
    at, vals = tangent
    np.add.at(M.ravel(), at, vals)
    return M


def _check(dense, M, rng):
    b = rng.standard_normal(len(M))
    x = dense.solve(b)
    assert np.linalg.norm(M @ x - b) <= CONDENSED_RTOL * np.linalg.norm(b)
    assert np.allclose(x, np.linalg.solve(M, b), rtol=1e-8, atol=1e-12 * np.abs(x).max())


def test_each_path_solves_the_block_of_its_step_size_and_tangent(blocks):
    rng = np.random.default_rng(1)
    dense = _CondensedSolver(blocks[1])
    contact = _tangent(np.arange(10, 20), 50.0)
    # a fresh LU
    inv0 = 1.0 / 1e-3
    M = _block(blocks, inv0, contact)
    dense.set(M, inv0, base=1, touched=contact[0])
    _check(dense, M, rng)
    assert (dense.factorizations, dense.updates) == (1, 0)
    # a longer step: only the storage rows changed, through the update on them (steps 5 times
    # longer: the storage, most of the flow rows' diagonal, falls by 4/5, so that an update that
    # is not exact misses the tolerance after the refinement it is allowed and M is factorised)
    inv1 = 1.0 / 5e-3
    M = _block(blocks, inv1, contact)
    dense.set(M, inv1, base=1, touched=contact[0])
    _check(dense, M, rng)
    assert (dense.factorizations, dense.updates) == (1, 1)
    # and a slip front moved by a few points: Woodbury on the changed rows, on top of it
    # (and an aperture's conduction in a flow row: a change inside the storage pattern)
    moved = _tangent(np.arange(10, 23), 50.0)
    moved = moved[0], moved[1] * np.where(moved[0] // N >= 18, 3.0, 1.0)
    moved = np.append(moved[0], FLOW[3] * (N + 1)), np.append(moved[1], 0.5)
    M = _block(blocks, inv1, moved)
    dense.set(M, inv1, base=1, touched=moved[0])
    changed = np.flatnonzero(dense._change_from_M0()[0])
    assert 0 < len(changed) * LOW_RANK_FRACTION <= N
    _check(dense, M, rng)
    assert (dense.factorizations, dense.updates) == (1, 2)
    # a change spread over most rows but small, at yet another step size: GMRES on top of it
    inv2 = 1.0 / 5.3e-3
    spread = (np.arange(N_MECH) * (N + 1), np.full(N_MECH, 0.01))
    both = np.concatenate([contact[0], spread[0]]), np.concatenate([contact[1], spread[1]])
    M = _block(blocks, inv2, both)
    dense.set(M, inv2, base=1, touched=both[0])
    iterations = dense.iterations
    _check(dense, M, rng)
    assert dense.factorizations == 1 and dense.iterations > iterations
    # a large spread change: M is factorised anew and becomes the base
    M = _block(blocks, inv2, (spread[0], 100 * spread[1]))
    dense.set(M, inv2, base=1, touched=spread[0])
    _check(dense, M, rng)
    assert dense.factorizations == 2 and dense.M0 is M


def test_the_change_is_found_alike_at_the_tangent_alone_and_in_the_whole_block(blocks):
    """The positions read when M and M0 share a condensation find what a read of every entry
    finds (a restored run reads every entry: its block's origin is unknown)."""
    dense = _CondensedSolver(blocks[1])
    contact = _tangent(np.arange(10, 20), 50.0)
    dense.set(_block(blocks, 1e3, contact), 1e3, base=1, touched=contact[0])
    # a tangent in the storage pattern too, changed beside the step size
    moved = _tangent(np.arange(12, 24), 60.0)
    moved = (np.append(moved[0], FLOW[3] * (N + 1)), np.append(moved[1], 0.5))
    for inv_dt in (1e3, 1e3 / 1.06, 20.0):
        M = _block(blocks, inv_dt, moved)
        dense.set(M, inv_dt, base=1, touched=moved[0])
        dense._step_size_update()
        at_tangent = dense._change_from_M0()
        dense._base = None
        whole = dense._change_from_M0()
        assert np.array_equal(at_tangent[0], whole[0]) and at_tangent[1] == whole[1]
        assert at_tangent[0][FLOW[3]] and not at_tangent[0][FLOW[4]]


def test_without_a_storage_block_a_new_step_size_is_factorised(blocks):
    rng = np.random.default_rng(2)
    dense = _CondensedSolver()
    for k, inv_dt in enumerate((1e3, 1e3 / 1.06)):
        M = _block(blocks, inv_dt, _tangent(np.arange(10, 20), 50.0))
        dense.set(M, inv_dt)
        _check(dense, M, rng)
        assert dense.factorizations == k + 1

"""The quasi-definite LDL^T (fault_screen/ldl.py) against numpy's dense linear algebra on real
blocks of each kind: an elastic bulk, a poroelastic one in its symmetric form at a small and a
large step size (5 s and 600 s), each with the fault's unknowns as its border; and its numeric
refactorisation at a new step size against a fresh factorisation.

Tolerances: the Schur complement, the swept right-hand sides and the solution to 1e-11
relative to the reference's largest entry (tests/solver/test_bordered_lu.py's check), the solve of the whole system
to a normwise backward error |M x - r| / (|M| |x| + |r|) (infinity norms) below 1e-15 (measured
2e-17 and less), which a wrong factor entry anywhere exceeds by orders of magnitude."""
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp

from fault_screen import Scene, ldl
from fault_screen.bordered_lu import BorderedLU, SplitBorderedLU
from fault_screen.discretisation import discretise
from fault_screen.solver import NewtonSolver

from conftest import CONFIGS, VERIFICATION
from test_bordered_lu import _check_against_dense as check_against_dense

TOL = 1e-11   # (the same as test_bordered_lu's)
BACKWARD_ERROR = 1e-15


def _solver(scene):
    solver = NewtonSolver(discretise(scene))
    x = np.zeros(solver.disc.n_dofs)
    contact = solver.disc.physics.contact
    solver._prepare(scene.time.dt, x, contact.initial_history(solver.disc) if contact else None)
    return solver


def _free_block(solver, dt, symmetric_form):
    """The scaled free block at ``dt`` in the factors' order; in the symmetric form its flow
    rows times -dt (what linear_system factorises for a poroelastic bulk)."""
    system = solver.system
    D = sp.diags(system.scale)
    M = (D @ system._linear_jacobian(dt) @ D).tocsr()[system.order][:, system.order]
    if symmetric_form:
        mechanical = system._mechanical[system.order]
        M = sp.diags(np.where(mechanical, 1.0, -dt)) @ M
    return M.tocsc(), len(system.B)


@pytest.fixture(scope="module")
def poroelastic():
    """The Newton solver of a permeable-rock scene (mass balance verification, 24 x 25)."""
    return _solver(Scene.from_toml(CONFIGS / "verification" / "mass-balance.toml"))


@pytest.fixture(scope="module")
def elastic():
    """A coarse inclined-fault scene in impermeable rock (1575 unknowns)."""
    scene = Scene.from_toml(VERIFICATION / "fluid-driven-slip-T0.4-dip30.toml")
    m = scene.mesh
    return _solver(scene.replace(mesh=replace(m, refinement=replace(m.refinement, size=4.0,
                                                                              growth=1.5))))


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


def _check_against_dense(lu, M, nB, seed):
    """Schur complement, forward and backward sweeps against numpy (``test_bordered_lu``'s
    check), and the backward error of the whole solve."""
    M = M.toarray()
    check_against_dense(lu, M, nB, seed)
    r = np.random.default_rng(seed).standard_normal(M.shape[0])
    swept, condensed = lu.forward(r[:nB], r[nB:])
    xN = np.linalg.solve(lu.schur, condensed)
    x = np.concatenate([lu.backward(swept, xN), xN])
    backward_error = (np.abs(M @ x - r).max()
                      / (np.abs(M).sum(axis=1).max() * np.abs(x).max() + np.abs(r).max()))
    assert backward_error < BACKWARD_ERROR


@pytest.mark.parametrize("dt", [5.0, 600.0])
def test_poroelastic_block_against_dense(poroelastic, dt):
    M, nB = _free_block(poroelastic, dt, symmetric_form=True)
    assert M.shape[0] - nB > 50   # a real border: the fault's unknowns
    lu = BorderedLU(M, nB, ldl.SymbolicAnalyses())
    assert lu.quasi_definite
    # quasi-definite: the stiffness pivots positive, the flow ones (times -dt) negative
    mechanical = poroelastic.system._mechanical[poroelastic.system.order][:nB]
    assert np.all(lu._D[mechanical] > 0) and np.all(lu._D[~mechanical] < 0)
    _check_against_dense(lu, M, nB, 1)


def test_elastic_block_against_dense(elastic):
    M, nB = _free_block(elastic, elastic.system.dt, symmetric_form=False)
    lu = BorderedLU(M, nB, ldl.SymbolicAnalyses())
    assert lu.quasi_definite and np.all(lu._D > 0)   # (positive definite)
    _check_against_dense(lu, M, nB, 2)


def test_split_block_against_dense(elastic):
    """Each half of a split bulk on its own symbolic analysis."""
    M, nB = _free_block(elastic, elastic.system.dt, symmetric_form=False)
    analyses = ldl.SymbolicAnalyses()
    lu = SplitBorderedLU(M, nB, elastic.system.split, analyses)
    assert all(part.quasi_definite for part in lu._parts) and len(analyses._held) == 2
    _check_against_dense(lu, M, nB, 3)


def test_refactorisation_at_a_new_step_size_equals_a_fresh_one(poroelastic):
    """The numeric factorisation at 600 s on the analysis made at 5 s: bit for bit the one made
    from scratch at 600 s, with no second analysis."""
    analyses = ldl.SymbolicAnalyses()
    BorderedLU(*_free_block(poroelastic, 5.0, True), analyses)
    held = analyses._held[0]
    M, nB = _free_block(poroelastic, 600.0, True)
    again = BorderedLU(M, nB, analyses)
    assert analyses._held == [held]
    fresh = BorderedLU(M, nB, ldl.SymbolicAnalyses())
    assert np.array_equal(again.schur, fresh.schur) and np.array_equal(again._D, fresh._D)
    for a, b in zip(again._L.arrays, fresh._L.arrays):
        assert np.array_equal(a, b)


def test_the_amalgamated_supernodes_hold_every_column_pattern(poroelastic):
    """Each supernode's rows hold the pattern of L in each of its columns (from a dense LDL^T of
    the bulk), and each child's update rows are among its parent's rows."""
    M, nB = _free_block(poroelastic, 5.0, True)
    first, width, row_at, rows, parent, children, relative = \
        ldl.SymbolicAnalyses().of(ldl._lower(M, nB), nB).tree
    assert np.sum(width) == nB and len(first) < nB / 4   # (supernodes, not columns)
    Md = M.toarray()
    # the pattern of L by a dense symbolic elimination of the bulk's pattern
    pattern = Md != 0
    for j in range(nB):
        below = np.flatnonzero(pattern[j + 1:, j]) + j + 1
        pattern[np.ix_(below[below < M.shape[0]], below[below < M.shape[0]])] |= True
    for t in range(len(first)):
        own = rows[row_at[t]:row_at[t + 1]]
        for j in range(first[t], first[t] + width[t]):
            assert set(np.flatnonzero(pattern[j:, j]) + j) <= set(own)
        if parent[t] >= 0:
            update = own[width[t]:]
            held = rows[row_at[parent[t]]:row_at[parent[t] + 1]]
            assert np.array_equal(held[relative[row_at[t] + width[t]:row_at[t + 1]]], update)
    assert np.bincount(parent[parent >= 0], minlength=len(first)).tolist() == children.tolist()


def test_a_zero_pivot_falls_back_to_superlu():
    """A symmetric block that needs pivoting (a zero diagonal entry): not factorised as LDL^T,
    the pivoting LU solves it."""
    rng = np.random.default_rng(4)
    n, nB = 12, 9
    A = rng.standard_normal((n, n))
    A = A + A.T + 10.0 * np.eye(n)
    A[0, 0], A[0, 1], A[1, 0] = 0.0, 5.0, 5.0   # (row 1 is the pivot of column 0)
    lu = BorderedLU(sp.csc_matrix(A), nB, ldl.SymbolicAnalyses())
    assert not lu.quasi_definite
    _check_against_dense(lu, sp.csc_matrix(A), nB, 5)


def test_the_solver_refactorises_a_poroelastic_bulk_on_one_analysis(poroelastic):
    """A step-size change: the bulk's new factors are the LDL^T on the analysis of the first,
    and its Schur complement matches numpy's at the new step size."""
    system = poroelastic.system
    assert system.lu.quasi_definite and not system.factors_any_dt
    held, count = list(system._analyses._held), system.factorizations
    dt = 2.5 * system.dt
    system.prepare(dt, None)
    assert system.factorizations == count + 1 and system._analyses._held == held
    assert _condensation_error(poroelastic, dt) < TOL


def _condensation_error(solver, dt):
    """The solver's Schur complement at ``dt`` (L_NN less its condensation P) against numpy's
    dense one, relative."""
    system = solver.system
    M, nB = _free_block(solver, dt, symmetric_form=False)
    M = M.toarray()
    exact = M[nB:, nB:] - M[nB:, :nB] @ np.linalg.solve(M[:nB, :nB], M[:nB, nB:])
    rows, cols, vals = system._LNN_entries
    L_NN = np.zeros_like(exact)
    L_NN[rows, cols] = vals
    return _rel(L_NN - system.P, exact)


def test_an_elastic_bulk_takes_the_ldl(elastic):
    """An elastic bulk (symmetric positive definite, factorised once for every step size) is
    factorised by the L D L^T too, and the solver's condensation P = L_NN - S matches numpy's
    dense Schur complement to TOL."""
    system = elastic.system
    assert system.factors_any_dt and system.lu.quasi_definite
    assert _condensation_error(elastic, system.dt) < TOL


def _fronts_by_blas(M, nB):
    """How many fronts of M's LDL^T meet ldl's thresholds for the BLAS panels."""
    first, width, row_at = ldl.SymbolicAnalyses().of(ldl._lower(M, nB), nB).tree[:3]
    below = np.diff(row_at) - width
    return int(np.count_nonzero((width >= ldl.BLAS_MIN_WIDTH) & (below >= ldl.BLAS_MIN_ROWS)))


@pytest.fixture
def every_front_by_blas(monkeypatch):
    """Every front with rows below its pivots through the BLAS panels (``_panel_by_blas``),
    not only the large ones."""
    monkeypatch.setattr(ldl, "BLAS_MIN_WIDTH", 1)
    monkeypatch.setattr(ldl, "BLAS_MIN_ROWS", 1)


@pytest.mark.parametrize("kind", ["poroelastic-5", "poroelastic-600", "elastic", "split"])
def test_the_blas_panels_against_dense(poroelastic, elastic, every_front_by_blas, kind):
    """The fronts by matrix products on blocks of each kind, every front of them so (the real
    blocks here are too small for the thresholds): against numpy's dense solves to 1e-11 and a
    backward error below 1e-15 (``_check_against_dense``), and against the loops' factors to
    1e-12 relative (round-off: the products sum in another order)."""
    if kind == "split":
        M, nB = _free_block(elastic, elastic.system.dt, symmetric_form=False)
        lu = SplitBorderedLU(M, nB, elastic.system.split, ldl.SymbolicAnalyses())
        assert all(part.quasi_definite for part in lu._parts)
        _check_against_dense(lu, M, nB, 7)
        return
    if kind == "elastic":
        M, nB = _free_block(elastic, elastic.system.dt, symmetric_form=False)
    else:
        M, nB = _free_block(poroelastic, float(kind.split("-")[1]), symmetric_form=True)
    assert _fronts_by_blas(M, nB) > 10
    lu = BorderedLU(M, nB, ldl.SymbolicAnalyses())
    assert lu.quasi_definite
    _check_against_dense(lu, M, nB, 6)
    ldl.BLAS_MIN_WIDTH = ldl.BLAS_MIN_ROWS = 10**9   # (the loops alone)
    loops = BorderedLU(M, nB, ldl.SymbolicAnalyses())
    assert _rel(lu.schur, loops.schur) < 1e-12 and _rel(lu._D, loops._D) < 1e-12
    assert _rel(lu._L.arrays[-1], loops._L.arrays[-1]) < 1e-12


@pytest.mark.parametrize("shared", [False, True])
@pytest.mark.parametrize("n, nB", [(260, 200), (140, 100), (133, 97)])
def test_a_wide_dense_front_by_panels(n, nB, shared, monkeypatch):
    """A dense quasi-definite block [[K, Q], [Q^T, -H]] (K, H positive definite), its last
    n - nB unknowns the border: one supernode as wide as the bulk, eliminated a panel of
    ldl.PANEL columns at a time, each panel's rows solved in blocks of ldl.SOLVE_BLOCK and
    updated in blocks of ldl.UPDATE_BLOCK (several of each, and partial last ones), against
    numpy to 1e-11 and the backward error below 1e-15. ``shared``: the front is the top's
    last, shared between two threads (``ldl._front_by_halves``: each panel's rows below and
    update in two halves), its factors in one and in two threads equal bit for bit."""
    monkeypatch.setattr(ldl, "SPLIT_FRONT_ABOVE", 0.0 if shared else np.inf)
    monkeypatch.setattr(ldl, "THREADS_ABOVE", 0.0)   # (two threads)
    rng = np.random.default_rng(n)
    k = nB // 2
    G = rng.standard_normal((n, n))
    A = G @ G.T / n + np.eye(n)
    A[k:, k:] = -A[k:, k:]
    A[:k, k:] *= 0.3
    A[k:, :k] = A[:k, k:].T
    M = sp.csc_matrix(A)
    first, width, row_at = ldl.SymbolicAnalyses().of(ldl._lower(M, nB), nB).tree[:3]
    assert len(first) == 1 and width[0] == nB
    assert _fronts_by_blas(M, nB) == 1
    assert ldl.SymbolicAnalyses().of(ldl._lower(M, nB), nB).split_front == (0 if shared else -1)
    analyses = ldl.SymbolicAnalyses()
    whole = BorderedLU(M, nB, analyses)
    lu = BorderedLU(M, nB, analyses)   # (a refactorisation: the front shared when ``shared``)
    assert lu.quasi_definite
    assert np.all(lu._D[:k] > 0) and np.all(lu._D[k:] < 0)
    _check_against_dense(lu, M, nB, 8)
    if shared:   # the same factors in one thread, and as the whole front's (ldl.SPLIT_ALIGN)
        monkeypatch.setattr(ldl, "THREADS_ABOVE", np.inf)
        one = BorderedLU(M, nB, analyses)
        for other in (one, whole):
            assert np.array_equal(other.schur, lu.schur) and np.array_equal(other._D, lu._D)
            assert all(np.array_equal(x, y) for x, y in zip(other._L.arrays, lu._L.arrays))


@pytest.mark.parametrize("shared", [False, True])
@pytest.mark.parametrize("kind", ["poroelastic-5", "poroelastic-600", "elastic", "split"])
def test_two_threads_give_the_factors_of_one(poroelastic, elastic, monkeypatch, kind, shared):
    """The two independent parts of the tree (``LDLSymbolic.parts``) factorised in two threads:
    the factors, pivots and Schur complement equal, bit for bit, those of the same parts one
    after the other; and against numpy's dense solves to 1e-11, the backward error below 1e-15
    (``_check_against_dense``). ``shared``: also the top's last front shared between the two
    threads (``ldl._front_by_halves``)."""
    monkeypatch.setattr(ldl, "SPLIT_FRONT_ABOVE", 0.0 if shared else np.inf)
    if kind in ("elastic", "split"):
        M, nB = _free_block(elastic, elastic.system.dt, symmetric_form=False)
    else:
        M, nB = _free_block(poroelastic, float(kind.split("-")[1]), symmetric_form=True)

    def factorise(threads_above, analyses):
        monkeypatch.setattr(ldl, "THREADS_ABOVE", threads_above)
        if kind == "split":
            return SplitBorderedLU(M, nB, elastic.system.split, analyses)
        return BorderedLU(M, nB, analyses)

    # (the front is shared at a refactorisation: the first factorisation on the analyses keeps
    # it whole, and gives the same factors bit for bit, ldl.SPLIT_ALIGN)
    analyses = [ldl.SymbolicAnalyses() for _ in range(2)]
    whole = [factorise(np.inf, a) for a in analyses]
    one, two = factorise(np.inf, analyses[0]), factorise(0.0, analyses[1])
    for a, b in zip(getattr(whole[0], "_parts", [whole[0]]), getattr(one, "_parts", [one])):
        assert np.array_equal(a.schur, b.schur) and np.array_equal(a._D, b._D)
        assert all(np.array_equal(x, y) for x, y in zip(a._L.arrays, b._L.arrays))
    for a, b in zip(getattr(one, "_parts", [one]), getattr(two, "_parts", [two])):
        assert a.quasi_definite and b.quasi_definite
        assert np.array_equal(a.schur, b.schur) and np.array_equal(a._D, b._D)
        for x, y in zip(a._L.arrays, b._L.arrays):
            assert np.array_equal(x, y)
    if kind != "split":   # (two parts of real work beside the top)
        symbolic = ldl.SymbolicAnalyses().of(ldl._lower(M, nB), nB)
        first_part, second_part, top = symbolic.parts
        assert len(first_part) > 10 and len(second_part) > 10 and len(top) >= 1
        assert (symbolic.split_front == top[-1]) if shared else symbolic.split_front == -1
    _check_against_dense(two, M, nB, 9)


@pytest.mark.parametrize("shared", [False, True])
@pytest.mark.parametrize("threads", [1, 2])
def test_one_root_adds_its_update_into_the_schur_complement_itself(poroelastic, monkeypatch,
                                                                    threads, shared):
    """A tree whose one root is the shared front (``shared``) adds that root's update straight
    into M_NN, both triangles (``_numeric``'s ``mirrored``, through the transpose for a
    Fortran-ordered M_NN); unshared, the roots' updates go through the parts' own arrays summed
    afterwards (also the path of a forest, and of an M_NN neither C- nor Fortran-ordered, here
    a strided view). Either way the Schur complement, the pivots and the packed L are equal
    bit for bit for the three layouts, and the Schur complement equals numpy's dense
    M_NN - M_NB B^-1 M_BN to 1e-11 of its largest entry."""
    monkeypatch.setattr(ldl, "SPLIT_FRONT_ABOVE", 0.0 if shared else np.inf)
    M, nB = _free_block(poroelastic, 600.0, symmetric_form=True)
    lower, M_NN = ldl._lower(M, nB), M[nB:, nB:].toarray()
    symbolic = ldl.SymbolicAnalyses().of(lower, nB)
    assert symbolic.roots == 1 and (symbolic.split_front >= 0) == shared
    ldl._numeric(lower, M_NN.copy(), symbolic, 1)   # (later ones are refactorisations)
    strided = np.zeros((M_NN.shape[0], 2 * M_NN.shape[1]))[:, ::2]
    made = {}
    for name, schur in (("C", M_NN.copy(order="C")), ("F", M_NN.copy(order="F")),
                        ("parts", strided)):
        schur[:] = M_NN
        values, diagonal, _ = ldl._numeric(lower, schur, symbolic, threads, share_front=shared)
        made[name] = (values, diagonal, np.array(schur))
    for name in ("C", "F"):
        assert all(np.array_equal(a, b) for a, b in zip(made[name], made["parts"]))
    dense = M.toarray()
    reference = dense[nB:, nB:] - dense[nB:, :nB] @ np.linalg.solve(dense[:nB, :nB],
                                                                     dense[:nB, nB:])
    assert _rel(made["C"][2], reference) < TOL


def test_the_second_half_assembles_after_the_calling_threads_fronts(poroelastic, monkeypatch):
    """The second thread reaches the shared front right after its part of the tree, while the
    calling thread may still run its own part and the top, whose updates the front's rows
    take: with each of the calling thread's ``_eliminate`` calls held back 50 ms, the second
    half must wait for them (``sync[4]``) before it assembles its rows, and the factors equal
    one thread's bit for bit (a half that did not wait reads those updates before they are
    made: other factors)."""
    monkeypatch.setattr(ldl, "SPLIT_FRONT_ABOVE", 0.0)
    M, nB = _free_block(poroelastic, 600.0, symmetric_form=True)
    analyses = ldl.SymbolicAnalyses()
    BorderedLU(M, nB, analyses)   # (the first factorisation: the front not shared yet)
    monkeypatch.setattr(ldl, "THREADS_ABOVE", np.inf)
    one = BorderedLU(M, nB, analyses)
    monkeypatch.setattr(ldl, "THREADS_ABOVE", 0.0)
    assert analyses.of(ldl._lower(M, nB), nB).split_front >= 0
    works = ldl._eliminate

    def late(*args):
        if threading.current_thread() is threading.main_thread():
            time.sleep(0.05)
        return works(*args)

    monkeypatch.setattr(ldl, "_eliminate", late)
    two = BorderedLU(M, nB, analyses)
    assert np.array_equal(one.schur, two.schur) and np.array_equal(one._D, two._D)
    assert all(np.array_equal(x, y) for x, y in zip(one._L.arrays, two._L.arrays))


@pytest.mark.parametrize("kernel", ["_eliminate", "_front_by_halves"])
def test_an_error_in_the_second_thread_reaches_the_caller(poroelastic, monkeypatch, kernel):
    """The second thread of a refactorisation (``ldl._in_background``: a part of the tree, or
    the second half of the shared front) failing: its own error is raised by the
    factorisation, in the calling thread (not printed and lost, nor a broken barrier), and the
    threads' next factorisation is whole again: the same factors bit for bit as one thread's."""
    monkeypatch.setattr(ldl, "SPLIT_FRONT_ABOVE", 0.0)
    M, nB = _free_block(poroelastic, 600.0, symmetric_form=True)
    analyses = ldl.SymbolicAnalyses()
    BorderedLU(M, nB, analyses)   # (the first factorisation: the front not shared yet)
    monkeypatch.setattr(ldl, "THREADS_ABOVE", 0.0)
    works = getattr(ldl, kernel)

    def failing(*args):
        if threading.current_thread() is not threading.main_thread():
            raise RuntimeError("the second thread failed")
        return works(*args)

    monkeypatch.setattr(ldl, kernel, failing)
    with pytest.raises(RuntimeError, match="the second thread failed"):
        BorderedLU(M, nB, analyses)
    monkeypatch.setattr(ldl, kernel, works)
    two = BorderedLU(M, nB, analyses)
    monkeypatch.setattr(ldl, "THREADS_ABOVE", np.inf)
    one = BorderedLU(M, nB, analyses)
    assert np.array_equal(one.schur, two.schur) and np.array_equal(one._D, two._D)
    assert all(np.array_equal(x, y) for x, y in zip(one._L.arrays, two._L.arrays))


def test_the_plan_of_a_forest_and_of_a_chain(monkeypatch):
    """Parts of trees without one branching top: a block-diagonal bulk (a forest of two
    independent roots: no top, the two trees the two parts) and a tridiagonal one (a single
    supernode's chain: one part); both against numpy to 1e-11, with the border."""
    rng = np.random.default_rng(11)
    n_half, n_N = 40, 6
    blocks = []
    for _ in range(2):
        G = rng.standard_normal((n_half, n_half))
        blocks.append(sp.csr_matrix(np.where(np.abs(G) > 1.2, G, 0.0) + 12.0 * np.eye(n_half)))
    B = sp.block_diag([X + X.T for X in blocks])
    Q = sp.random(2 * n_half, n_N, density=0.2, random_state=3)
    M = sp.bmat([[B, Q], [Q.T, -np.eye(n_N)]]).tocsc()
    nB = 2 * n_half
    symbolic = ldl.SymbolicAnalyses().of(ldl._lower(M, nB), nB)
    first_part, second_part, top = symbolic.parts
    assert len(first_part) > 0 and len(second_part) > 0 and len(top) == 0
    _check_plan(symbolic)
    for threads_above in (np.inf, 0.0):
        monkeypatch.setattr(ldl, "THREADS_ABOVE", threads_above)
        lu = BorderedLU(M, nB, ldl.SymbolicAnalyses())
        assert lu.quasi_definite
        _check_against_dense(lu, M, nB, 10)
    T = sp.diags([np.full(nB - 1, -1.0), np.full(nB, 4.0), np.full(nB - 1, -1.0)], [-1, 0, 1])
    M = sp.bmat([[T, Q], [Q.T, -np.eye(n_N)]]).tocsc()
    symbolic = ldl.SymbolicAnalyses().of(ldl._lower(M, nB), nB)
    first_part, second_part, top = symbolic.parts
    assert len(first_part) == len(second_part) == 0   # (no two parts: the top is all)
    _check_plan(symbolic)
    lu = BorderedLU(M, nB, ldl.SymbolicAnalyses())
    assert lu.quasi_definite
    _check_against_dense(lu, M, nB, 12)


def _check_plan(symbolic):
    """The parts of ``LDLSymbolic.parts`` partition the supernodes; the first two are whole
    subtrees (every descendant of one of their supernodes in the same part), the top holds the
    parent of each of its supernodes, and the stack counts (``stacked``) are the children in a
    supernode's own part."""
    first, width, row_at, srows, tparent, children, relative = symbolic.tree
    n_sn = len(width)
    part_of = np.full(n_sn, -1)
    for k, part in enumerate(symbolic.parts):
        assert np.all(np.diff(part) > 0) and np.all(part_of[part] == -1)
        part_of[part] = k
    assert np.all(part_of >= 0)
    for t in range(n_sn):
        p = tparent[t]
        if p != -1:
            assert part_of[p] == part_of[t] or part_of[p] == 2
        assert part_of[t] != 2 or p == -1 or part_of[p] == 2
        kids = symbolic.child_list[symbolic.child_ptr[t]:symbolic.child_ptr[t + 1]]
        assert np.all(tparent[kids] == t) and len(kids) == children[t]
        assert np.all(np.diff(kids) < 0)   # (reverse postorder: the order a stack pops them)
        assert symbolic.stacked[t] == np.count_nonzero(part_of[kids] == part_of[t])


def _contiguous_cut_path(symbolic):
    """The longer path (a part beside the other, then the top) of the plan that preceded the
    balanced one: the top the root's line of only children, the subtrees of its children cut
    into two runs of the postorder where their multiply-adds were nearest half and half."""
    first, width, row_at, srows, tparent, children, relative = symbolic.tree
    work = sum(ldl.front_multiply_adds(width, np.diff(row_at) - width))
    top, kids = len(width), np.flatnonzero(tparent == -1)
    while len(kids) == 1:
        top = int(kids[0])
        kids = np.flatnonzero(tparent == top)
    ends = np.sort(kids) + 1
    done = np.cumsum(work[:top])[ends - 1]
    cut = int(ends[np.argmin(np.abs(done - done[-1] / 2.0))])
    return max(work[:cut].sum(), work[cut:top].sum()) + work[top:].sum()


def _three_branching_blocks(half, n_N=40):
    """A bulk of three independent blocks, each two dense halves of ``half`` unknowns joined by
    a separator unknown, with a border of ``n_N`` fault unknowns coupled to each separator
    (rows unlike the halves': the separator stays a supernode of its own): (M, nB)."""
    rng = np.random.default_rng(14)
    blocks, n = [], 2 * half + 1
    for _ in range(3):
        K = np.zeros((n, n))
        for start in (0, half):
            G = rng.standard_normal((half, half))
            K[start:start + half, start:start + half] = G @ G.T + half * np.eye(half)
        K[n - 1, n - 1] = 4.0
        K[half - 1, n - 1] = K[n - 1, half - 1] = K[n - 2, n - 1] = K[n - 1, n - 2] = -1.0
        blocks.append(sp.csr_matrix(K))
    B = sp.block_diag(blocks).tocsr()
    nB = B.shape[0]
    Q = sp.lil_matrix((nB, n_N))
    for k in range(3):
        Q[(k + 1) * n - 1, :] = 0.1 * rng.standard_normal(n_N)
    return sp.bmat([[B, Q], [Q.T, -np.eye(n_N)]]).tocsc(), nB


@pytest.mark.parametrize("dt", [5.0, 600.0])
def test_the_parts_are_balanced_by_their_multiply_adds(poroelastic, elastic, dt):
    """Subtree-to-thread mapping (``LDLSymbolic._plan``): the parts partition the tree as the
    numeric factorisation needs (``_check_plan``), and the longer path of multiply-adds (the
    larger of the two parts, then the top) is no longer than that of cutting the top's
    children into two runs of the postorder (the plan it replaced) on real blocks; on three
    equal independent blocks (a forest: the old plan ran two of them beside one) one block is
    split (its separator into the top, its two halves dealt), which makes the path at most
    0.8 of the old one (3/4 plus the separator's front) and the parts within BALANCE."""
    paths = []
    for solver, symmetric in ((poroelastic, True), (elastic, False)):
        M, nB = _free_block(solver, dt if symmetric else solver.system.dt, symmetric)
        paths.append(_paths(ldl.SymbolicAnalyses().of(ldl._lower(M, nB), nB)))
    assert all(path <= before for path, before, _ in paths)
    M, nB = _three_branching_blocks(40)
    symbolic = ldl.SymbolicAnalyses().of(ldl._lower(M, nB), nB)
    path, before, loads = _paths(symbolic)
    assert path <= 0.8 * before
    assert abs(loads[0] - loads[1]) <= ldl.BALANCE * (loads[0] + loads[1])
    assert len(symbolic.parts[2]) == 1
    lu = BorderedLU(M, nB, ldl.SymbolicAnalyses())
    assert lu.quasi_definite
    _check_against_dense(lu, M, nB, 13)


def _paths(symbolic):
    """(the longer path of ``symbolic``'s plan, of the contiguous cut, the parts' loads), the
    plan checked (``_check_plan``) and its loads summing to the multiply-adds."""
    _check_plan(symbolic)
    first, width, row_at = symbolic.tree[:3]
    work = sum(ldl.front_multiply_adds(width, np.diff(row_at) - width))
    loads = [work[part].sum() for part in symbolic.parts]
    assert np.isclose(sum(loads), symbolic.multiply_adds, rtol=1e-12)
    return max(loads[:2]) + loads[2], _contiguous_cut_path(symbolic), loads


def test_off_linux_a_factorisation_takes_one_thread(poroelastic, monkeypatch):
    """The two threads' waits call Linux's clock_gettime and usleep: on another platform a
    factorisation that would take two threads (THREADS_ABOVE at 0) starts none, and its
    factors are those of one thread bit for bit."""
    M, nB = _free_block(poroelastic, 600.0, symmetric_form=True)
    monkeypatch.setattr(ldl, "THREADS_ABOVE", np.inf)
    one = BorderedLU(M, nB, ldl.SymbolicAnalyses())
    monkeypatch.setattr(ldl, "THREADS_ABOVE", 0.0)
    monkeypatch.setattr(ldl.sys, "platform", "win32")

    def no_thread(*args):
        raise AssertionError("a second thread was started")

    monkeypatch.setattr(ldl, "_in_background", no_thread)
    other = BorderedLU(M, nB, ldl.SymbolicAnalyses())
    assert np.array_equal(one.schur, other.schur) and np.array_equal(one._D, other._D)
    assert all(np.array_equal(x, y) for x, y in zip(one._L.arrays, other._L.arrays))

"""The BLAS fronts' dgemm on blocks of a front and of its rows below in place
(fault_screen/ldl.py: ``_gemm_less``, ``_panel_rows``, ``_panel_update``) against numpy's
dense products, and the fronts that the thresholds ``ldl.BLAS_MIN_WIDTH`` / ``BLAS_MIN_ROWS``
send through it on real blocks against dense solves.

The update writes into a row-major front through BLAS's column-major view of it (leading
dimension m, an offset for the panel): a wrong leading dimension, offset, transpose or block
edge puts products on wrong entries, which the checks below see as errors of order one, far
above their tolerances (1e-12 relative: round-off of sums of at most a few hundred products),
or as entries changed that must not change (checked bit for bit)."""
import numpy as np
import pytest
import scipy.sparse as sp

from fault_screen import Scene, ldl
from fault_screen.bordered_lu import BorderedLU

from conftest import CONFIGS
from test_ldl import _check_against_dense, _free_block, _solver

TOL = 1e-12


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


@pytest.mark.parametrize("a_transposed", [True, False])
def test_gemm_less_on_blocks_of_one_array(a_transposed):
    """C -= A B, A given as it is or by its transpose, A, B and C disjoint blocks of one array
    with leading dimensions larger than their rows (BLAS's column-major terms): C against
    numpy, every other entry unchanged."""
    rng = np.random.default_rng(3)
    ld, columns = 41, 60
    x = rng.standard_normal(ld * columns)
    view = x.reshape(columns, ld).T        # column-major ld x columns: view[i, j] = x[j ld + i]
    rows, cols, inner = 17, 23, 9
    # A: rows x inner at view[0:rows, 2:2 + inner], or A^T: inner x rows at
    # view[0:inner, 2:2 + rows]; B: inner x cols at view[0:inner, 30:53]; C: rows x cols at
    # view[12:29, 30:53] (rows 12.. of the same columns as B: no entry shared)
    a = view[0:inner, 2:2 + rows].T.copy() if a_transposed else view[0:rows, 2:2 + inner].copy()
    b = view[0:inner, 30:30 + cols].copy()
    expected = view[12:12 + rows, 30:30 + cols] - a @ b
    before = x.copy()
    ldl._gemm_less(a_transposed, rows, cols, inner, x, 2 * ld, ld, x, 30 * ld, ld, x,
                   30 * ld + 12, ld)
    assert _rel(view[12:12 + rows, 30:30 + cols], expected) < TOL
    changed = np.zeros_like(view, dtype=bool)
    changed[12:12 + rows, 30:30 + cols] = True
    assert np.array_equal(view[~changed], before.reshape(columns, ld).T[~changed])


def _quasi_definite(n, k, rng):
    """A dense quasi-definite block [[K, Q], [Q^T, -H]], K (k x k) and H positive definite."""
    G = rng.standard_normal((n, n))
    A = G @ G.T / n + np.eye(n)
    A[k:, k:] = -A[k:, k:]
    A[:k, k:] *= 0.3
    A[k:, :k] = A[:k, k:].T
    return A


def _dense_ldl(P):
    """L (unit lower) and d of P = L diag(d) L^T, P definite (either sign), by Cholesky of
    +-P: the reference for a panel's pivot block."""
    sign = 1.0 if P[0, 0] > 0 else -1.0
    C = np.linalg.cholesky(sign * P)
    diag = np.diag(C)
    return C / diag, sign * diag ** 2


@pytest.mark.parametrize("c0, b", [(37, 50), (150, 41)])   # (pivots > 0; pivots < 0)
def test_a_panel_of_a_front_in_place(c0, b):
    """One panel of a front eliminated as ``_eliminate`` does for a BLAS front: its pivot
    block (``_pivot_block``), its rows below (``_panel_rows``) and their update of the trailing
    block by dgemm in place (``_panel_update``: more rows than ldl.UPDATE_BLOCK, a partial last
    block), the panel starting inside the front (offset c0 m + c0, row stride m), against
    numpy: L11, d, L21 = F21 L11^-T D^-1 and the trailing block F22 - L21 D L21^T (lower
    triangles) to 1e-12 relative; the front's entries left of and above the panel unchanged
    bit for bit. The first panel's pivots lie in K (positive), the second's in -H (negative)."""
    m, k = 320, 140
    rng = np.random.default_rng(c0)
    n = m - c0
    A = _quasi_definite(m, k, rng)
    front = A.copy()                       # row-major m x m, read in its lower triangle only
    front[np.triu_indices(m, 1)] = np.nan  # (never read: a NaN read would spread)
    front = front.reshape(-1)
    before = front.copy()
    u = n - b
    assert u > ldl.UPDATE_BLOCK and u % ldl.UPDATE_BLOCK
    o = c0 * m + c0
    diagonal = np.empty(b)
    ldl._pivot_block(front, m, o, b, diagonal, 0, np.empty(b))
    xt, dlrows = np.empty(b * u), np.empty(b * u)
    strip = np.empty(ldl.SOLVE_BLOCK * b)
    ldl._panel_rows(front, m, o, b, diagonal, 0, u, xt, dlrows, strip)
    ldl._panel_update(front, m, o, b, dlrows, 0, u)

    F = A[c0:, c0:]
    L11, d = _dense_ldl(F[:b, :b])
    L21 = np.linalg.solve(L11, F[b:, :b].T).T / d
    trailing = F[b:, b:] - (L21 * d) @ L21.T
    got = front.reshape(m, m)[c0:, c0:]
    lower = np.tril_indices(b, -1)
    assert _rel(got[:b, :b][lower], L11[lower]) < TOL
    assert _rel(diagonal, d) < TOL and np.all(np.sign(diagonal) == np.sign(F[0, 0]))
    assert _rel(got[b:, :b], L21) < TOL
    assert _rel(np.tril(got[b:, b:]), np.tril(trailing)) < TOL
    assert _rel(dlrows, (L21 * d).reshape(-1)) < TOL   # (L21 D, by rows: the update's B)
    # left of and above the panel (earlier panels' columns, rows): untouched
    outside = np.ones((m, m), dtype=bool)
    outside[c0:, c0:] = False
    assert np.array_equal(front.reshape(m, m)[outside], before.reshape(m, m)[outside],
                          equal_nan=True)


@pytest.fixture(scope="module")
def poroelastic():
    """The Newton solver of a permeable-rock scene (mass balance verification, 24 x 25)."""
    return _solver(Scene.from_toml(CONFIGS / "verification" / "mass-balance.toml"))


@pytest.mark.parametrize("dt", [5.0, 600.0])
def test_the_fronts_at_the_default_thresholds_against_dense(poroelastic, dt):
    """With the default thresholds some fronts of a small real poroelastic block go through
    BLAS, among them fronts narrower than 16 columns or with fewer than 32 rows below (the
    ones the thresholds of 8 and 16 added): its LDL^T against numpy's dense solves to 1e-11
    and a backward error below 1e-15 (``test_ldl._check_against_dense``), and against the
    loops alone (no front by BLAS) to 1e-12 relative."""
    M, nB = _free_block(poroelastic, dt, symmetric_form=True)
    symbolic = ldl.SymbolicAnalyses().of(ldl._lower(M, nB), nB)
    first, width, row_at = symbolic.tree[:3]
    below = np.diff(row_at) - width
    blas = (width >= ldl.BLAS_MIN_WIDTH) & (below >= ldl.BLAS_MIN_ROWS)
    assert np.count_nonzero(blas & ((width < 16) | (below < 32))) > 0
    lu = BorderedLU(M, nB, ldl.SymbolicAnalyses())
    assert lu.quasi_definite
    _check_against_dense(lu, M, nB, 9)
    saved = ldl.BLAS_MIN_WIDTH, ldl.BLAS_MIN_ROWS
    try:
        ldl.BLAS_MIN_WIDTH = ldl.BLAS_MIN_ROWS = 10**9
        loops = BorderedLU(M, nB, ldl.SymbolicAnalyses())
    finally:
        ldl.BLAS_MIN_WIDTH, ldl.BLAS_MIN_ROWS = saved
    assert _rel(lu.schur, loops.schur) < TOL and _rel(lu._D, loops._D) < TOL
    assert _rel(lu._L.arrays[-1], loops._L.arrays[-1]) < TOL


def test_a_shared_front_with_an_empty_half_of_rows(monkeypatch):
    """A dense front of 40 pivots (wider than ldl.SOLVE_BLOCK: its rows below take a product
    per block) shared between two threads (``ldl._front_by_halves``) with exactly ldl.SPLIT_ALIGN
    rows below them: the cut leaves one thread no rows, so its products are empty (skipped:
    BLAS takes their leading dimension of 0 as an error). Against numpy to 1e-11 and a
    backward error below 1e-15 (``test_ldl._check_against_dense``), and equal bit for bit to
    the factors in one thread."""
    monkeypatch.setattr(ldl, "SPLIT_FRONT_ABOVE", 0.0)
    monkeypatch.setattr(ldl, "THREADS_ABOVE", 0.0)   # (two threads)
    nB = 40
    n = nB + ldl.SPLIT_ALIGN
    M = sp.csc_matrix(_quasi_definite(n, nB // 2, np.random.default_rng(n)))
    analyses = ldl.SymbolicAnalyses()
    BorderedLU(M, nB, analyses)   # (the first factorisation: the front is shared at the next)
    assert analyses.of(ldl._lower(M, nB), nB).split_front == 0
    two = BorderedLU(M, nB, analyses)
    _check_against_dense(two, M, nB, 10)
    monkeypatch.setattr(ldl, "THREADS_ABOVE", np.inf)
    one = BorderedLU(M, nB, analyses)
    assert np.array_equal(one.schur, two.schur) and np.array_equal(one._D, two._D)
    assert all(np.array_equal(x, y) for x, y in zip(one._L.arrays, two._L.arrays))

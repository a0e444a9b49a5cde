"""The triangular sweeps through factors packed by supernodes (bordered_lu._pack,
_forward_sweep, _backward_sweep) against dense triangular solves.

The factors are made up so that every path of the kernels is taken: supernodes one to thirteen
columns wide, with none to eleven rows below their triangle (each remainder of the four-row groups),
and a border of rows beyond the swept columns (the condensed unknowns). The backward sweep is
checked in the three forms the factorisations use: the packed matrix itself read in its own order
(U of an unsymmetric block, packed for the backward sweep), and L with a separate diagonal read
last supernode first (U = D L^T of a symmetric or quasi-definite block), with and without that
diagonal.
"""
import numpy as np
import pytest
import scipy.linalg
import scipy.sparse as sp

from fault_screen.bordered_lu import _NO_DIAGONAL, _backward_sweep, _forward_sweep, _pack

#: relative to the largest entry of the reference: round-off of a well conditioned solve (the
#: sums are taken in another order than LAPACK's, ~1e-15)
TOL = 1e-12

WIDTHS = [1, 3, 13, 2, 5, 1, 8, 4, 7, 1, 6, 2]
BORDER = 9


def _made_up_factor(seed, unit_diagonal):
    """A lower triangular (n + BORDER) x n matrix whose columns form the supernodes of WIDTHS:
    within a supernode each column's rows are those of the one before without it."""
    rng = np.random.default_rng(seed)
    n = sum(WIDTHS)
    L = np.zeros((n + BORDER, n))
    j0 = 0
    for s, w in enumerate(WIDTHS):
        below = np.arange(j0 + w, n + BORDER)
        # none to eleven rows below the triangle, always some of the border's rows among them
        count = min(len(below), s % 12)
        rows = np.sort(rng.choice(below, size=count, replace=False))
        for c in range(w):
            L[j0 + c:j0 + w, j0 + c] = rng.uniform(-0.5, 0.5, w - c)
            L[rows, j0 + c] = rng.uniform(-0.5, 0.5, count)
        j0 += w
    diagonal = np.arange(n)
    L[diagonal, diagonal] = 1.0 if unit_diagonal else rng.uniform(1.0, 2.0, n)
    return L, n


def _packed(L, n, for_backward):
    A = sp.csc_matrix(L)
    A.sort_indices()
    return _pack(A.indptr, A.indices.astype(np.int64), A.data, n, for_backward)


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


def test_packed_factor_holds_no_zero_and_no_entry_twice():
    """Each supernode's triangle is stored up to its diagonal only: the packed values are L's
    entries, none more (the made-up blocks are dense: every stored value is an entry)."""
    L, n = _made_up_factor(3, True)
    first, width, row_at, value_at, rows, values = _packed(L, n, False)
    assert len(values) == np.count_nonzero(L) and np.count_nonzero(values) == len(values)
    assert np.array_equal(np.sort(values), np.sort(L[L != 0]))


def test_made_up_factor_has_the_supernodes_meant():
    """(The check that the factors below exercise what they claim to.)"""
    L, n = _made_up_factor(0, True)
    first, width, row_at, value_at, rows, values = _packed(L, n, False)
    assert width.sum() == n and width.max() == 13
    below = np.diff(row_at) - width
    assert set(below % 4) == {0, 1, 2, 3} and below.max() >= 8


@pytest.mark.parametrize("seed", [1, 2])
def test_forward_sweep_solves_the_unit_lower_triangle(seed):
    L, n = _made_up_factor(seed, True)
    r = np.random.default_rng(10 + seed).standard_normal(n + BORDER)
    swept = r.copy()
    _forward_sweep(*_packed(L, n, False), swept)
    y = scipy.linalg.solve_triangular(L[:n], r[:n], lower=True, unit_diagonal=True)
    assert _rel(swept[:n], y) < TOL
    assert _rel(swept[n:], r[n:] - L[n:] @ y) < TOL


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("form", ["packed for backward", "L read backwards", "L and D"])
def test_backward_sweep_solves_the_transposed_triangle(seed, form):
    """V^T x = c for x[:n], x[n:] (the border's unknowns) given, with V = L itself or L D."""
    unit = form == "L and D"
    L, n = _made_up_factor(seed, unit)
    rng = np.random.default_rng(20 + seed)
    x = rng.standard_normal(n + BORDER)
    diagonal = rng.uniform(0.5, 3.0, n) if unit else _NO_DIAGONAL
    V = L * diagonal[None, :] if unit else L
    exact = scipy.linalg.solve_triangular(V[:n].T, x[:n] - V[n:].T @ x[n:], lower=False)
    packed = _packed(L, n, for_backward=form == "packed for backward")
    _backward_sweep(*packed, diagonal, form != "packed for backward", x)
    assert _rel(x[:n], exact) < TOL

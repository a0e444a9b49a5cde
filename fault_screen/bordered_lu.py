"""Sparse LU of the free system with the condensed (fault) unknowns ordered last.

With the linear block B in a fill-reducing order and the condensed unknowns N after it,

    [ B     L_BN ]   [ L11      ] [ U11  U12 ]
    [ L_NB  L_NN ] = [ L21  L22 ] [      U22 ]       (row pivoting kept inside each block)

one sparse factorisation gives everything the Newton iteration on the fault needs:
- the Schur complement S = L_NN - L_NB B^-1 L_BN = L22 U22 (dense, n_N x n_N), which a column
  by column condensation would get from n_N solves with B (seconds for a thousand fault unknowns,
  against a fraction of a second here);
- the condensed right-hand side r_N - L_NB B^-1 r_B = r_N - L21 (L11^-1 r_B): a forward sweep;
- the bulk's answer to a fault update dx_N, B^-1 (r_B - L_BN dx_N) = U11^-1 (L11^-1 r_B - U12 dx_N):
  a backward sweep, once per step for the sum of the step's fault updates.
A step thus costs one sweep each way through the factors instead of two solves with B (or one
solve and a product with the dense n_B x n_N matrix B^-1 L_BN).

The sweeps are column-oriented numba loops over the factors as SuperLU gives them (CSC); the
upper factor is stored with its rows and columns reversed (J U11 J is lower triangular), so that
the backward sweep too reads memory forwards (three times faster than walking it backwards on
this machine), and no factor is ever held twice over.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla

from ._jit import kernel


@kernel
def _lower_solve_by_columns(indptr, indices, data, r, n_columns, unit_diagonal):
    """Forward substitution with the first ``n_columns`` columns of a lower triangular matrix in
    CSC with sorted row indices (the diagonal first in each column): r[:n_columns] becomes the
    solution and the rows below are updated with it (they receive L21 y)."""
    for j in range(n_columns):
        start = indptr[j]
        yj = r[j] if unit_diagonal else r[j] / data[start]
        r[j] = yj
        if yj != 0.0:
            for k in range(start + 1, indptr[j + 1]):
                r[indices[k]] -= data[k] * yj


class PivotingAcrossBlocks(RuntimeError):
    """The factorisation swapped a row of the linear block with a condensed one: the trailing
    factors are then not the Schur complement's."""


class BorderedLU:
    """LU of ``M`` (CSC, n x n) whose first ``n_linear`` rows and columns are the linear block in
    the order to factorise it and whose last ones are the condensed unknowns.

    Vectors passed to and returned by ``forward``/``backward`` are in ``M``'s order (the caller
    permutes once); ``schur`` is the dense Schur complement on the condensed unknowns (the
    sweeps do not read it: its owner may take it and set it to None).

    ``M`` may also be a function that returns it, so that the caller holds no reference: the
    matrix then goes before the factors are copied out of SuperLU (the peak)."""

    def __init__(self, M, n_linear: int):
        if callable(M):
            M = M()
        n = M.shape[0]
        nB = n_linear
        lu = None
        # SuperLU keeps the given column order (NATURAL) and, with SymmetricMode, prefers the
        # diagonal pivot; the scaled block's diagonal dominates, so rows stay within their block.
        # If they do not, diagonal pivots only (threshold 0) are tried before giving up.
        for threshold in (None, 0.0):
            lu = spla.splu(M, permc_spec="NATURAL", diag_pivot_thresh=threshold,
                           options=dict(SymmetricMode=True))
            if np.all(lu.perm_r[:nB] < nB):
                break
        else:
            raise PivotingAcrossBlocks("the linear block's factorisation pivoted on a condensed row")
        del M
        self.n, self.n_linear = n, nB
        # SuperLU's own storage is freed as soon as the factors are copied out of it: perm_r is a
        # view into that object (a slice of it kept alive the whole factorisation, ~340 MB on
        # Rustrel 200 x 201), so it is copied too. scipy makes L and U together at the first
        # access; SuperLU's storage and those copies are the peak, which nothing below exceeds
        # (U11's reversed copy, below, is smaller than SuperLU's storage freed before it).
        rows_of = np.array(lu.perm_r)   # row i of M is row perm_r[i] of L U
        U, L = lu.U, lu.L
        del lu
        self._row_B = rows_of[:nB].copy()
        self._row_N = rows_of[nB:] - nB
        # no factor is held twice over: the backward sweep walks U11 reversed (J U11 J, lower
        # triangular), which reversing U's arrays gives directly, and the forward sweep walks L
        # by columns as SuperLU gives it
        U.sort_indices()
        self._U12 = U[:nB, nB:].tocsr()
        U22 = U[nB:, nB:].toarray()
        end_B = int(U.indptr[nB])
        lengths = np.diff(U.indptr[:nB + 1])[::-1]
        indptr = np.zeros(nB + 1, dtype=U.indptr.dtype)
        np.cumsum(lengths, out=indptr[1:])
        self.nnz = U.nnz  # fill, for diagnostics
        # U11's columns reversed, copied out of U's arrays, which then go (with U12 and U22)
        indices = U.indices[end_B - 1::-1] if end_B else U.indices[:0]
        indices = np.subtract(nB - 1, indices, dtype=U.indices.dtype)
        data = U.data[end_B - 1::-1].copy() if end_B else U.data[:0].copy()
        del U
        self._U11_reversed = (indptr, indices, data)
        _check_diagonal_first(indptr, indices, nB)
        L.sort_indices()
        self.nnz += L.nnz
        # the trailing columns (L22, dense, n_N^2 / 2) stay in the arrays the sweep reads
        self._L = (L.indptr, L.indices, L.data)
        _check_diagonal_first(L.indptr, L.indices, nB)
        S = L[nB:, nB:].toarray() @ U22   # (rows in pivot order) = L22 U22
        del L, U22
        self.schur = np.ascontiguousarray(S[self._row_N])

    def forward(self, r_linear, r_condensed):
        """(L11^-1 P r_B, r_N - L_NB B^-1 r_B): the swept linear right-hand side (to hand back to
        ``backward``) and the condensed right-hand side."""
        nB = self.n_linear
        r = np.empty(self.n)
        r[self._row_B] = r_linear
        r[nB + self._row_N] = r_condensed
        _lower_solve_by_columns(*self._L, r, nB, True)
        return r[:nB], r[nB:][self._row_N]

    def backward(self, c, x_condensed):
        """B^-1 (r_B - L_BN x_N) from the swept c = ``forward(r_B, .)[0]`` (None: r_B = 0)."""
        z = np.zeros(self.n_linear) if c is None else c.copy()
        if len(x_condensed):
            z -= self._U12 @ x_condensed
        z = z[::-1].copy()
        _lower_solve_by_columns(*self._U11_reversed, z, self.n_linear, False)
        return z[::-1]


def _check_diagonal_first(indptr, indices, n):
    """The sweeps read each column's diagonal as its first entry (sorted, lower triangular)."""
    if n and not np.array_equal(indices[indptr[:n]], np.arange(n)):
        raise PivotingAcrossBlocks("a factor column does not start at its diagonal")

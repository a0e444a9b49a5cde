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

The sweeps are row-oriented numba loops over CSR copies of the factors; the upper factor is stored
with its rows and columns reversed, so that the backward sweep reads memory forwards (three times
faster than walking it backwards on this machine).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ._jit import kernel


@kernel
def _unit_lower_solve(indptr, indices, data, r):
    """r <- L^-1 r in place, L unit lower triangular given by its strictly lower part (CSR)."""
    for i in range(r.shape[0]):
        acc = r[i]
        for k in range(indptr[i], indptr[i + 1]):
            acc -= data[k] * r[indices[k]]
        r[i] = acc


@kernel
def _lower_solve(indptr, indices, data, diagonal, r):
    """r <- L^-1 r in place, L lower triangular: strictly lower part (CSR) and its diagonal."""
    for i in range(r.shape[0]):
        acc = r[i]
        for k in range(indptr[i], indptr[i + 1]):
            acc -= data[k] * r[indices[k]]
        r[i] = acc / diagonal[i]


class PivotingAcrossBlocks(RuntimeError):
    """The factorisation swapped a row of the linear block with a condensed one: the trailing
    factors are then not the Schur complement's."""


class BorderedLU:
    """LU of ``M`` (CSC, n x n) whose first ``n_linear`` rows and columns are the linear block in
    the order to factorise it and whose last ones are the condensed unknowns.

    Vectors passed to and returned by ``forward``/``backward`` are in ``M``'s order (the caller
    permutes once); ``schur`` is the dense Schur complement on the condensed unknowns."""

    def __init__(self, M, n_linear: int):
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
        self.n, self.n_linear = n, nB
        self.nnz = lu.L.nnz + lu.U.nnz
        rows_of = lu.perm_r   # row i of M is row perm_r[i] of L U
        self._row_B = np.ascontiguousarray(rows_of[:nB])
        self._row_N = np.ascontiguousarray(rows_of[nB:] - nB)
        L = lu.L.tocsr()
        U = lu.U.tocsr()
        del lu
        self._L11 = sp.tril(L[:nB, :nB], k=-1, format="csr")
        self._L21 = L[nB:, :nB].tocsr()
        self._U12 = U[:nB, nB:].tocsr()
        # S (rows in pivot order) = L22 U22: back to M's row order
        S = L[nB:, nB:].toarray() @ U[nB:, nB:].toarray()
        self.schur = np.ascontiguousarray(S[self._row_N])
        del L, S
        flip = np.arange(nB)[::-1]
        U11 = U[:nB, :nB]
        self._diag_rev = np.ascontiguousarray(U11.diagonal()[flip])
        self._U11_rev = sp.tril(U11[flip][:, flip], k=-1, format="csr")
        self._U11_rev.sort_indices()
        self._L11.sort_indices()

    def forward(self, r_linear, r_condensed):
        """(L11^-1 P r_B, r_N - L_NB B^-1 r_B): the swept linear right-hand side (to hand back to
        ``backward``) and the condensed right-hand side."""
        c = np.empty(self.n_linear)
        c[self._row_B] = r_linear
        _unit_lower_solve(self._L11.indptr, self._L11.indices, self._L11.data, c)
        if len(r_condensed) == 0:
            return c, r_condensed.copy()
        return c, r_condensed - (self._L21 @ c)[self._row_N]

    def backward(self, c, x_condensed):
        """B^-1 (r_B - L_BN x_N) from the swept c = ``forward(r_B, .)[0]`` (None: r_B = 0)."""
        z = np.zeros(self.n_linear) if c is None else c.copy()
        if len(x_condensed):
            z -= self._U12 @ x_condensed
        z = z[::-1].copy()
        _lower_solve(self._U11_rev.indptr, self._U11_rev.indices, self._U11_rev.data,
                     self._diag_rev, z)
        return z[::-1]

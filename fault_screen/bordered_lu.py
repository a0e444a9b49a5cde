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

The sweeps are numba loops over the factors packed by supernodes (runs of columns with one row
pattern; nested dissection makes its separators such runs): L by columns, U by rows (the columns
of U^T), each stored in the order its sweep reads it, so both read memory forwards. Below its
triangle a supernode is a dense block: a row index is read once per block row, not per entry,
and the sums run four at a time (one sum alone is a chain of dependent adds); the sweeps index
with unsigned integers, which LLVM vectorises along a block row (``ldl._unsigned``: a plain
cast, where a helper's IR would be inlined at each of its calls). A supernode's diagonal
block is stored up to its diagonal only (a square block's zeros above it were a tenth of the
values on Rustrel 200 x 201: 124 against 113 MB, and the sweeps read every value stored). The
sweeps are memory-bound: on the two cores of the reference machine one thread streams 10-13 GB/s
through factors larger than the cache. No factor is ever held twice over. A large linear
block is factorised in parts, one after the other (``SplitBorderedLU``: halves or quarters),
which divides the factorisation's peak memory, and its parts are swept by two threads
(``_each_part``); an elastic (symmetric) one holds L and U's diagonal only.
"""
from __future__ import annotations

import functools
import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.linalg
from scipy.linalg.blas import dgemm as _gemm
from scipy.linalg.lapack import dgetrs as _getrs

from . import ldl
from ._jit import helper, kernel, sweep_kernel
from .ldl import NotQuasiDefinite, _unsigned  # noqa: F401  (_unsigned: the sweeps' index cast)


@functools.cache
def _libc_malloc_trim():
    """glibc's malloc_trim, or None (another C library). Looked up in the C library the
    process already has loaded: ``ctypes.util.find_library`` would start ``ldconfig``."""
    import ctypes

    for name in (None, "libc.so.6"):
        try:
            return ctypes.CDLL(name).malloc_trim
        except (OSError, AttributeError):
            continue
    return None


def release_freed_memory():
    """Hand the heap memory that Python and numpy freed back to the system (glibc keeps it, in
    pieces too small for its own use by a large allocation, which SuperLU's factors then take
    from fresh pages: the assembly's triplets, ~150 MB on Rustrel 200 x 201, stayed resident
    under the factorisation's peak)."""
    trim = _libc_malloc_trim()
    if trim is not None:
        trim(0)


def lu_solve(factors, b):
    """``scipy.linalg.lu_solve(factors, b)`` without its batching wrapper (the same LAPACK getrs,
    the same result bits; 20 us less per call, a thousand calls a Rustrel run).

    The pivots go in as a copy: scipy's getrs wrapper makes them 1-based in place for the call
    (and back after it, without the interpreter lock), so two threads solving with the same
    factors at once (a run and its fork) shifted them twice: wrong rows swapped, or a pivot
    out of range and a crash. The factors themselves are only read."""
    x, info = _getrs(factors[0], factors[1].copy(), b)
    if info != 0:
        raise ValueError(f"getrs: illegal argument {-info}")
    return x


@helper
def _supernodes(indptr, indices, n):
    """Starts of the fundamental supernodes of the first ``n`` columns of a lower triangular CSC
    matrix (sorted rows, diagonal first), and n at the end: column j + 1 joins column j's
    supernode when its rows are column j's without j."""
    starts = np.empty(n + 1, dtype=np.int64)
    count = 0
    for j in range(n):
        same = j > 0 and indptr[j + 1] - indptr[j] == indptr[j] - indptr[j - 1] - 1
        if same:
            a, b = indptr[j - 1] + 1, indptr[j]
            for k in range(indptr[j + 1] - b):
                if indices[a + k] != indices[b + k]:
                    same = False
                    break
        if not same:
            starts[count] = j
            count += 1
    starts[count] = n
    return starts[:count + 1]


@helper
def _triangle(w):
    """Values of a supernode's w x w diagonal block stored by rows, up to its diagonal."""
    return w * (w + 1) // 2


@helper
def _below(v0, w):
    """Where a block whose values start at ``v0`` would hold its row 0 if every row were w
    long: row k >= w (below the triangle) starts at ``_below(v0, w) + k * w``."""
    return v0 + _triangle(w) - w * w


@kernel
def _pack(indptr, indices, data, n, for_backward):
    """The first ``n`` columns of a lower triangular CSC matrix by supernodes (``_supernodes``):
    supernode t (columns j0 .. j0 + w - 1 from ``first``/``width``, the m rows
    ``rows[row_at[t]:row_at[t+1]]`` of column j0, its own first) is a dense block at
    ``values[value_at[t]:]``, by rows: its triangle (row k, k < w, holds columns 0..k: the
    diagonal block without the zeros above its diagonal, which a square block would store, a
    tenth of Rustrel's factors), then the m - w rows below, w values each (``_below``).
    ``for_backward``: last supernode first, the order of a backward sweep, so that it too reads
    memory forwards."""
    starts = _supernodes(indptr, indices, n)
    n_sn = len(starts) - 1
    first = np.empty(n_sn, dtype=np.int64)
    width = np.empty(n_sn, dtype=np.int64)
    row_at = np.zeros(n_sn + 1, dtype=np.int64)
    value_at = np.zeros(n_sn + 1, dtype=np.int64)
    for t in range(n_sn):
        s = n_sn - 1 - t if for_backward else t
        j0, w = starts[s], starts[s + 1] - starts[s]
        m = indptr[j0 + 1] - indptr[j0]
        first[t], width[t] = j0, w
        row_at[t + 1] = row_at[t] + m
        value_at[t + 1] = value_at[t] + _triangle(w) + (m - w) * w
    rows = np.empty(row_at[n_sn], dtype=indices.dtype)
    values = np.zeros(value_at[n_sn])
    for t in range(n_sn):
        j0, w = first[t], width[t]
        r0, v0 = row_at[t], value_at[t]
        m = row_at[t + 1] - r0
        for k in range(m):
            rows[r0 + k] = indices[indptr[j0] + k]
        below = _below(v0, w)
        for c in range(w):  # column j0 + c holds rows[c:]
            col = indptr[j0 + c] - c
            for k in range(c, w):
                values[v0 + _triangle(k) + c] = data[col + k]
            for k in range(w, m):
                values[below + k * w + c] = data[col + k]
    return first, width, row_at, value_at, rows, values


@sweep_kernel
def _forward_sweep(first, width, row_at, value_at, rows, values, r):
    """Forward substitution with a unit lower triangular matrix packed by ``_pack``: r[:n]
    becomes the solution (n its columns) and the rows below receive L21 y. A row below a
    supernode is one dot product with the supernode's solution, read and written once; four
    rows at a time, so that four sums run side by side (one sum is a chain of dependent adds),
    each split over vector lanes too (``sweep_kernel``: reassociation; 12-19 % faster on Rustrel's
    factors. Not the backward sweep: its sums over a block's columns vectorise without it, and
    with it it ran 2-25 % slower). The supernode's own triangle by rows too, reading the block
    forwards (by columns, it read it with a stride of the block's width: 6 % more time)."""
    for t in range(len(first)):
        j0, w = first[t], width[t]
        r0, v0 = row_at[t], value_at[t]
        m = row_at[t + 1] - r0
        nonzero = False   # (a right-hand side zero on the supernode: nothing to do)
        for c in range(w):
            if r[_unsigned(j0 + c)] != 0.0:
                nonzero = True
                break
        if not nonzero:
            continue
        for k in range(1, w):  # the triangle by rows: dot products along a block row
            b = v0 + _triangle(k)
            a0 = 0.0
            for c in range(k):
                a0 += values[_unsigned(b + c)] * r[_unsigned(j0 + c)]
            r[_unsigned(j0 + k)] -= a0
        below = _below(v0, w)
        k = w
        while k + 4 <= m:
            b = below + k * w
            a0 = a1 = a2 = a3 = 0.0
            for c in range(w):
                yc = r[_unsigned(j0 + c)]
                a0 += values[_unsigned(b + c)] * yc
                a1 += values[_unsigned(b + w + c)] * yc
                a2 += values[_unsigned(b + 2 * w + c)] * yc
                a3 += values[_unsigned(b + 3 * w + c)] * yc
            r[_unsigned(rows[_unsigned(r0 + k)])] -= a0
            r[_unsigned(rows[_unsigned(r0 + k + 1)])] -= a1
            r[_unsigned(rows[_unsigned(r0 + k + 2)])] -= a2
            r[_unsigned(rows[_unsigned(r0 + k + 3)])] -= a3
            k += 4
        for k in range(k, m):
            b = below + k * w
            a0 = 0.0
            for c in range(w):
                a0 += values[_unsigned(b + c)] * r[_unsigned(j0 + c)]
            r[_unsigned(rows[_unsigned(r0 + k)])] -= a0


@kernel
def _backward_sweep(first, width, row_at, value_at, rows, values, diagonal, reverse, x):
    """Backward substitution with the transpose of a lower triangular matrix V packed by
    ``_pack``: solves V^T x = c for x[:n] given c there and, in the rows beyond n, the unknowns
    already known. V is the packed matrix itself (``diagonal`` empty), or, given the diagonal D,
    the packed unit lower triangular L times D (V^T = D L^T: the U of a symmetric matrix).
    ``reverse``: the supernodes are packed in the forward sweep's order (``_pack(...,
    for_backward=False)``) and visited last first; else they are packed in this sweep's order.
    Below its triangle a supernode is a gather: each known
    unknown is read once for all the supernode's columns, four rows of the block at a time (so
    that each column's sum is a chain a quarter as long); the supernode's own triangle by block
    rows as well (each solved unknown added into the other columns' sums: 6 % less time than by
    columns, which read the block with a stride of its width).
    The block is read in the direction the sweep goes through memory: ``reverse``, from its last
    entry to its first, so that the whole sweep reads the packed values as one descending stream
    (read block by block forwards, the jumps back to each block's start cost a third more time
    where the factors outgrow the cache: 1.5 against 1.1 ms on the paper-units Rustrel scene)."""
    widest = 1      # a running maximum: np.max would compile numba's reduction for this alone
    for s in range(len(width)):
        widest = max(widest, width[s])
    acc = np.zeros(widest)
    scaled = diagonal.shape[0] > 0
    n_sn = len(first)
    for s in range(n_sn):
        t = n_sn - 1 - s if reverse else s
        j0, w = first[t], width[t]
        r0, v0 = row_at[t], value_at[t]
        m = row_at[t + 1] - r0
        for c in range(w):
            acc[_unsigned(c)] = 0.0
        below = _below(v0, w)
        groups = (m - w) // 4
        for g in range(groups):
            # the rows below the triangle four at a time: from the block's end when reverse
            k = m - 4 * (g + 1) if reverse else w + 4 * g
            x0 = x[_unsigned(rows[_unsigned(r0 + k)])]
            x1 = x[_unsigned(rows[_unsigned(r0 + k + 1)])]
            x2 = x[_unsigned(rows[_unsigned(r0 + k + 2)])]
            x3 = x[_unsigned(rows[_unsigned(r0 + k + 3)])]
            b = below + k * w
            if reverse:
                for cc in range(w):
                    c = w - 1 - cc
                    acc[_unsigned(c)] += ((values[_unsigned(b + c)] * x0
                                           + values[_unsigned(b + w + c)] * x1)
                                          + (values[_unsigned(b + 2 * w + c)] * x2
                                             + values[_unsigned(b + 3 * w + c)] * x3))
            else:
                for c in range(w):
                    acc[_unsigned(c)] += ((values[_unsigned(b + c)] * x0
                                           + values[_unsigned(b + w + c)] * x1)
                                          + (values[_unsigned(b + 2 * w + c)] * x2
                                             + values[_unsigned(b + 3 * w + c)] * x3))
        left = m - w - 4 * groups   # the rows the groups left: right below the triangle if reverse
        for i in range(left):
            k = w + left - 1 - i if reverse else w + 4 * groups + i
            xk = x[_unsigned(rows[_unsigned(r0 + k)])]
            b = below + k * w
            for c in range(w):
                acc[_unsigned(c)] += values[_unsigned(b + c)] * xk
        for c in range(w - 1, -1, -1):  # the triangle: each unknown, once known, into the
            b = v0 + _triangle(c)      # sums of those before it (along its block row)
            if scaled:   # (x_j = (c_j - d_j sum_k L_kj x_k) / d_j)
                d = diagonal[_unsigned(j0 + c)]
                xc = (x[_unsigned(j0 + c)] - d * acc[_unsigned(c)]) / d
            else:
                xc = (x[_unsigned(j0 + c)] - acc[_unsigned(c)]) / values[_unsigned(b + c)]
            x[_unsigned(j0 + c)] = xc
            for k in range(c):
                acc[_unsigned(k)] += values[_unsigned(b + k)] * xc


class _Packed:
    """The first ``n`` columns of a lower triangular CSC factor packed by supernodes (``_pack``),
    for the forward sweep or (``for_backward``) for the backward one with its transpose."""

    def __init__(self, indptr, indices, data, n, for_backward):
        _check_diagonal_first(indptr, indices, n)
        self.arrays = _pack(indptr, indices, data, n, for_backward)

    @classmethod
    def of(cls, arrays):
        """Factors already packed (``_pack``'s arrays)."""
        packed = cls.__new__(cls)
        packed.arrays = arrays
        return packed


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
    matrix then goes before the factors are copied out of SuperLU (the peak).

    When the linear block's rows equal its columns transposed (M_BB symmetric, M_BN = M_NB^T: an
    elastic bulk; not a poroelastic one, whose flow rows carry the storage over dt) and SuperLU
    kept its diagonal pivots there, U's linear rows are D L^T (D their diagonal): the backward
    sweep then reads L and D, and U is not held (half the factors' memory). U's trailing block
    still gives the Schur complement."""

    quasi_definite = False   # factorised by ldl.factorise (else by SuperLU)
    _rows_kept = False       # no row pivoted: the sweeps' vectors are M's order (no gather)

    def __init__(self, M, n_linear: int, analyses=None, symmetric_parts=None):
        if symmetric_parts is not None:   # (M's linear rows known to be symmetric)
            lower, condensed = symmetric_parts()
            self.n, self.n_linear = lower.shape[0], n_linear
            try:
                return self._quasi_definite_parts(lower, condensed, analyses)
            except NotQuasiDefinite:
                pass
        if callable(M):
            M = M()
        n = M.shape[0]
        nB = n_linear
        self.n, self.n_linear = n, nB
        symmetric = _linear_rows_symmetric(M, nB)
        if analyses is not None and symmetric:
            try:
                return self._quasi_definite(M, analyses)
            except NotQuasiDefinite:
                pass
        lu = None
        # SuperLU keeps the given column order (NATURAL) and, with SymmetricMode, prefers the
        # diagonal pivot; the scaled block's diagonal dominates, so rows stay within their block.
        # If they do not, diagonal pivots only (threshold 0) are tried before giving up. A
        # symmetric linear block is factorised with a lower threshold first, so that it keeps its
        # diagonal pivots (U = D L^T there: see above; at SuperLU's default of 1 it swapped 2 of
        # 42408 rows on a half of the fine 30 deg scene, 4 of 16000 on the T0.7 horizontal one)
        import scipy.sparse.linalg as spla   # (SuperLU: a fallback; its import costs a start)

        for threshold in ((SYMMETRIC_PIVOT_THRESHOLD, None, 0.0) if symmetric else (None, 0.0)):
            lu = spla.splu(M, permc_spec="NATURAL", diag_pivot_thresh=threshold,
                           options=dict(SymmetricMode=True))
            if np.all(lu.perm_r[:nB] < nB):
                break
        else:
            raise PivotingAcrossBlocks("the linear block's factorisation pivoted on a condensed row")
        del M
        # SuperLU's own storage is freed as soon as the factors are copied out of it: perm_r is a
        # view into that object (a slice of it kept alive the whole factorisation, ~340 MB on
        # Rustrel 200 x 201), so it is copied too. scipy makes L and U together at the first
        # access; SuperLU's storage and those copies are the peak, which nothing below exceeds
        # (each packed factor, below, is made after SuperLU's storage is freed).
        rows_of = np.array(lu.perm_r)   # row i of M is row perm_r[i] of L U
        U, L = lu.U, lu.L
        del lu
        self._row_B = rows_of[:nB].copy()
        self._row_N = rows_of[nB:] - nB
        self._rows_kept = bool(np.array_equal(rows_of, np.arange(n)))
        # SuperLU lists a supernode's rows in its own order: the sweeps' packing wants L's
        # columns sorted (U's order matters to no one: U.tocsr, below, sorts U). scipy's sort,
        # not a kernel: one took 0.07 s less a half on 200 x 201 but 0.7 s to compile cold
        L.sort_indices()
        self.nnz = L.nnz + U.nnz  # fill, for diagnostics
        S = L[nB:, nB:].toarray() @ U[nB:, nB:].toarray()   # (rows in pivot order) = L22 U22
        self.schur = np.ascontiguousarray(S[self._row_N])
        del S
        # each factor packed by supernodes and dropped before the next is: L by columns for the
        # forward sweep (with L21's rows), U by rows (the columns of U^T, with U12's columns) for
        # the backward one, whose gathers then read U12 too; or, U being D L^T on the linear
        # rows, L read backwards with D (U12 = D L21^T, L21's rows in pivot order)
        self._L = _Packed(L.indptr, L.indices, L.data, nB, for_backward=False)
        del L
        self._U = None
        self._D = _NO_DIAGONAL
        if symmetric and np.array_equal(self._row_B, np.arange(nB)):
            self._D = U.diagonal()[:nB].copy()
        else:
            U = U.tocsr()   # (a transpose: sorted whatever the order of U's rows)
            self._U = _Packed(U.indptr, U.indices, U.data, nB, for_backward=True)
        del U

    def _quasi_definite(self, M, analyses):
        """The factors by ``ldl.factorise`` (M symmetric, its linear block quasi-definite): the
        symbolic analysis of M's pattern from ``analyses``, no pivoting, so the rows keep their
        order and U = D L^T."""
        self._take(*ldl.factorise(M, self.n_linear, analyses))

    def _quasi_definite_parts(self, lower, condensed, analyses):
        """``_quasi_definite`` given the parts of M that it reads: the lower triangle of the
        linear columns and the dense condensed block (``ldl.factorise_lower``)."""
        self._take(*ldl.factorise_lower(lower, condensed, self.n_linear, analyses))

    def _take(self, packed, diagonal, schur, nnz):
        self._D, self.schur = diagonal, schur
        self.quasi_definite = True
        self.nnz = 2 * nnz   # (as L + U)
        self._row_B = np.arange(self.n_linear)
        self._row_N = np.arange(self.n - self.n_linear)
        self._rows_kept = True
        self._L = _Packed.of(packed)   # (ldl packs L in the sweeps' layout)
        self._U = None

    @property
    def packed_values(self) -> int:
        """How many values the sweeps read (the packed factors: L, and U when held)."""
        return len(self._L.arrays[5]) + (0 if self._U is None else len(self._U.arrays[5]))

    def forward(self, r_linear, r_condensed):
        """(L11^-1 P r_B, r_N - L_NB B^-1 r_B): the swept linear right-hand side (to hand back to
        ``backward``) and the condensed right-hand side."""
        nB = self.n_linear
        r = np.empty(self.n)
        if self._rows_kept:   # (slices: a quarter of the time of the gathers, which hold the GIL)
            r[:nB], r[nB:] = r_linear, r_condensed
            _forward_sweep(*self._L.arrays, r)
            return r[:nB], r[nB:]
        r[self._row_B] = r_linear
        r[nB + self._row_N] = r_condensed
        _forward_sweep(*self._L.arrays, r)
        return r[:nB], r[nB:][self._row_N]

    def backward(self, c, x_condensed):
        """B^-1 (r_B - L_BN x_N) from the swept c = ``forward(r_B, .)[0]`` (None: r_B = 0)."""
        nB = self.n_linear
        x = np.empty(self.n)
        x[:nB] = 0.0 if c is None else c
        if self._U is None:   # L21 (for U12 = D L21^T) has the condensed rows in pivot order
            if self._rows_kept:
                x[nB:] = x_condensed
            else:
                x[nB + self._row_N] = x_condensed
            _backward_sweep(*self._L.arrays, self._D, True, x)
        else:
            x[nB:] = x_condensed
            _backward_sweep(*self._U.arrays, self._D, False, x)
        return x[:nB]


#: SuperLU's diagonal pivot threshold for a symmetric linear block: the diagonal is kept unless
#: below this fraction of the column's largest entry (the condensed rows still pivot where their
#: diagonal is small). The Schur complements of the bundled elastic scenes agree with those
#: factorised at the default threshold (1) to 1e-17 relative.
SYMMETRIC_PIVOT_THRESHOLD = 0.1

#: no diagonal: ``_backward_sweep`` reads U itself
_NO_DIAGONAL = np.zeros(0)

#: the largest difference between a linear row's entries and the linear column's (relative to
#: the largest entry of the linear rows) that still counts as symmetric: assembly round-off
#: (3e-16 on the bundled elastic scenes)
SYMMETRY_ROUNDOFF = 1e-13


def _linear_rows_symmetric(M, nB):
    """Are M's first nB rows its first nB columns transposed, to SYMMETRY_ROUNDOFF?"""
    if nB == 0:
        return False
    M = M.tocsc()
    # first a product with a fixed random vector, which tells an unsymmetric block (a
    # poroelastic bulk: storage over dt against the coupling) at the cost of two products
    v = np.random.default_rng(0).standard_normal(M.shape[0])
    Mv = M @ v
    if np.max(np.abs((Mv - M.T @ v)[:nB])) > 1e-8 * np.max(np.abs(Mv)):
        return False
    rows = M[:nB]
    difference = rows - M[:, :nB].T
    return difference.nnz == 0 or abs(difference).max() <= SYMMETRY_ROUNDOFF * abs(rows).max()


#: a linear block of more unknowns than this is factorised in parts (``SplitBorderedLU``)
SPLIT_ABOVE = 50_000


def bordered_lu(M, n_linear: int, split=None, analyses=None, symmetric_parts=None):
    """``BorderedLU`` of ``M`` (or a function returning it), or ``SplitBorderedLU`` when the
    linear block is larger than SPLIT_ABOVE and ``split`` (the sizes of its parts, then of its
    separators: see ``split_layout``) is given. ``analyses`` (``ldl.SymbolicAnalyses``): a
    symmetric M is factorised as L D L^T on the symbolic analysis of its pattern kept there
    (numeric work only from the second matrix of a pattern on), SuperLU where a pivot fails.
    ``symmetric_parts``: M's linear rows are known to be symmetric, and this function returns
    the parts of M that the L D L^T reads (the lower triangle of the linear columns, the dense
    condensed block): no symmetry check, and M (best a function, then) is made only for SuperLU
    or a split (whose parts then skip their symmetry checks too)."""
    if split is not None and n_linear > SPLIT_ABOVE and min(split[:-1]) > 0:
        return SplitBorderedLU(M, n_linear, split, analyses, symmetric=symmetric_parts is not None)
    return BorderedLU(M, n_linear, analyses, symmetric_parts)


class SplitBorderedLU:
    """``BorderedLU``'s sweeps and Schur complement with the linear block factorised in parts
    that do not couple (the halves of the first nested-dissection cut, or the quarters of the
    first two), each bordered by the separators S and the condensed unknowns N that it couples
    to.

    The peak memory of a sparse LU is SuperLU's storage with scipy's copy of its factors beside
    it; one part at a time divides it. With M = [B1 . E1; . B2 E2; W1 W2 M_WW] (W = S + N),
    each part's factorisation of
    [B_i E_i; W_i M_WW] gives M_WW - W_i B_i^-1 E_i (the border's block keeps its trailing
    factors regular), so R = M_WW - sum_i W_i B_i^-1 E_i is M with every part eliminated, dense on
    W, and the Schur complement on N eliminates S from it with a dense LU of R_SS.

    A part borders only on the unknowns of W it couples to (a fault crossing the cuts has some
    of its unknowns on each side; a quarter touches one or two of the three separators):
    W_i B_i^-1 E_i is zero in the other rows and columns, and SuperLU's dense trailing block,
    the larger part of a half's factors when the fault has thousands of unknowns, is |W_i|^2
    instead of |W|^2 (fine 30 deg scene in halves: 1168^2 against 2401^2).

    ``split``: the sizes of the parts, then of the separators (n_1, ..., n_k, n_S), in ``M``'s
    order. Vectors in and out are in ``M``'s order [B1, ..., Bk, S, N], as ``BorderedLU``'s;
    the swept right hand side handed from ``forward`` to ``backward`` is
    [c_1, ..., c_k, R_SS^-1 g_S]. ``symmetric``: M's linear rows are known to be symmetric, so
    are each part's, whose L D L^T then takes its parts without the check (``BorderedLU``'s
    ``symmetric_parts``: 0.06 s of CPU of 0.8 s a refactorisation on Rustrel 200 x 201)."""

    def __init__(self, M, n_linear: int, split, analyses=None, symmetric=False):
        if callable(M):
            M = M()
        M = M.tocsc()
        n = M.shape[0]
        sizes, ns = split[:-1], split[-1]
        if sum(sizes) + ns != n_linear:
            raise ValueError(f"split {split} does not add up to {n_linear} linear unknowns")
        self.n, self.n_linear = n, n_linear
        starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        self._n_parts = nP = int(starts[-1])   # the parts' unknowns, before S
        self._ranges = [slice(a, b) for a, b in zip(starts[:-1], starts[1:])]
        parts = [np.arange(a, b) for a, b in zip(starts[:-1], starts[1:])]
        # the positions in W of each part's border: the separators' unknowns, then the
        # condensed ones, that it touches
        on_W, W_rows = M[:, nP:], M[nP:].tocsc()   # (the columns and the rows of W)
        self._borders = [_touched(on_W, W_rows, part) for part in parts]
        del on_W, W_rows
        blocks = [M[h][:, h].tocsc() for h in
                  (np.concatenate([part, nP + border]) for part, border in zip(parts, self._borders))]
        M_WW = M[nP:, nP:].tocsr()   # (sparse: dense, it would be one more |W|^2 array)
        del M
        self._parts = []
        self.nnz = 0
        eliminated = []   # each part's - W_i B_i^-1 E_i, on its border
        for part, border in zip(parts, self._borders):
            release_freed_memory()  # (what the last part's factorisation freed, before the next)
            block = blocks.pop(0)
            lu = BorderedLU(block, len(part), analyses,
                            _parts_of(block, len(part)) if symmetric else None)
            del block   # (the block goes with its factorisation)
            own = M_WW[border][:, border].tocoo()
            np.subtract.at(lu.schur, (own.row, own.col), own.data)
            eliminated.append(lu.schur)
            lu.schur = None
            self.nnz += lu.nnz
            self._parts.append(lu)
        # R in its four blocks on S and N (R_NN becomes the Schur complement in place: no
        # |W|^2 array beside it, and no |N|^2 product)
        R_SS, R_SN = M_WW[:ns, :ns].toarray(), M_WW[:ns, ns:].toarray()
        R_NS, R_NN = M_WW[ns:, :ns].toarray(), M_WW[ns:, ns:].toarray()
        del M_WW
        for border, E in zip(self._borders, eliminated):
            k = int(np.searchsorted(border, ns))   # (a border lists its S first, then its N)
            on_S, on_N = border[:k], border[k:] - ns
            R_SS[np.ix_(on_S, on_S)] += E[:k, :k]
            R_SN[np.ix_(on_S, on_N)] += E[:k, k:]
            R_NS[np.ix_(on_N, on_S)] += E[k:, :k]
            for a, w in enumerate(on_N):   # (a row at a time: no |N_i|^2 temporary)
                R_NN[w, on_N] += E[k + a, k:]
        del eliminated
        self._R_SS = scipy.linalg.lu_factor(R_SS, overwrite_a=True, check_finite=False)
        # R_SS^-1 R_SN: the separator's answer to the condensed unknowns
        self._S_from_N = lu_solve(self._R_SS, R_SN)
        del R_SN
        # R_NN - R_NS S_from_N, by BLAS on the transposes (Fortran views of these C arrays)
        self.schur = _gemm(-1.0, self._S_from_N.T, R_NS.T, beta=1.0, c=R_NN.T, overwrite_c=True).T
        self._R_NS = R_NS
        self.nnz += (ns + len(R_NN)) ** 2
        self._halves = _split_in_two([lu.packed_values for lu in self._parts])
        release_freed_memory()   # (the last part's factorisation and R's making)

    def forward(self, r_linear, r_condensed):
        """As ``BorderedLU.forward``: each part's sweep, then S eliminated from the border."""
        nP = self._n_parts
        ns = self.n_linear - nP
        g = np.concatenate([r_linear[nP:], r_condensed])
        swept = _each_part(len(self._parts), self._halves, lambda i: self._parts[i].forward(
            r_linear[self._ranges[i]], np.zeros(len(self._borders[i]))))
        for (c, g_i), border in zip(swept, self._borders):   # (in the parts' order: bit for bit)
            g[border] += g_i
        y_S = lu_solve(self._R_SS, g[:ns])
        return np.concatenate([*(c for c, _ in swept), y_S]), g[ns:] - self._R_NS @ y_S

    def backward(self, c, x_condensed):
        """As ``BorderedLU.backward``: the separator from the border, then each part's sweep."""
        nP = self._n_parts
        x_S = -(self._S_from_N @ x_condensed)
        if c is not None:
            x_S += c[nP:]
        x_W = np.concatenate([x_S, x_condensed])
        x = _each_part(len(self._parts), self._halves, lambda i: self._parts[i].backward(
            None if c is None else c[self._ranges[i]], x_W[self._borders[i]]))
        return np.concatenate([*x, x_S])


#: the parts of a split block are swept by two threads (the caller's and one worker) when each
#: thread's share holds at least this many packed values: handing a share to the worker and
#: waiting for it costs 30-40 us, a sweep through 500,000 values ~0.4 ms (memory-bound at
#: ~10 GB/s), so the hand-off stays under a tenth of the time saved. Every split block is far
#: above it (a part of 25,000 unknowns or more holds 3-4 million values on Rustrel 200 x 201)
THREADS_ABOVE = 500_000

_sweeper = None                     # the one worker thread (made at the first split sweep)
_sweeper_made = threading.Lock()
_sweeper_busy = threading.Lock()    # held while the worker sweeps for one caller


def _forget_sweeper():
    """In a child process made by fork the worker thread does not exist: make a new one."""
    global _sweeper, _sweeper_made, _sweeper_busy
    _sweeper, _sweeper_made, _sweeper_busy = None, threading.Lock(), threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_sweeper)


def _each_part(n, halves, sweep):
    """[sweep(i) for i in range(n)] (the parts of a split block), the parts of ``halves[1]`` in
    the worker thread meanwhile (``_split_in_two``), or all in this thread when ``halves`` is
    None or the worker is already sweeping for another caller (a run and its forks stepping in
    threads: they then keep to their own threads, and no call waits for another's). The numba
    sweeps release the interpreter lock; every call has its own vectors, so nothing is written
    by two threads, and each part's result is the same bits in either thread."""
    global _sweeper
    if halves is None or not _sweeper_busy.acquire(blocking=False):
        return [sweep(i) for i in range(n)]
    try:
        if _sweeper is None:
            with _sweeper_made:
                if _sweeper is None:
                    _sweeper = ThreadPoolExecutor(1, thread_name_prefix="fault-screen-sweep")
        mine, theirs = halves
        try:
            future = _sweeper.submit(lambda: [sweep(i) for i in theirs])
        except RuntimeError:   # (the interpreter shutting down takes no new work: sweep alone)
            return [sweep(i) for i in range(n)]
        try:
            done = {i: sweep(i) for i in mine}
        finally:
            done.update(zip(theirs, future.result()))   # (waits for it whatever happened here)
        return [done[i] for i in range(n)]
    finally:
        _sweeper_busy.release()


def _split_in_two(sizes):
    """The parts (by their packed values, ``sizes``) in two shares of about equal size, largest
    first to the lighter share: (the caller's, the worker's), or None when a share would hold
    fewer than THREADS_ABOVE values (one thread sweeps them all)."""
    shares, load = ([], []), [0, 0]
    for i in sorted(range(len(sizes)), key=lambda i: -sizes[i]):
        k = 0 if load[0] <= load[1] else 1
        shares[k].append(i)
        load[k] += sizes[i]
    if min(load) < THREADS_ABOVE:
        return None
    return sorted(shares[0]), sorted(shares[1])


#: a part of a split linear block holds at most about this many unknowns: halves larger than
#: that are factorised as quarters (the factorisation of a part, SuperLU's storage with scipy's
#: copy of its factors, is the peak of a large run)
PART_SIZE = 30_000


def split_layout(n_linear: int, split, quarters):
    """How ``bordered_lu`` factorises a linear block in its nested-dissection order, from the
    first cut ``split`` and the second level's ``quarters`` (``ordering.nested_dissection``):
    (order, split), ``order`` a permutation of the block to apply first (None: as it is).
    Halves when a half holds at most PART_SIZE unknowns, else quarters, the block then ordered
    [P1, P2, P3, P4, S_a, S_b, S] (each quarter keeping its order, the separators last)."""
    if (split is None or quarters is None or n_linear <= SPLIT_ABOVE
            or max(split[:2]) <= PART_SIZE):
        return None, split
    (a1, a2, a_s), (b1, b2, b_s) = quarters
    n1 = split[0]
    if min(a1, a2, b1, b2) == 0 or a1 + a2 + a_s != n1 or n1 + b1 + b2 + b_s != split[0] + split[1]:
        return None, split
    r = np.arange
    order = np.concatenate([r(0, a1 + a2), r(n1, n1 + b1 + b2),                    # quarters
                            r(a1 + a2, n1), r(n1 + b1 + b2, split[0] + split[1]),  # S_a, S_b
                            r(split[0] + split[1], n_linear)])                      # S
    return order, (a1, a2, b1, b2, a_s + b_s + split[2])


def _parts_of(M, n_linear):
    """``BorderedLU``'s ``symmetric_parts`` of a symmetric block M: a function returning what its
    L D L^T reads (``ldl.factorise``'s)."""
    return lambda: (ldl._lower(M, n_linear), M[n_linear:, n_linear:].toarray())


def _touched(on_W, W_rows, part):
    """The unknowns of W (counted from its first) with an entry in the rows or the columns
    ``part`` of M, given M's columns on W and M's rows of W (CSC)."""
    by_column = np.diff(on_W[part].tocsc().indptr) > 0       # E_i's columns
    by_row = np.diff(W_rows[:, part].tocsr().indptr) > 0     # W_i's rows
    return np.flatnonzero(by_column | by_row)


def _check_diagonal_first(indptr, indices, n):
    """The sweeps read each column's diagonal as its first entry (sorted, lower triangular)."""
    if n and not np.array_equal(indices[indptr[:n]], np.arange(n)):
        raise PivotingAcrossBlocks("a factor column does not start at its diagonal")

"""The linear Jacobian A + C / dt + theta Hf at a new step size, written straight into a pattern
fixed once: the blocks are constant and only dt changes, so the positions of every entry (in the
factors' order, scaled, with the row factors of the symmetric form) are found once per pattern and
a new step size is one pass over the values.

``FixedSum``: a few rows or the condensed block, A + C / dt + theta Hf in a fixed CSR pattern
(the union of the three blocks' patterns). ``FixedBulk``: the scaled free block in the factors'
order, D (A + C / dt + theta Hf) D with its flow rows times -dt (the symmetric form, see
``linear_system.CondensedSystem``), as CSC, with the lower triangle of its first ``n_linear``
columns and the dense block on the condensed unknowns (what ``ldl.factorise_lower`` reads).

Each value is computed with the operations, in the order, of the sparse sums and products that
built it before ((a + c (1/dt)) + h theta, then times the row's scale, the column's scale, the row
factor), so it is the same number to the last bit. The pattern is the union of the blocks'
nonzero entries (a stored zero is left out, as a sparse sum drops it); where their sum cancels
to zero the position holds an explicit zero, which adds nothing wherever it is read.
"""
from __future__ import annotations

import copy

import numpy as np
import scipy.sparse as sp

from ._jit import kernel


@kernel
def _scaled_values(indptr, indices, at_a, at_c, at_h, a, c, h, scale, row_factor, inv_dt, theta,
                   out):
    """out[p] = ((scale_i ((a + c inv_dt) + h theta)) scale_j) row_factor_i at each entry p (row
    i, column j) of a CSC pattern; at_x[p]: the entry's position in x's values, -1 if x has
    none there."""
    for j in range(len(indptr) - 1):
        s_j = scale[j]
        for p in range(indptr[j], indptr[j + 1]):
            i = indices[p]
            va = a[at_a[p]] if at_a[p] >= 0 else 0.0
            vc = c[at_c[p]] if at_c[p] >= 0 else 0.0
            vh = h[at_h[p]] if at_h[p] >= 0 else 0.0
            out[p] = ((scale[i] * ((va + vc * inv_dt) + vh * theta)) * s_j) * row_factor[i]


def _index_type(n):
    """int32 for positions in n values where they fit, else int64."""
    return np.int32 if n < np.iinfo(np.int32).max else np.int64


def _index(counts):
    """A CSC/CSR index pointer from the entries per column (row), in scipy's index type."""
    indptr = np.concatenate([[0], np.cumsum(counts)])
    return indptr.astype(np.int32) if indptr[-1] < np.iinfo(np.int32).max else indptr


def _gather(values, at):
    """values[at] where at >= 0, else 0 (a block without entries has no values to index)."""
    out = np.zeros(len(at))
    has = at >= 0
    out[has] = values[at[has]]
    return out


def _canonical(X):
    """X as CSR with sorted, summed entries (X itself when it is one)."""
    X = sp.csr_matrix(X)
    if not X.has_canonical_format:
        X = X.copy()
        X.sum_duplicates()
    return X


def _sorted_unique(keys):
    """The distinct values of the integer array ``keys``, ascending (``np.unique``'s result):
    by a sort and a comparison of neighbours. np.unique hashes integers first, and the keys
    here (column * rows + row, runs of near neighbours) took it 0.27 s for the 460,000 of the
    paper-units Rustrel bulk, against 0.01 s sorted."""
    keys = np.sort(keys)
    distinct = np.empty(len(keys), dtype=bool)
    distinct[:1] = True
    np.not_equal(keys[1:], keys[:-1], out=distinct[1:])
    return keys[distinct]


def _positions(blocks, shape):
    """The union pattern of ``blocks`` (sparse, one shape) as sorted keys column * rows + row
    (CSC order), and per block the position in the union of each of its entries (CSC order)."""
    n_rows = shape[0]
    keyed = []
    for X in blocks:
        X = sp.csc_matrix(X)
        X.sum_duplicates()
        cols = np.repeat(np.arange(X.shape[1], dtype=np.int64), np.diff(X.indptr))
        keyed.append((X, cols * n_rows + X.indices.astype(np.int64)))
    union = _sorted_unique(np.concatenate([k for _, k in keyed]))
    return union, [(X, np.searchsorted(union, k)) for X, k in keyed]


class FixedSum:
    """A + C / dt + theta Hf of the same rows and columns of each block, in the fixed CSR
    pattern of their union: ``matrix(dt)`` and ``entries(dt)``."""

    def __init__(self, blocks, time_weight):
        blocks = [sp.csr_matrix(X, copy=True) for X in blocks]
        for X in blocks:   # (a stored zero is no entry of the sum: sparse sums drop it)
            X.eliminate_zeros()
        self.shape = shape = blocks[0].shape
        # (a CSR matrix's pattern is the CSC pattern of its transpose)
        union, placed = _positions([X.T for X in blocks], shape[::-1])
        rows = union // shape[1]
        self.indptr = _index(np.bincount(rows, minlength=shape[0]))
        self.indices = (union % shape[1]).astype(self.indptr.dtype)
        self.rows = rows
        self._time_weight = time_weight
        # each block's values at the union's positions (zeros where it has none)
        self._values = []
        for XT, at in placed:
            v = np.zeros(len(union))
            v[at] = XT.data
            self._values.append(v)

    def values(self, dt, theta=None):
        """The values at step size dt and time weight theta (default the one made with)."""
        a, c, h = self._values
        out = a + c * (1.0 / dt)
        out += h * (self._time_weight if theta is None else theta)
        return out

    def matrix(self, dt, theta=None):
        """A + C / dt + theta Hf as CSR (the fixed pattern's arrays shared)."""
        M = sp.csr_matrix(self.shape)
        M.indptr, M.indices, M.data = self.indptr, self.indices, self.values(dt, theta)
        return M

    def entries(self, dt, theta=None):
        """(rows, columns, values) in row-major order."""
        return self.rows, self.indices.astype(np.int64), self.values(dt, theta)


class FixedBulk:
    """The scaled free block in the factors' order at any step size, in one fixed CSC pattern.

    ``blocks``: A, C, Hf (sparse, on all unknowns); ``order``: the free unknowns in the factors'
    order (global indices); ``scale``: the symmetric scaling (on all unknowns); ``flow``: which
    of ``order`` are flow unknowns, whose rows are multiplied by -dt (None: no row factor, the
    block as it is); ``n_linear``: the unknowns eliminated (the rest condensed)."""

    def __init__(self, blocks, time_weight, order, scale, flow, n_linear):
        self._time_weight = time_weight
        self.n_linear = n_linear
        n = len(order)
        self.shape = (n, n)
        # each block's nonzero entries, numbered (their positions in its CSR values, plus one:
        # a slice drops no entry, and no number is zero; a stored zero, numbered 0, is dropped
        # as a sparse sum drops it), restricted to the free unknowns in order
        self._data, numbered = [], []
        for X in map(_canonical, blocks):
            self._data.append(X.data)
            number = np.where(X.data != 0.0, np.arange(1, X.nnz + 1, dtype=np.float64), 0.0)
            ids = sp.csr_matrix((number, X.indices, X.indptr), shape=X.shape)[order][:, order]
            ids.eliminate_zeros()
            numbered.append(ids.tocsc())
        union, placed = _positions(numbered, self.shape)
        cols = union // n
        self.indptr = _index(np.bincount(cols, minlength=n))
        rows = (union % n).astype(self.indptr.dtype)
        self.indices = rows
        self._at = []   # (int32 where they fit: four bytes an entry and block held all run)
        for (X, at), values in zip(placed, self._data):
            where = np.full(len(union), -1, dtype=_index_type(len(values)))
            where[at] = X.data.astype(np.int64) - 1
            self._at.append(where)
        self._order = order
        self._scale = np.ascontiguousarray(scale[order])
        self._flow = None if flow is None else np.asarray(flow, dtype=bool)
        # the lower triangle of the first n_linear columns, and the condensed block
        lower = (rows >= cols) & (cols < n_linear)
        self._lower_at = np.flatnonzero(lower).astype(_index_type(len(union)))
        self.lower_indptr = _index(np.bincount(cols[lower], minlength=n_linear)).astype(rows.dtype)
        self.lower_indices = rows[lower]
        on_N = (rows >= n_linear) & (cols >= n_linear)
        self._N_at = np.flatnonzero(on_N)
        # (positions in the column-major block)
        self._N_flat = (cols[on_N] - n_linear) * (n - n_linear) + (rows[on_N].astype(np.int64) - n_linear)
        # what the L D L^T reads, as a CSC pattern of its own (``parts``): the lower triangle's
        # columns first, then the condensed block's, so that the first values are the lower
        # triangle's as they are; the upper triangle of the linear columns is left out
        read = lower | on_N
        self._read_indptr = _index(np.bincount(cols[read], minlength=n))
        self._read_indices = rows[read]
        self._read_at = [at[read] for at in self._at]
        self._read_data = None   # (``_read_blocks``)

    @staticmethod
    def pattern_key(blocks, order, flow, n_linear):
        """The arrays that decide every position of a ``FixedBulk`` of these arguments (each
        block's pattern and nonzero entries, the order, the flow rows, ``n_linear``): equal
        arrays, equal positions (see ``with_values``)."""
        key = [np.asarray(order), np.asarray([n_linear, -1 if flow is None else 1]),
               np.asarray([], dtype=bool) if flow is None else np.asarray(flow, dtype=bool)]
        for X in map(_canonical, blocks):
            key += [np.asarray(X.shape), X.indptr, X.indices, X.data != 0.0]
        return key

    def with_values(self, blocks, time_weight, scale):
        """This pattern with the values of other ``blocks``, ``time_weight`` and ``scale``,
        whose ``pattern_key`` (with this bulk's order, flow rows and n_linear) equals this
        bulk's: a copy sharing the positions (read-only), the same bulk as one made from them."""
        twin = copy.copy(self)
        twin._data = [X.data for X in map(_canonical, blocks)]
        twin._time_weight = time_weight
        twin._scale = np.ascontiguousarray(scale[self._order])
        twin._read_data = None
        return twin

    def _row_factor(self, dt):
        if self._flow is None:
            return np.ones(self.shape[0])
        return np.where(self._flow, -dt, 1.0)

    def values(self, dt, theta=None):
        """The CSC values of the block at step size dt (rows times the row factor) and time
        weight theta (default the one made with)."""
        out = np.empty(len(self.indices))
        a, c, h = self._data
        at_a, at_c, at_h = self._at
        _scaled_values(self.indptr, self.indices, at_a, at_c, at_h, a, c, h, self._scale,
                       self._row_factor(dt), 1.0 / dt,
                       self._time_weight if theta is None else theta, out)
        return out

    def _read_blocks(self):
        """Each block's values at the entries that ``parts`` computes, in their order (zero
        where the block has none), gathered at its first call, and the positions 0, 1, ... into
        them: a new step size's pass then streams through them in order. Gathered at each step
        size, the blocks' values were read at scattered positions that the factorisation before
        had evicted from the caches (3 ms of the pass's 3.5 on paper-units Rustrel, for 4 MB
        held there)."""
        if self._read_data is None:
            n = len(self._read_indices)
            self._read_data = ([_gather(x, at) for x, at in zip(self._data, self._read_at)],
                               np.arange(n, dtype=_index_type(n)))
        return self._read_data

    def parts(self, dt):
        """(``lower``, ``condensed``) at step size dt, the values of those entries alone
        computed (each as ``values`` computes it: the same numbers to the last bit)."""
        read = np.empty(len(self._read_indices))
        (a, c, h), at = self._read_blocks()
        _scaled_values(self._read_indptr, self._read_indices, at, at, at, a, c, h,
                       self._scale, self._row_factor(dt), 1.0 / dt, self._time_weight, read)
        n_lower = len(self.lower_indices)
        return self._lower_of(read[:n_lower]), self._condensed_of(read[n_lower:])

    def matrix(self, values):
        """The block as CSC from ``values`` (the pattern's arrays shared, not copied)."""
        M = sp.csc_matrix(self.shape)
        M.indptr, M.indices, M.data = self.indptr, self.indices, values
        return M

    def lower(self, values):
        """The lower triangle of the first n_linear columns (CSC, sorted) from ``values``."""
        return self._lower_of(values[self._lower_at])

    def _lower_of(self, data):
        L = sp.csc_matrix((self.shape[0], self.n_linear))
        L.indptr, L.indices, L.data = self.lower_indptr, self.lower_indices, data
        return L

    def condensed(self, values):
        """The dense block on the condensed unknowns from ``values``."""
        return self._condensed_of(values[self._N_at])

    def _condensed_of(self, data):
        n_N = self.shape[0] - self.n_linear
        out = np.zeros((n_N, n_N), order="F")   # (as a CSC block's toarray(): products with
        out.T.reshape(-1)[self._N_flat] = data  # it then sum in the same order)
        return out

    def components(self):
        """The block's parts X, Y, Z (CSC, the fixed pattern) with value(dt) = X + dt Y + Z / dt
        in exact arithmetic: one symmetric for every dt when all three are."""
        a, c, h = self._data
        at_a, at_c, at_h = self._at
        scale = self._scale
        rows = self.indices
        cols = np.repeat(np.arange(self.shape[1]), np.diff(self.indptr))
        va, vc, vh = _gather(a, at_a), _gather(c, at_c), _gather(h, at_h)
        ss = scale[rows] * scale[cols]
        stiff = ss * (va + self._time_weight * vh)
        storage = ss * vc
        flow = np.zeros(self.shape[0], dtype=bool) if self._flow is None else self._flow
        on_flow = flow[rows]
        X = np.where(on_flow, -storage, stiff)
        Y = np.where(on_flow, -stiff, 0.0)
        Z = np.where(on_flow, 0.0, storage)
        return [self.matrix(v) for v in (X, Y, Z)]

"""Quasi-definite LDL^T of the bulk with the fault unknowns as its border, numeric part redone
per step size on a symbolic analysis made once per pattern.

With its flow rows multiplied by -dt, the scaled poroelastic free block is symmetric, and its
bulk B is quasi-definite (stiffness positive definite, storage plus dt times conduction positive
definite): B = L D L^T exists in any symmetric order without pivoting, so the order and the
structure of L depend on the pattern alone. ``LDLSymbolic`` holds them (elimination tree, the
rows of each column of L, the supernodes, the assembly tree and its relative indices);
``factorise`` makes the numbers for a matrix of that pattern: a multifrontal elimination over
the supernodes in postorder, each front a dense block holding the supernode's columns, the rows
below them and the updates of its children.

The condensed unknowns N (ordered last) are rows of the fronts but are not eliminated: the
updates reaching them add up to the Schur complement S = M_NN - M_NB B^-1 M_BN, dense, and L's
rows there are L21 = M_NB L^-T D^-1. The factors are packed in ``bordered_lu``'s supernode layout,
so that its sweeps serve: forward with L (giving L21 L^-1 r_B), backward with D L^T and
U12 = D L21^T (the symmetric form has M_BN = M_NB^T).
"""
from __future__ import annotations

import _thread
import contextlib
import sys
import threading

import numpy as np
import scipy.sparse as sp
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ._jit import helper, kernel


@helper
def _filled(n, value):
    """n copies of ``value`` (int64) by a loop: numba's np.full and np.ones would each be
    compiled, and kept, for this module alone."""
    out = np.empty(n, dtype=np.int64)
    for i in range(n):
        out[i] = value
    return out


class NotQuasiDefinite(ArithmeticError):
    """A pivot of the LDL^T was zero or not finite: the block is not quasi-definite in this
    order (the caller falls back to a pivoting LU)."""


@kernel
def _etree(indptr, indices, n_linear):
    """Elimination tree of the first ``n_linear`` columns of a symmetric matrix given by its
    upper triangle (CSC: column k lists the rows i <= k): parent of each column, -1 at a root
    (a column whose first off-diagonal entry of L is a condensed row or none)."""
    parent = _filled(n_linear, -1)
    ancestor = _filled(n_linear, -1)
    for k in range(n_linear):
        for p in range(indptr[k], indptr[k + 1]):
            i = indices[p]
            while i != -1 and i < k:
                following = ancestor[i]
                ancestor[i] = k
                if following == -1:
                    parent[i] = k
                i = following
    return parent


@kernel
def _structure(indptr, indices, n, n_linear, parent):
    """The rows of each of the first ``n_linear`` columns of L (CSC, sorted, diagonal first),
    from the upper triangle (column i lists the rows k <= i): row i of L is the union of the
    tree paths from each k with an entry in row i up to i (or to a root, for a condensed row)."""
    count = _filled(n_linear, 1)
    mark = _filled(n_linear, -1)
    for i in range(n):
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            while j != -1 and j < i and j < n_linear and mark[j] != i:
                mark[j] = i
                count[j] += 1
                j = parent[j]
    col_ptr = np.zeros(n_linear + 1, dtype=np.int64)
    for j in range(n_linear):
        col_ptr[j + 1] = col_ptr[j] + count[j]
    rows = np.empty(col_ptr[n_linear], dtype=np.int64)
    fill = col_ptr[:n_linear].copy()
    for j in range(n_linear):
        rows[fill[j]] = j
        fill[j] += 1
        mark[j] = -1
    for i in range(n):
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            while j != -1 and j < i and j < n_linear and mark[j] != i:
                mark[j] = i
                rows[fill[j]] = i
                fill[j] += 1
                j = parent[j]
    return col_ptr, rows


@kernel
def _supernode_tree(col_ptr, rows, parent, n_linear):
    """Supernodes (columns with one row pattern, then amalgamated: ``_amalgamate``), the
    assembly tree over them in postorder, and the relative indices.

    Returns, per supernode in postorder: first column, width, its rows (its own columns, then
    the rows below them of its last column's pattern: ``srows[row_at[t]:row_at[t + 1]]``), its
    parent's position in the postorder (-1: its update goes to the Schur complement), its
    number of children, and for the update rows (the rows after its own columns) their positions
    in the parent's rows (``relative``, from ``row_at[t] + width[t]``), or in N for a root."""
    fundamental = np.empty(n_linear + 1, dtype=np.int64)
    count = 0
    for j in range(n_linear):   # (column j joins j - 1 when it is its parent with its rows less j)
        if not (j > 0 and parent[j - 1] == j
                and col_ptr[j + 1] - col_ptr[j] == col_ptr[j] - col_ptr[j - 1] - 1):
            fundamental[count] = j
            count += 1
    fundamental[count] = n_linear
    starts = _amalgamate(fundamental[:count + 1], col_ptr, parent)
    n_sn = len(starts) - 1
    node_of = np.empty(n_linear, dtype=np.int64)
    for s in range(n_sn):
        for j in range(starts[s], starts[s + 1]):
            node_of[j] = s
    sparent = _filled(n_sn, -1)
    for s in range(n_sn):
        p = parent[starts[s + 1] - 1]
        if p != -1:
            sparent[s] = node_of[p]
    # postorder: children lists, then a depth-first walk from each root (in column order)
    head = _filled(n_sn, -1)
    following = _filled(n_sn, -1)
    for s in range(n_sn - 1, -1, -1):
        q = sparent[s]
        if q != -1:
            following[s] = head[q]
            head[q] = s
    post = np.empty(n_sn, dtype=np.int64)
    stack = np.empty(n_sn, dtype=np.int64)
    k = 0
    for root in range(n_sn):
        if sparent[root] != -1:
            continue
        top = 0
        stack[0] = root
        while top >= 0:
            s = stack[top]
            c = head[s]
            if c == -1:
                post[k] = s
                k += 1
                top -= 1
            else:
                head[s] = following[c]   # (the list is consumed: each child once)
                top += 1
                stack[top] = c
    position = np.empty(n_sn, dtype=np.int64)
    for t in range(n_sn):
        position[post[t]] = t
    first = np.empty(n_sn, dtype=np.int64)
    width = np.empty(n_sn, dtype=np.int64)
    tparent = np.empty(n_sn, dtype=np.int64)
    children = np.zeros(n_sn, dtype=np.int64)
    row_at = np.zeros(n_sn + 1, dtype=np.int64)
    for t in range(n_sn):
        s = post[t]
        first[t] = starts[s]
        width[t] = starts[s + 1] - starts[s]
        tparent[t] = -1 if sparent[s] == -1 else position[sparent[s]]
        last = starts[s + 1] - 1
        row_at[t + 1] = row_at[t] + width[t] + col_ptr[last + 1] - col_ptr[last] - 1
    for t in range(n_sn):
        if tparent[t] != -1:
            children[tparent[t]] += 1
    srows = np.empty(row_at[n_sn], dtype=np.int64)
    for t in range(n_sn):
        w = width[t]
        for k in range(w):
            srows[row_at[t] + k] = first[t] + k
        a = col_ptr[first[t] + w - 1] + 1   # (the last column's rows below its diagonal)
        for k in range(w, row_at[t + 1] - row_at[t]):
            srows[row_at[t] + k] = rows[a + k - w]
    relative = np.empty(row_at[n_sn], dtype=np.int64)
    where = _filled(n_linear, -1)
    for t in range(n_sn):
        q = tparent[t]
        if q != -1:
            for k in range(row_at[q], row_at[q + 1]):
                r = srows[k]
                if r < n_linear:
                    where[r] = k - row_at[q]
        n_q_linear = 0
        if q != -1:
            for k in range(row_at[q], row_at[q + 1]):
                if srows[k] < n_linear:
                    n_q_linear += 1
        for k in range(row_at[t] + width[t], row_at[t + 1]):
            r = srows[k]
            if q == -1:
                relative[k] = r - n_linear
            elif r < n_linear:
                relative[k] = where[r]
            else:   # (a condensed row: the parent's rows hold them after its linear ones, sorted)
                relative[k] = -1
        if q != -1:   # the condensed rows by a merge of the two sorted lists
            a = row_at[q] + n_q_linear
            for k in range(row_at[t] + width[t], row_at[t + 1]):
                r = srows[k]
                if r >= n_linear:
                    while srows[a] != r:
                        a += 1
                    relative[k] = a - row_at[q]
    return first, width, row_at, srows, tparent, children, relative


#: amalgamation: a supernode is merged into its parent (the next columns) when the merged one
#: is at most this wide, ... (``_amalgamate``)
RELAX_WIDTHS = (4, 16, 48)
#: ... and at most this fraction of its block are zeros (any fraction up to the first width)
RELAX_ZEROS = (1.0, 0.8, 0.1, 0.05)


@helper
def _block_size(m, w):
    """Entries of a supernode's block: m rows, w columns, none above the diagonal."""
    return m * w - w * (w - 1) // 2


@helper
def _amalgamate(fundamental, col_ptr, parent):
    """Starts of the supernodes made by merging each run of fundamental ones into its parent
    while that is the next columns and the merged block holds few zeros (RELAX_WIDTHS,
    RELAX_ZEROS, which are CHOLMOD's defaults): the dense work then runs on wider blocks (the
    nested-dissection leaves alone are 1-8 columns wide), for some zeros stored and
    multiplied. The merged supernode's rows are its columns and the rows below its last
    column."""
    n_f = len(fundamental) - 1
    starts = np.empty(n_f + 1, dtype=np.int64)
    count = 0
    width = entries = 0
    for f in range(n_f):
        j0, j1 = fundamental[f], fundamental[f + 1]
        w = j1 - j0
        m = col_ptr[j0 + 1] - col_ptr[j0]
        own = _block_size(m, w)
        if count > 0 and parent[j0 - 1] == j0:
            merged_w = width + w
            merged = _block_size(width + m, merged_w)
            zeros = (merged - entries - own) / merged
            if merged_w <= RELAX_WIDTHS[0]:
                limit = RELAX_ZEROS[0]
            elif merged_w <= RELAX_WIDTHS[1]:
                limit = RELAX_ZEROS[1]
            elif merged_w <= RELAX_WIDTHS[2]:
                limit = RELAX_ZEROS[2]
            else:
                limit = RELAX_ZEROS[3]
            if zeros <= limit:
                width, entries = merged_w, merged
                continue
        starts[count] = j0
        count += 1
        width, entries = w, own
    starts[count] = fundamental[n_f]
    return starts[:count + 1]


#: an index known to be non-negative, as unsigned: numba then drops the wraparound of negative
#: indices, whose select keeps LLVM from vectorising a loop along a block row. A plain cast, not
#: a helper: numba types a cast at each use, whereas it inlines a helper's IR at each call
_unsigned = np.uint64


@helper
def _update_row(front, panel_t, m, w, i, k0):
    """Row i of the front's trailing block, columns k0..i: F[i, k] -= sum_c L[i, c] (D L^T)[c, k],
    four columns c of the panel at a time."""
    row = i * m
    c = 0
    while c + 4 <= w:
        l0, l1 = front[_unsigned(row + c)], front[_unsigned(row + c + 1)]
        l2, l3 = front[_unsigned(row + c + 2)], front[_unsigned(row + c + 3)]
        p0 = c * m
        for k in range(k0, i + 1):
            front[_unsigned(row + k)] -= ((l0 * panel_t[_unsigned(p0 + k)]
                                           + l1 * panel_t[_unsigned(p0 + m + k)])
                                          + (l2 * panel_t[_unsigned(p0 + 2 * m + k)]
                                             + l3 * panel_t[_unsigned(p0 + 3 * m + k)]))
        c += 4
    for c in range(c, w):
        lic = front[_unsigned(row + c)]
        pc = c * m
        for k in range(k0, i + 1):
            front[_unsigned(row + k)] -= lic * panel_t[_unsigned(pc + k)]


@helper
def _update_rows4(front, panel_t, m, w, i):
    """Rows i..i+3 of the trailing block (``_update_row``), columns w..i of the four together,
    four columns c at a time (a block of 4 x 4 multipliers: each load of the panel serves four
    rows); the rest of each row's triangle is ``_update_row``'s (``_eliminate``)."""
    r0, r1, r2, r3 = i * m, (i + 1) * m, (i + 2) * m, (i + 3) * m
    c = 0
    while c + 4 <= w:
        a0, a1 = front[_unsigned(r0 + c)], front[_unsigned(r0 + c + 1)]
        a2, a3 = front[_unsigned(r0 + c + 2)], front[_unsigned(r0 + c + 3)]
        b0, b1 = front[_unsigned(r1 + c)], front[_unsigned(r1 + c + 1)]
        b2, b3 = front[_unsigned(r1 + c + 2)], front[_unsigned(r1 + c + 3)]
        e0, e1 = front[_unsigned(r2 + c)], front[_unsigned(r2 + c + 1)]
        e2, e3 = front[_unsigned(r2 + c + 2)], front[_unsigned(r2 + c + 3)]
        g0, g1 = front[_unsigned(r3 + c)], front[_unsigned(r3 + c + 1)]
        g2, g3 = front[_unsigned(r3 + c + 2)], front[_unsigned(r3 + c + 3)]
        p0 = c * m
        for k in range(w, i + 1):
            q0, q1 = panel_t[_unsigned(p0 + k)], panel_t[_unsigned(p0 + m + k)]
            q2, q3 = panel_t[_unsigned(p0 + 2 * m + k)], panel_t[_unsigned(p0 + 3 * m + k)]
            front[_unsigned(r0 + k)] -= (a0 * q0 + a1 * q1) + (a2 * q2 + a3 * q3)
            front[_unsigned(r1 + k)] -= (b0 * q0 + b1 * q1) + (b2 * q2 + b3 * q3)
            front[_unsigned(r2 + k)] -= (e0 * q0 + e1 * q1) + (e2 * q2 + e3 * q3)
            front[_unsigned(r3 + k)] -= (g0 * q0 + g1 * q1) + (g2 * q2 + g3 * q3)
        c += 4
    for c in range(c, w):
        a, b = front[_unsigned(r0 + c)], front[_unsigned(r1 + c)]
        e, g = front[_unsigned(r2 + c)], front[_unsigned(r3 + c)]
        pc = c * m
        for k in range(w, i + 1):
            q = panel_t[_unsigned(pc + k)]
            front[_unsigned(r0 + k)] -= a * q
            front[_unsigned(r1 + k)] -= b * q
            front[_unsigned(r2 + k)] -= e * q
            front[_unsigned(r3 + k)] -= g * q


#: a front goes through BLAS-3 (``_panel_by_blas``) when its supernode is at least this wide
#: and it has at least this many rows below it (on paper-units Rustrel, with the update by
#: dgemm in place, 8 wide and 16 rows took 5 % less CPU than 16 and 32, limits from 4 to 12
#: wide and 8 to 24 rows the same to a few per cent; ``benchmarks/factorisation.py --fronts``)
BLAS_MIN_WIDTH = 8
BLAS_MIN_ROWS = 16
#: such a front's columns are eliminated a panel of at most this many at a time, each panel's
#: rows below it and their update of all the later rows by BLAS (the pivot blocks by loops)
PANEL = 96
#: the rows of L21^T solved together (their sum over the earlier rows is one product), and
#: the rows of the trailing block updated together (``_panel_by_blas``)
SOLVE_BLOCK = 16
UPDATE_BLOCK = 128


#: BLAS's dgemm through numba's own C helper for it (what numba's np.dot calls, on scipy's
#: BLAS): an external symbol, so the kernels calling it stay cacheable, and unlike np.dot it
#: takes leading dimensions, so that a product lands in a block of a front in place
_f64_pointer = types.CPointer(types.float64)
_xxgemm = types.ExternalFunction("numba_xxgemm", types.intc(
    types.char, types.char, types.char, types.intp, types.intp, types.intp, _f64_pointer,
    _f64_pointer, types.intp, _f64_pointer, types.intp, _f64_pointer, _f64_pointer, types.intp))
#: dgemm's alpha and beta for C <- C - A B
_LESS = np.array([-1.0, 1.0])


@helper
def _gemm_less(a_transposed, rows, columns, inner, a, a_at, lda, b, b_at, ldb, c, c_at, ldc):
    """C -= A B in BLAS's column-major terms (where a row-major array is its transpose): C
    ``rows`` x ``columns`` at ``c[c_at]``, A (``rows`` x ``inner``) at ``a[a_at]``, or given by
    its transpose (``inner`` x ``rows``) when ``a_transposed``, B (``inner`` x ``columns``) at
    ``b[b_at]``; ``lda``, ``ldb``, ``ldc`` their leading dimensions. A, B and C may be blocks of
    one array if C shares no entry with the others. An empty product is skipped (BLAS would
    take its leading dimension of 0, e.g. a shared front's empty half of rows, as an error)."""
    if rows > 0 and columns > 0 and inner > 0:
        _xxgemm(100, 84 if a_transposed else 78, 78, rows, columns, inner, _LESS[0:].ctypes,
                a[a_at:].ctypes, lda, b[b_at:].ctypes, ldb, _LESS[1:].ctypes, c[c_at:].ctypes,
                ldc)   # ('d', 'T' or 'N', 'N')


@helper
def _pivot_block(front, m, o, w, diagonal, j0, column_d):
    """F11 = L11 D L11^T of the w x w block at ``front[o]`` (row stride m), right-looking, each
    pivot's column (d l) kept in column_d so that the rows' updates run along contiguous
    memory; the pivots into ``diagonal[j0:j0 + w]``, L11 in the block's lower triangle."""
    for c in range(w):
        d = front[o + c * m + c]
        diagonal[j0 + c] = d
        for k in range(c + 1, w):
            column_d[k] = front[o + k * m + c]
            front[o + k * m + c] = column_d[k] / d
        for i in range(c + 1, w):
            li = front[_unsigned(o + i * m + c)]
            row = o + i * m
            for k in range(c + 1, i + 1):
                front[_unsigned(row + k)] -= li * column_d[_unsigned(k)]


@helper
def _panel_by_blas(front, m, o, n, w, d, xt, dlrows, strip):
    """The rows below a factorised pivot block and their update of the trailing block by matrix
    products (BLAS's dgemm), for a panel of a large front.

    The panel's block is n x n at ``front[o]`` (row stride m), its pivot block (the first w
    rows and columns) factorised (``_pivot_block``), ``d`` its pivots. On return the block's
    first w columns below the pivot block hold L21 = F21 (D L11^T)^-1 (``_panel_rows``) and its
    trailing block (lower triangle) F22 - L21 D L21^T (``_panel_update``)."""
    _panel_rows(front, m, o, w, d, 0, n - w, xt, dlrows, strip)
    _panel_update(front, m, o, w, dlrows, 0, n - w)


@helper
def _panel_rows(front, m, o, w, d, k_begin, k_end, xt, dlrows, strip):
    """Rows ``k_begin .. k_end - 1`` of L21 below a panel's factorised pivot block
    (``_panel_by_blas``), into the front and into ``dlrows`` = L21 D (row-major, w values a
    row, at their row). L21^T is solved in ``xt`` (w x u, u the rows): row c of it is
    (F21^T[c] - sum_{k<c} d_k L11[c, k] L21^T[k]) / d_c, each block of rows' sum over the earlier
    rows one product (dgemm into xt in place: in BLAS's column-major view xt is X^T, u x w, and
    X^T[:, c0:c1] -= X^T[:, :c0] S^T, S the block's rows of L11 D in ``strip``), the rows within
    the block by axpys along contiguous rows."""
    u = k_end - k_begin
    for k in range(u):   # xt = F21^T
        row = o + (w + k_begin + k) * m
        for c in range(w):
            xt[_unsigned(c * u + k)] = front[_unsigned(row + c)]
    c0 = 0
    while c0 < w:
        c1 = min(c0 + SOLVE_BLOCK, w)
        h = c1 - c0
        if c0 > 0:
            for a in range(h):   # S[a, k] = d_k L11[c0 + a, k], row-major (S^T: c0 x h)
                row = o + (c0 + a) * m
                for k in range(c0):
                    strip[_unsigned(a * c0 + k)] = d[k] * front[_unsigned(row + k)]
            _gemm_less(False, u, h, c0, xt, 0, u, strip, 0, c0, xt, c0 * u, u)
        for c in range(c0, c1):
            at = c * u
            for k in range(c0, c):
                f = d[k] * front[_unsigned(o + c * m + k)]
                kt = k * u
                for r in range(u):
                    xt[_unsigned(at + r)] -= f * xt[_unsigned(kt + r)]
            pivot = d[c]
            for r in range(u):
                xt[_unsigned(at + r)] /= pivot
        c0 = c1
    for k in range(u):   # L21 (into the front) and L21 D, row-major
        row = o + (w + k_begin + k) * m
        at = (k_begin + k) * w
        for c in range(w):
            x = xt[_unsigned(c * u + k)]
            front[_unsigned(row + c)] = x
            dlrows[_unsigned(at + c)] = d[c] * x


@helper
def _panel_update(front, m, o, w, dlrows, i_begin, i_end):
    """Rows ``i_begin .. i_end - 1`` of a panel's trailing block (lower triangle) less
    L21 D L21^T, by blocks of UPDATE_BLOCK rows from ``i_begin``, each over the columns up to
    its diagonal only (about half the full product's work), from L21 in the front and
    ``dlrows`` (``_panel_rows``: every row up to ``i_end`` made), by dgemm on the front in
    place (no product buffer, no pass subtracting it). In BLAS's column-major view the
    row-major front is its transpose G (leading dimension m): L21^T is G[:w, w:], and rows
    i0 .. i1 - 1 over columns 0 .. i1 - 1 of the trailing block are G[w:w + i1, w + i0:w + i1]
    (the block's part above the front's diagonal is written too, and never read)."""
    i0 = i_begin
    while i0 < i_end:
        i1 = min(i0 + UPDATE_BLOCK, i_end)
        _gemm_less(True, i1, i1 - i0, w, front, o + w * m, m, dlrows, i0 * w, w, front,
                   o + (w + i0) * m + w, m)
        i0 = i1


@helper
def _assemble(front, t, where, indptr, indices, data, first, width, row_at, srows, child_ptr,
              child_list, relative, stack, update_at, k_begin, k_end):
    """Rows ``k_begin .. k_end - 1`` of supernode t's front (m x m, its lower triangle): the
    matrix's own entries of its columns, then the extend-add of each child's update (lower
    triangles, at ``update_at[child]`` in ``stack``), the children in ``child_list``'s order
    (``_eliminate``: all the rows; ``_front_by_halves``: two ranges, one a thread, each entry
    the same sums in the same order). ``where``: each of those rows' position, by its row."""
    j0, w = first[t], width[t]
    r0 = row_at[t]
    m = row_at[t + 1] - r0
    whole = k_begin == 0 and k_end == m
    for a in range(k_begin, k_end):   # (only the lower triangle is read)
        for b in range(a + 1):
            front[_unsigned(a * m + b)] = 0.0
    for k in range(k_begin, k_end):
        where[srows[r0 + k]] = k
    if k_end <= k_begin:
        return
    lowest, highest = srows[r0 + k_begin], srows[r0 + k_end - 1]   # (the front's rows sorted)
    for c in range(w):   # the matrix's own entries of the supernode's columns
        for p in range(indptr[j0 + c], indptr[j0 + c + 1]):
            i = indices[p]
            if whole or lowest <= i <= highest:
                front[where[i] * m + c] += data[p]
    for q in range(child_ptr[t], child_ptr[t + 1]):
        child = child_list[q]
        base = update_at[child]
        cw = width[child]
        c0 = row_at[child] + cw
        u = row_at[child + 1] - c0
        a0, a1 = 0, u   # (the child's rows in the range: its positions ascend)
        if not whole:
            while a0 < u and relative[c0 + a0] < k_begin:
                a0 += 1
            a1 = a0
            while a1 < u and relative[c0 + a1] < k_end:
                a1 += 1
        for a in range(a0, a1):
            ra = relative[c0 + a] * m
            at = base + a * u
            for b in range(a + 1):
                front[_unsigned(ra + relative[_unsigned(c0 + b)])] += stack[_unsigned(at + b)]


@helper
def _pack_front(front, m, w, values, v):
    """A factorised front's packed L from ``values[v]``: the w x w block's rows up to the unit
    diagonal, then the m - w rows below, w values each (``bordered_lu._pack``'s layout)."""
    for k in range(w):
        for c in range(k):
            values[_unsigned(v + c)] = front[_unsigned(k * m + c)]
        values[v + k] = 1.0
        v += k + 1
    for k in range(w, m):
        for c in range(w):
            values[_unsigned(v + c)] = front[_unsigned(k * m + c)]
        v += w


@helper
def _to_condensed(front, m, w, r0, relative, flat, n_N, mirrored):
    """A root's update (its rows below, all condensed) added into the condensed block's lower
    triangle (``flat``: n_N x n_N by rows), and when ``mirrored`` also into its upper triangle
    (the update is symmetric: the Schur complement itself, when this is the only root)."""
    for a in range(m - w):
        i = relative[r0 + w + a]
        ra = i * n_N
        row = (w + a) * m + w
        for b in range(a + 1):
            flat[_unsigned(ra + relative[_unsigned(r0 + w + b)])] += front[_unsigned(row + b)]
        if mirrored:
            for b in range(a):
                flat[_unsigned(relative[_unsigned(r0 + w + b)] * n_N + i)] += \
                    front[_unsigned(row + b)]


@kernel
def _eliminate(sequence, indptr, indices, data, first, width, row_at, srows,
               tparent, child_ptr, child_list, stacked, relative, value_at, values, diagonal,
               condensed, stack, stack_base, update_at, blas_width, blas_rows, front, panel_t,
               where, column_d, xt, dlrows, strip, stack_at):
    """The multifrontal LDL^T of the supernodes ``sequence`` (ascending postorder positions:
    whole subtrees, or the top of the tree once they are done: see ``LDLSymbolic.parts``), their
    fronts in buffers of their own, so that two calls on disjoint subtrees may run at once.

    ``indptr, indices, data``: the lower triangle of the first n_linear columns (CSC, rows >= the
    column). Writes each supernode's packed L (``bordered_lu._pack``'s layout: by rows, the unit
    diagonal block's triangle, then the rows below it) at ``values[value_at[t]:]`` and its
    pivots into ``diagonal``; adds each root's update (its rows below are all condensed) into
    ``condensed`` (n_N x n_N, its lower triangle); the other updates wait for their parent in
    ``stack``, supernode t's from ``update_at[t]``, a stack of this call's own from
    ``stack_base``: a supernode takes the updates of its children (``child_list[child_ptr[t]:
    child_ptr[t + 1]]``, in reverse postorder), of which the last ``stacked[t]`` pushed on this
    call's stack are popped (a call on whole subtrees: all; the top: those of the top, the
    others read where another call left them). A front whose supernode is at least
    ``blas_width`` wide with at least ``blas_rows`` rows below it takes its rows below and its
    update by BLAS, a
    panel of columns at a time (``_panel_by_blas``), the others by the loops here. Its work
    arrays, ``front`` .. ``stack_at``, are ``_front_buffers``' (made by the caller: this
    kernel allocates nothing)."""
    n_N = condensed.shape[0]
    flat = condensed.reshape(-1)
    stack_at[0] = stack_base
    depth = 0
    for at_s in range(len(sequence)):
        t = sequence[at_s]
        j0, w = first[t], width[t]
        r0 = row_at[t]
        m = row_at[t + 1] - r0
        _assemble(front, t, where, indptr, indices, data, first, width, row_at, srows,
                  child_ptr, child_list, relative, stack, update_at, 0, m)
        depth -= stacked[t]   # (this call's stack: its children's entries are its top ones)
        if w >= blas_width and m - w >= blas_rows:
            # a panel of columns at a time: its pivots, then its rows below and their update
            # of all the later rows (also the supernode's later columns) by BLAS
            c0 = 0
            while c0 < w:
                b = min(PANEL, w - c0)
                o = c0 * m + c0
                _pivot_block(front, m, o, b, diagonal, j0 + c0, column_d)
                _panel_by_blas(front, m, o, m - c0, b, diagonal[j0 + c0:j0 + c0 + b], xt,
                               dlrows, strip)
                c0 += b
        else:
            _pivot_block(front, m, 0, w, diagonal, j0, column_d)
            # L11^T D, transposed into panel_t (w rows of m): panel_t[c, k] = d_c L[k, c]
            for c in range(w):
                d = diagonal[j0 + c]
                for k in range(w):
                    panel_t[c * m + k] = d * front[k * m + c] if k > c else (d if k == c else 0.0)
            # the rows below: L21 = F21 (D L11^T)^-1, a row at a time, each by forward substitution
            # in axpy form (contiguous in panel_t)
            i = w
            while i + 4 <= m:   # four rows at a time: each row of panel_t read once for four
                row0, row1, row2, row3 = i * m, (i + 1) * m, (i + 2) * m, (i + 3) * m
                for c in range(w):
                    pc = c * m
                    pivot = panel_t[_unsigned(pc + c)]
                    x0, x1 = front[_unsigned(row0 + c)] / pivot, front[_unsigned(row1 + c)] / pivot
                    x2, x3 = front[_unsigned(row2 + c)] / pivot, front[_unsigned(row3 + c)] / pivot
                    front[_unsigned(row0 + c)], front[_unsigned(row1 + c)] = x0, x1
                    front[_unsigned(row2 + c)], front[_unsigned(row3 + c)] = x2, x3
                    for k in range(c + 1, w):
                        entry = panel_t[_unsigned(pc + k)]
                        front[_unsigned(row0 + k)] -= x0 * entry
                        front[_unsigned(row1 + k)] -= x1 * entry
                        front[_unsigned(row2 + k)] -= x2 * entry
                        front[_unsigned(row3 + k)] -= x3 * entry
                i += 4
            for i in range(i, m):
                row = i * m
                for c in range(w):
                    x = front[row + c] / panel_t[c * m + c]
                    front[row + c] = x
                    for k in range(c + 1, w):
                        front[row + k] -= x * panel_t[c * m + k]
            # D L21^T into panel_t's columns w..m-1, then the update F22 -= L21 D L21^T (lower)
            for c in range(w):
                d = diagonal[j0 + c]
                for k in range(w, m):
                    panel_t[c * m + k] = d * front[k * m + c]
            blocks_end = w + (m - w) // 4 * 4
            for i in range(w, blocks_end, 4):   # four rows at a time (each column of panel_t
                _update_rows4(front, panel_t, m, w, i)   # read once for four)
            # the rest of each row, by one inlined copy of _update_row (LLVM's work grows with
            # each copy): in a block of four, row i + t's columns i + 1 .. i + t; below the
            # blocks, whole rows. Each entry is updated once, its sum in the same order.
            for i in range(w, m):
                _update_row(front, panel_t, m, w, i,
                            i - (i - w) % 4 + 1 if i < blocks_end else w)
        _pack_front(front, m, w, values, value_at[t])
        # the update: to the parent's stack entry, or (a root: its rows below are all
        # condensed) into ``condensed``
        u = m - w
        if tparent[t] == -1:
            _to_condensed(front, m, w, r0, relative, flat, n_N, False)
        else:
            base = stack_at[depth]   # (its children's entries popped: theirs are read)
            for a in range(u):
                at, row = base + a * u, (w + a) * m + w
                for b in range(a + 1):
                    stack[_unsigned(at + b)] = front[_unsigned(row + b)]
            update_at[t] = base
            depth += 1
            stack_at[depth] = base + u * u


def _front_buffers(sequence, symbolic, n_N, blas_width, blas_rows) -> tuple:
    """``_eliminate``'s work arrays for ``sequence``: (front, panel_t, where, column_d, xt,
    dlrows, strip, stack_at), each sized for the largest of its fronts (xt, dlrows, strip for
    the largest through BLAS). Made here, in the calling thread, for both threads' parts: a
    buffer the second thread allocated itself would be freed into that thread's own malloc
    arena, which keeps it resident (~9 MB of the fine scene's peak) where the calling thread's
    heap reuses it."""
    width, row_at = symbolic.tree[1], symbolic.tree[2]
    m = row_at[sequence + 1] - row_at[sequence]
    w = width[sequence]
    largest_front = int(m.max(initial=0))
    widest = int(w.max(initial=1))
    blas = (w >= blas_width) & (m - w >= blas_rows)
    big_w, big_m = (PANEL, int(m[blas].max(initial=1))) if blas.any() else (1, 1)
    return (np.empty(largest_front * largest_front), np.empty(largest_front * widest),
            np.full(symbolic.n_linear + n_N, -1, dtype=np.int64), np.empty(widest),
            np.empty(big_w * big_m), np.empty(big_w * big_m),
            np.empty(min(SOLVE_BLOCK, big_w) * big_w),
            np.empty(len(sequence) + 1, dtype=np.int64))


@intrinsic
def _load_acquire(typingctx, array, index):
    """array[index] (int64) by an atomic load with acquire order: what the other thread wrote
    before its ``_store_release`` of this entry is seen after it (and the load is made at each
    call: a plain one in a waiting loop may be hoisted out of it)."""
    def codegen(context, builder, signature, args):
        kind = signature.args[0]
        array = context.make_array(kind)(context, builder, args[0])
        at = cgutils.get_item_pointer(context, builder, kind, array, [args[1]])
        return builder.load_atomic(at, "acquire", 8)
    return types.int64(array, index), codegen


@intrinsic
def _store_release(typingctx, array, index, value):
    """array[index] = value (int64) by an atomic store with release order (``_load_acquire``)."""
    def codegen(context, builder, signature, args):
        kind = signature.args[0]
        array = context.make_array(kind)(context, builder, args[0])
        at = cgutils.get_item_pointer(context, builder, kind, array, [args[1]])
        builder.store_atomic(args[2], at, "release", 8)
        return context.get_dummy_value()
    return types.void(array, index, value), codegen


#: the C library's clock_gettime and usleep (found in the process, as numba_xxgemm)
_clock_gettime = types.ExternalFunction("clock_gettime", types.intc(
    types.intc, types.CPointer(types.int64)))
_usleep = types.ExternalFunction("usleep", types.intc(types.uint32))
#: clock_gettime's CLOCK_MONOTONIC (time.perf_counter's clock on Linux)
_MONOTONIC = 1
#: a waiting thread spins this long (ns; a thread woken from a sleep, as at a
#: threading.Barrier, took 70-100 us on this machine, a spin 0.4 us), ...
SPIN_NS = 50_000
#: ... then sleeps this long (us, plus the kernel's timer slack) between looks, so that a
#: machine's other work, or the other half sharing its core, runs
SLEEP_US = 20
#: ``sync``'s entries: the halves' counts (0, 1), a thread failed (2), the second thread's
#: part of the tree done (3), the top done (4), each half's clock read (from 8 and 16: other
#: cache lines)
_SYNC_SIZE, _CLOCK_AT = 24, 8


@helper
def _stamp(stamps, half, k):
    """The monotonic clock (s, ns) into stamps[half, 2k:2k + 2]."""
    _clock_gettime(_MONOTONIC, stamps[half, 2 * k:].ctypes)


@helper
def _now(sync, half):
    """The monotonic clock (ns), read into ``sync``'s entries for ``half``."""
    at = _CLOCK_AT * (1 + half)
    _clock_gettime(_MONOTONIC, sync[at:].ctypes)
    return sync[at] * 1_000_000_000 + sync[at + 1]


@helper
def _wait_until(sync, half, index, count):
    """Half ``half`` waits until ``sync[index]`` is at least ``count``: spinning for SPIN_NS,
    then sleeping SLEEP_US between looks; False when a thread failed (``sync[2]`` set)."""
    looks = 0
    start = -1
    while _load_acquire(sync, index) < count:
        if _load_acquire(sync, 2) != 0:
            return False
        looks += 1
        if looks % 64 == 0:
            if start < 0:
                start = _now(sync, half)
            elif _now(sync, half) - start > SPIN_NS:
                _usleep(SLEEP_US)
    return True


@helper
def _meet(sync, stamps, half, k):
    """The two halves' k-th meeting: this half's count (``sync[half]``) to k, then wait until
    the other's is k (``_wait_until``); False when the other half failed. Its arrival and its
    departure stamped (``stamps[half]``, points 2k - 1 and 2k)."""
    _stamp(stamps, half, 2 * k - 1)
    _store_release(sync, half, k)
    if not _wait_until(sync, half, 1 - half, k):
        return False
    _stamp(stamps, half, 2 * k)
    return True


@kernel
def _await_part(sync):
    """The calling thread waits for the second thread's part of the tree, done when its half of
    the shared front starts (``sync[3]``): a spin of the two threads' own, where a lock would
    wake the waiting thread 0.1-0.2 ms late on this machine (``_wait_until``). False when it
    failed."""
    return _wait_until(sync, 0, 3, 1)


@kernel
def _front_by_halves(half, t, assembly_cut, panel_c0, panel_b, rows_cut, block_ptr, blocks,
                     sync, stamps, front, where, indptr, indices, data, first, width, row_at,
                     srows, child_ptr, child_list, relative, stack, update_at, diagonal, column_d,
                     xt, dlrows, strip, value_at, values, condensed, mirrored):
    """Supernode t (the last of the top: a root) factorised by panels whose rows below and
    update are shared between two halves (``_numeric``, ``_front_arguments``): ``half`` 0 (the
    calling thread: its rows before ``assembly_cut`` assembled, each panel's pivots, the
    packing), 1 (the other thread, after its part of the tree: the other rows assembled), or
    -1 (both, one after the other, in one thread). Per panel
    p (columns ``panel_c0[p]``, ``panel_b[p]`` of them): its pivot block (``_pivot_block``),
    then each half's rows below (``_panel_rows``: half 0 the first ``rows_cut[p]``, half 1 the
    others), then each half's blocks of UPDATE_BLOCK rows of the update (``_panel_update``:
    those from ``blocks[block_ptr[2p + half]:block_ptr[2p + half + 1]]``); in two threads the
    halves meet (``_meet``) after the pivots, after the rows and after the update, with
    ``sync`` (``_SYNC_SIZE``: the halves' counts, a thread failed, [3] set as the second half
    starts, after the second thread's part of the tree, [4] as the first starts, after the
    top) and ``stamps`` (each half's clock at the start, at each meeting's arrival and departure, at
    the end). The same calls on the same rows in one thread or two: the same factors bit for
    bit. False when the other half failed. One kernel for a half's whole front: a call, not a
    Python call and a threading.Barrier per step (70-100 us each)."""
    j0, w = first[t], width[t]
    r0 = row_at[t]
    m = row_at[t + 1] - r0
    both = half == -1
    own = 0 if both else half
    k = 0
    if half == 1:   # (its part of the tree is done: ``_await_part``; it assembles its rows
        _store_release(sync, 3, 1)   # once the top's updates are made: sync[4])
        if not _wait_until(sync, 1, 4, 1):
            return False
    elif half == 0:
        _store_release(sync, 4, 1)
    _stamp(stamps, own, 0)
    for h in range(2):   # (its rows in two ranges; the first holds the first pivot block)
        if both or h == half:
            _assemble(front, t, where, indptr, indices, data, first, width, row_at, srows,
                      child_ptr, child_list, relative, stack, update_at,
                      0 if h == 0 else assembly_cut, assembly_cut if h == 0 else m)
    for p in range(len(panel_c0)):
        c0, b = panel_c0[p], panel_b[p]
        o = c0 * m + c0
        u = m - c0 - b
        if half != 1:
            _pivot_block(front, m, o, b, diagonal, j0 + c0, column_d)
        for step in range(2):   # (the rows below, then the update)
            if not both:
                k += 1
                if not _meet(sync, stamps, half, k):
                    return False
            for h in range(2):
                if both or h == half:
                    if step == 0:
                        _panel_rows(front, m, o, b, diagonal[j0 + c0:j0 + c0 + b],
                                    0 if h == 0 else rows_cut[p], rows_cut[p] if h == 0 else u,
                                    xt[h], dlrows, strip[h])
                    else:
                        for q in range(block_ptr[2 * p + h], block_ptr[2 * p + h + 1]):
                            _panel_update(front, m, o, b, dlrows, blocks[q],
                                          min(blocks[q] + UPDATE_BLOCK, u))
        if not both:   # (the trailing block updated: the next pivots, or the packing)
            k += 1
            if not _meet(sync, stamps, half, k):
                return False
    if half != 1:
        _pack_front(front, m, w, values, value_at[t])
        _to_condensed(front, m, w, r0, relative, condensed.reshape(-1), condensed.shape[0],
                      mirrored)
    _stamp(stamps, own, 2 * k + 1)
    return True


def _in_background(fn, *args):
    """Start fn(*args) in a thread of its own and return at once: a function that waits for it
    to end and raises what it raised. (``threading.Thread.start`` waits until the new thread
    runs, which on a busy machine is a scheduler's time slice during which the caller could
    already factorise its own part; a ``threading.Thread``'s exception is only printed.)"""
    done = _thread.allocate_lock()
    done.acquire()
    failed = []

    def body():
        try:
            fn(*args)
        except BaseException as error:   # (handed to the caller by ``join``)
            failed.append(error)
        finally:
            done.release()

    _thread.start_new_thread(body, ())

    def join(raise_failure=True):
        with done:
            pass
        if failed and raise_failure:
            raise failed[0]

    return join


def _front_plan(t, symbolic):
    """The plan of the shared front t (``_front_by_halves``), from the pattern alone: (the row
    where its assembly is cut between the halves, then per panel its first column, width,
    rows-below cut, and per half where its update's blocks start in the blocks' list, the list).
    The assembly is cut where the rows before hold ASSEMBLY_SHARE of the lower triangle (at
    least a panel: the first pivot block is the calling thread's, before the halves meet).
    Each panel's rows below are cut in half at a multiple of SPLIT_ALIGN rows; its update's
    blocks (``_panel_update``'s own, rows i0 .. i1 - 1 taking (i1 - i0) i1 products) are dealt
    to the lighter half, the largest first."""
    width, row_at = symbolic.tree[1], symbolic.tree[2]
    w, m = int(width[t]), int(row_at[t + 1] - row_at[t])
    panel_c0, panel_b, rows_cut, block_ptr, blocks = [], [], [], [0], []
    c0 = 0
    while c0 < w:
        b = min(PANEL, w - c0)
        u = m - c0 - b
        starts = np.arange(0, u, UPDATE_BLOCK, dtype=np.int64)
        ends = np.minimum(starts + UPDATE_BLOCK, u)
        dealt, loads = ([], []), [0, 0]
        for k in sorted(range(len(starts)), key=lambda k: (-(ends[k] - starts[k]) * ends[k], k)):
            half = 0 if loads[0] <= loads[1] else 1
            dealt[half].append(int(starts[k]))
            loads[half] += (ends[k] - starts[k]) * ends[k]
        for half in (0, 1):
            blocks += sorted(dealt[half])
            block_ptr.append(len(blocks))
        panel_c0.append(c0)
        panel_b.append(b)
        rows_cut.append(min(u, SPLIT_ALIGN * int(round(u / 2.0 / SPLIT_ALIGN))))
        c0 += b
    assembly_cut = min(m, max(PANEL, int(round(m * np.sqrt(ASSEMBLY_SHARE)))))
    return (assembly_cut, *(np.asarray(x, dtype=np.int64)
                            for x in (panel_c0, panel_b, rows_cut, block_ptr, blocks)))


def _front_arguments(t, lower, symbolic, diagonal, values, stack, update_at, condensed,
                     mirrored):
    """(``_front_by_halves``' arguments after ``half`` for supernode t (the last of the top: a
    root), their ``sync``), its buffers made here, in the calling thread (``_front_buffers``).
    The halves' clock stamps are left in ``symbolic.front_stamps``
    (``benchmarks/factorisation.py --fronts``)."""
    first, width, row_at, srows, tparent, children, relative = symbolic.tree
    w, m = int(width[t]), int(row_at[t + 1] - row_at[t])
    if symbolic.front_plan is None:
        symbolic.front_plan = _front_plan(t, symbolic)
    plan = symbolic.front_plan
    meetings = 3 * len(plan[1])
    symbolic.front_stamps = stamps = np.zeros((2, 2 * (2 * meetings + 2)), dtype=np.int64)
    sync = np.zeros(_SYNC_SIZE, dtype=np.int64)
    return (t, *plan, sync, stamps, np.empty(m * m),
            np.empty(symbolic.n_linear + condensed.shape[0], dtype=np.int64), lower.indptr,
            lower.indices, lower.data, first, width, row_at, srows, symbolic.child_ptr,
            symbolic.child_list, relative, stack, update_at, diagonal, np.empty(max(w, 1)),
            np.empty((2, PANEL * m)), np.empty(PANEL * m), np.empty((2, SOLVE_BLOCK * PANEL)),
            symbolic.value_at, values, condensed, mirrored), sync


def front_multiply_adds(width, below):
    """Multiply-adds of each front with ``width`` pivots and ``below`` rows under them: (its
    pivot block's L D L^T, its rows below solved against it, its update of the rows below)."""
    return (width ** 3 / 6.0, below * width * width / 2.0,
            width * below * (below + 1) / 2.0)


#: a factorisation of more multiply-adds than this takes its two parts in two threads
#: (``LDLSymbolic.parts``); below it a thread's start costs more than it saves
THREADS_ABOVE = 20e6

_in_this_thread = threading.local()


def _two_threads_here() -> bool:
    """The two threads meet through the C library's clock_gettime (CLOCK_MONOTONIC = 1) and
    usleep (``_wait_until``), Linux's: elsewhere a factorisation takes one thread (the same
    factors bit for bit)."""
    return sys.platform.startswith("linux")


@contextlib.contextmanager
def one_thread():
    """Factorisations made by the calling thread inside this block take one thread (the same
    factors bit for bit): one made beside the steps (``linear_system.CondensedSystem.
    factorise_ahead``) would otherwise be a third thread on two cores, and its second thread
    another malloc arena."""
    before = getattr(_in_this_thread, "one", False)
    _in_this_thread.one = True
    try:
        yield
    finally:
        _in_this_thread.one = before
#: the two threads' parts are balanced until their multiply-adds differ by at most this
#: fraction of their sum (``LDLSymbolic._plan``), ...
BALANCE = 0.03
#: ... splitting at most this many subtrees (each split moves a front into the serial top)
MOST_SPLITS = 16
#: the top's last front is shared between the two threads (``_front_by_halves``) when its rows
#: below and its update take at least this many multiply-adds, at a refactorisation only (a
#: pattern's numeric factorisations after its first: a run on one step size never compiles or
#: loads the shared front's kernels, which cost seconds of compilation and a cache load for
#: a millisecond or two)
SPLIT_FRONT_ABOVE = 4e6
#: its rows below are cut at a multiple of this many (its update by the unshared front's blocks
#: of rows): the products' shapes then part where the BLAS's own blocking does, and with the
#: OpenBLAS measured the factors equal the unshared front's bit for bit, as a restored run's
#: first factorisation must equal the refactorisation it repeats (cuts at any row gave
#: differences of 1e-20 of the largest entry)
SPLIT_ALIGN = 16
#: the calling thread assembles the shared front's rows that hold this share of its lower
#: triangle, the other thread the rest (the calling thread also makes the first pivots before
#: they meet: on paper-units Rustrel, with half the rows' entries each, 0.17 against 0.10 ms)
ASSEMBLY_SHARE = 0.4


def _numeric(lower, schur, symbolic, threads=None, blas_width=None, blas_rows=None,
             share_front=None):
    """The numeric LDL^T of ``lower`` (``_lower``'s form) on ``symbolic``: (packed values, D,
    smallest |d| / largest |d|: 0 or NaN, not quasi-definite); ``schur`` holds M_NN on entry and
    the Schur complement on return. The two independent parts of ``symbolic.parts`` run in two
    threads when ``threads`` is 2 (default: when the factorisation is larger than
    THREADS_ABOVE), else one after the other, then the top; the sums are the same either way
    (each part's fronts in their buffers and its stack in its own region, its roots' updates
    summed apart, the parts' sums added in one fixed order), so the factors are the same to the
    last bit; with one root (the tree's top, the usual case) the Schur complement is M_NN plus
    its update, as when one pass made it. ``blas_width``, ``blas_rows``: the fronts through
    BLAS (``_eliminate``; default BLAS_MIN_WIDTH and BLAS_MIN_ROWS). ``share_front``: the
    top's last front shared by the threads where the plan has one (``split_front``; default:
    at a refactorisation, see SPLIT_FRONT_ABOVE): its halves by ``_front_by_halves``, in two
    threads the second by the thread of the second part, after it."""
    if share_front is None:
        share_front = symbolic.factorisations > 0
    symbolic.factorisations += 1
    blas_width = BLAS_MIN_WIDTH if blas_width is None else blas_width
    blas_rows = BLAS_MIN_ROWS if blas_rows is None else blas_rows
    first, width, row_at, srows, tparent, children, relative = symbolic.tree
    n_linear = symbolic.n_linear
    values = np.empty(symbolic.value_at[-1])
    diagonal = np.empty(n_linear)
    n_N = schur.shape[0]
    stack = np.empty(symbolic.stack_size)
    update_at = np.empty(len(width), dtype=np.int64)
    sequences, bases = symbolic.parts, symbolic.part_bases
    share_front = share_front and symbolic.split_front >= 0   # (the top's last supernode)
    # the roots' updates: of the first part and the top (after it), and of the second part; a
    # tree whose one root is the shared front (a refactorisation's usual case) adds that
    # root's update into the Schur complement itself, both triangles, as M_NN + update (the
    # same sums as through the parts' arrays, which would hold it alone: 0.3 ms less on
    # paper-units Rustrel, two n_N x n_N arrays less); a Fortran-ordered one through its
    # transpose, whose triangles take the same sums. (Not in ``_eliminate``, whose argument
    # types stay those compile_ahead.KERNELS lists.)
    direct = schur if schur.flags.c_contiguous else schur.T
    mirrored = share_front and symbolic.roots == 1 and direct.flags.c_contiguous
    first_part, second_part = ((direct, direct) if mirrored
                               else (np.zeros((n_N, n_N)), np.zeros((n_N, n_N))))
    common = (lower.indptr, lower.indices, lower.data, first, width, row_at, srows,
              tparent, symbolic.child_ptr, symbolic.child_list, symbolic.stacked, relative,
              symbolic.value_at, values, diagonal)

    def run(part, condensed, sequence=None, buffers=None):
        sequence = sequences[part] if sequence is None else sequence
        _eliminate(sequence, *common, condensed, stack, bases[part], update_at,
                   blas_width, blas_rows,
                   *(buffers or _front_buffers(sequence, symbolic, n_N, blas_width, blas_rows)))

    if threads is None:
        threads = (1 if getattr(_in_this_thread, "one", False) or not _two_threads_here() else
                   2 if symbolic.multiply_adds > THREADS_ABOVE else 1)
    # the shared front's halves (``_front_by_halves``): the second in the thread of the second
    # part, right after it, so that one thread is started and joined per factorisation, and
    # the first thread waits for that part by a spin (``_await_part``), not a lock
    halves, sync = (_front_arguments(symbolic.split_front, lower, symbolic, diagonal, values,
                                     stack, update_at, first_part, mirrored)
                    if share_front else (None, None))
    top = sequences[2][:-1] if share_front else sequences[2]
    if threads >= 2 and (halves is not None or (len(sequences[0]) and len(sequences[1]))):
        # (the second part's buffers made here, not in its thread: see _front_buffers)
        buffers = _front_buffers(sequences[1], symbolic, n_N, blas_width, blas_rows)

        def second():
            try:
                run(1, second_part, None, buffers)
                if halves is not None:
                    _front_by_halves(1, *halves)
            except BaseException:
                if halves is not None:
                    sync[2] = 1   # (the calling thread stops waiting for it)
                raise

        join = _in_background(second)
        whole = True
        try:
            run(0, first_part)
            if halves is None:
                join()
            elif not _await_part(sync):
                join()   # (raises the second thread's error)
            run(2, first_part, top)
            if halves is not None:
                whole = _front_by_halves(0, *halves)
        except BaseException:
            if halves is not None:
                sync[2] = 1
            join(raise_failure=False)
            raise
        join()   # (raises the second half's error: when it failed, ``whole`` is False)
        if not whole:
            raise RuntimeError("the shared front's second half stopped without an error")
    else:
        run(0, first_part)
        run(1, second_part)
        run(2, first_part, top)
        if halves is not None:
            _front_by_halves(-1, *halves)
    if not mirrored:
        # the roots' updates are lower triangles (zero above the diagonal): summed in place and
        # mirrored with one temporary (n_N x n_N arrays: 46 MB each on a fault of 2,400 unknowns)
        update = np.add(first_part, second_part, out=first_part)
        del second_part
        schur += update
        schur += np.tril(update, -1).T
    magnitude = np.abs(diagonal)
    if not np.all(np.isfinite(magnitude)):
        return values, diagonal, np.nan
    if n_linear == 0:
        return values, diagonal, 1.0
    largest = magnitude.max()
    return values, diagonal, (magnitude.min() / largest if largest > 0.0 else 0.0)


def _two_bins(subtrees, load):
    """The subtrees (ids) dealt to two bins, each in turn to the lighter one, the largest first
    (ties by id): (bins, their loads)."""
    bins, loads = ([], []), [0.0, 0.0]
    for t in sorted(subtrees, key=lambda t: (-load[t], t)):
        k = 0 if loads[0] <= loads[1] else 1
        bins[k].append(t)
        loads[k] += load[t]
    return bins, loads


class LDLSymbolic:
    """The symbolic analysis of a pattern: made once, it serves every matrix of that pattern
    (``factorise``). ``lower``: the lower triangle of the first ``n_linear`` columns of the
    symmetric matrix in its elimination order (``_lower``), those the unknowns eliminated."""

    def __init__(self, lower, n_linear: int):
        self.n, self.n_linear = lower.shape[0], n_linear
        self.indptr, self.indices = lower.indptr, lower.indices
        upper = lower.T.tocsc()
        upper.sort_indices()
        parent = _etree(upper.indptr, upper.indices.astype(np.int64), n_linear)
        col_ptr, rows = _structure(upper.indptr, upper.indices.astype(np.int64), self.n,
                                   n_linear, parent)
        self.nnz = int(col_ptr[-1])   # L's entries
        self.tree = _supernode_tree(col_ptr, rows, parent, n_linear)
        self.rows = self.tree[3].astype(np.int32)   # (the sweeps' index type, SuperLU's)
        self._plan()

    def _plan(self):
        """What the numeric factorisation needs beyond the tree, from the pattern alone: where
        each supernode's packed values start (``value_at``), the multiply-adds, each
        supernode's children (``child_ptr``, ``child_list``: in reverse postorder, the order a
        stack pops them), and the parts it runs in.

        ``parts``: three ascending arrays of supernodes, the first two whole subtrees (run
        beside each other), the third the top (run after them: every supernode whose subtree
        was not dealt out). The subtrees are dealt by their multiply-adds (subtree-to-thread
        mapping): from the children of the root's line of only children (or the roots of a
        forest), each in turn to the lighter part, the largest first; while the parts differ by
        more than BALANCE of their sum, the largest subtree is split (its front joins the top,
        its children are dealt), and the plan of least multiply-adds on the longer path
        (larger part, then top) is kept. ``part_bases``: where each part's stack starts
        (the first at 0, the second above the first's peak, the top above what the second
        leaves), from a dry run of the pushes and pops that also sizes the stack
        (``stack_size``); ``stacked``: how many of a supernode's children its own part's stack
        holds (all, but in the top: its children in the top)."""
        first, width, row_at, srows, tparent, children, relative = self.tree
        n_sn = len(width)
        m = np.diff(row_at)
        u = m - width
        self.value_at = np.concatenate([[0], np.cumsum(width * (width + 1) // 2 + u * width)])
        pivot, below, update = front_multiply_adds(width, u)
        work = pivot + below + update
        self.multiply_adds = float(work.sum())
        kids_of = [[] for _ in range(n_sn)]
        for t in range(n_sn - 1, -1, -1):   # (reverse postorder)
            if tparent[t] != -1:
                kids_of[tparent[t]].append(t)
        self.child_ptr = np.concatenate([[0], np.cumsum([len(k) for k in kids_of])]).astype(np.int64)
        self.child_list = np.asarray([c for k in kids_of for c in k], dtype=np.int64)
        # each subtree's multiply-adds and size (in postorder, subtree t is t - size + 1 .. t)
        load, size = work.copy(), np.ones(n_sn, dtype=np.int64)
        for t in range(n_sn):
            if tparent[t] != -1:
                load[tparent[t]] += load[t]
                size[tparent[t]] += size[t]
        # the top: a unique root and its line of only children (none for a forest)
        top = []
        kids = [int(t) for t in np.flatnonzero(tparent == -1)]
        while len(kids) == 1:
            top.append(kids[0])
            kids = kids_of[kids[0]]
        subtrees, best = list(kids), None
        for _ in range(MOST_SPLITS + 1):
            bins, loads = _two_bins(subtrees, load)
            path = max(loads) + float(work[top].sum())
            if best is None or path < best[0]:
                best = (path, bins, list(top))
            largest = max(subtrees, key=lambda t: (load[t], t), default=None)
            if (largest is None or not kids_of[largest]
                    or abs(loads[0] - loads[1]) <= BALANCE * (loads[0] + loads[1])):
                break
            subtrees.remove(largest)
            subtrees += kids_of[largest]
            top.append(largest)
        _, bins, top = best
        parts = [np.sort(np.concatenate([np.arange(t - size[t] + 1, t + 1) for t in b]
                                        or [np.zeros(0, dtype=np.int64)])).astype(np.int64)
                 for b in bins]
        parts.append(np.sort(np.asarray(top, dtype=np.int64)))
        in_top = np.zeros(n_sn, dtype=bool)
        in_top[parts[2]] = True
        self.stacked = children.astype(np.int64).copy()
        for t in parts[2]:
            self.stacked[t] = sum(1 for c in kids_of[t] if in_top[c])

        def dry_run(sequence, base):
            """(peak, top at the end) of a part's stack from ``base``."""
            at = [base]
            peak = base
            for t in sequence:
                if self.stacked[t]:
                    del at[-self.stacked[t]:]
                if tparent[t] != -1:
                    at.append(at[-1] + int(u[t]) ** 2)
                    peak = max(peak, at[-1])
            return peak, at[-1]

        first_peak, _ = dry_run(parts[0], 0)
        second_peak, second_left = dry_run(parts[1], first_peak)
        top_peak, _ = dry_run(parts[2], second_left)
        self.stack_size = max(first_peak, second_peak, top_peak)
        self.part_bases = (0, first_peak, second_left)
        self.parts = tuple(parts)
        # the top's last supernode (a root) shared between the threads when it is large
        self.factorisations = 0   # (numeric ones on this analysis: ``_numeric``)
        self.roots = int(np.sum(tparent == -1))
        self.split_front = -1
        self.front_plan = self.front_stamps = None   # (``_front_arguments``)
        if len(parts[2]):
            last = int(parts[2][-1])
            if (width[last] >= BLAS_MIN_WIDTH and u[last] >= BLAS_MIN_ROWS
                    and below[last] + update[last] >= SPLIT_FRONT_ABOVE):
                self.split_front = last

    def matches(self, lower) -> bool:
        """Is ``lower`` (``_lower``) of this pattern?"""
        return (lower.shape == (self.n, self.n_linear)
                and np.array_equal(lower.indptr, self.indptr)
                and np.array_equal(lower.indices, self.indices))


class SymbolicAnalyses:
    """The symbolic analyses made so far, one per pattern (a bulk factorised in parts has one
    per part): a new step size finds its pattern's here and pays the numeric part only."""

    def __init__(self):
        self._held = []

    @property
    def made(self) -> int:
        """How many symbolic analyses were made (one per pattern)."""
        return len(self._held)

    def of(self, lower, n_linear):
        for symbolic in self._held:
            if symbolic.n_linear == n_linear and symbolic.matches(lower):
                return symbolic
        symbolic = LDLSymbolic(lower, n_linear)
        self._held.append(symbolic)
        return symbolic


def _lower(M, n_linear):
    """The lower triangle of M's first n_linear columns (CSC, sorted; explicit zeros kept: the
    pattern is the assembly's, the same at every step size)."""
    n = M.shape[0]
    first = M[:, :n_linear].tocoo()
    keep = first.row >= first.col
    lower = sp.csc_matrix((first.data[keep], (first.row[keep], first.col[keep])),
                          shape=(n, n_linear))
    lower.sort_indices()
    return lower


#: the smallest pivot relative to the largest that the factorisation accepts; below it (a
#: block not quasi-definite in this order, or singular to working precision) the caller
#: takes the pivoting LU
PIVOT_RATIO = 1e-14


def factorise(M, n_linear: int, analyses: SymbolicAnalyses):
    """(packed L, D, Schur complement on N, L's entries) of the symmetric ``M`` (sparse, the
    first ``n_linear`` unknowns eliminated), on the symbolic analysis of its pattern from
    ``analyses`` (made there at the first matrix of a pattern). Raises NotQuasiDefinite when a
    pivot is zero, not finite or below PIVOT_RATIO of the largest."""
    M = sp.csc_matrix(M)
    return factorise_lower(_lower(M, n_linear), M[n_linear:, n_linear:].toarray(), n_linear,
                           analyses)


def factorise_lower(lower, schur, n_linear: int, analyses: SymbolicAnalyses):
    """``factorise`` given the lower triangle of M's first ``n_linear`` columns (``_lower``'s
    form: CSC, sorted) and M's dense block on the condensed unknowns (``schur``, overwritten
    with the Schur complement)."""
    symbolic = analyses.of(lower, n_linear)
    first, width, row_at = symbolic.tree[:3]
    values, diagonal, ratio = _numeric(lower, schur, symbolic)
    if not ratio >= PIVOT_RATIO:
        raise NotQuasiDefinite(f"LDL^T pivot ratio {ratio:.1e} below {PIVOT_RATIO:.0e}")
    packed = (first, width, row_at, symbolic.value_at, symbolic.rows, values)
    return packed, diagonal, schur, symbolic.nnz

"""Fill-reducing ordering of the bulk's sparse LU: geometric nested dissection.

The bulk lives on a structured 2-D mesh, so its unknowns can be split by their coordinates: the
set is cut at the median along its longer extent, the unknowns of one half that couple to the
other form the separator, and each half is ordered the same way before the separator, which comes
last. On a 2-D grid this bounds the fill near n log n, where the minimum-degree orderings that
SuperLU offers fill more: on the Rustrel bulk at 100 x 101 (31k unknowns) it has 16-20 % fewer
non-zeros in L + U, factorises in 40-50 % less time and solves a block of right-hand sides (the
condensation) 25-35 % faster (issue 15).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ._jit import helper, kernel

#: sets of at most this many unknowns are not split further (kept in the order given); 8 has
#: 2.7-4.4 % fewer non-zeros in L + U than 32 (Rustrel 200 x 201: 34.6M -> 33.0M; the fine
#: 30 deg scene: 22.0M -> 21.4M), 4 no more than 8
LEAF_SIZE = 8


def nested_dissection(pattern: sp.spmatrix, xy: np.ndarray, leaf: int = LEAF_SIZE,
                      return_split: bool = False):
    """Permutation (new position -> old index) of the unknowns of a square sparse matrix whose
    unknown i sits at ``xy[i]`` (m). Only the pattern of ``pattern + pattern^T`` is used.

    ``return_split``: also the sizes (n_left, n_right, n_separator) of the first cut, in the
    order the permutation places them (None when the set was not cut): the two halves do not
    couple, so they can be factorised apart (``bordered_lu.SplitBorderedLU``)."""
    n = pattern.shape[0]
    sym = (abs(pattern) + abs(pattern.T)).tocsr()
    sym.sum_duplicates()
    # (the medians are taken in float64, as numpy takes them of float64 coordinates)
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    perm, split = _dissect(sym.indptr, sym.indices, xy, leaf)
    assert len(perm) == n
    split = None if split[0] < 0 else tuple(int(v) for v in split)
    return (perm, split) if return_split else perm


@kernel
def _dissect(indptr, indices, xy, leaf):
    """``nested_dissection``'s permutation and first cut ((-1, -1, -1): none) from the pattern
    (CSR, symmetric) and the coordinates.

    Each set is a segment of the permutation, rearranged in place as [left without separator,
    right, separator] (each part in the order given, as numpy's boolean selections keep it);
    the parts then go on the stack, so that the segments, read left to right, are the post-order
    (left, right, separator). A set is cut at the median of its longer extent (numpy's median:
    the middle value, or the mean of the two middle ones)."""
    n = len(indptr) - 1
    perm = np.arange(n)
    part = np.empty(n, dtype=np.int64)   # the segment being rearranged
    key = np.empty(n)
    in_right = np.zeros(n, dtype=np.bool_)
    touches = np.zeros(n, dtype=np.bool_)
    split = (-1, -1, -1)
    # (segment start, end, 1: a separator to place); a cut pops one and pushes three, so the
    # stack holds at most 2 per level of the (at most n deep) recursion, and one more
    stack = np.empty((2 * n + 1, 3), dtype=np.int64)
    stack[0, 0], stack[0, 1], stack[0, 2] = 0, n, 0
    top = 1
    while top:
        top -= 1
        lo, hi, emit = stack[top, 0], stack[top, 1], stack[top, 2]
        m = hi - lo
        if emit or m <= leaf:
            continue
        axis = _longer_extent(xy, perm, lo, hi)
        for k in range(m):
            key[k] = xy[perm[lo + k], axis]
        median = _median(key[:m].copy())
        n_left = 0
        for k in range(m):
            n_left += key[k] <= median
        if n_left == 0 or n_left == m:   # (also a NaN median: nothing is <= it)
            continue
        for k in range(m):
            if not key[k] <= median:
                in_right[perm[lo + k]] = True
        # unknowns of the left part with a neighbour in the right one: the separator
        n_sep = 0
        for k in range(m):
            i = perm[lo + k]
            touches[k] = False
            if key[k] <= median:
                for e in range(indptr[i], indptr[i + 1]):
                    if in_right[indices[e]]:
                        touches[k] = True
                        n_sep += 1
                        break
        n_inner, n_right = n_left - n_sep, m - n_left
        a, b, c = 0, n_inner, n_inner + n_right
        for k in range(m):
            i = perm[lo + k]
            if not key[k] <= median:
                in_right[i] = False
                part[b] = i
                b += 1
            elif touches[k]:
                part[c] = i
                c += 1
            else:
                part[a] = i
                a += 1
        for k in range(m):
            perm[lo + k] = part[k]
        if split[0] < 0:
            split = (n_inner, n_right, n_sep)
        top = _push(stack, top, lo + n_inner + n_right, hi, 1)
        top = _push(stack, top, lo + n_inner, lo + n_inner + n_right, 0)
        top = _push(stack, top, lo, lo + n_inner, 0)
    return perm, split


@helper
def _longer_extent(xy, perm, lo, hi):
    """The axis of the largest max - min of the points ``perm[lo:hi]`` (the first of equals)."""
    axis, longest = 0, 0.0
    for d in range(xy.shape[1]):
        low = high = xy[perm[lo], d]
        for k in range(lo + 1, hi):
            v = xy[perm[k], d]
            low = min(low, v)
            high = max(high, v)
        if d == 0 or high - low > longest:
            axis, longest = d, high - low
    return axis


@helper
def _push(stack, top, lo, hi, emit):
    """Put the segment [lo, hi) on ``_dissect``'s stack; the new top."""
    stack[top, 0], stack[top, 1], stack[top, 2] = lo, hi, emit
    return top + 1


@helper
def _median(values):
    """numpy's median of ``values`` (reordered): the middle value, or the two middle ones' mean
    ((a + b) / 2, as np.mean of two); NaN if any is NaN."""
    m = len(values)
    for k in range(m):
        if values[k] != values[k]:
            return np.nan
    half = m // 2
    middle = _select(values, half)
    if m % 2:
        return middle
    below = values[0]   # the largest of the values before the middle one
    for k in range(1, half):
        below = max(below, values[k])
    return (below + middle) / 2.0


@helper
def _select(values, rank):
    """The value of the given rank (0: the smallest) in ``values``, which it reorders so that
    none before it is larger and none after it smaller (Hoare's quickselect; a grid's many equal
    keys stop both scans, so they split evenly)."""
    lo, hi = 0, len(values) - 1
    while lo < hi:
        pivot = values[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if rank <= j:
            hi = j
        elif rank >= i:
            lo = i
        else:
            break
    return values[rank]

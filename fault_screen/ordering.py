"""Fill-reducing ordering of the bulk's sparse LU: geometric nested dissection.

The bulk lives on a structured 2-D mesh, so its unknowns can be split by their coordinates: the
set is cut at the median across its side with more node lines (on a graded mesh not always its
longer side in metres), the unknowns of one half that couple to the other form the separator,
and each half is ordered the same way before the separator, which comes last. On a 2-D grid
this bounds the fill near n log n, where the minimum-degree orderings that
SuperLU offers fill more: on the Rustrel bulk at 100 x 101 (31k unknowns) it has 16-20 % fewer
non-zeros in L + U, factorises in 40-50 % less time and solves a block of right-hand sides (the
condensation) 25-35 % faster (issue 15).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

#: sets of at most this many unknowns are not split further (kept in the order given); 8 has
#: 2.7-4.4 % fewer non-zeros in L + U than 32 (Rustrel 200 x 201: 34.6M -> 33.0M; the fine
#: 30 deg scene: 22.0M -> 21.4M), 4 no more than 8
LEAF_SIZE = 8
#: a bulk unknown coupled to at least this fraction of the most that any couples to is on the
#: fault's cut elements (``fault_coupling``): on Rustrel the two node lines inside the cut
#: element row couple to 14-24 of the 392 fault unknowns, the lines either side (the leak-off
#: of the fault's pressure) to 1-3
FAULT_COUPLED = 0.5
#: the first separator takes in the fault's unknowns beside it when at least this fraction of
#: them lie in it or beside it (the fault runs along the first cut): otherwise the fault crosses
#: the cut, and widening the top separator costs more than it saves (the fine 30 deg scene)
ALONG_THE_CUT = 0.5


def nested_dissection(pattern: sp.spmatrix, xy: np.ndarray, leaf: int = LEAF_SIZE,
                      return_split: bool = False, return_quarters: bool = False,
                      fault_coupling: np.ndarray | None = None):
    """Permutation (new position -> old index) of the unknowns of a square sparse matrix whose
    unknown i sits at ``xy[i]`` (m). Only the pattern of ``pattern + pattern^T`` is used.

    ``return_split``: also the sizes (n_left, n_right, n_separator) of the first cut, in the
    order the permutation places them (None when the set was not cut): the two halves do not
    couple, so they can be factorised apart (``bordered_lu.SplitBorderedLU``).
    ``return_quarters``: also the sizes of the second level's cuts, one (n_left, n_right,
    n_separator) per half of the first, in the permutation's order (None unless both halves
    were cut): the four parts do not couple either.

    Each set is cut at the median of its coordinate across its larger number of node lines
    (``_cut_axis``; np.median's value: the middle one, or the mean of the two middle ones), the
    unknowns of the lower side that couple to the upper side being the separator, and is placed
    as [its lower side without the separator, its upper side, the separator], each part keeping
    the order it had; the parts larger than ``leaf`` are cut in turn. All the sets of one level
    of cuts are cut together, in place in the permutation (a few array operations per level
    instead of per set; the same permutation).

    ``fault_coupling``: how many condensed (fault) unknowns each unknown couples to; they are
    never eliminated, so every front whose subtree holds such an unknown carries their rows up
    to the root. Where the fault runs along the first cut (``_fault_into_separator``), its
    unknowns beside the first separator join it: the halves below then carry few fault rows
    (paper-units Rustrel: the LDL^T's multiply-adds 123 M -> 93 M, see
    ``benchmarks/ordering_study.py``)."""
    n = pattern.shape[0]
    sym = (abs(pattern) + abs(pattern.T)).tocsr()
    sym.sum_duplicates()
    indptr, indices = sym.indptr, sym.indices
    degree = np.diff(indptr)
    line, n_lines = _node_lines(xy)
    perm = np.arange(n)
    # the sets still to cut: ranges [start, end) of the permutation
    starts = np.zeros(1 if n > leaf else 0, dtype=np.int64)
    ends = np.full(len(starts), n, dtype=np.int64)
    upper_of = np.full(n, -1, dtype=np.int64)   # the set whose upper side holds an unknown
    split = quarters = None
    level = 0
    while len(starts):
        sizes = ends - starts
        n_sets = len(starts)
        offsets = np.cumsum(sizes) - sizes                     # of each set in this level's arrays
        in_set = np.repeat(np.arange(n_sets), sizes)
        at = np.arange(sizes.sum()) - np.repeat(offsets, sizes) + np.repeat(starts, sizes)
        ids = perm[at]
        p = xy[ids]
        axis = _cut_axis(p, line[ids], n_lines, in_set, offsets, n_sets)
        key = p[np.arange(len(ids)), axis[in_set]]
        ranked = key[np.lexsort((key, in_set))]
        mid = offsets + sizes // 2
        median = np.where(sizes % 2 == 1, ranked[mid],
                          (ranked[np.maximum(mid - 1, offsets)] + ranked[mid]) / 2.0)
        lower = key <= median[in_set]
        n_lower = np.bincount(in_set, weights=lower, minlength=n_sets)
        cut = ((n_lower > 0) & (n_lower < sizes))[in_set]      # (a set all on one side stays)
        # the separator: unknowns of a lower side with a neighbour on the upper side of their set
        upper = cut & ~lower
        upper_of[ids[upper]] = in_set[upper]
        low_at = np.flatnonzero(cut & lower)
        low = ids[low_at]
        counts = degree[low]
        owner = np.repeat(np.arange(len(low)), counts)
        neighbours = indices[np.repeat(indptr[low], counts) + np.arange(counts.sum())
                             - np.repeat(np.cumsum(counts) - counts, counts)]
        touches = np.zeros(len(low), dtype=bool)
        touches[owner[upper_of[neighbours] == in_set[low_at][owner]]] = True
        upper_of[ids[upper]] = -1
        part = np.where(lower, 0, 1)                           # 0 lower, 1 upper, 2 separator
        part[low_at[touches]] = 2
        if level == 0 and cut.any() and fault_coupling is not None:
            part = _fault_into_separator(part, ids, fault_coupling, sym)
        if level == 0 and cut.any():
            split = tuple(int(np.count_nonzero(part == k)) for k in range(3))
        perm[at] = ids[np.argsort(in_set * 3 + part, kind="stable")]
        # the lower side (without the separator) and the upper side of each cut set go on
        n_part = [np.bincount(in_set, weights=(part == k), minlength=n_sets).astype(np.int64)
                  for k in (0, 1)]
        was_cut = (n_lower > 0) & (n_lower < sizes)
        if level == 1 and split is not None and n_sets == 2 and was_cut.all():
            quarters = tuple((int(a), int(b), int(c - a - b))
                             for a, b, c in zip(n_part[0], n_part[1], sizes))
        first = np.concatenate([starts[was_cut], (starts + n_part[0])[was_cut]])
        size = np.concatenate([n_part[0][was_cut], n_part[1][was_cut]])
        go_on = size > leaf
        starts, ends = first[go_on], first[go_on] + size[go_on]
        level += 1
    out = (perm,) + ((split,) if return_split else ()) + ((quarters,) if return_quarters else ())
    return out if len(out) > 1 else perm


def _fault_into_separator(part, ids, fault_coupling, sym):
    """``part`` (0 lower, 1 upper, 2 separator, of the unknowns ``ids`` of the first cut) with
    the fault's unknowns (FAULT_COUPLED) beside the separator moved into it, when the fault runs
    along the cut (ALONG_THE_CUT). A separator that takes in unknowns of either side still
    parts the rest (the sides lose unknowns, they gain no coupling)."""
    most = fault_coupling.max(initial=0)
    if most <= 0:
        return part
    on_fault = fault_coupling[ids] >= FAULT_COUPLED * most
    neighbour = np.zeros(sym.shape[0], dtype=bool)   # (of a separator unknown, by the pattern)
    neighbour[sym[ids[part == 2]].indices] = True
    beside = neighbour[ids] & (part != 2)
    if (np.count_nonzero(on_fault & ((part == 2) | beside))
            < ALONG_THE_CUT * np.count_nonzero(on_fault)):
        return part
    return np.where(on_fault & beside, 2, part)


def _node_lines(xy):
    """Each unknown's node line along x and along y (the rank of its coordinate among the
    distinct ones), and the number of lines of each."""
    lines = [np.unique(xy[:, a], return_inverse=True) for a in (0, 1)]
    return (np.column_stack([inverse.ravel() for _, inverse in lines]),
            [len(values) for values, _ in lines])


def _cut_axis(p, line, n_lines, in_set, offsets, n_sets):
    """The coordinate each set is cut along (0: x, 1: y), given its unknowns' points ``p`` and
    node lines ``line`` (``_node_lines``; the sets consecutive, ``in_set`` their set,
    ``offsets`` their first): the one with more node lines, so that the separator, a line of
    nodes across the other, holds fewer of them; on a tie the one with the larger extent. On a
    mesh graded towards a fault the longer side in metres can be the one with fewer node lines,
    and cutting across it fills more (``python benchmarks/sweeps.py --fill`` prints both rules'
    fill); on a uniform mesh the two choices agree."""
    distinct = np.empty((n_sets, 2), dtype=np.int64)
    for a in (0, 1):
        on = np.zeros(n_sets * n_lines[a], dtype=bool)
        on[in_set * n_lines[a] + line[:, a]] = True
        distinct[:, a] = on.reshape(n_sets, n_lines[a]).sum(axis=1)
    extent = np.maximum.reduceat(p, offsets, axis=0) - np.minimum.reduceat(p, offsets, axis=0)
    return np.where(distinct[:, 0] == distinct[:, 1], np.argmax(extent, axis=1),
                    np.argmax(distinct, axis=1))

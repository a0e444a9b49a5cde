"""The bulk's order against the fault's border (``nested_dissection(fault_coupling=...)``): where
the fault runs along the first cut, its cut elements' unknowns join the first separator, so that
no front below the top carries the fault's rows; where it crosses the cut, the order is the plain
one."""
from dataclasses import replace

import numpy as np
import scipy.sparse as sp

from fault_screen import Scene, ldl
from fault_screen.ordering import nested_dissection

from conftest import CONFIGS
from test_ldl import _solver


def _grid_with_fault(k, fault_at, along, weak_at=None):
    """The 9-point pattern of a k x k grid (one unknown per node, unit spacing, node (x, y) at
    x + k y) with a fault between the node lines ``fault_at`` and ``fault_at + 1`` of the x
    coordinate (``along`` 0: the fault runs along y) or of y (``along`` 1): two fault unknowns
    per segment between consecutive nodes, each coupled to the segment's four nodes of the cut
    element (an interior node of the cut element row couples to 4 fault unknowns, an end node to
    2); ``weak_at``: the node line (same direction) whose nodes each couple to one fault unknown
    (as a leak-off couples the fault's pressure to the next line). Returns (the bulk's pattern,
    coordinates, the whole pattern [bulk, fault] and the fault coupling of each bulk unknown)."""
    band = sp.diags([1.0, 1.0, 1.0], [-1, 0, 1], shape=(k, k))
    P = sp.kron(band, band).tocsr()
    xy = np.array([[x, y] for y in range(k) for x in range(k)], dtype=float)

    def node(across, lengthwise):   # (``across``: the coordinate normal to the fault)
        return across + k * lengthwise if along == 0 else lengthwise + k * across

    rows, cols = [], []
    for s in range(k - 1):
        for f in (2 * s, 2 * s + 1):
            for across in (fault_at, fault_at + 1):
                for lengthwise in (s, s + 1):
                    rows.append(node(across, lengthwise))
                    cols.append(f)
    if weak_at is not None:
        for s in range(k - 1):
            rows.append(node(weak_at, s))
            cols.append(2 * s + 1)
    C = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(k * k, 2 * (k - 1)))
    whole = sp.bmat([[P, C], [C.T, sp.eye(2 * (k - 1))]]).tocsr()
    return P, xy, whole, np.diff(C.indptr)


def _fronts_with_fault_rows(whole, nB, perm):
    """The first column of each supernode of the L D L^T in the order [perm, fault] whose front
    holds rows of the fault."""
    order = np.concatenate([perm, np.arange(nB, whole.shape[0])])
    symbolic = ldl.LDLSymbolic(ldl._lower(whole[order][:, order].tocsc(), nB), nB)
    first, width, row_at, srows = symbolic.tree[:4]
    has_fault_rows = np.add.reduceat((srows >= nB).astype(np.int64), row_at[:-1]) > 0
    return first[has_fault_rows], symbolic


def test_a_fault_along_the_first_cut_joins_its_separator():
    """20 x 20 grid: the first cut runs along y (a tie of node lines and of extents: x), at the
    median x = 9.5, the column x = 9 its separator (plain: split (180, 200, 20)). A fault between
    the columns 9 and 10 couples both (2-4 fault unknowns a node); the column x = 8 couples to one
    each (below half the most, 4: not the fault's). With the coupling, the column 10 joins the
    separator: split (180, 180, 40), the separator the columns 9 and 10 and nothing else, the
    halves uncoupled; every front that holds fault rows is a front of that separator (plain: 40
    fronts below it do too), and the factorisation takes fewer multiply-adds."""
    k = 20
    P, xy, whole, coupling = _grid_with_fault(k, 9, along=0, weak_at=8)
    plain, plain_split = nested_dissection(P, xy, return_split=True)
    perm, split = nested_dissection(P, xy, return_split=True, fault_coupling=coupling)
    assert plain_split == (180, 200, 20)
    assert np.array_equal(np.sort(perm), np.arange(k * k))
    assert split == (180, 180, 40)
    lower, upper, separator = perm[:180], perm[180:360], perm[360:]
    assert sorted(set(xy[separator, 0])) == [9.0, 10.0]
    assert P[lower][:, upper].nnz == 0
    P, xy, whole, coupling = _grid_with_fault(k, 9, along=0)
    perm = nested_dissection(P, xy, fault_coupling=coupling)
    nB = k * k
    firsts, symbolic = _fronts_with_fault_rows(whole, nB, perm)
    assert firsts.min() >= nB - 40
    plain_firsts, plain_symbolic = _fronts_with_fault_rows(whole, nB, plain)
    assert np.count_nonzero(plain_firsts < nB - 20) == 11
    assert symbolic.multiply_adds < 0.9 * plain_symbolic.multiply_adds


def test_a_fault_across_the_first_cut_leaves_the_order_as_it_is():
    """The same grid with the fault between the rows y = 9 and 10: the first cut (the column
    x = 9) crosses it, and of the fault's 40 nodes only the 4 at the crossing are in the
    separator or beside it (less than ALONG_THE_CUT): the order is the plain one."""
    P, xy, _, coupling = _grid_with_fault(20, 9, along=1)
    plain = nested_dissection(P, xy)
    assert np.array_equal(nested_dissection(P, xy, fault_coupling=coupling), plain)


def test_without_fault_coupling_the_order_is_the_plain_one():
    """No unknown couples to the fault (zero coupling): nothing moves."""
    P, xy, _, coupling = _grid_with_fault(12, 5, along=0)
    assert np.array_equal(nested_dissection(P, xy, fault_coupling=np.zeros_like(coupling)),
                          nested_dissection(P, xy))


def test_on_a_coarse_rustrel_bulk_only_the_leak_off_rows_go_below_the_first_separator():
    """Paper-units Rustrel at 16 x 17 elements (the fault across the middle of an element row):
    the bulk unknowns inside the cut element row couple to most of the fault's unknowns, those
    of the node lines either side to a few (the fault's pressure, by leak-off). With the fault's
    coupling, every bulk unknown coupled to at least half the most is in the first separator,
    and the fronts below that separator hold rows of only the fault unknowns that the weakly
    coupled unknowns reach (30 of the 120; in the plain order fronts below it hold rows of all
    120); L has fewer entries (measured 163,943 against 180,455)."""
    scene = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated-paper-units.toml")
    system = _solver(scene.replace(mesh=replace(scene.mesh, nx=16, ny=17))).system
    B, N = system.B, system.N
    L = system._linear_jacobian(600.0).tocsr()
    free = np.concatenate([B, N])
    whole = (abs(L[free][:, free]) + abs(L[free][:, free]).T).tocsr()
    nB = len(B)
    coupled = whole[:nB, nB:].tocsr()
    coupling = np.diff(coupled.indptr)
    strong = coupling >= 0.5 * coupling.max()
    reached_weakly = set(coupled[np.flatnonzero((coupling > 0) & ~strong)].indices.tolist())
    assert 0 < len(reached_weakly) < len(N)
    xy = system._coordinates()[B]

    def fault_rows_below(perm, split):
        order = np.concatenate([perm, np.arange(nB, whole.shape[0])])
        symbolic = ldl.LDLSymbolic(ldl._lower(whole[order][:, order].tocsc(), nB), nB)
        first, width, row_at, srows = symbolic.tree[:4]
        below = np.flatnonzero(first + width <= split[0] + split[1])
        rows = np.concatenate([srows[row_at[t]:row_at[t + 1]] for t in below])
        return set((rows[rows >= nB] - nB).tolist()), symbolic.nnz

    perm, split = nested_dissection(whole[:nB, :nB], xy, return_split=True,
                                    fault_coupling=coupling)
    assert np.array_equal(np.sort(perm), np.arange(nB))
    assert np.all(strong[perm[split[0] + split[1]:]] | (coupling[perm[split[0] + split[1]:]] == 0))
    assert strong[perm[split[0] + split[1]:]].sum() == strong.sum()
    rows, nnz = fault_rows_below(perm, split)
    assert rows <= reached_weakly
    plain_rows, plain_nnz = fault_rows_below(*nested_dissection(whole[:nB, :nB], xy,
                                                                return_split=True))
    assert len(plain_rows) == len(N)
    assert nnz < plain_nnz

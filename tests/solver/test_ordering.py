"""The bulk's fill-reducing order (``ordering.nested_dissection``): the cuts, the order it places
the parts in, the uncoupled halves that ``SplitBorderedLU`` relies on, and the fill it saves."""
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from fault_screen import Scene, ldl
from fault_screen.bordered_lu import BorderedLU
from fault_screen.ordering import nested_dissection
from fault_screen.scene import Refinement

from conftest import CONFIGS
from test_ldl import _check_against_dense, _free_block, _solver


def _grid_laplacian(k):
    """The 5-point Laplacian of a k x k grid and the grid points' coordinates."""
    T = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(k, k))
    L = (sp.kron(T, sp.eye(k)) + sp.kron(sp.eye(k), T)).tocsr()
    xy = np.array([[i, j] for i in range(k) for j in range(k)], dtype=float)
    return L, xy


def test_a_chain_is_cut_at_its_median_and_placed_lower_upper_separator():
    """0-1-2-3-4 on a line, sets of one unknown left whole: the median 2 cuts {0, 1, 2} from
    {3, 4}, 2 touches 3 (the separator); {0, 1} is cut at 0.5 with 0 its separator, {3, 4} at
    3.5 with 3: [order({0, 1}), order({3, 4}), 2] = [1, 0, 4, 3, 2] (worked by hand)."""
    chain = sp.diags([1.0, 1.0, 1.0], [-1, 0, 1], shape=(5, 5)).tocsr()
    xy = np.column_stack([np.arange(5.0), np.zeros(5)])
    perm, split = nested_dissection(chain, xy, leaf=1, return_split=True)
    assert perm.tolist() == [1, 0, 4, 3, 2]
    assert split == (2, 2, 1)


def test_the_halves_of_the_first_cut_do_not_couple():
    L, xy = _grid_laplacian(30)
    perm, (n_lower, n_upper, n_separator) = nested_dissection(L, xy, return_split=True)
    assert np.array_equal(np.sort(perm), np.arange(900))
    assert (n_lower, n_upper, n_separator) == (420, 450, 30)  # x <= 14.5, the column x = 14
    lower, upper = perm[:n_lower], perm[n_lower:n_lower + n_upper]
    assert L[lower][:, upper].nnz == 0
    assert np.all(xy[perm[n_lower + n_upper:], 0] == 14.0)


def test_the_quarters_of_the_first_two_cuts_do_not_couple():
    """The second level's cuts of a 30 x 30 grid (each half cut across its longer side): the four
    parts that ``split_layout`` factorises apart do not couple, and the quarters' and halves'
    sizes agree (each half: its two parts and its separator)."""
    L, xy = _grid_laplacian(30)
    perm, split, quarters = nested_dissection(L, xy, return_split=True, return_quarters=True)
    (a1, a2, a_s), (b1, b2, b_s) = quarters
    assert a1 + a2 + a_s == split[0] and b1 + b2 + b_s == split[1]
    n1 = split[0]
    parts = [perm[:a1], perm[a1:a1 + a2], perm[n1:n1 + b1], perm[n1 + b1:n1 + b1 + b2]]
    assert min(map(len, parts)) > 150
    for i, p in enumerate(parts):
        for q in parts[i + 1:]:
            assert L[p][:, q].nnz == 0
    # a half's separator cuts it across its longer side: the lower half is 14 x 30 (x <= 13),
    # cut at y = 14.5 along the row y = 14
    assert np.all(xy[perm[a1 + a2:n1], 1] == 14.0)


def test_it_fills_less_than_half_of_what_the_natural_order_fills():
    """A k x k grid: the band of the row-by-row order fills ~2 k^3 entries, nested dissection
    O(k^2 log k): 58,302 against 128,078 at k = 40 (bound: half)."""
    L, xy = _grid_laplacian(40)

    def fill(perm):
        lu = spla.splu(L[perm][:, perm].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                       options=dict(SymmetricMode=True))
        return lu.L.nnz + lu.U.nnz

    assert fill(nested_dissection(L, xy)) < 0.5 * fill(np.arange(1600))


def _grid(x_lines, y_lines):
    """The 9-point pattern (bilinear quadrilaterals: a node couples to its eight neighbours) of a
    structured mesh with these node lines, one unknown per node, and the nodes' coordinates."""
    nx, ny = len(x_lines), len(y_lines)

    def band(k):
        return sp.diags([1.0, 1.0, 1.0], [-1, 0, 1], shape=(k, k))

    P = sp.kron(band(ny), band(nx)).tocsr()
    xy = np.array([[x, y] for y in y_lines for x in x_lines], dtype=float)
    return P, xy


def test_a_set_is_cut_across_its_larger_number_of_node_lines():
    """4 node lines along x spread over 30 m, 10 along y over 9 m: the longer side in metres (x)
    has the fewer lines, so the cut runs along y, at its median 4.5, and the separator is the
    row y = 4 of 4 nodes (a cut along x would have taken a column of 10). The lower side is the
    16 nodes of y <= 3, the upper one the 20 of y >= 5."""
    P, xy = _grid([0.0, 10.0, 20.0, 30.0], np.arange(10.0))
    perm, split = nested_dissection(P, xy, return_split=True)
    assert split == (16, 20, 4)
    assert np.all(xy[perm[36:], 1] == 4.0)
    # on a tie of node lines, the longer extent: 5 x 5 lines, 40 m along y against 4 m along x
    P, xy = _grid(np.arange(5.0), 10.0 * np.arange(5.0))
    perm, split = nested_dissection(P, xy, return_split=True)
    assert split == (10, 10, 5) and np.all(xy[perm[20:], 1] == 20.0)


@pytest.fixture(scope="module")
def graded_poroelastic():
    """The Newton solver of the mass-balance scene (permeable rock, a fault with leak-off) on a
    mesh graded towards a band along the fault: 1 m elements within 20 m along x and 2 m along
    y of the centre, growing by 1.5 outside, so that the sides in metres and in node lines
    disagree (2,184 bulk unknowns, 228 on the fault)."""
    scene = Scene.from_toml(CONFIGS / "verification" / "mass-balance.toml")
    refinement = Refinement(center=(30.5, 30.5), half_width=(20.0, 2.0), size=1.0, growth=1.5)
    return _solver(scene.replace(mesh=replace(scene.mesh, refinement=refinement)))


#: the graded mass-balance bulk's factors (``BorderedLU.nnz``: L's entries twice, as L + U) in
#: its order, as measured; the rule that cut each set along its longer extent in metres had
#: 338,484 (12 % more)
GRADED_FILL = 301_000


@pytest.mark.filterwarnings("ignore:leak-off")   # (the physics' warning; the ordering is tested)
def test_the_order_of_a_graded_poroelastic_bulk(graded_poroelastic):
    """The system's order is a permutation of its free unknowns, B (in the nested-dissection
    order) then N; the L D L^T in it solves the symmetric-form free block at 5 s and 600 s to
    round-off against numpy (test_ldl's checks: 1e-11 relative, backward error 1e-15); and its
    fill is at most GRADED_FILL."""
    system = graded_poroelastic.system
    assert np.array_equal(np.sort(system.order), np.sort(system.free))
    nB = len(system.B)
    assert np.array_equal(np.sort(system.order[:nB]), np.sort(system.B))
    assert np.array_equal(system.order[nB:], system.N)
    for dt in (5.0, 600.0):
        M, nB = _free_block(graded_poroelastic, dt, symmetric_form=True)
        lu = BorderedLU(M, nB, ldl.SymbolicAnalyses())
        assert lu.quasi_definite and M.shape[0] - nB > 50
        _check_against_dense(lu, M, nB, 7)
    assert lu.nnz <= GRADED_FILL

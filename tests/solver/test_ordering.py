"""The bulk's fill-reducing order (``ordering.nested_dissection``): the cuts, the order it places
the parts in, the uncoupled halves that ``SplitBorderedLU`` relies on, and the fill it saves."""
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from fault_screen.ordering import nested_dissection


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

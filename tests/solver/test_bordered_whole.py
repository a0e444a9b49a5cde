"""A linear block above SPLIT_ABOVE (the limits lowered so that the mass balance scene, 24 x 25,
is laid out in quarters): factorised by ``bordered_lu.bordered_lu`` in parts
(``SplitBorderedLU``), each part its L D L^T, or SuperLU's where the block is not symmetric;
and the same block's L D L^T whole, which the solver does not take above SPLIT_ABOVE (its peak
memory: ``benchmarks/sweeps.py --whole``, docs/incoming/whole.md), against the split one and
against numpy's dense solves.

Tolerances: test_ldl's (the Schur complement and both sweeps to 1e-11 relative to the dense
reference's largest entry, the whole solve's normwise backward error below 1e-15); whole against
split: two elimination orders of one matrix, equal to 1e-11 relative (round-off; measured
2e-16 to 6e-16), which a wrong border, a separator left out or a part swept twice misses by
orders."""
import numpy as np
import pytest

from fault_screen import bordered_lu, ldl
from fault_screen.bordered_lu import BorderedLU, SplitBorderedLU

from test_dt_switch import _mass_balance
from test_ldl import _check_against_dense, _free_block, _solver

TOL = 1e-11


@pytest.fixture(scope="module")
def quartered():
    """(solver, the symmetric-form block at 600 s, nB, split) with the bulk laid out in quarters."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(bordered_lu, "SPLIT_ABOVE", 500)
        mp.setattr(bordered_lu, "PART_SIZE", 200)
        solver = _solver(_mass_balance())
    split = solver.system.split
    M, nB = _free_block(solver, 600.0, symmetric_form=True)
    assert len(split) == 5 and nB > 500 and min(split[:4]) > 0   # (four quarters, the separators)
    return solver, M, nB, split


@pytest.fixture
def lowered(monkeypatch):
    monkeypatch.setattr(bordered_lu, "SPLIT_ABOVE", 500)


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


def test_a_quasi_definite_block_above_split_above_is_split(quartered, lowered):
    """Above SPLIT_ABOVE with a split given, the symmetric block is factorised in its four
    quarters, each by its own L D L^T (one symbolic analysis each), and solves as numpy's dense
    solves do."""
    _, M, nB, split = quartered
    analyses = ldl.SymbolicAnalyses()
    lu = bordered_lu.bordered_lu(M, nB, split, analyses)
    assert type(lu) is SplitBorderedLU and len(lu._parts) == 4
    assert all(part.quasi_definite for part in lu._parts) and len(analyses._held) == 4
    _check_against_dense(lu, M, nB, 21)


def test_whole_equals_split(quartered):
    """The whole block's L D L^T (its Schur complement, condensed right-hand side and bulk
    answer) against the same block split in quarters, to round-off; and against numpy."""
    _, M, nB, split = quartered
    analyses = ldl.SymbolicAnalyses()
    whole = BorderedLU(M, nB, analyses)
    assert whole.quasi_definite and len(analyses._held) == 1
    _check_against_dense(whole, M, nB, 22)
    parts = SplitBorderedLU(M, nB, split, ldl.SymbolicAnalyses())
    assert _rel(whole.schur, parts.schur) < TOL
    rng = np.random.default_rng(22)
    r = rng.standard_normal(M.shape[0])
    x_N = rng.standard_normal(M.shape[0] - nB)
    (c_w, g_w), (c_s, g_s) = whole.forward(r[:nB], r[nB:]), parts.forward(r[:nB], r[nB:])
    assert _rel(g_w, g_s) < TOL
    assert _rel(whole.backward(c_w, x_N), parts.backward(c_s, x_N)) < TOL
    assert _rel(whole.backward(None, x_N), parts.backward(None, x_N)) < TOL


def test_split_where_the_block_is_not_symmetric(quartered, lowered):
    """The poroelastic block in its general form (flow rows not times -dt: not symmetric) is no
    L D L^T's: in parts by SuperLU."""
    solver, _, nB, split = quartered
    M, _ = _free_block(solver, 600.0, symmetric_form=False)
    lu = bordered_lu.bordered_lu([M].pop, nB, split, ldl.SymbolicAnalyses())
    assert type(lu) is SplitBorderedLU and not any(p.quasi_definite for p in lu._parts)
    _check_against_dense(lu, M, nB, 24)


def test_below_split_above_or_without_a_split_whole(quartered):
    """At the default SPLIT_ABOVE (above this block) or with no split given, one BorderedLU."""
    _, M, nB, split = quartered
    assert nB <= bordered_lu.SPLIT_ABOVE
    for given in (split, None):
        lu = bordered_lu.bordered_lu(M, nB, given, ldl.SymbolicAnalyses())
        assert type(lu) is BorderedLU and lu.quasi_definite


def test_a_symmetric_split_skips_the_parts_symmetry_checks(quartered, lowered, monkeypatch):
    """Given ``symmetric_parts`` (the caller knows the block symmetric), the parts take their
    L D L^T without the symmetry check (made to fail here): the same factors, bit for bit, as
    the parts that check."""
    _, M, nB, split = quartered
    checked = SplitBorderedLU(M, nB, split, ldl.SymbolicAnalyses())

    def no_check(*_):
        raise AssertionError("a part's symmetry checked")

    monkeypatch.setattr(bordered_lu, "_linear_rows_symmetric", no_check)
    lu = bordered_lu.bordered_lu(M, nB, split, ldl.SymbolicAnalyses(),
                                 symmetric_parts=bordered_lu._parts_of(M, nB))
    assert type(lu) is SplitBorderedLU and all(p.quasi_definite for p in lu._parts)
    assert np.array_equal(lu.schur, checked.schur)
    r = np.random.default_rng(25).standard_normal(M.shape[0])
    (c, g), (c0, g0) = lu.forward(r[:nB], r[nB:]), checked.forward(r[:nB], r[nB:])
    assert np.array_equal(g, g0) and np.array_equal(lu.backward(c, r[nB:]), checked.backward(c0, r[nB:]))

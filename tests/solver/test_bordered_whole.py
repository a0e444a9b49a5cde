"""A linear block above SPLIT_ABOVE (the limits lowered so that the mass balance scene, 24 x 25,
is laid out in quarters) factorised whole by the L D L^T (``bordered_lu.bordered_lu``), and in
parts (``SplitBorderedLU``) only where the L D L^T fails: what decides it, and the whole block
against the split one and against numpy's dense solves.

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


def test_a_quasi_definite_block_is_factorised_whole(quartered, lowered):
    """Above SPLIT_ABOVE with a split given, the symmetric block takes one L D L^T, on one
    symbolic analysis (not one per part), and solves as numpy's dense solves do."""
    _, M, nB, split = quartered
    analyses = ldl.SymbolicAnalyses()
    lu = bordered_lu.bordered_lu(M, nB, split, analyses)
    assert type(lu) is BorderedLU and lu.quasi_definite and len(analyses._held) == 1
    _check_against_dense(lu, M, nB, 21)


def test_whole_equals_split(quartered, lowered):
    """The whole block's Schur complement, condensed right-hand side and bulk answer against
    the same block's split in quarters (each part its own L D L^T), to round-off."""
    _, M, nB, split = quartered
    whole = bordered_lu.bordered_lu(M, nB, split, ldl.SymbolicAnalyses())
    parts = SplitBorderedLU(M, nB, split, ldl.SymbolicAnalyses())
    assert len(parts._parts) == 4 and all(p.quasi_definite for p in parts._parts)
    assert _rel(whole.schur, parts.schur) < TOL
    rng = np.random.default_rng(22)
    r = rng.standard_normal(M.shape[0])
    x_N = rng.standard_normal(M.shape[0] - nB)
    (c_w, g_w), (c_s, g_s) = whole.forward(r[:nB], r[nB:]), parts.forward(r[:nB], r[nB:])
    assert _rel(g_w, g_s) < TOL
    assert _rel(whole.backward(c_w, x_N), parts.backward(c_s, x_N)) < TOL
    assert _rel(whole.backward(None, x_N), parts.backward(None, x_N)) < TOL
    # (the factors read: the whole block's L against the parts' L and the dense R_SS)
    assert whole.nnz < parts.nnz


def test_split_where_the_ldl_fails(quartered, lowered, monkeypatch):
    """A pivot below ldl.PIVOT_RATIO (raised so that every pivot is): the block goes to SuperLU
    in parts, made from the one matrix the caller hands over (a function called once), and
    still solves as numpy does."""
    _, M, nB, split = quartered
    monkeypatch.setattr(ldl, "PIVOT_RATIO", 2.0)   # (a ratio of pivots is at most 1)
    lu = bordered_lu.bordered_lu([M].pop, nB, split, ldl.SymbolicAnalyses())
    assert type(lu) is SplitBorderedLU and not any(p.quasi_definite for p in lu._parts)
    _check_against_dense(lu, M, nB, 23)


def test_split_where_the_block_is_not_symmetric(quartered, lowered):
    """The poroelastic block in its general form (flow rows not times -dt: not symmetric) is no
    L D L^T's: in parts by SuperLU, as before."""
    solver, _, nB, split = quartered
    M, _ = _free_block(solver, 600.0, symmetric_form=False)
    lu = bordered_lu.bordered_lu([M].pop, nB, split, ldl.SymbolicAnalyses())
    assert type(lu) is SplitBorderedLU and not any(p.quasi_definite for p in lu._parts)
    _check_against_dense(lu, M, nB, 24)


def test_below_split_above_or_without_a_split_whole(quartered):
    """At the default SPLIT_ABOVE (above this block) or with no split, one BorderedLU whatever
    factorises it: SuperLU's for the general form."""
    solver, _, nB, split = quartered
    M, _ = _free_block(solver, 600.0, symmetric_form=False)
    assert nB <= bordered_lu.SPLIT_ABOVE
    assert type(bordered_lu.bordered_lu(M, nB, split, ldl.SymbolicAnalyses())) is BorderedLU

"""BorderedLU: the Schur complement and the two sweeps against dense linear algebra.

The matrix is a real one (the scaled free block of a small inclined-fault scene with a permeable
rock, condensed unknowns last), so the factorisation meets the pivoting and the fill it meets in a
run; the references are numpy's dense solves of the same blocks.
"""
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from fault_screen import Scene
from fault_screen import bordered_lu
from fault_screen.bordered_lu import BorderedLU, SplitBorderedLU, split_layout
from fault_screen.discretisation import discretise
from fault_screen.ordering import nested_dissection
from fault_screen.solver import NewtonSolver

from conftest import CONFIGS, VERIFICATION

TOL = 1e-11  # relative to the largest entry of the reference; round-off of a well scaled system


@pytest.fixture(scope="module")
def prepared():
    """The Newton solver of the scene, its linear Jacobian made for the first step."""
    scene = Scene.from_toml(CONFIGS / "verification" / "mass-balance.toml")
    solver = NewtonSolver(discretise(scene))
    x = np.zeros(solver.disc.n_dofs)
    solver._prepare(scene.time.dt, x, solver.disc.physics.contact.initial_history(solver.disc)
                    if solver.disc.physics.contact is not None else None)
    return solver


@pytest.fixture(scope="module")
def system(prepared):
    solver = prepared
    D = sp.diags(solver.scale)
    M = (D @ solver.L @ D).tocsr()[solver.system.order][:, solver.system.order]
    nB = len(solver.B)
    dense = M.toarray()
    return BorderedLU(M.tocsc(), nB), dense, nB


def _rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


def test_schur_complement(system):
    lu, M, nB = system
    assert M.shape[0] - nB > 50  # a real fault: tens of condensed unknowns
    B, BN, NB, NN = M[:nB, :nB], M[:nB, nB:], M[nB:, :nB], M[nB:, nB:]
    exact = NN - NB @ np.linalg.solve(B, BN)
    assert _rel(lu.schur, exact) < TOL


def test_forward_sweep_gives_the_condensed_right_hand_side(system):
    lu, M, nB = system
    rng = np.random.default_rng(3)
    rB, rN = rng.standard_normal(nB), rng.standard_normal(M.shape[0] - nB)
    _, condensed = lu.forward(rB, rN)
    exact = rN - M[nB:, :nB] @ np.linalg.solve(M[:nB, :nB], rB)
    assert _rel(condensed, exact) < TOL


def test_sweeps_solve_the_whole_system(system):
    """forward, the condensed dense solve, backward: the solution of M x = r."""
    lu, M, nB = system
    rng = np.random.default_rng(4)
    r = rng.standard_normal(M.shape[0])
    swept, condensed = lu.forward(r[:nB], r[nB:])
    xN = np.linalg.solve(lu.schur, condensed)
    xB = lu.backward(swept, xN)
    exact = np.linalg.solve(M, r)
    assert _rel(np.concatenate([xB, xN]), exact) < TOL
    # without a linear right-hand side (None): the bulk's answer to a fault update alone
    assert _rel(lu.backward(None, xN), -np.linalg.solve(M[:nB, :nB], M[:nB, nB:] @ xN)) < TOL


def test_matrix_given_by_a_function_factorises_the_same(system):
    """``BorderedLU(make, n)`` (the caller holds no reference to the matrix) equals the direct form
    bit for bit, and both agree with scipy's own sparse solve of the whole system."""
    lu, M, nB = system
    held = [sp.csc_matrix(M)]
    other = BorderedLU(held.pop, nB)
    assert not held
    assert np.array_equal(other.schur, lu.schur)
    r = np.random.default_rng(5).standard_normal(M.shape[0])
    swept, condensed = other.forward(r[:nB], r[nB:])
    xN = np.linalg.solve(other.schur, condensed)
    x = np.concatenate([other.backward(swept, xN), xN])
    assert _rel(x, spla.spsolve(sp.csc_matrix(M), r)) < TOL


@pytest.mark.parametrize("symmetric", [False, True])
@pytest.mark.parametrize("shape", ["dense", "diagonal", "arrow"])
def test_sweeps_on_extreme_supernodes(shape, symmetric):
    """The sweeps read the factors packed by supernodes: one supernode holding every linear
    column (a dense block, 37 columns: none of the four-row groups is whole), none wider than a
    column (a diagonal block: each column's supernode has no rows below it) and single columns
    feeding one long dense border (arrow). Each against numpy's dense solve."""
    rng = np.random.default_rng(6)
    nB, nN = 37, 6
    n = nB + nN
    if shape == "dense":
        M = rng.standard_normal((n, n))
    elif shape == "diagonal":
        M = np.zeros((n, n))
        M[nB:, :] = rng.standard_normal((nN, n))
        M[:, nB:] = rng.standard_normal((n, nN))
    else:
        M = np.zeros((n, n))
        M[-1, :] = rng.standard_normal(n)
        M[:, -1] = rng.standard_normal(n)
        M[nB:, nB:] = rng.standard_normal((nN, nN))
    if symmetric:  # (the backward sweep then reads L and U's diagonal: U = D L^T)
        M = M + M.T
    M[np.arange(n), np.arange(n)] += 4.0 * n  # the diagonal pivots SuperLU keeps here
    lu = BorderedLU(sp.csc_matrix(M), nB)
    assert (lu._U is None) == symmetric
    widths = lu._L.arrays[1]
    assert widths.sum() == nB
    assert widths.max() == {"dense": nB, "diagonal": 1, "arrow": 1}[shape]
    r = rng.standard_normal(n)
    swept, condensed = lu.forward(r[:nB], r[nB:])
    xN = np.linalg.solve(lu.schur, condensed)
    x = np.concatenate([lu.backward(swept, xN), xN])
    assert _rel(x, np.linalg.solve(M, r)) < TOL


def test_split_factorisation_equals_the_whole(system, prepared):
    """The linear block factorised as the two halves of its first nested-dissection cut, each
    bordered by the separator and the condensed unknowns (``SplitBorderedLU``): the same Schur
    complement and sweeps as the one factorisation, against numpy's dense solves."""
    lu, M, nB = system
    n1, n2, ns = prepared.system.split
    assert min(n1, n2) > 10 * ns > 0   # two real halves and a separator between them
    split = SplitBorderedLU(sp.csc_matrix(M), nB, prepared.system.split)
    assert np.allclose(M[:n1, n1:n1 + n2], 0.0) and np.allclose(M[n1:n1 + n2, :n1], 0.0)
    # each half borders on the separator and on the condensed unknowns it couples to: the fault
    # crosses the cut, so each touches a part of it (this scene: 58 and 74 of 128), and the
    # two parts cover it
    touched = [border[border >= ns] - ns for border in split._borders]
    nN = M.shape[0] - nB
    assert max(map(len, touched)) < 0.75 * nN
    assert np.array_equal(np.union1d(*touched), np.arange(nN))
    assert _rel(split.schur, lu.schur) < TOL
    rng = np.random.default_rng(7)
    r = rng.standard_normal(M.shape[0])
    swept, condensed = split.forward(r[:nB], r[nB:])
    assert _rel(condensed, lu.forward(r[:nB], r[nB:])[1]) < TOL
    xN = np.linalg.solve(split.schur, condensed)
    assert _rel(np.concatenate([split.backward(swept, xN), xN]), np.linalg.solve(M, r)) < TOL
    assert _rel(split.backward(None, xN), -np.linalg.solve(M[:nB, :nB], M[:nB, nB:] @ xN)) < TOL


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_sweeps_propagate_non_finite_values(system, bad):
    """The forward sweep is compiled with reassociation (``_jit.sweep_kernel``), never with the
    flags that assume finite values: a NaN or an infinity in the right-hand side still reaches
    the condensed right-hand side and the bulk's answer, where the solver's finiteness tests see
    it."""
    lu, M, nB = system
    r = np.random.default_rng(10).standard_normal(M.shape[0])
    r[nB // 2] = bad
    swept, condensed = lu.forward(r[:nB], r[nB:])
    assert not np.all(np.isfinite(condensed))
    assert not np.all(np.isfinite(lu.backward(swept, np.zeros(M.shape[0] - nB))))


@pytest.fixture(scope="module")
def elastic():
    """The scaled free block of a coarse inclined-fault scene in elastic (impermeable) rock,
    condensed unknowns last (1575 unknowns): its linear rows are its linear columns transposed,
    so the factorisation keeps L and U's diagonal only."""
    scene = Scene.from_toml(VERIFICATION / "fluid-driven-slip-T0.4-dip30.toml")
    m = scene.mesh
    scene = scene.replace(mesh=replace(m, refinement=replace(m.refinement, size=4.0, growth=1.5)))
    solver = NewtonSolver(discretise(scene))
    x = np.zeros(solver.disc.n_dofs)
    solver._prepare(scene.time.dt, x, solver.disc.physics.contact.initial_history(solver.disc))
    D = sp.diags(solver.scale)
    M = (D @ solver.L @ D).tocsr()[solver.system.order][:, solver.system.order].toarray()
    return solver, M, len(solver.B)


def _check_against_dense(lu, M, nB, seed):
    B, BN, NB, NN = M[:nB, :nB], M[:nB, nB:], M[nB:, :nB], M[nB:, nB:]
    assert _rel(lu.schur, NN - NB @ np.linalg.solve(B, BN)) < TOL
    r = np.random.default_rng(seed).standard_normal(M.shape[0])
    swept, condensed = lu.forward(r[:nB], r[nB:])
    assert _rel(condensed, r[nB:] - NB @ np.linalg.solve(B, r[:nB])) < TOL
    xN = np.linalg.solve(lu.schur, condensed)
    assert _rel(np.concatenate([lu.backward(swept, xN), xN]), np.linalg.solve(M, r)) < TOL
    assert _rel(lu.backward(None, xN), -np.linalg.solve(B, BN @ xN)) < TOL


def test_symmetric_linear_block_keeps_l_and_the_diagonal(elastic):
    """U = D L^T on the linear rows of a symmetric block (SuperLU keeping its diagonal pivots
    there, the condensed rows pivoting among themselves): the Schur complement and both sweeps
    against numpy's dense solves; the same matrix made unsymmetric in one linear entry beyond
    round-off factorises with U held, as accurately."""
    solver, M, nB = elastic
    assert np.abs(M[:nB] - M[:, :nB].T).max() <= 1e-15 * np.abs(M[:nB]).max()
    lu = BorderedLU(sp.csc_matrix(M), nB)
    assert lu._U is None and len(lu._D) == nB
    assert not np.array_equal(lu._row_N, np.arange(M.shape[0] - nB))   # (pivoted condensed rows)
    _check_against_dense(lu, M, nB, 11)
    i, j = next((i, j) for i, j in np.argwhere(M[:nB, :nB] != 0) if i != j)
    unsymmetric = M.copy()
    unsymmetric[i, j] += 1e-9 * np.abs(M[:nB]).max()
    other = BorderedLU(sp.csc_matrix(unsymmetric), nB)
    assert other._U is not None
    _check_against_dense(other, unsymmetric, nB, 12)


def test_symmetric_split_factorisation(elastic):
    """Both halves of a split symmetric block keep L and the diagonal only, and the split
    factorisation solves as the whole does."""
    solver, M, nB = elastic
    split = SplitBorderedLU(sp.csc_matrix(M), nB, solver.system.split)
    assert all(half._U is None for half in split._parts)
    _check_against_dense(split, M, nB, 13)


def test_quarters_factorisation(elastic, monkeypatch):
    """The linear block in the four parts of its first two nested-dissection cuts, each bordered
    by the separators and the fault unknowns it touches (``split_layout`` with the sizes lowered
    to this scene's): the Schur complement and both sweeps against numpy's dense solves."""
    solver, M, nB = elastic
    monkeypatch.setattr(bordered_lu, "SPLIT_ABOVE", 100)
    monkeypatch.setattr(bordered_lu, "PART_SIZE", 100)
    B = sp.csr_matrix(M[:nB, :nB])
    xy = solver.disc.dof_coordinates()[solver.system.order[:nB]]
    inner, split, quarters = nested_dissection(B, xy, return_split=True, return_quarters=True)
    layout, parts = split_layout(nB, split, quarters)
    assert len(parts) == 5 and min(parts[:4]) > 100 and parts[4] == sum(s for *_, s in quarters) + split[2]
    order = np.concatenate([inner[layout], np.arange(nB, M.shape[0])])
    Mq = M[order][:, order]
    starts = np.cumsum((0,) + parts[:4])
    for i in range(4):    # the parts do not couple
        for j in range(i + 1, 4):
            assert not Mq[starts[i]:starts[i + 1], starts[j]:starts[j + 1]].any()
    lu = SplitBorderedLU(sp.csc_matrix(Mq), nB, parts)
    assert len(lu._parts) == 4
    assert all(len(b) < M.shape[0] - nB for b in lu._borders)   # (each a part of W)
    _check_against_dense(lu, Mq, nB, 14)

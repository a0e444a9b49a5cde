"""CondensedSystem against a dense solve: the condensed LU (bulk factorised with the fault last,
the dense condensed block with the nonlinear tangent) solves the scaled Newton system
J dx = -r to round-off on small blocks of each kind: an elastic bulk with a fault (the step size
only in the condensed block), and a poroelastic bulk with a fault at a small and a large step
size (factorised in its symmetric form, flow rows times -dt)."""
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp

from fault_screen import Scene
from fault_screen.discretisation import discretise
from fault_screen.solver import NewtonSolver

from conftest import CONFIGS

#: |J dx + r| / |r|: the backward error of a direct solve of a scaled system (the dense solve of
#: the same system reaches 1e-15 to 1e-13 here)
BACKWARD = 1e-11
#: |dx - dx_dense| / |dx_dense|: round-off times the scaled system's conditioning
FORWARD = 1e-8


def _scene(kind):
    """The calibrated Rustrel scene on a 16 x 17 mesh; "elastic": without rock pore pressure
    (the fault's flow stays)."""
    scene = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    scene = scene.replace(mesh=replace(scene.mesh, nx=16, ny=17))
    if kind == "elastic":
        scene = scene.replace(effects=replace(scene.effects, poroelastic=False, leak_off=False))
    return scene


def _solve_both(kind, dt):
    """The system's and numpy's dx for a random right-hand side at x = 0."""
    scene = _scene(kind)
    solver = NewtonSolver(discretise(scene))
    disc = solver.disc
    x = np.zeros(disc.n_dofs)
    contact = disc.physics.contact
    history = contact.initial_history(disc) if contact is not None else None
    solver._prepare(dt, x, history)
    system = solver.system
    rows, cols, vals, _ = solver.nonlinear(x, history, dt, np.zeros(disc.n_dofs))
    dense = system.condensed(rows, cols, vals)
    r = np.random.default_rng(1).standard_normal(disc.n_dofs)
    r[disc.fixed] = 0.0
    with solver.blas_threads():
        dx, _, _ = system.solve(r, dense, bulk_eliminated=False, defer=False)
    J = solver.L + sp.coo_matrix((vals, (rows, cols)), shape=solver.L.shape)
    D = sp.diags(solver.scale)
    free = solver.free
    Js = (D @ J @ D).tocsr()[free][:, free].toarray()
    return system, Js, r[free], dx[free]


@pytest.mark.parametrize("kind, dt", [("elastic", 5.0), ("elastic", 600.0),
                                      ("poroelastic", 5.0), ("poroelastic", 600.0)])
def test_condensed_solve_equals_a_dense_solve(kind, dt):
    system, Js, r, dx = _solve_both(kind, dt)
    assert len(system.N) > 20 and len(system.B) > 4 * len(system.N)   # a fault and a bulk
    # the symmetric form is used exactly where the bulk depends on the step size
    assert (system._row_factor is not None) == (kind == "poroelastic")
    reference = np.linalg.solve(Js, -r)
    assert np.linalg.norm(Js @ dx + r) <= BACKWARD * np.linalg.norm(r)
    # both solves are backward stable: they agree to the round-off the conditioning amplifies
    assert np.linalg.norm(dx - reference) <= FORWARD * np.linalg.norm(reference)


@pytest.mark.parametrize("dt", [5.0, 600.0])
def test_poroelastic_bulk_keeps_its_diagonal_pivots(dt):
    """In the symmetric form the bulk's factorisation keeps the diagonal pivots at any step size
    (SuperLU as the bulk was factorised before pivoted more as dt grew), so U = D L^T and only L
    is held (BorderedLU's symmetric path: ``_U`` None)."""
    system = _solve_both("poroelastic", dt)[0]
    lu = system.lu
    parts = getattr(lu, "_parts", [lu])
    assert all(part._U is None for part in parts)


@pytest.mark.parametrize("index_type", [np.int32, np.int64])
def test_whole_products_are_scipys_products_bit_for_bit(index_type):
    """The convergence test's products in one pass (``_whole_products``: A x, Hf x, C x and
    C x - C x_n) equal scipy's CSR products and their difference exactly (0 difference, not a
    round-off bound: each row is summed in the same order), with either index width (the
    indices are read unsigned)."""
    from fault_screen.linear_system import unsigned_indices
    from fault_screen.solver import _whole_products

    solver = NewtonSolver(discretise(_scene("poroelastic")))
    rng = np.random.default_rng(3)
    # displacements (mm), pressures (MPa), multipliers: magnitudes of a run's unknowns
    x = rng.standard_normal(solver.disc.n_dofs) * np.where(rng.random(solver.disc.n_dofs) < 0.5,
                                                          1e-3, 1e6)
    x_n = x * (1.0 + 1e-3 * rng.standard_normal(x.shape))
    mats = []
    for M in (solver.A, solver.Hf, solver.C):
        M = M.copy()
        M.indptr, M.indices = M.indptr.astype(index_type), M.indices.astype(index_type)
        assert M.nnz > solver.disc.n_dofs    # (not trivially empty)
        mats.append(M)
    A, Hf, C = mats
    arrays = [a for M in mats for a in (unsigned_indices(M.indptr), unsigned_indices(M.indices), M.data)]
    AHx, Cx, Cd = _whole_products(*arrays, x, C @ x_n)
    assert np.array_equal(AHx, np.concatenate([A @ x, Hf @ x]))
    assert np.array_equal(Cx, C @ x)
    assert np.array_equal(Cd, C @ x - C @ x_n)


def test_fused_bulk_passes_are_the_numpy_expressions_bit_for_bit():
    """The one-pass kernels of a step's bulk update (x[B] += s[B] y) and of the forward sweep's
    right-hand side (f * -r[B]) equal the numpy expressions they replace exactly (0 difference),
    on a permuted subset of the unknowns as the factors' order gives it."""
    from fault_screen.linear_system import _negated_at, _scaled_update, unsigned_indices

    rng = np.random.default_rng(5)
    n = 500
    at = rng.permutation(n)[:350]
    scale = np.exp(rng.uniform(-20.0, 5.0, n))
    y = rng.standard_normal(350) * 1e6
    x = rng.standard_normal(n)
    expected_x = x.copy()
    expected_d = scale[at] * y
    expected_x[at] += expected_d
    d = _scaled_update(x, unsigned_indices(at), scale, y)
    assert np.array_equal(d, expected_d) and np.array_equal(x, expected_x)
    factor = np.where(rng.random(n) < 0.5, 1.0, -37.5)
    assert np.array_equal(_negated_at(x, unsigned_indices(at), factor), factor[:350] * -x[at])


@pytest.mark.parametrize("kind", ["elastic", "poroelastic"])
def test_factors_serve_every_step_size_exactly_without_rock_pore_pressure(kind):
    """The step size enters C and Hf only; without rock pore pressure neither touches a linear
    unknown (the fault's flow unknowns are condensed), with it both do: ``factors_any_dt``
    agrees with the free block of |C| + |Hf| sliced on the linear unknowns."""
    system = NewtonSolver(discretise(_scene(kind))).system
    assert system.factors_any_dt == (kind == "elastic")
    linear = np.zeros(system.n_dofs, dtype=bool)
    linear[system.B] = True
    CH = (abs(system.C) + abs(system.Hf)).tocsr()[system.free][:, system.free]
    on_B = linear[system.free]
    assert system.factors_any_dt == (CH[on_B].nnz == 0 and CH[:, on_B].nnz == 0)

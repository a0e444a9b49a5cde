"""The condensation P = L_NB B^-1 L_BN read from one triangle when it is symmetric
(``linear_system.condensation_symmetrised``, ``condensation_times``): P is taken as symmetric only
when its asymmetry is round-off, made exactly symmetric with its lower triangle kept bit for bit,
its products agree with the full product to round-off, the condensed solver's every path still
meets CONDENSED_RTOL against the dense block, and on a scene the elastic bulk's P is found
symmetric (and equals the dense condensation) while the poroelastic bulk's is not. A residual with
the bulk's answer pending takes P times the fault updates from the products the condensed solves'
checks made (``PendingBulk.condensed``), to the round-off of the sums."""
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp

from fault_screen import Scene, linear_system
from fault_screen.discretisation import discretise
from fault_screen.linear_system import (CONDENSATION_SYMMETRY_ROUNDOFF, CONDENSED_RTOL,
                                        CondensedSolver, condensation_symmetrised,
                                        condensation_times)
from fault_screen.solver import NewtonSolver

from conftest import CONFIGS

EPS = np.finfo(float).eps


def _symmetric(n, order, rng, noise):
    """A symmetric n x n matrix plus an asymmetry of ``noise`` times its largest entry."""
    S = rng.standard_normal((n, n))
    S = S + S.T
    S += noise * np.abs(S).max() * rng.uniform(-1.0, 1.0, (n, n))
    return np.asarray(S, order=order)


@pytest.mark.parametrize("order", ["C", "F"])
@pytest.mark.parametrize("n", [2, 255, 600])   # (one block of rows, one short, two and a rest)
def test_round_off_asymmetry_is_mirrored_from_the_lower_triangle(order, n):
    P = _symmetric(n, order, np.random.default_rng(n), 1e-14)
    before = P.copy(order="K")
    assert condensation_symmetrised(P)
    assert np.array_equal(P, P.T)
    assert np.array_equal(np.tril(P), np.tril(before))   # the lower triangle, bit for bit
    assert P.flags.c_contiguous == (order == "C")         # in place, its layout kept
    assert np.abs(P - before).max() <= 2e-14 * np.abs(before).max()


@pytest.mark.parametrize("where", [(1, 0), (599, 3), (300, 420)])
def test_an_asymmetry_above_round_off_leaves_p_as_it_is(where):
    P = _symmetric(600, "C", np.random.default_rng(3), 0.0)
    # ten times the bound: a poroelastic bulk's flow rows differ at the scale of their entries
    P[where] += 10 * CONDENSATION_SYMMETRY_ROUNDOFF * np.abs(P).max()
    before = P.copy()
    assert not condensation_symmetrised(P)
    assert np.array_equal(P, before)
    P[where] = np.nan
    assert not condensation_symmetrised(P)


@pytest.mark.parametrize("order", ["C", "F"])
def test_the_product_from_one_triangle_is_the_full_product_to_round_off(order):
    rng = np.random.default_rng(11)
    P = _symmetric(700, order, rng, 0.0)
    assert condensation_symmetrised(P)
    v = rng.standard_normal(700)
    bound = 4 * 700 * EPS * (np.abs(P) @ np.abs(v))   # (the summation's round-off bound)
    assert np.all(np.abs(condensation_times(P, True, v) - P @ v) <= bound)
    assert np.array_equal(condensation_times(P, False, v), P @ v)


N_MECH, N_FLOW = 60, 20
N = N_MECH + N_FLOW
FLOW = np.arange(N_MECH, N)


def _blocks(order):
    """L_NN's parts (A: a stiffness-like band, storage C on the flow rows reaching three
    mechanical columns each, H: a few conduction terms) and a symmetric P made symmetric."""
    rng = np.random.default_rng(7)
    A = sp.diags([np.full(N - 2, -1.0), np.full(N - 1, -2.0), np.full(N, 9.0),
                  np.full(N - 1, -2.0), np.full(N - 2, -1.0)], [-2, -1, 0, 1, 2])
    storage_rows = np.repeat(FLOW, 4)
    storage_cols = np.column_stack([FLOW, rng.integers(0, N_MECH, (N_FLOW, 3))]).ravel()
    storage = np.column_stack([np.full(N_FLOW, 0.03),
                               0.004 * rng.standard_normal((N_FLOW, 3))]).ravel()
    C = sp.coo_matrix((storage, (storage_rows, storage_cols)), shape=(N, N))
    H = sp.random(N, N, density=0.05, random_state=rng)
    P = _symmetric(N, order, rng, 1e-15) * 0.05
    assert condensation_symmetrised(P)
    return sp.csr_matrix(A), C.tocsr(), sp.csr_matrix(H), P


def _tangent(points, stiffness):
    rows = np.repeat(points, 2)
    cols = np.concatenate([[p, (p + 1) % N_MECH] for p in points])
    return rows, cols, np.tile([stiffness, -0.5 * stiffness], len(points))


def _set(dense, blocks, inv_dt, tangent):
    """Hand the block to the solver (tangent on one fixed pattern) and return it dense."""
    A, C, H, P = blocks
    L = (A + C * inv_dt + H).tocoo()
    rows, cols = _tangent(np.arange(N_MECH), 1.0)[:2]
    vals = np.zeros(len(rows))
    for r, c, v in zip(*tangent):
        vals[np.flatnonzero((rows == r) & (cols == c))[0]] += v
    dense.set(P, (L.row.astype(np.int64), L.col.astype(np.int64), L.data), (rows, cols, vals),
              1.0 / inv_dt, base=1, symmetric=True)
    M = (A + C * inv_dt + H).toarray() - P
    np.add.at(M, (tangent[0], tangent[1]), tangent[2])
    return M


@pytest.mark.parametrize("order", ["C", "F"])
def test_every_condensed_path_meets_its_tolerance_with_one_triangle(order, monkeypatch):
    """A fresh LU, a step-size change on the storage rows, a slip front's Woodbury update and a
    spread change left to iteration: each checked against M by products that read P's lower
    triangle (symv, given a Fortran-ordered array: no copy of P)."""
    symv_calls = []

    def symv(alpha, a, x, lower):
        assert a.flags.f_contiguous and lower == 1
        symv_calls.append(1)
        return linear_system.scipy.linalg.blas.dsymv(alpha, a, x, lower=lower)

    monkeypatch.setattr(linear_system, "_symv", symv)
    blocks = _blocks(order)
    rng = np.random.default_rng(1)
    dense = CondensedSolver(blocks[1])
    contact = _tangent(np.arange(10, 20), 50.0)
    spread = (np.arange(N_MECH), np.arange(N_MECH), np.full(N_MECH, 0.01))
    cases = [(1e3, contact), (200.0, contact), (200.0, _tangent(np.arange(10, 23), 50.0)),
             (190.0, tuple(np.concatenate([a, b]) for a, b in zip(contact, spread)))]
    for inv_dt, tangent in cases:
        M = _set(dense, blocks, inv_dt, tangent)
        b = rng.standard_normal(N)
        x = dense.solve(b)
        assert np.linalg.norm(M @ x - b) <= CONDENSED_RTOL * np.linalg.norm(b)
        assert np.allclose(x, np.linalg.solve(M, b), rtol=1e-8, atol=1e-12 * np.abs(x).max())
    assert dense.factorizations == 1 and dense.updates == 2 and dense.iterations > 0
    assert len(symv_calls) >= 3   # (every check: two updates and the iteration's last)


def _system(kind):
    """The 16 x 17 calibrated Rustrel scene prepared at its step size ("elastic": no rock pore
    pressure, the fault's flow kept)."""
    scene = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    scene = scene.replace(mesh=replace(scene.mesh, nx=16, ny=17))
    if kind == "elastic":
        scene = scene.replace(effects=replace(scene.effects, poroelastic=False, leak_off=False))
    solver = NewtonSolver(discretise(scene))
    x = np.zeros(solver.disc.n_dofs)
    contact = solver.disc.physics.contact
    solver._prepare(scene.time.dt, x, contact.initial_history(solver.disc))
    return solver


@pytest.mark.parametrize("kind", ["elastic", "poroelastic"])
def test_an_elastic_bulks_condensation_is_found_symmetric(kind):
    """P from the factors against the dense L_NB B^-1 L_BN of the scaled linear Jacobian: the
    elastic bulk's is symmetric (and made so), the poroelastic one's is not, far beyond
    round-off (the flow rows' Schur complement is divided by -dt)."""
    solver = _system(kind)
    system = solver.system
    D = sp.diags(solver.scale)
    J = (D @ solver.L @ D).tocsr()
    B, N_ = system.B, system.N
    dense = J[N_][:, B].toarray() @ np.linalg.solve(J[B][:, B].toarray(), J[B][:, N_].toarray())
    largest = np.abs(dense).max()
    assert np.abs(system.P - dense).max() <= 1e-10 * largest
    assert system.P_symmetric == (kind == "elastic")
    if kind == "elastic":
        assert np.array_equal(system.P, system.P.T)
    else:
        assert np.abs(dense - dense.T).max() > 1e3 * CONDENSATION_SYMMETRY_ROUNDOFF * largest


def test_a_checked_solves_product_is_handed_on_bit_for_bit():
    """A Woodbury solve is checked by a product with M, whose P x is kept with x: the product
    handed on is P x itself (bit for bit: the same call), for that array only."""
    blocks = _blocks("F")
    dense = CondensedSolver(blocks[1])
    _set(dense, blocks, 1e3, _tangent(np.arange(10, 20), 50.0))
    dense.solve(np.ones(N))   # (the factorisation: no check, no product)
    _set(dense, blocks, 1e3, _tangent(np.arange(10, 22), 50.0))
    b = np.random.default_rng(4).standard_normal(N)
    x = dense.solve(b)
    assert dense.updates == 1
    assert np.array_equal(dense.condensation_product(x), condensation_times(blocks[3], True, x))
    assert dense.condensation_product(x.copy()) is None
    _set(dense, blocks, 1e3, _tangent(np.arange(10, 22), 50.0))
    assert dense.condensation_product(x) is None   # (a new block forgets it)


@pytest.mark.parametrize("symmetric", [False, True])
def test_pending_updates_products_sum_to_the_product_of_their_sum(symmetric, monkeypatch):
    """P times a step's summed fault updates, from the checks' products (each scaled by its step
    length) plus one product of the updates that came without one: equal to P (sum) to the
    round-off of the sums (bound: 8 eps |P| |updates|), and no pass over P when every update
    brought its product."""
    rng = np.random.default_rng(21)
    n = 300
    P = _symmetric(n, "F", rng, 0.0) if symmetric else np.asfortranarray(rng.standard_normal((n, n)))
    if symmetric:
        assert condensation_symmetrised(P)
    updates = [rng.standard_normal(n) for _ in range(4)]
    alphas = [1.0, 0.5, 0.25, 1.0]
    calls = []
    original = linear_system.condensation_times

    def counted(*args):
        calls.append(1)
        return original(*args)

    monkeypatch.setattr(linear_system, "condensation_times", counted)
    every = linear_system.PendingBulk(n)
    some = linear_system.PendingBulk(n)
    for k, (alpha, dx) in enumerate(zip(alphas, updates)):
        with_product = linear_system.Deferred(None, None, original(P, symmetric, dx))
        every.add(alpha, dx, with_product)
        some.add(alpha, dx, with_product if k % 2 else None)
    exact = P @ every.fault
    bound = 8 * EPS * (np.abs(P) @ sum(abs(a) * np.abs(dx) for a, dx in zip(alphas, updates)))
    assert np.all(np.abs(every.condensed(P, symmetric) - exact) <= bound)
    assert calls == []
    assert np.all(np.abs(some.condensed(P, symmetric) - exact) <= bound)
    assert len(calls) == 1
    twin = some.copy()
    twin.add(0.5, updates[0], None)
    assert np.all(np.abs(twin.condensed(P, symmetric) - P @ twin.fault)
                  <= bound + 8 * EPS * 0.5 * (np.abs(P) @ np.abs(updates[0])))
    assert np.array_equal(some.fault, every.fault)

"""A new step size written into the fixed pattern (fault_screen/fixed_pattern.py) against the
matrices built the general way (sparse sums and products, as the solver built them before), on
an elastic bulk, a poroelastic one with a damage zone, whole and split in parts, and its border
(the fault's unknowns): equal bit for bit (np.array_equal, and no entry differing in the sparse
comparison), because each value is made by the same operations in the same order. A run with
growing steps on the poroelastic scene then equals, bit for bit, the same run with each new step
size's matrix built the general way, on one symbolic analysis and one fixed pattern."""
import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from fault_screen import Scene, bordered_lu, ldl
from fault_screen.fixed_pattern import FixedBulk
from fault_screen.linear_system import CondensedSystem
from fault_screen.simulate import simulate

from conftest import CONFIGS
# (the scenes: a permeable-rock one with a damage zone, mass balance verification, and a coarse
# inclined fault in impermeable rock)
from test_ldl import _solver, elastic, poroelastic  # noqa: F401  (fixtures)

#: the Schur complement of the split bulk against numpy's dense one (relative to its largest
#: entry; test_ldl's tolerance)
TOL = 1e-11


def _general_way(system, dt):
    """The free block as the solver built it before the fixed pattern: D (A + C/dt + theta Hf)
    D by sparse sums and products, permuted to the factors' order, the flow rows times -dt in
    the symmetric form."""
    D = sp.diags(system.scale)
    M = (D @ system._linear_jacobian(dt) @ D).tocsr()[system.order][:, system.order].tocsc()
    if not system.factors_any_dt:
        M.data *= np.where(system._mechanical[system.order], 1.0, -dt)[M.indices]
    return M


def _assert_same(new, old):
    """Equal as matrices to the last bit, with the same stored pattern."""
    assert new.shape == old.shape and new.nnz == old.nnz
    assert (new != old).nnz == 0
    a, b = sp.csc_matrix(new), sp.csc_matrix(old)
    a.sort_indices()
    b.sort_indices()
    for x, y in ((a.indptr, b.indptr), (a.indices, b.indices), (a.data, b.data)):
        assert np.array_equal(x, y)


def _mass_balance():
    return Scene.from_toml(CONFIGS / "verification" / "mass-balance.toml")


@pytest.mark.parametrize("dt", [7.3, 600.0])
def test_poroelastic_values_at_a_new_step_size_equal_the_general_way(poroelastic, dt):
    system = poroelastic.system
    bulk = system.fixed_bulk()   # (a run makes it at its first change of step size)
    assert not system.factors_any_dt and system.bulk_patterns == 1
    values = bulk.values(dt)
    old = _general_way(system, dt)
    _assert_same(bulk.matrix(values), old)
    nB = len(system.B)
    lower, old_lower = bulk.lower(values), ldl._lower(old, nB)   # (what the LDL^T reads)
    for x, y in ((lower.indptr, old_lower.indptr), (lower.indices, old_lower.indices),
                 (lower.data, old_lower.data)):
        assert np.array_equal(x, y)
    # the border: the fault's unknowns, their block dense as the Schur complement starts
    assert len(system.N) > 50
    condensed, old_condensed = bulk.condensed(values), old[nB:, nB:].toarray()
    assert np.array_equal(condensed, old_condensed)
    # (and in the same memory order: BLAS's products with the Schur complement made in it sum
    # in an order that depends on it)
    assert condensed.flags.f_contiguous == old_condensed.flags.f_contiguous
    # the same two parts with only their entries' values computed (what a refactorisation reads)
    read_lower, read_condensed = bulk.parts(dt)
    for x, y in ((read_lower.indptr, old_lower.indptr), (read_lower.indices, old_lower.indices),
                 (read_lower.data, old_lower.data)):
        assert np.array_equal(x, y)
    assert np.array_equal(read_condensed, old_condensed) and read_condensed.flags.f_contiguous


def test_the_rows_and_blocks_of_each_step_size_equal_the_general_way(poroelastic, elastic):
    """L's rows of the fixed unknowns on the bulk, the rows of N and of the fixed unknowns, and
    the condensed block's entries (``_combine``, as they were made before)."""
    for solver in (poroelastic, elastic):
        system = solver.system
        dt = 3.7 * system.dt
        system.prepare(dt, None)
        _assert_same(system._L_fixed_B, system._combine(system._blocks_fixed, dt))
        _assert_same(system._L_rows_N_fixed, system._combine(system._blocks_rows_N_fixed, dt))
        rows, cols, vals = system._LNN_entries
        L_NN = sp.csr_matrix((vals, (rows, cols)), shape=(len(system.N),) * 2)
        _assert_same(L_NN, system._combine(system._blocks_NN, dt))


def test_elastic_values_equal_the_general_way(elastic):
    """An elastic bulk (no row factor: the block as it is) in the fixed pattern."""
    system = elastic.system
    assert system.factors_any_dt
    bulk = FixedBulk((system.A, system.C, system.Hf), system.time_weight, system.order,
                     system.scale, None, len(system.B))
    for dt in (system.dt, 11.0 * system.dt):
        _assert_same(bulk.matrix(bulk.values(dt)), _general_way(system, dt))


def test_a_split_poroelastic_bulk(monkeypatch):
    """The bulk factorised in quarters (the limits lowered so that the small scene splits): the
    values in the fixed pattern equal the general way in the split order, and the Schur
    complement at a new step size equals numpy's dense one."""
    monkeypatch.setattr(bordered_lu, "SPLIT_ABOVE", 500)
    monkeypatch.setattr(bordered_lu, "PART_SIZE", 200)
    system = _solver(_mass_balance()).system
    assert len(system.split) == 5   # (four quarters and the separators)
    dt = 55.0
    system.prepare(dt, None)
    assert isinstance(system.lu, bordered_lu.SplitBorderedLU)
    assert all(part.quasi_definite for part in system.lu._parts)
    old = _general_way(system, dt)
    _assert_same(system.fixed_bulk().matrix(system.fixed_bulk().values(dt)), old)
    nB = len(system.B)
    M = (old.toarray() / np.where(system._mechanical[system.order], 1.0, -dt)[:, None])
    exact = M[nB:, nB:] - M[nB:, :nB] @ np.linalg.solve(M[:nB, :nB], M[:nB, nB:])
    rows, cols, vals = system._LNN_entries
    L_NN = np.zeros_like(exact)
    L_NN[rows, cols] = vals
    assert np.max(np.abs(L_NN - system.P - exact)) / np.max(np.abs(exact)) < TOL


def _growing(scene, end):
    return scene.replace(time=dataclasses.replace(scene.time, growth=1.3, dt_max=60.0, end=end))


def _factorise_the_general_way(self, dt):
    """``CondensedSystem._factorise_symmetric`` as it was: the matrix summed, scaled, permuted
    and row-scaled by sparse operations, checked for symmetry and its lower triangle taken at
    every step size."""
    if self._analyses is None:
        self._analyses = ldl.SymbolicAnalyses()
    self._row_factor = np.where(self._mechanical[self._order], 1.0, -dt)
    held = [_general_way(self, dt)]
    return bordered_lu.bordered_lu(held.pop, len(self.B), self._split, self._analyses)


def test_a_run_with_growing_steps_equals_the_general_way(monkeypatch):
    """Growing steps (factor 1.3 up to 60 s) on the poroelastic scene: every result array bit
    for bit the run that builds each step size's matrix the general way; one symbolic analysis
    and one fixed pattern serve every step size, one numeric factorisation per step size."""
    scene = _growing(_mass_balance(), 400.0)
    made = []
    prepare = CondensedSystem.prepare

    def watched(self, dt, tangent):
        made.append(self)
        return prepare(self, dt, tangent)

    monkeypatch.setattr(CondensedSystem, "prepare", watched)
    fixed = simulate(scene)
    system = made[-1]
    sizes = np.diff(fixed.time)
    assert len(set(sizes)) >= 8   # (5 s growing to 60 s, and the last step cut to the end)
    assert system._analyses.made == 1 and system.bulk_patterns == 1
    assert system.factorizations == len(set(sizes))
    monkeypatch.setattr(CondensedSystem, "_factorise_symmetric", _factorise_the_general_way)
    general = simulate(scene)
    assert np.array_equal(fixed.time, general.time)
    for group in ("fault", "injection", "balance", "solver"):
        ours, theirs = getattr(fixed, group), getattr(general, group)
        assert ours.keys() == theirs.keys()
        for key in ours:
            assert np.array_equal(np.asarray(ours[key]), np.asarray(theirs[key]), equal_nan=True), key


def test_a_block_without_entries():
    """Impermeable rock beside storage (Hf without an entry, as in the hard case
    permeability-0-poroelastic): the parts X, Y, Z and the values at a step size equal the
    general way's, bit for bit."""
    rng = np.random.default_rng(7)
    n, n_linear = 40, 30
    K = sp.random(n, n, density=0.15, random_state=rng) + sp.eye(n)
    A = (K + K.T).tocsr()
    C = sp.diags(rng.uniform(1.0, 2.0, n)).tocsr()
    Hf = sp.csr_matrix((n, n))
    scale = rng.uniform(0.5, 2.0, n)
    order = rng.permutation(n)
    flow = np.zeros(n, dtype=bool)
    flow[::3] = True
    bulk = FixedBulk((A, C, Hf), 0.5, order, scale, flow, n_linear)
    D = sp.diags(scale)
    for dt in (0.3, 40.0):
        M = (D @ (A + C * (1.0 / dt) + Hf * 0.5) @ D).tocsr()[order][:, order].tocsc()
        M.data *= np.where(flow, -dt, 1.0)[M.indices]
        _assert_same(bulk.matrix(bulk.values(dt)), M)
        # the parts the symmetry is checked on sum to the matrix (to a few ulps: summed in
        # another order)
        X, Y, Z = bulk.components()
        np.testing.assert_allclose((X + dt * Y + Z / dt).toarray(), M.toarray(), rtol=1e-15,
                                   atol=0.0)


def _random_blocks(rng, n):
    K = sp.random(n, n, density=0.15, random_state=rng) + sp.eye(n)
    H = sp.random(n, n, density=0.05, random_state=rng)
    return ((K + K.T).tocsr(), sp.diags(rng.uniform(1.0, 2.0, n)).tocsr(), (H + H.T).tocsr())


def test_parts_of_a_twin_with_other_values():
    """``parts`` streams through the blocks' values gathered at its first call: a twin with
    other values (``with_values``, as ensemble members share a pattern) gathers its own, and
    each bulk's parts equal, bit for bit, those of a bulk made from its own blocks, before and
    after the other's were gathered."""
    rng = np.random.default_rng(11)
    n, n_linear = 50, 38
    first = _random_blocks(rng, n)
    # the same nonzero pattern, other values
    second = tuple(sp.csr_matrix((rng.uniform(0.5, 1.5, X.nnz) * np.sign(X.data), X.indices,
                                  X.indptr), shape=X.shape) for X in first)
    scale, order = rng.uniform(0.5, 2.0, n), rng.permutation(n)
    flow = np.zeros(n, dtype=bool)
    flow[::4] = True
    bulk = FixedBulk(first, 0.5, order, scale, flow, n_linear)
    before = bulk.parts(3.0)
    scale2 = rng.uniform(0.5, 2.0, n)
    twin = bulk.with_values(second, 0.7, scale2)
    alone = FixedBulk(second, 0.7, order, scale2, flow, n_linear)
    for dt in (3.0, 250.0):
        (lower, condensed), (want_lower, want_condensed) = twin.parts(dt), alone.parts(dt)
        assert np.array_equal(lower.data, want_lower.data)
        assert np.array_equal(condensed, want_condensed)
        # and each part as ``values`` computes it
        values = alone.values(dt)
        assert np.array_equal(lower.data, alone.lower(values).data)
        assert np.array_equal(condensed, alone.condensed(values))
    after = bulk.parts(3.0)
    assert np.array_equal(before[0].data, after[0].data) and np.array_equal(before[1], after[1])
    assert not np.array_equal(before[0].data, twin.parts(3.0)[0].data)


@pytest.mark.parametrize("n, high", [(0, 5), (1, 5), (2000, 50), (5000, 10 ** 12)])
def test_sorted_unique_equals_numpy(n, high):
    """The fixed pattern's union of keys (``_sorted_unique``, by a sort): np.unique's array,
    value for value and in its dtype, with many repeats (high 50) and with almost none."""
    from fault_screen.fixed_pattern import _sorted_unique

    keys = np.random.default_rng(n).integers(0, high, n, dtype=np.int64)
    got, want = _sorted_unique(keys), np.unique(keys)
    assert got.dtype == want.dtype and np.array_equal(got, want)
    assert high > n or len(got) < n   # (the repeats were there to remove)

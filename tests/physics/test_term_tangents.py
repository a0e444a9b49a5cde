"""Eq. 11-14 (Newton's consistent Jacobian) for the terms of Eq. 17-28: the nonlinear terms'
assembled Jacobians (their triplets: rows and columns from the term's pattern, values from its
kernel) against central finite differences of the same terms' residuals, on the calibrated Rustrel
scene part-way through its injection (slipping and sticking points under rate-and-state friction, an
opening fault with an evolving aperture)."""
import numpy as np
import pytest
import scipy.sparse as sp

from fault_screen import Scene, Simulation
from fault_screen.physics.contact import Contact
from fault_screen.physics.fault_flow import EvolvingApertureConduction

from conftest import CONFIGS

#: relative to the largest entry of the field's columns; central differences of a smooth residual
#: at a step of 1e-6 of the field's magnitude are good to ~1e-8 (the return map converges to 1e-13)
TOL = 1e-5


@pytest.fixture(scope="module")
def state():
    scene = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    sim = Simulation(scene)
    sim.advance(600.0)   # the pressure front along the fault, points slipping near the source
    return sim


@pytest.mark.parametrize("kind", [Contact, EvolvingApertureConduction])
def test_assembled_tangent_matches_finite_differences(state, kind):
    """Eq. 17-27, 32 (contact, friction, dilation): each nonlinear term's assembled
    Jacobian matches central finite differences of its residual, column by column."""
    sim = state
    disc = sim.disc
    term = disc.physics.find(kind)
    dt, theta = 5.0, sim.solver.time_weight
    x = sim.x.copy()

    def residual(x):
        R = np.zeros(disc.n_dofs)
        rows, cols, vals = term.residual(disc, x, sim.history, dt, theta, R, {})
        return R, rows, cols, vals

    R0, rows, cols, vals = residual(x)
    assert rows is term.pattern(disc)[0] and cols is term.pattern(disc)[1]   # made once
    J = sp.coo_matrix((vals, (rows, cols)), shape=(disc.n_dofs,) * 2).tocsc()
    if kind is Contact:
        slipping = np.abs(disc.fault_jump(x)[0]) > 0
        assert slipping.any()
    columns = np.unique(cols)
    # each field of unknowns the term differentiates by (jumps in m, pressures in Pa) with a
    # step of 1e-6 of that field's magnitude, every column
    fields = [columns[(columns >= blk.start) & (columns < blk.stop)]
              for blk in (disc.blocks.u, disc.blocks.a, disc.blocks.p, disc.blocks.c,
                          disc.blocks.pf, disc.blocks.q)]
    fields = [f for f in fields if len(f)]
    # the contact term: the jumps; the conduction: the jumps and the fault's pressure, here the
    # rock pressure's trace and its enrichment (leak-off)
    assert len(fields) == (1 if kind is Contact else 3)
    for field in fields:
        h = 1e-6 * max(np.max(np.abs(x[field])), 1e-12)
        scale = abs(J[:, field]).max()   # (the difference quotients' round-off is of this order)
        assert scale > 0.0
        for j in field:
            e = np.zeros(disc.n_dofs)
            e[j] = h
            fd = (residual(x + e)[0] - residual(x - e)[0]) / (2 * h)
            exact = J[:, j].toarray().ravel()
            assert np.max(np.abs(fd - exact)) <= TOL * scale, f"column {j}"


def test_terms_share_the_jumps_at_x_without_changing_a_bit(state):
    """The conduction term leaves the jumps it computes at x in ``point`` for the contact term
    after it (one computation of the jumps per residual): the residual, the tangents' values and
    the fault state equal, to the bit, those of each term given a point of its own, at an
    iterate whose jumps differ from the accepted state's."""
    sim = state
    disc = sim.disc
    dt, theta = 5.0, sim.solver.time_weight
    rng = np.random.default_rng(3)
    x = sim.x.copy()
    jumps = disc.fault_points.jump_dofs
    moved = np.unique(jumps[jumps >= 0])
    x[moved] *= 1.0 + 1e-3 * rng.standard_normal(len(moved))
    terms = sim.solver.nonlinear_terms
    assert [type(t) for t in terms] == [EvolvingApertureConduction, Contact]
    shared, alone = {}, []
    R_shared, R_alone = np.zeros(disc.n_dofs), np.zeros(disc.n_dofs)
    vals_shared = [t.residual(disc, x, sim.history, dt, theta, R_shared, shared)[2] for t in terms]
    vals_alone = []
    for t in terms:
        point = {}
        vals_alone.append(t.residual(disc, x, sim.history, dt, theta, R_alone, point)[2])
        alone.append(point)
    assert np.array_equal(R_shared, R_alone) and np.any(R_shared != 0.0)
    for a, b in zip(vals_shared, vals_alone):
        assert np.array_equal(a, b)
    for key in ("slip", "opening", "shear_traction", "effective_normal_stress", "friction"):
        assert np.array_equal(shared[key], alone[1][key]), key
    assert np.array_equal(shared["hydraulic_aperture"], alone[0]["hydraulic_aperture"])
    assert np.array_equal(shared["opening"], disc.fault_jump(x)[1])

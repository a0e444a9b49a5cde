"""Terzaghi 1-D consolidation of a Biot column (no fault) against the series solution."""
import numpy as np
import pytest

import analytical as an
from conftest import VERIFICATION
from fault_screen import Scene, Simulation


@pytest.fixture(scope="module")
def run():
    scene = Scene.from_toml(VERIFICATION / "terzaghi.toml")
    sim = Simulation(scene)
    states = [(0.0, sim.x.copy())]
    sim.advance(scene.time.end, observer=lambda t, x, disc: states.append((t, x.copy())))
    return scene, sim.disc, states


def test_no_fault_means_no_fault_unknowns(run):
    _, model, _ = run
    counts = model.dof_counts()
    assert counts["a"] == counts["c"] == counts["pf"] == counts["q"] == 0
    assert counts["u"] == 2 * model.mesh.n_nodes and counts["p"] == model.mesh.n_nodes


@pytest.mark.parametrize("tau", [0.01, 0.05, 0.2, 0.5, 1.0])
def test_pressure_and_settlement_match_series(run, tau):
    """Eq. 1-2, 8-9 (elasticity, Biot coupling, storage, Darcy): pressure within 1 % of p_u and
    settlement within 1 % of Terzaghi's series."""
    scene, model, states = run
    rk = scene.rock
    biot_modulus = 1.0 / model.zone_props[0]["inv_M"]
    kw = dict(height=scene.mesh.ly, E=rk.youngs_modulus, nu=rk.poissons_ratio,
              biot=rk.biot_coefficient, biot_modulus=biot_modulus,
              mobility=rk.permeability / scene.fluid.viscosity)
    load = -scene.boundary.top.traction[1]
    time_scale = an.terzaghi_time_scale(**kw)
    times = np.array([t for t, _ in states])
    i = int(np.argmin(np.abs(times - tau * time_scale)))
    t, x = states[i]
    assert abs(t / time_scale - tau) < 0.05 * tau  # an output close to the wanted time
    column = model.coords[:, 0] == 0.0
    z = model.coords[column, 1]
    p = x[model.blocks.p][column]
    p_ref = an.terzaghi_pressure(z, t, load=load, **kw)
    p_u = an.terzaghi_undrained_pressure(load=load, E=rk.youngs_modulus, nu=rk.poissons_ratio,
                                         biot=rk.biot_coefficient, biot_modulus=biot_modulus)
    # 1 % of the undrained pressure: the tolerance; BE in time with steps <= 0.6 % of
    # the consolidation time and 40 elements keep the error near 0.6 %
    assert np.max(np.abs(p - p_ref)) / p_u < 0.01
    top = model.mesh.edge_nodes("top")[0]
    settlement = -x[model.blocks.u][2 * top + 1]
    w_ref = an.terzaghi_settlement(t, load=load, **kw)
    assert abs(settlement - w_ref) / w_ref < 0.01

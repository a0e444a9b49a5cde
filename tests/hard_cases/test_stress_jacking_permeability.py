"""Critically stressed and far-from-failure faults, hydraulic jacking, rock permeability 0 and
1e-12 m2."""
import numpy as np
import pytest

import analytical as an
from stability_cases import check_common, run_case

CASES = ["critically-stressed-T0.02", "far-from-failure-T0.98", "hydraulic-jacking",
         "permeability-0-poroelastic", "permeability-1e-12"]


@pytest.mark.parametrize("name", CASES)
def test_completes_finite_and_balanced(name):
    check_common(run_case(name))


def _diffusion_length(scene, t):
    f = scene.fault
    transmissivity = f.hydraulic_aperture ** 3 / (12 * scene.fluid.viscosity * f.kappa)
    alpha = transmissivity / (f.storativity + 1.0 / f.normal_stiffness)
    return np.sqrt(4 * alpha * t)


def test_critically_stressed_slip_front_lambda():
    """T = 0.02: lambda = 17.97 (Viesca 2021); the patch spans 60 elements. lambda from the slip
    moment (as in tests/verification/test_verification_fluid_driven_slip.py) within 4 %."""
    run = run_case("critically-stressed-T0.02")
    r, scene = run.result, run.scene
    T = 0.02
    lam = an.slip_front_lambda(T)
    L = _diffusion_length(scene, r.time[-1])
    G = scene.rock.youngs_modulus / (2 * (1 + scene.rock.poissons_ratio))
    scale = 2 * (1 - scene.rock.poissons_ratio) * scene.fault.friction * 5e6 / G
    xi = np.linspace(-1, 1, 20001)
    shape_integral = np.trapezoid(an.fluid_driven_slip_shape(xi, lam, T), xi)
    lam_num = np.sqrt(np.sum(r.fault_weights * r.fault["slip"][-1]) / (scale * shape_integral)) / L
    assert lam * L >= 10 * 2 * 1.0 / 2  # the half patch spans at least 10 one-metre elements
    assert lam_num == pytest.approx(lam, rel=0.04)
    # the front: sliding points reach a within one element and nothing slides beyond a + 2 m
    sliding = np.abs(r.fault_x[r.fault["contact_state"][-1] == 1])
    assert lam * L - 1.0 < sliding.max() < lam * L + 2.0


def test_far_from_failure_slips_nowhere_at_element_resolution():
    """T = 0.98: the exact patch (a = 0.028 L = 0.07 m) is far below an element: no Gauss point
    may slide, and the jump is the elastic give of the penalty springs only (< 1e-9 m)."""
    run = run_case("far-from-failure-T0.98")
    r = run.result
    L = _diffusion_length(run.scene, r.time[-1])
    assert an.slip_front_lambda(0.98) * L < 0.1
    assert not np.any(r.fault["contact_state"] == 1)
    assert np.max(np.abs(r.fault["slip"])) < 1e-9


def test_hydraulic_jacking_opens_then_closes_after_shut_in():
    r = run_case("hydraulic-jacking").result
    sigma_n = 10e6
    inject = r.time <= 0.01
    state = r.fault["contact_state"]
    assert r.injection["overpressure"][inject].max() > 1.5 * sigma_n      # well above sigma_n'
    assert (state[inject] == 2).sum(axis=1).max() >= 5                   # the walls lost contact
    assert r.fault["opening"][inject].max() > 1e-5                       # and opened by > 10 um
    # after shut-in the pressure spreads along the fault: closed again for the last half
    late = r.time >= 0.05
    assert not np.any(state[late] == 2)
    assert r.injection["overpressure"][-1] < sigma_n
    # the injected volume stops growing at shut-in
    assert np.all(np.diff(r.injection["volume"][r.time > 0.0115]) == 0.0)


def _nodal_storage(sim, x):
    """Fluid stored since t = 0 in each rock pressure node's mass balance (m^3 per m):
    int N_i (alpha eps_v + p / M) with the standard shape functions (a partition of unity)."""
    disc = sim.disc
    out = np.zeros(disc.mesh.n_nodes)
    for g in disc.element_groups:
        u = np.where(g.umap >= 0, x[np.maximum(g.umap, 0)], 0.0)
        p = np.where(g.pmap >= 0, x[np.maximum(g.pmap, 0)], 0.0)
        eps_v = (np.einsum("eqb,eb->eq", g.grad_u[..., 0], u[:, 0::2])
                 + np.einsum("eqb,eb->eq", g.grad_u[..., 1], u[:, 1::2]))
        pq = np.einsum("eqb,eb->eq", g.Np, p)
        density = disc.el_alpha[g.elements][:, None] * eps_v + disc.el_inv_M[g.elements][:, None] * pq
        local = np.einsum("eq,eqa->ea", g.w * density, g.Np[:, :, :4])
        np.add.at(out, disc.elements[g.elements], local)
    return out


def test_permeability_zero_stores_fluid_only_next_to_the_fault():
    """k = 0: the mass balance of a rock node has no conduction, so a free node away from the
    fault stores nothing net (it responds undrained). The nodes of the cut elements carry the
    fault's pressure (the trace basis) and store fluid in the rock around them although nothing
    can flow into the rock; drained edge nodes pass theirs to the drained volume. Bound (README):
    (1/M + alpha^2/K) times the largest overpressure over the elements touching those nodes: it
    scales with the element size, and an impermeable rock is better modelled without
    poroelasticity (the fault's own pressure line), as configs/rustrel-2015-impermeable.toml does."""
    run = run_case("permeability-0-poroelastic")
    sim, r = run.sim, run.result
    disc = sim.disc
    nodal = _nodal_storage(sim, sim.x)
    injected = r.injection["volume"][-1] / r.scene.injection.number_of_fractures
    cut_nodes = np.zeros(disc.mesh.n_nodes, dtype=bool)
    cut_nodes[disc.elements[disc.cut_elements]] = True
    drained = disc.fixed[disc.blocks.p]
    assert nodal.sum() == pytest.approx(r.balance["stored_rock"][-1], rel=1e-9)
    assert np.max(np.abs(nodal[~cut_nodes & ~drained])) < 1e-9 * injected
    near = nodal[cut_nodes].sum()
    # on this 10 m mesh it is most of the injected fluid (88 %): the band's pore storage (1/M
    # over ~5000 m2) dwarfs the fault's own (2h0/Kf over 250 m)
    assert 0.5 * injected < near <= injected
    band_elements = np.isin(disc.elements, np.flatnonzero(cut_nodes)).any(axis=1)
    band = np.sum(disc.mesh.element_sizes[band_elements].prod(axis=1))
    inv_M, alpha = disc.el_inv_M[band_elements].max(), disc.el_alpha[band_elements].max()
    K = min(r.scene.damage_zone.youngs_modulus or r.scene.rock.youngs_modulus, r.scene.rock.youngs_modulus) / (
        3 * (1 - 2 * max(r.scene.rock.poissons_ratio, r.scene.damage_zone.poissons_ratio or 0.0)))
    p_max = np.max(np.abs(r.fault["overpressure"]))
    assert near <= (inv_M + alpha ** 2 / K) * p_max * band


def test_very_permeable_rock_takes_the_fluid():
    """k = 1e-12 m2: nearly all the fluid leaks off into the rock or drains; the fault barely
    pressurises (< 0.1 MPa)."""
    r = run_case("permeability-1e-12").result
    injected = r.injection["volume"][-1] / r.scene.injection.number_of_fractures
    b = r.balance
    assert (b["stored_rock"][-1] + b["leaked"][-1]) > 0.9 * injected
    assert np.max(np.abs(r.injection["overpressure"])) < 1e5

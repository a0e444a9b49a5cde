"""Patch tests: a block under uniform in-situ stress with a closed, sticking fault at several
angles and at 1e-3 of an element from a row of nodes.

1. In-situ stress alone: nothing moves, fault tractions are the projected in-situ stress.
2. Plus a uniform stress change imposed through the boundary displacements: the exact solution
   is a uniform strain plus a uniform elastic jump of the sticking penalty contact,
   u = eps.x + H(phi) g with g.t = dtau/kT and g.n = dsigma_nn/kN; the X-FEM space contains it,
   so every unknown and every fault traction must match to round-off.
"""
import numpy as np
import pytest

from fault_screen import Scene
from fault_screen.kernels.rock import plane_strain_elasticity
from fault_screen.discretisation import discretise
from fault_screen.solver import NewtonSolver

SIGMA = np.array([-5.649e6, -3.351e6, 0.964e6])  # Rustrel in-situ effective stress, Pa
H = 10.0  # element size, m


def scene_for(angle, offset):
    # the fault passes ``offset`` (in element sizes) above the node at the domain centre
    return Scene.from_dict({
        "mesh": {"nx": 8, "ny": 8, "lx": 8 * H, "ly": 8 * H},
        "fault": {"point": [40.0, 40.0 + offset * H], "angle": angle, "friction": 0.8,
                  "normal_stiffness": 30e9, "shear_stiffness": 12e9},
        "rock": {"youngs_modulus": 30e9, "poissons_ratio": 0.25},
        "initial": {"effective_stress": SIGMA.tolist(), "pore_pressure": 0.0},
        "effects": {"poroelastic": False, "leak_off": False, "fault_flow": False},  # dry fault
    })


CASES = [(0.0, 0.5), (30.0, 0.31), (63.0, 0.27), (0.0, 1e-3), (30.0, 1e-3), (63.0, 1e-3)]


def _projected(model, stress_voigt):
    s = np.array([[stress_voigt[0], stress_voigt[2]], [stress_voigt[2], stress_voigt[1]]])
    t, n = model.fault.tangent, model.fault.normal
    return t @ s @ n, -(n @ s @ n)


@pytest.mark.parametrize("angle,offset", CASES)
def test_in_situ_stress_alone(angle, offset):
    model = discretise(scene_for(angle, offset))
    solver = NewtonSolver(model)
    hist = model.physics.contact.initial_history(model)
    out = solver.step(np.zeros(model.n_dofs), hist, 1.0, 0.0)
    assert np.all(np.isfinite(out.x))
    assert np.max(np.abs(out.point["slip"])) < 1e-15
    tau, sn = _projected(model, SIGMA)
    assert np.allclose(out.point["shear_traction"], tau, rtol=1e-12)
    assert np.allclose(out.point["effective_normal_stress"], sn, rtol=1e-12)
    assert np.all(out.point["contact_state"] == 0)  # stick


@pytest.mark.parametrize("angle,offset", CASES)
def test_uniform_stress_change_is_reproduced_exactly(angle, offset):
    """Eq. 3-7 (Heaviside enrichment): a uniform stress change on a sticking fault is reproduced
    exactly (displacements to 1e-8 of their scale, fault tractions to 1e-7)."""
    scene = scene_for(angle, offset)
    model = discretise(scene)
    f = model.fault
    dsig = np.array([-1.0e6, 0.4e6, 0.3e6])  # a stress change that keeps the fault sticking
    D = plane_strain_elasticity(scene.rock.youngs_modulus, scene.rock.poissons_ratio)
    eps = np.linalg.solve(D, dsig)  # Voigt, engineering shear
    grad = np.array([[eps[0], eps[2] / 2], [eps[2] / 2, eps[1]]])
    dtau, dsn = _projected(model, dsig)
    g = (dtau / scene.fault.shear_stiffness) * f.tangent - (dsn / scene.fault.normal_stiffness) * f.normal
    side = (f.node_phi > 0).astype(float)
    exact = np.zeros(model.n_dofs)
    u = model.coords @ grad.T + side[:, None] * g[None, :]
    exact[model.blocks.u] = u.ravel()
    enriched = np.flatnonzero(model.heav_index >= 0)
    a_dofs = model.blocks.a.start + 2 * model.heav_index[enriched]
    exact[a_dofs] = g[0]
    exact[a_dofs + 1] = g[1]
    x_n = np.where(model.fixed, exact, 0.0)
    solver = NewtonSolver(model)
    hist = model.physics.contact.initial_history(model)
    out = solver.step(x_n, hist, 1.0, 0.0)
    scale = np.max(np.abs(exact))
    # round-off of a direct solve on a scaled system: 1e-8 of the displacement scale
    assert np.max(np.abs(out.x - exact)) < 1e-8 * scale
    tau_ref, sn_ref = _projected(model, SIGMA + dsig)
    assert np.allclose(out.point["shear_traction"], tau_ref, rtol=1e-7)
    assert np.allclose(out.point["effective_normal_stress"], sn_ref, rtol=1e-7)
    assert np.all(out.point["contact_state"] == 0)


def _conditions(angle, offset):
    model = discretise(scene_for(angle, offset))
    solver = NewtonSolver(model)
    hist = model.physics.contact.initial_history(model)
    x0 = np.zeros(model.n_dofs)
    solver._prepare(1.0, x0, hist)
    J = solver.L.toarray()
    rows, cols, vals, _ = solver.nonlinear(x0, hist, 1.0, np.zeros(model.n_dofs))
    np.add.at(J, (rows, cols), vals)
    free = model.free
    Jff = J[np.ix_(free, free)]
    s = solver.scale[free]
    return np.linalg.cond(Jff), np.linalg.cond(s[:, None] * Jff * s[None, :])


@pytest.mark.parametrize("angle", [0.0, 63.0])
def test_scaling_keeps_a_near_node_fault_well_conditioned(angle):
    """As the fault approaches a row of nodes, the Heaviside functions of the far nodes live on a
    sliver and the raw Jacobian's condition number grows like 1/offset; the solver's Jacobi
    scaling must keep it at the level of a fault through the middle of the elements."""
    raw_mid, scaled_mid = _conditions(angle, 0.31)
    raw_3, scaled_3 = _conditions(angle, 1e-3)
    raw_6, scaled_6 = _conditions(angle, 1e-6)
    assert raw_6 > 100 * raw_3  # the sliver really is ill-conditioned without scaling
    assert scaled_3 < 10 * scaled_mid and scaled_6 < 10 * scaled_mid
    assert scaled_6 < 1e3

"""The contact forces and their tangent on a cut element's Heaviside DOFs
(``kernels.contact.contact_local_into``, ``assemble_contact``) against a dense
numpy reference and, for the tangent, central differences of the forces."""
from __future__ import annotations

import numpy as np
import pytest

from fault_screen.kernels import contact as kc


def _reference(N, t, n, tau, sigma_n, tau0, sigma_n0, dtau_ds, dtau_do, dsig_ds, dsig_do, w):
    """f = w N (x) [(tau - tau0) t - (sigma_n - sigma_n0) n] and K = w N N^T (x) C, C the
    derivative of that traction vector by the jump vector (slip = g.t, opening = g.n)."""
    traction = (tau - tau0) * t - (sigma_n - sigma_n0) * n
    C = np.outer(t, dtau_ds * t + dtau_do * n) - np.outer(n, dsig_ds * t + dsig_do * n)
    return w * np.kron(N, traction), w * np.kron(np.outer(N, N), C)


def _point(rng, angle):
    t = np.array([np.cos(angle), np.sin(angle)])
    n = np.array([-t[1], t[0]])
    N = rng.uniform(0.0, 1.0, 4)
    N /= N.sum()
    return (N, t, n, *rng.normal(size=4) * [2e6, 5e6, 1e6, 4e6], *rng.normal(size=4) * 1e10,
            rng.uniform(0.1, 2.0))



def _local(*args):
    """(r, k) of ``contact_local_into`` on arrays that start as NaN."""
    r, k = np.full(8, np.nan), np.full((8, 8), np.nan)
    kc.contact_local_into(*args, r, k)
    return r, k

@pytest.mark.parametrize("angle", [0.0, np.radians(30.0), np.radians(-71.0)])
def test_local_forces_and_tangent_match_the_dense_reference(angle):
    """Against numpy's Kronecker products: 1e-14 of the largest entry, every entry written
    (the arrays start as NaN)."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        args = _point(rng, angle)
        r, k = _local(*args)
        r_ref, k_ref = _reference(*args)
        assert np.max(np.abs(r - r_ref)) <= 1e-14 * np.max(np.abs(r_ref))
        assert np.max(np.abs(k - k_ref)) <= 1e-14 * np.max(np.abs(k_ref))


def test_the_tangent_is_the_derivative_of_the_forces():
    """Tractions linear in the jump (tau = tau0 + dtau_ds s + dtau_do o, alike sigma_n): central
    differences of the forces by each of the 8 jump DOFs give the tangent's columns to 1e-7."""
    rng = np.random.default_rng(11)
    N, t, n, _, _, tau0, sigma_n0, a, b, c, d, w = _point(rng, np.radians(25.0))

    def forces(u):   # u: the 8 DOFs (node i, component x/y)
        g = N @ u.reshape(4, 2)
        s, o = g @ t, g @ n
        return _local(N, t, n, tau0 + a * s + b * o, sigma_n0 + c * s + d * o, tau0,
                                sigma_n0, a, b, c, d, w)

    u = rng.normal(size=8) * 1e-4
    _, k = forces(u)
    h = 1e-7
    for j in range(8):
        e = np.zeros(8)
        e[j] = h
        column = (forces(u + e)[0] - forces(u - e)[0]) / (2 * h)
        assert np.max(np.abs(column - k[:, j])) <= 1e-7 * np.max(np.abs(k))


def test_assembly_adds_each_points_forces_and_lists_its_tangent():
    """``assemble_contact`` on 30 points sharing DOFs, some absent (-1): the residual is the sum
    of the points' reference forces at their DOFs (1e-14 of the largest), the values are each
    point's tangent entries between present DOFs, rows then columns, in order."""
    rng = np.random.default_rng(5)
    ng, n_dofs = 30, 40
    angle = np.radians(30.0)
    t = np.array([np.cos(angle), np.sin(angle)])
    n = np.array([-t[1], t[0]])
    N = rng.uniform(0.0, 1.0, (ng, 4))
    N /= N.sum(axis=1)[:, None]
    jump_dofs = rng.integers(0, n_dofs, (ng, 8))
    jump_dofs[rng.uniform(size=(ng, 8)) < 0.2] = -1
    weight = rng.uniform(0.1, 2.0, ng)
    traction = np.column_stack([rng.normal(size=ng) * 2e6, rng.normal(size=ng) * 5e6,
                                np.full(ng, 0.6)])
    tau0, sigma_n0 = rng.normal(size=ng) * 1e6, rng.normal(size=ng) * 4e6
    tangent = rng.normal(size=(ng, 4)) * 1e10
    residual = np.zeros(n_dofs)
    vals = kc.assemble_contact(N, jump_dofs, t, n, weight, traction, tau0, sigma_n0, tangent,
                               residual)
    expected = np.zeros(n_dofs)
    expected_vals = []
    for g in range(ng):
        r, k = _reference(N[g], t, n, traction[g, 0], traction[g, 1], tau0[g], sigma_n0[g],
                          *tangent[g], weight[g])
        present = jump_dofs[g] >= 0
        np.add.at(expected, jump_dofs[g, present], r[present])
        expected_vals.append(k[np.ix_(present, present)].ravel())
    expected_vals = np.concatenate(expected_vals)
    assert np.max(np.abs(residual - expected)) <= 1e-14 * np.max(np.abs(expected))
    assert vals.shape == expected_vals.shape
    assert np.max(np.abs(vals - expected_vals)) <= 1e-14 * np.max(np.abs(expected_vals))

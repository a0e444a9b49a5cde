"""Bilinear shape functions and the two X-FEM enrichments on a rectangle element, at one point or
at arrays of points.

Displacement enrichment (paper Eq. 3-4): shifted Heaviside ``N_j (H(x) - H(x_j))``.
Pressure enrichment (Eq. 6-7): modified level set ``N_j (psi(x) - psi(x_j))`` with
``psi = sum N_i |phi_i| - |sum N_i phi_i|``; ``psi(x_j) = 0`` at every node, so the shift vanishes.
Both vanish outside cut elements, so there are no blending elements to correct.

Plain numpy, not numba: the set-up calls these a few thousand times from Python, which costs
less than compiling them (a cold start) or loading them from numba's cache (every start). The
arithmetic is written in the order the compiled kernels used, sums included, so the values are
the same to the bit.
"""
import numpy as np


def shape(xi, eta):
    """The four bilinear functions at (xi, eta) (4,); elementwise, so arrays of points give
    (4, *points)."""
    return np.array([0.25 * (1 - xi) * (1 - eta), 0.25 * (1 + xi) * (1 - eta),
                     0.25 * (1 + xi) * (1 + eta), 0.25 * (1 - xi) * (1 + eta)])


def shape_gradient(xi, eta, hx, hy):
    """Physical gradients (4, 2) on an hx by hy rectangle (1/m); elementwise, so arrays of
    points (and sizes broadcasting with them) give (4, 2, *points)."""
    return np.array([[-0.25 * (1 - eta) * 2 / hx, -0.25 * (1 - xi) * 2 / hy],
                     [0.25 * (1 - eta) * 2 / hx, -0.25 * (1 + xi) * 2 / hy],
                     [0.25 * (1 + eta) * 2 / hx, 0.25 * (1 + xi) * 2 / hy],
                     [-0.25 * (1 + eta) * 2 / hx, 0.25 * (1 - xi) * 2 / hy]])


def heaviside_basis(N, dN, side, node_side):
    """Shifted-Heaviside enriched functions and gradients at a point on ``side`` (0 or 1)."""
    shift = float(side) - np.asarray(node_side, dtype=np.float64)
    return N * shift, dN * shift[:, None]


def level_set_basis(N, dN, phi):
    """The modified-level-set enriched functions and their gradients (paper Eq. 6-7) at arrays
    of points: N (..., 4), dN (..., 4, 2) and the element's nodal level set phi (..., 4,
    broadcasting with N) give (N psi, dN psi + N grad psi), shaped as N and dN (one point: N
    (4,), dN (4, 2), phi (4,)). The cut elements' quadrature points, the fault's points and the
    injection point all take them from here; the sums run over the nodes in order (the values
    are part of the regression baseline)."""
    lin = np.zeros(np.broadcast_shapes(N.shape[:-1], phi.shape[:-1]))
    absn = np.zeros(lin.shape)
    glin = np.zeros(lin.shape + (2,))
    gabs = np.zeros(lin.shape + (2,))
    for i in range(4):
        lin += N[..., i] * phi[..., i]
        absn += N[..., i] * abs(phi[..., i])
        glin += dN[..., i, :] * phi[..., i, None]
        gabs += dN[..., i, :] * abs(phi[..., i, None])
    sgn = np.sign(lin)
    psi = (absn - abs(lin))[..., None]
    gpsi = gabs - sgn[..., None] * glin
    return N * psi, dN * psi[..., None] + N[..., None] * gpsi[..., None, :]

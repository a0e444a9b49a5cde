"""Bilinear shape functions and the two X-FEM enrichments at one point of a rectangle element.

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


def level_set_basis(N, dN, phi_e):
    """Modified-level-set enriched functions and gradients (paper Eq. 6-7)."""
    n, g, phi = N.tolist(), dN.tolist(), phi_e.tolist()
    lin = absn = 0.0
    glin, gabs = [0.0, 0.0], [0.0, 0.0]
    for i in range(4):   # (sums in this order: the value is part of the regression baseline)
        lin += n[i] * phi[i]
        absn += n[i] * abs(phi[i])
        for d in range(2):
            glin[d] += g[i][d] * phi[i]
            gabs[d] += g[i][d] * abs(phi[i])
    sgn = 1.0 if lin > 0 else (-1.0 if lin < 0 else 0.0)
    psi = absn - abs(lin)
    gpsi = np.array([gabs[0] - sgn * glin[0], gabs[1] - sgn * glin[1]])
    return N * psi, dN * psi + N[:, None] * gpsi[None, :]

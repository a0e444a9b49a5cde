"""Bilinear shape functions and the two X-FEM enrichments at one point of a rectangle element.

Displacement enrichment (paper Eq. 3-4): shifted Heaviside ``N_j (H(x) - H(x_j))``.
Pressure enrichment (Eq. 6-7): modified level set ``N_j (psi(x) - psi(x_j))`` with
``psi = sum N_i |phi_i| - |sum N_i phi_i|``; ``psi(x_j) = 0`` at every node, so the shift vanishes.
Both vanish outside cut elements, so there are no blending elements to correct.
"""
import numpy as np

from .._jit import kernel


@kernel
def shape(xi, eta):
    N = np.empty(4)
    N[0] = 0.25 * (1 - xi) * (1 - eta)
    N[1] = 0.25 * (1 + xi) * (1 - eta)
    N[2] = 0.25 * (1 + xi) * (1 + eta)
    N[3] = 0.25 * (1 - xi) * (1 + eta)
    return N


@kernel
def shape_gradient(xi, eta, hx, hy):
    """Physical gradients (4, 2) on an hx by hy rectangle (1/m)."""
    g = np.empty((4, 2))
    g[0, 0] = -0.25 * (1 - eta) * 2 / hx
    g[1, 0] = 0.25 * (1 - eta) * 2 / hx
    g[2, 0] = 0.25 * (1 + eta) * 2 / hx
    g[3, 0] = -0.25 * (1 + eta) * 2 / hx
    g[0, 1] = -0.25 * (1 - xi) * 2 / hy
    g[1, 1] = -0.25 * (1 + xi) * 2 / hy
    g[2, 1] = 0.25 * (1 + xi) * 2 / hy
    g[3, 1] = 0.25 * (1 - xi) * 2 / hy
    return g


@kernel
def heaviside_basis(N, dN, side, node_side):
    """Shifted-Heaviside enriched functions and gradients at a point on ``side`` (0 or 1)."""
    Ne = np.empty(4)
    dNe = np.empty((4, 2))
    for j in range(4):
        shift = side - node_side[j]
        Ne[j] = N[j] * shift
        dNe[j, 0] = dN[j, 0] * shift
        dNe[j, 1] = dN[j, 1] * shift
    return Ne, dNe


@kernel
def level_set_basis(N, dN, phi_e):
    """Modified-level-set enriched functions and gradients (paper Eq. 6-7)."""
    lin = 0.0
    absn = 0.0
    glin = np.zeros(2)
    gabs = np.zeros(2)
    for i in range(4):
        lin += N[i] * phi_e[i]
        absn += N[i] * abs(phi_e[i])
        for d in range(2):
            glin[d] += dN[i, d] * phi_e[i]
            gabs[d] += dN[i, d] * abs(phi_e[i])
    sgn = 1.0 if lin > 0 else (-1.0 if lin < 0 else 0.0)
    psi = absn - abs(lin)
    gpsi = np.empty(2)
    for d in range(2):
        gpsi[d] = gabs[d] - sgn * glin[d]
    Ne = np.empty(4)
    dNe = np.empty((4, 2))
    for j in range(4):
        Ne[j] = N[j] * psi
        for d in range(2):
            dNe[j, d] = dN[j, d] * psi + N[j] * gpsi[d]
    return Ne, dNe

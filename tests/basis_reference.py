"""The modified-level-set enrichment (paper Eq. 6-7) at one point, a sum at a time: the reference
that ``kernels.basis.level_set_basis`` (arrays of points) is checked against, to the bit (the
same sums over the nodes, in the same order)."""
import numpy as np


def level_set_basis_at_point(N, dN, phi_e):
    """(N psi, dN psi + N grad psi) at one point: N (4,), dN (4, 2), the element's nodal level
    set phi_e (4,); psi = sum N_i |phi_i| - |sum N_i phi_i|."""
    n, g, phi = N.tolist(), dN.tolist(), phi_e.tolist()
    lin = absn = 0.0
    glin, gabs = [0.0, 0.0], [0.0, 0.0]
    for i in range(4):
        lin += n[i] * phi[i]
        absn += n[i] * abs(phi[i])
        for d in range(2):
            glin[d] += g[i][d] * phi[i]
            gabs[d] += g[i][d] * abs(phi[i])
    sgn = 1.0 if lin > 0 else (-1.0 if lin < 0 else 0.0)
    psi = absn - abs(lin)
    gpsi = np.array([gabs[0] - sgn * glin[0], gabs[1] - sgn * glin[1]])
    return N * psi, dN * psi + N[:, None] * gpsi[None, :]

"""Biot poroelastic rock (paper Eq. 1-2, 8-9): local matrices of one element from basis values
tabulated at its quadrature points. Local displacement DOFs are interleaved (x, y) per basis
function; strain is Voigt (xx, yy, 2xy); stress tension-positive.

    K = int B^T D B,  Q = int B^T alpha m Np,  H = int grad Np^T (k/mu) grad Np,  S = int Np^T (1/M) Np
"""
import numpy as np

from .._jit import helper, kernel


def plane_strain_elasticity(youngs_modulus, poissons_ratio):
    """Drained plane-strain stiffness D (3x3), Pa (plain numpy: called once per zone at set-up,
    cheaper than compiling or loading a kernel)."""
    E, nu = youngs_modulus, poissons_ratio
    c = E / ((1 + nu) * (1 - 2 * nu))
    D = np.zeros((3, 3))
    D[0, 0] = D[1, 1] = c * (1 - nu)
    D[0, 1] = D[1, 0] = c * nu
    D[2, 2] = c * (1 - 2 * nu) / 2
    return D


@helper
def elastic_stiffness(gu, w, D):
    nq, nb = gu.shape[0], gu.shape[1]
    K = np.zeros((2 * nb, 2 * nb))
    B = np.zeros((3, 2 * nb))
    DB = np.empty((3, 2 * nb))
    for q in range(nq):
        if w[q] == 0.0:
            continue
        for b in range(nb):
            B[0, 2 * b] = gu[q, b, 0]
            B[1, 2 * b + 1] = gu[q, b, 1]
            B[2, 2 * b] = gu[q, b, 1]
            B[2, 2 * b + 1] = gu[q, b, 0]
        # B^T D B by loops: numba's matrix product brings BLAS's typing into the compilation
        # (8-10 MB of a cold start's memory for a 3 x 3 by 3 x 2nb product)
        for i in range(3):
            for b in range(2 * nb):
                DB[i, b] = D[i, 0] * B[0, b] + D[i, 1] * B[1, b] + D[i, 2] * B[2, b]
        for a in range(2 * nb):
            for b in range(2 * nb):
                K[a, b] += w[q] * (B[0, a] * DB[0, b] + B[1, a] * DB[1, b] + B[2, a] * DB[2, b])
    return K


@helper
def biot_coupling(gu, Np, w, biot_coefficient):
    """Q (2 nbu x nbp): volumetric strain of the skeleton against pore pressure."""
    nq, nbu, nbp = gu.shape[0], gu.shape[1], Np.shape[1]
    Q = np.zeros((2 * nbu, nbp))
    for q in range(nq):
        if w[q] == 0.0:
            continue
        for b in range(nbu):
            for c in range(nbp):
                f = w[q] * biot_coefficient * Np[q, c]
                Q[2 * b, c] += gu[q, b, 0] * f
                Q[2 * b + 1, c] += gu[q, b, 1] * f
    return Q


@helper
def darcy_conductance(gp, w, mobility):
    """H (nbp x nbp) with mobility = permeability / viscosity (m^2 / (Pa s))."""
    nq, nb = gp.shape[0], gp.shape[1]
    H = np.zeros((nb, nb))
    for q in range(nq):
        for a in range(nb):
            for b in range(nb):
                H[a, b] += w[q] * mobility * (gp[q, a, 0] * gp[q, b, 0] + gp[q, a, 1] * gp[q, b, 1])
    return H


@helper
def pore_storage(Np, w, inverse_biot_modulus):
    """S (nbp x nbp) with 1/M = (alpha - n)/Ks + n/Kf (1/Pa)."""
    nq, nb = Np.shape[0], Np.shape[1]
    S = np.zeros((nb, nb))
    for q in range(nq):
        for a in range(nb):
            for b in range(nb):
                S[a, b] += w[q] * inverse_biot_modulus * Np[q, a] * Np[q, b]
    return S


@kernel
def body_force(Nu, w, force_density):
    """Consistent nodal forces of a body force density (N/m^3) (2 nbu,)."""
    nq, nb = Nu.shape[0], Nu.shape[1]
    f = np.zeros(2 * nb)
    for q in range(nq):
        for b in range(nb):
            f[2 * b] += w[q] * Nu[q, b] * force_density[0]
            f[2 * b + 1] += w[q] * Nu[q, b] * force_density[1]
    return f


# ---- every element of a group in one compiled pass (arguments per element: leading axis e)
@helper
def _store(out, e, local):
    """out[e] = local, entry by entry: numba compiles an array slice assignment with the
    formatting of its shape-mismatch message (str, join), 3.5 s of a cold start."""
    for i in range(local.shape[0]):
        for j in range(local.shape[1]):
            out[e, i, j] = local[i, j]


@kernel
def elastic_stiffness_all(gu, w, D):
    n, nb = gu.shape[0], gu.shape[2]
    out = np.empty((n, 2 * nb, 2 * nb))
    for e in range(n):
        _store(out, e, elastic_stiffness(gu[e], w[e], D[e]))
    return out


@kernel
def biot_coupling_all(gu, Np, w, biot_coefficient):
    n = gu.shape[0]
    out = np.empty((n, 2 * gu.shape[2], Np.shape[2]))
    for e in range(n):
        _store(out, e, biot_coupling(gu[e], Np[e], w[e], biot_coefficient[e]))
    return out


@kernel
def darcy_conductance_all(gp, w, mobility):
    n, nb = gp.shape[0], gp.shape[2]
    out = np.empty((n, nb, nb))
    for e in range(n):
        _store(out, e, darcy_conductance(gp[e], w[e], mobility[e]))
    return out


@kernel
def pore_storage_all(Np, w, inverse_biot_modulus):
    n, nb = Np.shape[0], Np.shape[2]
    out = np.empty((n, nb, nb))
    for e in range(n):
        _store(out, e, pore_storage(Np[e], w[e], inverse_biot_modulus[e]))
    return out

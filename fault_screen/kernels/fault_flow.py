"""Flow along the fault (paper Eq. 10, 16), one Gauss point of the fault.

Per unit out-of-plane length: transmissivity (2h)^3 / (12 mu kappa) (cubic law over kappa,
m^3/(Pa s)), storativity 2h/Kf (m/Pa), and the opening rate of the fault as stored volume.
``Np``/``dNp_ds`` are the fault-pressure basis at the point, whatever discretisation carries it
(the trace of the enriched rock pressure, or the fault's own 1-D line).
"""
import numpy as np

from .._jit import kernel


@kernel
def cubic_law_transmissivity(hydraulic_aperture, viscosity, kappa):
    return hydraulic_aperture ** 3 / (12.0 * viscosity * kappa)


@kernel
def fault_conduction(dNp_ds, transmissivity, weight):
    nb = dNp_ds.shape[0]
    H = np.empty((nb, nb))
    for a in range(nb):
        for b in range(nb):
            H[a, b] = weight * transmissivity * dNp_ds[a] * dNp_ds[b]
    return H


@kernel
def fault_storage(Np, storativity, weight):
    nb = Np.shape[0]
    S = np.empty((nb, nb))
    for a in range(nb):
        for b in range(nb):
            S[a, b] = weight * storativity * Np[a] * Np[b]
    return S


@kernel
def opening_coupling(Np, N, normal, weight):
    """G (nbp x 8): int Np_a N_j n_c -- opening rate in the fault's mass balance, and (transposed)
    the push of fault pressure on its walls in the momentum balance."""
    nb = Np.shape[0]
    G = np.empty((nb, 8))
    for a in range(nb):
        for j in range(4):
            for c in range(2):
                G[a, 2 * j + c] = weight * Np[a] * N[j] * normal[c]
    return G

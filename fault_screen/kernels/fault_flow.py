"""Flow along the fault (paper Eq. 10, 16), one Gauss point of the fault.

Per unit out-of-plane length: transmissivity (2h)^3 / (12 mu kappa) (cubic law over kappa,
m^3/(Pa s)), storativity 2h/Kf (m/Pa), and the opening rate of the fault as stored volume.
``Np``/``dNp_ds`` are the fault-pressure basis at the point, whatever discretisation carries it
(the trace of the enriched rock pressure, or the fault's own 1-D line).
"""
import numpy as np

from .._jit import helper, kernel


@helper
def cubic_law_transmissivity(hydraulic_aperture, viscosity, kappa):
    return hydraulic_aperture ** 3 / (12.0 * viscosity * kappa)


# fault_conduction, fault_storage and opening_coupling are plain numpy: the set-up calls them
# once per fault point from Python, which costs less than compiling or loading a kernel; the
# products are formed in the order the compiled kernels used (same values to the bit)
def fault_conduction(dNp_ds, transmissivity, weight):
    return np.multiply.outer(weight * transmissivity * dNp_ds, dNp_ds)


def fault_storage(Np, storativity, weight):
    return np.multiply.outer(weight * storativity * Np, Np)


def opening_coupling(Np, N, normal, weight):
    """G (nbp x 8): int Np_a N_j n_c -- opening rate in the fault's mass balance, and (transposed)
    the push of fault pressure on its walls in the momentum balance. For every fault point at
    once with a leading axis of points (Np: points x nbp, N: points x 4, weight: points): one
    set of numpy passes instead of a call per point (the same products in the same order)."""
    wNp = np.asarray(weight)[..., None] * Np
    G = wNp[..., :, None, None] * N[..., None, :, None] * normal
    return G.reshape(*Np.shape, 8)


@helper
def renshaw_aperture(opening_change, aperture0, sigma_h):
    """Hydraulic aperture 2h from the mechanical opening change (paper Eq. 28, Renshaw 1995):
    2h = 2h0 + d exp(-ln(1 + (sigma_h/d)^2)/2) = 2h0 + d^2 / sqrt(d^2 + sigma_h^2) for d >= 0.
    Closing (d < 0, contact compressed further) uses the odd extension r(d) of that increment
    through 2h = 2h0 exp(r / 2h0): value and slope match at d = 0 and the aperture stays
    positive however hard the fault is pressed (floored at 1e-12 2h0). Returns (2h, d(2h)/dd)."""
    d = opening_change
    q = d * d + sigma_h * sigma_h
    if q == 0.0:
        return aperture0, 1.0 if sigma_h == 0.0 else 0.0
    root = np.sqrt(q)
    r = d * abs(d) / root
    dr = abs(d) * (d * d + 2.0 * sigma_h * sigma_h) / (q * root)
    if d >= 0.0:
        return aperture0 + r, dr
    e = np.exp(r / aperture0)
    if e < 1e-12:  # pressed shut: keep a residual aperture so that T > 0 and dT/T stays finite
        return aperture0 * 1e-12, 0.0
    return aperture0 * e, e * dr


@kernel
def assemble_evolving_conduction(x, opening, N, jump_dofs, Np, dNp_ds, p_dofs, normal, weight,
                                 aperture0, sigma_h, viscosity, kappa, time_weight, residual):
    """Fault conduction with the aperture of the current ``opening`` (Eq. 28) at every fault
    point: adds time_weight * int dNp/ds T(2h) dp/ds into ``residual`` and returns the values
    of the Jacobian (per point and fault-pressure row: its fault-pressure columns, then its
    Heaviside ones; physics.fault_flow.EvolvingApertureConduction.pattern gives them) and the
    aperture at every point."""
    ng, nbp = Np.shape
    per = nbp * nbp + nbp * 8
    vals = np.empty(ng * per)
    aperture = np.empty(ng)
    k = 0
    for g in range(ng):
        h, dh = renshaw_aperture(opening[g], aperture0, sigma_h)
        aperture[g] = h
        T = cubic_law_transmissivity(h, viscosity, kappa)
        dT = 3.0 * T / h * dh
        grad = 0.0
        for a in range(nbp):
            if p_dofs[g, a] >= 0:
                grad += dNp_ds[g, a] * x[p_dofs[g, a]]
        w = time_weight * weight[g]
        for a in range(nbp):
            ra = p_dofs[g, a]
            if ra < 0:
                continue
            residual[ra] += w * T * dNp_ds[g, a] * grad
            for b in range(nbp):
                if p_dofs[g, b] < 0:
                    continue
                vals[k] = w * T * dNp_ds[g, a] * dNp_ds[g, b]
                k += 1
            for j in range(4):
                for c in range(2):
                    if jump_dofs[g, 2 * j + c] < 0:
                        continue
                    vals[k] = w * dT * dNp_ds[g, a] * grad * N[g, j] * normal[c]
                    k += 1
    return vals[:k], aperture

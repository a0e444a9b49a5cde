"""Penalty contact with Coulomb friction on the fault (paper Eq. 19-27), one Gauss point.

Jump ``g = u(+) - u(-)`` in the fault frame: ``slip`` = g.t, ``opening`` = g.n (positive apart).
Contact traction on the fault plane: shear ``tau`` (along t, positive where it drives positive
slip) and effective normal stress ``sigma_n`` (compression positive). Both include the in-situ
values; the normal one is elastic and path-independent (sigma_n = sigma_n0 - kN * opening), so a
fault that opened and closes again picks up contact where it lost it; the shear one is
incremental from the last converged step (predictor-corrector return map).

No fastmath here: the stick / slip / open decisions are comparisons.
"""
import numpy as np

from .._jit import kernel

STICK, SLIP, OPEN = 0, 1, 2


@kernel
def coulomb_return_map(slip, opening, slip_old, tau_old, sigma_n0, normal_stiffness,
                       shear_stiffness, friction):
    """Returns (tau, sigma_n, state, dtau_dslip, dtau_dopening, dsigma_n_dopening)."""
    sigma_n = sigma_n0 - normal_stiffness * opening
    if not sigma_n > 0.0:  # also catches NaN: treat as open, never as a silent stick
        return 0.0, 0.0, OPEN, 0.0, 0.0, 0.0
    tau_trial = tau_old + shear_stiffness * (slip - slip_old)
    strength = friction * sigma_n
    if abs(tau_trial) <= strength:
        return tau_trial, sigma_n, STICK, shear_stiffness, 0.0, -normal_stiffness
    sgn = 1.0 if tau_trial > 0 else -1.0
    return (sgn * strength, sigma_n, SLIP, 0.0, -sgn * friction * normal_stiffness,
            -normal_stiffness)


@kernel
def contact_local(N, tangent, normal, tau, sigma_n, tau0, sigma_n0, dtau_dslip, dtau_dopening,
                  dsigma_dopening, weight):
    """Residual (8,) and tangent (8, 8) on the Heaviside DOFs of one cut element.

    The residual carries the change of contact traction from the in-situ state (the in-situ
    state is in equilibrium on its own): f_j = int N_j [(tau - tau0) t - (sigma_n - sigma_n0) n].
    """
    T = np.empty(2)
    for c in range(2):
        T[c] = (tau - tau0) * tangent[c] - (sigma_n - sigma_n0) * normal[c]
    # d(traction vector)/d(jump vector) = R^T C R with R = [t; n]
    C = np.empty((2, 2))
    for c in range(2):
        for d in range(2):
            C[c, d] = (tangent[c] * (dtau_dslip * tangent[d] + dtau_dopening * normal[d])
                       - normal[c] * dsigma_dopening * normal[d])
    r = np.zeros(8)
    k = np.zeros((8, 8))
    for i in range(4):
        for c in range(2):
            r[2 * i + c] = weight * N[i] * T[c]
            for j in range(4):
                for d in range(2):
                    k[2 * i + c, 2 * j + d] = weight * N[i] * N[j] * C[c, d]
    return r, k


@kernel
def assemble_contact(x, N, jump_dofs, tangent, normal, weight, slip_old, tau_old, sigma_n0, tau0,
                     normal_stiffness, shear_stiffness, friction, residual):
    """Contact forces of every fault Gauss point added into ``residual``; returns the tangent's
    COO triplets and the point-wise (slip, opening, tau, sigma_n, state)."""
    ng = N.shape[0]
    rows = np.empty(ng * 64, dtype=np.int64)
    cols = np.empty(ng * 64, dtype=np.int64)
    vals = np.empty(ng * 64)
    slip = np.empty(ng)
    opening = np.empty(ng)
    tau = np.empty(ng)
    sigma_n = np.empty(ng)
    state = np.empty(ng, dtype=np.int64)
    k = 0
    for g in range(ng):
        gx = 0.0
        gy = 0.0
        for i in range(4):
            dx = jump_dofs[g, 2 * i]
            dy = jump_dofs[g, 2 * i + 1]
            if dx >= 0:
                gx += N[g, i] * x[dx]
            if dy >= 0:
                gy += N[g, i] * x[dy]
        slip[g] = gx * tangent[0] + gy * tangent[1]
        opening[g] = gx * normal[0] + gy * normal[1]
        t, sn, st, dts, dto, dso = coulomb_return_map(
            slip[g], opening[g], slip_old[g], tau_old[g], sigma_n0[g], normal_stiffness,
            shear_stiffness, friction[g])
        tau[g] = t
        sigma_n[g] = sn
        state[g] = st
        r, kl = contact_local(N[g], tangent, normal, t, sn, tau0[g], sigma_n0[g], dts, dto, dso,
                              weight[g])
        for a in range(8):
            ra = jump_dofs[g, a]
            if ra < 0:
                continue
            residual[ra] += r[a]
            for b in range(8):
                cb = jump_dofs[g, b]
                if cb < 0 or kl[a, b] == 0.0:
                    continue
                rows[k] = ra
                cols[k] = cb
                vals[k] = kl[a, b]
                k += 1
    return rows[:k], cols[:k], vals[:k], slip, opening, tau, sigma_n, state

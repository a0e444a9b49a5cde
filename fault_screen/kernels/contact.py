"""Penalty contact with Coulomb friction on the fault (paper Eq. 19-27), one Gauss point.

Jump ``g = u(+) - u(-)`` in the fault frame: ``slip`` = g.t, ``opening`` = g.n (positive apart).
Contact traction on the fault plane: shear ``tau`` (along t, positive where it drives positive
slip) and effective normal stress ``sigma_n`` (compression positive). Both include the in-situ
values; the normal one is elastic and path-independent (sigma_n = sigma_n0 - kN * opening), so a
fault that opened and closes again picks up contact where it lost it; the shear one is
incremental from the last converged step (predictor-corrector return map).

No fastmath here: the stick / slip / open decisions are comparisons.

numba's on-disk cache of these kernels does not notice a change of the friction kernels they
call (kernels/friction.py): after changing those, touch this file (or clear __pycache__).
"""
import numpy as np

from .._jit import helper, kernel
from .friction import LARGE_PSI_OVER_A, aging_state, rate_state_friction

STICK, SLIP, OPEN = 0, 1, 2


@helper
def _slip_tangent(sgn, kT, kN, tan_dilation, mu, Fp):
    """Consistent derivatives of (tau, sigma_n) with respect to (slip, opening) while sliding,
    from the scalar return-map equation |tau_trial| - kT ds - mu sigma_n(ds) = 0 whose
    derivative in the plastic slip increment ds is -Fp."""
    dtau_ds = kT * (1.0 - kT / Fp)
    dtau_do = -sgn * kT * mu * kN / Fp
    dsig_ds = kN * tan_dilation * sgn * kT / Fp
    dsig_do = -kN + kN * tan_dilation * mu * kN / Fp
    return dtau_ds, dtau_do, dsig_ds, dsig_do


@helper
def _in_contact(sigma_base, tau_trial, kN, kT, tan_dilation):
    """Are the walls in contact at the end of the step? Tested on the normal stress after the
    step's own dilatant slip, not before it: the most plastic slip a step can take is
    |tau_trial| / kT (all of the trial shear relaxed), which raises sigma_n by kN tan(psi) times
    it, so the walls touch iff sigma_base + kN tan(psi) |tau_trial| / kT > 0. On that boundary the
    sliding branch gives sigma_n = tau = 0, the open state's tractions, so the law is continuous.
    Testing sigma_base alone (as before) made it jump at sigma_base = 0 from open (0, 0) to
    sliding at sigma_n = kN tan(psi) |tau_trial| / (kT + mu kN tan(psi)), up to MPa: Newton
    cycled between the two with dilation on (issue 9, stick-slip-cycling-dilation). Without
    dilation both tests agree. Also false for NaN: never a silent stick."""
    return sigma_base + kN * tan_dilation * abs(tau_trial) / kT > 0.0


@helper
def coulomb_point(slip, opening, slip_old, tau_old, dilatant_slip_old, sigma_n0, kN, kT, mu,
                  tan_dilation):
    """Rate-independent Coulomb return map with dilation.

    Returns (tau, sigma_n, state, plastic slip increment, dtau_ds, dtau_do, dsig_ds, dsig_do);
    sigma_n = sigma_n0 - kN (opening - tan(psi) * cumulative plastic slip)."""
    sigma_base = sigma_n0 - kN * opening + kN * tan_dilation * dilatant_slip_old
    tau_trial = tau_old + kT * (slip - slip_old)
    if not _in_contact(sigma_base, tau_trial, kN, kT, tan_dilation):
        return 0.0, 0.0, OPEN, 0.0, 0.0, 0.0, 0.0, 0.0
    if abs(tau_trial) <= mu * sigma_base:
        return tau_trial, sigma_base, STICK, 0.0, kT, 0.0, 0.0, -kN
    sgn = 1.0 if tau_trial > 0 else -1.0
    Fp = kT + mu * kN * tan_dilation
    ds = (abs(tau_trial) - mu * sigma_base) / Fp
    sigma_n = sigma_base + kN * tan_dilation * ds
    d = _slip_tangent(sgn, kT, kN, tan_dilation, mu, Fp)
    return sgn * mu * sigma_n, sigma_n, SLIP, ds, d[0], d[1], d[2], d[3]


@helper
def rate_state_point(slip, opening, slip_old, tau_old, dilatant_slip_old, theta_old, sigma_n0,
                     kN, kT, tan_dilation, mu0, a, b, V0, Dc, dt, slip_rate_threshold):
    """Viscoplastic return map with rate(-and-state) friction, spring kT in series.

    Solves |tau_trial| - kT ds = mu(V = ds/dt, theta(V)) sigma_n(ds) for the plastic slip
    increment ds in [0, |tau_trial|/kT] (safeguarded Newton: the left side falls and the right
    side is 0 at ds = 0). Returns (tau, sigma_n, state, ds, theta, mu, dtau_ds, dtau_do, dsig_ds,
    dsig_do); state is SLIP where the slip rate exceeds ``slip_rate_threshold``."""
    sigma_base = sigma_n0 - kN * opening + kN * tan_dilation * dilatant_slip_old
    tau_trial = tau_old + kT * (slip - slip_old)
    if not _in_contact(sigma_base, tau_trial, kN, kT, tan_dilation):
        return 0.0, 0.0, OPEN, 0.0, theta_old, 0.0, 0.0, 0.0, 0.0, 0.0
    Tt = abs(tau_trial)
    sgn = 1.0 if tau_trial >= 0 else -1.0
    lo, hi = 0.0, Tt / kT
    ds = 0.0
    # first guess: the creep over dt at which the law alone carries the trial shear stress
    # (a sigma asinh(V e) = |tau_trial|, the spring's relaxation kT ds neglected, the state at
    # theta_old). The root carries less shear, so this slightly overestimates it and Newton
    # comes back in ~2 iterations (Rustrel: 2.0 on average against 11 from ds = 0); a guess
    # outside (0, hi) (fast slip, an overflow) starts from 0
    psi0 = mu0 + (b * np.log(V0 * theta_old / Dc) if b != 0.0 else 0.0)
    if sigma_base > 0.0 and psi0 / a < LARGE_PSI_OVER_A:
        guess = dt * np.sinh(Tt / (a * sigma_base)) * (2.0 * V0) / np.exp(psi0 / a)
        if 0.0 < guess < hi:
            ds = guess
    theta = theta_old
    mu = 0.0
    Fp = kT
    for _ in range(200):
        V = ds / dt
        if b != 0.0:
            theta, dtheta_dV = aging_state(theta_old, V, dt, Dc)
        else:
            dtheta_dV = 0.0
        mu, dmu_dV, dmu_dtheta = rate_state_friction(V, theta, mu0, a, b, V0, Dc)
        sigma = sigma_base + kN * tan_dilation * ds
        F = Tt - kT * ds - mu * sigma
        Fp = kT + (dmu_dV + dmu_dtheta * dtheta_dV) / dt * sigma + mu * kN * tan_dilation
        if F > 0.0:
            lo = ds
        else:
            hi = ds
        if abs(F) <= 1e-13 * max(Tt, 1.0) or hi - lo <= 1e-15 * max(hi, 1e-300):
            break
        step = ds + F / Fp
        ds = step if lo < step < hi else 0.5 * (lo + hi)
    sigma_n = sigma_base + kN * tan_dilation * ds
    state = SLIP if ds / dt > slip_rate_threshold else STICK
    d = _slip_tangent(sgn, kT, kN, tan_dilation, mu, Fp)
    return sgn * (Tt - kT * ds), sigma_n, state, ds, theta, mu, d[0], d[1], d[2], d[3]


@helper
def contact_local_into(N, tangent, normal, tau, sigma_n, tau0, sigma_n0, dtau_ds, dtau_do,
                       dsig_ds, dsig_do, weight, r, k):
    """Residual r (8,) and tangent k (8, 8) on the Heaviside DOFs of one cut element, every
    entry written into the arrays given (a loop over the points reuses them: four small arrays
    allocated per point were a third of ``assemble_contact``).

    The residual carries the change of contact traction from the in-situ state (the in-situ
    state is in equilibrium on its own): f_j = int N_j [(tau - tau0) t - (sigma_n - sigma_n0) n].
    """
    T0 = (tau - tau0) * tangent[0] - (sigma_n - sigma_n0) * normal[0]
    T1 = (tau - tau0) * tangent[1] - (sigma_n - sigma_n0) * normal[1]
    # d(traction vector)/d(jump vector) = R^T C R with R = [t; n], C = d(tau, -sigma_n)/d(s, o)
    C00 = (tangent[0] * (dtau_ds * tangent[0] + dtau_do * normal[0])
           - normal[0] * (dsig_ds * tangent[0] + dsig_do * normal[0]))
    C01 = (tangent[0] * (dtau_ds * tangent[1] + dtau_do * normal[1])
           - normal[0] * (dsig_ds * tangent[1] + dsig_do * normal[1]))
    C10 = (tangent[1] * (dtau_ds * tangent[0] + dtau_do * normal[0])
           - normal[1] * (dsig_ds * tangent[0] + dsig_do * normal[0]))
    C11 = (tangent[1] * (dtau_ds * tangent[1] + dtau_do * normal[1])
           - normal[1] * (dsig_ds * tangent[1] + dsig_do * normal[1]))
    for i in range(4):
        for c in range(2):
            Tc = T0 if c == 0 else T1
            r[2 * i + c] = weight * N[i] * Tc
            for j in range(4):
                for d in range(2):
                    if c == 0:
                        Ccd = C00 if d == 0 else C01
                    else:
                        Ccd = C10 if d == 0 else C11
                    k[2 * i + c, 2 * j + d] = weight * N[i] * N[j] * Ccd


@kernel
def fault_jumps(x, N, jump_dofs, tangent, normal):
    """(slip, opening) at every fault Gauss point from the Heaviside DOFs."""
    ng = N.shape[0]
    slip = np.empty(ng)
    opening = np.empty(ng)
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
    return slip, opening


#: Layout of the friction parameter vector shared by both laws (SI): penalty stiffnesses kN, kT
#: (Pa/m), tan of the dilation angle, mu0, rate-and-state a, b, V0 (m/s), Dc (m) and the slip rate
#: above which a point counts as sliding (m/s). Coulomb reads the first four.
KN, KT, TAN_DILATION, MU0, RATE_A, STATE_B, V_REF, D_C, SLIDING_RATE = range(9)
#: Layout of the history (n_points, 4): converged total slip (m), shear traction (Pa), cumulative
#: plastic slip (m, drives dilation), rate-and-state state variable (s).
H_SLIP, H_TAU, H_DILATANT_SLIP, H_STATE = range(4)


@kernel
def coulomb_law(params, slip, opening, history, sigma_n0, dt):
    """Coulomb return map at every point.

    Both friction laws share this signature. Returns ``traction`` (n, 3: tau, sigma_n, friction
    coefficient), ``contact_state`` (n,), ``tangent`` (n, 4: dtau/dslip, dtau/dopening,
    dsigma_n/dslip, dsigma_n/dopening) and the new ``history`` (n, 4) if this state converges."""
    ng = slip.shape[0]
    traction = np.empty((ng, 3))
    contact_state = np.empty(ng, dtype=np.int64)
    tangent = np.empty((ng, 4))
    new_history = np.empty((ng, 4))
    mu = params[MU0]
    for g in range(ng):
        r = coulomb_point(slip[g], opening[g], history[g, H_SLIP], history[g, H_TAU],
                          history[g, H_DILATANT_SLIP], sigma_n0[g], params[KN], params[KT], mu,
                          params[TAN_DILATION])
        traction[g, 0], traction[g, 1], traction[g, 2] = r[0], r[1], mu
        contact_state[g] = r[2]
        tangent[g, 0], tangent[g, 1], tangent[g, 2], tangent[g, 3] = r[4], r[5], r[6], r[7]
        new_history[g, H_SLIP] = slip[g]
        new_history[g, H_TAU] = r[0]
        new_history[g, H_DILATANT_SLIP] = history[g, H_DILATANT_SLIP] + r[3]
        new_history[g, H_STATE] = history[g, H_STATE]
    return traction, contact_state, tangent, new_history


@kernel
def rate_state_law(params, slip, opening, history, sigma_n0, dt):
    """Rate(-and-state) return map at every point; same signature and returns as coulomb_law
    (the state variable evolves only when b = params[STATE_B] > 0)."""
    ng = slip.shape[0]
    traction = np.empty((ng, 3))
    contact_state = np.empty(ng, dtype=np.int64)
    tangent = np.empty((ng, 4))
    new_history = np.empty((ng, 4))
    for g in range(ng):
        r = rate_state_point(slip[g], opening[g], history[g, H_SLIP], history[g, H_TAU],
                             history[g, H_DILATANT_SLIP], history[g, H_STATE], sigma_n0[g],
                             params[KN], params[KT], params[TAN_DILATION], params[MU0],
                             params[RATE_A], params[STATE_B], params[V_REF], params[D_C], dt,
                             params[SLIDING_RATE])
        traction[g, 0], traction[g, 1], traction[g, 2] = r[0], r[1], r[5]
        contact_state[g] = r[2]
        tangent[g, 0], tangent[g, 1], tangent[g, 2], tangent[g, 3] = r[6], r[7], r[8], r[9]
        new_history[g, H_SLIP] = slip[g]
        new_history[g, H_TAU] = r[0]
        new_history[g, H_DILATANT_SLIP] = history[g, H_DILATANT_SLIP] + r[3]
        new_history[g, H_STATE] = r[4]
    return traction, contact_state, tangent, new_history


@kernel
def assemble_contact(N, jump_dofs, tangent_vec, normal_vec, weight, traction, tau0, sigma_n0,
                     point_tangent, residual):
    """Contact forces of every fault Gauss point added into ``residual``; returns the values of
    their tangent on the Heaviside DOFs, each pair of a point's DOFs (rows a, columns b, a then
    b in order), zeros included (physics.contact.Contact.pattern gives their rows and columns)."""
    ng = N.shape[0]
    vals = np.empty(ng * 64)
    r = np.empty(8)
    kl = np.empty((8, 8))
    k = 0
    for g in range(ng):
        contact_local_into(N[g], tangent_vec, normal_vec, traction[g, 0], traction[g, 1], tau0[g],
                           sigma_n0[g], point_tangent[g, 0], point_tangent[g, 1],
                           point_tangent[g, 2], point_tangent[g, 3], weight[g], r, kl)
        for a in range(8):
            ra = jump_dofs[g, a]
            if ra < 0:
                continue
            residual[ra] += r[a]
            for b in range(8):
                if jump_dofs[g, b] < 0:
                    continue
                vals[k] = kl[a, b]
                k += 1
    return vals[:k]

"""Friction laws of the fault (paper Eq. 18, 32) and the aging law of state, one point.

Rate (and state) friction is regularised near V = 0 by the arcsinh form (Rice, Lapusta &
Ranjith 2001):  mu = a asinh( V / (2 V0) exp(psi / a) ),  psi = mu0 + b ln(V0 theta / Dc).
For V >> V0 exp(-psi/a) it equals mu0 + a ln(V/V0) + b ln(V0 theta/Dc) to within
exp(-2 psi / a) relative (below 1e-20 for Rustrel's mu0/a ~ 25), but it stays finite, smooth
and increasing down to V = 0, where mu = 0: a fault at rest is not stuck but creeps at the rate
that its shear stress asks for, which is vanishingly small far below the strength. That makes the
return map a well-posed, smooth scalar equation at every point and every load.
"""
import numpy as np

from .._jit import helper


#: Small ``a`` (psi/a above 600, e.g. mu0/a = 6800 at a = 1e-4): exp(psi/a) overflows, so the law
#: is evaluated in logarithms, and below V_FLOOR (m/s) it is continued linearly to mu = 0 at V = 0.
#: There the regularised law is a step from 0 to mu0 + a ln(V/V0) at V ~ V0 exp(-psi/a), a rate
#: below the smallest float, whose slope overflows; 1e-30 m/s (3e-23 m a year) is far below any
#: creep the model could show. For the usual a (psi/a below 600) the closed form is used as is.
V_FLOOR = 1e-30
LARGE_PSI_OVER_A = 600.0


@helper
def _regularised_log(V, psi, dpsi_dtheta, a, V0):
    """(mu, dmu/dV, dmu/dtheta) of mu = a asinh(z), z = V exp(psi/a) / (2 V0), for V > 0, with z
    in logarithms (z itself is moderate wherever the fault slides)."""
    log_z = np.log(V) + psi / a - np.log(2.0 * V0)
    if log_z > 20.0:  # asinh(z) = ln(2z) + O(z^-2): the unregularised law, to round-off
        return a * (log_z + np.log(2.0)), a / V, dpsi_dtheta
    z = np.exp(log_z)
    root = np.sqrt(1.0 + z * z)
    return a * np.arcsinh(z), a * (z / V) / root, z / root * dpsi_dtheta


@helper
def rate_state_friction(V, theta, mu0, a, b, V0, Dc):
    """(mu, dmu/dV, dmu/dtheta) of the regularised law; theta is ignored when b == 0."""
    psi = mu0
    dpsi_dtheta = 0.0
    if b != 0.0:
        psi += b * np.log(V0 * theta / Dc)
        dpsi_dtheta = b / theta
    if psi / a >= LARGE_PSI_OVER_A:
        if V < V_FLOOR:  # linear to 0 below the floor: finite slope, still increasing
            mu, _, dmu_dtheta = _regularised_log(V_FLOOR, psi, dpsi_dtheta, a, V0)
            return mu * V / V_FLOOR, mu / V_FLOOR, dmu_dtheta * V / V_FLOOR
        return _regularised_log(V, psi, dpsi_dtheta, a, V0)
    e = np.exp(psi / a) / (2.0 * V0)
    z = V * e
    mu = a * np.arcsinh(z)
    root = np.sqrt(1.0 + z * z)
    dmu_dV = a * e / root
    dmu_dtheta = z / root * dpsi_dtheta
    return mu, dmu_dV, dmu_dtheta


@helper
def aging_state(theta_old, V, dt, Dc):
    """Aging law d(theta)/dt = 1 - V theta / Dc by backward Euler over dt:
    (theta_new, d theta_new / dV)."""
    denom = 1.0 + V * dt / Dc
    theta = (theta_old + dt) / denom
    return theta, -theta * (dt / Dc) / denom

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

from .._jit import kernel


@kernel
def rate_state_friction(V, theta, mu0, a, b, V0, Dc):
    """(mu, dmu/dV, dmu/dtheta) of the regularised law; theta is ignored when b == 0."""
    psi = mu0
    dpsi_dtheta = 0.0
    if b != 0.0:
        psi += b * np.log(V0 * theta / Dc)
        dpsi_dtheta = b / theta
    e = np.exp(psi / a) / (2.0 * V0)
    z = V * e
    mu = a * np.arcsinh(z)
    root = np.sqrt(1.0 + z * z)
    dmu_dV = a * e / root
    dmu_dtheta = z / root * dpsi_dtheta
    return mu, dmu_dV, dmu_dtheta


@kernel
def aging_state(theta_old, V, dt, Dc):
    """Aging law d(theta)/dt = 1 - V theta / Dc by backward Euler over dt:
    (theta_new, d theta_new / dV)."""
    denom = 1.0 + V * dt / Dc
    theta = (theta_old + dt) / denom
    return theta, -theta * (dt / Dc) / denom

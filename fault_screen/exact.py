"""Exact solutions of the verification families, for the tests and for ``fault-screen accuracy``.

Pure numpy / scipy, SI units; nothing here imports the simulator, so a reference computed here
stays independent of the code it checks (``tests/analytical.py`` re-exports these functions and
keeps the brute-force quadrature that cross-checks the slip shape).

1. Fault-parallel diffusion from a constant-pressure source: ``fault_diffusion_pressure``.
2. Self-similar fluid-driven frictional slip (Bhattacharya & Viesca 2019, Science 364:464;
   Viesca 2021, JFM 928): ``theta_function``, ``slip_front_lambda``, ``fluid_driven_slip_shape``,
   ``fluid_driven_slip``.

Pore pressure is the overpressure above the initial state (Pa); slip is the positive displacement
discontinuity in the sense of the initial shear stress (m).
"""
from __future__ import annotations

import numpy as np
from scipy import integrate, optimize, special

__all__ = ["fault_diffusion_pressure", "theta_function", "slip_front_lambda", "fluid_driven_slip_shape",
           "fluid_driven_slip", "KERNEL_CONSTANT"]

# ---------------------------------------------------------------------------
# 1. Fault-parallel diffusion
# ---------------------------------------------------------------------------

def fault_diffusion_pressure(x, t, *, dp, alpha):
    """p(x, t) = dp erfc(|x| / sqrt(4 alpha t)) (Pa).

    1-D diffusion along the fault with hydraulic diffusivity ``alpha``
    (m^2/s) from a constant overpressure ``dp`` (Pa) held at x = 0 from t = 0.
    ``x`` in m, ``t`` in s (t > 0).
    """
    x = np.asarray(x, float)
    t = np.asarray(t, float)
    return dp * special.erfc(np.abs(x) / np.sqrt(4.0 * alpha * t))


# ---------------------------------------------------------------------------
# 2. Self-similar fluid-driven frictional slip
# ---------------------------------------------------------------------------
#
# Fault pressure p = dp erfc(|x|/L), L = sqrt(4 alpha t).  Inside the slipping
# region |x| < a the shear stress equals f (sigma0 - p), so the stress drop
# relative to tau0 is
#     Delta_tau(x) = tau0 - f (sigma0 - p) = f dp (erfc(|x|/L) - T),
#     T = (f sigma0 - tau0)/(f dp).
# Plane-strain mode-II crack, slip vanishing at both tips:
#     delta(x) = (2(1-nu)/(pi G)) int_{-a}^{a} Delta_tau(s) K(x,s) ds,
#     K = (1/2) ln|(a^2 - xs + sqrt(a^2-x^2)sqrt(a^2-s^2))
#                  /(a^2 - xs - sqrt(a^2-x^2)sqrt(a^2-s^2))|.
# With x = a cos(th), s = a cos(t):  K = ln|sin((th+t)/2)/sin((th-t)/2)|
#                                      = sum_n (2/n) sin(n th) sin(n t),
# hence for uniform Delta_tau:  int K ds = a sum_n (2/n) sin(n th)
#     int_0^pi sin(n t) sin(t) dt = pi a sin(th) = pi sqrt(a^2-x^2),
# so the constant 2(1-nu)/(pi G) indeed yields the elliptical profile
# (2(1-nu) Delta_tau / G) sqrt(a^2-x^2).  (Checked numerically in the tests.)
# Bounded stress at the tips (zero K_II) requires
#     int_{-a}^{a} Delta_tau(s)/sqrt(a^2-s^2) ds = 0  <=>  Theta(lambda) = T.

#: prefactor of the log-kernel crack formula, in units of (1-nu)/G
KERNEL_CONSTANT = 2.0 / np.pi


def theta_function(r):
    """Theta(r) = (2/pi) int_0^{pi/2} erfc(r sin u) du (dimensionless).

    Theta(0) = 1, strictly decreasing, Theta(r) ~ 2/(pi^{3/2} r) as r -> inf,
    Theta(r) ~ 1 - 4 r/pi^{3/2} as r -> 0.  Vectorised over ``r`` (r >= 0).
    """
    def _one(rv):
        if rv == 0.0:
            return 1.0
        # integrand varies on the scale u ~ 1/r near u = 0: add a breakpoint
        pts = [min(np.pi / 2, 1.0 / rv)] if rv > 2 else None
        val, _ = integrate.quad(lambda u: special.erfc(rv * np.sin(u)), 0.0,
                                np.pi / 2, points=pts, epsabs=1e-14,
                                epsrel=1e-13, limit=200)
        return 2.0 / np.pi * val
    r = np.asarray(r, float)
    out = np.vectorize(_one, otypes=[float])(r)
    return out if out.ndim else float(out)


def slip_front_lambda(T):
    """Slip-front amplification lambda = a/L solving Theta(lambda) = T.

    Valid for 0 < T < 1.  Bracket: Theta(0) = 1 > T, and since
    sin u >= 2u/pi on [0, pi/2] and erfc is decreasing,
        Theta(r) <= (2/pi) int_0^{pi/2} erfc(2 r u/pi) du
                 <= (1/r) int_0^inf erfc(y) dy = 1/(sqrt(pi) r),
    so Theta(r_hi) < T for r_hi = 1.01/(sqrt(pi) T).  Theta is strictly
    decreasing, so the root in [0, r_hi] is unique.
    """
    T = float(T)
    if not 0.0 < T < 1.0:
        raise ValueError("slip_front_lambda requires 0 < T < 1")
    r_hi = 1.01 / (np.sqrt(np.pi) * T)
    return optimize.brentq(lambda r: theta_function(r) - T, 0.0, r_hi,
                           xtol=1e-14, rtol=1e-14, maxiter=200)


_N_GL = 1024      # Gauss-Legendre nodes on t in [0, pi/2] for the remainder
_N_REM = 401      # highest odd Chebyshev-sine mode for the (C^3) remainder


def _linear_part_shape(xi):
    """(1/pi) int_{-1}^{1} |s| K(xi,s) ds in closed form:
    (1/pi) [sqrt(1-xi^2) + xi^2 ln((1+sqrt(1-xi^2))/|xi|)]  (0 at xi=0 term).
    Verified against the sine series sum_{odd n} (b_n/n) sin(n th),
    b_n = -(4/pi) (-1)^{(n-1)/2} / (n^2-4), in the tests."""
    xi = np.abs(xi)
    r = np.sqrt(np.clip(1.0 - xi * xi, 0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        lg = np.where(xi > 0, xi * xi * np.log((1.0 + r) / np.where(xi > 0, xi, 1.0)), 0.0)
    return (r + lg) / np.pi


def fluid_driven_slip_shape(xi, lam, T):
    """Normalised slip  delta / (2(1-nu) f dp a / G)  as a function of
    xi = x/a (dimensionless), for stress drop f dp (erfc(lam |xi|) - T).

    Zero for |xi| >= 1.  ``lam`` should satisfy Theta(lam) = T for the
    physical (tip-regular) solution, but any pair is accepted (the result is
    then the log-kernel slip, which still vanishes at the tips).

    Method: g(xi) = erfc(lam|xi|) - T is split into
      (1 - T)                     -> shape (1-T) sqrt(1-xi^2)   [exact]
      -(2 lam/sqrt(pi)) |xi|      -> closed form (_linear_part_shape)
      remainder r(xi) = O(|xi|^3) -> Chebyshev-sine series, xi = cos th:
         shape = sum_{odd n} (b_n/n) sin(n th),
         b_n = (4/pi) int_0^{pi/2} r(cos t) sin t sin(n t) dt  (Gauss-Legendre).
    """
    xi = np.asarray(xi, float)
    inside = np.abs(xi) < 1.0
    xin = np.clip(xi, -1.0, 1.0)
    th = np.arccos(xin)

    # remainder coefficients
    tg, wg = np.polynomial.legendre.leggauss(_N_GL)
    tq = (tg + 1.0) * np.pi / 4.0
    wq = wg * np.pi / 4.0
    c = np.cos(tq)
    y = lam * c
    rem = special.erfc(y) - 1.0 + 2.0 * y / np.sqrt(np.pi)
    n = np.arange(1, _N_REM + 1, 2)
    bn = 4.0 / np.pi * (np.sin(np.outer(n, tq)) * (rem * np.sin(tq) * wq)).sum(axis=1)

    shape = (1.0 - T) * np.sin(th)
    shape = shape - 2.0 * lam / np.sqrt(np.pi) * _linear_part_shape(xin)
    shape = shape + (np.sin(np.multiply.outer(th, n)) * (bn / n)).sum(axis=-1)
    return np.where(inside, shape, 0.0)


def fluid_driven_slip(x, t, *, alpha, dp, f, T, shear_modulus, nu):
    """Self-similar slip delta(x, t) (m) of the fluid-driven frictional crack.

    Parameters
    ----------
    x : array_like   along-fault coordinate (m), source at x = 0
    t : float        time since pressurisation (s), t > 0
    alpha : float    hydraulic diffusivity (m^2/s); L = sqrt(4 alpha t)
    dp : float       injection overpressure held at x = 0 (Pa, > 0)
    f : float        constant friction coefficient (-)
    T : float        stress-injection parameter (f sigma0 - tau0)/(f dp), 0<T<1
    shear_modulus : float  G (Pa)
    nu : float       Poisson ratio (plane strain)

    Slip is in the direction of tau0, zero for |x| >= a = lambda(T) L.
    delta = (2(1-nu) f dp a / G) * fluid_driven_slip_shape(x/a, lambda, T).
    Limits: T -> 1- gives lambda ~ pi^{3/2}(1-T)/4 -> 0 (marginally
    pressurised; slip ~ lambda^2 L, with shape tending to that for a stress
    drop proportional to 2/pi - |xi|); T -> 0+ gives
    lambda ~ 2/(pi^{3/2} T) -> inf (critically stressed).
    """
    L = np.sqrt(4.0 * alpha * t)
    lam = slip_front_lambda(T)
    a = lam * L
    x = np.asarray(x, float)
    return 2.0 * (1.0 - nu) * f * dp * a / shear_modulus * \
        fluid_driven_slip_shape(x / a, lam, T)

"""Independent analytical reference solutions for verification tests.

Pure numpy / scipy, SI units throughout.  Nothing here imports the simulator
(sections 2 and 3 live in ``fault_screen/exact.py``, a pure-formula module that
imports no simulator code either, so ``fault-screen accuracy`` can use them).

Contents
--------
1. Terzaghi 1-D consolidation of a Biot poroelastic column (oedometric,
   lateral strain zero):  ``terzaghi_pressure``, ``terzaghi_settlement``,
   ``terzaghi_time_scale`` (+ helpers ``terzaghi_undrained_pressure``,
   ``terzaghi_consolidation_coefficient``, ``constrained_modulus``).
2. Fault-parallel diffusion from a constant-pressure source:
   ``fault_diffusion_pressure``.
3. Self-similar fluid-driven frictional slip (Bhattacharya & Viesca 2019,
   Science 364:464; Viesca 2021, JFM 928): ``theta_function``,
   ``slip_front_lambda``, ``fluid_driven_slip_shape``, ``fluid_driven_slip``
   (+ ``crack_slip_quad``, a brute-force quadrature of the log-kernel crack
   formula used as an independent cross-check).

Sign conventions
----------------
* Pore pressure ``p`` is the *overpressure* above the initial (hydrostatic)
  state, positive when the fluid pressure increases (Pa).
* Stresses are compression-positive where stated (applied ``load``,
  effective normal stress ``sigma0``); strains are extension-positive, so the
  volumetric strain of a compressed column is negative.
* Settlement is the downward displacement of the loaded top, positive
  downward (m).
* Slip ``delta`` is the (positive) displacement discontinuity in the sense of
  the initial shear stress ``tau0`` (m).
"""
from __future__ import annotations

import numpy as np
from scipy import integrate, optimize, special

__all__ = [
    "constrained_modulus",
    "terzaghi_undrained_pressure",
    "terzaghi_consolidation_coefficient",
    "terzaghi_time_scale",
    "terzaghi_pressure",
    "terzaghi_settlement",
    "fault_diffusion_pressure",
    "theta_function",
    "slip_front_lambda",
    "crack_log_kernel",
    "crack_slip_quad",
    "fluid_driven_slip_shape",
    "fluid_driven_slip",
    "KERNEL_CONSTANT",
]

# ---------------------------------------------------------------------------
# 1. Terzaghi consolidation
# ---------------------------------------------------------------------------
#
# Column 0 <= z <= H.  z = 0: fixed, impermeable.  z = H: drained (p = 0),
# total vertical stress -load (compression) applied at t = 0+.
#
# Oedometric constitutive law (extension-positive strain, compression-positive
# load, Biot effective stress sigma' = sigma_total - alpha p in compression):
#     load - alpha p = -Mc eps_v,     Mc = E (1-nu) / ((1+nu)(1-2nu))
# Fluid content change:   zeta = alpha eps_v + p / M
# Undrained (zeta = 0) at t = 0+:
#     alpha (-(load - alpha p)/Mc) + p/M = 0
#     => p_u = alpha M load / (Mc + alpha^2 M)
# Mass balance with Darcy q = -k/mu dp/dz and constant total stress:
#     (1/M + alpha^2/Mc) dp/dt = (k/mu) d2p/dz2   =>  c = (k/mu)/(1/M + alpha^2/Mc)
# Solution (eigenfunctions cos(l_m z/H), l_m = (2m+1) pi/2):
#     p = p_u sum_m 2 (-1)^m / l_m cos(l_m z/H) exp(-l_m^2 c t / H^2)
# Equivalent short-time (image) representation, tau = c t / H^2, zeta = z/H:
#     p/p_u = 1 - sum_{n>=0} (-1)^n [erfc((2n+1-zeta)/(2 sqrt tau))
#                                    + erfc((2n+1+zeta)/(2 sqrt tau))]
# Settlement (positive downward):
#     s = int_0^H (load - alpha p)/Mc dz = (load H - alpha int p dz)/Mc,
#     int_0^H p dz = p_u H U(tau),  U = sum_m 2/l_m^2 exp(-l_m^2 tau)
#                                   = 1 - 2 sqrt(tau)[1/sqrt(pi)
#                                         + 2 sum_{n>=1} (-1)^n ierfc(n/sqrt tau)]
# U(0) = 1 gives s(0+) = load H/(Mc + alpha^2 M); U(inf) = 0 gives load H/Mc.

_TAU_SWITCH = 0.1  # below this dimensionless time use the image series
_N_IMAGES = 30     # image terms: erfc((2n+1-1)/(2 sqrt(0.1))) negligible for n >= 6


def constrained_modulus(E, nu):
    """Oedometric (P-wave / constrained) drained modulus Mc (Pa)."""
    return E * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu))


def terzaghi_undrained_pressure(*, load, E, nu, biot, biot_modulus, **_):
    """Undrained overpressure p_u = alpha M load / (Mc + alpha^2 M) (Pa).

    ``load`` in Pa, positive = compression; returned p_u > 0 for a
    compressive load.
    """
    Mc = constrained_modulus(E, nu)
    return biot * biot_modulus * load / (Mc + biot**2 * biot_modulus)


def terzaghi_consolidation_coefficient(*, E, nu, biot, biot_modulus, mobility, **_):
    """Consolidation coefficient c = mobility / (1/M + alpha^2/Mc) (m^2/s).

    ``mobility`` = permeability / viscosity in m^2/(Pa s).
    """
    Mc = constrained_modulus(E, nu)
    return mobility / (1.0 / biot_modulus + biot**2 / Mc)


def terzaghi_time_scale(*, height, E, nu, biot, biot_modulus, mobility, **_):
    """Consolidation time scale H^2 / c (s)."""
    c = terzaghi_consolidation_coefficient(
        E=E, nu=nu, biot=biot, biot_modulus=biot_modulus, mobility=mobility)
    return height**2 / c


def _ierfc(x):
    """First repeated integral of erfc: exp(-x^2)/sqrt(pi) - x erfc(x)."""
    return np.exp(-x * x) / np.sqrt(np.pi) - x * special.erfc(x)


def _p_ratio_fourier(zeta, tau, n_terms):
    m = np.arange(n_terms)
    lam = (2 * m + 1) * np.pi / 2.0
    coef = 2.0 * (-1.0) ** m / lam
    terms = coef * np.cos(lam * zeta[..., None]) * np.exp(-lam**2 * tau[..., None])
    return terms.sum(axis=-1)


def _p_ratio_images(zeta, tau):
    n = np.arange(_N_IMAGES)
    sgn = (-1.0) ** n
    st = 2.0 * np.sqrt(tau)[..., None]
    z = zeta[..., None]
    terms = sgn * (special.erfc((2 * n + 1 - z) / st) + special.erfc((2 * n + 1 + z) / st))
    return 1.0 - terms.sum(axis=-1)


def terzaghi_pressure(z, t, *, height, load, E, nu, biot, biot_modulus, mobility,
                      n_terms=400):
    """Overpressure p(z, t) (Pa) in the Terzaghi column.

    Parameters
    ----------
    z : array_like
        Elevation above the fixed, impermeable base (m), 0 <= z <= height.
        The drained, loaded top is at z = height.
    t : array_like
        Time since the sudden load (s), t > 0.  Broadcast against ``z``.
    height : float   column height H (m)
    load : float     applied vertical total stress (Pa, compression positive)
    E, nu : float    drained Young's modulus (Pa) and Poisson ratio
    biot : float     Biot coefficient alpha (-)
    biot_modulus : float  Biot modulus M (Pa), 1/M = (alpha-n)/Ks + n/Kf
    mobility : float permeability / viscosity (m^2/(Pa s))
    n_terms : int    number of Fourier terms (used for c t / H^2 >= 0.1; for
                     earlier times the exact image series is used, which is
                     far better conditioned).

    Returns
    -------
    ndarray : overpressure (Pa), positive for a compressive load.
    """
    z, t = np.broadcast_arrays(np.asarray(z, float), np.asarray(t, float))
    if np.any(t <= 0):
        raise ValueError("terzaghi_pressure requires t > 0")
    p_u = terzaghi_undrained_pressure(load=load, E=E, nu=nu, biot=biot,
                                      biot_modulus=biot_modulus)
    c = terzaghi_consolidation_coefficient(E=E, nu=nu, biot=biot,
                                           biot_modulus=biot_modulus,
                                           mobility=mobility)
    zeta = z / height
    tau = c * t / height**2
    out = np.empty(z.shape)
    early = tau < _TAU_SWITCH
    if np.any(early):
        out[early] = _p_ratio_images(zeta[early], tau[early])
    if np.any(~early):
        out[~early] = _p_ratio_fourier(zeta[~early], tau[~early], n_terms)
    return p_u * out


def terzaghi_degree_remaining(tau, n_terms=400):
    """U(tau) = (1/(H p_u)) int_0^H p dz, fraction of the undrained
    overpressure still present (dimensionless; U(0)=1, U(inf)=0)."""
    tau = np.asarray(tau, float)
    out = np.empty(tau.shape)
    early = tau < _TAU_SWITCH
    te = tau[early]
    if te.size:
        n = np.arange(1, _N_IMAGES + 1)
        sq = np.sqrt(te)
        with np.errstate(divide="ignore", invalid="ignore"):
            ser = ((-1.0) ** n * _ierfc(n / sq[..., None])).sum(axis=-1)
        ser = np.where(sq > 0, ser, 0.0)  # ierfc(inf) = 0
        out[early] = 1.0 - 2.0 * sq * (1.0 / np.sqrt(np.pi) + 2.0 * ser)
    tl = tau[~early]
    if tl.size:
        m = np.arange(n_terms)
        lam = (2 * m + 1) * np.pi / 2.0
        out[~early] = (2.0 / lam**2 * np.exp(-lam**2 * tl[..., None])).sum(axis=-1)
    return out


def terzaghi_settlement(t, *, height, load, E, nu, biot, biot_modulus, mobility,
                        n_terms=400):
    """Downward displacement of the loaded top (m, positive downward).

    s(t) = [load H - alpha p_u H U(c t/H^2)] / Mc; s(0+) = load H/(Mc+alpha^2 M)
    (instantaneous undrained settlement), s(inf) = load H / Mc (drained).
    ``t`` (s) may be an array; t = 0 returns the undrained (0+) value.
    Units/arguments as in :func:`terzaghi_pressure`.
    """
    t = np.asarray(t, float)
    Mc = constrained_modulus(E, nu)
    p_u = terzaghi_undrained_pressure(load=load, E=E, nu=nu, biot=biot,
                                      biot_modulus=biot_modulus)
    c = terzaghi_consolidation_coefficient(E=E, nu=nu, biot=biot,
                                           biot_modulus=biot_modulus,
                                           mobility=mobility)
    U = terzaghi_degree_remaining(c * t / height**2, n_terms=n_terms)
    return (load * height - biot * p_u * height * U) / Mc


# ---------------------------------------------------------------------------
# 2. Fault-parallel diffusion and 3. self-similar fluid-driven frictional slip:
#    in fault_screen/exact.py (pure numpy/scipy, no simulator import), which
#    `fault-screen accuracy` uses as its exact reference too. The brute-force
#    crack quadrature below cross-checks its slip shape independently.
# ---------------------------------------------------------------------------
from fault_screen.exact import (  # noqa: E402
    KERNEL_CONSTANT, _linear_part_shape, fault_diffusion_pressure, fluid_driven_slip,
    fluid_driven_slip_shape, slip_front_lambda, theta_function)


def crack_log_kernel(xi, s):
    """Dimensionless log kernel K(xi, s) for a crack on |xi|, |s| < 1
    (a = 1):  (1/2) ln|(1 - xi s + q)/(1 - xi s - q)|, q = sqrt(1-xi^2)sqrt(1-s^2),
    evaluated as ln((1 - xi s + q)/|xi - s|) using
    (1 - xi s)^2 - q^2 = (xi - s)^2.
    """
    q = np.sqrt(np.clip(1.0 - xi * xi, 0, None)) * np.sqrt(np.clip(1.0 - s * s, 0, None))
    num = 1.0 - xi * s + q
    # 1 - xi s - q = (xi - s)^2 / num  (exact identity; avoids cancellation)
    return np.log(num / np.abs(xi - s))


def crack_slip_quad(x, a, stress_drop, *, shear_modulus, nu, breakpoints=()):
    """Brute-force slip of a plane-strain mode-II crack (m) by adaptive
    quadrature of the log-kernel formula (independent cross-check; slow).

    delta(x) = (2(1-nu)/(pi G)) int_{-a}^{a} stress_drop(s) K(x,s) ds.
    ``stress_drop`` : callable (Pa) of s (m).  ``breakpoints``: extra
    non-smooth points of ``stress_drop`` (m).
    """
    pref = KERNEL_CONSTANT * (1.0 - nu) / shear_modulus
    x = np.atleast_1d(np.asarray(x, float))
    out = np.zeros(x.shape)
    for i, xv in enumerate(x):
        if abs(xv) >= a:
            continue
        xi = xv / a
        pts = sorted({xi, *[b / a for b in breakpoints if -a < b < a]})
        edges = [-1.0, *pts, 1.0]
        tot = 0.0
        for lo, hi in zip(edges[:-1], edges[1:]):
            if hi <= lo:
                continue
            v, _ = integrate.quad(
                lambda sg: stress_drop(sg * a) * crack_log_kernel(xi, sg),
                lo, hi, epsabs=1e-13, epsrel=1e-12, limit=200)
            tot += v
        out[i] = pref * a * tot
    return out

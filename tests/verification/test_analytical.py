"""Self-checks of the analytical reference solutions in ``analytical.py``
against independent facts (published values, limits, governing equations)."""
import os
import sys

import numpy as np
import pytest
from scipy import special

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # tests/analytical.py
import analytical as A  # noqa: E402

# Representative poroelastic column (SI)
TZ = dict(height=10.0, load=1.0e6, E=1.0e10, nu=0.25, biot=0.8,
          biot_modulus=2.0e10, mobility=1.0e-15 / 1.0e-3)
TZ_NOLOAD = {k: v for k, v in TZ.items() if k != "load"}


def _mc():
    return A.constrained_modulus(TZ["E"], TZ["nu"])


# ---------------------------------------------------------------- slip front
@pytest.mark.parametrize("T, lam_pub", [(0.4, 1.0252441), (0.2, 1.9125140)])
def test_published_lambda(T, lam_pub):
    # Bhattacharya & Viesca 2019 published values, quoted to 7-8 digits
    assert A.slip_front_lambda(T) == pytest.approx(lam_pub, abs=1e-6)


def test_lambda_asymptotes():
    # T->1: Theta(r) ~ 1 - 4r/pi^1.5 ; rel. 1e-3 since O(r^2) correction ~ 1e-3
    T = 0.999
    assert A.slip_front_lambda(T) == pytest.approx(np.pi**1.5 * (1 - T) / 4, rel=1e-3)
    # T->0: Theta(r) ~ 2/(pi^1.5 r) ; correction O(1/r^3) -> rel 1e-3 is generous
    T = 1e-3
    assert A.slip_front_lambda(T) == pytest.approx(2 / (np.pi**1.5 * T), rel=1e-3)


def test_theta_limits():
    # Theta(0) = 1 exactly (erfc(0) = 1); machine precision
    assert A.theta_function(0.0) == pytest.approx(1.0, abs=1e-14)
    # Root really solves Theta(lambda) = T; brentq tolerance 1e-12
    lam = A.slip_front_lambda(0.7)
    assert A.theta_function(lam) == pytest.approx(0.7, abs=1e-12)


# ---------------------------------------------------------- crack kernel
def test_uniform_stress_drop_is_elliptical():
    # Classical elliptical slip for uniform stress drop fixes the 2(1-nu)/(pi G)
    # constant; quadrature accuracy ~1e-12 so rel. 1e-6 is safe.
    a, dtau, G, nu = 2.0, 3.0e6, 3.0e10, 0.25
    x = np.array([-1.99, -1.3, -0.2, 0.0, 0.7, 1.5, 1.999])
    d = A.crack_slip_quad(x, a, lambda s: dtau + 0 * s, shear_modulus=G, nu=nu)
    ref = 2 * (1 - nu) * dtau / G * np.sqrt(a**2 - x**2)
    np.testing.assert_allclose(d, ref, rtol=1e-6)
    # spectral shape with lam = 0 is uniform drop (1 - T): same ellipse, rel 1e-10
    xi = x / a
    np.testing.assert_allclose(A.fluid_driven_slip_shape(xi, 0.0, 0.3),
                               0.7 * np.sqrt(1 - xi**2), rtol=1e-10)


def test_linear_part_closed_form_vs_series():
    # closed form for stress drop |s| vs exact Chebyshev-sine series (n^-3 tail
    # with 2e4 modes -> error < 1e-9)
    xi = np.array([-0.95, -0.5, 0.0, 0.3, 0.8, 0.999])
    th = np.arccos(xi)
    n = np.arange(1, 40001, 2)
    bn = -4 / np.pi * (-1.0) ** ((n - 1) // 2) / (n**2 - 4.0)
    ser = (bn / n * np.sin(np.multiply.outer(th, n))).sum(axis=1)
    np.testing.assert_allclose(A._linear_part_shape(xi), ser, atol=1e-9)


def test_spectral_slip_matches_direct_quadrature():
    # Two independent evaluations of the same integral; agreement ~1e-10,
    # tolerance 1e-8 absolute on an O(0.3) shape.
    T = 0.4
    lam = A.slip_front_lambda(T)
    xi = np.array([-0.9, -0.25, 0.0, 0.5, 0.97])
    shape = A.fluid_driven_slip_shape(xi, lam, T)
    q = A.crack_slip_quad(xi, 1.0, lambda s: special.erfc(lam * abs(s)) - T,
                          shear_modulus=1.0, nu=0.0, breakpoints=[0.0]) / 2.0
    np.testing.assert_allclose(shape, q, atol=1e-8)


def test_self_similar_slip_profile():
    alpha, dp, f, T, G, nu, t = 1e-2, 5e6, 0.6, 0.4, 3e10, 0.25, 1e4
    L = np.sqrt(4 * alpha * t)
    a = A.slip_front_lambda(T) * L
    x = np.linspace(-1.2 * a, 1.2 * a, 241)
    d = A.fluid_driven_slip(x, t, alpha=alpha, dp=dp, f=f, T=T,
                            shear_modulus=G, nu=nu)
    scale = 2 * (1 - nu) * f * dp * a / G
    # zero outside and at the tips (exactly, by construction)
    assert np.all(d[np.abs(x) >= a] == 0.0)
    edge = A.fluid_driven_slip(np.array([-a, a]), t, alpha=alpha, dp=dp, f=f,
                               T=T, shear_modulus=G, nu=nu)
    assert np.all(np.abs(edge) <= 1e-12 * scale)
    # maximal at x = 0 (symmetric profile, monotone away from the source)
    assert np.argmax(d) == 120 and x[120] == 0.0
    assert np.all(d > -1e-15 * scale)
    inner = np.abs(x) < a
    right = d[inner & (x >= 0)]
    assert np.all(np.diff(right) < 0)
    # symmetric to round-off (rel 1e-12)
    np.testing.assert_allclose(d, d[::-1], rtol=0, atol=1e-12 * scale)
    # self-similarity: delta / L depends on x / L only (rel 1e-12)
    d4 = A.fluid_driven_slip(2 * x, 4 * t, alpha=alpha, dp=dp, f=f, T=T,
                             shear_modulus=G, nu=nu)
    np.testing.assert_allclose(d4, 2 * d, rtol=1e-12, atol=1e-14 * scale)


def test_tip_regularity():
    # Theta(lambda)=T kills K_II: slip ~ (1-xi)^{3/2} near the tip, so the ratio
    # delta(1-e)/delta(1-4e) -> 4^{-3/2}=1/8 (vs 1/2 for a sqrt tip); 2% tol
    # covers O(e) corrections at e = 1e-4.
    T = 0.4
    lam = A.slip_front_lambda(T)
    e = 1e-4
    d = A.fluid_driven_slip_shape(np.array([1 - e, 1 - 4 * e]), lam, T)
    assert d[0] / d[1] == pytest.approx(1 / 8, rel=2e-2)
    # with an inconsistent lambda the tip is sqrt-like: ratio -> 1/2 (2% tol)
    d = A.fluid_driven_slip_shape(np.array([1 - e, 1 - 4 * e]), 0.5 * lam, T)
    assert d[0] / d[1] == pytest.approx(1 / 2, rel=2e-2)


# ---------------------------------------------------------------- Terzaghi
def test_terzaghi_early_time_uniform_pressure():
    # at tau = 1e-6 the diffusion length is 2e-3 H; away from the top p = p_u
    # to exponentially small error (rel 1e-10)
    p_u = A.terzaghi_undrained_pressure(**TZ)
    Mc = _mc()
    assert p_u == pytest.approx(TZ["biot"] * TZ["biot_modulus"] * TZ["load"]
                                / (Mc + TZ["biot"]**2 * TZ["biot_modulus"]), rel=1e-14)
    t = 1e-6 * A.terzaghi_time_scale(**TZ_NOLOAD)
    z = np.linspace(0, 0.9 * TZ["height"], 10)
    np.testing.assert_allclose(A.terzaghi_pressure(z, t, **TZ), p_u, rtol=1e-10)
    # drained top: p = 0 (abs 1e-9 p_u)
    assert abs(A.terzaghi_pressure(TZ["height"], t, **TZ)) < 1e-9 * p_u


def test_terzaghi_late_time_and_settlement_limits():
    H, load = TZ["height"], TZ["load"]
    Mc = _mc()
    M, al = TZ["biot_modulus"], TZ["biot"]
    ts = A.terzaghi_time_scale(**TZ_NOLOAD)
    # t -> 0+: undrained settlement load H/(Mc + alpha^2 M); image series exact
    assert A.terzaghi_settlement(1e-12 * ts, **TZ) == pytest.approx(
        load * H / (Mc + al**2 * M), rel=1e-5)  # O(sqrt(tau)) ~ 1e-6 drift
    # t -> inf: drained settlement load H/Mc; exp(-pi^2/4 * 20) ~ 1e-22
    assert A.terzaghi_settlement(20 * ts, **TZ) == pytest.approx(load * H / Mc, rel=1e-12)
    # pressure fully dissipated at late time (abs 1e-12 p_u)
    p_u = A.terzaghi_undrained_pressure(**TZ)
    assert np.all(np.abs(A.terzaghi_pressure(np.linspace(0, H, 5), 20 * ts, **TZ))
                  < 1e-12 * p_u)
    # monotone settlement growth
    s = A.terzaghi_settlement(np.logspace(-6, 1, 50) * ts, **TZ)
    assert np.all(np.diff(s) > 0)


def test_terzaghi_series_representations_agree():
    # Fourier (n_terms=400) and image series are independent expansions of the
    # same solution; at tau just either side of the switch they agree to 1e-10.
    ts = A.terzaghi_time_scale(**TZ_NOLOAD)
    z = np.linspace(0, TZ["height"], 11)
    tau = 0.1
    four = A._p_ratio_fourier(z / TZ["height"], np.full(z.shape, tau), 400)
    img = A._p_ratio_images(z / TZ["height"], np.full(z.shape, tau))
    np.testing.assert_allclose(four, img, atol=1e-10)
    U_img = A.terzaghi_degree_remaining(np.array([0.0999999999]))
    U_four = A.terzaghi_degree_remaining(np.array([0.1]))
    assert U_img[0] == pytest.approx(U_four[0], abs=1e-9)
    assert ts > 0


@pytest.mark.parametrize("tau", [0.02, 0.3])
def test_terzaghi_diffusion_equation(tau):
    # central FD of dp/dt and d2p/dz2 at an interior point: O(h^2) ~ 1e-6 error,
    # checked to 1e-4 relative
    c = A.terzaghi_consolidation_coefficient(**TZ_NOLOAD)
    H = TZ["height"]
    t = tau * H**2 / c
    z = 0.6 * H
    ht, hz = 1e-3 * t, 1e-3 * H
    p = lambda zz, tt: A.terzaghi_pressure(zz, tt, **TZ)  # noqa: E731
    dpdt = (p(z, t + ht) - p(z, t - ht)) / (2 * ht)
    d2p = (p(z + hz, t) - 2 * p(z, t) + p(z - hz, t)) / hz**2
    assert dpdt == pytest.approx(c * d2p, rel=1e-4)
    # impermeable base: dp/dz = 0 at z = 0 (one-sided FD, abs tol ~ h*|p_zz|)
    g0 = (p(hz, t) - p(0.0, t)) / hz
    assert abs(g0) < 1e-3 * A.terzaghi_undrained_pressure(**TZ) / H


def test_fault_diffusion_pressure():
    # erfc profile: dp at the source, dp*erfc(1) at |x| = L (rel 1e-14)
    dp, al, t = 2e6, 1e-3, 100.0
    L = np.sqrt(4 * al * t)
    p = A.fault_diffusion_pressure(np.array([0.0, L, -L]), t, dp=dp, alpha=al)
    np.testing.assert_allclose(p, dp * np.array([1, special.erfc(1), special.erfc(1)]),
                               rtol=1e-14)

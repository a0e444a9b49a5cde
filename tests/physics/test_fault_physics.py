"""Eq. 17-27, 32 (contact, friction, dilation) and Eq. 28: each fault term against something
independent: hand-computed return maps, finite-difference tangents, Renshaw's formula and its
limits, steady-state rate-and-state friction and the aging law's steady state."""
import numpy as np
import pytest

from fault_screen.kernels.contact import OPEN, SLIP, STICK, coulomb_point, rate_state_point
from fault_screen.kernels.fault_flow import renshaw_aperture
from fault_screen.kernels.friction import aging_state, rate_state_friction

KN, KT = 2.0e10, 1.0e10


def test_coulomb_stick_slip_open_by_hand():
    # stick: |tau_trial| = 5e6 + 1e10 * 1e-5 = 5.1e6 < 0.6 * (1e7 + 2e10 * 1e-5) = 6.12e6
    tau, sn, st, ds, *_ = coulomb_point(1e-5, -1e-5, 0.0, 5e6, 0.0, 1e7, KN, KT, 0.6, 0.0)
    assert st == STICK and tau == pytest.approx(5.1e6) and sn == pytest.approx(1.02e7) and ds == 0
    # slip: tau_trial = 5e6 + 1e10 * 2e-4 = 7e6 > 0.6 * 1.02e7 = 6.12e6
    tau, sn, st, ds, *_ = coulomb_point(2e-4, -1e-5, 0.0, 5e6, 0.0, 1e7, KN, KT, 0.6, 0.0)
    assert st == SLIP and tau == pytest.approx(6.12e6) and ds == pytest.approx((7e6 - 6.12e6) / KT)
    # open: the opening exceeds what the in-situ compression can close
    tau, sn, st, *_ = coulomb_point(0.0, 6e-4, 0.0, 5e6, 0.0, 1e7, KN, KT, 0.6, 0.0)
    assert st == OPEN and tau == 0.0 and sn == 0.0


def test_coulomb_with_dilation_by_hand():
    # slipping with tan(psi) = 0.2: ds = (|tau_trial| - mu sigma_base) / (kT + mu kN tan(psi)),
    # sigma_n = sigma_base + kN tan(psi) ds, tau = mu sigma_n
    tp = 0.2
    tau, sn, st, ds, *_ = coulomb_point(2e-4, -1e-5, 0.0, 5e6, 0.0, 1e7, KN, KT, 0.6, tp)
    ds_hand = (7e6 - 0.6 * 1.02e7) / (KT + 0.6 * KN * tp)
    assert st == SLIP and ds == pytest.approx(ds_hand, rel=1e-12)
    assert sn == pytest.approx(1.02e7 + KN * tp * ds_hand, rel=1e-12)
    assert tau == pytest.approx(0.6 * sn, rel=1e-12)
    # cumulative dilatant slip of earlier steps raises sigma_n of a fixed opening
    _, sn2, *_ = coulomb_point(0.0, -1e-5, 0.0, 0.0, 1e-3, 1e7, KN, KT, 0.6, tp)
    assert sn2 == pytest.approx(1.02e7 + KN * tp * 1e-3, rel=1e-12)


def _fd_tangent(fn, slip, opening, h=1e-9):
    """Finite-difference d(tau, sigma_n)/d(slip, opening)."""
    out = np.zeros(4)
    for k, (ds_, do_) in enumerate(((h, 0), (0, h))):
        p = fn(slip + ds_, opening + do_)
        m = fn(slip - ds_, opening - do_)
        out[k] = (p[0] - m[0]) / (2 * h)          # dtau/d(slip or opening)
        out[2 + k] = (p[1] - m[1]) / (2 * h)      # dsigma/d(...)
    return out[[0, 1, 2, 3]]


@pytest.mark.parametrize("tp", [0.0, 0.3])
def test_coulomb_tangent_is_consistent(tp):
    fn = lambda s, o: coulomb_point(s, o, 0.0, 5e6, 1e-4, 1e7, KN, KT, 0.6, tp)
    r = fn(2e-4, -1e-5)
    analytic = np.array([r[4], r[5], r[6], r[7]])
    assert np.allclose(analytic, _fd_tangent(fn, 2e-4, -1e-5), rtol=1e-5, atol=1e-3 * KT * 1e-3)


@pytest.mark.parametrize("b", [0.0, 0.015])
def test_rate_state_tangent_is_consistent(b):
    args = dict(theta_old=0.5, sigma_n0=1e7, kN=KN, kT=KT, tan_dilation=0.1, mu0=0.6, a=0.01,
                b=b, V0=1e-6, Dc=1e-4, dt=1.0, slip_rate_threshold=1e-9)
    fn = lambda s, o: rate_state_point(s, o, 0.0, 5.9e6, 0.0, *args.values())
    r = fn(3e-4, -1e-5)
    assert r[2] == SLIP
    analytic = np.array([r[6], r[7], r[8], r[9]])
    fd = _fd_tangent(fn, 3e-4, -1e-5, h=1e-10)
    assert np.allclose(analytic, fd, rtol=1e-4, atol=1e2)


def test_renshaw_matches_eq28_and_its_limits():
    """Eq. 28 (Renshaw aperture): the paper's form to 1e-14, its small- and large-slip limits, and a
    positive aperture with a continuous slope on closing."""
    h0, sh = 5e-5, 2e-4
    for d in (1e-6, 3e-5, 2e-4, 5e-3):
        eq28 = h0 + d * np.exp(-np.log(1 + (sh / d) ** 2) / 2)  # paper's form, written out
        assert renshaw_aperture(d, h0, sh)[0] == pytest.approx(eq28, rel=1e-14)
    assert renshaw_aperture(1e-3, h0, 0.0)[0] == pytest.approx(h0 + 1e-3, rel=1e-14)   # smooth plates
    d = 1e-7  # d << sigma_h: 2h0 + d^2 / sigma_h
    assert renshaw_aperture(d, h0, sh)[0] - h0 == pytest.approx(d * d / sh, rel=1e-6)
    d = 1e-1  # d >> sigma_h: 2h0 + d - sigma_h^2 / (2 d)
    assert renshaw_aperture(d, h0, sh)[0] - h0 == pytest.approx(d - sh * sh / (2 * d), rel=1e-9)
    # closing keeps the aperture positive and the slope continuous at zero
    assert 0 < renshaw_aperture(-1.0, h0, sh)[0] < h0
    for d in (-3e-5, -1e-6, 0.0, 1e-6, 3e-5):
        eps = 1e-10
        fd = (renshaw_aperture(d + eps, h0, sh)[0] - renshaw_aperture(d - eps, h0, sh)[0]) / (2 * eps)
        assert renshaw_aperture(d, h0, sh)[1] == pytest.approx(fd, rel=1e-4, abs=1e-6)


@pytest.mark.parametrize("V", [1e-9, 1e-7, 1e-5, 1e-3])
def test_steady_sliding_friction_is_mu0_plus_a_ln(V):
    mu0, a, V0 = 0.68, 2.69e-2, 1e-7
    mu, *_ = rate_state_friction(V, 1.0, mu0, a, 0.0, V0, 1e-4)
    assert mu == pytest.approx(mu0 + a * np.log(V / V0), rel=1e-12)
    # with state at its steady value Dc/V: mu0 + (a - b) ln(V/V0)
    b, Dc = 0.02, 1e-4
    mu, *_ = rate_state_friction(V, Dc / V, mu0, a, b, V0, Dc)
    assert mu == pytest.approx(mu0 + (a - b) * np.log(V / V0), rel=1e-12)


def test_regularised_friction_is_finite_and_increasing_at_rest():
    mus = [rate_state_friction(V, 1.0, 0.6, 0.01, 0.0, 1e-6, 1e-4)[0] for V in (0.0, 1e-30, 1e-20)]
    assert mus[0] == 0.0 and 0.0 < mus[1] < mus[2]


def test_aging_law_relaxes_to_dc_over_v():
    V, Dc = 1e-6, 1e-4
    theta = 10.0
    for _ in range(6000):  # 60 relaxation times
        theta, _ = aging_state(theta, V, 1.0, Dc)
    assert theta == pytest.approx(Dc / V, rel=1e-10)
    # transient: exact theta(t) = Dc/V + (theta0 - Dc/V) exp(-V t / Dc); backward Euler with
    # dt = 0.1 s (V dt / Dc = 1e-3) is within 0.1 % after 100 s
    theta, theta0 = 10.0, 10.0
    for _ in range(1000):
        theta, _ = aging_state(theta, V, 0.1, Dc)
    exact = Dc / V + (theta0 - Dc / V) * np.exp(-V * 100.0 / Dc)
    assert theta == pytest.approx(exact, rel=1e-3)


def test_return_map_reaches_steady_sliding():
    """A point driven at constant slip rate V through its spring: once the transient is over,
    the plastic slip rate is V and tau = sigma_n (mu0 + a ln(V/V0)) -- the whole return map,
    not just the friction function."""
    mu0, a, V0, V, dt, sn0 = 0.6, 0.01, 1e-6, 1e-5, 0.5, 1e7
    slip = tau = 0.0
    tau = 0.5 * mu0 * sn0
    for k in range(400):
        new = slip + V * dt
        r = rate_state_point(new, 0.0, slip, tau, 0.0, 1.0, sn0, KN, KT, 0.0, mu0, a, 0.0, V0,
                             1e-4, dt, 1e-9)
        tau, ds = r[0], r[3]
        slip = new
    assert ds / dt == pytest.approx(V, rel=1e-8)
    assert tau == pytest.approx(sn0 * (mu0 + a * np.log(V / V0)), rel=1e-10)


@pytest.mark.parametrize("b", [0.0, 0.015])
@pytest.mark.parametrize("stress_ratio", [0.3, 0.6, 0.7, 1.0, 1.05, 1.2, 2.0])
def test_return_map_solves_its_equation(b, stress_ratio):
    """The slip increment ds the return map returns solves |tau_trial| - kT ds = mu(ds/dt,
    theta(ds)) sigma_n(ds), with mu written out here (a asinh(V e^(psi/a) / 2V0), the aging
    law by backward Euler): from creep far below the strength (where the map starts from its
    creep guess) to sliding that relaxes most of the trial stress (where the guess is out of
    range and it starts from 0), with dilation."""
    kN, kT, tp, mu0, a, V0, Dc, dt, sn0 = KN, KT, 0.1, 0.6, 0.01, 1e-6, 1e-4, 2.0, 1e7
    theta_old = 0.5
    tau_trial = stress_ratio * mu0 * sn0
    r = rate_state_point(0.0, 0.0, 0.0, tau_trial, 0.0, theta_old, sn0, kN, kT, tp, mu0, a, b, V0,
                         Dc, dt, 1e-9)
    tau, sigma_n, ds, theta = r[0], r[1], r[3], r[4]
    V = ds / dt
    if b:
        assert theta == pytest.approx((theta_old + dt) / (1 + V * dt / Dc), rel=1e-14)
    psi = mu0 + b * np.log(V0 * theta / Dc)
    mu = a * np.arcsinh(V / (2 * V0) * np.exp(psi / a))
    assert 0.0 < ds < tau_trial / kT
    assert sigma_n == pytest.approx(sn0 + kN * tp * ds, rel=1e-14)
    assert tau == pytest.approx(tau_trial - kT * ds, rel=1e-14)
    assert abs(tau_trial - kT * ds - mu * sigma_n) <= 1e-12 * tau_trial


def test_rate_state_step_limit_is_half_dc_over_the_peak_rate_and_none_without_state():
    """dt <= 0.5 Dc / max|V| with state evolution (Dc 1e-5 m, peak 2e-6 m/s: 2.5 s); no limit
    without it (b = 0), at rest, or with no fault points."""
    import dataclasses
    from pathlib import Path

    from fault_screen import Scene
    from fault_screen.physics.contact import RateStateFriction

    scene = Scene.from_toml(Path(__file__).resolve().parents[2] / "configs" / "rustrel-2015-impermeable.toml")
    scene = scene.replace(fault=dataclasses.replace(scene.fault, state_parameter=0.02,
                                                    critical_slip_distance=1e-5))
    evolving = RateStateFriction(scene, dilation=False, state_evolution=True)
    rates = np.array([1e-7, -2e-6, 0.0])
    assert evolving.max_step(rates) == pytest.approx(2.5, rel=1e-15)
    assert evolving.max_step(np.zeros(3)) == np.inf and evolving.max_step(np.zeros(0)) == np.inf
    assert RateStateFriction(scene, dilation=False, state_evolution=False).max_step(rates) == np.inf

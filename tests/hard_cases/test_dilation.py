"""Dilation: the contact test of the dilatant return map, and stick-slip cycling with dilation on.

With dilation, sliding raises the normal stress (sigma_n = sigma_n0 - kN (opening - tan(psi) D),
D the cumulative plastic slip). A point whose walls are apart before the step's own plastic slip
may be pressed together by it; testing contact before that slip made the law jump from open
(tau = sigma_n = 0) to sliding at sigma_n of MPa, and Newton cycled between the two (the case
stick-slip-cycling-dilation failed at the first jump of the held pressure).
"""
import numpy as np
import pytest

from fault_screen.kernels.contact import OPEN, SLIP, H_DILATANT_SLIP, coulomb_point, rate_state_point
from stability_cases import check_common, run_case

KN, KT, TAN_PSI, MU = 1e10, 1e10, 0.5, 0.6
SIGMA_N0 = 1e7


def _coulomb(opening, tau_trial=2e6):
    # history: no slip, no shear traction, no plastic slip; the slip is the trial's
    return coulomb_point(tau_trial / KT, opening, 0.0, 0.0, 0.0, SIGMA_N0, KN, KT, MU, TAN_PSI)


def _rate_state(opening, tau_trial=2e6):
    return rate_state_point(tau_trial / KT, opening, 0.0, 0.0, 0.0, 1.0, SIGMA_N0, KN, KT, TAN_PSI,
                            MU, 0.01, 0.0, 1e-6, 1e-4, 1.0, 1e-9)


def test_dilatant_slip_closes_walls_that_are_apart_before_it_by_hand():
    """sigma_base = sigma_n0 - kN opening = -0.5 MPa (apart before the step's slip), tau_trial =
    2 MPa: ds = (2e6 + 0.6 * 0.5e6) / (kT + 0.6 kN 0.5) = 2.3e6 / 1.3e10, sigma_n = -0.5e6 +
    kN 0.5 ds = 5e15 / 1.3e10 = 384615.38 Pa, tau = 0.6 sigma_n: in contact, sliding."""
    opening = (SIGMA_N0 + 0.5e6) / KN
    tau, sn, state, ds, *_ = _coulomb(opening)
    assert state == SLIP
    assert ds == pytest.approx(2.3e6 / 1.3e10, rel=1e-12)
    assert sn == pytest.approx(5e15 / 1.3e10, rel=1e-12)
    assert tau == pytest.approx(MU * 5e15 / 1.3e10, rel=1e-12)
    # apart by more than the whole trial shear can dilate (sigma_base < -kN tan(psi) tau_trial/kT
    # = -1 MPa): open
    tau, sn, state, *_ = _coulomb((SIGMA_N0 + 1.01e6) / KN)
    assert state == OPEN and tau == 0.0 and sn == 0.0


@pytest.mark.parametrize("law", [_coulomb, _rate_state], ids=["coulomb", "rate-state"])
def test_tangent_where_dilatant_slip_closes_the_walls_matches_finite_differences(law):
    """Where the walls are apart before the step's slip and pressed together by it (sigma_base
    = -0.5 MPa), the consistent tangent is the sliding branch's: central differences agree."""
    slip, opening = 2e6 / KT, (SIGMA_N0 + 0.5e6) / KN

    def at(s, o):
        r = (coulomb_point(s, o, 0.0, 0.0, 0.0, SIGMA_N0, KN, KT, MU, TAN_PSI) if law is _coulomb else
             rate_state_point(s, o, 0.0, 0.0, 0.0, 1.0, SIGMA_N0, KN, KT, TAN_PSI, MU, 0.01, 0.0, 1e-6,
                              1e-4, 1.0, 1e-9))
        return np.array(r[:2]), r[2], np.array(r[4:8] if law is _coulomb else r[6:10])

    (_, state, analytic), h = at(slip, opening), 1e-10
    assert state == SLIP
    fd = np.empty(4)
    for k, (ds, do) in enumerate(((h, 0.0), (0.0, h))):
        d = (at(slip + ds, opening + do)[0] - at(slip - ds, opening - do)[0]) / (2 * h)
        fd[k], fd[2 + k] = d[0], d[1]          # (dtau, dsigma) / d(slip or opening)
    np.testing.assert_allclose(analytic, fd, rtol=1e-5, atol=1e-6 * KN)


@pytest.mark.parametrize("law", [_coulomb, _rate_state], ids=["coulomb", "rate-state"])
def test_the_dilatant_return_map_is_continuous_where_the_walls_part(law):
    """Sweep the opening across the contact boundary (sigma_base = -kN tan(psi) tau_trial / kT =
    -1 MPa) in steps of 1e-9 m: tau and sigma_n change by at most kN x 1e-9 m = 10 Pa a step (the
    normal stiffness bounds the law's slope). The old test on sigma_base jumped by 0.6-1 MPa at
    sigma_base = 0."""
    boundary = (SIGMA_N0 + 1e6) / KN
    openings = np.linspace(SIGMA_N0 / KN - 2e-5, boundary + 2e-5, 2 * 3000 + 1)
    out = np.array([law(o)[:3] for o in openings])
    states = out[:, 2]
    assert {SLIP, OPEN} <= set(states.astype(int))           # both sides of the boundary swept
    assert np.all(states[openings > boundary + 1e-12] == OPEN)
    assert np.all(states[openings < boundary - 1e-12] == SLIP)
    step = np.diff(openings)[0]
    jumps = np.max(np.abs(np.diff(out[:, :2], axis=0)), axis=0)
    assert np.all(jumps <= KN * step * (1 + 1e-6)), jumps


# ---------------------------------------------------------------- the hard case
NAME = "stick-slip-cycling-dilation"


@pytest.fixture(scope="module")
def run():
    return run_case(NAME)


def test_cycling_with_dilation_completes_finite_and_balanced(run):
    check_common(run)


def test_the_patch_sticks_and_slips_three_times_and_never_opens(run):
    r = run.result
    state = r.fault["contact_state"][:, np.argmin(np.abs(r.fault_x))]
    sliding = (state == SLIP).astype(int)
    assert np.count_nonzero(np.diff(sliding) == 1) == 3        # the three jumps past failure
    assert np.count_nonzero(np.diff(sliding) == -1) == 3       # the three drops back
    # dilation presses the walls together: no point opens in this case
    assert not np.any(r.fault["contact_state"] == OPEN)


def test_dilatant_opening_is_tan_psi_times_the_plastic_slip(run):
    """The plastic slip is rebuilt from the recorded slip and shear traction alone, step by step
    (ds_p = |d slip - d tau / kT|, the slip the spring kT does not carry), and the dilatant
    opening from the recorded opening and normal stress (opening less the penalty's elastic
    closure (sigma_n0 - sigma_n) / kN). They must agree at every point and step, to 1e-6 of the
    largest dilatant opening (round-off of differences of recorded values); and the rebuilt
    plastic slip is the contact history's own (a step's history is that step's, never a
    continuation stage's)."""
    r, scene = run.result, run.scene
    kN, kT = scene.fault.normal_stiffness, scene.fault.shear_stiffness
    tan_psi = np.tan(np.radians(scene.fault.dilation_angle))
    slip, tau = r.fault["slip"], r.fault["shear_traction"]
    plastic = np.cumsum(np.abs(np.diff(slip, axis=0) - np.diff(tau, axis=0) / kT), axis=0)
    sigma_n0 = r.fault["effective_normal_stress"][0]          # the in-situ state at t = 0
    dilatant = r.fault["opening"][1:] - (sigma_n0 - r.fault["effective_normal_stress"][1:]) / kN
    scale = tan_psi * plastic.max()
    assert scale > 1e-3                                        # mm of dilatant opening
    assert np.max(np.abs(dilatant - tan_psi * plastic)) < 1e-6 * scale
    np.testing.assert_allclose(plastic[-1], run.sim.history[:, H_DILATANT_SLIP], rtol=0,
                               atol=1e-6 * plastic.max())
    # the dilatant part is what opens the fault: at the injection point the opening is tan(psi)
    # times the slip to within the elastic parts (2 %: ~1 MPa / kN of closure, ~1 MPa / kT of
    # elastic slip, against tan(psi) x 9 mm)
    g = np.argmin(np.abs(r.fault_x))
    assert r.fault["opening"][-1, g] == pytest.approx(tan_psi * slip[-1, g], rel=0.02)

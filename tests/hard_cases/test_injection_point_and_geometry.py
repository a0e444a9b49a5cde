"""Injection point anywhere on the fault, faults at any angle, through nodes and along mesh lines.

The physics is the fluid-driven-slip family at T = 0.4 (5 MPa held at the point, or a constant
rate): moving the point or turning the fault must not change the slip beyond the mesh error.
"""
import numpy as np
import pytest

from stability_cases import CASES, REFINED_CASES, check_common, rotated_stress, run_case

POINT = [n for n, c in CASES.items() if c.family == "point"]
POINT_RATE = [n for n, c in CASES.items() if c.family == "point-rate"]
ANGLES = [n for n, c in CASES.items() if c.family == "angle"]


def moment(r):
    """Slip moment (m^2): integral of slip along the fault at the end."""
    return float(np.sum(r.fault_weights * r.fault["slip"][-1]))


@pytest.mark.parametrize("name", POINT + POINT_RATE + ANGLES)
def test_completes_finite_and_balanced(name):
    check_common(run_case(name))


@pytest.mark.parametrize("name", POINT)
def test_pressure_control_holds_the_overpressure_at_the_point(name):
    r = run_case(name).result
    assert np.allclose(r.injection["overpressure"][1:], 5e6, rtol=1e-9, atol=0)


@pytest.mark.parametrize("angle", ["30deg", "0deg"])
def test_slip_does_not_depend_on_where_the_point_is_in_the_element(angle):
    """Before the fix the slip moment grew by 90 % with the point moved half an element (the
    held pressure was flattened over the segment holding the point); now the fault line has a
    node at the point. 6 %: the spread of the coarse mesh (1 m elements, diffusion length 2.5 m)."""
    names = [n for n in POINT if angle in n]
    m = np.array([moment(run_case(n).result) for n in names])
    assert m.min() > 0
    assert (m.max() - m.min()) / m.mean() < 0.06, dict(zip(names, m))


def test_rate_control_point_off_the_edges_agrees_with_the_node():
    """Same injected volume: the overpressure at the point agrees with the point on a node
    within 6 %, the slip moment within 20 % (at 30 degrees, 0.3-0.5 of an element off the node,
    a few points next to the source open on this 1 m mesh and the moment is 16 % lower: the
    mesh effect of test_rate_control_point_off_the_node_converges_to_the_node_case)."""
    ref = run_case("point-node-30deg-rate").result
    for name in ("point-1e-6-30deg-rate", "point-0.5-30deg-rate", "point-0.3-0deg-rate"):
        r = run_case(name).result
        assert r.injection["volume"][-1] == pytest.approx(ref.injection["volume"][-1], rel=1e-12)
        assert r.injection["overpressure"][-1] == pytest.approx(ref.injection["overpressure"][-1], rel=0.06)
        assert moment(r) == pytest.approx(moment(ref), rel=0.20)
    # the 1e-6 offset is the node case to round-off of the geometry
    assert moment(run_case("point-1e-6-30deg-rate").result) == pytest.approx(moment(ref), rel=1e-4)


@pytest.mark.slow
def test_rate_control_point_off_the_node_converges_to_the_node_case():
    """The 16 % lower slip moment of a rate-controlled source 0.3-0.5 of an element off the node
    (30 degrees, 1 m elements) is discretisation and converges away: measured 16 %, 6.5 %, 1.0 %
    at 1, 0.5, 0.25 m. Cause: the contact traction at the fault's Gauss points oscillates
    (penalty kN = 1e13 Pa/m is 400 times the elements' stiffness E/h; +-5 MPa around the
    expected sigma'_n even with the point on a node), and the pressure's kink at a source inside
    an element, which the element's jump cannot follow, drives it harder: a few points next to
    the source open by microns (9 % of the injected fluid in their opening) while neighbours are
    pressed MPa too hard. Asserted: each halving of the elements at least halves the deficit,
    and at 0.25 m the moment is within 2 % of the node case's, itself converged to 0.5 %."""
    def moments(h):
        return [moment(run_case(f"point-{lab}-30deg-rate-h{h:g}").result) for lab in ("node", "0.3", "0.5")]

    for name in (n for n in REFINED_CASES if n.startswith("point-")):
        check_common(run_case(name))
    deficit = {}
    node = {}
    for h in (1.0, 0.5, 0.25):
        m = moments(h)
        node[h] = m[0]
        deficit[h] = max(abs(1.0 - m[1] / m[0]), abs(1.0 - m[2] / m[0]))
    assert deficit[1.0] > 0.10                      # the effect is there on the 1 m mesh
    assert deficit[0.5] < 0.5 * deficit[1.0] and deficit[0.25] < 0.5 * deficit[0.5], deficit
    assert deficit[0.25] < 0.02, deficit
    assert node[0.25] == pytest.approx(node[0.5], rel=0.005)


def test_a_fault_through_a_node_is_moved_off_it_with_a_warning():
    run = run_case("point-node-30deg-pressure")
    assert run.result.meta["fault_shift"] == pytest.approx(1e-6, rel=1e-12)  # 1e-6 of a 1 m element
    assert any("passes through mesh nodes" in w for w in run.warnings)
    # and it behaves as the fault 1e-6 of an element off the node
    assert moment(run.result) == pytest.approx(moment(run_case("point-1e-6-30deg-pressure").result), rel=1e-3)


@pytest.mark.parametrize("name,offset_case", [("mesh-line-90", "angle-90"), ("mesh-line-0", "angle-0")])
def test_a_fault_along_a_mesh_line_runs_like_one_off_it(name, offset_case):
    """Shifted by 1e-6 of an element, the mesh-line fault slips like the same fault 0.37 of an
    element off the line (5 %: the pressure mesh differs)."""
    run = run_case(name)
    assert run.result.meta["fault_shift"] == pytest.approx(1e-6, rel=1e-12)
    assert any("passes through mesh nodes" in w for w in run.warnings)
    assert moment(run.result) == pytest.approx(moment(run_case(offset_case).result), rel=0.05)


def test_the_slip_does_not_depend_on_the_fault_angle():
    """Every angle sees the same tractions (rotated in-situ stress): the slip moment agrees with
    the horizontal fault's within 8 % (the cut pattern of the coarse mesh changes with the angle)."""
    ref = moment(run_case("angle-0").result)
    for name in ANGLES:
        assert moment(run_case(name).result) == pytest.approx(ref, rel=0.08), name


def test_rotated_stress_gives_the_fault_tractions():
    for angle in (0.0, 30.0, 89.9, 135.0):
        sxx, syy, sxy = rotated_stress(angle)
        a = np.deg2rad(angle)
        t, n = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
        s = np.array([[sxx, sxy], [sxy, syy]])
        assert -(n @ s @ n) == pytest.approx(10e6, rel=1e-12)
        assert t @ s @ n == pytest.approx(4.8e6, rel=1e-12)

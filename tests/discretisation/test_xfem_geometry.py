"""Geometry of the embedded fault: quadrature exactness, areas, lengths, enrichment."""
import numpy as np
import pytest

from fault_screen import xfem
from fault_screen.mesh import build_mesh, graded_line


def test_radon_rule_is_exact_to_degree_five():
    # integrate x^i y^j over the unit triangle (0,0),(1,0),(0,1): i! j! / (i + j + 2)!
    from math import factorial
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    pts = xfem.TRI_BARY @ tri
    for i in range(6):
        for j in range(6 - i):
            exact = factorial(i) * factorial(j) / factorial(i + j + 2)
            approx = 0.5 * np.sum(xfem.TRI_W * pts[:, 0] ** i * pts[:, 1] ** j)
            assert approx == pytest.approx(exact, rel=1e-13)


@pytest.mark.parametrize("angle,offset", [(0.0, 0.4), (30.0, 0.0), (63.0, 1e-3), (-45.0, 0.2)])
def test_cut_areas_and_fault_length(angle, offset):
    mesh = build_mesh(10, 9, 10.0, 9.0)
    point = (5.0, 4.5 + offset)
    f = xfem.locate_fault(mesh, point, angle)
    sizes = mesh.element_sizes[f.cut_elements]
    # sub-cell weights add up to the element areas
    assert np.allclose(f.cut_w.sum(axis=1), sizes[:, 0] * sizes[:, 1], rtol=1e-12)
    # fault Gauss weights add up to the chord of the line through the rectangle
    t = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    ends = [point + s * t for s in (f.segment_s[0, 0], f.segment_s[-1, 1])]
    assert np.sum(f.gp_w) == pytest.approx(np.linalg.norm(ends[1] - ends[0]), rel=1e-12)
    for e in ends:  # the fault is through-going: it ends on the boundary
        on_x = min(abs(e[0] - 0.0), abs(e[0] - 10.0)) < 1e-9
        on_y = min(abs(e[1] - 0.0), abs(e[1] - 9.0)) < 1e-9
        assert on_x or on_y
    # the area on the + side of every cut element matches the exact polygon area
    for k, e in enumerate(f.cut_elements):
        plus = f.cut_w[k][f.cut_side[k] == 1].sum()
        xs = np.linspace(mesh.coordinates[mesh.elements[e]][:, 0].min(), mesh.coordinates[mesh.elements[e]][:, 0].max(), 801)
        ys = np.linspace(mesh.coordinates[mesh.elements[e]][:, 1].min(), mesh.coordinates[mesh.elements[e]][:, 1].max(), 801)
        X, Y = np.meshgrid(0.5 * (xs[1:] + xs[:-1]), 0.5 * (ys[1:] + ys[:-1]))
        phi = (X - point[0]) * f.normal[0] + (Y - point[1]) * f.normal[1]
        approx = np.mean(phi > 0) * sizes[k, 0] * sizes[k, 1]
        assert plus == pytest.approx(approx, abs=5e-3 * sizes[k, 0] * sizes[k, 1])


def test_a_fault_along_a_mesh_line_is_moved_off_it_by_the_documented_clearance():
    mesh = build_mesh(4, 4, 4.0, 4.0)
    f = xfem.locate_fault(mesh, (2.0, 2.0), 0.0)
    assert f.shift == pytest.approx(xfem.NODE_CLEARANCE * 1.0, rel=1e-12)
    # the row below the line is cut (a sliver of 1e-6 of each element), every node on one side
    assert len(f.cut_elements) == 4
    assert np.min(np.abs(f.node_phi)) == pytest.approx(f.shift, rel=1e-9)
    assert f.length == pytest.approx(4.0, rel=1e-12)


def test_a_fault_missing_the_mesh_is_refused():
    mesh = build_mesh(4, 4, 4.0, 4.0)
    with pytest.raises(ValueError, match="does not cross"):
        xfem.locate_fault(mesh, (2.0, 10.0), 0.0)


def test_graded_line_keeps_the_focus_on_a_node_and_grows_geometrically():
    x = graded_line(-100.0, 200.0, 0.0, 10.0, 1.0, 1.2)
    assert x[0] == -100.0 and x[-1] == 100.0
    assert np.min(np.abs(x)) == 0.0
    h = np.diff(x)
    assert np.allclose(h[np.abs(x[:-1] + 0.5 * h) < 10], 1.0)
    assert np.all(h > 0) and h.max() / h.min() < 1.2 ** 30

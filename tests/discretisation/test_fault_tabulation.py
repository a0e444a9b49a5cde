"""The fault's Gauss points and the injection point, tabulated for all points at once
(``Discretisation._tabulate_fault``, ``kernels.basis.level_set_basis``), against the same functions
made a point at a time (``kernels.basis`` and the per-point level set of tests/basis_reference.py; 0 difference: the same arithmetic in the same
order), on faults that cut their elements in different shapes."""
import warnings
from dataclasses import replace

import numpy as np
import pytest

from fault_screen import Scene, xfem
from fault_screen.discretisation import discretise
from fault_screen.kernels import basis

from basis_reference import level_set_basis_at_point
from conftest import CONFIGS, VERIFICATION


def per_point(disc):
    """(N, xy, Np, dNp_ds, p_dofs, jump_dofs) of the fault's Gauss points, one point at a time."""
    f = disc.fault
    ng = len(f.gp_s)
    cut_nodes = disc.elements[disc.cut_elements]
    sizes = disc.mesh.element_sizes
    trace = disc.fault_pressure_is_trace
    nbp = 8 if trace else 2
    N, xy = np.zeros((ng, 4)), np.zeros((ng, 2))
    Np, dNp = np.zeros((ng, nbp)), np.zeros((ng, nbp))
    pmap = -np.ones((ng, nbp), dtype=np.int64)
    jump = -np.ones((ng, 8), dtype=np.int64)
    for g in range(ng):
        k = f.gp_element[g]
        e = disc.cut_elements[k]
        nodes = cut_nodes[k]
        xi, eta = f.gp_ref[g]
        Ng = basis.shape(xi, eta)
        N[g] = Ng
        xy[g] = Ng @ disc.coords[nodes]
        if disc.has("a"):
            jump[g] = disc._a_map(nodes[None, :])[0]
        if trace:
            dN = basis.shape_gradient(xi, eta, sizes[e, 0], sizes[e, 1])
            Nl, dNl = level_set_basis_at_point(Ng, dN, f.node_phi[nodes])
            Np[g, :4], Np[g, 4:] = Ng, Nl
            dNp[g, :4], dNp[g, 4:] = dN @ f.tangent, dNl @ f.tangent
            if disc.has("p"):
                pmap[g, :4] = disc._p_map(nodes)
            if disc.has("c"):
                pmap[g, 4:] = disc._c_map(nodes)
        else:
            lam = f.gp_xi1d[g]
            s0, s1 = f.segment_s[f.gp_segment[g]]
            Np[g] = (1.0 - lam, lam)
            dNp[g] = (-1.0 / (s1 - s0), 1.0 / (s1 - s0))
            if disc.has("pf"):
                pmap[g] = disc.blocks.pf.start + f.segment_nodes[f.gp_segment[g]]
    return N, xy, Np, dNp, pmap, jump


def _scene(config, nx, ny, **fault):
    scene = Scene.from_toml(config)
    scene = scene.replace(mesh=replace(scene.mesh, nx=nx, ny=ny))
    return scene.replace(fault=replace(scene.fault, **fault)) if fault else scene


SHAPES = {
    # rock pressure traced on the fault (level-set enriched), a horizontal fault
    "rustrel horizontal": lambda: _scene(CONFIGS / "rustrel-2015-calibrated.toml", 12, 13),
    # the same, cutting its elements into triangles and pentagons at 37 degrees
    "rustrel 37 deg": lambda: _scene(CONFIGS / "rustrel-2015-calibrated.toml", 12, 13, angle=37.0),
    # the fault's own pressure line, 30 degrees
    "fault line 30 deg": lambda: _scene(VERIFICATION / "fluid-driven-slip-T0.7-dip30.toml", 14, 15),
    # a finite fault, its tips snapped to element edges
    "finite fault": lambda: _scene(VERIFICATION / "fluid-driven-slip-T0.7-dip30.toml", 14, 15,
                                   length=150.0),
}


def _through_a_node():
    """A 45-degree fault through the model's centre node, which the geometry moves off it."""
    return _scene(CONFIGS / "rustrel-2015-calibrated.toml", 12, 12, angle=45.0)


SHAPES["through a node at 45 deg"] = _through_a_node


@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_fault_points_all_at_once_are_the_per_point_functions(shape):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        disc = discretise(SHAPES[shape]())
    fp = disc.fault_points
    assert len(fp.s) >= 8
    N, xy, Np, dNp, pmap, jump = per_point(disc)
    # the same arithmetic in the same order: every value equal to the bit (0 difference)
    for name, a, b in (("N", fp.N, N), ("xy", fp.xy, xy), ("Np", fp.Np, Np), ("dNp_ds", fp.dNp_ds, dNp),
                       ("p_dofs", fp.p_dofs, pmap), ("jump_dofs", fp.jump_dofs, jump)):
        assert a.shape == b.shape and np.array_equal(a, b), name
    # the injection point's functions, the one point made by the same array function
    f = disc.fault
    if disc.fault_pressure_is_trace:
        k, lam = xfem.locate_point_on_fault(f, disc.injection.s)
        xi, eta = f.segment_ref[k, 0] + lam * (f.segment_ref[k, 1] - f.segment_ref[k, 0])
        e = disc.cut_elements[f.segment_element[k]]
        Nl, _ = level_set_basis_at_point(basis.shape(xi, eta),
                                         basis.shape_gradient(xi, eta, *disc.mesh.element_sizes[e]),
                                         f.node_phi[disc.elements[e]])
        assert np.array_equal(disc.injection.Np[4:], Nl)
    # standard functions: a partition of unity at every point (round-off); on the fault the
    # level set's sum vanishes, so psi = sum N_i |phi_i| there and the enriched functions are
    # N_j times it (round-off of that sum)
    assert np.max(np.abs(fp.N.sum(axis=1) - 1.0)) <= 1e-15
    if disc.fault_pressure_is_trace:
        phi = np.abs(f.node_phi[disc.elements[disc.cut_elements[f.gp_element]]])
        on_fault = fp.N * np.sum(fp.N * phi, axis=1)[:, None]
        assert np.max(np.abs(fp.Np[:, 4:] - on_fault)) <= 1e-12 * np.max(on_fault)
        assert np.max(on_fault) > 0.0

@pytest.mark.filterwarnings("ignore:leak-off")
def test_a_fault_through_a_node_is_moved_off_it():
    """The 45-degree scene above does pass through mesh nodes (else it tests nothing special)."""
    with pytest.warns(Warning, match="passes through mesh nodes"):
        disc = discretise(_through_a_node())
    assert disc.fault.shift > 0.0

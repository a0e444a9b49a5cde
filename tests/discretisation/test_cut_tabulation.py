"""The cut elements' shape functions, tabulated for all points at once (``xfem.tabulate_cut``),
against the per-point basis functions they are made of and against partition of unity."""
from dataclasses import replace

import numpy as np
import pytest

from fault_screen import Scene
from fault_screen.discretisation import discretise
from fault_screen.kernels import basis

from basis_reference import level_set_basis_at_point
from conftest import CONFIGS, VERIFICATION


@pytest.mark.parametrize("config", [CONFIGS / "rustrel-2015-calibrated.toml",
                                    VERIFICATION / "fluid-driven-slip-T0.7-dip30.toml"])
def test_cut_tabulation_is_the_per_point_basis_and_a_partition_of_unity(config):
    scene = Scene.from_toml(config)
    scene = scene.replace(mesh=replace(scene.mesh, nx=12, ny=13))
    disc = discretise(scene)
    f = disc.fault
    cut = disc.element_groups[-1]
    assert np.array_equal(cut.elements, f.cut_elements) and len(f.cut_elements) >= 4
    sizes = disc.mesh.element_sizes
    for k, e in enumerate(f.cut_elements):
        phi_e = f.node_phi[disc.elements[e]]
        node_side = (phi_e > 0).astype(float)
        for q in range(f.cut_qp.shape[1]):
            xi, eta = f.cut_qp[k, q]
            N = basis.shape(xi, eta)
            dN = basis.shape_gradient(xi, eta, *sizes[e])
            Nh, dNh = basis.heaviside_basis(N, dN, float(f.cut_side[k, q]), node_side)
            Nl, dNl = level_set_basis_at_point(N, dN, phi_e)
            # the same arithmetic, so the same bits (0 difference)
            assert np.array_equal(cut.Nu[k, q], np.concatenate([N, Nh]))
            assert np.array_equal(cut.grad_u[k, q], np.concatenate([dN, dNh]))
            assert np.array_equal(cut.Np[k, q], np.concatenate([N, Nl]))
            assert np.array_equal(cut.grad_p[k, q], np.concatenate([dN, dNl]))
    # bilinear functions sum to one and their gradients to zero at every point (round-off)
    assert np.max(np.abs(cut.Nu[:, :, :4].sum(axis=2) - 1.0)) <= 1e-15
    assert np.max(np.abs(cut.grad_u[:, :, :4].sum(axis=2))) <= 1e-12 * np.max(np.abs(cut.grad_u))

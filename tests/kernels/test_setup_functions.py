"""The set-up functions of fault_screen.kernels that are plain numpy (the shape functions and
their enrichments, the plane-strain elasticity, the fault's constant-aperture conduction,
storage and opening coupling): their values against the closed forms they stand for, and the
kernels a run of the bundled scene compiles or loads (none of these: every kernel is a compilation
on a cold start and a cache load on every start)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fault_screen.kernels import basis, fault_flow, rock

from basis_reference import level_set_basis_at_point

ROOT = Path(__file__).resolve().parents[2]
CORNERS = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
POINTS = [(-0.7, 0.3), (0.0, 0.0), (0.25, -0.9), (0.577, 0.577)]


def test_shape_functions_are_nodal_and_a_partition_of_unity():
    assert np.array_equal(np.array([basis.shape(*c) for c in CORNERS]), np.eye(4))
    for xi, eta in POINTS:
        assert abs(basis.shape(xi, eta).sum() - 1.0) <= 1e-15


@pytest.mark.parametrize("hx, hy", [(1.0, 1.0), (2.5, 0.4)])
def test_shape_gradient_is_the_derivative_of_the_shape_functions(hx, hy):
    """Bilinear functions: a central difference is exact up to round-off (1e-9 relative to
    the gradient's scale 1/h); the gradients sum to zero (1e-15 / h)."""
    h = 1e-3
    for xi, eta in POINTS:
        g = basis.shape_gradient(xi, eta, hx, hy)
        fd_x = (basis.shape(xi + h, eta) - basis.shape(xi - h, eta)) / (2 * h) * 2 / hx
        fd_y = (basis.shape(xi, eta + h) - basis.shape(xi, eta - h)) / (2 * h) * 2 / hy
        assert np.max(np.abs(g[:, 0] - fd_x)) <= 1e-9 / hx
        assert np.max(np.abs(g[:, 1] - fd_y)) <= 1e-9 / hy
        assert np.max(np.abs(g.sum(axis=0))) <= 1e-15 / min(hx, hy)


def test_heaviside_enrichment_is_shifted_by_each_nodes_side():
    """On side 1 with nodes 0 and 3 on side 1: the enrichment is N_j at nodes 1, 2 and zero at
    nodes 0, 3 (exactly), and so is its gradient."""
    N, dN = basis.shape(0.3, -0.2), basis.shape_gradient(0.3, -0.2, 2.0, 1.0)
    Ne, dNe = basis.heaviside_basis(N, dN, 1.0, np.array([1.0, 0.0, 0.0, 1.0]))
    assert np.array_equal(Ne, N * np.array([0.0, 1.0, 1.0, 0.0]))
    assert np.array_equal(dNe, dN * np.array([0.0, 1.0, 1.0, 0.0])[:, None])


def test_level_set_enrichment_of_a_fault_through_the_middle():
    """Level set phi = eta at the nodes (-1, -1, 1, 1): psi = 1 - |eta| inside the element,
    zero at every node, 1 on the fault (Ne = N exactly at the centre, 0.25 each); its gradient
    (hx = 2, hy = 4: d/dy = (1/2) d/deta) against a central difference to 1e-9 off the fault."""
    phi = np.array([-1.0, -1.0, 1.0, 1.0])
    for xi, eta in CORNERS:
        Ne, _ = basis.level_set_basis(basis.shape(xi, eta), basis.shape_gradient(xi, eta, 2.0, 4.0), phi)
        assert np.max(np.abs(Ne)) <= 1e-16
    Ne, _ = basis.level_set_basis(basis.shape(0.0, 0.0), basis.shape_gradient(0.0, 0.0, 2.0, 4.0), phi)
    assert np.array_equal(Ne, np.full(4, 0.25))
    h = 1e-4
    for xi, eta in [(-0.3, 0.4), (0.6, -0.5)]:
        N = basis.shape(xi, eta)
        Ne, dNe = basis.level_set_basis(N, basis.shape_gradient(xi, eta, 2.0, 4.0), phi)
        assert np.max(np.abs(Ne - N * (1.0 - abs(eta)))) <= 1e-15

        def at(x, e):
            return basis.level_set_basis(basis.shape(x, e), basis.shape_gradient(x, e, 2.0, 4.0), phi)[0]

        fd_x = (at(xi + h, eta) - at(xi - h, eta)) / (2 * h) * 2 / 2.0
        fd_y = (at(xi, eta + h) - at(xi, eta - h)) / (2 * h) * 2 / 4.0
        assert np.max(np.abs(dNe[:, 0] - fd_x)) <= 1e-9
        assert np.max(np.abs(dNe[:, 1] - fd_y)) <= 1e-9


def test_level_set_enrichment_at_arrays_of_points():
    """The array form on a 7 x 9 grid of points inside two elements at once (one cut through the
    middle, phi = eta: psi = 1 - |eta| in closed form, to 1e-15; one cut across a corner, phi =
    (-1, 0.5, 2, 0.5)), against the per-point reference (tests/basis_reference.py) to the bit,
    the points of the line phi = 0 (sign 0) included."""
    xi, eta = np.meshgrid(np.linspace(-1, 1, 7), np.linspace(-1, 1, 9), indexing="ij")
    N = np.moveaxis(basis.shape(xi, eta), 0, -1)                              # (7, 9, 4)
    dN = np.transpose(basis.shape_gradient(xi, eta, 2.0, 4.0), (2, 3, 0, 1))  # (7, 9, 4, 2)
    phi = np.array([[-1.0, -1.0, 1.0, 1.0], [-1.0, 0.5, 2.0, 0.5]])[:, None, None, :]
    Ne, dNe = basis.level_set_basis(N[None], dN[None], phi)
    assert Ne.shape == (2, 7, 9, 4) and dNe.shape == (2, 7, 9, 4, 2)
    assert np.max(np.abs(Ne[0] - N * (1.0 - np.abs(eta))[..., None])) <= 1e-15
    for k in range(2):
        for i in range(7):
            for j in range(9):
                ref_N, ref_dN = level_set_basis_at_point(N[i, j], dN[i, j], phi[k, 0, 0])
                assert np.array_equal(Ne[k, i, j], ref_N) and np.array_equal(dNe[k, i, j], ref_dN)


def test_plane_strain_elasticity_of_a_known_rock():
    """E = 30 GPa, nu = 0.25: lambda + 2G = 36 GPa, lambda = 12 GPa, G = 12 GPa (1e-15 relative)."""
    D = rock.plane_strain_elasticity(30e9, 0.25)
    expected = np.array([[36e9, 12e9, 0.0], [12e9, 36e9, 0.0], [0.0, 0.0, 12e9]])
    assert np.max(np.abs(D - expected)) <= 1e-15 * 36e9


def test_fault_storage_conduction_and_opening_coupling_of_a_linear_segment():
    """A 2-node segment of length L = 0.5 m at its midpoint (Np = 1/2, dNp/ds = -+1/L), weight
    w = 0.25 m: storage w S Np Np^T = w S / 4 everywhere; conduction w T / L^2 [[1, -1], [-1, 1]];
    coupling G[a, 2 j + c] = w Np_a N_j n_c (relative 1e-15)."""
    w, S, T, L = 0.25, 3e-10, 2e-9, 0.5
    Np, dNp = np.array([0.5, 0.5]), np.array([-1.0 / L, 1.0 / L])
    assert np.max(np.abs(fault_flow.fault_storage(Np, S, w) - w * S / 4)) <= 1e-15 * w * S
    H = fault_flow.fault_conduction(dNp, T, w)
    assert np.max(np.abs(H - w * T / L**2 * np.array([[1.0, -1.0], [-1.0, 1.0]]))) <= 1e-15 * w * T / L**2
    N, normal = basis.shape(0.2, 0.0), np.array([0.6, 0.8])
    G = fault_flow.opening_coupling(Np, N, normal, w)
    assert G.shape == (2, 8)
    for a in range(2):
        for j in range(4):
            for c in range(2):
                assert abs(G[a, 2 * j + c] - w * Np[a] * N[j] * normal[c]) <= 1e-16
    # summed over the nodes (a partition of unity) the coupling is w Np_a n_c
    assert np.max(np.abs(G.reshape(2, 4, 2).sum(axis=1) - w * Np[:, None] * normal)) <= 1e-16
    # every fault point at once (a leading axis of points): each point's G to the bit
    rng = np.random.default_rng(3)
    Nps, Ns, ws = rng.uniform(size=(5, 2)), rng.uniform(size=(5, 4)), rng.uniform(size=5)
    Gs = fault_flow.opening_coupling(Nps, Ns, normal, ws)
    assert Gs.shape == (5, 2, 8)
    for g in range(5):
        assert np.array_equal(Gs[g], fault_flow.opening_coupling(Nps[g], Ns[g], normal, ws[g]))
        assert abs(Gs[g, 1, 2 * 3 + 1] - ws[g] * Nps[g, 1] * Ns[g, 3] * normal[1]) <= 1e-16


CODE = """
import gc, json, sys
from numba.core.registry import CPUDispatcher
from fault_screen import Scene, Simulation
scene = Scene.from_toml(sys.argv[1])
sim = Simulation(scene)
sim.advance(2 * scene.time.dt)
names = sorted(f"{d.py_func.__module__}.{d.py_func.__name__}" for d in gc.get_objects()
               if isinstance(d, CPUDispatcher) and d.signatures and d.py_func.__module__.startswith("fault_screen."))
print(json.dumps(names))
"""


def test_bundled_scene_loads_eight_kernels_of_the_kernels_package():
    """A run of the bundled scene compiles (or loads from numba's cache) exactly these 8 kernels
    of fault_screen.kernels: contact's 3, rock's 4 element kernels and the evolving-aperture
    conduction; the set-up functions above are none of them (checked in a fresh interpreter)."""
    scene = ROOT / "configs" / "rustrel-2015-calibrated-paper-units.toml"   # what `fault-screen run` runs
    out = subprocess.run([sys.executable, "-c", CODE, str(scene)], capture_output=True, text=True, cwd=ROOT,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    names = json.loads(out.stdout.strip().splitlines()[-1])
    ours = [n.removeprefix("fault_screen.kernels.") for n in names if n.startswith("fault_screen.kernels.")]
    assert ours == ["contact.assemble_contact", "contact.fault_jumps", "contact.rate_state_law",
                    "fault_flow.assemble_evolving_conduction", "rock.biot_coupling_all",
                    "rock.darcy_conductance_all", "rock.elastic_stiffness_all", "rock.pore_storage_all"]

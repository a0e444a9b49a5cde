"""The porous rock: drained elasticity, Biot coupling, pore storage and Darcy flow
(paper Eq. 1-2, discretised as K, Q, S and H of Eq. 8-9), and the material zones they read.

Each term assembles its constant matrix over both element groups (standard 2x2 Gauss, and cut
elements with their sub-cell rule and enriched bases).
"""
from __future__ import annotations

import numpy as np

from ..kernels import rock
from ..scene import Zone
from .base import Term


def _scatter(w, dofs, local):
    """w[dofs] += local over the entries with an unknown (dofs >= 0), duplicates summed."""
    ok = dofs >= 0
    np.add.at(w, dofs[ok], local[ok])


class Elasticity(Term):
    """Drained plane-strain elasticity: K = int B^T D B dOmega (Eq. 8-9), acting on the
    standard and Heaviside-enriched displacements (Eq. 3). Momentum balance, N per m."""
    blocks = ("u",)

    def assemble_bulk(self, disc, g, out):
        out.A.add(rock.elastic_stiffness_all(g.grad_u, g.w, disc.el_D[g.elements]), g.umap, g.umap)


class BiotCoupling(Term):
    """Biot coupling Q = int B^T alpha m N_p dOmega (Eq. 8-9): pore pressure pushes the
    skeleton (-Q p in the momentum balance) and volumetric strain rate stores fluid
    (Q^T du/dt in the mass balance, m^3/s per m). Stored volume: int alpha eps_v dOmega."""
    blocks = ("u", "p")
    fluid_store = "rock"

    def assemble_bulk(self, disc, g, out):
        Q = rock.biot_coupling_all(g.grad_u, g.Np, g.w, disc.el_alpha[g.elements])
        out.A.add(Q, g.umap, g.pmap, scale=-1.0)
        out.C.add(np.transpose(Q, (0, 2, 1)), g.pmap, g.umap)

    def stored_volume_weights(self, disc):
        w = np.zeros(disc.n_dofs)
        for g in disc.element_groups:
            wa = g.w * disc.el_alpha[g.elements][:, None]  # (ne, nq)
            local = np.empty(g.umap.shape)
            local[:, 0::2] = np.einsum("eq,eqb->eb", wa, g.grad_u[..., 0])  # d eps_v / d ux
            local[:, 1::2] = np.einsum("eq,eqb->eb", wa, g.grad_u[..., 1])
            _scatter(w, g.umap, local)
        return w


class DarcyRock(Term):
    """Pore storage S = int N_p^T (1/M) N_p dOmega, 1/M = (alpha - n)/Ks + n/Kf, and Darcy
    conduction H = int grad N_p^T (k/mu) grad N_p dOmega (Eq. 2, 8-9), on the rock pressure
    and, with leak-off, its modified-level-set enrichment. Stored volume: int p/M dOmega."""
    blocks = ("p",)
    fluid_store = "rock"

    def assemble_bulk(self, disc, g, out):
        els = g.elements
        out.C.add(rock.pore_storage_all(g.Np, g.w, disc.el_inv_M[els]), g.pmap, g.pmap)
        out.Hf.add(rock.darcy_conductance_all(g.grad_p, g.w, disc.el_mobility[els]), g.pmap, g.pmap)

    def stored_volume_weights(self, disc):
        w = np.zeros(disc.n_dofs)
        for g in disc.element_groups:
            wm = g.w * disc.el_inv_M[g.elements][:, None]
            _scatter(w, g.pmap, np.einsum("eq,eqb->eb", wm, g.Np))
        return w


class LeakOff(Term):
    """Modified-level-set enrichment of the rock pressure (Eq. 6-7): the pressure stays
    continuous across the fault while its normal gradient jumps, so the fault's fluid leaks off
    into the rock. It adds unknowns only; the rock terms integrate the enriched bases."""
    blocks = ("c",)


class DamageZone(Term):
    """Damaged rock in a band on both sides of the fault: a material zone with the
    [damage_zone] properties (unset values: intact rock)."""

    def __init__(self, scene):
        dz = scene.damage_zone
        self.zone = Zone(name="damage zone", band=dz.width, rock=dz.rock_overrides())

    def zones(self, scene):
        return (self.zone,)

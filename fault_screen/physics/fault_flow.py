"""Fluid in the fault: storage by compressibility and by opening, and flow along the fault by
the cubic law (paper Eq. 10, 16, 28).

The fault pressure lives either on the trace of the (enriched) rock pressure (leak-off) or on
the fault's own 1-D line of nodes (``pf`` block, impermeable walls); ``disc.fault_points``
carries whichever basis applies, so these terms do not care which.
"""
from __future__ import annotations

import numpy as np

from ..kernels import fault_flow
from .base import Term, fault_jump_at


def _line_block(line):
    return ("pf",) if line else ()


class FaultStorage(Term):
    """Storage of the fluid in the fault by compressibility (Eq. 10, 16): int Np^T S_f Np ds
    with S_f = 2h0/Kf unless ``fault.storativity`` is given (m/Pa). Stored volume:
    int S_f p ds (m^3 per m)."""
    fluid_store = "fault"

    def __init__(self, scene, line: bool):
        f = scene.fault
        self.blocks = _line_block(line)
        self.storativity = (f.storativity if f.storativity is not None
                            else f.hydraulic_aperture / scene.fluid.bulk_modulus)

    def assemble(self, disc, out):
        fp = disc.fault_points
        Sf = np.array([fault_flow.fault_storage(fp.Np[g], self.storativity, fp.weight[g])
                       for g in range(len(fp.s))])
        out.C.add(Sf, fp.p_dofs, fp.p_dofs)

    def stored_volume_weights(self, disc):
        fp = disc.fault_points
        w = np.zeros(disc.n_dofs)
        ok = fp.p_dofs >= 0
        np.add.at(w, fp.p_dofs[ok], ((fp.weight * self.storativity)[:, None] * fp.Np)[ok])
        return w


class OpeningStorage(Term):
    """Fluid stored by the opening of the fault: the opening rate int Np^T [[du/dt]].n ds in the
    fault's mass balance (Eq. 10, fourth term). Stored volume: int opening ds."""
    fluid_store = "fault"

    def assemble(self, disc, out):
        out.C.add(_opening_coupling(disc), disc.fault_points.p_dofs, disc.fault_points.jump_dofs)

    def stored_volume_weights(self, disc):
        fp = disc.fault_points
        n = disc.fault.normal
        # opening = sum_i N_i (a_ix n_x + a_iy n_y) at each point (kernels.contact.fault_jumps)
        local = np.empty(fp.jump_dofs.shape)
        local[:, 0::2] = (fp.weight[:, None] * fp.N) * n[0]
        local[:, 1::2] = (fp.weight[:, None] * fp.N) * n[1]
        w = np.zeros(disc.n_dofs)
        ok = fp.jump_dofs >= 0
        np.add.at(w, fp.jump_dofs[ok], local[ok])
        return w


class FaultPressureOnWalls(Term):
    """The fault's fluid pressure pushes its walls apart: -int [[N_u]]^T n Np ds p in the
    momentum balance (Eq. 15), N per m."""

    def assemble(self, disc, out):
        G = _opening_coupling(disc)
        out.A.add(np.transpose(G, (0, 2, 1)), disc.fault_points.jump_dofs, disc.fault_points.p_dofs,
                  scale=-1.0)


def _opening_coupling(disc):
    fp = disc.fault_points
    return fault_flow.opening_coupling(fp.Np, fp.N, disc.fault.normal, fp.weight)


class ConstantApertureConduction(Term):
    """Flow along the fault by the cubic law over kappa with the initial aperture 2h0
    (Eq. 10, 16): int dNp/ds^T T dNp/ds ds, T = (2h0)^3 / (12 mu kappa) (m^3/(Pa s))."""

    def __init__(self, scene, line: bool):
        f = scene.fault
        self.blocks = _line_block(line)
        self.transmissivity = fault_flow.cubic_law_transmissivity(f.hydraulic_aperture, scene.fluid.viscosity,
                                                                  f.kappa)

    def assemble(self, disc, out):
        fp = disc.fault_points
        Hc = np.array([fault_flow.fault_conduction(fp.dNp_ds[g], self.transmissivity, fp.weight[g])
                       for g in range(len(fp.s))])
        out.Hf.add(Hc, fp.p_dofs, fp.p_dofs)


class EvolvingApertureConduction(Term):
    """Flow along the fault by the cubic law with the hydraulic aperture of the current
    mechanical opening (Renshaw's law, Eq. 28): nonlinear in the fault pressure and the jump,
    assembled each Newton iteration, time-weighted by theta."""

    def __init__(self, scene, line: bool):
        f = scene.fault
        self.blocks = _line_block(line)
        self.aperture0 = f.hydraulic_aperture
        self.asperity_height_std = f.asperity_height_std
        self.viscosity = scene.fluid.viscosity
        self.kappa = f.kappa
        self._pattern = None   # the Jacobian's rows and columns (``pattern``)

    def nonlinear_dofs(self, disc):
        pd = disc.fault_points.p_dofs
        return pd[pd >= 0]

    def _assemble(self, disc, x, time_weight, residual, opening=None):
        fp = disc.fault_points
        if opening is None:
            _, opening = disc.fault_jump(x)
        return fault_flow.assemble_evolving_conduction(
            x, opening, fp.N, fp.jump_dofs, fp.Np, fp.dNp_ds, fp.p_dofs, disc.fault.normal, fp.weight,
            self.aperture0, self.asperity_height_std, self.viscosity, self.kappa, time_weight, residual)

    def residual(self, disc, x, history, dt, time_weight, residual, point):
        _, opening = fault_jump_at(disc, x, point)   # (kept for the contact term)
        vals, aperture = self._assemble(disc, x, time_weight, residual, opening)
        point["hydraulic_aperture"] = aperture
        return (*self.pattern(disc), vals)

    def pattern(self, disc):
        """Rows and columns of the Jacobian's triplets (``assemble_evolving_conduction``'s order:
        per point and fault-pressure row, its fault-pressure columns, then its Heaviside ones),
        made once: the same arrays at every call."""
        if self._pattern is None:
            fp = disc.fault_points
            columns = np.concatenate([fp.p_dofs, fp.jump_dofs], axis=1)
            rows = np.broadcast_to(fp.p_dofs[:, :, None], fp.p_dofs.shape + columns.shape[1:])
            cols = np.broadcast_to(columns[:, None, :], rows.shape)
            kept = (rows >= 0) & (cols >= 0)
            self._pattern = (rows[kept].astype(np.int64), cols[kept].astype(np.int64))
        return self._pattern

    def previous_step(self, disc, x_n, time_weight, residual):
        if time_weight < 1.0:
            self._assemble(disc, x_n, 1.0 - time_weight, residual)

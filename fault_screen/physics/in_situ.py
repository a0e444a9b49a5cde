"""The in-situ state: effective stress and pore pressure before injection, with or without
gravity, and the tractions it puts on the fault (paper Eq. 1 at rest, Eq. 19 at t = 0).

The unknowns are changes from this state, so it must be in equilibrium by itself:
div(sigma' - alpha p0 I) + rho g = 0 in the rock, and the fault carries the projected in-situ
tractions. ``equilibrium_residual`` checks that on the assembled forces.
"""
from __future__ import annotations

import numpy as np

from ..scene import EDGES, SceneError
from .base import Term


#: pore-pressure coefficient k of each stress kind: total stress sigma = given - k p0 I
def _kind_coefficient(kind: str, alpha: float) -> float:
    return {"total": 0.0, "biot_effective": alpha, "fault_effective": 1.0}[kind]


class InSituState(Term):
    """Uniform in-situ stress and pore pressure (no gravity).

    The scene's stress is total, Biot-effective or fault-effective (``initial.stress_kind``);
    it is held here as the rock's Biot-effective stress sigma' = sigma + alpha p0 (intact rock's
    alpha), so the fault starts at sigma'_n0 = -sigma_nn - p0 whatever the kind."""

    def __init__(self, scene):
        self.initial = scene.initial
        given, kind = scene.initial.stress_and_kind
        alpha = scene.rock.biot_coefficient
        self.stress_kind = kind
        # Biot-effective at the reference point: given + (alpha - k) p0 on the normal components
        shift = (alpha - _kind_coefficient(kind, alpha)) * scene.initial.pore_pressure
        self.effective_stress = np.array(given, dtype=float) + np.array([shift, shift, 0.0])

    body_force = np.zeros(2)
    """Body force density rho g (N/m^3); zero without gravity."""

    def state(self, disc, xy: np.ndarray):
        """In-situ Biot-effective stress (n, 3: sxx', syy', sxy', Pa, tension +) and pore
        pressure (n,) at points ``xy``."""
        sig = np.broadcast_to(self.effective_stress, (len(xy), 3)).copy()
        return sig, np.full(len(xy), self.initial.pore_pressure)

    def fault_tractions(self, disc, xy, alpha):
        """In-situ (effective normal stress, compression +; shear stress; pore pressure) at fault
        points ``xy`` in rock of Biot coefficient ``alpha``. The rock's total stress
        sigma' - alpha p0 I balances the fault's sigma_n + p0 (Biot coefficient 1 on the fault)."""
        sig, p0 = self.state(disc, xy)
        t, n = disc.fault.tangent, disc.fault.normal
        snn = sig[:, 0] * n[0] ** 2 + sig[:, 1] * n[1] ** 2 + 2 * sig[:, 2] * n[0] * n[1]
        stn = (sig[:, 0] * t[0] * n[0] + sig[:, 1] * t[1] * n[1]
               + sig[:, 2] * (t[0] * n[1] + t[1] * n[0]))
        return -snn - (1.0 - alpha) * p0, stn, p0

    def equilibrium_residual(self, disc) -> tuple[float, float]:
        """Norm of the out-of-balance force of the in-situ state at the free interior
        displacement DOFs (N/m), and the norm of the forces it is made of."""
        r = np.zeros(disc.n_dofs)
        scale = np.zeros(disc.n_dofs)
        b = self.body_force
        for grp in disc.element_groups:
            els, Nu, gu, w, umap = grp.elements, grp.Nu, grp.grad_u, grp.w, grp.umap
            Nstd = grp.Np[:, :, :4]  # standard shape functions locate the quadrature points
            xe = disc.coords[disc.elements[els]]               # (ne, 4, 2)
            xq = np.einsum("eqa,eac->eqc", Nstd, xe)          # quadrature points
            sig, p0 = self.state(disc, xq.reshape(-1, 2))
            alpha = np.repeat(disc.el_alpha[els], xq.shape[1])
            sxx = (sig[:, 0] - alpha * p0).reshape(xq.shape[:2])
            syy = (sig[:, 1] - alpha * p0).reshape(xq.shape[:2])
            sxy = sig[:, 2].reshape(xq.shape[:2])
            fx = np.einsum("eq,eqb->eb", w * sxx, gu[..., 0]) + np.einsum("eq,eqb->eb", w * sxy, gu[..., 1])
            fy = np.einsum("eq,eqb->eb", w * sxy, gu[..., 0]) + np.einsum("eq,eqb->eb", w * syy, gu[..., 1])
            bx = np.einsum("eq,eqb->eb", w, Nu) * b[0]
            by = np.einsum("eq,eqb->eb", w, Nu) * b[1]
            local = np.empty((len(els), 2 * gu.shape[2]))
            local[:, 0::2], local[:, 1::2] = fx - bx, fy - by
            ok = umap >= 0
            np.add.at(r, umap[ok], local[ok])
            np.add.at(scale, umap[ok], np.abs(np.column_stack([bx, by]).reshape(local.shape)[ok])
                      + np.abs(local[ok]))
        fp = disc.fault_points
        if len(fp.s):
            t, n = disc.fault.tangent, disc.fault.normal
            traction = fp.tau0[:, None] * t[None, :] - (fp.sigma_n0 + fp.p0)[:, None] * n[None, :]
            # int N_i T_c over the fault, laid out like jump_dofs (x, y per node)
            local = (fp.weight[:, None, None] * fp.N[:, :, None] * traction[:, None, :]).reshape(len(fp.s), 8)
            ok = fp.jump_dofs >= 0
            np.add.at(r, fp.jump_dofs[ok], local[ok])
        # the outer edges carry the in-situ tractions by assumption (the surroundings hold them),
        # so the check is on the interior nodes and their enriched DOFs
        inner = np.ones(disc.mesh.n_nodes, dtype=bool)
        for edge in EDGES:
            inner[disc.mesh.edge_nodes(edge)] = False
        keep = np.zeros(disc.n_dofs, dtype=bool)
        nodes = np.flatnonzero(inner)
        keep[disc.blocks.u.start + 2 * nodes] = keep[disc.blocks.u.start + 2 * nodes + 1] = True
        h = disc.heav_index[nodes]
        h = h[h >= 0]
        keep[disc.blocks.a.start + 2 * h] = keep[disc.blocks.a.start + 2 * h + 1] = True
        keep &= ~disc.fixed
        return float(np.linalg.norm(r[keep])), float(np.linalg.norm(scale[keep]))

    def check(self, disc):
        if disc.has("u"):
            self.check_equilibrium(disc)

    def check_equilibrium(self, disc, rtol: float = 1e-8):
        """Refuse a scene whose in-situ state is not in equilibrium (the solution is written in
        changes from it, so an unbalanced state would drive deformation at t = 0)."""
        out, ref = self.equilibrium_residual(disc)
        if out > rtol * max(ref, 1e-300):
            raise SceneError(
                f"the in-situ state is not in equilibrium (out-of-balance {out:.3e} N/m against "
                f"forces of {ref:.3e} N/m): the stress gradient with depth assumes one Biot "
                f"coefficient, porosity and density; zones that change them break it")


class GravityInSituState(InSituState):
    """In-situ state under gravity: p0 grows by the hydrostatic gradient with depth
    d = g_hat . (x - x_ref); the effective stress along gravity by -(rho - alpha rho_f) g per
    metre (rho = n rho_f + (1 - n) rho_s, intact rock) and across it by lateral_stress_ratio
    times that, so that div(sigma' - alpha p0 I) + rho g = 0."""

    def __init__(self, scene):
        super().__init__(scene)
        ini, rk, fl = scene.initial, scene.rock, scene.fluid
        e = np.array(ini.gravity_direction, dtype=float)
        self.direction = e / np.linalg.norm(e)
        self.reference_point = ini.reference_point
        g = ini.gravity
        self.pressure_gradient = (ini.pore_pressure_gradient if ini.pore_pressure_gradient is not None
                                  else fl.density * g)
        rho = rk.porosity * fl.density + (1 - rk.porosity) * rk.density
        k_lat = (ini.lateral_stress_ratio if ini.lateral_stress_ratio is not None
                 else rk.poissons_ratio / (1 - rk.poissons_ratio))
        vertical = -(rho * g - rk.biot_coefficient * self.pressure_gradient)  # per metre of depth
        ep = np.array([-self.direction[1], self.direction[0]])
        self.stress_gradient = vertical * (np.outer(self.direction, self.direction) + k_lat * np.outer(ep, ep))
        self.body_force = rho * g * self.direction  # N/m^3

    def state(self, disc, xy):
        sig, p0 = super().state(disc, xy)
        ref = np.array(self.reference_point if self.reference_point is not None else disc.injection_xy)
        depth = (xy - ref) @ self.direction
        grad = self.stress_gradient
        sig[:, 0] += depth * grad[0, 0]
        sig[:, 1] += depth * grad[1, 1]
        sig[:, 2] += depth * grad[0, 1]
        p0 += self.pressure_gradient * depth
        return sig, p0

"""Quantities evaluated from a state vector at quadrature points, independently of the
assembled matrices (used for the fluid-volume balance and for output)."""
from __future__ import annotations

import numpy as np

from .model import Model


def _gather(x, dofs):
    return np.where(dofs >= 0, x[np.maximum(dofs, 0)], 0.0)


def fluid_volumes(model: Model, x: np.ndarray) -> dict:
    """Fluid volume stored since the in-situ state (m^3 per m thickness): in the rock,
    int (alpha eps_v + p/M) dOmega; in the fault, int (opening + storativity * p) ds."""
    m = model
    rock_vol = 0.0
    for g in m.element_groups():
        if m.has_u and m.has_p:
            u = _gather(x, g.umap)  # (ne, 2 nb)
            ux, uy = u[:, 0::2], u[:, 1::2]
            eps_v = (np.einsum("eqb,eb->eq", g.grad_u[..., 0], ux)
                     + np.einsum("eqb,eb->eq", g.grad_u[..., 1], uy))
            rock_vol += np.sum(g.w * m.el_alpha[g.elements][:, None] * eps_v)
        if m.has_p:
            pq = np.einsum("eqb,eb->eq", g.Np, _gather(x, g.pmap))
            rock_vol += np.sum(g.w * m.el_inv_M[g.elements][:, None] * pq)
    fault_vol = 0.0
    fp = m.fp
    if m.scene.effects.fault_flow or m.has_c:
        _, opening = m.fault_jump(x)
        fault_vol += np.sum(fp.weight * opening)
        if m.scene.effects.fault_flow:
            fault_vol += np.sum(fp.weight * m.fault_storativity * m.fault_overpressure(x))
    return {"rock": float(rock_vol), "fault": float(fault_vol)}

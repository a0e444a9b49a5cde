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
    groups = []
    if len(m.std_elements):
        groups.append(("std", m.std_elements, m.std_N, m.std_grad, m.std_w))
    if len(m.cut_elements):
        groups.append(("cut", m.cut_elements, m.cut_Np, m.cut_gu, m.cut_w))
    for name, els, Np, gu, w in groups:
        if m.has_u and m.has_p:
            u = _gather(x, getattr(m, f"{name}_umap"))  # (ne, 2 nb)
            ux, uy = u[:, 0::2], u[:, 1::2]
            eps_v = np.einsum("eqb,eb->eq", gu[..., 0], ux) + np.einsum("eqb,eb->eq", gu[..., 1], uy)
            rock_vol += np.sum(w * m.el_alpha[els][:, None] * eps_v)
        if m.has_p:
            p = _gather(x, getattr(m, f"{name}_pmap"))
            pq = np.einsum("eqb,eb->eq", Np, p)
            rock_vol += np.sum(w * m.el_inv_M[els][:, None] * pq)
    fault_vol = 0.0
    fp = m.fp
    if m.scene.effects.fault_flow or m.has_c:
        _, opening = m.fault_jump(x)
        fault_vol += np.sum(fp.weight * opening)
        if m.scene.effects.fault_flow:
            fault_vol += np.sum(fp.weight * m.fault_storativity * m.fault_overpressure(x))
    return {"rock": float(rock_vol), "fault": float(fault_vol)}

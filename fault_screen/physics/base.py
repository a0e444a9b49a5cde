"""What a physics term is: a small object that knows one equation of the model.

A term declares the unknown blocks it needs and adds its share to the places the solver
gathers: the constant matrices (integrals over the rock element group by element group, then
the rest) (``A`` acts on the unknowns at the new time, ``C`` on their
change over the step divided by dt, ``Hf`` is time-weighted by theta), the source vector, the
nonlinear residual and Jacobian, the fluid stored, and the fault state recorded each step.
Every hook has a do-nothing default, so a term overrides only what its equation touches.

Unknown blocks: ``u`` rock displacement, ``a`` Heaviside (fault jump) coefficients, ``p`` rock
pore pressure, ``c`` modified-level-set pressure enrichment, ``pf`` fault-pressure line, ``q``
injection multiplier (pressure control).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..assembly import TripletBuilder

BLOCK_ORDER = ("u", "a", "p", "c", "pf", "q")


@dataclass
class ConstantMatrices:
    """Builders of the matrices that stay fixed for the whole run, and the source vector."""
    A: TripletBuilder
    C: TripletBuilder
    Hf: TripletBuilder
    source: np.ndarray  # unit injection source (rate control): times the model fault's rate


def fault_jump_at(disc, x, point) -> tuple[np.ndarray, np.ndarray]:
    """(slip, opening) at the fault's points at ``x``, computed once per residual evaluation:
    ``point`` is that evaluation's fault state (a new dict for each x), so the first term that
    asks keeps them there for the others."""
    if "opening" not in point:
        point["slip"], point["opening"] = disc.fault_jump(x)
    return point["slip"], point["opening"]


class Term:
    """Base of all physics terms; see the module docstring for the hooks."""

    #: unknown blocks this term needs
    blocks: tuple[str, ...] = ()
    #: where the fluid this term stores is counted in the volume balance: "rock", "fault" or None
    fluid_store: str | None = None

    def zones(self, scene) -> tuple:
        """Material zones this term adds to the scene's own (``scene.Zone`` objects)."""
        return ()

    def refine_mesh(self, scene, mesh, zones):
        """The mesh the term needs, given the scene's (``zones``: every material zone)."""
        return mesh

    def assemble_bulk(self, disc, group, out: ConstantMatrices) -> None:
        """Add the term's constant matrices over one element group (``disc.element_groups``)."""

    def assemble(self, disc, out: ConstantMatrices) -> None:
        """Add the term's constant matrices that are not integrals over the rock (fault, point)."""

    def nonlinear_dofs(self, disc) -> np.ndarray:
        """Unknowns whose equations this term makes nonlinear."""
        return np.zeros(0, dtype=np.int64)

    def residual(self, disc, x, history, dt, time_weight, residual, point) -> tuple | None:
        """Nonlinear contribution at ``x``: added into ``residual``; returns Jacobian triplets
        (rows, cols, vals) or None, and writes its point-wise fault state into ``point``. A term
        whose triplets keep one pattern returns the same rows and cols arrays at every call
        (never changed in place): the solver then knows the pattern without comparing it."""
        return None

    def previous_step(self, disc, x_n, time_weight, residual) -> None:
        """Known part at the start of the step of a time-weighted nonlinear term."""

    def check(self, disc) -> None:
        """Refuse (SceneError) a discretised scene this term cannot start from."""

    def stored_volume_weights(self, disc) -> np.ndarray | None:
        """Weights w (n_dofs,) with stored volume = w . x (m^3 per m of thickness), for a term
        whose stored fluid is linear in the unknowns (every store today): the recorder forms
        them once instead of integrating the fields every step. None: not linear."""
        return None

    def stored_volume(self, disc, x) -> float:
        """Fluid volume (m^3 per m of thickness) this term stores since the in-situ state."""
        w = self.stored_volume_weights(disc)
        return 0.0 if w is None else float(w @ x)

"""The physics of a scene as a list of terms, one module per equation.

``terms_for(scene)`` is the one place that reads ``scene.effects`` (besides the scene's own
validation of effect combinations): it returns the terms the scene calls for, and nothing
else exists. Studies that switch effects (accuracy ladders, ensembles) ask ``effects_on``,
``SWITCHABLE`` and ``switches_implied_by`` here instead of reading the switches themselves. Numbering, assembly, the solver's nonlinear set, the fluid-volume balance and the
recorded fault state all loop over these terms, so an effect that is off costs nothing.

Which file holds which equation (Schwartzkopff et al. 2020):

=============================  =================================================================
``in_situ.py``                 in-situ stress and pore pressure, gravity; fault tractions at t=0
``rock.py``                    Eq. 1-2, 8-9: elasticity K, Biot coupling Q, storage S, Darcy H;
                               leak-off enrichment (Eq. 6-7); damage zone
``fault_flow.py``              Eq. 10, 16: fault storage (compressibility, opening), cubic-law
                               conduction (constant or Renshaw aperture, Eq. 28); Eq. 15 walls
``contact.py``                 Eq. 17-27, 32: penalty contact, Coulomb or rate(-and-state)
                               friction, dilation
``injection.py``               Eq. 10 (source), Eq. 29 (NoF): rate or pressure control
``leak_off_mesh.py``           leak-off resolved across the fault: mesh graded normal to it
``materials.py``               Eq. 1-2 constants: drained and constrained moduli, Biot modulus,
                               uniaxial storage and diffusivity
=============================  =================================================================
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, fields

from .base import BLOCK_ORDER, ConstantMatrices, Term
from .contact import Contact, CoulombFriction, RateStateFriction
from .fault_flow import (ConstantApertureConduction, EvolvingApertureConduction, FaultPressureOnWalls,
                         FaultStorage, OpeningStorage)
from .in_situ import GravityInSituState, InSituState
from .injection import PressureInjection, RateInjection
from .leak_off_mesh import LeakOffGrading
from .rock import BiotCoupling, DamageZone, DarcyRock, Elasticity, LeakOff

__all__ = ["Physics", "Term", "ConstantMatrices", "terms_for", "BLOCK_ORDER", "SWITCHABLE", "effects_on",
           "switches_implied_by"]

#: effects a study may switch off one at a time (the others define which model it is)
SWITCHABLE = ("fault_flow", "leak_off", "rate_friction", "state_evolution", "dilation",
              "aperture_evolution", "gravity", "damage_zone", "poroelastic")


def effects_on(scene) -> frozenset:
    """Names of the scene's effects that are switched on."""
    ef = scene.effects
    return frozenset(f.name for f in fields(ef) if getattr(ef, f.name))


def switches_implied_by(fault: dict) -> dict:
    """Effect switches (name -> False) that zero values of a ``[fault]`` table imply: a = 0 is
    constant friction (rate friction and state evolution off), a dilation angle of 0 is no
    dilation. Zero is the lower bound of both parameters in the paper's ranges, which the scene
    would otherwise refuse as a switch without its parameter."""
    off = {}
    if fault.get("rate_parameter", 1.0) == 0.0:
        off.update(rate_friction=False, state_evolution=False)
    if fault.get("dilation_angle", 1.0) == 0.0:
        off["dilation"] = False
    return off


@dataclass(frozen=True)
class Physics:
    """The terms of a scene, in assembly order."""
    terms: tuple[Term, ...]
    has_fault: bool

    @property
    def blocks(self) -> frozenset:
        return frozenset(b for t in self.terms for b in t.blocks)

    def zones(self, scene) -> tuple:
        return tuple(z for t in self.terms for z in t.zones(scene))

    def find(self, kind):
        """The term of type ``kind``, or None."""
        return next((t for t in self.terms if isinstance(t, kind)), None)

    # (found once: the stepper and the solver ask at every step; a cached_property writes the
    # instance's __dict__, which a frozen dataclass allows)
    @functools.cached_property
    def in_situ(self) -> InSituState:
        return self.find(InSituState)

    @functools.cached_property
    def contact(self) -> Contact | None:
        return self.find(Contact)

    @functools.cached_property
    def injection(self):
        return self.find(RateInjection) or self.find(PressureInjection)

    def graded_cut_height(self, scene) -> float:
        """Height across the fault of the element the leak-off grading makes the fault cut (m);
        0 when the mesh is not graded (no leak-off, grading off, a fault at an angle,
        impermeable rock)."""
        grading = self.find(LeakOffGrading)
        return 0.0 if grading is None else grading.cut_height(scene, self.zones(scene) + tuple(scene.zones))

    def refine_mesh(self, scene, mesh):
        """The scene's mesh as the terms need it (e.g. graded across the fault)."""
        zones = self.zones(scene) + tuple(scene.zones)
        for t in self.terms:
            mesh = t.refine_mesh(scene, mesh, zones)
        return mesh

    def names(self) -> list[str]:
        return [type(t).__name__ for t in self.terms]


def terms_for(scene) -> Physics:
    """The physics terms that ``scene.effects`` (and the injection control) call for."""
    ef = scene.effects
    terms: list[Term] = [(GravityInSituState if ef.gravity else InSituState)(scene)]
    if ef.damage_zone:
        terms.append(DamageZone(scene))
    if ef.mechanics:
        terms.append(Elasticity())
    if ef.mechanics and ef.poroelastic:
        terms.append(BiotCoupling())
    if ef.poroelastic:
        terms.append(DarcyRock())
    if ef.fault:
        if ef.leak_off:
            terms.append(LeakOff())
            terms.append(LeakOffGrading(scene, mechanics=ef.mechanics))
        line = not ef.leak_off  # the fault's own pressure line, else the rock pressure's trace
        if ef.fault_flow:
            terms.append(FaultStorage(scene, line))
            conduction = EvolvingApertureConduction if ef.aperture_evolution else ConstantApertureConduction
            terms.append(conduction(scene, line))
        if ef.mechanics:
            if ef.fault_flow or ef.leak_off:
                terms.append(OpeningStorage())
            terms.append(FaultPressureOnWalls())
            law = (RateStateFriction(scene, dilation=ef.dilation, state_evolution=ef.state_evolution)
                   if ef.rate_friction else CoulombFriction(scene, dilation=ef.dilation))
            terms.append(Contact(law))
        terms.append(PressureInjection(scene) if scene.injection.control == "pressure"
                     else RateInjection(scene))
    return Physics(tuple(terms), has_fault=ef.fault)

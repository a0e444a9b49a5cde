"""Fluid injected into the fault at one point (paper Eq. 10, last term; Eq. 29).

Rate control: the interval's flow rate is shared by NoF parallel fractures (Eq. 29), so the
model fault receives volume / (dt NoF) over a step, as a point source on the fault-pressure
basis. Pressure control: a Lagrange multiplier holds the injection-point overpressure; the
multiplier is the injection rate into the model fault.
"""
from __future__ import annotations

import numpy as np

from .base import Term


class RateInjection(Term):
    """Point source of the step's volume: rate into the model fault = volume / dt / NoF
    (Eq. 29), m^2/s per m of thickness."""

    control = "rate"

    def __init__(self, scene):
        self.number_of_fractures = scene.injection.number_of_fractures

    def assemble(self, disc, out):
        inj = disc.injection
        ok = inj.p_dofs >= 0
        out.source[inj.p_dofs[ok]] = inj.Np[ok]

    def model_rate(self, volume, dt):
        """Rate into the model fault (m^2/s) of ``volume`` (m^3, whole interval) over dt."""
        return volume / dt / self.number_of_fractures

    def load(self, disc, source, rhs, volume, dt, time_weight):
        """Right-hand side of the step: the step-average rate (the same at both ends)."""
        rate = self.model_rate(volume, dt)
        # on the injection point's rows alone (the rest of ``source`` is zero)
        at = disc.injection.p_dofs[disc.injection.p_dofs >= 0]
        rhs[at] += source[at] * (time_weight * rate + (1.0 - time_weight) * rate)

    def model_fault_rate(self, disc, x, x_n, volume, dt, time_weight):
        """Rate into the model fault over the step (m^2/s); times NoF: the interval's."""
        return self.model_rate(volume, dt)


class PressureInjection(Term):
    """Pressure control: the multiplier row prescribes the injection-point overpressure
    (Np . p = value) and its column injects the multiplier (the rate into the model fault)
    at the injection point."""

    control = "pressure"
    blocks = ("q",)

    def __init__(self, scene):
        self.number_of_fractures = scene.injection.number_of_fractures

    def assemble(self, disc, out):
        q = disc.blocks.q.start
        inj = disc.injection
        rows = inj.p_dofs[None, :]
        out.Hf.add(-inj.Np[None, :, None], rows, np.array([[q]]))
        out.A.add(inj.Np[None, None, :], np.array([[q]]), rows)

    def load(self, disc, source, rhs, overpressure, dt, time_weight):
        rhs[disc.blocks.q.start] += overpressure

    def model_fault_rate(self, disc, x, x_n, overpressure, dt, time_weight):
        """The multiplier, time-weighted over the step (m^2/s)."""
        q = disc.blocks.q.start
        return time_weight * x[q] + (1 - time_weight) * x_n[q]

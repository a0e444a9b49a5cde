"""The fault's walls in contact: penalty contact with friction (paper Eq. 17-27, 32), with
dilation (Eq. 21) through the cumulative plastic slip.

The friction laws share one signature, ``law(slip, opening, history, sigma_n0, dt) ->
(traction, contact_state, tangent, new_history)`` (arrays over the fault points; layouts in
``kernels.contact``): Coulomb (rate-independent) or regularised rate(-and-state) friction.
"""
from __future__ import annotations

import numpy as np

from ..kernels import contact as kc
from .base import Term


#: Slip rate above which a point of a rate-friction fault counts as sliding (its contact state),
#: m/s: the order of tectonic loading rates (~1e-9 m/s, ~3 cm/yr), far above the creep of a
#: fault at rest under the regularised law (~1e-12 m/s in the bundled scenes). Screening
#: thresholds are the scene's [monitor] table, not this.
SLIDING_SLIP_RATE = 1e-9


class FrictionLaw:
    """Parameters of a friction law as one plain array, and the kernel that applies it."""

    kernel = staticmethod(kc.coulomb_law)
    #: Does the law have a slip-rate scale? Only then is the slip rate a state of the model
    #: that can run away (a quasi-static instability); under rate-independent Coulomb friction
    #: it is the loading's and the time step's (slip increment over dt).
    rate_dependent = False

    def __init__(self, scene, *, dilation: bool):
        f = scene.fault
        p = np.zeros(9)
        p[kc.KN], p[kc.KT] = f.normal_stiffness, f.shear_stiffness
        p[kc.TAN_DILATION] = np.tan(np.radians(f.dilation_angle)) if dilation else 0.0
        p[kc.MU0] = f.friction
        p[kc.V_REF], p[kc.D_C] = f.reference_velocity, f.critical_slip_distance
        p[kc.SLIDING_RATE] = SLIDING_SLIP_RATE
        self.params = p
        self.initial_state_variable = (f.initial_state if f.initial_state is not None
                                       else f.critical_slip_distance / f.reference_velocity)

    def __call__(self, slip, opening, history, sigma_n0, dt):
        return self.kernel(self.params, slip, opening, history, sigma_n0, dt)

    def max_step(self, slip_rate) -> float:
        """Largest next step (s) the law allows after a step with these slip rates: no limit."""
        return np.inf


class CoulombFriction(FrictionLaw):
    """Constant friction mu0 (Eq. 17, 24-25)."""


class RateStateFriction(FrictionLaw):
    """mu0 + a ln(V/V0) (Eq. 32), + b ln(V0 theta/Dc) with the aging law (Eq. 18) when
    ``state_evolution``; regularised near V = 0 (kernels.friction)."""

    kernel = staticmethod(kc.rate_state_law)
    rate_dependent = True
    #: With state evolution a step may slip at most this fraction of Dc at the peak slip rate
    #: (dt <= fraction Dc / V_max; Lapusta et al. 2000 use 0.25-0.5): a longer step averages the
    #: state over a slip that changes it, and steps over the acceleration of a velocity-weakening
    #: patch instead of following it to the instability.
    STATE_SLIP_FRACTION = 0.5

    def max_step(self, slip_rate) -> float:
        """Largest next step (s) the law allows after a step with these slip rates (m/s)."""
        b, dc = self.params[kc.STATE_B], self.params[kc.D_C]
        v = float(np.max(np.abs(slip_rate))) if np.size(slip_rate) else 0.0
        if b == 0.0 or v == 0.0:
            return np.inf
        return self.STATE_SLIP_FRACTION * dc / v

    def __init__(self, scene, *, dilation: bool, state_evolution: bool):
        super().__init__(scene, dilation=dilation)
        f = scene.fault
        self.params[kc.RATE_A] = f.rate_parameter
        self.params[kc.STATE_B] = f.state_parameter if state_evolution else 0.0


class Contact(Term):
    """Penalty contact on the Heaviside DOFs (Eq. 19-27): the change of contact traction from
    the in-situ state, int N^T [(tau - tau0) t - (sigma_n - sigma_n0) n] ds, N per m; the walls
    carry the fault's effective stress, its fluid pressure is FaultPressureOnWalls'."""
    blocks = ("a",)

    def __init__(self, law: FrictionLaw):
        self.law = law

    def initial_history(self, disc) -> np.ndarray:
        """Fault at rest: no slip, the in-situ shear traction, no plastic slip, state theta0."""
        fp = disc.fault_points
        h = np.zeros((len(fp.s), 4))
        h[:, kc.H_TAU] = fp.tau0
        h[:, kc.H_STATE] = self.law.initial_state_variable
        return h

    def nonlinear_dofs(self, disc):
        return np.arange(disc.blocks.a.start, disc.blocks.a.stop)

    def residual(self, disc, x, history, dt, time_weight, residual, point):
        fp = disc.fault_points
        slip, opening = disc.fault_jump(x)
        traction, contact_state, tangent, new_history = self.law(slip, opening, history, fp.sigma_n0, dt)
        rows, cols, vals = kc.assemble_contact(fp.N, fp.jump_dofs, disc.fault.tangent, disc.fault.normal,
                                               fp.weight, traction, fp.tau0, fp.sigma_n0, tangent, residual)
        point.update(slip=slip, opening=opening, shear_traction=traction[:, 0],
                     effective_normal_stress=traction[:, 1], friction=traction[:, 2],
                     contact_state=contact_state, history=new_history)
        return rows, cols, vals

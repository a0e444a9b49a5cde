"""The fault's walls in contact: penalty contact with friction (paper Eq. 17-27, 32), with
dilation (Eq. 21) through the cumulative plastic slip.

The friction laws share one signature, ``law(slip, opening, history, sigma_n0, dt) ->
(traction, contact_state, tangent, new_history)`` (arrays over the fault points; layouts in
``kernels.contact``): Coulomb (rate-independent) or regularised rate(-and-state) friction.
"""
from __future__ import annotations

import numpy as np

from ..kernels import contact as kc
from .base import Term, fault_jump_at


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
        if b == 0.0:   # (no state evolution: no limit, whatever the rates)
            return np.inf
        v = float(np.max(np.abs(slip_rate))) if np.size(slip_rate) else 0.0
        if v == 0.0:
            return np.inf
        return self.STATE_SLIP_FRACTION * dc / v

    def __init__(self, scene, *, dilation: bool, state_evolution: bool):
        super().__init__(scene, dilation=dilation)
        f = scene.fault
        self.params[kc.RATE_A] = f.rate_parameter
        self.params[kc.STATE_B] = f.state_parameter if state_evolution else 0.0


def failure_state(disc, mu0: float) -> dict:
    """The in-situ state of the fault at the injection point (SI; stresses compression +):
    total normal stress, pore pressure, effective normal stress, shear stress, mu0, and the
    overpressure that brings it to failure, (mu0 sigma'_n0 - |tau0|) / mu0."""
    g = disc.injection.nearest_point
    alpha = disc.el_alpha[disc.cut_elements[disc.fault.gp_element[g]]]
    sigma_n0, tau0, p0 = disc.in_situ.fault_tractions(disc, disc.injection.xy[None, :], np.array([alpha]))
    sn, tau, p = float(sigma_n0[0]), float(tau0[0]), float(p0[0])
    return {"total_normal_stress": sn + p, "pore_pressure": p, "effective_normal_stress": sn,
            "shear_stress": tau, "friction": mu0, "overpressure_to_failure": (mu0 * sn - abs(tau)) / mu0}


class Contact(Term):
    """Penalty contact on the Heaviside DOFs (Eq. 19-27): the change of contact traction from
    the in-situ state, int N^T [(tau - tau0) t - (sigma_n - sigma_n0) n] ds, N per m; the walls
    carry the fault's effective stress, its fluid pressure is FaultPressureOnWalls'."""
    blocks = ("a",)

    def __init__(self, law: FrictionLaw):
        self.law = law
        self._pattern = None   # the tangent's rows and columns (``pattern``)

    def initial_history(self, disc) -> np.ndarray:
        """Fault at rest: no slip, the in-situ shear traction, no plastic slip, state theta0."""
        fp = disc.fault_points
        h = np.zeros((len(fp.s), 4))
        h[:, kc.H_TAU] = fp.tau0
        h[:, kc.H_STATE] = self.law.initial_state_variable
        return h

    def nonlinear_dofs(self, disc):
        return np.arange(disc.blocks.a.start, disc.blocks.a.stop)

    def check(self, disc):
        """A fault that the in-situ state puts beyond failure at t = 0 cannot start from rest."""
        fp = disc.fault_points
        mu0 = self.law.params[kc.MU0]
        if not len(fp.s):
            return
        # beyond failure: shear above the strength by more than round-off (a stress-free fault,
        # 0 <= 0, is at rest; a fault in tension is not)
        excess = np.abs(fp.tau0) - mu0 * fp.sigma_n0
        scale = np.maximum(np.abs(fp.tau0), np.abs(fp.sigma_n0))
        beyond = excess > 1e-12 * scale
        if not beyond.any():
            return
        worst = int(np.argmax(np.where(beyond, excess / np.maximum(scale, 1.0), -np.inf)))
        from ..scene import SceneError

        st = failure_state(disc, mu0)
        if st["overpressure_to_failure"] < 0:
            where = "at the injection point"
            tau, sn = abs(st["shear_stress"]), st["effective_normal_stress"]
        else:
            where = f"at s = {fp.s[worst]:.4g} m along the fault"
            tau, sn = abs(fp.tau0[worst]), fp.sigma_n0[worst]
        ratio = f"{tau / sn:.3g}" if sn > 0 else "inf (no effective normal stress)"
        raise SceneError(
            f"the in-situ state puts the fault beyond failure at t = 0 {where}: |tau0| = "
            f"{tau / 1e6:.4g} MPa, sigma'_n0 = {sn / 1e6:.4g} MPa, |tau0| / sigma'_n0 = {ratio} > "
            f"mu0 = {mu0:g} (initial.stress_kind = {disc.in_situ.stress_kind!r}); check the kind of "
            f"stress the numbers are (total stresses minus the pore pressure give the fault's "
            f"effective stress) and the values")

    def pattern(self, disc):
        """Rows and columns of the tangent's triplets (``kc.assemble_contact``'s order: per point,
        every pair of its Heaviside DOFs), made once: the same arrays at every call."""
        if self._pattern is None:
            jump = disc.fault_points.jump_dofs
            rows = np.repeat(jump, jump.shape[1], axis=1)   # (point, a b): DOF a
            cols = np.tile(jump, (1, jump.shape[1]))        # DOF b
            kept = (rows >= 0) & (cols >= 0)
            self._pattern = (rows[kept].astype(np.int64), cols[kept].astype(np.int64))
        return self._pattern

    def residual(self, disc, x, history, dt, time_weight, residual, point):
        fp = disc.fault_points
        slip, opening = fault_jump_at(disc, x, point)
        traction, contact_state, tangent, new_history = self.law(slip, opening, history, fp.sigma_n0, dt)
        vals = kc.assemble_contact(fp.N, fp.jump_dofs, disc.fault.tangent, disc.fault.normal,
                                   fp.weight, traction, fp.tau0, fp.sigma_n0, tangent, residual)
        rows, cols = self.pattern(disc)
        point.update(slip=slip, opening=opening, shear_traction=traction[:, 0],
                     effective_normal_stress=traction[:, 1], friction=traction[:, 2],
                     contact_state=contact_state, history=new_history)
        return rows, cols, vals

"""One implicit time step: Newton-Raphson on the coupled residual with its consistent Jacobian,
solved by a sparse direct LU on a symmetrically scaled system.

Scaling: rows and columns of the free block are scaled by 1/sqrt(|J_ii|) (row maximum where
the diagonal is zero, as for the injection multiplier). This equilibrates displacements (m,
stiffness ~1e10 Pa) against pressures (Pa, conductance ~1e-16) and keeps Heaviside DOFs whose
support is cut into a thin sliver well conditioned (the Jacobi part of Béchet et al. 2005).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .kernels.contact import assemble_contact, coulomb_law, fault_jumps, rate_state_law
from .kernels.fault_flow import assemble_evolving_conduction
from .model import Model


class StepFailed(RuntimeError):
    """Newton did not converge (or produced non-finite values) within the iteration limit."""


@dataclass
class ContactState:
    """Converged history at the fault Gauss points: total slip and shear traction (for the
    incremental tangential return map), cumulative plastic slip (dilation) and friction state."""
    slip: np.ndarray
    tau: np.ndarray
    dilatant_slip: np.ndarray
    theta: np.ndarray

    @classmethod
    def initial(cls, model: Model) -> "ContactState":
        fp = model.fp
        ng = len(fp.s)
        f = model.scene.fault
        theta0 = f.initial_state if f.initial_state is not None else f.critical_slip_distance / f.reference_velocity
        return cls(np.zeros(ng), fp.tau0.copy(), np.zeros(ng), np.full(ng, theta0))


class CoulombFriction:
    """Constant friction mu0 (effects.rate_friction off)."""

    def __init__(self, model: Model):
        f = model.scene.fault
        ng = len(model.fp.s)
        self.mu = np.full(ng, f.friction)
        self.kN, self.kT = f.normal_stiffness, f.shear_stiffness
        self.tan_dilation = np.tan(np.radians(f.dilation_angle)) if model.scene.effects.dilation else 0.0
        self.sigma_n0 = model.fp.sigma_n0

    def __call__(self, slip, opening, hist: ContactState, dt):
        tau, sn, state, ds, tangent = coulomb_law(slip, opening, hist.slip, hist.tau, hist.dilatant_slip,
                                                  self.sigma_n0, self.kN, self.kT, self.mu,
                                                  self.tan_dilation)
        return tau, sn, state, ds, hist.theta, self.mu, tangent


class RateStateFriction(CoulombFriction):
    """mu0 + a ln(V/V0) (+ b ln(V0 theta/Dc) with the aging law), regularised (kernels.friction)."""

    def __init__(self, model: Model):
        super().__init__(model)
        f = model.scene.fault
        self.params = (f.friction, f.rate_parameter,
                       f.state_parameter if model.scene.effects.state_evolution else 0.0,
                       f.reference_velocity, f.critical_slip_distance)
        self.threshold = f.slip_rate_threshold

    def __call__(self, slip, opening, hist: ContactState, dt):
        mu0, a, b, V0, Dc = self.params
        tau, sn, state, ds, theta, mu, tangent = rate_state_law(
            slip, opening, hist.slip, hist.tau, hist.dilatant_slip, hist.theta, self.sigma_n0,
            self.kN, self.kT, self.tan_dilation, mu0, a, b, V0, Dc, dt, self.threshold)
        return tau, sn, state, ds, theta, mu, tangent


@dataclass
class StepOutcome:
    x: np.ndarray
    iterations: int
    factorizations: int
    slip: np.ndarray
    opening: np.ndarray
    tau: np.ndarray
    sigma_n: np.ndarray
    state: np.ndarray
    reactions: np.ndarray
    history: ContactState
    friction: np.ndarray
    aperture: np.ndarray


class NewtonSolver:
    """Newton on the coupled residual, with the linear bulk condensed onto the fault.

    Only the fault terms are nonlinear: contact and friction act on the Heaviside DOFs alone, and
    the evolving-aperture conduction (when switched on) on the fault-pressure DOFs and the
    Heaviside DOFs. The free unknowns are split into those (N, a few hundred) and everything else
    (B: rock displacement, rock pressure, and the remaining flow unknowns), whose Jacobian block is
    constant for a given time step. B is factorised once per step size and its Schur complement on N is formed once;
    each Newton iteration then costs two sparse triangular solves and a small dense solve.
    """

    def __init__(self, model: Model):
        self.model = model
        s = model.scene
        self.theta = s.time.theta
        self.tol = s.solver.tolerance
        self.max_it = s.solver.max_iterations
        self._dt = None
        self.free = model.free
        b = model.blocks
        mech = np.zeros(model.n_dofs, dtype=bool)
        mech[b.u] = True
        mech[b.a] = True
        self.mech_free = mech[self.free]
        nonlinear = np.zeros(model.n_dofs, dtype=bool)
        nonlinear[b.a] = True
        # without rock pore pressure, the flow unknowns (fault line, multiplier) join the condensed
        # set so that the remaining block (rock displacements) is independent of the step size
        self.static_B = model.has_u and not model.has_p
        if self.static_B:
            nonlinear[b.pf] = True
            nonlinear[b.q] = True
        sc = model.scene
        self.evolving_aperture = sc.effects.aperture_evolution and model.has_fault and sc.effects.fault_flow
        if self.evolving_aperture:  # the fault conduction depends on the opening
            pd = model.fp.p_dofs
            nonlinear[pd[pd >= 0]] = True
        self.friction_law = (RateStateFriction if sc.effects.rate_friction else CoulombFriction)(model)
        self.scale = None
        self.lu_B = None
        nl_free = nonlinear[self.free]
        self.N = self.free[nl_free]
        self.B = self.free[~nl_free]
        # position of each global DOF in N (for the contact tangent), -1 elsewhere
        self.n_index = np.full(model.n_dofs, -1, dtype=np.int64)
        self.n_index[self.N] = np.arange(len(self.N))
        self.factorizations = 0

    def fault_terms(self, x, hist: ContactState, dt, residual):
        """Nonlinear fault terms at x: contact (and evolving-aperture conduction) added into
        ``residual``; returns their Jacobian triplets and the point-wise fault state."""
        m = self.model
        fp = m.fp
        ng = len(fp.s)
        empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0))
        point = {"slip": np.zeros(ng), "opening": np.zeros(ng), "aperture": None}
        rows, cols, vals = [empty[0]], [empty[1]], [empty[2]]
        if m.has_u:
            slip, opening = fault_jumps(x, fp.N, fp.jump_dofs, m.fault.tangent, m.fault.normal)
            tau, sn, state, ds, theta, mu, tangent = self.friction_law(slip, opening, hist, dt)
            r, c, v = assemble_contact(fp.N, fp.jump_dofs, m.fault.tangent, m.fault.normal,
                                       fp.weight, tau, sn, fp.tau0, fp.sigma_n0, tangent, residual)
            rows.append(r), cols.append(c), vals.append(v)
            point.update(slip=slip, opening=opening, tau=tau, sigma_n=sn, state=state, ds=ds,
                         theta=theta, mu=mu)
        if self.evolving_aperture:
            r, c, v, aperture = self._evolving_conduction(x, self.theta, residual)
            rows.append(r), cols.append(c), vals.append(v)
            point["aperture"] = aperture
        return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals), point

    def _evolving_conduction(self, x, weight, residual):
        """Fault conduction with the aperture of the opening at x, times ``weight``."""
        m, f = self.model, self.model.scene.fault
        fp = m.fp
        return assemble_evolving_conduction(x, fp.N, fp.jump_dofs, fp.Np, fp.dNp_ds, fp.p_dofs,
                                            m.fault.normal, fp.weight, f.hydraulic_aperture,
                                            f.asperity_height_std, m.scene.fluid.viscosity,
                                            f.kappa, weight, residual)

    def old_conduction(self, x_n):
        """(1 - theta) times the evolving-aperture conduction at the start of the step."""
        out = np.zeros(self.model.n_dofs)
        if self.evolving_aperture and self.theta < 1.0:
            self._evolving_conduction(x_n, 1.0 - self.theta, out)
        return out

    def _prepare(self, dt, x_n, hist):
        """Factorise the linear block for step size ``dt`` and form its Schur complement.

        The scaling is fixed at the first step. When the rock has no pore pressure, B holds only
        rock displacements, whose block does not depend on dt: it is factorised once and the
        Schur complement is rebuilt for a new dt from three precomputed dense products."""
        if dt == self._dt:
            return
        m = self.model
        L = (m.A + m.C * (1.0 / dt) + m.Hf * self.theta).tocsr()
        if self.scale is None:
            diag = np.abs(L.diagonal())
            if m.has_u or self.evolving_aperture:  # nonlinear stiffness belongs in the scaling
                rows, cols, vals, _ = self.fault_terms(x_n, hist, dt, np.zeros(m.n_dofs))
                on_diag = rows == cols
                np.add.at(diag, rows[on_diag], np.abs(vals[on_diag]))
            zero = diag == 0.0
            if zero.any():
                rowmax = abs(L).max(axis=1).toarray().ravel()
                diag[zero] = rowmax[zero]
            diag[diag == 0.0] = 1.0
            self.scale = 1.0 / np.sqrt(diag)
            self._D = sp.diags(self.scale)
        D = self._D
        B, N = self.B, self.N
        Ls = (D @ L @ D).tocsr()
        LsN = Ls[N]
        self.L_NB = LsN[:, B].tocsr()
        self.L_BN = Ls[B][:, N].tocsc()
        if self.static_B:
            if self.lu_B is None:
                self.lu_B = spla.splu(Ls[B][:, B].tocsc(), permc_spec="MMD_ATA")
                self.factorizations += 1
                parts = [(D @ M @ D).tocsr()[N][:, B] for M in (m.A, m.C, m.Hf)]
                self._P = [np.zeros((len(N), len(N))) for _ in parts]
                for j0 in range(0, len(N), 256):
                    X = self.lu_B.solve(self.L_BN[:, j0:j0 + 256].toarray())
                    for P, part in zip(self._P, parts):
                        P[:, j0:j0 + 256] = part @ X
            P0, P1, P2 = self._P
            self.schur = LsN[:, N].toarray() - (P0 + P1 / dt + self.theta * P2)
        else:
            self.lu_B = spla.splu(Ls[B][:, B].tocsc(), permc_spec="MMD_ATA")
            self.factorizations += 1
            if len(N):
                schur = LsN[:, N].toarray()
                for j0 in range(0, len(N), 256):
                    schur[:, j0:j0 + 256] -= self.L_NB @ self.lu_B.solve(self.L_BN[:, j0:j0 + 256].toarray())
                self.schur = schur
        self.L = L
        self._dt = dt

    def _solve(self, sR, kc):
        """Solve (scaled) J dx = -sR with J = L + contact tangent (on N only)."""
        B, N = self.B, self.N
        rB = -sR[B]
        if not len(N):
            out = np.zeros_like(sR)
            out[B] = self.lu_B.solve(rB)
            return out
        rN = -sR[N]
        yB = self.lu_B.solve(rB)
        dxN = kc.solve(rN - self.L_NB @ yB)
        dxB = self.lu_B.solve(rB - self.L_BN @ dxN)
        out = np.zeros_like(sR)
        out[B] = dxB
        out[N] = dxN
        return out

    def step(self, x_n, hist: ContactState, dt, load, source_rate, source_rate_old, prescribed_q):
        """Advance from x_n over dt. ``load``: applied nodal forces at n+1; ``source_rate``:
        injection rate into the model fault (m^2/s) at n+1 and n (rate control); ``prescribed_q``:
        the constraint value of the multiplier row (overpressure, pressure control)."""
        m = self.model
        th = self.theta
        self._prepare(dt, x_n, hist)
        L = self.L
        scale = self.scale
        rhs = (m.C @ x_n) / dt - (1.0 - th) * (m.Hf @ x_n) + load
        rhs = rhs + m.source_vector * (th * source_rate + (1.0 - th) * source_rate_old)
        if m.has_q:
            rhs[m.blocks.q.start] += prescribed_q
        rhs -= self.old_conduction(x_n)
        x = x_n.copy()
        free = self.free
        ref0 = None
        kc = None
        last_vals = None
        n_fact = 0
        for it in range(self.max_it + 1):
            R = L @ x - rhs
            rows, cols, vals, point = self.fault_terms(x, hist, dt, R)
            sR = scale * R
            if not np.all(np.isfinite(sR[free])):
                raise StepFailed("non-finite residual")
            mf = self.mech_free
            sRf = sR[free]
            norms = (np.linalg.norm(sRf[mf]), np.linalg.norm(sRf[~mf]))
            if ref0 is None:
                ref0 = norms
            # reference magnitudes at the current iterate: internal forces (mechanics);
            # stored-volume rate plus conduction plus sources (flow)
            s_mech = (scale * (m.A @ x))[free]
            s_flow = (scale * (np.abs(m.C @ (x - x_n)) / dt + np.abs(m.Hf @ x)
                               + np.abs(rhs - (m.C @ x_n) / dt)))[free]
            ref = (max(ref0[0], np.linalg.norm(s_mech[mf])), max(ref0[1], np.linalg.norm(s_flow[~mf])))
            if it > 0 or max(norms) == 0.0:
                if norms[0] <= self.tol * ref[0] and norms[1] <= self.tol * ref[1]:
                    return self._outcome(x, it, n_fact, R, point, hist)
            if it == self.max_it:
                break
            if kc is None or len(vals) != len(last_vals) or np.any(vals != last_vals):
                kc = self._contact_system(rows, cols, vals)
                last_vals = vals
                n_fact += 1
            dx = scale * self._solve(sR, kc)
            if not np.all(np.isfinite(dx)):
                raise StepFailed("non-finite Newton update")
            x += dx
        raise StepFailed(f"Newton did not converge in {self.max_it} iterations "
                         f"(scaled residuals {norms[0]:.3e}, {norms[1]:.3e})")

    def _outcome(self, x, it, n_fact, R, point, hist):
        m = self.model
        ng = len(m.fp.s)
        reactions = np.zeros(m.n_dofs)
        reactions[m.fixed] = R[m.fixed]
        if m.has_u:
            new_hist = ContactState(point["slip"].copy(), point["tau"].copy(),
                                    hist.dilatant_slip + point["ds"], point["theta"].copy())
            tau, sn, state, mu = point["tau"], point["sigma_n"], point["state"], point["mu"]
        else:
            new_hist = hist
            tau, sn = m.fp.tau0.copy(), m.fp.sigma_n0 - m.fault_overpressure(x)
            state, mu = np.zeros(ng, dtype=np.int64), np.full(ng, m.scene.fault.friction)
        aperture = point["aperture"]
        if aperture is None:
            aperture = np.full(ng, m.scene.fault.hydraulic_aperture)
        return StepOutcome(x, it, n_fact, point["slip"], point["opening"], tau, sn, state,
                           reactions, new_hist, np.asarray(mu).copy(), aperture)

    def _contact_system(self, rows, cols, vals):
        """Dense LU of the condensed system: Schur complement plus scaled contact tangent."""
        if not len(self.N):
            return None
        M = self.schur.copy()
        r = self.n_index[rows]
        c = self.n_index[cols]
        ok = (r >= 0) & (c >= 0)
        np.add.at(M, (r[ok], c[ok]), vals[ok] * self.scale[rows[ok]] * self.scale[cols[ok]])
        return _DenseLU(M)


class _DenseLU:
    def __init__(self, M):
        self.factors = scipy.linalg.lu_factor(M, check_finite=False)

    def solve(self, b):
        return scipy.linalg.lu_solve(self.factors, b, check_finite=False)

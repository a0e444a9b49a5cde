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

from .kernels.contact import assemble_contact
from .model import Model


class StepFailed(RuntimeError):
    """Newton did not converge (or produced non-finite values) within the iteration limit."""


@dataclass
class ContactState:
    """Converged contact history at the fault Gauss points."""
    slip: np.ndarray
    tau: np.ndarray

    def copy(self):
        return ContactState(self.slip.copy(), self.tau.copy())


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


class NewtonSolver:
    """Newton on the coupled residual, with the linear bulk condensed onto the fault.

    Only the contact forces are nonlinear, and they act on the Heaviside DOFs alone. The free
    unknowns are split into those (N, a few hundred) and everything else (B: rock displacement,
    pressures, fault pressure, injection multiplier), whose Jacobian block is constant for a given
    time step. B is factorised once per step size and its Schur complement on N is formed once;
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
        self.scale = None
        self.lu_B = None
        nl_free = nonlinear[self.free]
        self.N = self.free[nl_free]
        self.B = self.free[~nl_free]
        # position of each global DOF in N (for the contact tangent), -1 elsewhere
        self.n_index = np.full(model.n_dofs, -1, dtype=np.int64)
        self.n_index[self.N] = np.arange(len(self.N))
        ng = len(model.fp.s)
        self.friction = np.full(ng, s.fault.friction)
        self.factorizations = 0

    def contact(self, x, hist: ContactState, residual):
        m = self.model
        fp = m.fp
        s = m.scene.fault
        return assemble_contact(x, fp.N, fp.jump_dofs, m.fault.tangent, m.fault.normal, fp.weight,
                                hist.slip, hist.tau, fp.sigma_n0, fp.tau0, s.normal_stiffness,
                                s.shear_stiffness, self.friction, residual)

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
            if m.has_u:  # contact stiffness belongs in the scaling of the Heaviside DOFs
                rows, cols, vals, *_ = self.contact(x_n, hist, np.zeros(m.n_dofs))
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
        x = x_n.copy()
        free = self.free
        ref0 = None
        kc = None
        last_vals = None
        n_fact = 0
        ng = len(m.fp.s)
        zeros = np.zeros(ng)
        for it in range(self.max_it + 1):
            R = L @ x - rhs
            if m.has_u:
                rows, cols, vals, slip, opening, tau, sn, state = self.contact(x, hist, R)
            else:
                rows = cols = np.zeros(0, dtype=np.int64)
                vals = np.zeros(0)
                slip, opening, tau, sn = zeros, zeros, zeros, zeros
                state = np.zeros(ng, dtype=np.int64)
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
                    reactions = np.zeros(m.n_dofs)
                    reactions[m.fixed] = R[m.fixed]
                    return StepOutcome(x, it, n_fact, slip, opening, tau, sn, state, reactions)
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

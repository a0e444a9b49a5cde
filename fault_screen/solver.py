"""One implicit time step: Newton-Raphson on the coupled residual with its consistent Jacobian,
solved by a sparse direct LU on a symmetrically scaled system.

Residual of a step from x_n over dt (theta = ``time_weight`` of the flow terms)::

    R(x) = A x + C (x - x_n)/dt + Hf (theta x + (1 - theta) x_n) - load - sources
           + sum of the nonlinear terms' contributions (contact, evolving-aperture conduction)

Scaling: rows and columns of the free block are scaled by 1/sqrt(|J_ii|) (row maximum where
the diagonal is zero, as for the injection multiplier). This equilibrates displacements (m,
stiffness ~1e10 Pa) against pressures (Pa, conductance ~1e-16) and keeps Heaviside DOFs whose
support is cut into a thin sliver well conditioned (the Jacobi part of Béchet et al. 2005).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .assembly import TripletBuilder, add_triplets_to_dense
from .discretisation import Discretisation
from .physics import ConstantMatrices, Term


#: The damped (line-search) Newton iteration may take this many times solver.max_iterations.
DAMPED_ITERATION_FACTOR = 4


#: the dense condensation W = B^-1 L_BN (rows: linear unknowns, columns: nonlinear ones) is kept
#: up to this size (bytes); beyond, each Newton iteration solves with the sparse LU twice
KEEP_CONDENSATION_BYTES = 64 * 2 ** 20


#: condensed (nonlinear) blocks up to this many unknowns are solved with one BLAS thread
SINGLE_THREAD_BLAS_UP_TO = 2000


@functools.cache
def _blas_controller():
    """The BLAS libraries loaded in the process (found once; limiting them is then cheap)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


class StepFailed(RuntimeError):
    """Newton did not converge (or produced non-finite values) within the iteration limit."""


def fault_at_rest(disc: Discretisation, x: np.ndarray) -> dict:
    """The fault state where no term says otherwise: no jump, the in-situ shear traction,
    effective normal stress lowered by the fault's overpressure, sticking at mu0, aperture 2h0.
    The contact and evolving-aperture terms overwrite what they compute."""
    fp = disc.fault_points
    ng = len(fp.s)
    f = disc.scene.fault
    return {"slip": np.zeros(ng), "opening": np.zeros(ng), "shear_traction": fp.tau0.copy(),
            "effective_normal_stress": fp.sigma_n0 - disc.fault_overpressure(x),
            "friction": np.full(ng, f.friction), "contact_state": np.zeros(ng, dtype=np.int64),
            "hydraulic_aperture": np.full(ng, f.hydraulic_aperture), "history": None}


@dataclass
class StepOutcome:
    x: np.ndarray
    iterations: int
    factorizations: int
    point: dict              # fault state at the Gauss points (see fault_at_rest for the keys)
    history: np.ndarray      # new contact history (n_points, 4)
    reactions: np.ndarray


def assemble_constant(disc: Discretisation) -> tuple:
    """The constant matrices A, C, Hf (CSR) and the unit source vector, from every term: the
    rock integrals element group by element group, then the fault and point terms."""
    n = disc.n_dofs
    out = ConstantMatrices(TripletBuilder(n), TripletBuilder(n), TripletBuilder(n), np.zeros(n))
    for group in disc.element_groups:
        for term in disc.physics.terms:
            term.assemble_bulk(disc, group, out)
    for term in disc.physics.terms:
        term.assemble(disc, out)
    return out.A.tocsr(), out.C.tocsr(), out.Hf.tocsr(), out.source


class NewtonSolver:
    """Newton on the coupled residual, with the linear bulk condensed onto the fault.

    Only the fault terms are nonlinear (the terms' ``nonlinear_dofs``: contact on the Heaviside
    DOFs, evolving-aperture conduction on the fault pressures). The free unknowns are split into
    those (N, a few hundred) and everything else (B), whose Jacobian block is constant for a given
    time step. B is factorised once per step size and its Schur complement on N is formed once;
    each Newton iteration then costs one sparse solve with B, a small dense solve and the product
    with the kept condensation W = B^-1 L_BN (a second sparse solve where W is not kept).
    """

    #: B^-1 L_BN (scaled), kept when small (KEEP_CONDENSATION_BYTES), else None
    W = None
    _AH = None

    def __init__(self, disc: Discretisation):
        self.disc = disc
        s = disc.scene
        self.time_weight = s.time.theta
        self.tol = s.solver.tolerance
        self.max_it = s.solver.max_iterations
        self.A, self.C, self.Hf, self.source = assemble_constant(disc)
        self.nonlinear_terms = [t for t in disc.physics.terms
                                if type(t).residual is not Term.residual]
        self._dt = None
        self.free = disc.free
        b = disc.blocks
        mech = np.zeros(disc.n_dofs, dtype=bool)
        mech[b.u] = True
        mech[b.a] = True
        self.mech_free = mech[self.free]
        nonlinear = np.zeros(disc.n_dofs, dtype=bool)
        for term in disc.physics.terms:
            nonlinear[term.nonlinear_dofs(disc)] = True
        # without rock pore pressure, the flow unknowns (fault line, multiplier) join the condensed
        # set so that the remaining block (rock displacements) is independent of the step size
        self.static_B = disc.has("u") and not disc.has("p")
        if self.static_B:
            nonlinear[b.pf] = True
            nonlinear[b.q] = True
        nonlinear |= self._uncoupled_to_linear(nonlinear)
        self.scale = None
        self.lu_B = None
        nl_free = nonlinear[self.free]
        self.N = self.free[nl_free]
        self.B = self.free[~nl_free]
        # position of each global DOF in N (for the nonlinear tangents), -1 elsewhere
        self.n_index = np.full(disc.n_dofs, -1, dtype=np.int64)
        self.n_index[self.N] = np.arange(len(self.N))
        self.factorizations = 0

    def _uncoupled_to_linear(self, nonlinear):
        """Free unknowns whose constant rows or columns touch no other linear unknown: left in
        the linear block they would make it singular (e.g. the pressure-control multiplier when
        the fault pressures it constrains are nonlinear), so they join the condensed set."""
        pattern = (abs(self.A) + abs(self.C) + abs(self.Hf)).tocsr()
        linear = np.zeros(self.disc.n_dofs, dtype=bool)
        linear[self.free] = True
        linear &= ~nonlinear
        lin = linear.astype(float)
        rows_touch = pattern @ lin          # per row: weight of linear columns
        cols_touch = pattern.T @ lin        # per column: weight of linear rows
        return linear & ((rows_touch == 0) | (cols_touch == 0))

    def nonlinear(self, x, history, dt, residual):
        """Nonlinear terms at x added into ``residual``; their Jacobian triplets and the fault
        state at the Gauss points."""
        point = fault_at_rest(self.disc, x)
        rows, cols, vals = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)], [np.zeros(0)]
        for term in self.nonlinear_terms:
            r, c, v = term.residual(self.disc, x, history, dt, self.time_weight, residual, point)
            rows.append(r), cols.append(c), vals.append(v)
        return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals), point

    def _prepare(self, dt, x_n, history):
        """Factorise the linear block for step size ``dt`` and form its Schur complement.

        The scaling is fixed at the first step (and kept in checkpoints). When the rock has no
        pore pressure, B holds only rock displacements, whose block does not depend on dt: it is
        factorised once and the Schur complement is rebuilt for a new dt from the scaled N blocks
        of A, C, Hf and three precomputed dense products."""
        if dt == self._dt:
            return
        L = (self.A + self.C * (1.0 / dt) + self.Hf * self.time_weight).tocsr()
        if self.static_B and self.lu_B is not None:
            self.schur = self._static_schur(dt)
            self.L = L
            self._dt = dt
            return
        if self.scale is None:
            diag = np.abs(L.diagonal())
            rows, cols, vals, _ = self.nonlinear(x_n, history, dt, np.zeros(self.disc.n_dofs))
            on_diag = rows == cols  # nonlinear stiffness belongs in the scaling
            np.add.at(diag, rows[on_diag], np.abs(vals[on_diag]))
            zero = diag == 0.0
            if zero.any():
                rowmax = abs(L).max(axis=1).toarray().ravel()
                diag[zero] = rowmax[zero]
            diag[diag == 0.0] = 1.0
            self.scale = 1.0 / np.sqrt(diag)
        D = sp.diags(self.scale)
        B, N = self.B, self.N
        Ls = (D @ L @ D).tocsr()
        LsN = Ls[N]
        self.L_NB = LsN[:, B].tocsr()
        self.L_BN = Ls[B][:, N].tocsc()
        # W = B^-1 L_BN is formed column block by column block for the Schur complement anyway;
        # kept when it is small, it turns the second sparse solve of every Newton iteration into
        # one dense product (dxB = yB - W dxN)
        keep_W = len(N) > 0 and len(B) * len(N) * 8 <= KEEP_CONDENSATION_BYTES
        self.lu_B = _sparse_lu(Ls[B][:, B])
        self.factorizations += 1
        if self.static_B:  # first step: B, the products and the N blocks, once for the run
            rows_N = [(D @ M @ D).tocsr()[N] for M in (self.A, self.C, self.Hf)]
            parts = [r[:, B] for r in rows_N]
            self._NN = [r[:, N] for r in rows_N]
            self._P = [np.zeros((len(N), len(N))) for _ in parts]
            for cols, X in self._condensation(keep_W):
                for P, part in zip(self._P, parts):
                    P[:, cols] = part @ X
            self.schur = self._static_schur(dt)
        else:
            schur = LsN[:, N].toarray()
            for cols, X in self._condensation(keep_W):
                schur[:, cols] -= self.L_NB @ X
            self.schur = schur
        self.L = L
        self._dt = dt

    def _condensation(self, keep_W):
        """B^-1 L_BN, 256 columns at a time: yields (column slice, block); keeps the whole of it
        as W when ``keep_W``."""
        N, B = self.N, self.B
        self.W = np.empty((len(B), len(N))) if keep_W else None
        for j0 in range(0, len(N), 256):
            cols = slice(j0, j0 + 256)
            X = self.lu_B.solve(self.L_BN[:, cols].toarray())
            if self.W is not None:
                self.W[:, cols] = X
            yield cols, X

    def _static_schur(self, dt):
        """Schur complement for step size dt when B does not depend on it: only the N block and
        the three precomputed products change (no sparse slicing per step size)."""
        th = self.time_weight
        (A, C, Hf), (P0, P1, P2) = self._NN, self._P
        return (A + C * (1.0 / dt) + Hf * th).toarray() - (P0 + P1 / dt + th * P2)

    def _solve(self, sR, dense):
        """Solve (scaled) J dx = -sR with J = L + nonlinear tangent (on N only)."""
        B, N = self.B, self.N
        rB = -sR[B]
        if not len(N):
            out = np.zeros_like(sR)
            out[B] = self.lu_B.solve(rB)
            return out
        rN = -sR[N]
        yB = self.lu_B.solve(rB)
        dxN = dense.solve(rN - self.L_NB @ yB)
        if self.W is not None:
            dxB = yB - self.W @ dxN
        else:
            dxB = self.lu_B.solve(rB - self.L_BN @ dxN)
        out = np.zeros_like(sR)
        out[B] = dxB
        out[N] = dxN
        return out

    def step(self, x_n, history, dt, injection_value, damped=False, x0=None):
        """Advance from x_n over dt. ``injection_value``: the step's injected volume (m^3, whole
        interval; rate control) or the prescribed overpressure at the step's end (Pa; pressure
        control); ignored without an injection term. ``damped``: globalise the Newton iteration
        with a backtracking line search (see ``_line_search``); the stepper retries a failed step
        so before it halves the step, because a sudden load (a pressure jump, a slip front
        crossing many points at once) makes the full Newton step of the Coulomb return map
        overshoot and cycle, and under pressure control a shorter step does not reduce the jump.
        ``x0``: the first guess (default x_n).

        BLAS runs on one thread while the condensed block is small: its dense products and LU
        take a millisecond or less, where OpenBLAS's threads only add start-up and, on a busy
        machine, spin against the other processes (a 3-14x slow-down measured, issue 15)."""
        if len(self.N) > SINGLE_THREAD_BLAS_UP_TO:
            return self._step(x_n, history, dt, injection_value, damped, x0)
        with _blas_controller().limit(limits=1, user_api="blas"):
            return self._step(x_n, history, dt, injection_value, damped, x0)

    def _step(self, x_n, history, dt, injection_value, damped, x0):
        disc = self.disc
        th = self.time_weight
        self._prepare(dt, x_n, history)
        L = self.L
        scale = self.scale
        n = disc.n_dofs
        if self._AH is None:  # A and Hf stacked: both products of the convergence test in one pass
            self._AH = sp.vstack([self.A, self.Hf]).tocsr()
        stored_n = (self.C @ x_n) / dt
        rhs = stored_n - (1.0 - th) * (self.Hf @ x_n) + disc.load
        injection = disc.physics.injection
        if injection is not None:
            injection.load(disc, self.source, rhs, injection_value, dt, th)
        known = np.zeros(disc.n_dofs)
        for term in self.nonlinear_terms:
            term.previous_step(disc, x_n, th, known)
        rhs -= known
        flow_known = np.abs(rhs - stored_n)  # sources and the known parts of the flow terms
        x = x_n.copy() if x0 is None else x0.copy()  # x0: a better first guess (continuation)
        free = self.free
        ref0 = None
        dense = None
        last_vals = None
        n_fact = 0
        # the damped iteration lowers its merit at every step, so it may take longer: a slip
        # front that must cross many fault points moves a few points per iteration
        max_it = self.max_it * (DAMPED_ITERATION_FACTOR if damped else 1)
        for it in range(max_it + 1):
            R = L @ x - rhs
            rows, cols, vals, point = self.nonlinear(x, history, dt, R)
            sR = scale * R
            if not np.all(np.isfinite(sR[free])):
                raise StepFailed("non-finite residual")
            mf = self.mech_free
            sRf = sR[free]
            norms = (np.linalg.norm(sRf[mf]), np.linalg.norm(sRf[~mf]))
            if ref0 is None:
                ref0 = norms
            if it > 0 or max(norms) == 0.0:
                # reference magnitudes at the current iterate: internal forces (mechanics);
                # stored-volume rate plus conduction plus sources (flow)
                AHx = self._AH @ x
                s_mech = (scale * AHx[:n])[free]
                s_flow = (scale * (np.abs(self.C @ (x - x_n)) / dt + np.abs(AHx[n:]) + flow_known))[free]
                ref = (max(ref0[0], np.linalg.norm(s_mech[mf])), max(ref0[1], np.linalg.norm(s_flow[~mf])))
                if norms[0] <= self.tol * ref[0] and norms[1] <= self.tol * ref[1]:
                    reactions = np.zeros(disc.n_dofs)
                    reactions[disc.fixed] = R[disc.fixed]
                    new_history = point.pop("history")
                    return StepOutcome(x, it, n_fact, point,
                                       history if new_history is None else new_history, reactions)
            if it == max_it:
                break
            if dense is None or len(vals) != len(last_vals) or np.any(vals != last_vals):
                dense = self._condensed_system(rows, cols, vals)
                last_vals = vals
                n_fact += 1
            dx = scale * self._solve(sR, dense)
            if not np.all(np.isfinite(dx)):
                raise StepFailed("non-finite Newton update")
            if damped and it > 0:  # the first update solves the linear flow part: take it whole
                dx *= self._line_search(x, dx, norms, ref, rhs, history, dt)
            x += dx
        raise StepFailed(f"Newton did not converge in {max_it} iterations "
                         f"(scaled residuals {norms[0]:.3e}, {norms[1]:.3e})")

    def _line_search(self, x, dx, norms, ref, rhs, history, dt, max_halvings=10):
        """Step length along the Newton direction dx: the first of 1, 1/2, 1/4, ... that lowers
        the merit (sum of the squared field residuals relative to their references) by the Armijo
        fraction 1e-4; the last one tried if none does (the next iteration then re-linearises)."""
        free, mf = self.free, self.mech_free
        r0, r1 = max(ref[0], 1e-300), max(ref[1], 1e-300)
        merit0 = (norms[0] / r0) ** 2 + (norms[1] / r1) ** 2
        alpha = 1.0
        for _ in range(max_halvings):
            xt = x + alpha * dx
            R = self.L @ xt - rhs
            self.nonlinear(xt, history, dt, R)
            sRf = (self.scale * R)[free]
            with np.errstate(over="ignore", invalid="ignore"):
                merit = (np.linalg.norm(sRf[mf]) / r0) ** 2 + (np.linalg.norm(sRf[~mf]) / r1) ** 2
            if merit <= (1.0 - 1e-4 * alpha) * merit0:
                break
            alpha *= 0.5
        return alpha

    def _condensed_system(self, rows, cols, vals):
        """Dense LU of the condensed system: Schur complement plus scaled nonlinear tangent."""
        if not len(self.N):
            return None
        M = self.schur.copy()
        add_triplets_to_dense(M, self.n_index, rows, cols, vals, self.scale)
        return _DenseLU(M)


def _sparse_lu(M):
    """Sparse LU of the linear block. Its pattern is symmetric (the same unknowns couple both
    ways) and, scaled, its diagonal dominates: minimum degree on A^T + A with diagonal pivots
    preferred has 20 % less fill than on A^T A and solves a third faster (issue 15)."""
    return spla.splu(M.tocsc(), permc_spec="MMD_AT_PLUS_A", options=dict(SymmetricMode=True))


class _DenseLU:
    def __init__(self, M):
        self.factors = scipy.linalg.lu_factor(M, check_finite=False)

    def solve(self, b):
        return scipy.linalg.lu_solve(self.factors, b, check_finite=False)

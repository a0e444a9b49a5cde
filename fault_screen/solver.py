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

import contextlib
import functools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from ._jit import helper, kernel
from .assembly import TripletBuilder
from .bordered_lu import bordered_lu, lu_solve, release_freed_memory, split_layout
from .discretisation import Discretisation
from .ordering import nested_dissection
from .physics import ConstantMatrices, Term


#: The damped (line-search) Newton iteration may take this many times solver.max_iterations.
DAMPED_ITERATION_FACTOR = 4


#: the linear rows' residual at a step's start is left unsolved below this fraction of what the
#: convergence test resolves (solver.tolerance times the reference magnitudes)
BULK_BALANCE = 1e-3


#: the contact forces are differences of total tractions and their in-situ values (f = int N
#: (tau - tau0) t - ...): their round-off is this many units of round-off of the in-situ traction
#: forces, which the mechanical reference never goes below (``NewtonSolver._in_situ_reference``)
IN_SITU_ROUNDOFF = 4.0


#: a deferred bulk update (see NewtonSolver._step) is made when the fault residual has not halved
#: for this many Newton iterations
STALLED_ITERATIONS = 3


#: condensed (nonlinear) blocks up to this many unknowns are solved with one BLAS thread: with
#: the factors reused (``_CondensedSolver``) the work is mostly matrix-vector solves and products,
#: which threads do not speed up and which spin against the other processes of a busy machine
#: (the fine 30 deg scene, 2059 fault unknowns: 323 s of CPU for 465 s of wall at load 7-10)
SINGLE_THREAD_BLAS_UP_TO = 6000


@functools.cache
def _blas_controller():
    """The BLAS libraries loaded in the process (found once; limiting them is then cheap)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


class StepFailed(RuntimeError):
    """Newton did not converge (or produced non-finite values) within the iteration limit."""


def fault_at_rest(disc: Discretisation, x: np.ndarray, point: dict | None = None) -> dict:
    """The fault state where no term says otherwise: no jump, the in-situ shear traction,
    effective normal stress lowered by the fault's overpressure, sticking at mu0, aperture 2h0.
    ``point``: what the terms computed (the contact and evolving-aperture terms), completed with
    the rest (only the missing entries are made)."""
    fp = disc.fault_points
    ng = len(fp.s)
    f = disc.scene.fault
    point = {} if point is None else point
    for key in ("slip", "opening"):
        if key not in point:
            point[key] = np.zeros(ng)
    if "shear_traction" not in point:
        point["shear_traction"] = fp.tau0.copy()
    if "effective_normal_stress" not in point:
        point["effective_normal_stress"] = fp.sigma_n0 - disc.fault_overpressure(x)
    if "friction" not in point:
        point["friction"] = np.full(ng, f.friction)
    if "contact_state" not in point:
        point["contact_state"] = np.zeros(ng, dtype=np.int64)
    if "hydraulic_aperture" not in point:
        point["hydraulic_aperture"] = np.full(ng, f.hydraulic_aperture)
    point.setdefault("history", None)
    return point


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


@helper
def _norm_at(v, at):
    """(2-norm of v[at], all finite): one pass of squares, a second scaled by the largest
    magnitude only when the squares overflow or underflow (as LAPACK's nrm2 guards them)."""
    total = 0.0
    largest = 0.0
    finite = True
    for k in at:
        a = abs(v[k])
        if not np.isfinite(a):
            finite = False
        total += a * a
        largest = max(largest, a)
    if not finite:
        return np.inf, False
    if largest > 0.0 and (total == np.inf or total < 1e-290):
        total = 0.0
        for k in at:
            a = v[k] / largest
            total += a * a
        return largest * np.sqrt(total), True
    return np.sqrt(total), True


@kernel
def _scaled_field_norms(R, scale, mech_at, flow_at):
    """scale R and its 2-norms over the free mechanical and the free flow unknowns; ``finite``
    False when an entry there is not finite."""
    sR = np.empty_like(R)
    for i in range(R.shape[0]):
        sR[i] = scale[i] * R[i]
    mech, finite_mech = _norm_at(sR, mech_at)
    flow, finite_flow = _norm_at(sR, flow_at)
    return sR, mech, flow, finite_mech and finite_flow


@kernel
def _reference_norms(scale, AHx, Cd, dt, flow_known, mech_at, flow_at):
    """The convergence test's reference magnitudes: |scale A x| over the free mechanical
    unknowns, |scale (|C (x - x_n)| / dt + |Hf x| + known flow terms)| over the free flow ones."""
    n = scale.shape[0]
    mech = np.empty(n)
    flow = np.empty(n)
    for k in mech_at:
        mech[k] = scale[k] * AHx[k]
    for k in flow_at:
        flow[k] = scale[k] * (abs(Cd[k]) / dt + abs(AHx[n + k]) + flow_known[k])
    return _norm_at(mech, mech_at)[0], _norm_at(flow, flow_at)[0]


class NewtonSolver:
    """Newton on the coupled residual, with the linear bulk condensed onto the fault.

    Only the fault terms are nonlinear (the terms' ``nonlinear_dofs``: contact on the Heaviside
    DOFs, evolving-aperture conduction on the fault pressures). The free unknowns are split into
    those (N, a few hundred) and everything else (B), whose Jacobian block is constant for a given
    time step. One sparse LU of the free block with N ordered last (``BorderedLU``) gives the
    Schur complement on N and the two sweeps that eliminate the bulk (a large bulk in parts
    factorised one after the other, ``SplitBorderedLU``). The bulk is linear, so after
    a step's first Newton update its rows stay in balance: a step sweeps forward once for the
    step's right-hand side, iterates on the fault with the small dense condensed system, and
    sweeps backward once for the bulk's answer to the sum of its fault updates (see ``_step``).
    """

    _AH_N = None
    _products = None
    _Cx_n = None       # (x_n, C x_n) of the current step
    _dense = None
    _order = None
    _split = None      # the parts of the bulk's factorisation (see bordered_lu.split_layout)
    _blocks_NN = None
    _blocks_fixed = None
    _blocks_rows_N_fixed = None
    _blas_limited = False
    _restored_P = None
    _restored_condensed = None   # (tangent, dt) of the checkpoint's condensed block
    _in_situ_floor = None        # (see _in_situ_reference)
    lu = None

    def __init__(self, disc: Discretisation):
        self.disc = disc
        s = disc.scene
        self.time_weight = s.time.theta
        self.tol = s.solver.tolerance
        self.max_it = s.solver.max_iterations
        self.A, self.C, self.Hf, self.source = assemble_constant(disc)
        self.nonlinear_terms = [t for t in disc.physics.terms
                                if type(t).residual is not Term.residual]
        self._tangent_pattern = None   # the nonlinear terms' rows and columns, joined (``nonlinear``)
        self._L = None                 # the linear Jacobian (``L``), when made
        self._dt = None
        self.free = disc.free
        self._fixed = np.flatnonzero(disc.fixed) if disc.fixed.dtype == bool else disc.fixed
        b = disc.blocks
        mech = np.zeros(disc.n_dofs, dtype=bool)
        mech[b.u] = True
        mech[b.a] = True
        self.mech_free = mech[self.free]
        self._free_mech = self.free[self.mech_free]    # (the two fields' free unknowns)
        self._free_flow = self.free[~self.mech_free]
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
        nl_free = nonlinear[self.free]
        self.N = self.free[nl_free]
        self.B = self.free[~nl_free]
        self._mech_B = self.mech_free[~nl_free]
        # position of each global DOF in N (for the nonlinear tangents), -1 elsewhere
        self.n_index = np.full(disc.n_dofs, -1, dtype=np.int64)
        self.n_index[self.N] = np.arange(len(self.N))
        self.factorizations = 0
        # the bulk update may wait until a convergence check needs it only when the nonlinear
        # terms read nothing but condensed unknowns (the fault's jump and pressure DOFs)
        fp = disc.fault_points
        read = np.concatenate([fp.jump_dofs.ravel(), fp.p_dofs.ravel()])
        read = read[(read >= 0) & ~disc.fixed[np.maximum(read, 0)]]
        self._fault_reads_only_N = bool(np.all(self.n_index[read] >= 0))
        # the step size enters only the storage (C) and the theta-weighted conduction (Hf): when
        # neither touches a linear unknown, the factors serve every step size and only the N block
        # of the Schur complement changes with it
        CH = (abs(self.C) + abs(self.Hf)).tocsr()[self.free][:, self.free].tocsc()
        on_B = np.zeros(len(self.free), dtype=bool)
        on_B[~nl_free] = True
        self._factors_any_dt = not (CH[on_B].nnz or CH[:, on_B].nnz)

    def checkpoint_state(self) -> dict:
        """Arrays that a restored solver needs to take bit-identical steps: the nonlinear tangent
        and step size of the condensed block last factorised (later solves are preconditioned by
        its factors; the block is formed again from them), whether it was formed from the
        current condensation, and the condensation when it serves every step size (see
        ``_prepare``)."""
        out = {}
        if self._factors_any_dt and self.lu is not None:
            out["condensation"] = self.P
        d = self._dense
        if d is not None and d.tangent0 is not None:
            rows, cols, vals = d.tangent0
            out.update(condensed_tangent_rows=rows, condensed_tangent_cols=cols,
                       condensed_tangent_values=vals, condensed_step=np.array(d.factored_step),
                       condensed_current=np.array(d._base0 == self.factorizations))
        return out

    def restore_state(self, state: dict):
        """Undo ``checkpoint_state``. The condensed block is formed and factorised again at the
        first Newton iteration, once the condensation is at hand (LAPACK repeats the factors
        exactly). (A checkpoint written before the tangent was stored holds the block itself:
        it is not used, the first iteration factorises its own block.)"""
        if "condensation" in state:
            self._restored_P = np.array(state["condensation"])
        if "condensed_tangent_rows" in state and bool(state["condensed_current"]):
            self._restored_condensed = (
                (np.array(state["condensed_tangent_rows"]), np.array(state["condensed_tangent_cols"]),
                 np.array(state["condensed_tangent_values"])), float(state["condensed_step"]))

    def _new_condensed_solver(self):
        """The run's dense solver; it is told the storage block when that is all a step-size
        change alters (``_factors_any_dt``), so that it can keep its factors across step sizes."""
        return _CondensedSolver(self._condensed_blocks()[1] if self._factors_any_dt else None,
                                position=self.n_index, scale=self.scale)

    def _condensed_blocks(self):
        """The condensed block of A, C, Hf (scaled: needs the scaling), sliced once."""
        if self._blocks_NN is None:
            N = self.N
            sN = self.scale[N]
            self._blocks_NN = [M[N][:, N].multiply(sN[:, None]).multiply(sN[None, :]).tocsr()
                               for M in (self.A, self.C, self.Hf)]
        return self._blocks_NN

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
        point = {}
        parts = [term.residual(self.disc, x, history, dt, self.time_weight, residual, point)
                 for term in self.nonlinear_terms]
        fault_at_rest(self.disc, x, point)   # (what no term computed)
        vals = np.concatenate([np.zeros(0)] + [v for _, _, v in parts])
        # the terms' rows and columns, joined once while each term returns the same arrays (its
        # pattern): the condensed solver then recognises the joined ones by identity
        known = self._tangent_pattern
        if known is None or len(known[0]) != len(parts) or any(
                r is not r0 or c is not c0 for (r, c, _), r0, c0 in zip(parts, *known[:2])):
            empty = [np.zeros(0, dtype=np.int64)]
            known = self._tangent_pattern = (
                [r for r, _, _ in parts], [c for _, c, _ in parts],
                np.concatenate(empty + [r for r, _, _ in parts]),
                np.concatenate(empty + [c for _, c, _ in parts]))
        return known[2], known[3], vals, point

    def _prepare(self, dt, x_n, history):
        """The Jacobian's linear part for step size ``dt``, its factors and Schur complement.

        The scaling is fixed at the first step (and kept in checkpoints). When the step size
        touches no linear unknown (``_factors_any_dt``: no rock pore pressure), the factors of the
        first step serve all: for a new dt only the N block changes, S = L_NN(dt) - P with the
        condensation P = L_NB B^-1 L_BN of the first factorisation (kept in checkpoints, so that
        a restored run repeats the same round-off)."""
        if dt == self._dt:
            return
        self._L = None   # (the last step size's L goes first)
        factorise = self.lu is None or not self._factors_any_dt
        L = self._linear_jacobian(dt) if factorise or self.scale is None else None
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
        B, N = self.B, self.N
        self._condensed_blocks()
        # L_NN's entries: the condensed solver forms its block from them and P (the Schur
        # complement L_NN - P is not held: one n_N x n_N array less), and P is made with them
        self._LNN_entries = self._linear_entries(dt)
        if factorise:
            D = sp.diags(self.scale)
            Ls = (D @ L @ D).tocsr()
            if self._order is None:  # the pattern of B is that of every step size
                inner, split, quarters = nested_dissection(
                    Ls[B][:, B], self.disc.dof_coordinates()[B], return_split=True,
                    return_quarters=True)
                layout, self._split = split_layout(len(B), split, quarters)
                if layout is not None:
                    inner = inner[layout]
                self._order = np.concatenate([B[inner], N])
            # the factorisation's peak (SuperLU's storage and the factors copied out of it) is
            # reached holding neither L nor the matrix factorised
            held = [Ls[self._order][:, self._order].tocsc()]
            del Ls, L
            self.lu = None  # the old factors go before the new ones are made (peak memory)
            release_freed_memory()
            self.lu = bordered_lu(held.pop, len(B), self._split)
            self.factorizations += 1
            # P = L_NN - S in the Schur complement's own memory, which the factors then give up
            # (n_N x n_N dense: 34 MB on the fine 30 deg scene), L_NN added entry by entry
            rows, cols, vals = self._LNN_entries
            self.P = np.negative(self.lu.schur, out=self.lu.schur)
            self.P[rows, cols] += vals   # (each position once)
            self.lu.schur = None
            if self._restored_P is not None:
                self.P, self._restored_P = self._restored_P, None
        if self._blocks_fixed is None:  # rows of the fixed unknowns on the linear ones, in order
            self._blocks_fixed = [M[self._fixed].tocsc()[:, self._linear_order()].tocsr()
                                  for M in (self.A, self.C, self.Hf)]
        self._L_fixed_B = self._combine(self._blocks_fixed, dt)
        if self._blocks_rows_N_fixed is None:  # the rows a residual with a pending bulk needs
            self._rows_N_fixed = np.concatenate([N, self._fixed])
            self._blocks_rows_N_fixed = [M[self._rows_N_fixed] for M in (self.A, self.C, self.Hf)]
        self._L_rows_N_fixed = self._combine(self._blocks_rows_N_fixed, dt)
        self._dt = dt

    @property
    def L(self):
        """The linear Jacobian at the current step size, made at its first use and kept while
        the step size is: a residual with the bulk's answer deferred never reads it (every step
        of the bundled scenes), so it is not held beside A (17 MB on the fine 30 deg scene)."""
        if self._L is None:
            self._L = self._linear_jacobian(self._dt)
        return self._L

    def _linear_jacobian(self, dt):
        """A + C / dt + theta Hf (CSR, unscaled)."""
        return self._combine((self.A, self.C, self.Hf), dt).tocsr()

    def _combine(self, blocks, dt):
        """A + C / dt + theta Hf from the same block of each."""
        A, C, Hf = blocks
        return A + C * (1.0 / dt) + Hf * self.time_weight

    def _linear_order(self):
        """The linear unknowns in the factors' order."""
        return self._order[:len(self.B)]

    def _solve(self, sR, dense, bulk_eliminated, defer):
        """Solve (scaled) J dx = -sR with J = L + nonlinear tangent (on N only).

        Returns (dx, dxN, swept). ``bulk_eliminated``: the linear rows are in balance (every
        Newton update after a step's first solves them exactly, and the bulk is linear), so their
        residual is round-off and the forward sweep is skipped (swept is None). ``defer``: dx
        holds only the fault update dxN, whose bulk response B^-1 (r_B - L_BN dxN) is left to the
        caller, who sums the updates of a step and sweeps backward once (``_step``); ``swept``
        goes with it: the forward-swept r_B and its effect on the fault rows, L_NB B^-1 r_B.
        Otherwise dx is complete and dxN None."""
        N = self.N
        linear = self._linear_order()
        out = np.zeros_like(sR)
        rN = -sR[N]
        swept = None
        if bulk_eliminated:
            g = rN
        else:
            swept, g = self.lu.forward(-sR[linear], rN)
        dxN = dense.solve(g) if len(N) else g
        out[N] = dxN
        if defer:
            return out, dxN, (None if swept is None else (swept, rN - g))
        out[linear] = self.lu.backward(swept, dxN)
        return out, None, None

    def _AH_times(self, x):
        """[A x; Hf x], the two products of the convergence test (A and Hf are not held stacked
        as well: 18 MB on the fine 30 deg scene; CSR, so the sums are those of the stack's)."""
        return np.concatenate([self.A @ x, self.Hf @ x])

    def _linear_times_start(self, x_n, stored_n):
        """L x_n at a step's start, from A x_n and Hf x_n (the convergence test's products, at
        hand when the last step was accepted there, else made whole now and kept for the test)
        and C x_n / dt (the step's stored volume), instead of a product with L. Whole products
        only, so that a restored run makes the same sums."""
        last = self._products
        if last is None or not last.whole or not np.array_equal(last.x, x_n):
            last = self._products = _Products(x_n, x_n.copy(), self._AH_times(x_n),
                                              np.zeros_like(x_n), True, self._C_times_start(x_n))
        n = self.disc.n_dofs
        return last.AHx[:n] + stored_n + self.time_weight * last.AHx[n:]

    def _residual(self, x, rhs, history, dt, pending, Lx=None):
        """Residual at x and the nonlinear terms' tangent and fault state. ``pending``
        (``_PendingBulk`` or None): the bulk's answer to the step's updates that x[B] does not
        hold yet. On the fault rows it adds L_NB B^-1 (r_B - L_BN dx_N) = shift - P dx_N (P =
        L_NB B^-1 L_BN, dense, from the factorisation); the bulk rows are in balance once it is
        made (linear bulk, eliminated exactly), so only the fault rows and those of the fixed
        unknowns (the reactions) are computed."""
        if pending is None:
            R = (self.L @ x if Lx is None else Lx) - rhs
        else:
            needed = self._rows_N_fixed
            R = np.zeros_like(x)
            R[needed] = self._L_rows_N_fixed @ x - rhs[needed]
            R[self.N] += (pending.shift - self.P @ pending.fault) / self.scale[self.N]
        rows, cols, vals, point = self.nonlinear(x, history, dt, R)
        return R, rows, cols, vals, point

    def _make_pending(self, x, pending, R):
        """Bring x[B] up to date with the pending bulk answer (one backward sweep) and the
        residual's rows of fixed unknowns (the reactions) with it: the other rows are up to date
        (see ``_step``) and the nonlinear terms read no bulk unknown."""
        rows = self._linear_order()
        dxB = self.scale[rows] * self.lu.backward(pending.swept, pending.fault)
        x[rows] += dxB
        R[self._fixed] += self._L_fixed_B @ dxB

    def step(self, x_n, history, dt, injection_value, damped=False, x0=None):
        """Advance from x_n over dt. ``injection_value``: the step's injected volume (m^3, whole
        interval; rate control) or the prescribed overpressure at the step's end (Pa; pressure
        control); ignored without an injection term. ``damped``: globalise the Newton iteration
        with a backtracking line search (see ``_line_search``); the stepper retries a failed step
        so before it halves the step, because a sudden load (a pressure jump, a slip front
        crossing many points at once) makes the full Newton step of the Coulomb return map
        overshoot and cycle, and under pressure control a shorter step does not reduce the jump.
        ``x0``: the first guess (default x_n).

        BLAS threads: see ``blas_threads``."""
        with self.blas_threads():
            return self._step(x_n, history, dt, injection_value, damped, x0)

    @contextlib.contextmanager
    def blas_threads(self):
        """Run BLAS on one thread while the condensed block is small: its dense products and LU
        take a millisecond or less, where OpenBLAS's threads only add start-up and, on a busy
        machine, spin against the other processes (a 3-14x slow-down measured, issue 15). A
        caller that takes many steps holds this around all of them: limiting and restoring the
        threads at every step cost a BLAS thread spinning beside the run (CPU 1.8x the wall
        time on the T = 0.4 scene). Re-entrant."""
        if len(self.N) > SINGLE_THREAD_BLAS_UP_TO or self._blas_limited:
            yield
            return
        self._blas_limited = True
        try:
            with _blas_controller().limit(limits=1, user_api="blas"):
                yield
        finally:
            self._blas_limited = False

    def _reference(self, x, x_n, dt, ref0, flow_known):
        """Reference magnitudes of the convergence test at x: internal forces (mechanics);
        stored-volume rate plus conduction plus sources (flow); never below the step's first
        residual norms ``ref0``."""
        AHx, Cd = self._linear_products(x, x_n)
        mech, flow = _reference_norms(self.scale, AHx, Cd, dt, flow_known, self._free_mech,
                                      self._free_flow)
        return max(ref0[0], mech, self._in_situ_reference()), max(ref0[1], flow)

    def _in_situ_reference(self):
        """The mechanical reference below which the test would ask for less than the round-off of
        the contact forces: IN_SITU_ROUNDOFF units of round-off of the in-situ traction forces
        (scaled), over the tolerance. Without it a step in which nothing moves the fault (no flow
        yet) has internal forces near zero as its reference and cannot converge: its residual
        stays at the round-off of tau - tau0. Zero without a contact term."""
        if self._in_situ_floor is None:
            forces = np.zeros(self.disc.n_dofs)
            if self.disc.physics.contact is not None:
                fp = self.disc.fault_points
                t, n = self.disc.fault.tangent, self.disc.fault.normal
                for a in range(8):   # (node a // 2, component a % 2 of the jump)
                    i, c = divmod(a, 2)
                    at = fp.jump_dofs[:, a] >= 0
                    np.add.at(forces, fp.jump_dofs[at, a],
                              (fp.weight * fp.N[:, i] * (abs(fp.tau0 * t[c])
                                                         + abs(fp.sigma_n0 * n[c])))[at])
            magnitude = np.linalg.norm((self.scale * forces)[self._free_mech])
            self._in_situ_floor = IN_SITU_ROUNDOFF * np.finfo(float).eps * magnitude / self.tol
        return self._in_situ_floor

    def _linear_products(self, x, x_n):
        """[A; Hf] x and C (x - x_n), for the reference magnitudes. While the bulk's answer is
        deferred (``_step``), Newton changes x in its condensed unknowns only: the products of
        the last call are then brought up to date through those columns alone; and a step
        starts where the last one was accepted, whose products are at hand. (Across steps only
        products computed whole are reused, so that a restored run repeats them bit for bit.)"""
        last = self._products
        if last is not None and (last.x_n is x_n or last.whole):
            d = x - last.x
            dN = d[self.N]
            n_changed = np.count_nonzero(d)
            if n_changed == 0 and last.x_n is x_n:
                return last.AHx, last.Cd
            if n_changed == np.count_nonzero(dN):
                if last.x_n is x_n:
                    AHx, Cd = last.AHx + self._AH_N @ dN, last.Cd + self._C_N @ dN
                    self._products = _Products(x_n, x.copy(), AHx, Cd, False)
                    return AHx, Cd
                if n_changed == 0:  # a new step from the last accepted state
                    Cd = np.zeros_like(x) if np.array_equal(x, x_n) else self.C @ (x - x_n)
                    self._products = _Products(x_n, x.copy(), last.AHx, Cd, True)
                    return last.AHx, Cd
        AHx, Cx = self._AH_times(x), self.C @ x
        Cd = Cx - self._C_times_start(x_n)
        self._products = _Products(x_n, x.copy(), AHx, Cd, True, Cx)
        return AHx, Cd

    def _C_times_start(self, x_n):
        """C x_n: the last whole product C x when x_n is that x (the step starts where the last
        one was accepted), else computed whole (as a restored run does: the same sums)."""
        known = self._Cx_n
        if known is not None and known[0] is x_n:
            return known[1]
        last = self._products
        if last is not None and last.Cx is not None and np.array_equal(last.x, x_n):
            Cx_n = last.Cx
        else:
            Cx_n = self.C @ x_n
        self._Cx_n = (x_n, Cx_n)
        return Cx_n

    def _bulk_in_balance(self, sR, ref):
        """Is the scaled residual of the linear rows below BULK_BALANCE of what the convergence
        test resolves, in each field? Solving it away would then change nothing the test sees."""
        rB = sR[self.B]
        mB = self._mech_B
        lim = BULK_BALANCE * self.tol
        return (np.linalg.norm(rB[mB]) <= lim * ref[0]) and (np.linalg.norm(rB[~mB]) <= lim * ref[1])

    def _step(self, x_n, history, dt, injection_value, damped, x0):
        disc = self.disc
        th = self.time_weight
        self._prepare(dt, x_n, history)
        scale = self.scale
        if self._AH_N is None:  # the columns of A and Hf on the condensed unknowns, stacked
            self._AH_N = sp.vstack([self.A[:, self.N], self.Hf[:, self.N]]).tocsr()
            self._C_N = self.C.tocsr()[:, self.N]
        stored_n = self._C_times_start(x_n) / dt
        rhs = stored_n + disc.load
        if th != 1.0:  # backward Euler (the default) has no known part of the conduction
            rhs -= (1.0 - th) * (self.Hf @ x_n)
        injection = disc.physics.injection
        if injection is not None:
            injection.load(disc, self.source, rhs, injection_value, dt, th)
        known = np.zeros(disc.n_dofs)
        for term in self.nonlinear_terms:
            term.previous_step(disc, x_n, th, known)
        rhs -= known
        flow_known = np.abs(rhs - stored_n)  # sources and the known parts of the flow terms
        x = x_n.copy() if x0 is None else x0.copy()  # x0: a better first guess (continuation)
        Lx = self._linear_times_start(x_n, stored_n) if x0 is None else None
        tol = self.tol
        # the bulk's answer to every Newton update would cost a backward sweep: it is summed
        # instead (pending) and swept for once, when the fault looks converged; possible when the
        # nonlinear terms read only condensed unknowns
        defer = len(self.N) > 0 and len(self.B) > 0 and self._fault_reads_only_N
        pending = None
        ref0 = ref = exact_ref = last_norms = None
        stalled = 0
        dense = None
        last_vals = None
        n_fact = 0
        # the damped iteration lowers its merit at every step, so it may take longer: a slip
        # front that must cross many fault points moves a few points per iteration
        max_it = self.max_it * (DAMPED_ITERATION_FACTOR if damped else 1)
        it = 0
        while True:
            R, rows, cols, vals, point = self._residual(x, rhs, history, dt, pending,
                                                        Lx if it == 0 else None)
            sR, norm_mech, norm_flow, finite = _scaled_field_norms(R, scale, self._free_mech,
                                                                   self._free_flow)
            if not finite:
                raise StepFailed("non-finite residual")
            norms = (norm_mech, norm_flow)
            if ref0 is None:
                ref0 = norms
            check = it > 0 or max(norms) == 0.0
            if pending is not None:
                # the reference magnitudes at the lagging bulk are an estimate (never below the
                # last exact ones): once the fault converges by it, or has not halved its
                # residual for STALLED_ITERATIONS iterations (round-off floor, a reference
                # underestimated), or at the last iteration, the bulk is brought up to date with
                # one backward sweep and the iterate is checked exactly, as if never deferred.
                # The residual needs no new evaluation: its fault rows are exact already, the
                # bulk rows are in balance and the nonlinear terms read only fault unknowns;
                # only the reactions (rows of fixed unknowns) are recomputed.
                # (the estimate never lowers the last exact reference: it is only needed when the
                # fault fails against that one)
                ref = exact_ref
                if any(norms[k] > tol * ref[k] for k in (0, 1)):
                    ref = tuple(map(max, exact_ref, self._reference(x, x_n, dt, ref0, flow_known)))
                failing = [k for k in (0, 1) if norms[k] > tol * ref[k]]
                stalled = stalled + 1 if all(norms[k] > 0.5 * last_norms[k] for k in failing) else 0
                if not failing or stalled >= STALLED_ITERATIONS or it == max_it:
                    self._make_pending(x, pending, R)
                    pending = None
            # at the first iteration the reference serves the deferred update and the bulk
            # balance test, which only a step-size-independent bulk can pass
            if pending is None and (check or (it == 0 and (defer or self.static_B))):
                ref = exact_ref = self._reference(x, x_n, dt, ref0, flow_known)
                if check and norms[0] <= tol * ref[0] and norms[1] <= tol * ref[1]:
                    reactions = np.zeros(disc.n_dofs)
                    reactions[self._fixed] = R[self._fixed]
                    new_history = point.pop("history")
                    return StepOutcome(x, it, n_fact, point,
                                       history if new_history is None else new_history, reactions)
            last_norms = norms
            if it == max_it:
                break
            if dense is None or len(vals) != len(last_vals) or np.any(vals != last_vals):
                dense = self._condensed_system(rows, cols, vals)
                last_vals = vals
                n_fact += 1
            # after the first update the bulk rows are in balance; at the first they may be
            # already (a bulk that does not depend on the step: only the fault's load changed)
            eliminated = it > 0 or (ref is not None and self._bulk_in_balance(sR, ref))
            dx, dxN, swept = self._solve(sR, dense, bulk_eliminated=eliminated, defer=defer)
            dx *= scale
            if not np.all(np.isfinite(dx)):
                raise StepFailed("non-finite Newton update")
            alpha = 1.0
            if damped and it > 0:  # the first update solves the linear flow part: take it whole
                alpha = self._line_search(x, dx, dxN, pending, norms, ref, rhs, history, dt)
                dx *= alpha
            x += dx
            if dxN is not None:
                if pending is None:
                    pending = _PendingBulk(len(self.N))
                pending.add(alpha, dxN, swept)
            it += 1
        raise StepFailed(f"Newton did not converge in {max_it} iterations "
                         f"(scaled residuals {norms[0]:.3e}, {norms[1]:.3e})")

    def _line_search(self, x, dx, dxN, pending, norms, ref, rhs, history, dt, max_halvings=10):
        """Step length along the Newton direction dx: the first of 1, 1/2, 1/4, ... that lowers
        the merit (sum of the squared field residuals relative to their references) by the Armijo
        fraction 1e-4; the last one tried if none does (the next iteration then re-linearises).
        ``dxN``, ``pending``: the deferred bulk response (see ``_solve``), or None."""
        r0, r1 = max(ref[0], 1e-300), max(ref[1], 1e-300)
        merit0 = (norms[0] / r0) ** 2 + (norms[1] / r1) ** 2
        alpha = 1.0
        for _ in range(max_halvings):
            xt = x + alpha * dx
            trial = None
            if dxN is not None:  # (the line search starts after a step's first iteration:
                # the swept residual is in pending already)
                trial = _PendingBulk(len(self.N)) if pending is None else pending.copy()
                trial.add(alpha, dxN, None)
            R = self._residual(xt, rhs, history, dt, trial)[0]
            # (a non-finite residual has infinite norms: the step is halved)
            _, mech, flow, _ = _scaled_field_norms(R, self.scale, self._free_mech, self._free_flow)
            with np.errstate(over="ignore", invalid="ignore"):
                merit = (mech / r0) ** 2 + (flow / r1) ** 2
            if merit <= (1.0 - 1e-4 * alpha) * merit0:
                break
            alpha *= 0.5
        return alpha

    def _condensed_system(self, rows, cols, vals):
        """The condensed system (Schur complement L_NN - P plus scaled nonlinear tangent) handed
        to the run's one dense solver, which forms and factorises it only when the factors it
        has stop serving (see ``_CondensedSolver``)."""
        if not len(self.N):
            return None
        if self._dense is None:
            self._dense = self._new_condensed_solver()
            if self._restored_condensed is not None:
                # the block of the restored checkpoint, formed from the condensation it was
                # formed from: the restored one, or the one made again at its step size (at
                # another step size the next block is factorised anyway)
                tangent, dt0 = self._restored_condensed
                self._restored_condensed = None
                if self._factors_any_dt or dt0 == self._dt:
                    self._dense.set(self.P, self._linear_entries(dt0), tangent, dt0,
                                    base=self.factorizations)
        tangent = (rows, cols, vals)
        # the Schur complements of one condensation (factorisation of the bulk) differ only in
        # the storage term, which the dense solver is told of when it serves every step size
        self._dense.set(self.P, self._LNN_entries, tangent, self._dt, base=self.factorizations)
        return self._dense

    def _linear_entries(self, dt):
        """L_NN's entries at step size dt (scaled; rows, columns, values)."""
        LNN = self._combine(self._blocks_NN, dt).tocoo()
        return LNN.row.astype(np.int64), LNN.col.astype(np.int64), LNN.data


class _Products(NamedTuple):
    """``NewtonSolver._linear_products`` at x: [A; Hf] x and C (x - x_n); ``whole``: computed
    as whole products (not brought up to date through the condensed columns); ``Cx``: C x when
    computed whole (the next step's stored volume if x is accepted), else None."""
    x_n: np.ndarray
    x: np.ndarray
    AHx: np.ndarray
    Cd: np.ndarray
    whole: bool
    Cx: np.ndarray | None = None


class _PendingBulk:
    """The bulk's answer to a step's Newton updates, not yet in x[B] (``NewtonSolver._step``):
    B^-1 (r_B - L_BN sum(dx_N)), r_B the linear rows' residual at the step's first iteration
    (kept forward-swept), and its effect on the fault rows, L_NB B^-1 r_B (``shift``)."""

    def __init__(self, n_condensed):
        self.swept = None
        self.shift = np.zeros(n_condensed)
        self.fault = np.zeros(n_condensed)

    def add(self, alpha, dxN, swept):
        """Add the update alpha dx_N and, at a step's first iteration, the forward sweep of the
        linear rows' residual with its effect on the fault rows (``swept``: (c, shift), see
        ``NewtonSolver._solve``), both linear in the step length."""
        self.fault += alpha * dxN
        if swept is not None:
            c, shift = swept
            self.swept = alpha * c if self.swept is None else self.swept + alpha * c
            self.shift += alpha * shift

    def copy(self):
        out = _PendingBulk(0)
        out.swept = self.swept
        out.shift = self.shift.copy()
        out.fault = self.fault.copy()
        return out


#: relative residual |M x - b| / |b| of a condensed solve by the preconditioned iteration. Newton's
#: right-hand side is its current residual, so each iteration still reduces it by 1e10 at least
#: (beyond solver.tolerance from the step's start in one iteration) and the iterations taken are
#: those of a direct solve; a direct solve of the ill-conditioned penalty block has a relative
#: residual of 1e-13 to 1e-11 itself.
CONDENSED_RTOL = 1e-10

#: the change of the condensed block is applied as a low-rank update while it lies in at most
#: 1/LOW_RANK_FRACTION of its rows and columns (its cost: that many solves with the old factors)
LOW_RANK_FRACTION = 6

#: a change of the condensed block spread over more rows is left to iteration (refinement, then
#: GMRES) when no entry changed by more than this fraction of its largest entry (else M is
#: factorised anew)
SMALL_CHANGE = 0.05

#: steps of iterative refinement tried before GMRES, each while the last one cut the residual to
#: at most REFINEMENT_GAIN of what it was (Rustrel's rate-and-state tangents: 2.7 steps a solve
#: where GMRES took 3.5 solves and products)
REFINEMENTS = 3
REFINEMENT_GAIN = 1e-3

#: GMRES iterations allowed before the condensed block is factorised anew: measured on this
#: machine, an LU of n unknowns costs as much as 12 iterations (each a product with M and a
#: solve with the old factors) at n = 400, where fixed costs dominate, and about n/40 beyond
def _condensed_max_iterations(n):
    return min(30, max(12, n // 40))


#: columns of the inverse of the factorised block are solved for in pages of this many (a
#: slip front's changed rows are contiguous: few more are solved than needed)
COLUMN_PAGE = 16


@helper
def _add_at_slots(out, slots, weight, vals):
    """The tangent's triplets scaled by their weight added at their slots, in order (those with
    slot -1 lie outside the block)."""
    for k in range(slots.shape[0]):
        if slots[k] >= 0:
            out[slots[k]] += vals[k] * weight[k]


@kernel
def _block_values(n_slots, linear_slots, linear_vals, tangent_slots, weight, vals):
    """L_NN + T at each slot: L_NN's entries, then the tangent's triplets scaled by their weight,
    each in order (duplicates summed)."""
    out = np.zeros(n_slots)
    for k in range(linear_slots.shape[0]):
        out[linear_slots[k]] += linear_vals[k]
    _add_at_slots(out, tangent_slots, weight, vals)
    return out


@kernel
def _tangent_change(n, slot_rows, slot_cols, slots, weight, vals, then):
    """Per slot, the tangent's sum minus the first tangent's ``then`` (its sums at the slots,
    made alike: an entry whose triplets are equal differs by exactly 0); a mask of the rows and
    columns holding a difference and its largest magnitude."""
    m = slot_rows.shape[0]
    now = np.zeros(m)
    _add_at_slots(now, slots, weight, vals)
    changed = np.zeros(n, dtype=np.bool_)
    largest = 0.0
    for s in range(m):
        now[s] -= then[s]
        if now[s] != 0.0:
            changed[slot_rows[s]] = True
            changed[slot_cols[s]] = True
            largest = max(largest, abs(now[s]))
    return now, changed, largest


@kernel
def _sparse_times(indptr, indices, values, v, out):
    """out += S v (S in CSR)."""
    for i in range(indptr.shape[0] - 1):
        acc = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            acc += values[k] * v[indices[k]]
        out[i] += acc


class _BlockPattern:
    """Where the sparse part of the condensed block lies: the union of L_NN's entries and the
    nonlinear tangent's triplets on condensed unknowns (a term's triplets keep their pattern from
    one iteration to the next: it lists zero entries too), each position once in CSR
    order (a slot), and the slot of every entry and triplet (-1: a triplet outside the block)
    with the triplet's scaling."""

    def __init__(self, n, linear, tangent, position, scale):
        self.n = n
        self._linear_at = (linear[0], linear[1])
        self._tangent_at = (tangent[0], tangent[1])
        rows, cols = tangent[0], tangent[1]
        i, j = position[rows], position[cols]
        kept = (i >= 0) & (j >= 0)
        keys = np.concatenate([linear[0] * n + linear[1], i[kept] * n + j[kept]])
        self.keys, slots = np.unique(keys, return_inverse=True)
        self.linear_slots = slots[:len(linear[0])]
        self.tangent_slots = np.full(len(rows), -1, dtype=np.int64)
        self.tangent_slots[kept] = slots[len(linear[0]):]
        self.weight = np.where(kept, scale[rows] * scale[cols], 0.0)
        self.rows, self.cols = self.keys // n, self.keys % n
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(self.rows, minlength=n))])

    def holds(self, linear, tangent):
        """Are these L_NN entries and tangent triplets at this pattern's positions, in its order?
        Arrays that match by their contents are remembered (the pattern's from then on), so
        that the same arrays next time match by identity, without a comparison."""
        pairs = ((linear[0], self._linear_at[0]), (linear[1], self._linear_at[1]),
                 (tangent[0], self._tangent_at[0]), (tangent[1], self._tangent_at[1]))
        if all(a is b for a, b in pairs):
            return True
        if not all(a is b or (len(a) == len(b) and np.array_equal(a, b)) for a, b in pairs):
            return False
        self._linear_at = (linear[0], linear[1])
        self._tangent_at = (tangent[0], tangent[1])
        return True

    def values(self, linear, tangent):
        """L_NN + T at the slots."""
        return _block_values(len(self.keys), self.linear_slots, linear[2], self.tangent_slots,
                             self.weight, tangent[2])


class _CondensedSolver:
    """Solves with the condensed block of the current Newton iteration,
    M = -P + L_NN + T: the bulk's condensation P (dense), the linear Jacobian's condensed block
    L_NN (sparse, of the step size) and the scaled nonlinear tangent T (triplets).

    M changes at every Newton iteration that moves a slip front or an aperture, and with every
    step size; a dense LU of it (n = 400-2000) is the largest cost per iteration. M is formed
    only to be factorised (then M0, at 1/dt0 with the tangent T0; its LU is all that is kept of
    it): otherwise it is applied as -P v + (L_NN + T) v, and M x = b is solved with M0's factors:
    - a step-size change, when the block's only part that depends on it is the storage term
      (``storage``: the condensed, scaled C, nonzero in the flow rows R alone; no rock pore
      pressure), changes M by delta C with delta = 1/dt - 1/dt0: exactly by the Woodbury identity
      on the rows R, M1 = M0 + delta E_R C_R, whose capacitance I + delta C_R M0^-1 E_R is an LU of
      |R| per step size (C_R M0^-1 E_R is made once per M0). M1 is the base that the tangent's
      change below is taken from (without ``storage``, a new step size factorises M);
    - M - M1 = T - T0 (the same condensation: ``base``), read off the tangents' triplets. When
      it lies in few rows and columns K (a slip front that moved by a few fault points), exactly
      by the Woodbury identity, at the cost of |K| solves with M1 in one block;
    - when it is spread but small (rate-dependent friction, an evolving aperture), by iterative
      refinement with M1's factors and, if that contracts slowly, GMRES preconditioned with them
      (right preconditioning: the true residual of M is what converges), to CONDENSED_RTOL.
    Every result is checked against M itself. When none serves, M is factorised and becomes M0.
    (GMRES preconditioned across a step size change of 6 % took 9 iterations per solve on the
    30 deg T = 0.7 scene, more than an LU: hence the exact update on R.)"""

    def __init__(self, storage=None, position=None, scale=None):
        self.P = None
        self._pattern = None
        # the tangent's triplets are on the whole system's unknowns: position in the block of
        # each (-1: not condensed) and the scaling (default: the block's own, unscaled)
        self._position, self._scale = position, scale
        self._base = self._base0 = None
        self.factors = None
        self.factored = False      # the current M is the factorised one
        self.factored_inv_dt = None    # 1/dt of M0
        self.factored_step = None      # and its dt
        self.tangent0 = None           # T0 (triplets, as given to ``set``)
        self.inv_dt = None
        self.factorizations = 0
        self.iterations = 0        # GMRES and refinement iterations, for diagnostics
        self.updates = 0           # low-rank (Woodbury) solves, for diagnostics
        self.storage = None
        if storage is not None:
            self.storage = sp.csr_matrix(storage, copy=True)
            self.storage.sum_duplicates()
            C = self.storage
            self._storage_rows = np.flatnonzero(np.diff(C.indptr))   # R
            self._C_R = C[self._storage_rows]

    def set(self, P, linear, tangent, dt, base=None):
        """The block to solve with next, M = -P + L_NN + T at step size ``dt``: ``linear``, L_NN's
        entries (rows, columns, values in the block) and ``tangent``, T's triplets (rows, columns,
        values, on the unknowns that ``position`` places in the block, scaled by ``scale``;
        duplicates summed). ``base`` tells which condensation P is (a count, not the array;
        None: unknown, the block is factorised); blocks of the same base and pattern differ by
        the tangent and the step size alone."""
        self.P = P
        self.inv_dt = 1.0 / dt
        self._step = dt
        self._base = base
        self._tangent = tangent
        n = len(P)
        if self._pattern is None or not self._pattern.holds(linear, tangent):
            position = np.arange(n) if self._position is None else self._position
            scale = np.ones(len(position)) if self._scale is None else self._scale
            self._pattern = _BlockPattern(n, linear, tangent, position, scale)
            self.factors = None  # (the tangent of M0 is on another pattern)
        pattern = self._pattern
        self._sparse = pattern.values(linear, tangent)
        self.factored = False
        if (self.factors is None or base is None or base != self._base0
                or (self.inv_dt != self.factored_inv_dt and self.storage is None)):
            self._factorise()

    def _times(self, v):
        """M v = -P v + (L_NN + T) v."""
        out = -(self.P @ v)
        p = self._pattern
        _sparse_times(p.indptr, p.cols, self._sparse, v, out)
        return out

    def _form(self):
        """M as a dense array (the one n x n array of its own this solver makes), in Fortran
        order: LAPACK factorises it in place (a C-ordered one would be copied first)."""
        M = np.negative(self.P, order="F")
        p = self._pattern
        M[p.rows, p.cols] += self._sparse  # (each position once)
        return M

    def _factorise(self):
        # the old factors and what was solved with them go before the new block is formed (the
        # run's peak memory on the fine 30 deg scene: three n x n arrays at once, not four)
        self.factors = None
        self._Z = self._Z1 = self._Z_R = self._K_R = None
        M = self._form()
        self._M0_largest = max(float(M.max()), -float(M.min())) if M.size else 0.0
        self.factors = scipy.linalg.lu_factor(M, overwrite_a=True, check_finite=False)
        del M
        self.factored_inv_dt = self.inv_dt
        self.factored_step = self._step
        self._base0 = self._base
        self.tangent0 = self._tangent
        # T0 summed at the slots (as _tangent_change sums T), once while T0 is the base
        p = self._pattern
        self._tangent0_sums = _block_values(len(p.keys), p.linear_slots[:0], self._sparse[:0],
                                            p.tangent_slots, p.weight, self.tangent0[2])
        self.factored = True
        self.factorizations += 1
        # columns of M0^-1 solved for so far (the changed rows only grow until M0 is replaced;
        # _Z, None above)
        self._have = np.zeros(len(self.P), dtype=bool)
        # M0^-1 E_R and C_R M0^-1 E_R (_Z_R, _K_R): made at the first step-size change, from M0
        # alone (in one block: a restored run makes them bit for bit)
        self._new_step_size(0.0)

    def _new_step_size(self, delta):
        """The base M1 = M0 + delta E_R C_R: its capacitance's LU and the columns of M1^-1 kept
        for it (``_base_columns``)."""
        self._delta = delta
        self._capacitance_R = None
        self._Z1 = None
        self._have1 = np.zeros(len(self.P), dtype=bool)

    def _step_size_update(self):
        """Make the base M1 that of the current step size; False when its capacitance cannot be
        factorised."""
        delta = self.inv_dt - self.factored_inv_dt
        if delta == self._delta:
            return True
        self._new_step_size(delta)
        if self._Z_R is None:
            R = self._storage_rows
            E = np.zeros((len(self.P), len(R)))
            E[R, np.arange(len(R))] = 1.0
            self._Z_R = lu_solve(self.factors, E)
            self._K_R = np.asarray(self._C_R @ self._Z_R)
        capacitance = np.eye(len(self._K_R)) + delta * self._K_R
        try:
            self._capacitance_R = scipy.linalg.lu_factor(capacitance, check_finite=False)
        except (np.linalg.LinAlgError, ValueError):
            return False
        return True

    def _step_size_correction(self, W):
        """M1^-1 V from W = M0^-1 V (a vector or columns):
        W - delta Z_R (I + delta K_R)^-1 C_R W."""
        if self._delta == 0.0:
            return W
        t = lu_solve(self._capacitance_R, self._C_R @ W)
        return W - self._delta * (self._Z_R @ t)

    def _precondition(self, v):
        """M1^-1 v (M0^-1 v while M is of M0's step size)."""
        return self._step_size_correction(lu_solve(self.factors, v))

    def solve(self, b):
        if not self.factored:
            x = None
            if self._step_size_update():
                D, K, DK, largest = self._tangent_change()
                if len(K) * LOW_RANK_FRACTION <= len(b):
                    x = self._low_rank(b, DK, K)
                elif largest <= SMALL_CHANGE * self._M0_largest:
                    x = self._iterate(b, D)
            if x is not None:
                return x
            self._factorise()
        return self._precondition(b)

    def _tangent_change(self):
        """M - M1 = T - T0 (same condensation and pattern): its values at the slots, the rows
        and columns K holding a difference, its dense K x K block and its largest magnitude."""
        p = self._pattern
        D, changed, largest = _tangent_change(p.n, p.rows, p.cols, p.tangent_slots, p.weight,
                                              self._tangent[2], self._tangent0_sums)
        K = np.flatnonzero(changed)
        DK = None
        if len(K) * LOW_RANK_FRACTION <= p.n:
            at = np.full(p.n, -1)
            at[K] = np.arange(len(K))
            DK = np.zeros((len(K), len(K)))
            nz = np.flatnonzero(D)
            DK[at[p.rows[nz]], at[p.cols[nz]]] = D[nz]   # (each position once)
        return D, K, DK, largest

    def _base_columns(self, K):
        """M1^-1 E_K: the columns of M0^-1 at K (kept while M0 is: K grows as a front advances),
        corrected for the step size (kept while it is that of M1). Both are made a page of
        COLUMN_PAGE columns at a time, each page alone: a column's round-off then does not depend
        on which others were asked for with it, so a restored run, which starts with none kept,
        repeats them bit for bit."""
        n = len(self.P)
        if self._Z is None:
            self._Z = np.empty((n, n), order="F")  # (pages of unsolved columns stay untouched)
        for page in self._pages(K, self._have):
            E = np.zeros((n, len(page)))
            E[page, np.arange(len(page))] = 1.0
            self._Z[:, page] = lu_solve(self.factors, E)
            self._have[page] = True
        if self._delta == 0.0:
            return self._Z[:, K]
        if self._Z1 is None:
            self._Z1 = np.empty((n, n), order="F")
        for page in self._pages(K, self._have1):
            self._Z1[:, page] = self._step_size_correction(self._Z[:, page])
            self._have1[page] = True
        return self._Z1[:, K]

    @staticmethod
    def _pages(K, have):
        """The pages (column ranges of COLUMN_PAGE) holding a column of K not in ``have``."""
        n = len(have)
        for first in np.unique(K[~have[K]] // COLUMN_PAGE) * COLUMN_PAGE:
            yield np.arange(first, min(first + COLUMN_PAGE, n))

    def _low_rank(self, b, DK, K):
        """Woodbury: with M = M1 + E D E^T (E: the columns of the identity at the changed rows
        and columns K), M^-1 b = y - Z (I + D Z_K)^-1 D y_K, y = M1^-1 b, Z = M1^-1 E. None when
        the result misses the check."""
        if len(K) == 0 and self._delta == 0.0:
            return self._precondition(b)  # M is M0
        if len(K):
            Z = self._base_columns(K)
            capacitance = np.eye(len(K)) + DK @ Z[K]
            try:
                cap = scipy.linalg.lu_factor(capacitance, check_finite=False)
            except (np.linalg.LinAlgError, ValueError):
                return None

            def apply(r):
                y = self._precondition(r)
                return y - Z @ lu_solve(cap, DK @ y[K])
        else:  # only the step size changed
            apply = self._precondition

        # a slip front's tangents change the stiff shear penalty, and M1 differs from M by the
        # round-off of the storage change: the identity loses digits there, which up to two
        # steps of refinement with it recover
        goal = CONDENSED_RTOL * np.linalg.norm(b)
        x = apply(b)
        for refinements in range(3):
            r = b - self._times(x)
            if np.linalg.norm(r) <= goal:
                self.updates += 1
                return x
            if refinements == 2:  # (a third correction would go unchecked)
                return None
            x = x + apply(r)

    def _iterate(self, b, D):
        """x with |M x - b| <= CONDENSED_RTOL |b|, or None: iterative refinement with M1's
        factors while each step gains REFINEMENT_GAIN (a change of 1e-5 of the block: two
        steps), then GMRES from where it stopped. With M = M1 + D (D = T - T0 at the pattern's
        slots, sparse; up to the round-off of the storage change), each step is
        x' = M1^-1 (b - D x), whose residual b - M x' is D (x - x'): the steps need no product
        with the dense M, which checks the last one."""
        goal = CONDENSED_RTOL * np.linalg.norm(b)
        p = self._pattern
        y = self._precondition(b)
        x = y
        D_x = np.zeros_like(b)
        _sparse_times(p.indptr, p.cols, D, x, D_x)
        last = np.linalg.norm(D_x)   # (b - M y = -D y)
        for _ in range(REFINEMENTS):
            if last <= goal:
                break
            self.iterations += 1
            x_next = y - self._precondition(D_x)
            D_next = np.zeros_like(b)
            _sparse_times(p.indptr, p.cols, D, x_next, D_next)
            norm = np.linalg.norm(D_x - D_next)
            x, D_x = x_next, D_next
            if norm > REFINEMENT_GAIN * last:
                break
            last = norm
        r = b - self._times(x)
        if np.linalg.norm(r) <= goal:
            return x
        return self._gmres(b, x, r, goal)

    def _gmres(self, b, x, r, goal):
        """From x (residual r = b - M x): x with |M x - b| <= goal in at most
        ``_condensed_max_iterations`` GMRES iterations, right-preconditioned by the old factors;
        None if not reached. The recurrence's residual estimate drifts from the true one in
        floating point: the true one decides, and the iteration restarts from it while the
        budget lasts."""
        budget = _condensed_max_iterations(len(b))
        while True:
            beta = np.linalg.norm(r)
            if beta <= goal:
                return x
            if budget <= 0:
                return None
            y, V = self._arnoldi(r, beta, 0.5 * goal, budget)
            budget -= len(y)
            x = x + self._precondition(y @ V)
            r = b - self._times(x)

    def _arnoldi(self, r, beta, goal, m):
        """GMRES cycle on M z = r (z = P^-1 v): the least-squares coefficients y and the basis V
        (rows) once the residual estimate is below ``goal`` or after m iterations. The
        Hessenberg matrix is reduced by Givens rotations as it grows, so the estimate is the
        last entry of the rotated right-hand side."""
        V = np.empty((m + 1, len(r)))
        H = np.zeros((m + 1, m))
        cs, sn = np.zeros(m), np.zeros(m)
        g = np.zeros(m + 1)
        g[0] = beta
        V[0] = r / beta
        for j in range(m):
            w = self._times(self._precondition(V[j]))
            # classical Gram-Schmidt twice: as stable as modified, in two matrix products
            h = V[:j + 1] @ w
            w -= h @ V[:j + 1]
            h2 = V[:j + 1] @ w
            w -= h2 @ V[:j + 1]
            col = np.append(h + h2, np.linalg.norm(w))
            for i in range(j):  # the earlier rotations, then a new one zeroing the subdiagonal
                col[i], col[i + 1] = cs[i] * col[i] + sn[i] * col[i + 1], -sn[i] * col[i] + cs[i] * col[i + 1]
            rho = np.hypot(col[j], col[j + 1])
            cs[j], sn[j] = (col[j] / rho, col[j + 1] / rho) if rho > 0.0 else (1.0, 0.0)
            H[:j + 1, j] = col[:j + 1]
            H[j, j] = rho
            g[j + 1] = -sn[j] * g[j]
            g[j] *= cs[j]
            self.iterations += 1
            if abs(g[j + 1]) <= goal or col[j + 1] == 0.0 or j == m - 1:
                y = scipy.linalg.solve_triangular(H[:j + 1, :j + 1], g[:j + 1], check_finite=False)
                return y, V[:j + 1]
            V[j + 1] = w / col[j + 1]

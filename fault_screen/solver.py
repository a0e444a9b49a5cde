"""One implicit time step: Newton-Raphson on the coupled residual with its consistent Jacobian,
solved by a sparse direct LU on a symmetrically scaled system (``linear_system``).

Residual of a step from x_n over dt (theta = ``time_weight`` of the flow terms)::

    R(x) = A x + C (x - x_n)/dt + Hf (theta x + (1 - theta) x_n) - load - sources
           + sum of the nonlinear terms' contributions (contact, evolving-aperture conduction)

Scaling: rows and columns of the free block are scaled by 1/sqrt(|J_ii|) (row maximum where
the diagonal is zero, as for the injection multiplier). This equilibrates displacements (m,
stiffness ~1e10 Pa) against pressures (Pa, conductance ~1e-16) and keeps Heaviside DOFs whose
support is cut into a thin sliver well conditioned (the Jacobi part of Béchet et al. 2005).
"""
from __future__ import annotations

import copy
import functools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from ._jit import helper, kernel
from .assembly import TripletBuilder
from .discretisation import Discretisation
from .linear_system import CondensedSystem, PendingBulk, _csr_row_times, unsigned_indices
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


#: whole products of this many accepted states are kept for an extrapolated first guess (the
#: stepper's extrapolation reads three)
KEPT_STATE_PRODUCTS = 3


#: ``_where_changed`` stops after the first block of this many unknowns that shows a change off
#: the condensed ones (each block's loop has no branch, so that it is vectorised)
CHANGE_BLOCK = 1024


#: a deferred bulk update (see NewtonSolver._step) is made when the fault residual has not halved
#: for this many Newton iterations while within STALLED_NEAR_TOLERANCE of the tolerance
STALLED_ITERATIONS = 3

#: the stalled rule serves a residual at a floor that the exact reference may clear (round-off,
#: a reference underestimated at the lagging bulk): one within this factor of what the test asks.
#: Far above it the fault is still converging (a slip front crossing a few points an iteration
#: does not halve the residual): the exact check could not pass there, and bringing the bulk up
#: to date early only costs a second backward sweep in the step (at stalls 8e4 to 3e8 times
#: the tolerance in the regression cases and the fine 30-degree scene, no exact check passed)
STALLED_NEAR_TOLERANCE = 1e3


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
def _whole_products(A_indptr, A_indices, A_data, H_indptr, H_indices, H_data, C_indptr,
                    C_indices, C_data, x, Cx_n):
    """[A x; Hf x], C x and C x - C x_n in one pass over the rows (three CSR products and a
    difference that took five calls and passes); each row's sums as ``A @ x`` makes them."""
    n = x.shape[0]
    AHx = np.empty(2 * n)
    Cx = np.empty(n)
    Cd = np.empty(n)
    for i in range(n):
        AHx[i] = _csr_row_times(A_indptr, A_indices, A_data, x, i)
        AHx[n + i] = _csr_row_times(H_indptr, H_indices, H_data, x, i)
        c = _csr_row_times(C_indptr, C_indices, C_data, x, i)
        Cx[i] = c
        Cd[i] = c - Cx_n[i]
    return AHx, Cx, Cd


@kernel
def _weighted_sum_of(terms, w0, a0, w1, a1, w2, a2):
    """w0 a0 + w1 a1 (+ w2 a2 when ``terms`` is 3) in one pass, each product rounded and the
    sum added left to right as numpy makes ``w0 * a0``, ``+= w1 * a1``, ``+= w2 * a2``."""
    n = a0.shape[0]
    out = np.empty(n)
    if terms == 3:
        for k in range(n):
            out[k] = (w0 * a0[k] + w1 * a1[k]) + w2 * a2[k]
    else:
        for k in range(n):
            out[k] = w0 * a0[k] + w1 * a1[k]
    return out


def weighted_sum(weights, arrays) -> np.ndarray:
    """sum_i weights[i] * arrays[i] (a new array), added in their order: the same floats as
    ``weights[0] * arrays[0]`` with each further product added in place; one pass for two or
    three arrays (an extrapolation's states), five numpy passes fewer."""
    if len(arrays) in (2, 3):
        w = [float(v) for v in weights] + [0.0]
        return _weighted_sum_of(len(arrays), w[0], arrays[0], w[1], arrays[1], w[2], arrays[-1])
    out = weights[0] * arrays[0]
    for w, a in zip(weights[1:], arrays[1:]):
        out += w * a
    return out


@kernel
def _where_changed(x, before, n_index):
    """0 when x equals ``before`` (x - before zero everywhere), 1 when it differs only at
    condensed unknowns (n_index >= 0), 2 when elsewhere too: one pass, stopping at the first
    block of CHANGE_BLOCK with a change off them, where the difference and its counts took
    three. (A NaN difference counts as a change, as count_nonzero counts it.)"""
    n = x.shape[0]
    out = 0
    for start in range(0, n, CHANGE_BLOCK):
        off = 0
        on = 0
        for k in range(start, min(start + CHANGE_BLOCK, n)):   # (branch-free: vectorised)
            changed = x[k] - before[k] != 0.0
            off += changed & (n_index[k] < 0)
            on += changed
        if off:
            return 2
        if on:
            out = 1
    return out


@helper
def _reference_entry(scale, AHx, Cd, dt, flow_known, k, flow):
    """One entry of ``_reference_norms``' vectors: scale A x at a mechanical unknown k, scale
    (|C (x - x_n)| / dt + |Hf x| + known flow terms) at a flow unknown."""
    if flow:
        return scale[k] * (abs(Cd[k]) / dt + abs(AHx[scale.shape[0] + k]) + flow_known[k])
    return scale[k] * AHx[k]


@kernel
def _reference_norms(scale, AHx, Cd, dt, flow_known, mech_at, flow_at):
    """The convergence test's reference magnitudes: |scale A x| over the free mechanical
    unknowns, |scale (|C (x - x_n)| / dt + |Hf x| + known flow terms)| over the free flow ones
    (inf where an entry is not finite). Each entry made where its square is summed (no vectors
    of the entries), in the order and with the overflow guard of ``_norm_at``: the same floats."""
    out = np.zeros(2)
    for field in range(2):
        at = flow_at if field == 1 else mech_at
        total = 0.0
        largest = 0.0
        finite = True
        for k in at:
            a = abs(_reference_entry(scale, AHx, Cd, dt, flow_known, k, field == 1))
            if not np.isfinite(a):
                finite = False
            total += a * a
            largest = max(largest, a)
        if not finite:
            out[field] = np.inf
        elif largest > 0.0 and (total == np.inf or total < 1e-290):
            total = 0.0
            for k in at:
                a = _reference_entry(scale, AHx, Cd, dt, flow_known, k, field == 1) / largest
                total += a * a
            out[field] = largest * np.sqrt(total)
        else:
            out[field] = np.sqrt(total)
    return out[0], out[1]


@kernel
def _updated_through_columns(base, indptr, slots, data, touched, dN):
    """base + M dN for the few columns M of a matrix on the condensed unknowns (CSC, each row
    index given as its slot in ``touched``, the rows with an entry): the column products summed
    column by column as scipy's CSC product sums them, then added to base on those rows only
    (a copy of base elsewhere, where the product is zero), in one pass where the product's
    vector and the sum took two and a temporary of base's length."""
    work = np.zeros(touched.shape[0])
    for j in range(dN.shape[0]):
        d = dN[j]
        for p in range(indptr[j], indptr[j + 1]):
            work[slots[p]] += data[p] * d
    out = base.copy()
    for s in range(touched.shape[0]):
        out[touched[s]] = base[touched[s]] + work[s]
    return out


def _columns_on(M):
    """(indptr, slots, data, touched) of ``_updated_through_columns`` for the CSC matrix M."""
    touched, slots = np.unique(M.indices, return_inverse=True)
    return (M.indptr.astype(np.int64), slots.astype(np.int64), M.data,
            touched.astype(np.int64))


class NewtonSolver:
    """Newton on the coupled residual, with the linear bulk condensed onto the fault.

    Only the fault terms are nonlinear (the terms' ``nonlinear_dofs``: contact on the Heaviside
    DOFs, evolving-aperture conduction on the fault pressures). The free unknowns are split into
    those (N, a few hundred) and everything else (B), whose Jacobian block is constant for a given
    time step. The linear algebra (scaling, the sparse LU of the free block with N ordered last,
    the Schur complement on N, the sweeps that eliminate the bulk, the dense condensed solver) is
    ``linear_system.CondensedSystem`` (``system``); this class is the iteration. The bulk is
    linear, so after a step's first Newton update its rows stay in balance: a step sweeps
    forward once for the step's right-hand side, iterates on the fault with the small dense
    condensed system, and sweeps backward once for the bulk's answer to the sum of its fault
    updates (see ``_step``).
    """

    _AH_N = None
    _products = None
    _Cx_n = None       # (x_n, C x_n) of the current step
    _next_rung = None            # the next rung's expected first step size (``expect_rung``)
    _in_situ_floor = None        # (see _in_situ_reference)
    _state_products = ()         # (x, [A; Hf] x, C x) of the last accepted states, whole

    def __init__(self, disc: Discretisation):
        self.disc = disc
        s = disc.scene
        # the time weight of the current step: the scene's theta, or the step's of the theta
        # ladder (``step``'s ``time_weight``, decided by the stepper)
        self.time_weight = s.time.theta
        self.tol = s.solver.tolerance
        self.max_it = s.solver.max_iterations
        # the accepted states' whole products are kept only for an extrapolated first guess,
        # which sums them (``_combined_products``)
        self._keeps_state_products = s.solver.first_guess == "extrapolated"
        self.A, self.C, self.Hf, self.source = assemble_constant(disc)
        self.nonlinear_terms = [t for t in disc.physics.terms
                                if type(t).residual is not Term.residual]
        self._tangent_pattern = None   # the nonlinear terms' rows and columns, joined (``nonlinear``)
        self.free = disc.free
        self._fixed = np.flatnonzero(disc.fixed) if disc.fixed.dtype == bool else disc.fixed
        b = disc.blocks
        mech = np.zeros(disc.n_dofs, dtype=bool)
        mech[b.u] = True
        mech[b.a] = True
        self.mech_free = mech[self.free]
        # the two fields' free unknowns, unsigned for the kernels that gather over them (see
        # ``unsigned_indices``)
        self._free_mech = unsigned_indices(self.free[self.mech_free])
        self._free_flow = unsigned_indices(self.free[~self.mech_free])
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
        self.system = CondensedSystem(self.A, self.C, self.Hf, self.time_weight, self.free,
                                      self._fixed, nonlinear, disc.dof_coordinates, mech)
        self.N, self.B = self.system.N, self.system.B
        mech_B = self.mech_free[~nonlinear[self.free]]
        # the bulk's unknowns of each field (``_bulk_in_balance``)
        self._B_mech, self._B_flow = self.B[mech_B], self.B[~mech_B]
        self.n_index = self.system.n_index
        # the bulk update may wait until a convergence check needs it only when the nonlinear
        # terms read nothing but condensed unknowns (the fault's jump and pressure DOFs)
        fp = disc.fault_points
        read = np.concatenate([fp.jump_dofs.ravel(), fp.p_dofs.ravel()])
        read = read[(read >= 0) & ~disc.fixed[np.maximum(read, 0)]]
        self._fault_reads_only_N = bool(np.all(self.n_index[read] >= 0))

    @property
    def scale(self):
        """The symmetric scaling of the free system (``CondensedSystem``; None before the first
        step; set by a restored checkpoint)."""
        return self.system.scale

    @scale.setter
    def scale(self, value):
        self.system.scale = value

    @property
    def fixed_unknowns(self):
        """The fixed unknowns (indices, ascending)."""
        return self._fixed

    @property
    def factorizations(self):
        """Factorisations of the bulk so far."""
        return self.system.factorizations

    @property
    def L(self):
        """The linear Jacobian at the current step size (``CondensedSystem.L``)."""
        return self.system.L

    def checkpoint_state(self) -> dict:
        """``CondensedSystem.checkpoint_state``."""
        return self.system.checkpoint_state()

    def restore_state(self, state: dict):
        """``CondensedSystem.restore_state``."""
        self.system.restore_state(state)

    def fork(self) -> "NewtonSolver":
        """A solver for a fork of the run, continuing from this one's state (``CondensedSystem.fork``:
        the constant matrices and factors shared read-only). Call it between steps."""
        twin = copy.copy(self)
        twin.system = self.system.fork()
        twin._next_rung = None
        return twin

    def blas_threads(self):
        """``CondensedSystem.blas_threads``: a caller that takes many steps holds it around
        all of them."""
        return self.system.blas_threads()

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

    def _prepare(self, dt, x_n, history, rung=None):
        """The linear system of step size ``dt`` and the step's time weight
        (``CondensedSystem.prepare``; ``rung``: see there), scaled at the first step with the
        nonlinear terms' tangent at x_n."""
        def tangent():
            rows, cols, vals, _ = self.nonlinear(x_n, history, dt, np.zeros(self.disc.n_dofs))
            return rows, cols, vals

        if rung is None:
            self.system.prepare(dt, tangent)
        else:
            self.system.prepare(dt, tangent, self.time_weight, rung)
        if self._next_rung is not None:   # (once: a retry of this step does not start it again)
            self.system.factorise_ahead(self._next_rung)
            self._next_rung = None

    def expect_rung(self, dt):
        """The next rung's first step size, if the steps go as planned (None: none expected):
        its bulk factors are made beside this rung's steps, started once this step's linear
        system is at hand (``CondensedSystem.factorise_ahead``)."""
        self._next_rung = dt

    def settle(self):
        """No factors in the making after this (``CondensedSystem.settle``): at the end of a
        run's steps, however they ended."""
        self._next_rung = None
        self.system.settle()

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
        th = self.time_weight
        return last.AHx[:n] + stored_n + (last.AHx[n:] if th == 1.0 else th * last.AHx[n:])

    def _linear_times_guess(self, x0, x_n, dt, combination=None):
        """L x0 for a step that starts from a first guess x0 other than x_n, from the products
        A x0, Hf x0 and C x0 (kept for the convergence test, which then needs no product at the
        first iteration) instead of a product with L (not held: see ``CondensedSystem.L``).
        ``combination``: (weights, states) with x0 = sum of weights times states on the free
        unknowns (an extrapolated guess): the products are then those sums of the states' whole
        products (``_state_products``), which saves a whole product per step; else made whole."""
        Cx_n = self._C_times_start(x_n)
        combined = None if combination is None else self._combined_products(x0, *combination)
        if combined is None:
            AHx, Cx, Cd = _whole_products(*self._csr_arrays, x0, Cx_n)
            self._products = _Products(x_n, x0.copy(), AHx, Cd, True, Cx)
        else:
            AHx, Cx = combined
            Cd = Cx - Cx_n
            # (not whole: a later step does not take them for whole products at x0)
            self._products = _Products(x_n, x0.copy(), AHx, Cd, False)
        n = self.disc.n_dofs
        th = self.time_weight
        return AHx[:n] + Cx / dt + (AHx[n:] if th == 1.0 else th * AHx[n:])

    def _whole_state_products(self, x):
        """(x, [A; Hf] x, C x) of an accepted state, made whole: those kept at the step that
        was accepted there (``_keep_state_products``), else made now. Whole products of equal
        states are equal to the bit, so sums of them do not depend on which were kept (a
        restored or forked run makes the same ones)."""
        for kept in self._state_products:   # (by identity first: a comparison is a pass)
            if kept[0] is x:
                return kept
        for kept in self._state_products:
            if np.array_equal(kept[0], x):
                return kept
        AHx, Cx, _ = _whole_products(*self._csr_arrays, x, np.zeros_like(x))
        return x, AHx, Cx

    def _keep_state_products(self, x, AHx, Cx):
        # (a new tuple, never changed in place: a fork shares it)
        self._state_products = (self._state_products + ((x, AHx, Cx),))[-KEPT_STATE_PRODUCTS:]

    def _combined_products(self, x0, weights, states):
        """([A; Hf] x0, C x0) as the weighted sums of the states' whole products, x0 the sum of
        the weighted states on the free unknowns and the last state's values on the fixed ones;
        None when those differ between the states (a prescribed value that moves: the sum
        would not hold there). The states' products are kept in their order, oldest first: the
        next step's extrapolation reads the newer ones again."""
        fixed = self._fixed
        last = states[-1]
        if any(not np.array_equal(x[fixed], last[fixed]) for x in states[:-1]):
            return None
        used = tuple(self._whole_state_products(x) for x in states)
        self._state_products = used[-KEPT_STATE_PRODUCTS:]
        return (weighted_sum(weights, [AHx for _, AHx, _ in used]),
                weighted_sum(weights, [Cx for _, _, Cx in used]))

    def _residual(self, x, rhs, history, dt, pending, Lx=None):
        """Residual at x and the nonlinear terms' tangent and fault state. ``pending``
        (``PendingBulk`` or None): the bulk's answer to the step's updates that x[B] does not
        hold yet. On the fault rows it adds L_NB B^-1 (r_B - L_BN dx_N) = shift - P dx_N (P =
        L_NB B^-1 L_BN, dense, from the factorisation); the bulk rows are in balance once it is
        made (linear bulk, eliminated exactly), so only the fault rows and those of the fixed
        unknowns (the reactions) are computed."""
        if pending is None:
            R = (self.L @ x if Lx is None else Lx) - rhs
        else:
            R = self.system.residual_with_pending(x, rhs, pending)
        rows, cols, vals, point = self.nonlinear(x, history, dt, R)
        return R, rows, cols, vals, point

    def step(self, x_n, history, dt, injection_value, damped=False, x0=None, combination=None,
             time_weight=None, rung=None):
        """Advance from x_n over dt. ``injection_value``: the step's injected volume (m^3, whole
        interval; rate control) or the prescribed overpressure at the step's end (Pa; pressure
        control); ignored without an injection term. ``damped``: globalise the Newton iteration
        with a backtracking line search (see ``_line_search``); the stepper retries a failed step
        so before it halves the step, because a sudden load (a pressure jump, a slip front
        crossing many points at once) makes the full Newton step of the Coulomb return map
        overshoot and cycle, and under pressure control a shorter step does not reduce the jump.
        ``x0``: the first guess (default x_n); ``combination``: (weights, states) when x0 is
        the weighted sum of earlier accepted states (x_n the last) on the free unknowns and x_n
        on the fixed ones (an extrapolation). ``time_weight``, ``rung``: a step of the theta
        ladder, its weight and its rung's first step size (``CondensedSystem.prepare``); default
        the scene's theta. The weight is the solver's ``time_weight`` until the next step.

        BLAS threads: see ``blas_threads``."""
        theta = self.disc.scene.time.theta
        if (time_weight is None) != (rung is None) or (
                rung is not None and abs(time_weight * dt - theta * rung) > 1e-12 * theta * rung):
            # (the factors of the rung serve only a step of its theta dt)
            raise ValueError(f"a step of the theta ladder needs time_weight * dt = theta * rung "
                             f"(theta = {theta}); got time_weight {time_weight}, dt {dt}, rung {rung}")
        self.time_weight = theta if time_weight is None else time_weight
        with self.blas_threads():
            return self._step(x_n, history, dt, injection_value, damped, x0, combination, rung)

    def _reference(self, x, x_n, dt, ref0, flow_known, at_start=False):
        """Reference magnitudes of the convergence test at x: internal forces (mechanics);
        stored-volume rate plus conduction plus sources (flow); never below the step's first
        residual norms ``ref0``. ``at_start``: x is the step's first guess, untouched (see
        ``_linear_products``)."""
        AHx, Cd = self._linear_products(x, x_n, at_start)
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

    def _linear_products(self, x, x_n, at_start=False):
        """[A; Hf] x and C (x - x_n), for the reference magnitudes. While the bulk's answer is
        deferred (``_step``), Newton changes x in its condensed unknowns only: the products of
        the last call are then brought up to date through those columns alone; and a step
        starts where the last one was accepted, whose products are at hand. (Across steps only
        products computed whole are reused, so that a restored run repeats them bit for bit.)
        ``at_start``: x is the step's first guess, whose products are at hand: at x0
        (``_linear_times_guess`` made them) or whole at x_n (``_linear_times_start`` made sure);
        the comparisons below, two passes over x, would find that."""
        last = self._products
        if at_start:
            if last.x_n is not x_n:   # (only a first guess x_n: a guess x0 sets x_n)
                last = self._products = _Products(x_n, x.copy(), last.AHx, np.zeros_like(x), True)
            return last.AHx, last.Cd
        if last is not None and (last.x_n is x_n or last.whole):
            changed = _where_changed(x, last.x, self.n_index)
            if changed == 0 and last.x_n is x_n:
                return last.AHx, last.Cd
            if changed < 2:   # (x - last.x is zero off the condensed unknowns)
                if last.x_n is x_n:
                    dN = x[self.N] - last.x[self.N]
                    AHx = _updated_through_columns(last.AHx, *self._AH_N, dN)
                    Cd = _updated_through_columns(last.Cd, *self._C_N, dN)
                    self._products = _Products(x_n, x.copy(), AHx, Cd, False)
                    return AHx, Cd
                if changed == 0:  # a new step from the last accepted state
                    Cd = np.zeros_like(x) if np.array_equal(x, x_n) else self.C @ (x - x_n)
                    self._products = _Products(x_n, x.copy(), last.AHx, Cd, True)
                    return last.AHx, Cd
        AHx, Cx, Cd = _whole_products(*self._csr_arrays, x, self._C_times_start(x_n))
        self._products = _Products(x_n, x.copy(), AHx, Cd, True, Cx)
        return AHx, Cd

    @functools.cached_property
    def _csr_arrays(self):
        """A, Hf and C as (indptr, indices, data) each, for ``_whole_products`` (the index
        arrays unsigned: ``unsigned_indices``)."""
        return tuple(a for M in (self.A, self.Hf, self.C)
                     for a in (unsigned_indices(M.indptr), unsigned_indices(M.indices), M.data))

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
        lim = BULK_BALANCE * self.tol
        return (np.linalg.norm(sR[self._B_mech]) <= lim * ref[0]
                and np.linalg.norm(sR[self._B_flow]) <= lim * ref[1])

    def _step(self, x_n, history, dt, injection_value, damped, x0, combination=None, rung=None):
        disc = self.disc
        th = self.time_weight
        self._prepare(dt, x_n, history, rung)
        scale = self.scale
        if self._AH_N is None:  # the columns of A and Hf on the condensed unknowns, stacked
            # by columns: a product then visits the few hundred columns, not every row, most of
            # them empty (2.5x faster on the paper-units Rustrel scene); each row's sum still
            # runs over the columns in order, as by rows (the same bits)
            self._AH_N = _columns_on(sp.vstack([self.A[:, self.N], self.Hf[:, self.N]]).tocsc())
            self._C_N = _columns_on(self.C.tocsc()[:, self.N])
        stored_n = self._C_times_start(x_n) / dt
        rhs = stored_n + disc.load
        if th != 1.0:  # backward Euler (the default) has no known part of the conduction
            rhs -= (1.0 - th) * (self.Hf @ x_n)
        injection = disc.physics.injection
        if injection is not None:
            injection.load(disc, self.source, rhs, injection_value, dt, th)
        if th != 1.0:  # (the known part of a time-weighted term is (1 - theta) of it)
            known = np.zeros(disc.n_dofs)
            for term in self.nonlinear_terms:
                term.previous_step(disc, x_n, th, known)
            rhs -= known
        flow_known = np.abs(rhs - stored_n)  # sources and the known parts of the flow terms
        x = x_n.copy() if x0 is None else x0.copy()  # x0: a better first guess (continuation)
        Lx = (self._linear_times_start(x_n, stored_n) if x0 is None
              else self._linear_times_guess(x, x_n, dt, combination))
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
                # residual for STALLED_ITERATIONS iterations near the tolerance (round-off floor,
                # a reference underestimated: STALLED_NEAR_TOLERANCE), or at the last iteration,
                # the bulk is brought up to date with one backward sweep and the iterate is
                # checked exactly, as if never deferred.
                # The residual needs no new evaluation: its fault rows are exact already, the
                # bulk rows are in balance and the nonlinear terms read only fault unknowns;
                # only the reactions (rows of fixed unknowns) are recomputed.
                # (the estimate never lowers the last exact reference: it is only needed when the
                # fault fails against that one)
                ref = exact_ref
                if any(norms[k] > tol * ref[k] for k in (0, 1)):
                    ref = tuple(map(max, exact_ref, self._reference(x, x_n, dt, ref0, flow_known)))
                failing = [k for k in (0, 1) if norms[k] > tol * ref[k]]
                stalled = stalled + 1 if all(
                    0.5 * last_norms[k] < norms[k] <= STALLED_NEAR_TOLERANCE * tol * ref[k]
                    for k in failing) else 0
                if not failing or stalled >= STALLED_ITERATIONS or it == max_it:
                    self.system.complete_bulk(x, pending, R)
                    pending = None
            # at the first iteration the reference serves the deferred update and the bulk
            # balance test, which only a step-size-independent bulk can pass
            if pending is None and (check or (it == 0 and (defer or self.static_B))):
                ref = exact_ref = self._reference(x, x_n, dt, ref0, flow_known, at_start=it == 0)
                if check and norms[0] <= tol * ref[0] and norms[1] <= tol * ref[1]:
                    reactions = np.zeros(disc.n_dofs)
                    reactions[self._fixed] = R[self._fixed]
                    new_history = point.pop("history")
                    last = self._products
                    if (self._keeps_state_products and last.whole and last.Cx is not None
                            and last.x_n is x_n):
                        # (at x: the next step's extrapolation sums them)
                        self._keep_state_products(x, last.AHx, last.Cx)
                    return StepOutcome(x, it, n_fact, point,
                                       history if new_history is None else new_history, reactions)
            last_norms = norms
            if it == max_it:
                break
            if dense is None or len(vals) != len(last_vals) or np.any(vals != last_vals):
                dense = self.system.condensed(rows, cols, vals)
                last_vals = vals
                n_fact += 1
            # after the first update the bulk rows are in balance; at the first they may be
            # already (a bulk that does not depend on the step: only the fault's load changed)
            eliminated = it > 0 or (ref is not None and self._bulk_in_balance(sR, ref))
            dx, dxN, swept = self.system.solve(sR, dense, bulk_eliminated=eliminated, defer=defer)
            alpha = 1.0
            if dxN is not None and not damped:
                # dx is zero off N (the bulk's answer is pending): the update and its test there
                N = self.N
                dx_N = dx[N] * scale[N]
                if not np.all(np.isfinite(dx_N)):
                    raise StepFailed("non-finite Newton update")
                x[N] += dx_N
            else:
                dx *= scale
                if not np.all(np.isfinite(dx)):
                    raise StepFailed("non-finite Newton update")
                if damped and it > 0:  # the first update solves the linear flow part: take it whole
                    alpha = self._line_search(x, dx, dxN, pending, norms, ref, rhs, history, dt)
                    dx *= alpha
                x += dx
            if dxN is not None:
                if pending is None:
                    pending = PendingBulk(len(self.N))
                pending.add(alpha, dxN, swept)
            it += 1
        raise StepFailed(f"Newton did not converge in {max_it} iterations "
                         f"(scaled residuals {norms[0]:.3e}, {norms[1]:.3e})")

    def _line_search(self, x, dx, dxN, pending, norms, ref, rhs, history, dt, max_halvings=10):
        """Step length along the Newton direction dx: the first of 1, 1/2, 1/4, ... that lowers
        the merit (sum of the squared field residuals relative to their references) by the Armijo
        fraction 1e-4; the last one tried if none does (the next iteration then re-linearises).
        ``dxN``, ``pending``: the deferred bulk response (see ``CondensedSystem.solve``), or None."""
        r0, r1 = max(ref[0], 1e-300), max(ref[1], 1e-300)
        merit0 = (norms[0] / r0) ** 2 + (norms[1] / r1) ** 2
        alpha = 1.0
        for _ in range(max_halvings):
            xt = x + alpha * dx
            trial = None
            if dxN is not None:  # (the line search starts after a step's first iteration:
                # the swept residual is in pending already)
                trial = PendingBulk(len(self.N)) if pending is None else pending.copy()
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

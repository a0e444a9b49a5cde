"""The linear algebra of a Newton step: the free system condensed onto the fault.

The free unknowns are split into the nonlinear ones N (the fault's jumps and pressures, a few
hundred; chosen by the Newton iteration) and everything else B, whose Jacobian block is
constant for a given step size. ``CondensedSystem`` holds what solving with that Jacobian
needs and keeps it across Newton iterations and steps:

- the symmetric scaling of the free block (fixed at the first step, kept in checkpoints);
- one sparse LU of the scaled free block with N ordered last (``bordered_lu``: a nested-dissection
  order of B, the Schur complement on N, the forward and backward sweeps that eliminate the bulk),
  made again only when the step size changes what the bulk holds;
- the condensation P = L_NB B^-1 L_BN and the dense solver of the condensed block
  M = -P + L_NN + T (``CondensedSolver``: factors reused across tangents and step sizes);
- the bulk's answer to a step's fault updates, deferred and summed (``PendingBulk``);
- the BLAS threads (one while the condensed block is small).
"""
from __future__ import annotations

import contextlib
import copy
import functools
import os
import sys
import threading
from typing import NamedTuple

import numpy as np
import scipy.linalg
import scipy.sparse as sp
from scipy.linalg.blas import dsymv as _symv

from ._jit import helper, kernel
from .bordered_lu import (_linear_rows_symmetric, bordered_lu, lu_solve, release_freed_memory,
                          split_layout)
from .fixed_pattern import FixedBulk, FixedSum
from . import ldl
from .ldl import SymbolicAnalyses
from .ordering import nested_dissection
from . import shared_bulk


#: condensed (nonlinear) blocks up to this many unknowns are solved with one BLAS thread: with
#: the factors reused (``CondensedSolver``) the work is mostly matrix-vector solves and products,
#: which threads do not speed up and which spin against the other processes of a busy machine
#: (the fine 30 deg scene, 2059 fault unknowns: 323 s of CPU for 465 s of wall at load 7-10)
SINGLE_THREAD_BLAS_UP_TO = 6000


@functools.cache
def _blas_controller():
    """The BLAS libraries loaded in the process (found once; limiting them is then cheap)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


class _SingleThreadBlas:
    """One BLAS thread while any holder is inside, for the whole process (BLAS's thread count is
    process-wide): the first holder in limits it, the last one out restores what it was. Two
    runs stepping in two threads (a run and its fork) each limiting and restoring on their own
    would interleave: the first out restored the threads under the other, and the last out
    restored the limit it had found, one thread, for good. And threadpoolctl lets only one
    thread change OpenBLAS's threads (the first that did, while it lives) and silently ignores
    the others: a fork stepping in a worker thread beside a run on the main thread had two BLAS
    threads, and its pressures differed in round-off (5e-10 of 4 MPa) from the same fork's
    stepped alone. So each change here takes that control for itself and hands it back."""

    def __init__(self):
        self._lock = threading.Lock()
        self._holders = 0
        self._limiter = None

    @staticmethod
    @contextlib.contextmanager
    def _in_control():
        from threadpoolctl import OpenBLASController

        release = getattr(OpenBLASController, "clear_controlling_thread", None)
        if release is not None:
            release(force=True)
        try:
            yield
        finally:
            if release is not None:
                release(force=True)

    @contextlib.contextmanager
    def held(self):
        with self._lock:
            if self._holders == 0:
                with self._in_control():
                    self._limiter = _blas_controller().limit(limits=1, user_api="blas")
            self._holders += 1
        try:
            yield
        finally:
            with self._lock:
                self._holders -= 1
                if self._holders == 0:
                    with self._in_control():
                        self._limiter.restore_original_limits()
                    self._limiter = None


_SINGLE_THREAD_BLAS = _SingleThreadBlas()


class CondensedSystem:
    """The scaled free system of a Newton step, A + C / dt + theta Hf plus the nonlinear tangent
    on N, solved by condensation onto N (see the module docstring).

    ``A``, ``C``, ``Hf``: the constant matrices (CSR); ``free``, ``fixed``: the free and fixed
    unknowns; ``condensed``: which unknowns are condensed (N; a mask over all unknowns, the free
    ones of the rest are B); ``coordinates``: () -> the unknowns' positions (m), for the bulk's
    order; ``mechanical``: which unknowns are displacements (a mask; the rest are flow ones).

    A bulk that depends on the step size (rock pore pressure) is factorised in its symmetric
    form: with its flow rows multiplied by -dt the scaled poroelastic block is symmetric and
    quasi-definite (stiffness positive definite, storage plus dt times conduction positive
    definite), so it has an L D L^T in the fill-reducing order without pivoting, at every step
    size: ``ldl.py``, whose symbolic analysis (``_analyses``) is made at the first step and
    serves every later step size, which pays the numeric factorisation only (SuperLU, keeping
    its diagonal pivots, where a pivot fails); the matrix of a new step size is written into
    the pattern fixed at the first (``fixed_pattern``), not summed, scaled and permuted anew.
    Factorised as it is, its pivoting grew with dt (the flow rows' diagonal, storage over dt,
    shrinks against the coupling): on the paper-units Rustrel scene the factors
    took 3.7 times the memory and 5-6 times the time at dt = 60-600 s that they take at 5 s
    (benchmarks/factorisation.py). The row factors are undone on the right-hand side and on the
    Schur complement (``_row_factor``). An elastic bulk (no rock pore pressure: symmetric
    positive definite, one factorisation a run) takes the same L D L^T."""

    _dense = None
    _order = None
    _split = None      # the parts of the bulk's factorisation (see bordered_lu.split_layout)
    _blocks_NN = None
    _blocks_fixed = None
    _blocks_rows_N_fixed = None
    _blas_limited = False
    _restored_P = None
    _restored_condensed = None   # [(tangent, dt)] of the checkpoint's condensed blocks, recalled first
    lu = None
    P = None
    P_symmetric = False   # P made exactly symmetric (``condensation_symmetrised``)
    _row_factor = None   # per free unknown in the factors' order: -dt (flow), 1 (mechanics)
    _analyses = None     # the LDL^T's symbolic analyses of the symmetric form (ldl.py)
    _bulk = None         # the symmetric form's fixed pattern (fixed_pattern.FixedBulk)
    _bulk_symmetric = False
    bulk_patterns = 0    # FixedBulk patterns made (one a run)
    _sum_NN = _sum_fixed = _sum_rows_N_fixed = None   # fixed patterns of L's other parts
    _ahead = None        # the next rung's bulk factors in the making (``factorise_ahead``)

    def __init__(self, A, C, Hf, time_weight, free, fixed, condensed, coordinates, mechanical):
        self.A, self.C, self.Hf = A, C, Hf
        self._mechanical = mechanical
        self.time_weight = time_weight
        self.free = free
        self._fixed = fixed
        nl_free = condensed[free]
        self.N = N = free[nl_free]
        self.B = free[~nl_free]
        self._coordinates = coordinates
        self.n_dofs = A.shape[0]
        # position of each global DOF in N (for the nonlinear tangents), -1 elsewhere
        self.n_index = np.full(self.n_dofs, -1, dtype=np.int64)
        self.n_index[N] = np.arange(len(N))
        self.scale = None
        self.factorizations = 0
        self._L = None                 # the linear Jacobian (``L``), when made
        self.dt = None
        self.theta = time_weight       # the time weight of the current step (``prepare``)
        self._factored_dt = None       # the step size of the bulk's factors (at ``time_weight``)
        self._P_factored = None        # P at that step size (a rung's steps scale its rows)
        self._P_factored_symmetric = False
        self._LNN_factored = None      # L_NN's entries at that step size
        # in a rung's later step (``_rung_step``), per condensed unknown: dt / dt0 in the flow
        # rows, 1 in the mechanical ones (D); else None
        self._rung_rows = None
        # the step size enters only the storage (C) and the theta-weighted conduction (Hf): when
        # neither touches a linear unknown, the factors serve every step size and only the N block
        # of the Schur complement changes with it
        self.factors_any_dt = not any(self._touches_linear(M) for M in (C, Hf))

    def _touches_linear(self, M) -> bool:
        """Has M a nonzero entry between two free unknowns, one of them linear (in B)? Read off
        its entries (slicing M's free block for it cost more than the rest of this set-up)."""
        M = M.tocsr()
        free = np.zeros(self.n_dofs, dtype=bool)
        free[self.free] = True
        linear = np.zeros(self.n_dofs, dtype=bool)
        linear[self.B] = True
        rows = np.repeat(np.arange(self.n_dofs), np.diff(M.indptr))
        cols = M.indices
        return bool(np.any((M.data != 0.0) & free[rows] & free[cols] & (linear[rows] | linear[cols])))

    def checkpoint_state(self) -> dict:
        """Arrays that a restored solver needs to take bit-identical steps: the nonlinear tangent
        and step size of the condensed block last factorised (later solves are preconditioned by
        its factors; the block is formed again from them), whether it was formed from the
        current condensation, and the condensation when it serves every step size (see
        ``prepare``)."""
        out = {}
        if self.factors_any_dt and self.lu is not None:
            out["condensation"] = self.P
        d = self._dense
        if d is not None and d.tangent0 is not None:
            for key, ((rows, cols, vals), step, base) in d.factorised_blocks().items():
                out.update({f"{key}_tangent_rows": rows, f"{key}_tangent_cols": cols,
                            f"{key}_tangent_values": vals, f"{key}_step": np.array(step),
                            f"{key}_current": np.array(base == self.factorizations)})
        return out

    def restore_state(self, state: dict):
        """Undo ``checkpoint_state``. The condensed block is formed and factorised again at the
        first Newton iteration, once the condensation is at hand (LAPACK repeats the factors
        exactly). (A checkpoint written before the tangent was stored holds the block itself:
        it is not used, the first iteration factorises its own block.)"""
        if "condensation" in state:
            self._restored_P = np.array(state["condensation"])
        # the recalled block first: factorising the current one then recalls it (``condensed``)
        self._restored_condensed = [
            ((np.array(state[f"{key}_tangent_rows"]), np.array(state[f"{key}_tangent_cols"]),
              np.array(state[f"{key}_tangent_values"])), float(state[f"{key}_step"]))
            for key in ("condensed_recalled", "condensed")
            if f"{key}_tangent_rows" in state and bool(state[f"{key}_current"])] or None

    def fork(self) -> "CondensedSystem":
        """A system for a fork of the run: the same state, the constant blocks, the bulk's
        factors and the condensation shared read-only (a step only replaces them, never writes
        into them: a fork that needs new factors makes its own), the dense solver's caches its
        own. Call it between steps."""
        twin = copy.copy(self)
        twin._blas_limited = False
        twin._ahead = None   # (the factors made ahead are this run's guess)
        twin._dense = None if self._dense is None else self._dense.fork()
        return twin

    def _new_condensed_solver(self):
        """The run's dense solver; it is told the storage block when that is all a step-size
        change alters (``factors_any_dt``), so that it can keep its factors across step sizes."""
        return CondensedSolver(self._condensed_blocks()[1] if self.factors_any_dt else None,
                               position=self.n_index, scale=self.scale)

    def _condensed_blocks(self):
        """The condensed block of A, C, Hf (scaled: needs the scaling), sliced once."""
        if self._blocks_NN is None:
            N = self.N
            sN = self.scale[N]
            self._blocks_NN = [M[N][:, N].multiply(sN[:, None]).multiply(sN[None, :]).tocsr()
                               for M in (self.A, self.C, self.Hf)]
        return self._blocks_NN

    @functools.cached_property
    def keeps_factors_at_theta_dt(self) -> bool:
        """Do the bulk's factors depend on the step only through theta dt? So when the factors
        are of the symmetric form (rock pore pressure: flow rows times -dt) and, on the free
        unknowns, A has no flow rows and C and Hf no mechanical ones: the flow rows are then
        -C - theta dt Hf, the mechanical ones A (the theta ladder, ``prepare``'s ``rung``)."""
        if self.factors_any_dt:
            return False
        free = np.zeros(self.n_dofs, dtype=bool)
        free[self.free] = True
        for M, wrong_rows in ((self.A, ~self._mechanical), (self.C, self._mechanical),
                              (self.Hf, self._mechanical)):
            M = M.tocsr()
            rows = np.repeat(np.arange(self.n_dofs), np.diff(M.indptr))
            if np.any((M.data != 0.0) & free[rows] & free[M.indices] & wrong_rows[rows]):
                return False
        return True

    def prepare(self, dt, nonlinear_tangent, theta=None, rung=None):
        """The linear part for step size ``dt`` and time weight ``theta`` (default the scene's):
        ``rung``, a step of the theta ladder (``keeps_factors_at_theta_dt``): the step size at
        which the bulk is factorised, at the scene's weight, with theta dt = time_weight rung.
        The factors of that size serve (factorised now if they are not at hand: a restored run
        makes the same ones); only P's flow rows (P = L_NB B^-1 L_BN of rows as they are, whose
        flow rows scale as 1/dt at a fixed theta dt), the row factors and the sparse sums change
        (``_rung_step``); the condensed block keeps its factors too (``condensed``). Without
        ``rung`` (or at dt = rung) see ``_prepare_factorised``."""
        if theta is None or rung is None or rung == dt:
            return self._prepare_factorised(dt, nonlinear_tangent)
        if dt == self.dt and theta == self.theta:
            return
        if self.lu is None or self._factored_dt != rung:
            self._prepare_factorised(rung, nonlinear_tangent)
        self._rung_step(dt, theta)

    def _row_factors(self, dt):
        """Per free unknown in the factors' order: -dt on a flow row, 1 on a mechanical one (the
        symmetric form's row factors at step size dt)."""
        return np.where(self._mechanical[self._order], 1.0, -dt)

    def _rung_step(self, dt, theta):
        """The linear system of a step inside the rung of the factors (``prepare``)."""
        self._L = None
        ratio = self._factored_dt / dt
        flow_N = ~self._mechanical[self.N]
        if flow_N.any():   # (a new array: forks share the factorisation's)
            self.P = self._P_factored * np.where(flow_N, ratio, 1.0)[:, None]
            self.P_symmetric = False
        self._rung_rows = np.where(flow_N, dt / self._factored_dt, 1.0)
        self._row_factor = self._row_factors(dt)
        self._L_fixed_B = self._sum_fixed.matrix(dt, theta)
        self._L_rows_N_fixed = self._sum_rows_N_fixed.matrix(dt, theta)
        self.dt, self.theta = dt, theta

    def _prepare_factorised(self, dt, nonlinear_tangent):
        """The Jacobian's linear part for step size ``dt``, its factors and Schur complement.

        The scaling is fixed at the first step (and kept in checkpoints), from the diagonal of
        the linear Jacobian and of ``nonlinear_tangent()`` (the nonlinear terms' triplets at the
        step's start). When the step size touches no linear unknown (``factors_any_dt``: no rock
        pore pressure), the factors of the first step serve all: for a new dt only the N block
        changes, S = L_NN(dt) - P with the condensation P = L_NB B^-1 L_BN of the first
        factorisation (kept in checkpoints, so that a restored run repeats the same round-off)."""
        if dt == self.dt and self.theta == self.time_weight:
            return
        # factors made ahead for this step size, or none (made for another size: dropped, their
        # thread ended first, before this thread factorises on the same pattern)
        ahead = self._take_ahead(dt)
        self._L = None   # (the last step size's L goes first)
        factorise = self.lu is None or not self.factors_any_dt
        # the Jacobian summed the general way: for the scaling and the order (first step) and an
        # elastic bulk's one factorisation; a poroelastic bulk's values at later step sizes are
        # written into its fixed pattern (``_bulk``)
        L = (self._linear_jacobian(dt)
             if self.scale is None or self._order is None or (factorise and self.factors_any_dt)
             else None)
        if self.scale is None:
            diag = np.abs(L.diagonal())
            rows, cols, vals = nonlinear_tangent()
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
            Ls = None
            if L is not None:   # (first step; an elastic bulk's one factorisation)
                D = sp.diags(self.scale)
                Ls = (D @ L @ D).tocsr()
                del L
            if self._order is None:  # the pattern of B is that of every step size
                # (how many fault unknowns each bulk unknown couples to: the order reads it)
                coupling = np.diff(Ls[B][:, N].tocsr().indptr)
                self._order, self._split = _with_shared(
                    lambda store, make: store.order(Ls[B][:, B], self._coordinates()[B], make,
                                                    coupling),
                    lambda: self._bulk_order(Ls, coupling))
            self._row_factor = None
            self.lu = None  # the old factors go before the new ones are made (peak memory)
            if Ls is not None:
                # (not at a refactorisation in the fixed pattern: what that frees, the last
                # factors, are arrays of the sizes it allocates next, which the heap reuses;
                # handed back, they cost the trim and fresh pages at every step-size change)
                release_freed_memory()
                # the factorisation's peak (SuperLU's storage and the factors copied out of it)
                # is reached holding neither L nor the matrix factorised
                held = [Ls[self._order][:, self._order].tocsc()]
                del Ls
                if not self.factors_any_dt:
                    # the symmetric form (see the class docstring) at the run's first step size,
                    # summed the general way: the fixed pattern (``_factorise_symmetric``) is
                    # made when the step size first changes, and never for a run on one step
                    # size (on 200 x 201 it cost 3.9 s of 24); its values equal these bit for bit
                    self._row_factor = self._row_factors(dt)
                    held[0].data *= self._row_factor[held[0].indices]
                # an elastic bulk (positive definite, symmetric) takes the L D L^T too: on the
                # fine 30 deg scene its factorisation took half SuperLU's CPU time; factorised
                # once a run, it then lets its symbolic analyses go (13 MB on that scene, whose
                # limit is 500 MB)
                if self._analyses is None:
                    self._analyses = _with_shared(lambda store, make: store.analyses,
                                                  SymbolicAnalyses)
                self.lu = self._factorise_held(held, len(B))
                if self.factors_any_dt:
                    self._analyses = None
            else:   # the symmetric form in its fixed pattern (made ahead, or now)
                self.lu = ahead if ahead is not None else self._factorise_symmetric(dt)
                self._row_factor = self._row_factors(dt)
            self.factorizations += 1
            if self._row_factor is not None:   # (the Schur complement of the rows as they are)
                self.lu.schur /= self._row_factor[len(B):, None]
            # P = L_NN - S in the Schur complement's own memory, which the factors then give up
            # (n_N x n_N dense: 34 MB on the fine 30 deg scene), L_NN added entry by entry
            rows, cols, vals = self._LNN_entries
            self.P = np.negative(self.lu.schur, out=self.lu.schur)
            self.P[rows, cols] += vals   # (each position once)
            self.lu.schur = None
            if self._restored_P is not None:
                # into the factorisation's own P, so that it keeps its memory layout (the
                # L D L^T's is Fortran-ordered, a C-ordered copy makes later sums in another order)
                np.copyto(self.P, self._restored_P)
                self._restored_P = None
            self.P_symmetric = condensation_symmetrised(self.P)
            self._factored_dt, self._P_factored = dt, self.P
            self._P_factored_symmetric, self._LNN_factored = self.P_symmetric, self._LNN_entries
        self._rung_rows = None
        if self._blocks_fixed is None:  # rows of the fixed unknowns on the linear ones, in order
            self._blocks_fixed = [M[self._fixed].tocsc()[:, self.linear_order()].tocsr()
                                  for M in (self.A, self.C, self.Hf)]
        self._L_fixed_B = self._fixed_sum("_sum_fixed", self._blocks_fixed).matrix(dt)
        if self._blocks_rows_N_fixed is None:  # the rows a residual with a pending bulk needs
            self._rows_N_fixed = np.concatenate([N, self._fixed])
            self._blocks_rows_N_fixed = [M[self._rows_N_fixed] for M in (self.A, self.C, self.Hf)]
        self._L_rows_N_fixed = self._fixed_sum("_sum_rows_N_fixed",
                                               self._blocks_rows_N_fixed).matrix(dt)
        self.dt, self.theta = dt, self.time_weight

    def _fixed_sum(self, name, blocks):
        """The ``FixedSum`` of these blocks, made at the first step and kept as ``name``."""
        made = getattr(self, name)
        if made is None:
            made = FixedSum(blocks, self.time_weight)
            setattr(self, name, made)
        return made

    def _factorise_held(self, held, n_linear):
        """``bordered_lu`` of the one matrix in the list ``held`` (emptied, so that the
        factorisation's peak holds no copy of it), or the factors of an equal matrix inside
        ``shared_bulk.sharing()``."""
        store = shared_bulk.active()
        if store is None:
            return bordered_lu(held.pop, n_linear, self._split, self._analyses)
        M = held.pop()   # (the key needs the matrix: held here until factorised)
        return store.factors((M.indptr, M.indices, M.data, np.asarray(M.shape)), n_linear,
                             self._split, lambda: bordered_lu(lambda: M, n_linear, self._split,
                                                              self._analyses))

    def fixed_bulk(self):
        """The poroelastic bulk's fixed pattern (``fixed_pattern.FixedBulk``), made at the first
        call (the solver's: when the step size first changes) with its symmetry check."""
        if self._bulk is None:
            nB, blocks, flow = len(self.B), (self.A, self.C, self.Hf), ~self._mechanical[self._order]
            # (inside sharing(): the positions of an earlier member's equal pattern, its values ours)
            self._bulk = _with_shared(
                lambda store, make: store.pattern(FixedBulk.pattern_key(blocks, self._order, flow, nB),
                                                  make).with_values(blocks, self.time_weight, self.scale),
                lambda: FixedBulk(blocks, self.time_weight, self._order, self.scale, flow, nB))
            self._bulk_symmetric = all(_linear_rows_symmetric(X, nB)
                                       for X in self._bulk.components())
            self.bulk_patterns += 1
        return self._bulk

    def _factorise_symmetric(self, dt):
        """The bulk's factors at step size dt in the symmetric form, its values written into
        the fixed pattern (``fixed_pattern.FixedBulk``, made with its symmetry check at the
        first step: every later matrix is X + dt Y + Z / dt of the same three parts, so it is
        symmetric, to their round-off, when they are)."""
        nB = len(self.B)
        bulk = self.fixed_bulk()
        if self._analyses is None:
            self._analyses = _with_shared(lambda store, make: store.analyses, SymbolicAnalyses)
        # every entry's value only where it is read: by SuperLU, a split bulk or as the key of
        # a shared bulk (the L D L^T reads the lower triangle and the condensed block alone)
        values = []

        def full():
            if not values:
                values.append(bulk.values(dt))
            return values[0]

        def parts():
            return (bulk.parts(dt) if not values
                    else (bulk.lower(values[0]), bulk.condensed(values[0])))

        def matrix():   # (for SuperLU or a split bulk: the values go with the call)
            M = bulk.matrix(full())
            values.clear()
            return M

        def make():
            return bordered_lu(matrix, nB, self._split, self._analyses,
                               symmetric_parts=parts if self._bulk_symmetric else None)

        return _with_shared(
            lambda store, make: store.factors(
                (bulk.indptr, bulk.indices, full(), np.asarray(bulk.shape)), nB, self._split, make),
            make)

    def factorise_ahead(self, dt):
        """Start the bulk's factors for step size ``dt`` at the scene's time weight (the next
        rung's first size, ``Simulation._next_rung``) in a thread of their own, while the current
        rung's steps run on their factors: ``prepare`` at that size takes them (waiting for them if
        unfinished), a factorisation at any other size drops them first. Only where a rung's
        start refactorises (``keeps_factors_at_theta_dt``, the fixed pattern's first factors
        made), outside ``shared_bulk.sharing()`` (whose store is the calling thread's). The thread
        calls what ``prepare`` would, ``_factorise_symmetric(dt)`` on the same arrays, which
        writes nothing a step reads: the same factors bit for bit (ldl.py's factors are the same
        bits in one thread or two)."""
        if (not self.keeps_factors_at_theta_dt or self.lu is None or self._order is None
                or dt == self._factored_dt or shared_bulk.active() is not None):
            return
        self.settle()
        self.fixed_bulk()   # (made here, so that the thread only reads what the run holds)
        if self._analyses is None:
            self._analyses = SymbolicAnalyses()
        self._ahead = _Ahead(dt, self._factorise_symmetric)

    def _take_ahead(self, dt):
        """The factors made ahead for step size ``dt`` (waiting for them), or None (none made,
        or made for another size: dropped once their thread has ended). A failure in their
        thread is raised here, where ``prepare`` would have raised it."""
        ahead, self._ahead = self._ahead, None
        if ahead is None:
            return None
        if ahead.dt != dt:
            ahead.discard()
            return None
        return ahead.factors()

    @property
    def making_ahead(self) -> float | None:
        """The step size whose factors are being made ahead, or None."""
        return None if self._ahead is None else self._ahead.dt

    def finish_ahead(self):
        """Wait for the factors in the making (kept for their step): before a fork, which
        shares the fixed pattern and the symbolic analyses, or a checkpoint."""
        if self._ahead is not None:
            self._ahead.wait()

    def settle(self):
        """Drop factors made ahead (their thread ended first): at the end of a run's steps,
        however they ended, so that no thread outlives them and no second set of factors is held
        between calls."""
        ahead, self._ahead = self._ahead, None
        if ahead is not None:
            ahead.discard()

    def _bulk_order(self, Ls, fault_coupling):
        """(the free unknowns in the factors' order, the split of B's factorisation): B in a
        nested-dissection order of its pattern that knows which unknowns couple to the fault
        (``fault_coupling``, see ``ordering.nested_dissection``), then N."""
        B = self.B
        inner, split, quarters = nested_dissection(Ls[B][:, B], self._coordinates()[B], return_split=True,
                                                   return_quarters=True, fault_coupling=fault_coupling)
        layout, split = split_layout(len(B), split, quarters)
        if layout is not None:
            inner = inner[layout]
        return np.concatenate([B[inner], self.N]), split

    @property
    def order(self):
        """The free unknowns in the factors' order (B in its fill-reducing order, then N)."""
        return self._order

    @property
    def split(self):
        """The parts of the bulk's factorisation (see bordered_lu.split_layout)."""
        return self._split

    @property
    def L(self):
        """The linear Jacobian at the current step size, made at its first use and kept while
        the step size is: a residual with the bulk's answer deferred never reads it (every step
        of the bundled scenes), so it is not held beside A (17 MB on the fine 30 deg scene)."""
        if self._L is None:
            self._L = self._linear_jacobian(self.dt, self.theta)
        return self._L

    def _linear_jacobian(self, dt, theta=None):
        """A + C / dt + theta Hf (CSR, unscaled; theta default the scene's)."""
        return self._combine((self.A, self.C, self.Hf), dt, theta).tocsr()

    def _combine(self, blocks, dt, theta=None):
        """A + C / dt + theta Hf from the same block of each."""
        A, C, Hf = blocks
        return A + C * (1.0 / dt) + Hf * (self.time_weight if theta is None else theta)

    def linear_order(self):
        """The linear unknowns in the factors' order."""
        return self._order[:len(self.B)]

    def solve(self, sR, dense, bulk_eliminated, defer):
        """Solve (scaled) J dx = -sR with J = L + nonlinear tangent (on N only; ``dense``, the
        condensed block's solver from ``condensed``).

        Returns (dx, dxN, swept). ``bulk_eliminated``: the linear rows are in balance (every
        Newton update after a step's first solves them exactly, and the bulk is linear), so their
        residual is round-off and the forward sweep is skipped (swept is None). ``defer``: dx
        holds only the fault update dxN, whose bulk response B^-1 (r_B - L_BN dxN) is left to the
        caller, who sums the updates of a step (``PendingBulk``) and sweeps backward once
        (``complete_bulk``); ``swept`` goes with it: the forward-swept r_B and its effect on the
        fault rows, L_NB B^-1 r_B. Otherwise dx is complete and dxN None."""
        N = self.N
        linear = self.linear_order()
        out = np.zeros_like(sR)
        rN = -sR[N]
        swept = None
        if bulk_eliminated:
            g = rN
        elif self._row_factor is None:
            swept, g = self.lu.forward(-sR[linear], rN)
        else:   # (the factors are of the rows times _row_factor: so is the right-hand side)
            f = self._row_factor
            nB = len(linear)
            swept, g = self.lu.forward(_negated_at(sR, unsigned_indices(linear), f), f[nB:] * rN)
            g /= f[nB:]
        D = self._rung_rows   # (a rung's block is D M: see ``condensed``)
        dxN = (dense.solve(g) if D is None else dense.solve(D * g)) if len(N) else g
        out[N] = dxN
        if defer:
            # P dxN, when the condensed solve's check made it: the residual with the bulk's
            # answer pending then sums the products (``PendingBulk``) instead of a pass over P
            product = dense.condensation_product(dxN) if len(N) else None
            if product is not None and D is not None:   # (the dense solver's P is D P)
                product = product / D
            return out, dxN, Deferred(swept, None if swept is None else rN - g, product)
        out[linear] = self.lu.backward(swept, dxN)
        return out, None, None

    def residual_with_pending(self, x, rhs, pending):
        """The linear part of the residual, L x - rhs, on the rows of N and of the fixed unknowns
        (zero elsewhere), with the bulk's answer to the step's updates that x[B] does not hold
        yet (``pending``): on the fault rows L_NB B^-1 (r_B - L_BN dx_N) = shift - P dx_N (P =
        L_NB B^-1 L_BN, dense, from the factorisation). The bulk rows are in balance once it is
        made (linear bulk, eliminated exactly)."""
        needed = self._rows_N_fixed
        R = np.zeros_like(x)
        R[needed] = self._L_rows_N_fixed @ x - rhs[needed]
        R[self.N] += ((pending.shift - pending.condensed(self.P, self.P_symmetric))
                      / self.scale[self.N])
        return R

    def complete_bulk(self, x, pending, R):
        """Bring x[B] up to date with the pending bulk answer (one backward sweep) and the
        residual's rows of fixed unknowns (the reactions) with it: the other rows are up to date
        (see ``NewtonSolver._step``) and the nonlinear terms read no bulk unknown."""
        dxB = _scaled_update(x, unsigned_indices(self.linear_order()), self.scale,
                             self.lu.backward(pending.swept, pending.fault))
        R[self._fixed] += self._L_fixed_B @ dxB

    def blas_threads(self):
        """Run BLAS on one thread while the condensed block is small: its dense products and LU
        take a millisecond or less, where OpenBLAS's threads only add start-up and, on a busy
        machine, spin against the other processes (a 3-14x slow-down measured, issue 15). A
        caller that takes many steps holds this around all of them: limiting and restoring the
        threads at every step cost a BLAS thread spinning beside the run (CPU 1.8x the wall
        time on the T = 0.4 scene). Re-entrant, and safe from several threads (``_SingleThreadBlas``:
        a large system stepping beside a small one then has one thread too). Held already, or
        for a large block, it is a null context: each step enters it, so that case costs no
        generator."""
        if len(self.N) > SINGLE_THREAD_BLAS_UP_TO or self._blas_limited:
            return contextlib.nullcontext()
        return self._one_blas_thread()

    @contextlib.contextmanager
    def _one_blas_thread(self):
        """(``blas_threads``, not held yet)"""
        self._blas_limited = True
        try:
            with _SINGLE_THREAD_BLAS.held():
                yield
        finally:
            self._blas_limited = False

    def condensed(self, rows, cols, vals):
        """The condensed system (Schur complement L_NN - P plus scaled nonlinear tangent) handed
        to the run's one dense solver, which forms and factorises it only when the factors it
        has stop serving (see ``CondensedSolver``)."""
        if not len(self.N):
            return None
        if self._dense is None:
            self._dense = self._new_condensed_solver()
            restored, self._restored_condensed = self._restored_condensed or [], None
            for tangent, dt0 in restored:
                # the blocks of the restored checkpoint (the recalled one, then M0), each formed
                # from the condensation it was formed from: the restored one, or the one made
                # again at its step size (at another step size the next block is factorised
                # anyway)
                if self.factors_any_dt or dt0 == self._factored_dt or dt0 == self.dt:
                    P, symmetric = self._condensation_of(dt0)
                    self._dense.set(P, self._linear_entries(dt0), tangent, dt0,
                                    base=self.factorizations, symmetric=symmetric)
                    self._dense.factorise_set()
        D = self._rung_rows
        if D is None:
            tangent = (rows, cols, vals)
            # the Schur complements of one condensation (factorisation of the bulk) differ only
            # in the storage term, which the dense solver is told of when it serves every step size
            self._dense.set(self.P, self._LNN_entries, tangent, self.dt, base=self.factorizations,
                            symmetric=self.P_symmetric)
        else:
            # a rung's later step: its block M in the rows of the factors' step, D M = -P0 +
            # L_NN(dt0) + D T (D: dt / dt0 on the flow rows; theta dt is dt0's), whose linear
            # part is the block of the rung's first step: its factors serve, and the tangent's
            # change is taken from theirs (``CondensedSolver``)
            at = self.n_index[rows]
            tangent = (rows, cols, vals * np.where(at >= 0, D[at], 1.0))
            self._dense.set(self._P_factored, self._LNN_factored, tangent, self._factored_dt,
                            base=self.factorizations, symmetric=self._P_factored_symmetric)
        return self._dense

    def _condensation_of(self, dt):
        """(P, symmetric) the dense solver was given at step size dt, the current or the
        factors' (``condensed``)."""
        if dt == self._factored_dt and self._P_factored is not None:
            return self._P_factored, self._P_factored_symmetric
        return self.P, self.P_symmetric

    def _linear_entries(self, dt, theta=None):
        """L_NN's entries at step size dt (scaled; rows, columns, values; theta default the
        scene's)."""
        return self._fixed_sum("_sum_NN", self._blocks_NN).entries(dt, theta)


#: the condensation P = L_NB B^-1 L_BN is taken as symmetric, and made exactly so, when no entry
#: differs from its mirror image by more than this fraction of its largest entry: the round-off
#: of condensing a symmetric bulk (3e-13 on the fine 30 deg scene, factorised in parts). An
#: unsymmetric one (a poroelastic bulk's flow rows, whose Schur complement is divided by -dt)
#: differs at the scale of its entries
CONDENSATION_SYMMETRY_ROUNDOFF = 1e-11

#: rows of P compared and mirrored at a time (a temporary of this many rows, not n x n: the fine
#: 30 deg scene's peak memory is close to its limit)
_MIRROR_ROWS = 256


def condensation_symmetrised(P) -> bool:
    """Is P (square) symmetric to CONDENSATION_SYMMETRY_ROUNDOFF? If so, its upper triangle is
    made the mirror image of its lower one, in place: its products then read one triangle
    (``condensation_times``), half its bytes (34 MB on the fine 30 deg scene, read at every check
    of a condensed solve and every residual with the bulk's answer pending)."""
    n = len(P)
    if n < 2:
        return False
    bound = CONDENSATION_SYMMETRY_ROUNDOFF * max(float(P.max()), -float(P.min()))
    if not np.isfinite(bound):
        return False
    for a in range(0, n, _MIRROR_ROWS):
        b = min(a + _MIRROR_ROWS, n)
        if np.max(np.abs(P[a:b, :b] - P[:b, a:b].T)) > bound:
            return False
    for a in range(0, n, _MIRROR_ROWS):   # row block a:b takes the columns a:b above it
        b = min(a + _MIRROR_ROWS, n)
        block = P[a:b, a:b]
        upper = np.triu_indices(b - a, 1)
        block[upper] = block.T[upper]
        P[:a, a:b] = P[a:b, :a].T
    return True


def condensation_times(P, symmetric, v):
    """P v; ``symmetric`` (``condensation_symmetrised``): from one triangle of P (BLAS symv),
    the same up to the order of the sums."""
    if not symmetric:
        return P @ v
    # (a C-ordered P is its own transpose, a Fortran-ordered array: symv takes it without a copy)
    return _symv(1.0, P if P.flags.f_contiguous else P.T, v, lower=1)


@kernel
def _scaled_update(x, at, scale, y):
    """x[at] += scale[at] * y, in one pass; returns scale[at] * y."""
    d = np.empty(y.shape[0])
    for k in range(y.shape[0]):
        i = at[k]
        d[k] = scale[i] * y[k]
        x[i] += d[k]
    return d


@kernel
def _negated_at(v, at, factor):
    """factor[k] * -v[at[k]] for every k of ``at``, in one pass."""
    out = np.empty(at.shape[0])
    for k in range(at.shape[0]):
        out[k] = factor[k] * -v[at[k]]
    return out


def unsigned_indices(index):
    """An index array (int32 or int64, non-negative) viewed as its unsigned type, no copy: a
    kernel indexing with a signed integer tests it for a negative (wrap-around) index at every
    read, which made a CSR product in numba twice as slow as scipy's."""
    return index.view(np.uint32 if index.dtype == np.int32 else np.uint64)


def _with_shared(shared, make):
    """``shared(store, make)`` inside ``shared_bulk.sharing()`` (members of an ensemble
    reusing equal bulks), ``make()`` otherwise."""
    store = shared_bulk.active()
    return make() if store is None else shared(store, make)


class Deferred(NamedTuple):
    """What ``CondensedSystem.solve`` hands on with a fault update dx_N whose bulk answer is
    deferred: at a step's first iteration the forward-swept linear rows' residual ``swept`` and
    its effect on the fault rows ``shift`` (else both None), and ``product``, P dx_N when the
    condensed solve's check made it (else None)."""
    swept: np.ndarray | None
    shift: np.ndarray | None
    product: np.ndarray | None


class PendingBulk:
    """The bulk's answer to a step's Newton updates, not yet in x[B] (``NewtonSolver._step``):
    B^-1 (r_B - L_BN sum(dx_N)), r_B the linear rows' residual at the step's first iteration
    (kept forward-swept), and its effect on the fault rows, L_NB B^-1 r_B (``shift``).

    P sum(dx_N), which every residual with the answer pending needs, is kept as the sum of the
    updates' products that the condensed solves' checks made (``product``), plus a product of
    the updates that came without one (``unproduced``): one pass over the dense P (20-34 MB on
    the large scenes) less per Newton iteration, equal up to the order of the sums."""

    def __init__(self, n_condensed):
        self.swept = None
        self.shift = np.zeros(n_condensed)
        self.fault = np.zeros(n_condensed)
        self.product = np.zeros(n_condensed)
        self.unproduced = None

    def add(self, alpha, dxN, deferred):
        """Add the update alpha dx_N and, at a step's first iteration, the forward sweep of the
        linear rows' residual with its effect on the fault rows (``deferred``: see ``Deferred``;
        None: neither, nor P dx_N), all linear in the step length."""
        self.fault += alpha * dxN
        product = None if deferred is None else deferred.product
        if product is not None:
            self.product += alpha * product
        elif self.unproduced is None:
            self.unproduced = alpha * dxN
        else:
            self.unproduced += alpha * dxN
        if deferred is not None and deferred.swept is not None:
            c = deferred.swept
            self.swept = alpha * c if self.swept is None else self.swept + alpha * c
            self.shift += alpha * deferred.shift

    def condensed(self, P, symmetric):
        """P times the sum of the updates (``condensation_times``)."""
        if self.unproduced is None:
            return self.product
        return self.product + condensation_times(P, symmetric, self.unproduced)

    def copy(self):
        out = PendingBulk(0)
        out.swept = self.swept
        out.shift = self.shift.copy()
        out.fault = self.fault.copy()
        out.product = self.product.copy()
        out.unproduced = None if self.unproduced is None else self.unproduced.copy()
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

#: refinement that stopped with its residual (D (x - x'), sparse: see ``CondensedSolver._iterate``)
#: above this many times the goal hands it to GMRES as it is: it differs from the true one by the
#: round-off of M1's factors and of the storage change (a direct solve's relative residual, 1e-13
#: to 1e-11: a tenth of the goal at most), so a product with P would only confirm that it misses
#: (the paper-units Rustrel scene: 1.16 such products a step of 2.36)
UNCHECKED_MARGIN = 2.0


#: the nice value of a thread making factors ahead (``_yield_to_the_steps``)
AHEAD_NICE = 19


def _yield_to_the_steps():
    """Lower the calling thread's scheduling priority (Linux: nice is per thread, inherited by
    the threads it starts): the factors made ahead take a core the steps leave idle, not the
    steps' own when another process holds the other core; a step that waits for them leaves its
    core to them. (Elsewhere PRIO_PROCESS would name the process: left as it is.)"""
    if sys.platform == "linux" and AHEAD_NICE > 0:
        try:
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), AHEAD_NICE)
        except OSError:
            pass


class _Ahead:
    """``make(dt)`` run in a thread of its own (``CondensedSystem.factorise_ahead``)."""

    def __init__(self, dt, make):
        self.dt = dt
        self._out = []
        self._failed = []

        def body():
            _yield_to_the_steps()
            try:
                with ldl.one_thread():   # (the steps hold the other core)
                    self._out.append(make(dt))
            except BaseException as error:   # (raised where the factors are taken)
                self._failed.append(error)

        self._thread = threading.Thread(target=body, name="fault_screen rung ahead", daemon=True)
        self._thread.start()

    def factors(self):
        """The factors, once made (waits); raises what making them raised."""
        self._thread.join()
        if self._failed:
            raise self._failed.pop()
        return self._out.pop()

    def wait(self):
        self._thread.join()

    def discard(self):
        """Wait for the thread to end and drop what it made or raised."""
        self._thread.join()
        self._out.clear()
        self._failed.clear()


#: the condensed solver keeps the factorised block before the last one (and what it solved with
#: it) while the block has at most this many rows: a Newton iteration whose block is close to
#: that one again takes its factors instead of a new LU (``CondensedSolver``; two n x n arrays
#: more at most, 17 MB at this size; the fine 30 deg scene's 2059 rows keep one)
RECALL_UP_TO = 1024


#: GMRES iterations allowed before the condensed block is factorised anew: an LU of n unknowns
#: costs about as much as 12 iterations (each a product with M and a solve with the old factors)
#: at n = 400, where fixed costs dominate, and about n/40 beyond
def _condensed_max_iterations(n):
    return min(30, max(12, n // 40))


#: columns of the inverse of the factorised block are solved for in pages of this many (a
#: slip front's changed rows are contiguous: few more are solved than needed)
COLUMN_PAGE = 16


def _zeros_filled_later(shape):
    """A Fortran-ordered array of zeros whose memory becomes resident only where it is written:
    the columns kept by ``CondensedSolver`` (``_base_columns``, ``_shift_columns``) are filled a
    page at a time as a slip front reaches them, a few hundred of thousands. np.zeros takes
    what malloc hands it, and below its mmap threshold (which rises to 32 MB once the set-up has
    freed arrays that large) that is heap memory freed earlier, which calloc clears and so
    makes resident whole: the 414 x 2059 columns of the fine 30 deg scene held 6.5 MB where
    their 336 filled columns are 1.1 MB. An anonymous mapping is zero pages until written."""
    import mmap

    size = int(np.prod(shape)) * np.dtype(float).itemsize
    if size == 0:
        return np.zeros(shape, order="F")
    return np.ndarray(shape, dtype=float, buffer=mmap.mmap(-1, size), order="F")


#: what the condensed solver keeps of one factorised block M0 (``CondensedSolver``: M0's and
#: the recalled block's): its factors, its tangent and step size, the columns solved with it
#: and the step size's correction of them
BASE_STATE = ("factors", "_M0_largest", "factored_inv_dt", "factored_step", "_base0", "tangent0",
              "_tangent0_sums", "_Z", "_have", "_T", "_have1", "_Z_R", "_K_R", "_delta",
              "_capacitance_R", "_front")


def _solved_columns_of(state):
    """For a fork: copies of the columns solved with a block (``_Z``, ``_T``) and of the marks
    of which are solved, from ``state`` (a solver's attributes, or its recalled block's)."""
    out = {}
    for name, have in (("_Z", "_have"), ("_T", "_have1")):
        solved = state.get(have)
        if solved is not None:
            out[have] = solved.copy()
        if state.get(name) is not None:
            out[name] = _solved_columns_copied(state[name], solved)
    return out


def _solved_columns_copied(kept, have):
    """A copy of the kept columns ``kept`` (Fortran order) for a fork: the columns ``have``
    marks solved, run by run, into zeros filled later (``_zeros_filled_later``); the others are
    zeros never written, which a whole copy would read and make resident (the fork of a run on
    the fine 30 deg scene: 32 MB for 8 MB of columns solved)."""
    twin = _zeros_filled_later(kept.shape)
    solved = np.flatnonzero(have)
    for run in np.split(solved, np.flatnonzero(np.diff(solved) != 1) + 1):
        if len(run):
            twin[:, run[0]:run[-1] + 1] = kept[:, run[0]:run[-1] + 1]
    return twin


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
        out[i] += _csr_row_times(indptr, indices, values, v, i)


@helper
def _csr_row_times(indptr, indices, data, v, i):
    """Row i of a CSR matrix times v, summed from 0.0 over the row's entries in order (as
    scipy's csr_matvec sums it: the same bits)."""
    acc = 0.0
    for k in range(indptr[i], indptr[i + 1]):
        acc += data[k] * v[indices[k]]
    return acc


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
        rows = self.keys // n
        self.indptr = unsigned_indices(np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n))]))
        self.rows, self.cols = unsigned_indices(rows), unsigned_indices(self.keys % n)

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


class CondensedSolver:
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
      by the Woodbury identity, at the cost of |K| solves with M0 (kept while M0 is) and, at
      another step size than M0's, of their rows K corrected for it (``_low_rank``);
    - when it is spread but small (rate-dependent friction, an evolving aperture), by iterative
      refinement with M1's factors and, if that contracts slowly, GMRES preconditioned with them
      (right preconditioning: the true residual of M is what converges), to CONDENSED_RTOL.
    Every result is checked against M itself. When none serves, M is factorised and becomes M0.
    - The block factorised before M0 is kept too (``_recalled``, up to RECALL_UP_TO rows), with
      what was solved with it. When M0 does not serve by a low-rank change and the recalled
      block does (the same condensation and step size), the two trade places instead of a new
      LU. Under constant friction a step's first Newton iteration finds every point of the fault
      stuck (the trial traction lies on the friction limit), its second finds the slipping
      patch again, and each step alternates between the same two blocks but for a moved front
      (the peer scene's graded run: 58 LUs of 576 rows for its 105 Newton iterations, now 6).
    (GMRES preconditioned across a step size change of 6 % took 9 iterations per solve on the
    30 deg T = 0.7 scene, more than an LU: hence the exact update on R.)"""

    def __init__(self, storage=None, position=None, scale=None):
        self.P = None
        self._P_symmetric = False
        self._product = (None, None)   # (v, P v) of the last product with M
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
        self.recalls = 0           # the recalled block's factors taken up, for diagnostics
        self._recalled = None      # the block factorised before M0: its BASE_STATE, or None
        self.storage = None
        if storage is not None:
            self.storage = sp.csr_matrix(storage, copy=True)
            self.storage.sum_duplicates()
            C = self.storage
            self._storage_rows = np.flatnonzero(np.diff(C.indptr))   # R
            self._C_R = C[self._storage_rows]

    def set(self, P, linear, tangent, dt, base=None, symmetric=False):
        """The block to solve with next, M = -P + L_NN + T at step size ``dt``: ``linear``, L_NN's
        entries (rows, columns, values in the block) and ``tangent``, T's triplets (rows, columns,
        values, on the unknowns that ``position`` places in the block, scaled by ``scale``;
        duplicates summed). ``base`` tells which condensation P is (a count, not the array;
        None: unknown, the block is factorised); blocks of the same base and pattern differ by
        the tangent and the step size alone. ``symmetric``: P is exactly symmetric (its products
        then read one triangle, ``condensation_times``)."""
        self.P = P
        self._P_symmetric = symmetric
        self._product = (None, None)
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
        if self.factors is None or not self._fits(self._base0, self.factored_inv_dt):
            if self._recall_fits():
                self._trade()
            else:
                self._factorise()

    def factorise_set(self):
        """Factorise the block set unless ``set`` did (a restored checkpoint's blocks)."""
        if not self.factored:
            self._factorise()

    def factorised_blocks(self) -> dict:
        """(tangent, step size, condensation count) of each block whose factors are kept, by
        its checkpoint name: "condensed_recalled" (if any) first, then "condensed" (M0)."""
        kept = {} if self._recalled is None else {"condensed_recalled": self._recalled}
        kept["condensed"] = self._base_state()
        return {key: (b["tangent0"], b["factored_step"], b["_base0"]) for key, b in kept.items()}

    def _base_state(self) -> dict:
        """M0's BASE_STATE, as the recalled block keeps it."""
        return {name: getattr(self, name) for name in BASE_STATE}

    def _recall_fits(self) -> bool:
        """Is there a recalled block, of the condensation and step size of the block set?"""
        kept = self._recalled
        return kept is not None and self._fits(kept["_base0"], kept["factored_inv_dt"])

    def _fits(self, base0, inv_dt0):
        """Do factors made of condensation ``base0`` at 1/dt = ``inv_dt0`` serve the block set
        (the same condensation, and the same step size unless the storage change is taken
        from them)?"""
        return (self._base is not None and base0 == self._base
                and (inv_dt0 == self.inv_dt or self.storage is not None))

    def _trade(self):
        """M0 and the recalled block trade places, each with what was solved with it."""
        kept, self._recalled = self._recalled, self._base_state()
        for name in BASE_STATE:
            setattr(self, name, kept[name])

    def fork(self) -> "CondensedSolver":
        """The same solver for a fork: the factors shared read-only, the columns of the inverse
        solved for so far (filled in place, page by page) copied, and the block's pattern its
        own (it remembers the arrays it last matched)."""
        twin = copy.copy(self)
        twin._pattern = copy.copy(self._pattern)
        for name, value in _solved_columns_of(vars(self)).items():
            setattr(twin, name, value)
        twin._front = None   # (views of this solver's columns)
        if self._recalled is not None:
            twin._recalled = {**self._recalled, **_solved_columns_of(self._recalled), "_front": None}
        return twin

    def _times(self, v):
        """M v = -P v + (L_NN + T) v; P v is kept with v (``condensation_product``)."""
        Pv = condensation_times(self.P, self._P_symmetric, v)
        self._product = (v, Pv)
        out = -Pv
        p = self._pattern
        _sparse_times(p.indptr, p.cols, self._sparse, v, out)
        return out

    def condensation_product(self, x):
        """P x when the last product with M (a solve's check) was of this very array x (not
        written to since: a solve's result is not), else None."""
        v, Pv = self._product
        return Pv if v is x else None

    def _form(self):
        """M as a dense array (the one n x n array of its own this solver makes), in Fortran
        order: LAPACK factorises it in place (a C-ordered one would be copied first)."""
        M = np.negative(self.P, order="F")
        p = self._pattern
        M[p.rows, p.cols] += self._sparse  # (each position once)
        return M

    def _factorise(self):
        # M0 is recalled from now on where it serves the block set and is small; the block
        # recalled so far goes. Else the old factors and what was solved with them go before
        # the new block is formed (the run's peak memory on the fine 30 deg scene: three n x n
        # arrays at once, not four)
        self._recalled = None
        if (self.factors is not None and len(self.P) <= RECALL_UP_TO
                and self._fits(self._base0, self.factored_inv_dt)):
            self._recalled = self._base_state()
        self.factors = None
        self._Z = self._T = self._Z_R = self._K_R = None
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
        """The base M1 = M0 + delta E_R C_R: its capacitance's LU and the columns kept for it
        (``_shift_columns``)."""
        self._delta = delta
        self._capacitance_R = None
        self._T = None
        self._have1 = np.zeros(len(self.P), dtype=bool)
        self._front = None   # (``_front_columns``: of the base M1)

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
                else:
                    x = self._recalled_low_rank(b)
                    if x is None and largest <= SMALL_CHANGE * self._M0_largest:
                        x = self._iterate(b, D)
            if x is not None:
                return x
            self._factorise()
        return self._precondition(b)

    def _recalled_low_rank(self, b):
        """M^-1 b by a low-rank change of the recalled block, which then becomes M0 (and M0 the
        recalled one); None, the two as they were, when it is not close enough or misses the
        check."""
        if not self._recall_fits():
            return None
        self._trade()
        # its distance first: the step size's columns (an n x |R| solve) only for a block that serves
        _, K, DK, _ = self._tangent_change()
        if len(K) * LOW_RANK_FRACTION <= len(b) and self._step_size_update():
            x = self._low_rank(b, DK, K)
            if x is not None:
                self.recalls += 1
                return x
        self._trade()
        return None

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
        """M0^-1 E_K: the columns of M0^-1 from K's first to its last (a view, not a copy: a
        slip front's K is nearly contiguous; the columns between that are not in K are zero
        or solved, and are multiplied by zero), kept while M0 is (K grows as a front
        advances), made a page of COLUMN_PAGE columns at a time, each page alone: a column's
        round-off then does not depend on which others were asked for with it, so a restored
        run, which starts with none kept, repeats them bit for bit."""
        n = len(self.P)
        if self._Z is None:
            # (zeros: columns never solved stay finite in the span; their pages are not touched)
            self._Z = _zeros_filled_later((n, n))
        for page in self._pages(K, self._have):
            E = np.zeros((n, len(page)))
            E[page, np.arange(len(page))] = 1.0
            self._Z[:, page] = lu_solve(self.factors, E)
            self._have[page] = True
        return self._Z[:, K[0]:K[-1] + 1]

    def _shift_columns(self, K):
        """(I + delta K_R)^-1 C_R M0^-1 E_K, |R| rows, over K's span like ``_base_columns``
        (after them): what the step size's correction takes off M0^-1 E_K through Z_R
        (``_step_size_correction``), kept while the step size is, made for the pages it lacks
        with one sparse product and one solve (each column's result is that of its page alone:
        the sparse product sums each entry in the same order, getrs solves each column alike;
        a page a call cost 1.5 calls of the 414-row LU per call on the fine 30 deg scene)."""
        if self._T is None:
            self._T = _zeros_filled_later((len(self._storage_rows), len(self.P)))
        missing = list(self._pages(K, self._have1))
        if missing:
            columns = np.concatenate(missing)
            self._T[:, columns] = lu_solve(self._capacitance_R, self._C_R @ self._Z[:, columns])
            self._have1[columns] = True
        return self._T[:, K[0]:K[-1] + 1]

    def _front_columns(self, K, Z0, at):
        """Z_R's rows K, the shift columns over K's span and Z_K = M1^-1's block at K (rows and
        columns), kept while K and M1 are: a Newton iteration whose slip front did not move
        (one Woodbury solve in five on the fine 30 deg scene) reuses them, the same arrays as
        made anew; the capacitance, of D_K, is made at every call."""
        kept = self._front
        if kept is not None and np.array_equal(kept[0], K):
            return kept[1:]
        delta = self._delta
        Z_K = Z0[K][:, at]
        Z_R_K = T_K = None
        if delta != 0.0:
            Z_R_K = self._Z_R[K]
            T_K = self._shift_columns(K)
            Z_K = Z_K - delta * (Z_R_K @ T_K[:, at])
        self._front = (K, Z_R_K, T_K, Z_K)
        return Z_R_K, T_K, Z_K

    @staticmethod
    def _pages(K, have):
        """The pages (column ranges of COLUMN_PAGE) holding a column of K not in ``have``."""
        n = len(have)
        for first in np.unique(K[~have[K]] // COLUMN_PAGE) * COLUMN_PAGE:
            yield np.arange(first, min(first + COLUMN_PAGE, n))

    def _low_rank(self, b, DK, K):
        """Woodbury: with M = M1 + E D E^T (E: the columns of the identity at the changed rows
        and columns K), M^-1 b = y - Z (I + D Z_K)^-1 D y_K, y = M1^-1 b, Z = M1^-1 E. None when
        the result misses the check.

        M1^-1 is M0^-1 followed by the step size's correction, which is linear: so
        y - Z s = correction(w - Z0 s) with w = M0^-1 b and Z0 = M0^-1 E, one correction of a
        vector per solve, and Z itself is needed only in its rows K (for the capacitance): Z0_K
        less delta Z_R[K] times the kept ``_shift_columns`` (|R| rows a column, where the n rows
        of Z's columns cost a product with the n x |R| Z_R each, at every new step size)."""
        delta = self._delta
        if len(K) == 0 and delta == 0.0:
            return self._precondition(b)  # M is M0
        if len(K):
            Z0 = self._base_columns(K)   # (K's span: a product with it takes s at K, zeros between)
            at = K - K[0]
            Z_R_K, T_K, Z_K = self._front_columns(K, Z0, at)
            capacitance = np.eye(len(K)) + DK @ Z_K
            try:
                cap = scipy.linalg.lu_factor(capacitance, check_finite=False)
            except (np.linalg.LinAlgError, ValueError):
                return None
            spread = np.zeros(Z0.shape[1])

            def apply(r):
                w = lu_solve(self.factors, r)
                if delta == 0.0:
                    spread[at] = lu_solve(cap, DK @ w[K])
                    return w - Z0 @ spread
                # the step size's correction of w - Z0 s from that of w (u, also y = M1^-1 r at
                # K) and the kept shift columns: one solve with its capacitance, not two
                u = lu_solve(self._capacitance_R, self._C_R @ w)
                spread[at] = lu_solve(cap, DK @ (w[K] - delta * (Z_R_K @ u)))
                return (w - Z0 @ spread) - delta * (self._Z_R @ (u - T_K @ spread))
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
        with the dense M, which checks the last one. When that residual is still above
        UNCHECKED_MARGIN times the goal, GMRES starts from it without the check."""
        goal = CONDENSED_RTOL * np.linalg.norm(b)
        p = self._pattern
        y = self._precondition(b)
        x = y
        D_x = np.zeros_like(b)
        _sparse_times(p.indptr, p.cols, D, x, D_x)
        last = np.linalg.norm(D_x)   # (b - M y = -D y)
        estimate = None              # b - M x of the last step (-D y before any)
        for _ in range(REFINEMENTS):
            if last <= goal:
                break
            self.iterations += 1
            x_next = y - self._precondition(D_x)
            D_next = np.zeros_like(b)
            _sparse_times(p.indptr, p.cols, D, x_next, D_next)
            estimate = D_x - D_next
            norm = np.linalg.norm(estimate)
            x, D_x = x_next, D_next
            if norm > REFINEMENT_GAIN * last:
                last = norm
                break
            last = norm
        if last > UNCHECKED_MARGIN * goal:
            return self._gmres(b, x, -D_x if estimate is None else estimate, goal, D)
        r = b - self._times(x)
        if np.linalg.norm(r) <= goal:
            return x
        return self._gmres(b, x, r, goal, D)

    def _gmres(self, b, x, r, goal, D=None):
        """From x (residual r = b - M x): x with |M x - b| <= goal in at most
        ``_condensed_max_iterations`` GMRES iterations, right-preconditioned by the old factors;
        None if not reached. The recurrence's residual estimate drifts from the true one in
        floating point: the true one decides, and the iteration restarts from it while the
        budget lasts. ``D``: M - M1 at the pattern's slots (``_iterate``): the first cycle then
        takes M z_j as v_j + D z_j (M1 z_j = v_j), a sparse product where M's own is a pass
        over the dense P; they differ by the round-off of M1's factors and of the storage
        change, which the true residual after the cycle measures (a restart, if it misses,
        takes M's own products)."""
        budget = _condensed_max_iterations(len(b))
        while True:
            beta = np.linalg.norm(r)
            if beta <= goal:
                return x
            if budget <= 0:
                return None
            y, Z = self._arnoldi(r, beta, 0.5 * goal, budget, D)
            D = None
            budget -= len(y)
            x = x + y @ Z
            r = b - self._times(x)

    def _arnoldi(self, r, beta, goal, m, D=None):
        """GMRES cycle on M z = r (z = P^-1 v): the least-squares coefficients y and the
        preconditioned basis Z (rows z_j = P^-1 v_j; the update is y Z, which saves the solve
        of P^-1 (y V)) once the residual estimate is below ``goal`` or after m iterations. The
        Hessenberg matrix is reduced by Givens rotations as it grows, so the estimate is the
        last entry of the rotated right-hand side (``_arnoldi_column``: one kernel call an
        iteration for what took a dozen numpy calls, 70 us an iteration on a 392-unknown block).
        ``D``: M z_j taken as v_j + D z_j (see ``_gmres``)."""
        p = self._pattern
        V = np.empty((m + 1, len(r)))
        Z = np.empty((m, len(r)))
        H = np.zeros((m + 1, m))
        cs, sn = np.zeros(m), np.zeros(m)
        g = np.zeros(m + 1)
        g[0] = beta
        V[0] = r / beta
        for j in range(m):
            Z[j] = self._precondition(V[j])
            if D is None:
                w = self._times(Z[j])
            else:
                w = V[j].copy()
                _sparse_times(p.indptr, p.cols, D, Z[j], w)
            norm = _arnoldi_column(V, H, cs, sn, g, j, w)
            self.iterations += 1
            if abs(g[j + 1]) <= goal or norm == 0.0 or j == m - 1:
                y = scipy.linalg.solve_triangular(H[:j + 1, :j + 1], g[:j + 1], check_finite=False)
                return y, Z[:j + 1]
            V[j + 1] = w / norm


@kernel
def _arnoldi_column(V, H, cs, sn, g, j, w):
    """Iteration j of an Arnoldi process with Givens rotations, given w = M z_j: w is
    orthogonalised in place against the basis rows V[:j + 1] by classical Gram-Schmidt twice (as
    stable as modified), its coefficients with the earlier rotations and a new one that zeroes
    the subdiagonal go into column j of H (upper triangular), the rotated right-hand side g gets
    entry j + 1 (the residual estimate); returns |w| (the subdiagonal entry before rotation)."""
    n = w.shape[0]
    col = np.zeros(j + 2)
    h = np.empty(j + 1)
    for twice in range(2):
        for i in range(j + 1):
            dot = 0.0
            for k in range(n):
                dot += V[i, k] * w[k]
            h[i] = dot
        for i in range(j + 1):
            col[i] += h[i]
            for k in range(n):
                w[k] -= h[i] * V[i, k]
    total = 0.0
    for k in range(n):
        total += w[k] * w[k]
    norm = np.sqrt(total)
    col[j + 1] = norm
    for i in range(j):   # the earlier rotations, then a new one zeroing the subdiagonal
        a, b = col[i], col[i + 1]
        col[i] = cs[i] * a + sn[i] * b
        col[i + 1] = -sn[i] * a + cs[i] * b
    rho = np.hypot(col[j], col[j + 1])
    if rho > 0.0:
        cs[j], sn[j] = col[j] / rho, col[j + 1] / rho
    else:
        cs[j], sn[j] = 1.0, 0.0
    for i in range(j):
        H[i, j] = col[i]
    H[j, j] = rho
    g[j + 1] = -sn[j] * g[j]
    g[j] *= cs[j]
    return norm

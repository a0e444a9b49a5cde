"""Bulk factorisations shared by the simulations of one process that factorise the same matrix.

The members of an ensemble are separate scenes, but the parameters an ensemble varies often
leave the bulk (the linear block the solver factorises per step size) as it is: the friction
and the number of fractures enter the fault's nonlinear terms and the source only. Inside
``with sharing():`` every :class:`~fault_screen.linear_system.CondensedSystem` of the process
takes its fill-reducing order, its symbolic analyses, the positions of its poroelastic bulk's
fixed pattern and its factors from here when a simulation before it made them for exactly the
same input (compared exactly, array by array: pattern and coordinates for the order, the
blocks' patterns and the order for the positions, pattern and values for the factors; a cheap
fingerprint of each, its shape and sum, picks the candidates to compare), and makes them
otherwise. Equal input gives equal factors, so a shared run is bit-identical to one made
alone. The factors are read-only for their users (a step replaces them, never writes into
them, as forks already rely on); the Schur complement, which its owner takes and overwrites,
is handed out as a copy. Outside ``sharing()`` nothing is kept.

One store may serve several threads (a live ensemble's members stepped by the look-ahead
worker of one refresh while the next refresh forks them): a lock makes each look-up and the
making of what it misses one step, so two threads asking for the same order or factors get the
one object, made once. The symbolic analyses handed out are the store's, behind the same lock.
"""
from __future__ import annotations

import contextlib
import copy
import threading

import numpy as np

from .ldl import SymbolicAnalyses

__all__ = ["sharing", "SharedBulk", "active", "MAX_FACTORS"]

_LOCAL = threading.local()

#: factorisations a store keeps at most (the oldest goes first): members whose bulks all differ
#: (a varied aperture enters the fault's storage) then hold no more than these
MAX_FACTORS = 8


def _bits(a):
    """The bytes of a contiguous array as unsigned integers of its item size (compared, a
    -0.0 differs from a 0.0 and a NaN equals the same NaN: equal bits, equal factors)."""
    return a.view(f"u{a.itemsize}") if a.itemsize in (1, 2, 4, 8) else a.view(np.uint8)


class _Kept:
    """Values kept by the arrays that define them, bit for bit. A look-up compares the arrays
    with the kept ones instead of hashing their bytes (a cryptographic hash took a few per cent
    of an ensemble member's CPU time; a sum is far cheaper): the fingerprint, each array's
    dtype, shape and the sum of its bits, finds the candidates (equal arrays have equal sums),
    a comparison of the bits decides. The arrays are kept as copies, the oldest entry first."""

    def __init__(self):
        self._entries = []     # (fingerprint, arrays, value), in the order kept

    @staticmethod
    def key(arrays) -> tuple:
        """(fingerprint, contiguous arrays) of ``arrays``."""
        arrays = [np.ascontiguousarray(a) for a in arrays]
        return tuple((a.dtype.str, a.shape, int(_bits(a).sum())) for a in arrays), arrays

    def find(self, key):
        fingerprint, arrays = key
        for kept_print, kept, value in self._entries:
            if kept_print == fingerprint and all(np.array_equal(_bits(a), _bits(b))
                                                 for a, b in zip(arrays, kept)):
                return value
        return None

    def add(self, key, value) -> None:
        fingerprint, arrays = key
        self._entries.append((fingerprint, [a.copy() for a in arrays], value))

    def drop_oldest(self) -> None:
        del self._entries[0]

    def clear(self) -> None:
        self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)


class _LockedAnalyses(SymbolicAnalyses):
    """The store's symbolic analyses: a look-up that makes one holds the store's lock (a
    system keeps this object and may factorise later outside ``sharing()``)."""

    def __init__(self, lock):
        super().__init__()
        self._lock = lock

    def of(self, lower, n_linear):
        with self._lock:
            return super().of(lower, n_linear)


class SharedBulk:
    """What the simulations inside one ``sharing()`` block share (see the module docstring).
    ``made`` / ``shared``: factorisations made here / handed out again; ``patterns_made`` /
    ``patterns_shared``: the same for the bulk's fixed pattern (its positions: an equal pattern
    with other values, ``fixed_pattern.FixedBulk.with_values``). Safe to share between threads."""

    def __init__(self, max_factors: int = MAX_FACTORS):
        # (re-entrant: making factors looks up the symbolic analyses under the same lock)
        self._lock = threading.RLock()
        self.analyses = _LockedAnalyses(self._lock)   # (keyed by pattern itself)
        self._orders = _Kept()
        self._patterns = _Kept()             # fixed patterns of the bulk, by their key
        self.patterns_made = self.patterns_shared = 0
        self._factors = _Kept()              # in the order made: the oldest goes first
        self.max_factors = int(max_factors)
        self.made = 0
        self.shared = 0

    def order(self, pattern, coordinates, make, fault_coupling=None):
        """``make()`` (the bulk's order and split), or what it gave for the same ``pattern``
        (sparse), ``coordinates`` and ``fault_coupling`` (the fault unknowns each bulk unknown
        couples to, which the order reads: two faults in one mesh share B's pattern)."""
        pattern = pattern.tocsr()
        coupling = () if fault_coupling is None else (np.asarray(fault_coupling),)
        key = _Kept.key((pattern.indptr, pattern.indices, np.asarray(pattern.shape), coordinates,
                         *coupling))
        with self._lock:
            made = self._orders.find(key)
            if made is None:
                made = make()
                self._orders.add(key, made)
            return made

    def pattern(self, key_arrays, make):
        """``make()`` (a bulk's fixed pattern), or what it gave for equal ``key_arrays``."""
        key = _Kept.key(key_arrays)
        with self._lock:
            made = self._patterns.find(key)
            if made is None:
                made = make()
                self._patterns.add(key, made)
                self.patterns_made += 1
            else:
                self.patterns_shared += 1
            return made

    def factors(self, matrix_arrays, n_linear: int, split, factorise):
        """``factorise()``, or the factors it gave for the same matrix (``matrix_arrays``: the
        arrays that define it exactly, pattern and values) with the same ``n_linear`` and
        ``split``: a copy of the kept object sharing its factors, its Schur complement a copy of
        its own (the kept one is never handed out, so its Schur complement stays as made)."""
        key = _Kept.key((*matrix_arrays, np.asarray([n_linear]),
                         np.asarray(split if split is not None else [], dtype=np.int64)))
        with self._lock:
            lu = self._factors.find(key)
            if lu is None:
                lu = factorise()
                while len(self._factors) and len(self._factors) >= self.max_factors:
                    self._factors.drop_oldest()
                self._factors.add(key, lu)
                self.made += 1
            else:
                self.shared += 1
        twin = copy.copy(lu)
        twin.schur = lu.schur.copy(order="K")   # (its memory layout kept: the products that read it round alike)
        return twin

    def drop_factors(self) -> int:
        """Forget every factorisation kept (the order, the symbolic analyses and the fixed
        patterns stay): for stores whose users have all made their factorisations of the
        current step sizes, as a live ensemble's members have after each round of steps. A
        system holding factors keeps its own; returns how many sets were dropped."""
        with self._lock:
            dropped = len(self._factors)
            self._factors.clear()
        return dropped


def active() -> SharedBulk | None:
    """The store of the innermost ``sharing()`` block of this thread, or None."""
    return getattr(_LOCAL, "store", None)


@contextlib.contextmanager
def sharing(store: SharedBulk | None = None):
    """Share bulk orders and factors among the simulations built and stepped inside (in this
    thread); yields the :class:`SharedBulk` (a new one unless given)."""
    store = SharedBulk() if store is None else store
    before = active()
    _LOCAL.store = store
    try:
        yield store
    finally:
        _LOCAL.store = before

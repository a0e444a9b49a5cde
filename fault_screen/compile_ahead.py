"""A cold start's compilation done by child processes, one per core.

With an empty numba cache, the first run spends most of its time compiling the model's kernels
(:data:`KERNELS`), one after the other: numba compiles under one lock, on one core. Before such a
run builds its model, :func:`compile_ahead` deals the missing kernels to as many child processes
as there are cores (at most :data:`MOST_PROCESSES`), each compiling its share into numba's cache
at the same time, waits for them, and the run then loads every kernel from the cache at its
first call. The compilers' memory is the children's, so the run's own peak memory is that of a
warm start. That is what it buys for certain; the wall time of the cold start drops only where
the cores are otherwise idle, since the children's compilation takes more CPU time in all than
one process's (each child starts Python and numba again, and cores that share caches compile
more slowly side by side).

Nothing depends on it: a kernel whose argument types differ from the list's (a changed kernel
before the list was regenerated), a child that fails or cannot start, or a cache a child cannot
write leave those kernels to be compiled at their first call, in this process, as without this
module. The list is regenerated with ``python benchmarks/cold_compile.py --kernels`` and checked
against a run by tests/package/test_compile_ahead.py.
"""
from __future__ import annotations

import importlib
import json
import os
import subprocess
import sys
from pathlib import Path

#: (module, kernel, compile CPU seconds measured by benchmarks/cold_compile.py: the weights that
#: split the work, argument types in numba's signature syntax) of the bundled `fault-screen run`
KERNELS = (
    ('fault_screen.kernels.rock', 'elastic_stiffness_all', 0.61,
     '(float64[:, :, :, ::1], float64[:, ::1], float64[:, :, ::1])'),
    ('fault_screen.assembly', 'scatter_matrices', 0.32,
     '(float64[:, :, ::1], int64[:, ::1], int64[:, ::1])'),
    ('fault_screen.kernels.rock', 'biot_coupling_all', 0.25,
     '(float64[:, :, :, ::1], float64[:, :, ::1], float64[:, ::1], float64[::1])'),
    ('fault_screen.kernels.rock', 'pore_storage_all', 0.22,
     '(float64[:, :, ::1], float64[:, ::1], float64[::1])'),
    ('fault_screen.kernels.rock', 'darcy_conductance_all', 0.34,
     '(float64[:, :, :, ::1], float64[:, ::1], float64[::1])'),
    ('fault_screen.kernels.contact', 'fault_jumps', 0.13,
     '(float64[::1], float64[:, ::1], int64[:, ::1], float64[::1], float64[::1])'),
    ('fault_screen.kernels.fault_flow', 'assemble_evolving_conduction', 0.48,
     '(float64[::1], float64[::1], float64[:, ::1], int64[:, ::1], float64[:, ::1], '
     'float64[:, ::1], int64[:, ::1], float64[::1], float64[::1], float64, float64, '
     'float64, float64, float64, float64[::1])'),
    ('fault_screen.kernels.contact', 'rate_state_law', 0.86,
     '(float64[::1], float64[::1], float64[::1], float64[:, ::1], float64[::1], float64)'),
    ('fault_screen.kernels.contact', 'assemble_contact', 0.46,
     '(float64[:, ::1], int64[:, ::1], float64[::1], float64[::1], float64[::1], '
     'float64[:, ::1], float64[::1], float64[::1], float64[:, ::1], float64[::1])'),
    ('fault_screen.ldl', '_etree', 0.27,
     '(int32[::1], int64[::1], int64)'),
    ('fault_screen.ldl', '_structure', 0.39,
     '(int32[::1], int64[::1], int64, int64, int64[::1])'),
    ('fault_screen.ldl', '_supernode_tree', 1.06,
     '(int64[::1], int64[::1], int64[::1], int64)'),
    ('fault_screen.ldl', '_eliminate', 4.19,
     '(int64[::1], int32[::1], int32[::1], float64[::1], int64[::1], int64[::1], '
     'int64[::1], int64[::1], int64[::1], int64[::1], int64[::1], int64[::1], int64[::1], '
     'int64[::1], float64[::1], float64[::1], float64[:, ::1], float64[::1], int64, '
     'int64[::1], int64, int64, float64[::1], float64[::1], int64[::1], float64[::1], '
     'float64[::1], float64[::1], float64[::1], int64[::1])'),
    ('fault_screen.solver', '_scaled_field_norms', 0.27,
     '(float64[::1], float64[::1], uint64[::1], uint64[::1])'),
    ('fault_screen.solver', '_reference_norms', 0.31,
     '(float64[::1], float64[::1], float64[::1], float64, float64[::1], uint64[::1], '
     'uint64[::1])'),
    ('fault_screen.linear_system', '_block_values', 0.12,
     '(int64, int64[::1], float64[::1], int64[::1], float64[::1], float64[::1])'),
    ('fault_screen.solver', '_where_changed', 0.10,
     '(float64[::1], float64[::1], int64[::1])'),
    ('fault_screen.solver', '_updated_through_columns', 0.13,
     '(float64[::1], int64[::1], int64[::1], float64[::1], int64[::1], float64[::1])'),
    ('fault_screen.linear_system', '_tangent_change', 0.56,
     '(int64, uint64[::1], uint64[::1], int64[::1], float64[::1], float64[::1], '
     'float64[::1])'),
    ('fault_screen.linear_system', '_sparse_times', 0.08,
     '(uint64[::1], uint64[::1], float64[::1], float64[::1], float64[::1])'),
    ('fault_screen.bordered_lu', '_backward_sweep', 0.48,
     '(int64[::1], int64[::1], int64[::1], int64[::1], int32[::1], float64[::1], '
     'float64[::1], bool, float64[::1])'),
    ('fault_screen.linear_system', '_scaled_update', 0.08,
     '(float64[::1], uint64[::1], float64[::1], float64[::1])'),
    ('fault_screen.solver', '_whole_products', 0.36,
     '(uint32[::1], uint32[::1], float64[::1], uint32[::1], uint32[::1], float64[::1], '
     'uint32[::1], uint32[::1], float64[::1], float64[::1], float64[::1])'),
    ('fault_screen.solver', '_weighted_sum_of', 0.11,
     '(int64, float64, float64[::1], float64, float64[::1], float64, float64[::1])'),
    ('fault_screen.linear_system', '_negated_at', 0.07,
     '(float64[::1], uint64[::1], float64[::1])'),
    ('fault_screen.bordered_lu', '_forward_sweep', 0.27,
     '(int64[::1], int64[::1], int64[::1], int64[::1], int32[::1], float64[::1], '
     'float64[::1])'),
    ('fault_screen.linear_system', '_arnoldi_column', 0.28,
     '(float64[:, ::1], float64[:, ::1], float64[::1], float64[::1], float64[::1], int64, '
     'float64[::1])'),
)

#: CPU seconds of a child's start (Python, numba, the model's modules) before it compiles
#: anything: below twice this much compilation, the kernels are left to their first call
CHILD_START = 2.0
#: most child processes compiling at once (each holds a Python with numba, ~200 MB)
MOST_PROCESSES = 3


def _dispatcher(module: str, name: str):
    from numba.core.dispatcher import Dispatcher

    d = getattr(importlib.import_module(module), name, None)
    return d if isinstance(d, Dispatcher) else None


def _arguments(text: str) -> tuple:
    from numba.core.sigutils import normalize_signature

    args, _ = normalize_signature(text)
    return tuple(args)


class _Machine:
    """What numba's cache key asks of the code generator (the host CPU, via LLVM: a third of
    the check's time when asked for each kernel), asked once."""

    def __init__(self, codegen):
        self._magic = codegen.magic_tuple()

    def magic_tuple(self):
        return self._magic


def _cached(d, args: tuple, machine=None) -> bool:
    """Whether numba's cache holds ``d`` compiled for ``args`` (True when that cannot be told:
    then nothing is done ahead)."""
    try:
        cache = d._cache
        if type(cache).__name__ == "NullCache":      # compiled without cache=True
            return True
        key = cache._index_key(args, machine or d.targetctx.codegen())
        return key in cache._cache_file._load_index()
    except Exception:   # noqa: BLE001 - numba's internals differ: behave as without this module
        return True


def _missing(kernels) -> list:
    """The ``kernels`` numba's cache does not hold. A warm start asks only about the longest
    to compile, half of the whole time (4 of the 24 listed), and finds them there: then none
    are (a kernel changed since is compiled at its first call, as without this module)."""
    machine = None
    by_time = sorted(kernels, key=lambda k: -k[2])
    head, total = [], 0.0
    for k in by_time:
        if total >= 0.5 * sum(k[2] for k in kernels):
            break
        head.append(k)
        total += k[2]
    missing = []
    for group in (head, by_time[len(head):]):
        for k in group:
            d = _dispatcher(k[0], k[1])
            if d is None:
                continue
            if machine is None:
                machine = _Machine(d.targetctx.codegen())
            if not _cached(d, _arguments(k[3]), machine):
                missing.append(k)
        if not missing:         # the longest ones are cached: a warm start
            return []
    return missing


def compile_kernels(kernels) -> int:
    """Compile (or load from numba's cache) each (module, kernel, weight, argument types) of
    ``kernels`` in this process; returns how many were compiled for their types. A kernel
    that does not compile for the listed types is left to its first call."""
    done = 0
    for module, name, _, text in kernels:
        try:
            d = _dispatcher(module, name)
            if d is not None:
                d.compile(_arguments(text))
                done += 1
        except Exception:   # noqa: BLE001 - a stale entry: compiled at its first call instead
            continue
    return done


def _shares(kernels, n: int) -> list[list]:
    """The kernels dealt into ``n`` shares of about equal compile time: by decreasing time,
    each to the share with the least so far."""
    shares, load = [[] for _ in range(n)], [0.0] * n
    for k in sorted(kernels, key=lambda k: -k[2]):
        i = load.index(min(load))
        shares[i].append(k)
        load[i] += k[2]
    return [s for s in shares if s]


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def compile_ahead(kernels=KERNELS) -> bool:
    """At a cold start (a listed kernel missing from numba's cache) on a machine with more than
    one core: compile the missing ``kernels`` in child processes, one per core, and wait for
    them. Returns whether it did (False: warm cache, one core, too little to compile, numba's
    cache not in use, or FAULT_SCREEN_COMPILE_AHEAD=0 in the environment: each kernel then
    compiled at its first call, in this process, as benchmarks/cold_compile.py measures them)."""
    if os.environ.get("FAULT_SCREEN_COMPILE_AHEAD", "1") == "0":
        return False
    cores = _cores()
    if cores < 2:
        return False
    try:
        missing = _missing(kernels)
    except Exception:   # noqa: BLE001 - numba's internals differ: behave as without this module
        return False
    if sum(k[2] for k in missing) < 2 * CHILD_START:
        return False
    env = dict(os.environ)
    # the children import this very package (numba's cache is keyed by these source files)
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    children, left = [], []
    try:
        for share in _shares(missing, min(cores, MOST_PROCESSES)):
            try:
                child = subprocess.Popen([sys.executable, "-m", "fault_screen.compile_ahead"],
                                         stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
                                         stderr=subprocess.DEVNULL, env=env, cwd=root)
            except OSError:
                left += share
                continue
            children.append(child)
            child.stdin.write(json.dumps(share).encode())
            child.stdin.close()
        for child in children:
            child.wait()
    except BaseException:          # interrupted: the children's work is of no use any more
        for child in children:
            child.kill()
            child.wait()
        raise
    compile_kernels(left)           # the shares of children that could not start
    return True


if __name__ == "__main__":
    compile_kernels(json.loads(sys.stdin.read()))

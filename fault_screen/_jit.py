"""The one place that owns numba's compilation options.

``cache=True`` keeps the second start fast; ``fastmath`` is deliberately never enabled: the
contact and friction kernels compare traction against strength (stick/slip/open) and guard
against NaN, and fast-math would let LLVM reorder or drop exactly those comparisons.
"""
from numba import njit

JIT_OPTIONS = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy",
               "no_cfunc_wrapper": True}


def kernel(fn):
    """Compile ``fn`` with the project's numba options."""
    return njit(**JIT_OPTIONS)(fn)


def helper(fn):
    """A kernel that other kernels call: inlined into them at numba IR level."""
    return njit(inline="always", **JIT_OPTIONS)(fn)

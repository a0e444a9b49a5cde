"""The one place that owns numba's compilation options.

``cache=True`` keeps the second start fast; ``fastmath`` is deliberately not enabled in general:
the contact and friction kernels compare traction against strength (stick/slip/open) and guard
against NaN, and fast-math would let LLVM reorder or drop exactly those comparisons. The one
exception is ``sweep_kernel`` (a triangular sweep through the factors): only reassociation and
fused multiply-add there, never the flags that assume no NaN or infinity.

Compilation is most of a cold start (an empty cache), so: no cfunc wrapper (nothing takes a kernel
as a first-class function), and a kernel that other kernels call is a ``helper``, inlined into
its callers at numba IR level instead of compiled, wrapped and cached on its own (it still
compiles on its own when Python calls it). Inside
kernels, array slice assignment (``out[e] = local``) and array expressions cost far more to
compile than the loops they stand for (the first alone, 3.5 s: numba formats its shape-mismatch
message); write them as loops when the arithmetic is the same.
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


#: reassociation and fused multiply-add only: NaN and infinity keep their IEEE meaning
SWEEP_OPTIONS = {**JIT_OPTIONS, "fastmath": {"reassoc", "contract"}}


def sweep_kernel(fn):
    """A kernel of linear algebra (a triangular sweep: sums of products) compiled with
    ``fastmath={'reassoc', 'contract'}``, so that LLVM may split a dot product's sum over
    vector lanes and fuse its multiply-adds. Safe there: reordering a sum of products changes
    its round-off only, as a BLAS's blocking does (results agree to ~1e-15 relative), and no
    decision hangs on it. NaN and infinity still propagate (no 'nnan'/'ninf': comparisons and
    the solver's finiteness tests downstream see them)."""
    return njit(**SWEEP_OPTIONS)(fn)

"""Whether a measured process was warm: the kernels numba compiled in it (issue 28).

A process that compiles a kernel itself (a cache miss: a signature no earlier run cached, a cache
made stale by a checkout, an emptied cache) holds the compiler's memory: 20-95 MB more peak RSS
and seconds of CPU. benchmarks/performance.py and benchmarks/memory.py call :func:`watch` in each
measured process before the model runs and report what it caught; a row that claims "warm" is
measured in a process that compiled nothing, and a compile that happens anyway is printed.

Light on purpose (numba is imported only when watching starts): memory.py measures the imports.
"""
from __future__ import annotations


def watch() -> list[str]:
    """Start recording numba's compilations in this process; returns the list that fills with
    each compiled function's ``module.qualname`` (numba's own overloads, compiled inside a
    kernel's compilation, included: ``...<locals>.impl``; an attempt that failed, e.g. a stale
    compile_ahead.KERNELS entry's types, left out)."""
    from numba.core import event

    compiled: list[str] = []

    class _Compiled(event.Listener):
        def on_start(self, ev):
            pass

        def on_end(self, ev):
            # an attempt that raised (types the kernel does not take): nothing was compiled
            # (numba 0.68's Event.is_failed is inverted: it is True when nothing was raised)
            if getattr(ev, "_exc_details", None) is not None:
                return
            f = ev.data["dispatcher"].py_func
            compiled.append(f"{f.__module__}.{f.__qualname__}")
    event.register("numba:compile", _Compiled())
    return compiled


def kernels(compiled: list[str]) -> list[str]:
    """The model's functions among ``compiled`` (not numba's nested overloads), each once, in
    order."""
    return list(dict.fromkeys(n for n in compiled if "<locals>" not in n))


def describe(compiled: list[str], most: int = 6) -> str:
    """``compiled`` in a few words for a table ("" when nothing compiled)."""
    if not compiled:
        return ""
    names = [n.removeprefix("fault_screen.") for n in kernels(compiled)]
    shown = ", ".join(names[:most]) + (", ..." if len(names) > most else "")
    return f"{len(compiled)} compilations in its process ({shown or 'numba overloads only'})"


def measure_warm(run, case: str) -> tuple[dict, str]:
    """``run(case)`` (a child process's result dict with its ``compiled`` list) measured warm:
    a run that compiled is discarded and the case run once more, when numba's cache holds what
    the first compiled. Returns the kept result and a note for the table: "" when the first run
    was warm, what the discarded run compiled (and its peak) otherwise, and a warning when the
    kept run compiled too (its numbers then include compilation)."""
    first = run(case)
    if not first.get("compiled"):
        return first, ""
    note = (f"a first run compiled ({describe(first['compiled'])}; peak "
            f"{first.get('peak_mb', float('nan')):.0f} MB): discarded, run again")
    second = run(case)
    if second.get("compiled"):
        note += f"; NOT WARM: the run kept compiled too ({describe(second['compiled'])})"
    return second, note

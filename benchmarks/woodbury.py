"""Where a slip front's Woodbury solve (``CondensedSolver._low_rank``) spends its time, part by
part, on the fine 30-degree scene (issue 28: that scene <= 6 s).

    python benchmarks/woodbury.py                  # the fine 30 deg T = 0.7 scene, 1 counted run
    python benchmarks/woodbury.py --repeat 3       # the median of 3 counted runs

In one process, after a first run that loads the kernels from numba's cache, the scene is run
whole with the solver's parts wrapped (process CPU seconds of each call, summed over the run):
the Woodbury solve itself; inside it, the columns of M0^-1 solved for (``_base_columns``), the
set-up of K (``_front_columns``: the gathers, the shift columns and Z_R[K] T_K; of it the shift
columns, ``_shift_columns``), the capacitance's LU, the solves by the size of their LU (the
condensed block's, the step size's 414-row one, the capacitance's |K| rows) and the checks
against M (``_times``); the rest of the Woodbury solve is numpy's products (D_K Z_K, the
applications' Z0 s, Z_R v, C_R w). Counts are the same on any machine; the seconds measure
the other processes too on a shared machine: say how busy it was.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from patching import Patches  # noqa: E402
from per_step import SCENES, _run  # noqa: E402


class _Parts:
    """Wraps the condensed solver's methods and the linear system's ``lu_solve`` and the LU
    factorisation: calls and CPU seconds by part, and whether a call is inside ``_low_rank``."""

    def __init__(self, n_condensed):
        import scipy.linalg

        from fault_screen import linear_system

        self.n = n_condensed
        self.calls, self.seconds = {}, {}
        self.inside = False
        self.reused = 0
        self._patches = Patches()
        solver = linear_system.CondensedSolver
        for name in ("_low_rank", "_base_columns", "_front_columns", "_shift_columns", "_times"):
            self._wrap(solver, name, lambda *args, _name=name: _name
                       if self.inside or _name == "_low_rank" else None)
        self._wrap(linear_system, "lu_solve", self._solve_part)
        self._wrap(scipy.linalg, "lu_factor", lambda M, *a, **k: "LU of the capacitance (|K| rows)"
                   if self.inside else None)

        def counting(front):
            def counted(solver_self, K, *args):
                kept = solver_self._front
                self.reused += kept is not None and len(kept[0]) == len(K) and (kept[0] == K).all()
                return front(solver_self, K, *args)
            return counted

        self._patches.replace(solver, "_front_columns", counting)

    def _solve_part(self, factors, b, *args):
        if not self.inside:
            return None
        n = len(factors[0])
        what = " (columns)" if b.ndim == 2 else " (a vector)"
        if n == self.n:
            return "solve with M0's LU" + what
        if n == self.storage_rows:
            return "solve with the step size's LU" + what
        return "solve with the capacitance (|K| rows)"

    def _wrap(self, owner, name, part):
        is_low_rank = name == "_low_rank"

        def timing(original):
            def timed(*args, **kwargs):
                key = part(*args)
                if is_low_rank:
                    self.inside = True
                c0 = time.process_time()
                try:
                    return original(*args, **kwargs)
                finally:
                    if is_low_rank:
                        self.inside = False
                    if key is not None:
                        self.calls[key] = self.calls.get(key, 0) + 1
                        self.seconds[key] = self.seconds.get(key, 0.0) + time.process_time() - c0
            return timed

        self._patches.replace(owner, name, timing)

    def restore(self):
        self._patches.restore()


#: parts inside other parts: the Woodbury solve itself, the shift columns (in K's set-up) and the
#: solves for columns (in ``_base_columns`` and the shift columns)
NESTED = ("_low_rank", "_shift_columns", "solve with M0's LU (columns)",
          "solve with the step size's LU (columns)")


def attribution(repeat):
    _, sim, _ = _run(SCENES["fine"])   # (the kernels loaded; the block's and R's sizes)
    n = len(sim.solver.N)
    storage_rows = len(sim.solver.system._dense._storage_rows)
    runs = []
    for _ in range(repeat):
        parts = _Parts(n)
        parts.storage_rows = storage_rows
        try:
            cpu, sim, steps = _run(SCENES["fine"])
        finally:
            parts.restore()
        runs.append((cpu, len(steps), parts))
    cpu, steps, parts = sorted(runs, key=lambda r: r[0])[len(runs) // 2]
    total = parts.seconds["_low_rank"]
    print(f"\n### fine 30 deg T = 0.7: {steps} steps, run CPU {cpu:.2f} s with the counting "
          f"(median of {repeat}), the Woodbury solve {total:.2f} s ({100 * total / cpu:.0f} %)\n")
    print("| part | calls | calls a step | CPU s a run | ms a call | % of the Woodbury solve |")
    print("|---|---|---|---|---|---|")
    counted_inside = 0.0
    for key in sorted(parts.seconds, key=lambda k: -parts.seconds[k]):
        calls, seconds = parts.calls[key], parts.seconds[key]
        print(f"| {key} | {calls} | {calls / steps:.2f} | {seconds:.3f} | {1e3 * seconds / calls:.2f} "
              f"| {100 * seconds / total:.0f} |")
        if key not in NESTED:
            counted_inside += seconds
    rest = total - counted_inside
    print(f"| rest: numpy's products | | | {rest:.3f} | | {100 * rest / total:.0f} |")
    print(f"\nK's set-up reused (K and the step size unchanged): {parts.reused} of "
          f"{parts.calls.get('_front_columns', 0)} calls")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1)
    attribution(parser.parse_args(argv).repeat)


if __name__ == "__main__":
    main()

"""Where a step of the bundled Rustrel scenes goes, and how much of its sweeps' time is the cache
(issue 28: per-step cost).

    python benchmarks/per_step.py                    # the SI scene and the paper-units scene
    python benchmarks/per_step.py --scenes paper --repeat 5
    python benchmarks/per_step.py --scenes paper rustrel fine --why-only   # the reasons alone

In one process per scene, after a first run that loads the kernels from numba's cache:

- ``runs``: the scene run whole ``--repeat`` times (``Simulation`` made, advanced to the end, its
  result made): process CPU seconds per run (median, least) and the median step's CPU time in ms
  (steps after the first, whose factorisation is the set-up's);
- per step, what the solver calls (counts, the same on any machine): forward and backward sweeps
  through the bulk's factors, solves with the condensed block's dense LU (``lu_solve``) and
  products with the condensation P;
- the sweeps: their CPU time a call inside a run (median), and on the same factors after the run
  (the right-hand sides of a run's size), back to back and with a pass over ``--traffic`` MB of
  other memory before each sweep: a sweep whose factor no longer sits in the cache reads it
  from memory, and the MB it takes to get there tell how much of a step's own traffic between
  two sweeps the cache holds beside the factor;
- ``why``: per step, the reason of each solve with the condensed block's factors and of each
  product with P (the calling solver method: a first solve, a refinement step, a GMRES
  iteration, a check of a result against M, a Woodbury update, the residual's product of updates
  without one), with the condensed solves, Newton iterations and factorisations of the block;
- ``shared``: the same run inside ``shared_bulk.sharing()`` (a run after an equal one: the order,
  the symbolic analyses and the factors reused, bit for bit) against one outside it, interleaved,
  CPU seconds per run (median), and whether the final states are equal to the bit.

On a shared machine every time measures the other processes too: compare the rows of one run,
and say how busy the machine was.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from patching import Patches

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SCENES = {"rustrel": ROOT / "configs" / "rustrel-2015-calibrated.toml",
          "paper": ROOT / "configs" / "rustrel-2015-calibrated-paper-units.toml",
          "fine": "fine-T0.7-dip30"}   # (the 30 deg T = 0.7 verification scene, elements halved)


def _scene(path):
    from fault_screen import Scene

    if path == SCENES["fine"]:
        sys.path.insert(0, str(ROOT / "benchmarks"))
        from verification_cost import scaled_scene

        return scaled_scene("fluid-driven-slip-T0.7-dip30", 0.5)
    return Scene.from_toml(path)


def _run(path):
    """One whole run: (process CPU s, the Simulation, the CPU s of each step)."""
    from fault_screen import Simulation

    c0 = time.process_time()
    sim = Simulation(_scene(path))
    marks = [time.process_time()]
    sim.advance(sim.scene.time.end, progress=lambda *_: marks.append(time.process_time()))
    sim.result()
    return time.process_time() - c0, sim, np.diff(marks)


class _Counted:
    """Wraps a module's function: calls and CPU seconds of each call."""

    def __init__(self, module, name):
        self.times = []
        self._patches = Patches()
        self._patches.replace(module, name, self._counting)

    def _counting(self, original):
        def counted(*args, **kwargs):
            c0 = time.process_time()
            out = original(*args, **kwargs)
            self.times.append(time.process_time() - c0)
            return out
        return counted

    def restore(self):
        self._patches.restore()


#: the reason of a solve with the condensed factors, by the first solver method met going up the
#: stack from it (``_iterate``'s first solve: before its refinement has an iterate ``x``)
_SOLVE_REASONS = (("_arnoldi", "GMRES iteration"), ("_base_columns", "Woodbury columns"),
                  ("_step_size_update", "step-size columns"), ("apply", "Woodbury solve"),
                  ("_iterate", "refinement"), ("solve", "direct (M is the factorised one)"))
#: the reason of a product with P, by the method calling ``_times`` (or ``condensation_times``)
_PRODUCT_REASONS = (("_arnoldi", "GMRES iteration"), ("_gmres", "GMRES restart check"),
                    ("_iterate", "check after refinement"), ("_low_rank", "Woodbury check"),
                    ("condensed", "residual: updates without a product"))


class _Reasons:
    """Wraps ``lu_solve`` and ``condensation_times`` of the linear system's module and counts
    their calls by reason (``_SOLVE_REASONS``, ``_PRODUCT_REASONS``); solves with a smaller LU
    than the condensed block's (the Woodbury capacitances) are counted apart."""

    def __init__(self, n_condensed):
        from fault_screen import linear_system

        self.n = n_condensed
        self.solves, self.products = {}, {}
        self._patches = Patches()
        self._lu_solve = self._patches.replace(linear_system, "lu_solve", lambda _: self._solve)
        self._condensation_times = self._patches.replace(linear_system, "condensation_times",
                                                         lambda _: self._product)

    @staticmethod
    def _reason(table, what):
        frame = sys._getframe(2)
        while frame is not None:
            name = frame.f_code.co_name
            for method, reason in table:
                if name == method:
                    if method == "_iterate" and table is _SOLVE_REASONS and "x" not in frame.f_locals:
                        return "first solve"
                    return reason
            frame = frame.f_back
        return f"other {what}"

    def _solve(self, factors, b, *args, **kwargs):
        reason = (self._reason(_SOLVE_REASONS, "solve") if len(factors[0]) == self.n
                  else "capacitance (small LU)")
        columns = 1 if b.ndim == 1 else b.shape[1]
        calls, cols = self.solves.get(reason, (0, 0))
        self.solves[reason] = (calls + 1, cols + columns)
        return self._lu_solve(factors, b, *args, **kwargs)

    def _product(self, P, symmetric, v):
        reason = self._reason(_PRODUCT_REASONS, "product")
        self.products[reason] = self.products.get(reason, 0) + 1
        return self._condensation_times(P, symmetric, v)

    def restore(self):
        self._patches.restore()


def why_rows(name, path):
    """Per step, why each condensed solve and product with P happens (``_Reasons``)."""
    from fault_screen import linear_system

    _, sim, _ = _run(path)   # (the kernels loaded; the block's size)
    reasons = _Reasons(len(sim.solver.N))
    solves = []
    original = linear_system.CondensedSolver.solve

    def counted(solver, b):
        solves.append(1)
        return original(solver, b)

    linear_system.CondensedSolver.solve = counted
    try:
        cpu, sim, steps = _run(path)
    finally:
        reasons.restore()
        linear_system.CondensedSolver.solve = original
    n = len(steps)
    dense = sim.solver.system._dense
    result = sim.result()
    newton = int(result.solver["iterations"].sum())
    print(f"\n### {name}, why: {n} steps, {newton / n:.2f} Newton iterations, {len(solves) / n:.2f} "
          f"condensed solves, {dense.factorizations / n:.2f} factorisations of the block a step "
          f"(CPU {cpu:.2f} s with the counting)\n")
    print("| solves with the condensed LU | calls a step | columns a step |\n|---|---|---|")
    for reason, (calls, cols) in sorted(reasons.solves.items(), key=lambda kv: -kv[1][0]):
        print(f"| {reason} | {calls / n:.2f} | {cols / n:.2f} |")
    total = sum(c for r, (c, _) in reasons.solves.items() if not r.startswith("capacitance"))
    print(f"| all but the capacitances | {total / n:.2f} | |")
    print("\n| products with P | calls a step |\n|---|---|")
    for reason, calls in sorted(reasons.products.items(), key=lambda kv: -kv[1]):
        print(f"| {reason} | {calls / n:.2f} |")
    print(f"| all | {sum(reasons.products.values()) / n:.2f} |")


def _sweep_times(lu, traffic_mb, repeat):
    """Median CPU ms of a forward and a backward sweep on ``lu`` after a pass over
    ``traffic_mb`` MB of other memory before each (0: back to back)."""
    from fault_screen import bordered_lu

    rng = np.random.default_rng(0)
    r_linear, r_condensed = rng.standard_normal(lu.n_linear), rng.standard_normal(lu.n - lu.n_linear)
    other = np.ones(max(1, int(traffic_mb * 1e6 / 8)))
    forward, backward = _Counted(bordered_lu, "_forward_sweep"), _Counted(bordered_lu, "_backward_sweep")
    try:
        for _ in range(repeat):
            if traffic_mb:
                other += 1.0
            swept, _ = lu.forward(r_linear, r_condensed)
            if traffic_mb:
                other += 1.0
            lu.backward(swept, r_condensed)
    finally:
        forward.restore()
        backward.restore()
    return 1e3 * np.median(forward.times), 1e3 * np.median(backward.times)


def scene_rows(name, repeat, traffic, sweep_repeat):
    from fault_screen import bordered_lu, linear_system, shared_bulk

    path = SCENES[name]
    _run(path)   # (the kernels loaded)
    cpu, step_ms = [], []
    for _ in range(repeat):
        c, sim, steps = _run(path)
        cpu.append(c)
        step_ms.append(1e3 * np.median(steps[1:]))
    print(f"\n### {name}: {sim.disc.n_dofs} unknowns, {len(sim.solver.B)} in the bulk, "
          f"{len(sim.solver.N)} condensed\n")
    print("| runs | CPU s a run (median, least) | median step CPU ms |")
    print("|---|---|---|")
    print(f"| {repeat} | {np.median(cpu):.3f}, {min(cpu):.3f} | {np.median(step_ms):.2f} |")

    counted = [_Counted(bordered_lu, "_forward_sweep"), _Counted(bordered_lu, "_backward_sweep"),
               _Counted(linear_system, "lu_solve"), _Counted(linear_system, "condensation_times")]
    try:
        _, sim, steps = _run(path)
    finally:
        for c in counted:
            c.restore()
    n_steps = len(steps)
    lu = sim.solver.system.lu
    print(f"\nper step ({n_steps} steps; calls a step): forward sweeps "
          f"{len(counted[0].times) / n_steps:.2f}, backward sweeps {len(counted[1].times) / n_steps:.2f}, "
          f"condensed LU solves {len(counted[2].times) / n_steps:.2f}, products with P "
          f"{len(counted[3].times) / n_steps:.2f}; packed factor {8e-6 * lu.packed_values:.1f} MB\n")
    print("| sweeps, CPU ms a call (median) | forward | backward |")
    print("|---|---|---|")
    print(f"| in the run | {1e3 * np.median(counted[0].times):.3f} | {1e3 * np.median(counted[1].times):.3f} |")
    for mb in traffic:
        f, b = _sweep_times(lu, mb, sweep_repeat)
        what = "back to back" if mb == 0 else f"after {mb:g} MB of other memory"
        print(f"| on the run's factors, {what} | {f:.3f} | {b:.3f} |")

    store = shared_bulk.SharedBulk()
    with shared_bulk.sharing(store):
        _run(path)   # (what the shared runs reuse)
    plain, shared = [], []
    for _ in range(repeat):
        c, alone, _ = _run(path)
        plain.append(c)
        with shared_bulk.sharing(store):
            c, inside, _ = _run(path)
        shared.append(c)
    print("\n| second run | CPU s (median) |\n|---|---|")
    print(f"| alone | {np.median(plain):.3f} |")
    print(f"| inside `shared_bulk.sharing()` after an equal run | {np.median(shared):.3f} |")
    print(f"\nfinal states equal to the bit: {np.array_equal(alone.x, inside.x)}")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="+", choices=sorted(SCENES), default=["rustrel", "paper"])
    p.add_argument("--repeat", type=int, default=3, help="runs per row (default 3)")
    p.add_argument("--traffic", type=float, nargs="+", default=[0, 4, 8, 16, 32],
                   help="MB of other memory passed over before each sweep (default 0 4 8 16 32)")
    p.add_argument("--sweep-repeat", type=int, default=40, help="sweeps per traffic row (default 40)")
    p.add_argument("--why-only", action="store_true",
                   help="only the reasons of the condensed solves and products (``why``)")
    a = p.parse_args(argv)
    for name in a.scenes:
        if not a.why_only:
            scene_rows(name, a.repeat, a.traffic, a.sweep_repeat)
        why_rows(name, SCENES[name])


if __name__ == "__main__":
    main()

"""The per-step sweeps through the bulk's factors on the large scenes (issue 28): bytes and times.

    python benchmarks/sweeps.py                     # Rustrel 200 x 201 and the fine 30-degree scene
    python benchmarks/sweeps.py --scenes rustrel    # the bundled 50 x 51 (one part)

Each scene is stepped three times (its factors made as in a run), then its factors are read as the
solver holds them (``bordered_lu.BorderedLU``, or ``SplitBorderedLU``'s parts) and each sweep is
timed on them alone. Per part:

- what its packed factor holds, in MB: ``values`` (all of them; ``square``: what square
  diagonal blocks would hold, the layout before the triangles were stored up to their
  diagonal), of which ``upper`` (zeros stored above a supernode's diagonal: none in that
  layout), ``diag`` (the diagonal), ``zeros`` (other zeros: the amalgamated supernodes' fill)
  and ``border`` (the rows of the condensed unknowns and separators, L21: both sweeps read
  them), and ``rows`` (the row indices);
- ``least``: what a sweep must read at the least, L's entries below the diagonal (amalgamation's
  zeros counted: they are the layout's, not the padding's) with their row indices, and the
  right-hand side read and written once;
- ``fwd``/``bwd``: the least CPU time of a forward and a backward sweep of the part in ms (the
  kernels alone, ``--repeat`` times), and the rate at which each reads the packed factor (its
  values and row indices over that time, GB/s).

Then the whole step's sweeps of a split block (``forward``/``backward``, with the separator's dense
solves): one thread against two (``bordered_lu._each_part``), wall and process CPU time, least of
``--repeat``, side by side in one run; and the dense separator's LU solve (``lu_solve``: getrs on
R_SS) with the products beside it. On a shared machine wall times measure the other processes
too: compare the rows of one run, and read the CPU columns.

    python benchmarks/sweeps.py --phases            # where a whole run spends its time

``--phases``: each scene run whole in this process (after a first run that loads its kernels
from numba's cache, timed too), with timers around the set-up's phases (mesh, fault geometry,
the fault's points, the elements' tabulation, the rest of the discretisation, the assembly of
the constant matrices, the fill-reducing order, the factorisations) and the steps' (forward and
backward sweeps with the separator's solves, the condensed solve with its LAPACK solves
with the condensed block's LU (getrs, on vectors and pages of columns) and its products with
the dense condensation P counted apart, the residual (with its products with P), the contact
law, the output per step, and the passes over whole vectors around them: the products A x, Hf x,
C x of the convergence references, the scaled residual's norms, the bulk solve's and update's
gathers and scatters, the step's set-up and first guess; what is left is the rest of the Newton
iteration and the step control). Each phase's own time (the phases it calls subtracted), wall
and process CPU (the sweep worker thread's included, in the sweeps), in seconds, and its calls
(a call inside one of its own phase, a split block's part inside the block's sweep, is not
counted again: ``forward sweeps`` counts the step's forward sweeps through all the parts).

    python benchmarks/sweeps.py --fill              # what the fill-reducing order leaves to read

``--fill``: the bulk's pattern at the first step, ordered by ``ordering.nested_dissection`` with
each set cut across its side with more node lines (the rule in use) and, beside it, across its
longer side in metres (the rule before), and analysed whole by the L D L^T's symbolic analysis:
L's entries, the factorisation's multiply-adds, the MB of packed values a sweep reads, and the
order's CPU time. Counts, not timings: the same on a busy machine.

    python benchmarks/sweeps.py --whole             # a large bulk's L D L^T whole or split

``--whole``: the bulk's L D L^T whole (one ``BorderedLU``) against split in parts as the solver
splits a bulk above ``bordered_lu.SPLIT_ABOVE`` (``SplitBorderedLU``: the parts one after the
other, each its own L D L^T; ``--forms halves``: in the first cut's halves, however large;
``split-checked``: each part's symmetry checked, as before ``SplitBorderedLU(symmetric=True)``), on the same
matrix, each in a fresh process (``--rounds`` times, alternating): the CPU and wall time of the first factorisation (with the symbolic analysis) and
of the numeric one again (what a change of step size pays), the peak of resident memory above
what the process held before the factorisation, what stays resident (the factors, the Schur
complement), the packed values the sweeps read, and a step's forward and backward sweeps (a
split block's parts in two threads, a whole one in one thread, as the solver sweeps them).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from patching import Patches  # noqa: E402

SCENES = ("rustrel-200x201", "fine-T0.7-dip30", "rustrel")


def _scene(name):
    from fault_screen import Scene

    if name.startswith("rustrel"):
        s = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
        return s.replace(mesh=replace(s.mesh, nx=200, ny=201)) if name == "rustrel-200x201" else s
    from verification_cost import scaled_scene

    return scaled_scene("fluid-driven-slip-T0.7-dip30", 0.5)


def factors_of(name):
    """The bulk's factors of the scene after three steps, as its solver holds them."""
    from fault_screen import Simulation

    scene = _scene(name)
    sim = Simulation(scene)
    sim.advance(3 * scene.time.dt)
    return sim.solver.system.lu


def accounting(part):
    """MB of each kind in a part's packed factor (see the module docstring)."""
    first, width, row_at, value_at, rows, values = part._L.arrays
    if part._U is not None:   # (SuperLU's unsymmetric form: U packed beside L, counted with it)
        values = np.concatenate([values, part._U.arrays[5]])
    m = np.diff(row_at)
    factors = 1 if part._U is None else 2
    diagonal = int(width.sum()) * factors
    square = int((m * width).sum()) * factors   # (values in square diagonal blocks)
    upper = values.size - int((width * (width + 1) // 2 + (m - width) * width).sum()) * factors
    border = 0
    for t in range(len(width)):
        on_border = rows[row_at[t]:row_at[t + 1]] >= part.n_linear
        border += int(np.count_nonzero(on_border)) * int(width[t])
    zeros = int(np.count_nonzero(values == 0.0)) - upper
    index_bytes = rows.nbytes * (1 if part._U is None else 2)
    least = (values.size - upper - diagonal) * 8 + index_bytes + 2 * 8 * part.n
    mb = 1e-6 * 8
    return dict(values=values.size * mb, square=square * mb, upper=upper * mb, diag=diagonal * mb,
                zeros=zeros * mb,
                border=border * mb, rows=1e-6 * index_bytes, least=1e-6 * least,
                streamed=1e-6 * (values.nbytes + index_bytes), m_max=int(m.max()),
                width_mean=float(width.mean()))


def least_cpu(fn, repeat):
    """The least thread CPU time of ``repeat`` calls (s), and the least wall time."""
    cpu = wall = np.inf
    for _ in range(repeat):
        w, c = time.perf_counter(), time.thread_time()
        fn()
        cpu, wall = min(cpu, time.thread_time() - c), min(wall, time.perf_counter() - w)
    return cpu, wall


def part_sweeps(part, repeat):
    """Least CPU time of the part's forward and backward kernels (s)."""
    from fault_screen.bordered_lu import _backward_sweep, _forward_sweep

    r = np.random.default_rng(0).standard_normal(part.n)

    def forward():
        _forward_sweep(*part._L.arrays, r.copy())

    def backward():
        if part._U is None:
            _backward_sweep(*part._L.arrays, part._D, True, r.copy())
        else:
            _backward_sweep(*part._U.arrays, part._D, False, r.copy())

    return least_cpu(forward, repeat)[0], least_cpu(backward, repeat)[0]


def whole(lu, repeat):
    """Forward then backward of the whole block, one thread against two (a split block), side by
    side, alternating: least wall and process CPU of each (s), and for two threads the critical
    path, the larger of the two threads' CPU in the parts' sweeps (what the wall would be on two
    otherwise idle cores: each thread's CPU time includes its waits for memory, so it counts the
    two streams' contention, which a busy machine's wall time cannot show)."""
    from fault_screen.bordered_lu import SplitBorderedLU

    r = np.random.default_rng(1).standard_normal(lu.n)
    nB = lu.n_linear
    forms = {"1 thread": lu}
    spent = {}   # thread name -> CPU in the parts' sweeps

    if isinstance(lu, SplitBorderedLU) and lu._halves is not None:
        alone = SplitBorderedLU.__new__(SplitBorderedLU)
        alone.__dict__.update(lu.__dict__, _halves=None)
        threaded = SplitBorderedLU.__new__(SplitBorderedLU)
        threaded.__dict__.update(lu.__dict__)
        threaded._parts = [_Timed(part, spent) for part in lu._parts]
        forms = {"1 thread": alone, "2 threads": threaded}
    best = {k: [np.inf] * 6 for k in forms}
    for _ in range(repeat):
        for k, f in forms.items():
            spent.clear()
            w, c = time.perf_counter(), time.process_time()
            swept, _ = f.forward(r[:nB], r[nB:])
            w1, c1 = time.perf_counter(), time.process_time()
            path_forward = max(spent.values(), default=np.nan)
            spent.clear()
            f.backward(swept, r[nB:])
            w2, c2 = time.perf_counter(), time.process_time()
            path_backward = max(spent.values(), default=np.nan)
            b = best[k]
            b[:] = (min(b[0], w1 - w), min(b[1], c1 - c), min(b[2], w2 - w1), min(b[3], c2 - c1),
                    np.fmin(b[4], path_forward), np.fmin(b[5], path_backward))
    return best


class _Timed:
    """A part whose sweeps add their thread's CPU time to ``spent`` under the thread's name."""

    def __init__(self, part, spent):
        self.part, self.spent = part, spent

    def _timed(self, sweep, *args):
        import threading

        c = time.thread_time()
        out = sweep(*args)
        name = threading.current_thread().name
        self.spent[name] = self.spent.get(name, 0.0) + time.thread_time() - c
        return out

    def forward(self, *args):
        return self._timed(self.part.forward, *args)

    def backward(self, *args):
        return self._timed(self.part.backward, *args)


def separator(lu, repeat):
    """The split block's dense separator solves a step makes: getrs on R_SS (each sweep way one),
    and the products with R_NS and S_from_N, least CPU (s)."""
    from fault_screen.bordered_lu import lu_solve

    g = np.random.default_rng(2).standard_normal(len(lu._R_SS[0]))
    xN = np.random.default_rng(3).standard_normal(lu._S_from_N.shape[1])
    return dict(n_S=len(g), n_N=len(xN),
                getrs=least_cpu(lambda: lu_solve(lu._R_SS, g), repeat)[0],
                R_NS=least_cpu(lambda: lu._R_NS @ g, repeat)[0],
                S_from_N=least_cpu(lambda: lu._S_from_N @ xN, repeat)[0])


def bulk_pattern(name):
    """(scaled linear Jacobian, the bulk's unknowns B, the fault's N, every unknown's point) of
    the scene at its first step, as the solver orders them."""
    from fault_screen import Simulation
    from fault_screen import linear_system

    held = {}
    order = linear_system.CondensedSystem._bulk_order

    def capture(system, Ls, *_):
        held.update(Ls=Ls, B=system.B, N=system.N, xy=system._coordinates())
        raise _Captured

    linear_system.CondensedSystem._bulk_order = capture
    try:
        scene = _scene(name)
        Simulation(scene).advance(scene.time.dt)
    except _Captured:
        pass
    finally:
        linear_system.CondensedSystem._bulk_order = order
    return held["Ls"], held["B"], held["N"], held["xy"]


class _Captured(Exception):
    pass


def _longer_extent(p, line, n_lines, in_set, offsets, n_sets):
    """The rule before: each set cut along its longer extent in metres."""
    extent = np.maximum.reduceat(p, offsets, axis=0) - np.minimum.reduceat(p, offsets, axis=0)
    return np.argmax(extent, axis=1)


def fill(name):
    """Rows (rule, L's entries, multiply-adds, packed MB, order CPU s) of the scene's bulk."""
    from fault_screen import ordering
    from fault_screen.ldl import LDLSymbolic, _lower

    Ls, B, N, xy = bulk_pattern(name)
    pattern, points = Ls[B][:, B], xy[B]
    rows = []
    in_use = ordering._cut_axis
    for rule, axis in (("node lines (in use)", in_use), ("longer extent", _longer_extent)):
        ordering._cut_axis = axis
        try:
            cpu = time.process_time()
            inner = ordering.nested_dissection(pattern, points)
            cpu = time.process_time() - cpu
        finally:
            ordering._cut_axis = in_use
        order = np.concatenate([B[inner], N])
        symbolic = LDLSymbolic(_lower(Ls[order][:, order].tocsc(), len(B)), len(B))
        rows.append((rule, symbolic.nnz, symbolic.multiply_adds,
                     8e-6 * float(symbolic.value_at[-1]), cpu))
    return rows


#: (module, attribute, phase) timed by ``--phases``: a function or a method (``Class.name``)
PHASES = [
    ("fault_screen.discretisation", "model_mesh", "set-up: mesh"),
    ("fault_screen.xfem", "locate_fault", "set-up: fault geometry (locate_fault)"),
    ("fault_screen.discretisation", "Discretisation._tabulate_fault", "set-up: fault points"),
    ("fault_screen.discretisation", "Discretisation._tabulate_bulk", "set-up: element tabulation"),
    ("fault_screen.solver", "assemble_constant", "set-up: assembly of the constant matrices"),
    ("fault_screen.linear_system", "nested_dissection", "set-up: fill-reducing order"),
    ("fault_screen.linear_system", "CondensedSystem._factorise_held", "factorisations of the bulk"),
    ("fault_screen.bordered_lu", "BorderedLU.forward", "steps: forward sweeps"),
    ("fault_screen.bordered_lu", "SplitBorderedLU.forward", "steps: forward sweeps"),
    ("fault_screen.bordered_lu", "BorderedLU.backward", "steps: backward sweeps"),
    ("fault_screen.bordered_lu", "SplitBorderedLU.backward", "steps: backward sweeps"),
    ("fault_screen.linear_system", "CondensedSolver.solve", "steps: condensed solve"),
    # (names looked up in linear_system's namespace at each call: the condensed block's solves
    # and the products with P, wherever linear_system makes them)
    ("fault_screen.linear_system", "lu_solve", "steps: condensed block's getrs"),
    ("fault_screen.linear_system", "condensation_times", "steps: products with P"),
    ("fault_screen.solver", "NewtonSolver._residual", "steps: residual"),
    ("fault_screen.physics.contact", "Contact.residual", "steps: contact law"),
    ("fault_screen.stepper", "Recorder.record", "steps: output per step"),
    # what was "the rest of the Newton iteration": the passes over whole vectors around the
    # linear algebra, each named
    ("fault_screen.solver", "_whole_products", "steps: whole products A x, Hf x, C x (references)"),
    ("fault_screen.solver", "NewtonSolver._reference",
     "steps: references' other work (norms, products through N)"),
    ("fault_screen.solver", "_scaled_field_norms", "steps: scaled residual and its norms"),
    ("fault_screen.solver", "NewtonSolver._prepare", "steps: step set-up (prepare)"),
    ("fault_screen.solver", "NewtonSolver._linear_times_start",
     "steps: products at a step's start"),
    ("fault_screen.solver", "NewtonSolver._linear_times_guess",
     "steps: products at a step's start"),
    ("fault_screen.linear_system", "CondensedSystem.solve",
     "steps: bulk solve's own vectors (gathers, scatters around the sweeps)"),
    ("fault_screen.linear_system", "CondensedSystem.complete_bulk",
     "steps: bulk update's own vectors (scatter into x, reactions)"),
    ("fault_screen.linear_system", "CondensedSystem.condensed",
     "steps: condensed block set (its values, its LU when new)"),
    ("fault_screen.stepper", "Simulation._extrapolated_guess", "steps: first guess"),
]


class _PhaseTimers:
    """Timers around PHASES (in the main thread only: a split block's worker runs inside the
    main thread's sweep, whose process CPU time counts it), each phase's own time kept."""

    def __init__(self):
        import threading

        self.main = threading.main_thread()
        self.own = {}      # phase -> [wall, cpu, calls]
        self.stack = []    # [phase, wall0, cpu0, children's wall, children's cpu]
        self.stage = None  # what the run is doing: "set-up", "steps", "result"
        self.timed = {}    # stage -> [wall, cpu] inside the phases
        self.patches = Patches()

    def wrap(self, fn, phase):
        import functools
        import threading

        @functools.wraps(fn)
        def timed(*args, **kwargs):
            if threading.current_thread() is not self.main:
                return fn(*args, **kwargs)
            self.stack.append([phase, time.perf_counter(), time.process_time(), 0.0, 0.0])
            try:
                return fn(*args, **kwargs)
            finally:
                _, w0, c0, cw, cc = self.stack.pop()
                wall, cpu = time.perf_counter() - w0, time.process_time() - c0
                own = self.own.setdefault(phase, [0.0, 0.0, 0])
                own[0] += wall - cw
                own[1] += cpu - cc
                # a call inside a call of its own phase (a split block's parts inside its
                # sweep) is not counted again: the calls are the step's sweeps
                own[2] += not any(frame[0] == phase for frame in self.stack)
                inside = self.timed.setdefault(self.stage, [0.0, 0.0])
                inside[0] += wall - cw
                inside[1] += cpu - cc
                if self.stack:
                    self.stack[-1][3] += wall
                    self.stack[-1][4] += cpu
        return timed

    def __enter__(self):
        for module, name, phase in PHASES:
            self.patches.replace(module, name, lambda fn, _phase=phase: self.wrap(fn, _phase))
        return self

    def __exit__(self, *exc):
        self.patches.restore()


def phases(name):
    """Seconds (wall, CPU) per phase of a whole run of the scene: (rows, totals)."""
    from fault_screen import Simulation

    scene = _scene(name)
    w0, c0 = time.perf_counter(), time.process_time()
    first = Simulation(scene)       # (the kernels loaded from numba's cache, their first calls)
    first.advance(scene.time.end)
    first.result()
    del first
    first_run = (time.perf_counter() - w0, time.process_time() - c0)
    with _PhaseTimers() as timers:
        w0, c0 = time.perf_counter(), time.process_time()
        timers.stage = "set-up"
        sim = Simulation(scene)
        w1, c1 = time.perf_counter(), time.process_time()
        timers.stage = "steps"      # (the order and the first factorisation: in the first step)
        sim.advance(scene.time.end)
        w2, c2 = time.perf_counter(), time.process_time()
        timers.stage = "result"
        sim.result()
        w3, c3 = time.perf_counter(), time.process_time()
    own = timers.own
    inside = {k: timers.timed.get(k, [0.0, 0.0]) for k in ("set-up", "steps", "result")}
    rest = {"set-up: the rest (Simulation: physics, unknowns, boundary conditions, solver)":
                (w1 - w0 - inside["set-up"][0], c1 - c0 - inside["set-up"][1]),
            "steps: the rest (Newton iteration, line search, step control)":
                (w2 - w1 - inside["steps"][0], c2 - c1 - inside["steps"][1]),
            "result": (w3 - w2 - inside["result"][0], c3 - c2 - inside["result"][1])}
    rows = [(phase, wall, cpu, calls) for phase, (wall, cpu, calls) in own.items()]
    rows += [(phase, wall, cpu, 1) for phase, (wall, cpu) in rest.items()]
    return rows, dict(steps=len(sim.result().time) - 1, dofs=sim.disc.n_dofs, total=(w3 - w0, c3 - c0),
                      first_run=first_run)


def print_phases(name):
    rows, totals = phases(name)
    print(f"\n## {name}: {totals['dofs']} unknowns, {totals['steps']} steps; whole run {totals['total'][0]:.2f} s "
          f"wall, {totals['total'][1]:.2f} s CPU (the first run in this process, kernels loaded: "
          f"{totals['first_run'][0]:.2f} s wall, {totals['first_run'][1]:.2f} s CPU)")
    print("| phase | calls | per step | wall s | CPU s | CPU ms a step |")
    print("|---|---|---|---|---|---|")
    steps = max(totals["steps"], 1)
    for phase, wall, cpu, calls in sorted(rows, key=lambda r: (not r[0].startswith("set-up"), -r[2])):
        each_step = phase.startswith("steps")
        per_step = f"{calls / steps:.2f}" if each_step and "the rest" not in phase else ""
        cpu_ms = f"{1e3 * cpu / steps:.2f}" if each_step else ""
        print(f"| {phase} | {calls} | {per_step} | {wall:.2f} | {cpu:.2f} | {cpu_ms} |")


def _vm(field):
    """This process's /proc/self/status ``field`` (VmRSS, VmHWM) in MB."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def whole_or_split_case(name, mode, repeat):
    """``--whole`` in a process of its own (``mode``: ``split`` or ``whole``): the scaled free
    matrix at WHOLE_STEP_SIZE as the solver hands it to ``bordered_lu`` (the symmetric form of a
    poroelastic bulk), in the solver's order with its split, factorised three times on one
    ``ldl.SymbolicAnalyses`` (the first also analyses the pattern; the later are what a step-size
    change pays): the process CPU and wall of each (s), the peak of resident memory above the
    memory before it (MB: the peak reset through /proc/self/clear_refs) and what stays resident
    after it (the factors and the Schur complement); then the packed values the sweeps read (MB)
    and a step's forward and backward sweeps (least wall and process CPU of ``repeat``, ms: a
    split block's parts in two threads, as the solver sweeps them)."""
    import gc

    import scipy.sparse as sp

    from fault_screen import Simulation, bordered_lu, ldl

    if mode == "halves":   # (the order of the first cut's halves: no part size forces quarters)
        bordered_lu.PART_SIZE = 10 ** 9
    scene = _scene(name)
    sim = Simulation(scene)
    solver, disc = sim.solver, sim.disc
    contact = disc.physics.contact
    solver._prepare(scene.time.dt, np.zeros(disc.n_dofs),
                    contact.initial_history(disc) if contact is not None else None)
    system = solver.system
    D = sp.diags(system.scale)
    M = (D @ system._linear_jacobian(WHOLE_STEP_SIZE) @ D).tocsr()[system.order][:, system.order]
    M = M.tocsc()
    if not system.factors_any_dt:
        M.data *= np.where(system._mechanical[system.order], 1.0, -WHOLE_STEP_SIZE)[M.indices]
    nB, split = len(system.B), system.split
    # (a poroelastic bulk's parts are known symmetric at a new step size, as the solver's are;
    # an elastic one's, factorised once, and ``split-checked``'s are checked)
    symmetric = not system.factors_any_dt and mode != "split-checked"
    system.lu = system.P = None
    del sim, solver
    analyses = ldl.SymbolicAnalyses()
    out = dict(factorisations=[])
    lu = None
    for _ in range(3):
        lu = None
        gc.collect()
        bordered_lu.release_freed_memory()
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")   # (VmHWM back to VmRSS)
        base = _vm("VmRSS")
        w, c = time.perf_counter(), time.process_time()
        lu = (bordered_lu.BorderedLU(M, nB, analyses) if mode == "whole" else
              bordered_lu.SplitBorderedLU(M, nB, split, analyses, symmetric=symmetric))
        out["factorisations"].append((time.process_time() - c, time.perf_counter() - w,
                                      _vm("VmHWM") - base, _vm("VmRSS") - base))
    parts = getattr(lu, "_parts", [lu])
    out["values_mb"] = 8e-6 * sum(part.packed_values for part in parts)
    out["ldl"] = all(part.quasi_definite for part in parts)
    out["parts"] = len(parts)
    r = np.random.default_rng(1).standard_normal(lu.n)
    wall = cpu = np.inf
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        swept, _ = lu.forward(r[:nB], r[nB:])
        lu.backward(swept, r[nB:])
        wall, cpu = min(wall, time.perf_counter() - w), min(cpu, time.process_time() - c)
    out["sweeps"] = (1e3 * wall, 1e3 * cpu)
    return out


#: ``--whole``'s step size (s): the paper-units scenes' largest
WHOLE_STEP_SIZE = 600.0


def whole_or_split(name, rounds, repeat, modes=("split", "whole")):
    """``--whole``: split against whole, each case in a fresh process (its own peak), the
    ``modes`` alternating ``rounds`` times; the rows of each round."""
    import json
    import subprocess

    rows = []
    for _ in range(rounds):
        for mode in modes:
            out = subprocess.run([sys.executable, __file__, "--whole-case", name, mode,
                                  "--repeat", str(repeat)], capture_output=True, text=True,
                                 check=True)
            rows.append((mode, json.loads(out.stdout.strip().splitlines()[-1]),
                         os.getloadavg()[0]))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="*", default=list(SCENES[:2]), choices=SCENES)
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--phases", action="store_true", help="where a whole run spends its time")
    ap.add_argument("--fill", action="store_true",
                    help="the fill-reducing order's L entries, multiply-adds and packed MB")
    ap.add_argument("--whole", action="store_true",
                    help="a large bulk's L D L^T whole against split in parts: time, memory, sweeps")
    ap.add_argument("--rounds", type=int, default=2, help="--whole: split and whole alternately")
    ap.add_argument("--forms", nargs="*", default=["split", "whole"], choices=["split", "split-checked", "halves", "whole"],
                    help="--whole: split as the solver splits (split-checked: each part's symmetry "
                         "checked), in halves only, whole")
    ap.add_argument("--whole-case", nargs=2, metavar=("SCENE", "MODE"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.whole_case:
        import json

        print(json.dumps(whole_or_split_case(*args.whole_case, args.repeat)))
        return
    print(f"load average at start: {os.getloadavg()[0]:.1f}")
    if args.whole:
        for name in args.scenes:
            print(f"\n## {name}: the bulk's L D L^T whole or split (at {WHOLE_STEP_SIZE:.0f} s)")
            print("| form | parts | analysis + numeric: CPU s, wall s, peak MB | numeric again: "
                  "CPU s, wall s, peak MB | held MB | values MB | sweeps: wall ms, CPU ms "
                  "| load |")
            print("|---|---|---|---|---|---|---|---|")
            for mode, o, load in whole_or_split(name, args.rounds, args.repeat, args.forms):
                (c0, w0, p0, _), *again = o["factorisations"]
                c1, w1 = min(a[0] for a in again), min(a[1] for a in again)
                p1, held = max(a[2] for a in again), again[-1][3]
                print(f"| {mode} | {o['parts']}{'' if o['ldl'] else ' (SuperLU)'} "
                      f"| {c0:.3f}, {w0:.3f}, {p0:.0f} | {c1:.3f}, {w1:.3f}, {p1:.0f} | {held:.0f} "
                      f"| {o['values_mb']:.1f} | {o['sweeps'][0]:.2f}, {o['sweeps'][1]:.2f} "
                      f"| {load:.1f} |")
        print(f"\nload average at end: {os.getloadavg()[0]:.1f}")
        return
    if args.fill:
        for name in args.scenes:
            print(f"\n## {name}: the bulk's L D L^T in its fill-reducing order")
            print("| each set cut across | L entries (M) | multiply-adds (M) | packed MB "
                  "| order CPU s |")
            print("|---|---|---|---|---|")
            for rule, nnz, work, mb, cpu in fill(name):
                print(f"| {rule} | {1e-6 * nnz:.3f} | {1e-6 * work:.0f} | {mb:.1f} | {cpu:.2f} |")
        return
    if args.phases:
        for name in args.scenes:
            print_phases(name)
        print(f"\nload average at end: {os.getloadavg()[0]:.1f}")
        return
    for name in args.scenes:
        lu = factors_of(name)
        parts = getattr(lu, "_parts", [lu])
        print(f"\n## {name}: {lu.n} unknowns, {lu.n_linear} linear, {len(parts)} part(s)")
        print("| part | unknowns | values MB | square MB | upper | diag | zeros | border | rows MB "
              "| least MB "
              "| fwd ms | fwd GB/s | bwd ms | bwd GB/s |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        total = dict(fwd=0.0, bwd=0.0)
        for i, part in enumerate(parts):
            a = accounting(part)
            fwd, bwd = part_sweeps(part, args.repeat)
            total["fwd"] += fwd
            total["bwd"] += bwd
            print(f"| {i} | {part.n} | {a['values']:.1f} | {a['square']:.1f} | {a['upper']:.1f} "
                  f"| {a['diag']:.2f} "
                  f"| {a['zeros']:.1f} | {a['border']:.1f} | {a['rows']:.2f} | {a['least']:.1f} "
                  f"| {1e3 * fwd:.2f} | {1e-3 * a['streamed'] / fwd:.1f} "
                  f"| {1e3 * bwd:.2f} | {1e-3 * a['streamed'] / bwd:.1f} |")
        print(f"kernels' CPU, all parts: forward {1e3 * total['fwd']:.2f} ms, backward "
              f"{1e3 * total['bwd']:.2f} ms")
        for k, (wf, cf, wb, cb, pf, pb) in whole(lu, args.repeat).items():
            path = (f", critical path (the busier thread's CPU in the parts) {1e3 * pf:.2f} + "
                    f"{1e3 * pb:.2f} ms" if k == "2 threads" else "")
            print(f"whole forward + backward, {k}: wall {1e3 * wf:.2f} + {1e3 * wb:.2f} ms, "
                  f"process CPU {1e3 * cf:.2f} + {1e3 * cb:.2f} ms{path}")
        if hasattr(lu, "_R_SS"):
            s = separator(lu, args.repeat)
            print(f"separator: R_SS {s['n_S']} x {s['n_S']} getrs {1e3 * s['getrs']:.2f} ms, "
                  f"R_NS ({s['n_N']} x {s['n_S']}) product {1e3 * s['R_NS']:.2f} ms, "
                  f"S_from_N product {1e3 * s['S_from_N']:.2f} ms")
    print(f"\nload average at end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()

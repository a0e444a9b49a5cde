"""The performance table of issue 15, measured in one run on this machine.

    python benchmarks/performance.py                 # every row (several minutes on 2 cores)
    python benchmarks/performance.py --skip fine tests refined   # leave out the longest rows
    python benchmarks/performance.py --only cold compile --no-doc  # the start-up rows alone

The table is printed and written to docs/performance/performance.md (--no-doc: printed only).

Every case runs in its own process (peak memory is that process's max RSS). "issue 15 measured" is the figure
the issue measured before the work on it; "measured" is this run. The machine's load (1-minute
load average) is printed before and after: on a shared machine every wall time grows with it,
so compare rows of one run, and rerun when the load was high.

"Warm" means measured in a process that compiled no kernel itself: every measured process
watches numba's compile events (benchmarks/warmth.py). A warm row's case is run once first and
that run discarded when it compiled (a scene whose signatures no earlier run cached, a cache
made stale by a checkout: 20-95 MB more peak and seconds of CPU); a compile in a process that is
kept is named under the table, and the cold `fault-screen run` names the kernels it compiled in
its own process (those fault_screen.compile_ahead's children did not).

Rows (keys for --skip in brackets):
- [replay] the calibrated Rustrel scene (280 steps of 5 s), warm: a new process with numba's
  cache in place, Simulation built, run and its Result made; median wall per step from the
  stepper's progress callback; peak memory of that process. Then the same run again in a
  process that made it once before (its kernels loaded from the cache and their first calls
  made: what a run costs inside a long-lived process such as the monitor).
- [cold] the first `fault-screen run` (bundled scene, result written) in a new process with an
  empty numba cache (JIT compilation included: fault_screen.compile_ahead's child processes,
  their CPU time and largest peak memory), then three more with that cache (best and
  slowest); a warm `fault-screen run` as a whole process, five times with fault_screen's
  bytecode read from its .pyc files (as an installed package) and five times compiled from its
  sources in each process (as with PYTHONDONTWRITEBYTECODE set before any process wrote them);
  where a warm `fault-screen run` spends its time (imports, numba's cache loads of the kernels,
  the rest), timed inside one process, and the same finer: the interpreter's start and exit
  (`python -c pass`), each import group (IMPORT_GROUPS) and each part of the run (RUN_PARTS:
  scene, set-up, discretisation, assembly, result file, steps, first factorisation, screening,
  writes, close, read-back, summary) without the cache loads inside it; `fault-screen --help`
  in a new process. Every other
  process of this script runs with the bytecode written (PYTHONDONTWRITEBYTECODE removed).
- [compile] the first `fault-screen run` again, in-process with a listener on numba's compile
  event (benchmarks/cold_compile.py): the CPU time of the compilation, the number of kernels
  compiled, the three that take longest, the process's peak memory.
- [busy] the warm replay again while two CPU-bound processes run (3 processes on 2 cores), right
  after the same replay alone, with the default BLAS threading (no OPENBLAS_NUM_THREADS set) and
  with OPENBLAS_NUM_THREADS=1: wall against the isolated run, CPU against the isolated run's
  (threads spinning would raise it) and the share of a core the run got (CPU / wall).
- [slip] each fluid-driven-slip verification scene at bundled resolution, warm, and its slip
  error against the reference (relative L2 at the end, as tests/verification/test_verification_*.py).
- [refined] Rustrel on a 200 x 201 mesh (4x refinement), whole run.
- [fine] the 30 deg T = 0.7 scene at half its element size, whole run.
- [stepsize] the paper-units calibrated Rustrel scene with growing steps (growth 1.2, dt_max
  600 s) and 3 h of shut-in after its 1400 s: the median wall of a step right after a step-size
  change against that of a step at an unchanged size (the ratio; target <= 3x), and the whole
  run's wall time against the plain 1400-s run's (target <= 2x). One run has only 13 steps at
  an unchanged size: the run is made GROWING_RUNS times, the steps pooled, each run's ratio
  printed beside the pooled one, in wall and in CPU time, with the changed step's parts
  (re-preparation, numeric factorisation, condensed LU, Newton iterations), and the Newton
  iterations of the changed steps solved again from the same states at their own size and at
  the previous step's (``growing_iterations``). The bundled scene sets ``time.theta_min`` (the
  theta ladder: a step whose size stays in its rung keeps the bulk's factors). Like for like:
  the same ratio over the changed and unchanged steps that took the unchanged steps' usual
  number of Newton iterations; and the changed steps inside a rung (the bulk's factors kept)
  apart from those that start a rung (new factors, made in place or ahead in a thread beside
  the rung before: see ``benchmarks/rung_switch.py``).
- [tests] `python -m pytest -q` (the README's test command), wall time.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the source tree whose fault_screen a case runs (benchmarks/before_after.py sets it to a
#: checkout of another revision); the scenes and these scripts are this tree's
TREE = Path(os.environ.get("FAULT_SCREEN_TREE", ROOT))
sys.path.insert(0, str(TREE))
sys.path.insert(0, str(ROOT / "benchmarks"))
import warmth  # noqa: E402
from patching import Patches  # noqa: E402
RUSTREL = ROOT / "configs" / "rustrel-2015-calibrated.toml"
PAPER = ROOT / "configs" / "rustrel-2015-calibrated-paper-units.toml"
SLIP_SCENES = ["fluid-driven-slip-T0.4-horizontal", "fluid-driven-slip-T0.4-dip30",
               "fluid-driven-slip-T0.7-horizontal", "fluid-driven-slip-T0.7-dip30"]
#: a case that runs longer than this is stopped and reported as such (s)
CASE_TIMEOUT = 600
#: runs of the [stepsize] scene, their steps pooled (one run has 13 steps at an unchanged size)
GROWING_RUNS = 3
#: the rows' keys (--skip, --only)
ROWS = ["replay", "cold", "compile", "busy", "slip", "refined", "fine", "stepsize", "tests"]


# ------------------------------------------------------------------ cases (in a child process)
def _scene(case: str):
    from fault_screen import Scene

    if case == "rustrel":
        return Scene.from_toml(RUSTREL)
    if case == "rustrel-200x201":
        s = Scene.from_toml(RUSTREL)
        return s.replace(mesh=replace(s.mesh, nx=200, ny=201))
    if case == "paper-growing":
        s = Scene.from_toml(PAPER)
        return s.replace(time=replace(s.time, growth=1.2, dt_max=600.0, end=s.time.end + 3 * 3600.0))
    if case == "paper":
        return Scene.from_toml(PAPER)
    if case == "fine-T0.7-dip30":
        from verification_cost import scaled_scene

        return scaled_scene("fluid-driven-slip-T0.7-dip30", 0.5)
    return Scene.from_toml(ROOT / "configs" / "verification" / f"{case}.toml")


def run_case(case: str) -> dict:
    """A case in this process, with what numba compiled in it (``compiled``: [] when warm)."""
    compiled = warmth.watch()
    out = _run_case(case)
    out["compiled"] = compiled
    return out


def _run_case(case: str) -> dict:
    import numpy as np

    from fault_screen import Simulation

    if case == "paper-growing":
        return run_growing()
    if case == "paper-growing-iterations":
        return growing_iterations()
    if case.endswith("-second"):   # the same run again in this process, its kernels loaded
        case = case[: -len("-second")]
        first = Simulation(_scene(case))
        first.advance(first.scene.time.end)
        first.result()
        del first
    scene = _scene(case)
    walls, step_sizes = [], []

    def progress(step, t, end, wall):
        walls.append(time.perf_counter())
        step_sizes.append(sim.last_row["dt"])

    t0, c0 = time.perf_counter(), time.process_time()
    sim = Simulation(scene)
    sim.advance(scene.time.end, progress=progress)
    result = sim.result()
    total = time.perf_counter() - t0
    out = dict(case=case, wall=total, cpu=time.process_time() - c0, dofs=sim.disc.n_dofs,
               steps=len(result.time) - 1,
               newton=int(result.solver["iterations"].sum()),
               step_ms=1e3 * float(np.median(np.diff(walls))) if len(walls) > 1 else float("nan"),
               peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    # each step's wall after the first; a step whose size differs from the last one's "changed"
    step_walls, sizes = np.diff(walls), np.asarray(step_sizes[1:])
    changed = sizes != np.asarray(step_sizes[:-1])
    if changed.any() and (~changed).any():
        out.update(changed_ms=1e3 * float(np.median(step_walls[changed])),
                   unchanged_ms=1e3 * float(np.median(step_walls[~changed])),
                   n_changed=int(changed.sum()), n_unchanged=int((~changed).sum()))
    if case.startswith("fluid-driven-slip") or case == "fine-T0.7-dip30":
        from verification_cost import error_against_reference

        name = "fluid-driven-slip-T0.7-dip30" if case == "fine-T0.7-dip30" else case
        out["error"] = error_against_reference(name, scene, result, sim.disc, [])[1]
    return out


def run_growing() -> dict:
    """The [stepsize] row's run (paper-units Rustrel, growing steps), each step's wall and CPU
    time (the process's, both factorisation threads) with its parts: the re-preparation of the
    linear system at a new step size (``CondensedSystem.prepare``), within it the numeric
    factorisation (``bordered_lu``: the values written into the fixed pattern and the L D L^T),
    and the condensed block's dense LU (``CondensedSolver._factorise``, which a new step size
    may also need); a step "changed" when its size differs from the last one's."""
    import numpy as np

    from fault_screen import Simulation
    import fault_screen.linear_system as ls

    spent = dict(prepare=[0.0, 0.0], factorise=[0.0, 0.0], condensed_lu=[0.0, 0.0])

    def timed(name, fn):
        def wrapper(*args, **kwargs):
            t, c = time.perf_counter(), time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[name][0] += time.perf_counter() - t
                spent[name][1] += time.process_time() - c
        return wrapper

    ls.CondensedSystem.prepare = timed("prepare", ls.CondensedSystem.prepare)
    ls.bordered_lu = timed("factorise", ls.bordered_lu)
    ls.CondensedSolver._factorise = timed("condensed_lu", ls.CondensedSolver._factorise)
    scene = _scene("paper-growing")
    steps = []   # per step: dt, wall, CPU, then each part's wall and CPU (s)

    def progress(step, t, end, wall):
        now = (time.perf_counter(), time.process_time())
        parts = [x for name in ("prepare", "factorise", "condensed_lu") for x in spent[name]]
        steps.append([sim.last_row["dt"], now[0] - last[0], now[1] - last[1], *parts,
                      sim.last_row["theta"]])
        for v in spent.values():
            v[:] = [0.0, 0.0]
        last[:] = now

    t0, c0 = time.perf_counter(), time.process_time()
    sim = Simulation(scene)
    last = [time.perf_counter(), time.process_time()]
    for v in spent.values():   # (the model's set-up is not the first step's)
        v[:] = [0.0, 0.0]
    sim.advance(scene.time.end, progress=progress)
    result = sim.result()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    iterations = np.asarray(result.solver["iterations"])[-len(steps):]
    return dict(case="paper-growing", wall=wall, cpu=cpu, steps=steps,
                iterations=iterations.tolist(), theta=scene.time.theta)


def growing_iterations() -> dict:
    """Newton iterations of each changed step of the [stepsize] run solved twice more from the
    same state, with the same extrapolated first guess made for each size: at its own size and
    at the previous step's (an unchanged size). Equal counts say that the changed steps' extra
    iterations are the run's phase (injection, early shut-in), not the change. (Not timed: the
    extra solves refactorise.)"""
    from fault_screen import Simulation
    import fault_screen.stepper as stepper

    take = stepper.Simulation._step
    counts = dict(own=[], previous=[])
    last = []

    def step(self, dt, step_value):
        if last and dt != last[-1]:
            for key, size in (("own", dt), ("previous", last[-1])):
                guess, combination = self._extrapolated_guess(size)
                counts[key].append(self.solver.step(self.x, self.history, size, step_value,
                                                    x0=guess, combination=combination,
                                                    **self._time_weight(size)).iterations)
        last.append(dt)
        return take(self, dt, step_value)

    stepper.Simulation._step = step
    scene = _scene("paper-growing")
    sim = Simulation(scene)
    sim.advance(scene.time.end)
    return dict(case="paper-growing-iterations", **counts)


def growing_summary(runs: list[dict]) -> dict:
    """The [stepsize] row's numbers from ``run_growing`` runs: the steps after the first of
    each run (its first step pays the first factorisation), changed or not, pooled over the
    runs; each run's own ratio of the medians."""
    import numpy as np

    def split(run):
        a = np.asarray(run["steps"], dtype=float)
        its = np.asarray(run["iterations"], dtype=float)
        changed = a[1:, 0] != a[:-1, 0]
        return a[1:], its[1:], changed

    per_run, pooled_changed, pooled_unchanged, its_changed, its_unchanged = [], [], [], [], []
    for run in runs:
        a, its, changed = split(run)
        per_run.append((np.median(a[changed, 1]) / np.median(a[~changed, 1]),
                        np.median(a[changed, 2]) / np.median(a[~changed, 2])))
        pooled_changed.append(a[changed])
        pooled_unchanged.append(a[~changed])
        its_changed.append(its[changed])
        its_unchanged.append(its[~changed])
    ch, un = np.concatenate(pooled_changed), np.concatenate(pooled_unchanged)
    its_ch, its_un = np.concatenate(its_changed), np.concatenate(its_unchanged)
    med = lambda x: 1e3 * float(np.median(x)) if len(x) else float("nan")   # noqa: E731 (ms)
    # like for like: the changed and unchanged steps that took the unchanged steps' most common
    # number of Newton iterations (the changed ones are the busier phase's, see the row)
    counts = np.bincount(its_un.astype(int))
    usual = int(np.argmax(counts))
    # a changed step inside a rung of the theta ladder (a weight below the scene's: the bulk's
    # factors kept) and one that starts a rung (the scene's weight: factors of a new size, made
    # in place or ahead beside the rung before, so not told apart by the factorisation's time)
    refactorised = ch[:, 9] == runs[0]["theta"]
    return dict(
        n_runs=len(runs), n_changed=len(ch), n_unchanged=len(un),
        changed_ms=med(ch[:, 1]), unchanged_ms=med(un[:, 1]),
        changed_cpu_ms=med(ch[:, 2]), unchanged_cpu_ms=med(un[:, 2]),
        ratios=[r[0] for r in per_run], cpu_ratios=[r[1] for r in per_run],
        # the changed step's parts (medians of each, CPU): re-preparation, of it the numeric
        # factorisation, the condensed LU; Newton iterations (mean) changed and not
        prepare_cpu_ms=med(ch[:, 4]), factorise_cpu_ms=med(ch[:, 6]),
        condensed_lu_cpu_ms=med(ch[:, 8]),
        newton_changed=float(np.mean(np.concatenate(its_changed))),
        newton_unchanged=float(np.mean(np.concatenate(its_unchanged))),
        usual_iterations=usual,
        like_changed_ms=med(ch[its_ch == usual, 1]), like_unchanged_ms=med(un[its_un == usual, 1]),
        n_like_changed=int(np.sum(its_ch == usual)), n_like_unchanged=int(np.sum(its_un == usual)),
        n_refactorised=int(np.sum(refactorised)), refactorised_ms=med(ch[refactorised, 1]),
        kept_ms=med(ch[~refactorised, 1]),
        wall=float(np.median([r["wall"] for r in runs])))


#: the import groups of a warm `fault-screen run`, imported one after the other in this order
#: (a later group's time leaves out what an earlier one imported: numba imports part of scipy)
IMPORT_GROUPS = [("the CLI (click)", ["click", "fault_screen.cli"]),
                 ("numpy", ["numpy"]),
                 ("scipy (sparse, linalg)", ["scipy.sparse", "scipy.linalg"]),
                 ("numba", ["numba"]),
                 ("h5py", ["h5py"]),
                 ("fault_screen's model modules", ["fault_screen.api", "fault_screen.cli.run",
                                                   "fault_screen.cli._running", "fault_screen.result_stream"])]

#: the parts of a warm `fault-screen run` timed in one process: (name, module, attribute of the
#: function timed); a part's time leaves out the kernels' cache loads inside it and the parts
#: nested in it (those that follow it here and run within it)
RUN_PARTS = [("scene load and validation", "fault_screen.cli.run", "load_scene"),
             ("model set-up", "fault_screen.stepper", "Simulation.__init__"),
             ("mesh and discretisation", "fault_screen.stepper", "discretise"),
             ("constant matrices", "fault_screen.solver", "assemble_constant"),
             ("result file created", "fault_screen.result_stream", "ResultWriter.create"),
             ("steps", "fault_screen.api", "_screened_run"),
             ("first factorisation (ordering, symbolic, numeric)", "fault_screen.linear_system",
              "CondensedSystem._factorise_held"),
             ("step screening", "fault_screen.screening.stepwise", "StepScreening.screen_simulation"),
             ("result file closed", "fault_screen.stepper", "Simulation.close_stream"),
             ("result read back", "fault_screen.result", "ResultFile.view"),
             ("result read back", "fault_screen.result", "ResultFile.maximum"),
             ("result read back", "fault_screen.cli._running", "slip_split"),
             ("summary", "fault_screen.cli._running", "_summary"),
             ("result rows written (during the steps and at the close)", "fault_screen.result_stream",
              "ResultWriter._write")]


def _timed_parts(parts, record, patches):
    """Wrap each of ``parts`` (RUN_PARTS) by ``patches`` so that its calls append (name, start,
    end, cpu start, cpu end) to ``record``."""
    import functools

    def timing(name):
        def make(func):
            @functools.wraps(func)
            def wrapped(*args, **kw):
                t, c = time.perf_counter(), time.process_time()
                try:
                    return func(*args, **kw)
                finally:
                    record.append((name, t, time.perf_counter(), c, time.process_time()))
            return wrapped
        return make

    for name, module, attr in parts:
        patches.replace(module, attr, timing(name))


def _union(spans):
    """The union of the intervals (a, b) as a sorted list of disjoint intervals."""
    out = []
    for a, b in sorted(spans):
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return out


def _overlap(a, b, union):
    return sum(max(0.0, min(b, y) - max(a, x)) for x, y in union)


def run_split() -> dict:
    """Where a warm `fault-screen run` of the bundled scene spends its time, in one process:
    the imports by group (IMPORT_GROUPS), numba's cache loads of the kernels (each kernel's first
    call), and the run's parts (RUN_PARTS), each without the cache loads and parts inside it;
    "other" is what no part covers (the command's own code, the CLI's checks, the collector)."""
    import importlib

    t0, c0 = time.perf_counter(), time.process_time()
    groups = []
    for label, modules in IMPORT_GROUPS:
        a, ca = time.perf_counter(), time.process_time()
        for m in modules:
            importlib.import_module(m)
        groups.append((label, time.perf_counter() - a, time.process_time() - ca))
    import fault_screen.cli
    t1, c1 = time.perf_counter(), time.process_time()
    from numba.core.dispatcher import Dispatcher
    compiled = warmth.watch()   # (after the imports it times; numba is imported by then)

    spans, loaded, parts = [], set(), []

    def timing(compile_):
        def timed(self, sig):
            start, cpu = time.perf_counter(), time.process_time()
            try:
                return compile_(self, sig)
            finally:
                spans.append((start, time.perf_counter(), cpu, time.process_time()))
                loaded.add(self.py_func)
        return timed

    with tempfile.TemporaryDirectory() as tmp, Patches() as patches:
        patches.replace(Dispatcher, "compile", timing)
        _timed_parts(RUN_PARTS, parts, patches)
        fault_screen.cli.main(["run", "--out", str(Path(tmp) / "r.h5"), "--quiet"],
                              prog_name="fault-screen", standalone_mode=False)
    t2, c2 = time.perf_counter(), time.process_time()
    # a kernel that two threads call first is asked for twice, the second waiting for the
    # first's load: the time is that of the spans' union
    loads = [tuple(x) for x in _union([sp[:2] for sp in spans])]
    # each part's own time: its calls' union less the kernel loads and later parts inside it;
    # its own CPU time (the process's, every thread's): its calls' less that of the outermost
    # kernel loads and later parts inside each call
    order = list(dict.fromkeys(name for name, _, _ in RUN_PARTS))
    own, own_cpu = {}, {}
    for i, name in enumerate(order):
        mine = _union([(a, b) for n, a, b, _, _ in parts if n == name])
        later = [p[1:] for p in parts if p[0] in order[i + 1:]] + spans
        inside = _union(loads + [(a, b) for a, b, _, _ in later])
        own[name] = sum(b - a - _overlap(a, b, inside) for a, b in mine)
        own_cpu[name] = sum(cb - ca - _outermost_cpu(a, b, later)
                            for n, a, b, ca, cb in parts if n == name)
    kernels = sum(b - a for a, b in loads)
    kernels_cpu = _outermost_cpu(t1, t2, spans)
    rest = t2 - t1
    return dict(imports=t1 - t0, import_groups=groups, kernels=kernels, n_kernels=len(loaded),
                first_kernel=(loads[0][1] - loads[0][0]) if loads else 0.0, parts=own,
                parts_cpu=own_cpu, kernels_cpu=kernels_cpu,
                other=rest - kernels - sum(own.values()), rest=rest - kernels, total=t2 - t0,
                cpu_imports=c1 - c0, cpu=c2 - c0, compiled=compiled)


def _outermost_cpu(a, b, items) -> float:
    """The CPU time of the items (wall start, wall end, CPU start, CPU end) inside the wall
    interval (a, b) that no other of them contains."""
    inside = sorted((x for x in items if a <= x[0] and x[1] <= b), key=lambda x: (x[0], -x[1]))
    total, end = 0.0, -float("inf")
    for x in inside:
        if x[1] <= end:
            continue   # inside one counted already
        total += x[3] - x[2]
        end = x[1]
    return total


def interpreter_start(env) -> float:
    """Wall time (s) of a fresh `python -c pass` (the interpreter's start and exit, site included)."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], env=env, check=True)
    return time.perf_counter() - t0


def child(case: str, env=None, timeout=CASE_TIMEOUT) -> dict:
    try:
        out = subprocess.run([sys.executable, __file__, "--case", case], capture_output=True,
                             text=True, cwd=ROOT, env=env, timeout=timeout)
    except subprocess.TimeoutExpired:
        return dict(case=case, timeout=timeout)
    if out.returncode != 0:
        raise RuntimeError(f"{case}: {out.stderr.strip()[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def cli_run(env) -> dict:
    """`fault-screen run` of the bundled scene in a new process: its wall time (s), peak memory
    (MB), what numba compiled in it (``compiled``) and its child processes' largest peak memory
    (MB) and CPU time (s) (at a cold start: those of fault_screen.compile_ahead)."""
    with tempfile.TemporaryDirectory() as tmp:
        code = (f"import sys; sys.path.insert(0, {str(ROOT / 'benchmarks')!r}); import warmth; "
                "compiled = warmth.watch(); import atexit, json, resource; "
                "atexit.register(lambda: print('COMPILED', json.dumps(compiled), file=sys.stderr)); "
                "atexit.register(lambda: print('MAXRSS', resource.getrusage("
                "resource.RUSAGE_SELF).ru_maxrss, *(lambda c: (c.ru_maxrss, c.ru_utime + c.ru_stime))("
                "resource.getrusage(resource.RUSAGE_CHILDREN)), file=sys.stderr)); "
                "from fault_screen.cli import main; sys.argv[0] = 'fault-screen'; main()")
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", code, "run", "--out", str(Path(tmp) / "r.h5"), "--quiet"],
                             capture_output=True, text=True, cwd=tmp, env=env, timeout=CASE_TIMEOUT)
        wall = time.perf_counter() - t0
    if out.returncode != 0:
        raise RuntimeError(out.stderr)
    last = {line.split(maxsplit=1)[0]: line.split(maxsplit=1)[1] for line in out.stderr.splitlines()
            if line.startswith(("MAXRSS", "COMPILED"))}
    rss = last["MAXRSS"].split()
    return dict(wall=wall, peak_mb=float(rss[0]) / 1024.0, children_mb=float(rss[1]) / 1024.0,
                children_cpu=float(rss[2]), compiled=json.loads(last["COMPILED"]))


#: the child's first lines when it is to start as from a tree without fault_screen's bytecode
#: (as in an environment with PYTHONDONTWRITEBYTECODE set, where no process ever wrote it): the
#: package's modules compiled from their sources, every other module read from its .pyc
_SOURCE_ONLY = ("import importlib.machinery as m, os, sys\n"
                "_stats = m.SourceFileLoader.path_stats\n"
                "def _no_bytecode(self, path, _pkg=os.path.join({tree!r}, 'fault_screen', '')):\n"
                "    if path.startswith(_pkg):\n"
                "        raise OSError('read from the source')\n"
                "    return _stats(self, path)\n"
                "m.SourceFileLoader.path_stats = _no_bytecode\n")


def cli_run_warm(env, bytecode: bool, repeat: int = 5) -> tuple[list[float], float, list]:
    """Wall times (s) of ``repeat`` warm `fault-screen run` processes of the bundled scene
    (numba's cache in place), sorted: with fault_screen's bytecode read from its .pyc files as
    a user's installed package has them, or (``bytecode=False``) compiled from the sources in
    every process; the median wall time (s) from the command's end (``main()`` leaving) to
    the process's (the interpreter's teardown); and what numba compiled in the processes (a
    cache miss: [] when they were warm)."""
    code = ("" if bytecode else _SOURCE_ONLY.format(tree=str(TREE))) + \
        (f"import sys, time, json\nsys.path.insert(0, {str(ROOT / 'benchmarks')!r})\nimport warmth\n"
         "compiled = warmth.watch()\nfrom fault_screen.cli import main\nsys.argv[0] = 'fault-screen'\n"
         "try:\n    main()\nfinally:\n    print('COMMAND-END', time.time(), json.dumps(compiled), "
         "file=sys.stderr)\n")
    walls, ends, compiled = [], [], []
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            out = subprocess.run([sys.executable, "-c", code, "run", "--out", str(Path(tmp) / "r.h5"), "--quiet"],
                                 capture_output=True, text=True, cwd=tmp, env=env, timeout=CASE_TIMEOUT,
                                 check=True)
            end = time.time()
            walls.append(time.perf_counter() - t0)
        _, at, names = [x for x in out.stderr.splitlines() if x.startswith("COMMAND-END")][-1].split(maxsplit=2)
        ends.append(end - float(at))
        compiled += json.loads(names)
    return sorted(walls), sorted(ends)[len(ends) // 2], compiled


def cli_help(env) -> float:
    """Wall time (s) of `fault-screen --help` in a fresh process."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "from fault_screen.cli import main; main(['--help'])"],
                   capture_output=True, text=True, cwd=ROOT, env=env, timeout=CASE_TIMEOUT, check=True)
    return time.perf_counter() - t0


def _env(tree=ROOT, **extra):
    """The environment of a case's process: default BLAS threading, ``tree``'s fault_screen,
    Python's bytecode cache on (an installed package has its .pyc files; with
    PYTHONDONTWRITEBYTECODE set, every start would compile fault_screen's sources again, about
    0.1 s of CPU counted as imports)."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "PYTHONDONTWRITEBYTECODE")}
    env["PYTHONPATH"] = str(tree) + os.pathsep + env.get("PYTHONPATH", "")
    env["FAULT_SCREEN_TREE"] = str(tree)
    env.update(extra)
    return env


# ------------------------------------------------------------------ table
def _s(seconds):
    return f"{seconds:.2f} s"


def _ms(seconds):
    return f"{1e3 * seconds:.0f} ms"


def _wc(r):
    """Wall and CPU time of a case (CPU: the process's own, user + system)."""
    return f"{_s(r['wall'])} (CPU {_s(r['cpu'])})"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--skip", nargs="*", default=[], choices=ROWS)
    ap.add_argument("--only", nargs="*", choices=ROWS,
                    help="measure these rows alone (e.g. --only cold compile --no-doc)")
    ap.add_argument("--case", help=argparse.SUPPRESS)
    ap.add_argument("--no-doc", action="store_true", help="do not write docs/performance/performance.md")
    args = ap.parse_args()
    if args.only:
        args.skip = [r for r in ROWS if r not in args.only]
    if args.case:
        print(json.dumps(run_split() if args.case == "split" else run_case(args.case)), flush=True)
        return
    rows = []

    def row(what, now, target, measured):
        rows.append((what, now, target, measured))
        print(f"  {what}: {measured}", file=sys.stderr, flush=True)

    load0 = os.getloadavg()[0]
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    env = _env()
    notes = []   # what compiled in a measured process (printed under the table)

    def warm(case, case_env=env):
        """A case's child run measured warm (a run that compiled discarded, run again)."""
        r, note = warmth.measure_warm(lambda c: child(c, case_env), case)
        if note:
            notes.append(f"{case}: {note}")
            print(f"    ({case}: {note})", file=sys.stderr, flush=True)
        return r

    def checked(case, r):
        """``r`` as measured, its compilations (if any) noted: its row is then not warm."""
        if r.get("compiled"):
            notes.append(f"{case}: NOT WARM: {warmth.describe(r['compiled'])}")
        return r

    if "replay" not in args.skip:
        warm("rustrel")   # numba's cache in place for the warm rows (the first run discarded)
        runs = [checked("rustrel", child("rustrel", env)) for _ in range(3)]
        r = min(runs, key=lambda r: r["wall"])
        row("calibrated Rustrel replay, warm, 1 process", "2.9 s", "<= 1.0 s",
            f"{_wc(r)} ({r['dofs']} unknowns, {r['steps']} steps, {r['newton']} Newton)")
        row("median wall per step, Rustrel", "~10 ms", "<= 3 ms", f"{r['step_ms']:.1f} ms")
        r2 = min((checked("rustrel-second", child("rustrel-second", env)) for _ in range(3)),
                 key=lambda r: r["wall"])
        row("calibrated Rustrel replay, the second run in one process (kernels loaded)", "-",
            "<= 1.0 s", f"{_wc(r2)}; median wall per step {r2['step_ms']:.1f} ms")
        warm_mb = "-".join(sorted({f"{x['peak_mb']:.0f}" for x in runs}, key=float))
        warm_what = "warm (3 runs, no kernel compiled in their process)" if not any(
            x["compiled"] for x in runs) else "NOT WARM (kernels compiled in the process: see below)"
        row("peak memory of the process, Rustrel (cold: compilation included; warm: none)", "264 MB",
            "<= 300 MB", f"{warm_mb} MB {warm_what}")
    if "cold" not in args.skip:
        with tempfile.TemporaryDirectory() as cache:
            first = cli_run(_env(NUMBA_CACHE_DIR=cache))
            later = [cli_run(_env(NUMBA_CACHE_DIR=cache)) for _ in range(3)]
        for x in later:
            checked("`fault-screen run` after the cold one", x)
        own = warmth.kernels(first["compiled"])
        walls = sorted(x["wall"] for x in later)
        row("cold: first `fault-screen run` in a fresh process (JIT included)", "~10 s",
            "<= 10 s; <= 3 s from the second process on",
            f"{_s(first['wall'])} (kernels compiled ahead by child processes, one per core: CPU "
            f"{_s(first['children_cpu'])}, peak memory {first['children_mb']:.0f} MB each at most; "
            f"compiled in the run's own process: {len(own)} kernels"
            f"{' (' + ', '.join(k.removeprefix('fault_screen.') for k in own) + ')' if own else ''}); "
            f"later processes {_s(walls[0])} (best of 3; slowest {_s(walls[-1])})")
        if "replay" not in args.skip:
            at = next(i for i, w in enumerate(rows) if w[0].startswith("peak memory of the process"))
            later_mb = "-".join(sorted({f"{x['peak_mb']:.0f}" for x in later}, key=float))
            rows[at] = rows[at][:3] + (
                f"{first['peak_mb']:.0f} MB cold (`fault-screen run`, {len(own)} kernels compiled in "
                f"its process); {later_mb} MB the next 3 `fault-screen run` (warm); {rows[at][3]}",)
        split = min([warm("split")] + [checked("split", child("split", env)) for _ in range(2)],
                    key=lambda r: r["total"])
        row("where a warm `fault-screen run` spends its time (in one process, best of 3)", "~1.1 s imports, "
            "~0.8 s 24 kernels, ~2 s the rest", "<= 2 s in all",
            f"{_s(split['total'])} (CPU {_s(split['cpu'])}): imports {_s(split['imports'])} "
            f"(CPU {_s(split['cpu_imports'])}), numba's cache loads "
            f"{_s(split['kernels'])} ({split['n_kernels']} kernels; the first, with numba's own set-up, "
            f"{_s(split['first_kernel'])}), scene, model, steps and result {_s(split['rest'])}")
        starts = sorted(interpreter_start(env) for _ in range(5))
        row("the same split, finer (imports in the order listed, each group without what an earlier "
            "one imported; each part without the cache loads and the parts inside it; CPU: the process's, every thread's)", "-", "-",
            f"interpreter start and exit (`python -c pass`, best of 5) {_ms(starts[0])}; imports: "
            + ", ".join(f"{label} {_ms(t)} (CPU {_ms(c)})" for label, t, c in split["import_groups"])
            + f"; numba's cache loads {_ms(split['kernels'])} (CPU {_ms(split['kernels_cpu'])}); "
            + ", ".join(f"{name} {_ms(t)} (CPU {_ms(split['parts_cpu'][name])})"
                        for name, t in split["parts"].items())
            + f", other {_ms(split['other'])}")
        (with_pyc, teardown, c1), (from_source, _, c2) = cli_run_warm(env, True), cli_run_warm(env, False)
        checked("warm `fault-screen run`", dict(compiled=c1 + c2))
        row("warm `fault-screen run`, whole process (bundled scene, numba's cache in place; best and "
            "median of 5)", "4.1 s median", "<= 2 s",
            f"{_s(with_pyc[0])}, median {_s(with_pyc[2])} with fault_screen's bytecode (.pyc) as an "
            f"installed package has it (of which {_s(teardown)}, median, from the command's end to the "
            f"process's); {_s(from_source[0])}, median {_s(from_source[2])} compiling "
            "fault_screen's modules from source in each process (PYTHONDONTWRITEBYTECODE set from "
            "the start)")
        helps = sorted(cli_help(env) for _ in range(3))
        row("`fault-screen --help` in a fresh process (imports no model)", "-", "-",
            f"{_s(helps[0])} (best of 3; slowest {_s(helps[-1])})")
    if "compile" not in args.skip:
        from cold_compile import measure

        c = measure()
        kernels = [k for k in c["compiles"] if k["depth"] == 0]
        top = sorted(kernels, key=lambda k: -k["cpu"])[:3]
        row("cold: numba's compilation in the first `fault-screen run` (CPU time: compilation is "
            "CPU-bound, so this hardly depends on the load)", "-", "-",
            f"{_s(c['compile_cpu'])} CPU of the process's {_s(c['cpu'])} ({len(kernels)} kernels; most: "
            + ", ".join(f"{k['kernel'].removeprefix('fault_screen.')} {_s(k['cpu'])}" for k in top)
            + f"); peak memory {c['peak_mb']:.0f} MB (`python benchmarks/cold_compile.py`: every kernel)")
    if "busy" not in args.skip:
        # isolated and busy back to back, the BLAS threads as the user has them and forced to one:
        # the CPU time shows whether threads spin (CPU above the isolated run's), the CPU share
        # (CPU / wall) what the scheduler gave the run
        for label, case_env in (("default BLAS threads", env),
                                ("OPENBLAS_NUM_THREADS=1", _env(OPENBLAS_NUM_THREADS="1"))):
            alone = warm("rustrel", case_env)
            hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
            try:
                time.sleep(0.5)
                b = checked("rustrel (busy)", child("rustrel", case_env))
                load_busy = os.getloadavg()[0]
            finally:
                for h in hogs:
                    h.kill()
                    h.wait()
            row(f"Rustrel warm with 2 competing CPU-bound processes ({label})", "8.6-41 s",
                "<= 2.5x the isolated time",
                f"{_wc(b)} = {b['wall'] / alone['wall']:.1f}x isolated ({_wc(alone)} just before); CPU "
                f"{b['cpu'] / alone['cpu']:.2f}x isolated; CPU share {b['cpu'] / b['wall']:.2f} of a core "
                f"(load average {load_busy:.1f} at its end; 3 equal processes on 2 cores alone would "
                f"get 0.67)")
    if "slip" not in args.skip:
        for name in SLIP_SCENES:
            s = warm(name)
            short = name.replace("fluid-driven-slip-", "")
            if "timeout" in s:
                row(f"fluid-driven slip {short}, bundled resolution", "7-45 s", "<= 5 s, same accuracy",
                    f"> {s['timeout']} s (stopped)")
                continue
            row(f"fluid-driven slip {short}, bundled resolution", "7-45 s", "<= 5 s, same accuracy",
                f"{_wc(s)}, slip L2 error {100 * s['error']:.2f} % ({s['dofs']} unknowns)")
    if "refined" not in args.skip:
        s = warm("rustrel-200x201")
        row("Rustrel at 4x refinement (200 x 201)", "-", "<= 20 s, <= 1 GB",
            f"> {s['timeout']} s (stopped)" if "timeout" in s else
            f"{_wc(s)}, {s['peak_mb']:.0f} MB ({s['dofs']} unknowns)")
    if "fine" not in args.skip:
        s = warm("fine-T0.7-dip30")
        row("fine inclined fault (30 deg T = 0.7, half element size)", "151 s, 1.4 GB", "<= 30 s, <= 500 MB",
            f"> {s['timeout']} s (stopped)" if "timeout" in s else
            f"{_wc(s)}, {s['peak_mb']:.0f} MB ({s['dofs']} unknowns), slip L2 error {100 * s['error']:.2f} %")
    if "stepsize" not in args.skip:
        plain = warm("paper")
        runs = [warm("paper-growing")] + [checked("paper-growing", child("paper-growing", env))
                                          for _ in range(GROWING_RUNS - 1)]
        iterations = checked("paper-growing-iterations", child("paper-growing-iterations", env))
        theta_min = _scene("paper-growing").time.theta_min
        what = ("step-size change, paper-units Rustrel (growth 1.2, dt_max 600 s, 3 h shut-in"
                + (f", the bundled scene's theta ladder: time.theta_min {theta_min:.3g})"
                   if theta_min is not None else ")"))
        if any("timeout" in g for g in runs):
            row(what, "80x; 31 s", "<= 3x; <= 2x the 1400-s run",
                f"> {CASE_TIMEOUT} s (stopped)")
        else:
            g = growing_summary(runs)
            again = ("" if "timeout" in iterations else
                     f": the {len(iterations['own'])} changed steps solved again take "
                     f"{sum(iterations['own'])} iterations at their size, "
                     f"{sum(iterations['previous'])} at the previous step's")
            spread = lambda r: f"{min(r):.1f}-{max(r):.1f}x"   # noqa: E731
            kept = ("" if g["n_refactorised"] == g["n_changed"] else
                    f"; {g['n_changed'] - g['n_refactorised']} changed steps inside a rung "
                    f"{g['kept_ms']:.1f} ms = {g['kept_ms'] / g['unchanged_ms']:.1f}x, the "
                    f"{g['n_refactorised']} that start a rung {g['refactorised_ms']:.1f} ms = "
                    f"{g['refactorised_ms'] / g['unchanged_ms']:.1f}x")
            like = (f"; like for like ({g['usual_iterations']} Newton iterations each, "
                    f"{g['n_like_changed']} changed and {g['n_like_unchanged']} unchanged steps) "
                    f"{g['like_changed_ms']:.1f} against {g['like_unchanged_ms']:.1f} ms = "
                    f"{g['like_changed_ms'] / g['like_unchanged_ms']:.1f}x")
            row(what, "80x; 31 s", "<= 3x; <= 2x the 1400-s run",
                f"first step after a change {g['changed_ms']:.0f} ms (median of {g['n_changed']}, "
                f"{g['n_runs']} runs pooled) = {g['changed_ms'] / g['unchanged_ms']:.1f}x a step at "
                f"unchanged size ({g['unchanged_ms']:.0f} ms, median of {g['n_unchanged']}); each "
                f"run's ratio {spread(g['ratios'])}{kept}{like}; in CPU time {g['changed_cpu_ms']:.0f} against "
                f"{g['unchanged_cpu_ms']:.0f} ms = {g['changed_cpu_ms'] / g['unchanged_cpu_ms']:.1f}x "
                f"(runs {spread(g['cpu_ratios'])}); the changed step's CPU (medians): "
                f"re-preparation {g['prepare_cpu_ms']:.0f} ms (numeric factorisation "
                f"{g['factorise_cpu_ms']:.0f} ms), condensed LU {g['condensed_lu_cpu_ms']:.1f} ms, "
                f"Newton iterations {g['newton_changed']:.1f} against {g['newton_unchanged']:.1f} "
                f"(means; the changed steps are the injection's and early shut-in's, the unchanged "
                f"ones the late shut-in's{again}); whole run {_s(g['wall'])} (median) = "
                f"{g['wall'] / plain['wall']:.1f}x the 1400-s run ({_s(plain['wall'])})")
    if "tests" not in args.skip:
        t0 = time.perf_counter()
        c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"],
                             capture_output=True, text=True, cwd=ROOT, env=env)
        wall = time.perf_counter() - t0
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime)
        tail = out.stdout.strip().splitlines()[-1] if out.stdout.strip() else "no output"
        row("`python -m pytest -q` on 2 cores", "13.5 min", "<= 3 min",
            f"{wall / 60:.1f} min (CPU {cpu / 60:.1f} min; {tail.strip('= ')})")
    print(f"Measured {started} on {os.cpu_count()} cores; load average {load0:.1f} at the start, "
          f"{os.getloadavg()[0]:.1f} at the end\n")
    table = ["| what | issue 15 measured | target | measured |", "|---|---|---|---|"]
    table += [f"| {what} | {now} | {target} | {measured} |" for what, now, target, measured in rows]
    print("\n".join(table))
    warm_note = ("Warm rows: numba's compilations watched in every measured process; "
                 + ("; ".join(notes) if notes else "none compiled a kernel") + ".")
    print("\n" + warm_note)
    if not args.no_doc:
        from doc_tables import write

        write("performance", "Run costs",
              "Each case runs in its own process (peak memory is that process's max RSS). "
              "\"issue 15 measured\" is what the performance issue measured before the work on it. "
              "Rows left out with `--skip`: " + (", ".join(args.skip) or "none") + ". " + warm_note,
              table, load0)


if __name__ == "__main__":
    main()

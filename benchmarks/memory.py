"""Where the peak memory of a run comes from (issue 28): the libraries, numba's cache loads and
the model's own arrays at the peak, by name.

    python benchmarks/memory.py                          # every case (about a minute, warm)
    python benchmarks/memory.py --cases rustrel fine     # some of them
    python benchmarks/memory.py --tree /tmp/old-checkout # another checkout's fault_screen (A/B)
    python benchmarks/memory.py --repeat 3               # each case 3 times (the peak varies;
                                                         # the table: the largest warm one)

Each case runs in its own process (the peak is that process's max RSS), with numba's cache in
place (run `fault-screen run` once first after a change of the kernels):
- [rustrel] the calibrated Rustrel scene (SI, 280 steps) in-process: Simulation, advance, result
  (the performance table's warm replay row);
- [cli] `fault-screen run` of the bundled paper-units scene, the whole command in-process
  (result streamed to a file, screening, summary), as a user starts it;
- [fine] the 30 deg T = 0.7 scene at half its element size in-process (the performance table's
  [fine] row, without its error against the exact solution);
- [refined] Rustrel on a 200 x 201 mesh in-process (not run unless asked: --cases refined).

For each case the table gives:
- the peak (max RSS) and where the run was when a sampling thread (every 0.5 ms) saw it;
- the libraries' share: the RSS after each import group (numpy; scipy.sparse and scipy.linalg;
  numba, with llvmlite's LLVM; h5py; click and fault_screen's model modules), numba's set-up
  (its target context, made at the first kernel's cache load, with its lowering registries) and
  the cache loads of the model's kernels (``compile_ahead.KERNELS``) after it;
- the model's arrays at the step with the highest RSS after it (the whole peak when that is
  the run's peak, as on the fine scene; else the arrays at the steps' high point): every numpy
  array reachable from the Simulation (and the Result), counted by its resident pages (mincore:
  an array made by calloc whose columns are filled as they are needed counts what is filled),
  grouped by what holds it, the largest by name;
- what glibc's malloc holds freed (mallinfo2's fordblks: heap memory freed by Python and numpy
  but not handed back), and the rest (interpreter objects, numba's code, shared libraries'
  pages, thread stacks).
The RSS by mapping at the end (smaps: llvmlite's LLVM, the other shared libraries, heap and
anonymous memory) closes each case.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import warmth  # noqa: E402 (numba imported only when it starts watching)
from patching import Patches  # noqa: E402
CASES = ["rustrel", "cli", "fine", "refined"]
DEFAULT_CASES = ["rustrel", "cli", "fine"]


# ------------------------------------------------------------------ measuring (in the child)
def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def peak_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class Sampler:
    """The RSS every 0.5 ms from a thread, with the label of what the run was doing."""

    def __init__(self):
        import threading

        self.label = "start"
        self.peak, self.peak_label = 0.0, "start"
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.wait(0.0005):
            r = rss_mb()
            if r > self.peak:
                self.peak, self.peak_label = r, self.label

    def stop(self):
        self._stop.set()
        self._thread.join()


def _mincore():
    import ctypes

    libc = ctypes.CDLL(None, use_errno=True)
    libc.mincore.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_char_p]
    page = os.sysconf("SC_PAGE_SIZE")

    def resident(a) -> int:
        """Bytes of ``a``'s buffer in resident pages (an array smaller than a page: its size
        when its page is resident)."""
        if a.nbytes == 0:
            return 0
        start = a.__array_interface__["data"][0]
        first = start - start % page
        n = (start + a.nbytes - first + page - 1) // page
        vec = ctypes.create_string_buffer(n)
        if libc.mincore(ctypes.c_void_p(first), ctypes.c_size_t(start + a.nbytes - first), vec):
            return a.nbytes
        pages = sum(b & 1 for b in vec.raw)
        return min(a.nbytes, pages * page)
    return resident


def held_arrays(root, name: str) -> dict:
    """{owning buffer id: (shortest path, array)}: every numpy array reachable from ``root``
    through attributes, slots, containers and closures, views counted as their base."""
    import types

    import numpy as np

    seen, found, stack = set(), {}, [(root, name)]
    leaves = (str, bytes, int, float, bool, complex, type(None), types.ModuleType, type)
    while stack:
        obj, path = stack.pop()
        if id(obj) in seen or isinstance(obj, leaves):
            continue
        seen.add(id(obj))
        if isinstance(obj, np.ndarray):
            base = obj
            while isinstance(base.base, np.ndarray):
                base = base.base
            if id(base) not in found or len(path) < len(found[id(base)][0]):
                found[id(base)] = (path, base)
            continue
        if isinstance(obj, dict):
            stack.extend((v, f"{path}[{k!r}]") for k, v in obj.items())
        elif isinstance(obj, (list, tuple, set, frozenset)) or type(obj).__name__ == "deque":
            stack.extend((v, f"{path}[{i}]") for i, v in enumerate(obj))
        elif isinstance(obj, types.FunctionType):
            for var, cell in zip(obj.__code__.co_freevars, obj.__closure__ or ()):
                try:
                    stack.append((cell.cell_contents, f"{path}.<{var}>"))
                except ValueError:
                    pass
        elif isinstance(obj, types.MethodType):
            stack.append((obj.__self__, path))
        else:
            attrs = getattr(obj, "__dict__", None)
            if isinstance(attrs, dict):
                stack.extend((v, f"{path}.{k}") for k, v in attrs.items())
            for slot in getattr(type(obj), "__slots__", ()):
                if isinstance(slot, str) and hasattr(obj, slot):
                    stack.append((getattr(obj, slot), f"{path}.{slot}"))
    return found


#: (path prefix, group) in the order they are tried: what holds the model's arrays
GROUPS = [
    ("sim.solver.system.lu", "bulk factors (packed L, a split bulk's border blocks)"),
    ("sim.solver.system._dense.P", "condensation P (dense n_N x n_N)"),
    ("sim.solver.system._dense.factors", "condensed block's LU (dense n_N x n_N)"),
    ("sim.solver.system._dense._Z", "condensed solver's kept columns (Woodbury)"),
    ("sim.solver.system._dense._T", "condensed solver's kept columns (Woodbury)"),
    ("sim.solver.system._dense._K_R", "condensed solver's kept columns (Woodbury)"),
    ("sim.solver.system._dense._capacitance", "condensed solver's kept columns (Woodbury)"),
    ("sim.solver.system._dense._front", "condensed solver's kept columns (Woodbury)"),
    ("sim.solver.system._dense", "condensed solver's patterns and tangents"),
    ("sim.solver.system._analyses", "LDL^T symbolic analyses"),
    ("sim.solver.system._bulk", "poroelastic bulk's fixed pattern"),
    ("sim.solver._csr_arrays", "constant matrices A, Hf, C"),
    ("sim.solver.system.A", "constant matrices A, Hf, C"),
    ("sim.solver.system.C", "constant matrices A, Hf, C"),
    ("sim.solver.system.Hf", "constant matrices A, Hf, C"),
    ("sim.solver.A", "constant matrices A, Hf, C"),
    ("sim.solver.C", "constant matrices A, Hf, C"),
    ("sim.solver.Hf", "constant matrices A, Hf, C"),
    ("sim.solver", "solver's other arrays (fixed sums, products, indices)"),
    ("sim.recorder.rows", "recorded rows (profiles kept in memory)"),
    ("sim.recorder.last", "recorded rows (profiles kept in memory)"),
    ("sim.writer", "result stream buffers"),
    ("sim.recorder.writer", "result stream buffers"),
    ("result", "Result made from the rows"),
    ("sim", "discretisation and other model arrays"),
]


def arrays_report(roots: dict, top: int = 12) -> dict:
    resident = _mincore()
    found = {}
    for name, root in roots.items():
        for key, (path, a) in held_arrays(root, name).items():
            found.setdefault(key, (path, a))
    groups, named = {}, []
    for path, a in found.values():
        r = resident(a)
        group = next((g for p, g in GROUPS if path.startswith(p)), "other")
        groups[group] = groups.get(group, 0.0) + r / 2**20
        named.append((r / 2**20, a.nbytes / 2**20, path))
    named.sort(reverse=True)
    return dict(groups=sorted(groups.items(), key=lambda kv: -kv[1]), named=named[:top],
                total=sum(groups.values()), count=len(found))


def malloc_free_mb() -> float:
    """Heap memory glibc's malloc holds freed (mallinfo2's fordblks), MB; nan elsewhere."""
    import ctypes

    class MallInfo2(ctypes.Structure):
        _fields_ = [(n, ctypes.c_size_t) for n in (
            "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
            "fordblks", "keepcost")]
    try:
        f = ctypes.CDLL(None).mallinfo2
    except AttributeError:
        return float("nan")
    f.restype = MallInfo2
    return f().fordblks / 2**20


def smaps_mb() -> dict:
    """The RSS by mapping (MB): llvmlite's LLVM, the other shared libraries, heap, the rest."""
    import re

    out = {"llvmlite (LLVM)": 0.0, "other shared libraries": 0.0, "[heap] (malloc)": 0.0,
           "anonymous (large arrays, Python's arenas, JIT code, stacks)": 0.0}
    key = None
    with open("/proc/self/smaps") as f:
        for line in f:
            if re.match(r"^[0-9a-f]+-[0-9a-f]+ ", line):
                parts = line.split(None, 5)
                path = parts[5].strip() if len(parts) > 5 else ""
                key = ("llvmlite (LLVM)" if "libllvmlite" in path else
                       "[heap] (malloc)" if path == "[heap]" else
                       "other shared libraries" if path.startswith("/") else
                       "anonymous (large arrays, Python's arenas, JIT code, stacks)")
            elif line.startswith("Rss:"):
                out[key] += int(line.split()[1]) / 1024.0
    return out


def _labelling(sampler, label):
    """A wrapper (for ``Patches.replace``) labelling the sampler with ``label`` while the
    function runs."""
    def make(f):
        def wrapped(*args, **kwargs):
            before, sampler.label = sampler.label, label
            try:
                return f(*args, **kwargs)
            finally:
                sampler.label = before
        return wrapped
    return make


def run_case(case: str) -> dict:
    import importlib

    out = {"case": case, "libraries": []}
    sampler = Sampler()

    def stage(label):
        out["libraries"].append((label, rss_mb()))
        sampler.label = label

    stage("interpreter")
    import numpy as np
    stage("numpy")
    import scipy.linalg
    import scipy.sparse   # noqa: F401
    stage("scipy.sparse, scipy.linalg")
    import numba   # noqa: F401
    from numba.core import event   # noqa: F401 (warmth's, imported within this stage)
    stage("numba (llvmlite's LLVM)")

    # (a compilation in this process: its memory is in the peak, a load's is not)
    compiled = warmth.watch()
    if case == "cli":
        import h5py   # noqa: F401
        stage("h5py")
    import click   # noqa: F401

    import fault_screen.api
    import fault_screen.cli._running   # noqa: F401
    import fault_screen.stepper as stepper
    stage("click, fault_screen's model modules")
    from fault_screen import linear_system, solver
    from fault_screen.compile_ahead import KERNELS
    dispatchers = [(getattr(importlib.import_module(m), k), sig) for m, k, _, sig in KERNELS]
    dispatchers[0][0].compile(dispatchers[0][1])
    stage("numba's set-up (the first cache load)")
    stale = []   # (entries whose types the kernel no longer takes: loaded at their first call)
    for d, sig in dispatchers[1:]:
        try:
            d.compile(sig)
        except Exception:   # noqa: BLE001 - numba's typing error: the list awaits regeneration
            stale.append(d.py_func.__name__)
    stage(f"the other {len(KERNELS) - 1 - len(stale)} kernels' cache loads")
    out["stale"] = stale

    # the run, labelled by phase; the Simulation kept for the arrays' walk
    sims = []

    def keeping(init):
        def keep(self, *args, **kwargs):
            sims.append(self)
            init(self, *args, **kwargs)
        return keep
    patches = Patches()   # (left in place: the process ends with the case)
    patches.replace(stepper.Simulation, "__init__", keeping)
    patches.replace(stepper, "discretise", _labelling(sampler, "discretisation"))
    patches.replace(solver, "assemble_constant", _labelling(sampler, "assembly"))
    patches.replace(linear_system, "bordered_lu", _labelling(sampler, "bulk factorisation"))
    patches.replace(linear_system.CondensedSolver, "_factorise",
                    _labelling(sampler, "condensed block's LU"))
    walks = {"rss": 0.0}

    def walk_if_highest(step, *_):
        sampler.label = "steps"
        r = rss_mb()
        if r > walks["rss"] + 1.0:   # (the arrays at the step with the highest RSS so far)
            walks.update(rss=r, step=step, report=arrays_report({"sim": sims[-1]}))
    advance = stepper.Simulation.advance

    def advance_watched(self, *args, **kwargs):
        if kwargs.get("progress") is None:
            kwargs["progress"] = walk_if_highest
        else:
            given = kwargs["progress"]
            kwargs["progress"] = lambda *a: (given(*a), walk_if_highest(*a))
        sampler.label = "steps"
        return advance(self, *args, **kwargs)
    stepper.Simulation.advance = advance_watched

    result = None
    if case == "cli":
        import tempfile

        from fault_screen.cli import main
        with tempfile.TemporaryDirectory() as tmp:
            try:
                main(["run", "--quiet", "--out", str(Path(tmp) / "r.h5")], standalone_mode=False)
            finally:
                sampler.label = "after the run"
    else:
        from performance import _scene

        scene = _scene({"rustrel": "rustrel", "fine": "fine-T0.7-dip30",
                        "refined": "rustrel-200x201"}[case])
        sampler.label = "set-up"
        sim = stepper.Simulation(scene)
        sim.advance(scene.time.end)
        sampler.label = "result"
        result = sim.result()
        sampler.label = "end"
    r_end = rss_mb()
    end = arrays_report({"sim": sims[-1], **({"result": result} if result is not None else {})})
    if end["total"] + 0.0 >= walks.get("report", {"total": -1})["total"] and r_end >= walks["rss"]:
        walks.update(rss=r_end, step="end", report=end)
    sampler.stop()
    out.update(peak=peak_mb(), peak_sampled=sampler.peak, peak_at=sampler.peak_label,
               arrays_at=walks["step"], arrays_rss=walks["rss"], arrays=walks["report"],
               malloc_free=malloc_free_mb(), rss_end=r_end, smaps=smaps_mb(),
               threads=os.environ.get("OPENBLAS_NUM_THREADS", "default"), compiled=compiled)
    return out


# ------------------------------------------------------------------ the table (parent)
def child(case: str, tree: Path, extra_env: dict) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    env["PYTHONPATH"] = str(tree) + os.pathsep + env.get("PYTHONPATH", "")
    env["FAULT_SCREEN_TREE"] = str(tree)   # (benchmarks/performance.py's scenes, imported here)
    env.update(extra_env)
    out = subprocess.run([sys.executable, __file__, "--case", case], capture_output=True, text=True,
                         cwd=ROOT, env=env, timeout=900)
    if out.returncode != 0:
        raise RuntimeError(f"{case}: {out.stderr.strip()[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def print_case(runs: list[dict]) -> None:
    """The table of the warm run (no compilation in its process) with the largest peak."""
    warm = [x for x in runs if not x["compiled"]] or runs
    r = max(warm, key=lambda x: x["peak"])
    print(f"\n## {r['case']}: peak {r['peak']:.0f} MB (max RSS; sampled at "
          f"'{r['peak_at']}'), OPENBLAS_NUM_THREADS {r['threads']}")
    if len(runs) > 1:
        print("peaks of the runs: " + ", ".join(f"{x['peak']:.0f}" for x in runs) + " MB")
    for x in runs:
        if x["compiled"]:
            print(f"(a run with {x['peak']:.0f} MB: {warmth.describe(x['compiled'])}: its peak "
                  f"includes them; run it again for a warm start)")
    if r.get("stale"):
        print(f"(compile_ahead.KERNELS lists {', '.join(r['stale'])} with types it no longer "
              "takes: loaded at the first call, in the run's phases; regenerate the list)")
    print("\n| part | MB | RSS after it, MB |\n|---|---:|---:|")
    last = 0.0
    for label, rss in r["libraries"]:
        print(f"| {label} | {rss - last:.1f} | {rss:.1f} |")
        last = rss
    a = r["arrays"]
    libs = last
    print(f"| the model's arrays at step {r['arrays_at']} ({a['count']} arrays, resident) | "
          f"{a['total']:.1f} | |")
    for group, mb in a["groups"]:
        if mb >= 0.5:
            print(f"| - {group} | {mb:.1f} | |")
    rest = r["arrays_rss"] - libs - a["total"]
    print(f"| freed, held by malloc (at the end) | {r['malloc_free']:.1f} | |")
    print(f"| the rest (interpreter objects, numba's code, heap) at step {r['arrays_at']} | "
          f"{rest - r['malloc_free']:.1f} | {r['arrays_rss']:.1f} |")
    print(f"| peak (max RSS) | | {r['peak']:.1f} |")
    print("\nlargest arrays (resident MB of MB):")
    for res, size, path in a["named"]:
        print(f"  {res:7.1f} of {size:6.1f}  {path}")
    print("RSS by mapping at the end: "
          + "; ".join(f"{k} {v:.0f} MB" for k, v in r["smaps"].items()))


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="*", choices=CASES, default=DEFAULT_CASES)
    ap.add_argument("--tree", type=Path, default=ROOT, help="the checkout whose fault_screen runs")
    ap.add_argument("--repeat", type=int, default=1,
                    help="runs of each case (the table: the largest warm peak)")
    ap.add_argument("--one-blas-thread", action="store_true", help="OPENBLAS_NUM_THREADS=1")
    ap.add_argument("--case", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.case:
        print(json.dumps(run_case(args.case)))
        return
    extra = {"OPENBLAS_NUM_THREADS": "1"} if args.one_blas_thread else {}
    print(f"fault_screen from {args.tree}; load average {os.getloadavg()[0]:.1f}")
    for case in args.cases:
        runs = [child(case, args.tree, extra) for _ in range(args.repeat)]
        print_case(runs)
    print(f"\nload average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()

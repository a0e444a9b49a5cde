"""Where a cold `fault-screen run` (empty numba cache) spends its compilation, kernel by kernel.

    python benchmarks/cold_compile.py            # the top 10 kernels by compile CPU time
    python benchmarks/cold_compile.py --top 40   # more rows
    python benchmarks/cold_compile.py --json     # every compilation, one JSON object
    python benchmarks/cold_compile.py --kernels  # fault_screen.compile_ahead.KERNELS for this run

A child process with an empty NUMBA_CACHE_DIR runs the bundled scene as `fault-screen run`
does (in-process, through the CLI) while a listener on numba's ``numba:compile`` event records
each compilation: the kernel, its argument types, its wall and CPU time (user + system of the
process) and the process's resident memory after it. A compilation that triggers another one
(a kernel calling a kernel that is not inlined) includes it; "own" is the time without the
nested ones. CPU time is the figure to compare on a busy machine: compilation is single-threaded
and CPU-bound, so its CPU time hardly depends on the load, whereas wall time grows with it.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _rss_mb():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _signature(args) -> str | None:
    """Argument types in numba's signature syntax (``(float64[::1], int64)``), or None where
    that syntax cannot say them (read-only or unaligned arrays, other types)."""
    from numba.core import types

    out = []
    for t in args:
        if isinstance(t, types.Array):
            if not t.mutable or not t.aligned or t.layout not in "CA":
                return None
            dims = [":"] * t.ndim
            if t.layout == "C":
                dims[-1] = "::1"
            out.append(f"{t.dtype}[{', '.join(dims)}]")
        elif isinstance(t, (types.Integer, types.Float, types.Boolean)):
            out.append(str(t))
        else:
            return None
    return "(" + ", ".join(out) + ("," if len(out) == 1 else "") + ")"


def record() -> dict:
    """In the child: run the bundled scene through the CLI, recording every compilation."""
    t0, c0 = time.perf_counter(), _cpu()
    import fault_screen.cli
    import fault_screen.api  # noqa: F401 - the model's modules, as `run` imports them
    from numba.core import event

    t1, c1 = time.perf_counter(), _cpu()
    compiles, stack = [], []

    class Listener(event.Listener):
        def on_start(self, ev):
            stack.append((time.perf_counter(), _cpu(), len(compiles)))
            compiles.append(None)

        def on_end(self, ev):
            w0, cpu0, index = stack.pop()
            d = ev.data["dispatcher"]
            compiles[index] = dict(
                kernel=f"{d.py_func.__module__}.{d.py_func.__qualname__}",
                args=", ".join(str(a) for a in ev.data["args"]),
                signature=_signature(ev.data["args"]),
                wall=time.perf_counter() - w0, cpu=_cpu() - cpu0, rss_mb=_rss_mb(),
                depth=len(stack), inline=d.targetoptions.get("inline", "never"))

    listener = Listener()
    event.register("numba:compile", listener)
    with tempfile.TemporaryDirectory() as tmp:
        fault_screen.cli.main(["run", "--out", str(Path(tmp) / "r.h5"), "--quiet"],
                              prog_name="fault-screen", standalone_mode=False)
    event.unregister("numba:compile", listener)
    t2, c2 = time.perf_counter(), _cpu()
    # own time: without the compilations nested in it
    for i, c in enumerate(compiles):
        # those nested inside c follow it until the next one at c's depth or above
        own_wall, own_cpu = c["wall"], c["cpu"]
        for n in compiles[i + 1:]:
            if n["depth"] <= c["depth"]:
                break
            if n["depth"] == c["depth"] + 1:
                own_wall -= n["wall"]
                own_cpu -= n["cpu"]
        c["own_wall"], c["own_cpu"] = own_wall, own_cpu
    top = [c for c in compiles if c["depth"] == 0]
    return dict(imports=t1 - t0, cpu_imports=c1 - c0, total=t2 - t0, cpu=c2 - c0,
                compile_wall=sum(c["wall"] for c in top), compile_cpu=sum(c["cpu"] for c in top),
                peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                compiles=compiles)


def measure() -> dict:
    with tempfile.TemporaryDirectory() as cache:
        # Python's bytecode cache on, as an installed package has it (benchmarks/performance.py)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env["NUMBA_CACHE_DIR"] = cache
        env["FAULT_SCREEN_COMPILE_AHEAD"] = "0"    # every kernel compiled here, at its first call
        env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
        out = subprocess.run([sys.executable, __file__, "--child"], capture_output=True, text=True,
                             cwd=ROOT, env=env)
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-3000:])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--top", type=int, default=10, help="rows of the table (by own CPU time)")
    ap.add_argument("--json", action="store_true", help="print every compilation as JSON")
    ap.add_argument("--kernels", action="store_true",
                    help="print fault_screen.compile_ahead.KERNELS for this run (paste it there)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(record()), flush=True)
        return
    load0 = os.getloadavg()[0]
    r = measure()
    if args.json:
        print(json.dumps(r, indent=1))
        return
    if args.kernels:
        print("KERNELS = (")
        for c in r["compiles"]:
            if c["depth"] == 0 and c["signature"] is not None:
                module, _, name = c["kernel"].rpartition(".")
                parts = textwrap.wrap(c["signature"], 84, break_on_hyphens=False, drop_whitespace=False)
                print(f"    ({module!r}, {name!r}, {c['cpu']:.2f},\n" +
                      "\n".join(f"     {p!r}" for p in parts) + "),")
        print(")")
        return
    compiles = r["compiles"]
    by_kernel = {}
    for c in compiles:
        by_kernel.setdefault(c["kernel"], []).append(c)
    print(f"cold `fault-screen run` (bundled scene, empty numba cache), load average {load0:.1f} at the "
          f"start, {os.getloadavg()[0]:.1f} at the end")
    print(f"whole process {r['total']:.2f} s (CPU {r['cpu']:.2f} s), imports {r['imports']:.2f} s "
          f"(CPU {r['cpu_imports']:.2f} s), compilation {r['compile_wall']:.2f} s (CPU "
          f"{r['compile_cpu']:.2f} s) in {len(compiles)} compilations of {len(by_kernel)} kernels, "
          f"peak memory {r['peak_mb']:.0f} MB\n")
    print("| kernel | argument types | own CPU (s) | own wall (s) | nested in | inline | RSS after (MB) |")
    print("|---|---|---|---|---|---|---|")
    for c in sorted(compiles, key=lambda c: -c["own_cpu"])[:args.top]:
        print(f"| {c['kernel'].removeprefix('fault_screen.')} | {c['args']} | {c['own_cpu']:.2f} | "
              f"{c['own_wall']:.2f} | {c['depth']} | {c['inline']} | {c['rss_mb']:.0f} |")
    several = {k: v for k, v in by_kernel.items() if len(v) > 1}
    if several:
        print("\nkernels compiled for more than one signature:")
        for k, v in several.items():
            print(f"  {k}: " + "; ".join(f"({c['args']}) {c['own_cpu']:.2f} s" for c in v))


if __name__ == "__main__":
    main()

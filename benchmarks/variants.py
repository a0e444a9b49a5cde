"""Variants a user would write of the bundled scenes: do they run to their end, finitely, at a
cost close to the plain scene's?

    python benchmarks/variants.py                   # every variant; writes docs/performance/variants.md
    python benchmarks/variants.py surges flowback   # some of them (printed only)
    python benchmarks/variants.py --no-doc          # every variant, printed only

The plain scene is the bundled calibrated Rustrel scene in the paper's units (what
`fault-screen run` runs). The variants change what a user would change:

- [surges] short surges on the step-rate schedule: every 200 s a 20-s surge to twice the
  step's rate (the same steps of 5 s);
- [shut-in-3h] three hours of shut-in after the 1400 s of injection, with growing steps as the
  monitor advises for long runs (growth 1.2 up to 600 s);
- [shut-in-1h-fixed] one hour of shut-in after injection at the scene's own 5-s steps
  (3.6x the steps of the plain scene);
- [flowback] after shut-in at 1400 s, fluid produced back at 20 L/min from 1600 s to 2400 s
  (about a third of the injected volume; `injection.allow_flowback = true`);
- [weak-rate] rate dependence of friction 30x weaker (a = 9e-4 instead of 2.69e-2);
- [very-weak-rate] 270x weaker (a = 1e-4);
- [weak-rate-surges] the two together;
- [impermeable-flowback] the bundled impermeable scene with the same flowback.

Each runs in its own process (numba's cache warm; Simulation built, run to its end, Result
made). The table gives the steps, step cuts, Newton iterations, the wall time and its ratio to
the plain scene's, the CPU time of the process and the CPU per step against the plain scene's,
whether every recorded number is finite and the mass-balance error (stored + drained against
injected, relative to the most injected). On a busy machine read the CPU ratios, not the
seconds: the wall time of one process depends on what else runs.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests" / "hard_cases"))
PAPER = ROOT / "configs" / "rustrel-2015-calibrated-paper-units.toml"
IMPERMEABLE = ROOT / "configs" / "rustrel-2015-impermeable-paper-units.toml"
L_PER_MIN = 1e-3 / 60.0
#: a variant that runs longer than this is stopped and reported as such (s)
CASE_TIMEOUT = 900


def _surged(schedule, every=200.0, length=20.0, factor=2.0):
    """The step schedule with a surge to ``factor`` times the rate of the moment, ``length`` s
    long, every ``every`` s while injecting."""
    times = [t for t, _ in schedule]
    end = times[-1]

    def rate_at(t):
        return [v for s, v in schedule if s <= t][-1]

    points = set(times)
    t = every
    while t + length < end:
        points.update((t, t + length))
        t += every
    out = []
    for t in sorted(points):
        surge = any(s <= t < s + length for s in np.arange(every, end, every))
        out.append((t, rate_at(t) * (factor if surge else 1.0)))
    return tuple(out)


def _flowback(scene, start=1600.0, stop=2400.0, rate=-20.0 * L_PER_MIN):
    schedule = tuple((t, v) for t, v in scene.injection.schedule if t < start) + ((start, rate), (stop, 0.0))
    return scene.replace(injection=replace(scene.injection, schedule=schedule, allow_flowback=True),
                         time=replace(scene.time, end=stop + 200.0))


def variant(name: str):
    from fault_screen import Scene

    plain = Scene.from_toml(PAPER)
    inj, tm, fault = plain.injection, plain.time, plain.fault
    if name == "plain":
        return plain
    if name == "surges":
        return plain.replace(injection=replace(inj, schedule=_surged(inj.schedule)))
    if name == "shut-in-3h":
        return plain.replace(time=replace(tm, end=tm.end + 3 * 3600.0, growth=1.2, dt_max=600.0))
    if name == "shut-in-1h-fixed":
        return plain.replace(time=replace(tm, end=tm.end + 3600.0))
    if name == "flowback":
        return _flowback(plain)
    if name == "weak-rate":
        return plain.replace(fault=replace(fault, rate_parameter=9e-4))
    if name == "very-weak-rate":
        return plain.replace(fault=replace(fault, rate_parameter=1e-4))
    if name == "weak-rate-surges":
        return plain.replace(fault=replace(fault, rate_parameter=9e-4),
                             injection=replace(inj, schedule=_surged(inj.schedule)))
    if name == "impermeable-flowback":
        return _flowback(Scene.from_toml(IMPERMEABLE))
    raise KeyError(name)


VARIANTS = ["plain", "surges", "shut-in-3h", "shut-in-1h-fixed", "flowback", "weak-rate",
            "very-weak-rate", "weak-rate-surges", "impermeable-flowback"]


def run_variant(name: str) -> dict:
    from stability_cases import all_finite, balance_error

    from fault_screen import Simulation

    scene = variant(name)
    warnings.simplefilter("ignore")
    t0, c0 = time.perf_counter(), time.process_time()
    sim = Simulation(scene)
    error = ""
    try:
        sim.advance(scene.time.end)
    except Exception as exc:  # noqa: BLE001 - a failing variant is a row of the table
        error = f"{type(exc).__name__}: {str(exc).splitlines()[0][:120]}"
    result = sim.result()
    wall = time.perf_counter() - t0
    solver = result.solver
    return dict(name=name, wall=wall, cpu=time.process_time() - c0, steps=len(result.time) - 1,
                end=float(result.time[-1]), scene_end=scene.time.end,
                cuts=int(np.sum(solver["step_cuts"])),
                newton=int(np.sum(solver["iterations"])), finite=all_finite(result),
                balance=balance_error(result), stopped=str(result.meta.get("stopped") or ""), error=error,
                peak_slip_mm=1e3 * float(np.nanmax(np.abs(result.fault["slip"]))))


def child(name: str) -> dict:
    try:
        out = subprocess.run([sys.executable, __file__, "--case", name], capture_output=True, text=True,
                             cwd=ROOT, timeout=CASE_TIMEOUT)
    except subprocess.TimeoutExpired:
        return dict(name=name, timeout=CASE_TIMEOUT)
    if out.returncode != 0:
        return dict(name=name, error=out.stderr.strip().splitlines()[-1][:160])
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("names", nargs="*", metavar="VARIANT", help=", ".join(VARIANTS))
    ap.add_argument("--case", help=argparse.SUPPRESS)
    ap.add_argument("--no-doc", action="store_true", help="do not write docs/performance/variants.md")
    args = ap.parse_args()
    if args.case:
        print(json.dumps(run_variant(args.case)))
        return
    unknown = sorted(set(args.names) - set(VARIANTS))
    if unknown:
        ap.error(f"unknown variant(s) {', '.join(unknown)}; known: {', '.join(VARIANTS)}")
    names = args.names or VARIANTS
    if "plain" not in names:
        names = ["plain", *names]
    load0 = os.getloadavg()[0]
    child("plain")  # numba's cache in place
    head = ("variant", "steps", "cuts", "Newton", "wall", "wall / plain", "CPU / plain",
            "CPU per step / plain", "finite", "balance", "end")
    table = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    plain = None
    for name in names:
        r = child(name)
        if "timeout" in r or "wall" not in r:
            why = f"> {r['timeout']} s (stopped)" if "timeout" in r else f"FAILED: {r['error']}"
            cells = (name, "-", "-", "-", why, "-", "-", "-", "-", "-", "-")
        else:
            if name == "plain":
                plain = r
            ratio, cpu_ratio = r["wall"] / plain["wall"], r["cpu"] / plain["cpu"]
            per_step = cpu_ratio * plain["steps"] / r["steps"]
            reached = r["end"] >= r["scene_end"] * (1 - 1e-12)
            end = ("ran to its end" if reached and not r["error"] else
                   f"stopped at {r['end']:.0f} s of {r['scene_end']:.0f} s ({r['error'] or r['stopped']})")
            cells = (name, r["steps"], r["cuts"], r["newton"], f"{r['wall']:.2f} s (CPU {r['cpu']:.2f} s)",
                     f"{ratio:.2f}x", f"{cpu_ratio:.2f}x", f"{per_step:.2f}x", "yes" if r["finite"] else "NO",
                     f"{r['balance']:.1e}", end)
        table.append("| " + " | ".join(str(c) for c in cells) + " |")
        print(table[-1], flush=True)
    print(f"load average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end")
    if not args.no_doc and not args.names:
        from doc_tables import write

        write("variants", "Variants of the bundled scenes",
              "The plain scene is the bundled calibrated Rustrel scene in the paper's units "
              "(`fault-screen run`); the variants are described in `benchmarks/variants.py`. Each runs "
              "in its own process with numba's cache warm. \"CPU per step / plain\" is the CPU time "
              "per step against the plain scene's (on a busy machine the CPU ratios are the ones to "
              "read); \"balance\" the largest mass-balance error relative to the most injected "
              "volume.", table, load0)


if __name__ == "__main__":
    main()

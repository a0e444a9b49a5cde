"""What each effect of the Rustrel 2015 calibrated scene costs, and what the full scene costs.

    python benchmarks/rustrel_effects.py

Table 1: the calibrated replay (50 x 51 mesh, 280 steps of 5 s): wall time cold (a fresh numba
cache: includes JIT compilation), warm (cached compiled kernels, new process) and in-process
repeat, Newton iterations per step, step latency and peak memory (max RSS).
Table 2: the same scene with each effect switched off in turn (dependent switches go with it):
unknowns, condensed nonlinear unknowns, wall time (in-process, warm), Newton iterations, and the
peak injection overpressure and slip, so that the cost of each effect sits next to what it
changes. Every case runs in its own process.
"""
from __future__ import annotations

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
SCENE = ROOT / "configs" / "rustrel-2015-calibrated.toml"

#: effect switched off -> the switches that must go with it
OFF = {
    "none (full scene)": {},
    "poroelastic": {"poroelastic": False, "leak_off": False},
    "leak_off": {"leak_off": False},
    "fault_flow": {"fault_flow": False, "aperture_evolution": False},
    "rate_friction": {"rate_friction": False, "state_evolution": False},
    "dilation": {"dilation": False},
    "aperture_evolution": {"aperture_evolution": False},
    "gravity": {"gravity": False},
    "damage_zone": {"damage_zone": False},
}


def run_case(label: str, repeats: int) -> dict:
    import numpy as np

    from fault_screen import Scene, Simulation

    scene = Scene.from_toml(SCENE)
    scene = scene.replace(effects=replace(scene.effects, **OFF[label]))
    walls = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        sim = Simulation(scene)
        sim.advance(scene.time.end)
        result = sim.result()
        walls.append(time.perf_counter() - t0)
    steps = len(result.time) - 1
    return dict(label=label, dofs=sim.disc.n_dofs, nonlinear=len(sim.solver.N), steps=steps,
                first=walls[0], best=min(walls), newton=float(result.solver["iterations"][1:].mean()),
                max_newton=int(result.solver["iterations"].max()),
                peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                dp=float(np.max(result.injection["overpressure"])),
                slip=float(np.max(np.abs(result.fault["slip"]))))


def subprocess_case(label: str, repeats: int, env=None) -> dict:
    out = subprocess.run([sys.executable, __file__, "--case", label, str(repeats)],
                         capture_output=True, text=True, cwd=ROOT, env=env)
    if out.returncode != 0:
        raise RuntimeError(out.stderr)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    if len(sys.argv) == 4 and sys.argv[1] == "--case":
        print(json.dumps(run_case(sys.argv[2], int(sys.argv[3]))))
        return
    with tempfile.TemporaryDirectory() as cache:
        cold = subprocess_case("none (full scene)", 1, env={**os.environ, "NUMBA_CACHE_DIR": cache})
    warm = subprocess_case("none (full scene)", 3)
    print(f"Rustrel 2015 calibrated replay: {warm['dofs']} unknowns ({warm['nonlinear']} condensed "
          f"nonlinear), {warm['steps']} steps of 5 s")
    print(f"{'cold (JIT compile) s':>21s} {'warm s':>7s} {'repeat s':>9s} {'ms/step':>8s} "
          f"{'Newton/step':>11s} {'max Newton':>10s} {'peak MB':>8s}")
    print(f"{cold['first']:21.2f} {warm['first']:7.2f} {warm['best']:9.2f} "
          f"{1e3 * warm['best'] / warm['steps']:8.2f} {warm['newton']:11.2f} {warm['max_newton']:10d} "
          f"{warm['peak_mb']:8.0f}")
    print()
    head = (f"{'effect switched off':22s} {'unknowns':>8s} {'nonlin.':>7s} {'wall s':>7s} "
            f"{'Newton/step':>11s} {'peak dp MPa':>11s} {'peak slip mm':>12s}")
    print(head)
    print("-" * len(head))
    for label in OFF:
        r = warm if label == "none (full scene)" else subprocess_case(label, 2)
        print(f"{label:22s} {r['dofs']:8d} {r['nonlinear']:7d} {r['best']:7.2f} {r['newton']:11.2f} "
              f"{r['dp'] / 1e6:11.3f} {r['slip'] * 1e3:12.4f}", flush=True)


if __name__ == "__main__":
    main()

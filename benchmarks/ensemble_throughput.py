"""Ensemble throughput (runs per minute) on 1 and 2 local Dask workers.

The tasks: the paper-units calibrated Rustrel scene on the sensitivity studies' coarse mesh
(26 x 25, 20 s steps, grading growth 1.5: ~4000 unknowns, 70 steps, ~1.6 s of CPU a run), NoF
varied over 12 values. Cluster start-up and the workers' warm-up are timed separately.
Run: OPENBLAS_NUM_THREADS=1 python benchmarks/ensemble_throughput.py [N_TASKS]
"""
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

from fault_screen import Scene
from fault_screen.ensemble import Runner, Variant

ROOT = Path(__file__).resolve().parents[1]


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 12
    base = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated-paper-units.toml")
    base = base.replace(mesh=dataclasses.replace(base.mesh, nx=26, ny=25, fault_grading_growth=1.5),
                        time=dataclasses.replace(base.time, dt=20.0))
    variants = [Variant(f"nof {v:.0f}", {"injection.number_of_fractures": float(v)})
                for v in np.linspace(46, 120, n)]
    print(f"{n} runs of {base.title} on 26 x 25, dt 20 s, grading growth 1.5; load average {os.getloadavg()[0]:.2f} at start")
    for workers in (1, 2):
        t0 = time.perf_counter()
        with Runner(workers) as runner:
            t1 = time.perf_counter()
            runner.run(base, variants[:2])          # warm the workers (numba cache load)
            t2 = time.perf_counter()
            outs = runner.run(base, variants)
            t3 = time.perf_counter()
        failed = sum(not o.ok for o in outs)
        per_run = np.mean([o.wall_s for o in outs if o.ok])
        print(f"workers {workers}: {60 * n / (t3 - t2):.1f} runs/min warm ({t3 - t2:.1f} s for {n} runs, "
              f"{per_run:.2f} s per run in the worker, {failed} failed); cluster start {t1 - t0:.1f} s, "
              f"warm-up {t2 - t1:.1f} s; load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()

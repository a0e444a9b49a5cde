"""The theta ladder's step kinds on the [stepsize] run of benchmarks/performance.py (paper-units
Rustrel, growth 1.2, dt_max 600 s, 3 h of shut-in): the steps that start a rung (a new size at
the scene's theta: the bulk refactorised, or its factors made ahead beside the last rung,
``CondensedSystem.factorise_ahead``), the other changed steps (inside a rung) and the unchanged
ones; median wall and CPU (the process's: every thread) per kind, the whole run's, and the
process's peak memory. Run in one process for the tree on sys.path; compare trees by
interleaving processes (PYTHONPATH=/path/to/other/tree python benchmarks/rung_switch.py).

    python benchmarks/rung_switch.py [--runs 3]

The first run of the process is not counted (the kernels' first calls, a compile)."""

import argparse
import resource
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def run_once(scene):
    from fault_screen import Simulation

    sim = Simulation(scene)
    rows = []
    last = [time.perf_counter(), time.process_time()]

    def progress(step, t, end, wall):
        now = (time.perf_counter(), time.process_time())
        rows.append((sim.last_row["dt"], sim.last_row["theta"], now[0] - last[0], now[1] - last[1]))
        last[:] = now

    t0, c0 = time.perf_counter(), time.process_time()
    sim.advance(scene.time.end, progress=progress)
    return rows, time.perf_counter() - t0, time.process_time() - c0


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    import fault_screen   # (first: performance puts its own tree on sys.path)
    import performance

    scene = performance._scene("paper-growing")
    kinds = {"rung's first step": ([], []), "changed, inside a rung": ([], []),
             "unchanged": ([], [])}
    whole = ([], [])
    for r in range(args.runs + 1):
        rows, wall, cpu = run_once(scene)
        if r == 0:
            continue
        whole[0].append(wall)
        whole[1].append(cpu)
        for (dt0, _, _, _), (dt, theta, w, c) in zip(rows[:-1], rows[1:]):
            kind = ("unchanged" if dt == dt0 else "rung's first step" if theta == scene.time.theta
                    else "changed, inside a rung")
            kinds[kind][0].append(w)
            kinds[kind][1].append(c)
    same = statistics.median(kinds["unchanged"][0])
    print(f"fault_screen from {Path(fault_screen.__file__).parent}; {args.runs} runs; "
          f"load average {open('/proc/loadavg').read().split()[0]}")
    print("| step | count a run | wall (ms, median) | CPU (ms, median) | wall / unchanged |")
    print("|---|---|---|---|---|")
    for kind, (w, c) in kinds.items():
        print(f"| {kind} | {len(w) // args.runs} | {1e3 * statistics.median(w):.2f} | "
              f"{1e3 * statistics.median(c):.2f} | {statistics.median(w) / same:.2f} |")
    print(f"| whole run | | {1e3 * statistics.median(whole[0]):.0f} | "
          f"{1e3 * statistics.median(whole[1]):.0f} | |")
    print(f"peak memory (max RSS of this process) "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()

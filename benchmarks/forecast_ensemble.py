"""Speed of an ensemble forecast (issue 29 item 6): N members x P plans on the Dask runner.

    python benchmarks/forecast_ensemble.py                 # 32 members, 3 plans, 1 h ahead of 600 s
    python benchmarks/forecast_ensemble.py --ladder 160   # also on a step ladder up to 160 s
    python benchmarks/forecast_ensemble.py --quick         # 4 members, 10 min ahead (a smoke run)
    python benchmarks/forecast_ensemble.py --doc           # also write docs/performance/forecast-ensemble.md

Each member is one task (``fault_screen.forecast.ensemble.run_member``): the calibrated Rustrel
scene with one draw of the varied parameters runs its history from 0 to ``--at``, forks, and
runs each plan over the horizon, screened. The table gives the wall time of the whole ensemble
on ``--workers`` local worker processes (one BLAS thread each; the cluster's start-up is left
out and given apart) and each member's CPU time, which does not grow with the load of a shared
machine as the wall time does: the sum of the CPU times over the workers is what the ensemble
would take on that many idle cores. ``--growth`` adds a second run with look-ahead steps growing
from the run's step (see benchmarks/lookahead.py for what that costs in accuracy).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from fault_screen import Scene  # noqa: E402
from fault_screen.calibration import load_parameters, sample_parameters  # noqa: E402
from fault_screen.ensemble import Runner  # noqa: E402
from fault_screen.forecast import parse_plan  # noqa: E402
from fault_screen.forecast.ensemble import run_member, summarise  # noqa: E402

#: the scene `fault-screen run` runs (first yellow at 705 s): the SI calibrated scene stays green
CALIBRATED = ROOT / "configs" / "rustrel-2015-calibrated-paper-units.toml"
PARAMETERS = ROOT / "configs" / "calibration" / "rustrel-2015-parameters.toml"
#: the varied parameters: the friction, the fractures the rate enters and the fault's aperture
FREE = ("fault.friction", "injection.number_of_fractures", "fault.hydraulic_aperture")
PLANS = ("hold", "stop", "scale:1.5")
#: the issue's target: this many members with the three plans within TARGET_S on 2 cores
TARGET_MEMBERS, TARGET_S = 32, 30.0


def ensemble(scene, draws, at, horizon, plans, workers, steps=None):
    """(wall of the batch (s), wall of the cluster's start (s), the member runs)."""
    calls = [(i, scene.to_dict(), d, [at], plans, horizon, None, None, None, steps)
             for i, d in enumerate(draws)]
    t0 = time.perf_counter()
    with Runner(workers) as runner:
        started = time.perf_counter() - t0
        if runner.client is not None:   # the workers import the package and load the numba cache
            runner.client.run(_warm)
        t1 = time.perf_counter()
        runs = [None] * len(calls)
        for i, run in runner.each(run_member, calls):
            if isinstance(run, BaseException):
                raise run
            runs[i] = run
        wall = time.perf_counter() - t1
    return wall, started, runs


def _warm():
    import fault_screen.stepper  # noqa: F401

    return True


def rows_for(label, wall, started, runs, workers):
    ok = [r for r in runs if r.ok]
    cpu = sorted(r.cpu_s for r in ok)
    each = sorted(r.wall_s for r in ok)
    spread = summarise(runs)
    p = "; ".join(f"{m.plan}: {m.p_yellow:.2f}" for m in spread)
    idle = sum(cpu) / max(workers, 1)
    median = cpu[len(cpu) // 2]
    return [(label, f"{len(ok)}/{len(runs)}", f"{wall:.1f}", f"{started:.1f}",
             f"{median:.2f}", f"{cpu[-1]:.2f}", f"{each[len(each) // 2]:.2f}", f"{idle:.1f}",
             f"{TARGET_MEMBERS * median / max(workers, 1):.0f}", p)]


def table(head, rows):
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--members", type=int, default=32, help="members [32]")
    ap.add_argument("--at", type=float, default=600.0, help="forecast time (s) [600]")
    ap.add_argument("--horizon", type=float, default=3600.0, help="horizon (s) [3600]")
    ap.add_argument("--workers", type=int, default=2, help="local worker processes [2]")
    ap.add_argument("--growth", type=float, default=None, help="also with steps growing by this factor")
    ap.add_argument("--dt-max", type=float, default=60.0, help="largest growing step (s) [60]")
    ap.add_argument("--ladder", type=float, default=None, metavar="DT_MAX",
                    help="also with look-aheads on a step ladder up to DT_MAX (s), one per member")
    ap.add_argument("--quick", action="store_true", help="4 members, 10 min ahead")
    ap.add_argument("--doc", action="store_true", help="write docs/performance/forecast-ensemble.md")
    args = ap.parse_args(argv)
    members, horizon = (4, 600.0) if args.quick else (args.members, args.horizon)
    load = os.getloadavg()[0]
    scene = Scene.from_toml(CALIBRATED)
    params = load_parameters(PARAMETERS).select(list(FREE))
    draws = sample_parameters(params, members, "normal", 1)
    plans = [parse_plan(p) for p in PLANS]
    print(f"{members} members x {len(plans)} plans ({', '.join(PLANS)}), calibrated Rustrel at "
          f"{args.at:g} s, {horizon:g} s ahead, {args.workers} workers; {os.cpu_count()} cores, "
          f"load average {load:.1f} at the start", flush=True)
    rows = rows_for("scene's own steps", *ensemble(scene, draws, args.at, horizon, plans, args.workers),
                    args.workers)
    if args.growth is not None:
        steps = {"growth": args.growth, "dt_max": args.dt_max}
        rows += rows_for(f"steps x{args.growth:g} up to {args.dt_max:g} s",
                         *ensemble(scene, draws, args.at, horizon, plans, args.workers, steps), args.workers)
    if args.ladder is not None:
        rows += rows_for(f"step ladder up to {args.ladder:g} s",
                         *ensemble(scene, draws, args.at, horizon, plans, args.workers,
                                   {"ladder": args.ladder}), args.workers)
    head = ("look-ahead steps", "members ok", "wall (s)", "cluster start (s)", "CPU per member, median (s)",
            "CPU per member, most (s)", "wall per member, median (s)", f"sum of CPU / {args.workers} workers (s)",
            f"{TARGET_MEMBERS} members on {args.workers} idle cores, from the median CPU (s)", "P(yellow) per plan")
    lines = table(head, rows)
    print("\n".join(lines), flush=True)
    if args.doc:
        from doc_tables import write

        intro = (f"{members} members, each the calibrated Rustrel scene in the paper's units (the default scene) with one draw of "
                 f"{', '.join(f'`{k}`' for k in FREE)} (normal, from "
                 f"`configs/calibration/rustrel-2015-parameters.toml`, seed 1), its history run from 0 to "
                 f"{args.at:g} s, then the plans {', '.join(f'`{p}`' for p in PLANS)} each {horizon:g} s ahead, "
                 f"screened; one Dask task per member on {args.workers} local workers. The target "
                 f"(issue 29): {TARGET_MEMBERS} members x 3 plans within {TARGET_S:g} s on 2 cores. The CPU "
                 f"time per member does not grow with the machine's load as the wall time does; the sum of "
                 f"the members' CPU times over the workers is the wall time on as many idle cores, and "
                 f"{TARGET_MEMBERS} times the median over the workers estimates the target's.")
        print(write("forecast-ensemble", "Ensemble forecast speed", intro, lines, load))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

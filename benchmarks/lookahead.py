"""Look-ahead speed and the accuracy of longer steps (issue 29).

    python benchmarks/lookahead.py                       # calibrated Rustrel at 700 s, 1 h ahead
    python benchmarks/lookahead.py --quick               # 10 min ahead (a smoke run)
    python benchmarks/lookahead.py --markdown docs/performance/lookahead.md

Prints (and with ``--markdown`` writes) two tables:

1. speed on the calibrated Rustrel scene forked at ``--at`` (default 700 s): the fork itself,
   one look-ahead of one plan over the horizon (the second of two runs, numba warm), the
   advice (bisection to 2 %; on the calibrated scene every rate up to twice the largest so far
   stays green, so it takes two look-aheads: an advice that bisects is timed on the impermeable
   scene at 300 s, 10 min ahead), and the same look-ahead with steps growing from the run's step;
2. what the growing steps cost in accuracy against the default (the scene's own 5 s steps):
   time to yellow, largest utilisation and the injection overpressure at the horizon, on the
   impermeable Rustrel scene (which reaches yellow) and on the calibrated one, per plan.

Wall times depend on the machine and on what else runs on it: the table says how many cores
the machine has and its load average when the run began.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fault_screen import Scene, Simulation  # noqa: E402
from fault_screen.screening.stepwise import StepScreening  # noqa: E402
from fault_screen.forecast import LookAhead, advise, parse_plan  # noqa: E402

CALIBRATED = ROOT / "configs" / "rustrel-2015-calibrated.toml"
IMPERMEABLE = ROOT / "configs" / "rustrel-2015-impermeable.toml"
#: the longer steps compared with the scene's own: growth per step and largest step (s)
GROWTH, DT_MAX = 1.2, 60.0


def run_to(scene, t):
    sim = Simulation(scene)
    fp = sim.disc.fault_points
    screening = StepScreening.for_scene(scene, fp.s - sim.disc.injection.s, fp.weight)
    screening.screen_simulation(sim)
    while sim.advance(t, align=True, max_steps=1):
        screening.screen_simulation(sim)
    return sim, screening


def _s(v):
    return "-" if v is None else f"{v:.0f}"


def speed(at, horizon, plan):
    sim, screening = run_to(Scene.from_toml(CALIBRATED), at)
    t0 = time.perf_counter()
    sim.fork()
    fork_wall = time.perf_counter() - t0
    ahead = LookAhead(sim, screening)
    ahead.run(parse_plan(plan), horizon)                 # warm-up
    one = ahead.run(parse_plan(plan), horizon)
    t0 = time.perf_counter()
    advice = advise(ahead, horizon)
    advice_wall = time.perf_counter() - t0
    longer = LookAhead(sim, screening, growth=GROWTH, dt_max=DT_MAX).run(parse_plan(plan), horizon)
    # an advice that bisects: impermeable Rustrel at 300 s (yellow at 390 s under its schedule)
    short = min(horizon, 600.0)
    t0 = time.perf_counter()
    bisected = advise(LookAhead(*run_to(Scene.from_toml(IMPERMEABLE), 300.0)), short)
    bisect_wall = time.perf_counter() - t0
    return [("fork (new solver from the checkpoint state)", f"{fork_wall:.3f}", "", ""),
            (f"one look-ahead, plan {plan}, scene's steps", f"{one.wall_s:.2f}", str(len(one.time) - 1),
             _outcome(one)),
            (f"advice ({advice.evaluations} look-aheads)", f"{advice_wall:.2f}", "",
             advice.describe().split(": ", 1)[1]),
            (f"one look-ahead, steps x{GROWTH} up to {DT_MAX:g} s", f"{longer.wall_s:.2f}",
             str(len(longer.time) - 1), _outcome(longer)),
            (f"advice, impermeable Rustrel at 300 s, {short:g} s ahead ({bisected.evaluations} look-aheads)",
             f"{bisect_wall:.2f}", "", bisected.describe().split(": ", 1)[1])]


def _outcome(f):
    from fault_screen.screening import LEVEL_NAMES

    return (f"max level {LEVEL_NAMES[f.max_level]}, to yellow {_s(f.time_to_yellow)} s, "
            f"max utilisation {f.max_utilisation:.4f}")


def accuracy(at, horizon, plans):
    rows = []
    for path, t in ((IMPERMEABLE, min(at, 300.0)), (CALIBRATED, at)):
        sim, screening = run_to(Scene.from_toml(path), t)
        default = LookAhead(sim, screening)
        longer = LookAhead(sim, screening, growth=GROWTH, dt_max=DT_MAX)
        for plan in plans:
            a = default.run(parse_plan(plan), horizon)
            b = longer.run(parse_plan(plan), horizon)
            rows.append((path.stem, f"{t:g}", plan, _s(a.time_to_yellow), _s(b.time_to_yellow),
                         f"{a.max_utilisation:.4f}", f"{b.max_utilisation:.4f}",
                         f"{b.max_utilisation - a.max_utilisation:+.1e}", _relative(a, b), str(len(a.time) - 1),
                         str(len(b.time) - 1), f"{a.wall_s:.2f}", f"{b.wall_s:.2f}"))
    return rows


def _relative(a, b):
    pa = a.metrics["injection_overpressure"][-1]
    pb = b.metrics["injection_overpressure"][-1]
    return f"{(pb - pa) / abs(pa):+.1e}" if pa else "-"


def table(head, rows):
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--at", type=float, default=700.0, help="fork time (s) [700]")
    ap.add_argument("--horizon", type=float, default=3600.0, help="look-ahead horizon (s) [3600]")
    ap.add_argument("--plan", default="hold", help="plan timed [hold]")
    ap.add_argument("--quick", action="store_true", help="a 10 min horizon")
    ap.add_argument("--markdown", type=Path, default=None, help="also write the tables here")
    args = ap.parse_args(argv)
    horizon = 600.0 if args.quick else args.horizon
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    header = (f"Look-ahead from t = {args.at:g} s, horizon {horizon:g} s; {os.cpu_count()} cores, "
              f"load average {load:.1f} at the start (wall times on a busy machine are upper bounds)")
    print(header, flush=True)
    t1 = table(("calibrated Rustrel", "wall (s)", "steps", "result"), speed(args.at, horizon, args.plan))
    print(t1, flush=True)
    t2 = table(("scene", "made at (s)", "plan", "to yellow (s), 5 s steps", f"to yellow (s), x{GROWTH}",
                "max util., 5 s steps", f"max util., x{GROWTH}", "difference",
                "injection overpressure at horizon, relative difference", "steps", f"steps x{GROWTH}",
                "wall (s)", f"wall x{GROWTH} (s)"),
               accuracy(args.at, horizon, ("hold", "scale:1.5", "stop")))
    print(t2, flush=True)
    if args.markdown is not None:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(
            "# Look-ahead speed and accuracy\n\n"
            f"Printed by `python benchmarks/lookahead.py{' --quick' if args.quick else ''}`.\n\n"
            f"{header}.\n\n## Speed\n\n{t1}\n\n## Longer steps against the scene's own\n\n{t2}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

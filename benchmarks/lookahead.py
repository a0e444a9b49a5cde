"""Look-ahead speed and the accuracy of longer steps (issue 29).

    python benchmarks/lookahead.py              # both calibrated Rustrel scenes at 700 s, 1 h
                                                # ahead; writes docs/performance/lookahead.md
    python benchmarks/lookahead.py --quick --no-doc   # 10 min ahead (a smoke run), printed only

The scenes: the one ``fault-screen run`` runs without a SCENE (the bundled Rustrel 2015
calibrated scene in the paper's units; under its own schedule it first reaches yellow at 705 s)
and the SI reading of the same table (``configs/rustrel-2015-calibrated.toml``, which stays
green), each forked at ``--at`` (default 700 s, the time issue 29 names). Prints (and, unless
``--no-doc``, writes with ``benchmarks/doc_tables.py``) two tables:

1. speed, per scene: the fork itself; one look-ahead of one plan over the horizon with the
   scene's own steps (the second of two runs, numba warm); the same on step ladders (steps
   doubling from the run's step up to a largest size, each size factorised once: the first
   look-ahead on a ladder pays for its factorisations, the next ones share them); the advice
   (bisection to 2 %) on a ladder; with the steps, the Newton iterations they took (what makes
   a long step dearer than a short one);
2. what the ladders cost in accuracy against the scene's own steps, per plan: time to yellow,
   largest utilisation, injection overpressure at the horizon, on the impermeable Rustrel scene
   at 300 s (yellow at 390 s under its schedule), on the default scene at 600 s and at ``--at``,
   and on the SI scene at ``--at``.

Wall and CPU times depend on the machine and on what else runs on it: the tables say how many
cores the machine has and its load average at the start and at the end.
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
from fault_screen.cli._common import BUNDLED_SCENE  # noqa: E402
from fault_screen.forecast import LookAhead, StepLadder, advise, parse_plan  # noqa: E402
from fault_screen.screening import LEVEL_NAMES  # noqa: E402
from fault_screen.screening.stepwise import StepScreening  # noqa: E402

DEFAULT_SCENE = ROOT / "configs" / BUNDLED_SCENE
SI_SCENE = ROOT / "configs" / "rustrel-2015-calibrated.toml"
IMPERMEABLE = ROOT / "configs" / "rustrel-2015-impermeable.toml"
#: the ladders compared with the scene's own steps: their largest step (s)
LADDERS = (40.0, 160.0)
PLANS = ("scene", "hold", "scale:1.5", "stop")


def run_to(scene, t):
    sim = Simulation(scene)
    fp = sim.disc.fault_points
    screening = StepScreening.for_scene(scene, fp.s - sim.disc.injection.s, fp.weight)
    screening.screen_simulation(sim)
    while sim.advance(t, align=True, max_steps=1):
        screening.screen_simulation(sim)
    return sim, screening


def timed(fn):
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - wall, time.process_time() - cpu


def _s(v):
    return "-" if v is None else f"{v:.0f}"


def _outcome(f):
    return (f"max level {LEVEL_NAMES[f.max_level]}, to yellow {_s(f.time_to_yellow)} s, "
            f"max utilisation {f.max_utilisation:.4f}")


def speed(name, sim, screening, horizon, plan, ladders):
    plan = parse_plan(plan)
    _, fork_wall, fork_cpu = timed(sim.fork)
    rows = [(name, "fork (the solver's factors shared)", f"{fork_wall:.4f}", f"{fork_cpu:.4f}", "", "", "", "")]
    ahead = LookAhead(sim, screening)
    ahead.run(plan, horizon)                 # warm-up
    one, wall, cpu = timed(lambda: ahead.run(plan, horizon))
    rows.append((name, f"one look-ahead, plan {plan.name}, the scene's steps", f"{wall:.2f}", f"{cpu:.2f}",
                 str(len(one.time) - 1), str(one.iterations), "", _outcome(one)))
    for dt_max in ladders:
        ladder = StepLadder(dt_max)
        for what in ("first", "second"):
            made = ladder.factorizations
            f, wall, cpu = timed(lambda: LookAhead(sim, screening, ladder=ladder).run(plan, horizon))
            rows.append((name, f"one look-ahead, plan {plan.name}, ladder to {dt_max:g} s, {what}",
                         f"{wall:.2f}", f"{cpu:.2f}", str(len(f.time) - 1), str(f.iterations),
                         str(ladder.factorizations - made), _outcome(f)))
        advice, wall, cpu = timed(lambda: advise(LookAhead(sim, screening, ladder=ladder), horizon))
        rows.append((name, f"advice, ladder to {dt_max:g} s ({advice.evaluations} look-aheads)", f"{wall:.2f}",
                     f"{cpu:.2f}", "", "", "", advice.describe().split(": ", 1)[1]))
    return rows


def accuracy(cases, horizon, plans, ladders):
    rows = []
    for path, t in cases:
        sim, screening = run_to(Scene.from_toml(path), t)
        modes = [("scene's steps", LookAhead(sim, screening))]
        modes += [(f"ladder to {d:g} s", LookAhead(sim, screening, ladder=StepLadder(d))) for d in ladders]
        for name in plans:
            plan = parse_plan(name)
            exact = None
            for mode, ahead in modes:
                f, wall, _ = timed(lambda: ahead.run(plan, horizon))
                p = f.metrics["injection_overpressure"][-1]
                if exact is None:
                    exact, p0 = f, p
                    diff = ("", "", "")
                else:
                    diff = (_delta(f.time_to_yellow, exact.time_to_yellow),
                            f"{f.max_utilisation - exact.max_utilisation:+.1e}",
                            f"{(p - p0) / abs(p0):+.1e}" if p0 else "-")
                rows.append((path.stem, f"{t:g}", name, mode, _s(f.time_to_yellow), diff[0],
                             f"{f.max_utilisation:.4f}", diff[1], f"{p / 1e6:.4f}", diff[2],
                             str(len(f.time) - 1), f"{wall:.2f}"))
    return rows


def _delta(a, b):
    if a is None and b is None:
        return ""
    if a is None or b is None:
        return "reached in one only"
    return f"{a - b:+.0f}"


def table(head, rows):
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(out)


NOTES = """\
The scene's own steps are the default of `fault-screen forecast` and of `LookAhead`: the plan
`scene` then reproduces the uninterrupted run row for row (tests/forecast/test_forecast.py), so its
time to yellow is exact to the step (5 s). A step ladder (`LookAhead(..., ladder=StepLadder(dt_max))`:
steps doubling from the run's step up to `dt_max`, then the largest that fit to end on the
horizon) takes a handful of step sizes; with rock pore pressure each size needs its own
factorisation of the bulk, made once and shared by every look-ahead on the same ladder (the
plans, the advice's evaluations, the next refreshes of a live run): compare its first and second
rows above. Its cost is accuracy, in the second table: a look-ahead on a ladder sees a level
change only at the end of a step, and the implicit scheme's longer steps lag the pressure front,
so its time to yellow comes later than the exact one, by up to one of its largest steps (late:
the wrong side for a warning); its largest utilisation is a little lower, and after a shut-in
its pressure falls more slowly. The advice stops each rate's look-ahead once it reaches the
level, and its evaluations share the fork (and the ladder's factorisations).

Which mode the live monitor takes: the scene's own steps, the exact forecast (an hour ahead
costs about what an hour of the run costs, in a worker beside the live steps). A ladder is for
when a refresh cannot finish within the refresh interval; a forecast made on one must say so,
with its largest step as the resolution of its time to yellow. An ensemble
(`fault-screen forecast --members`) runs every plan on every member: it looks ahead on a ladder
to 160 s by default and says so (`--scene-steps` for the exact steps;
[ensemble speed](forecast-ensemble.md)).

Why a step of the ladder costs more than a step of the run: the Newton iterations (column
"Newton iterations" against "steps"): a long step moves the fault further from where its
iteration starts, and each iteration is a residual, a condensed solve and a convergence check.
The first look-ahead on a ladder also pays for a factorisation of the bulk per new step size,
and every change of step size for a new condensed factorisation.

Scenes: the default scene is `configs/rustrel-2015-calibrated-paper-units.toml`, the one
`fault-screen run` runs (the paper's table values read as mobilities, as its findings need).
The SI reading of the same table, `configs/rustrel-2015-calibrated.toml`, drains through its
damage zone: its fault barely pressurises (0.08 MPa at 700 s), its largest utilisation stays at
its in-situ 0.4537 whatever the plan, and it never leaves green.
Timed there, every plan gives the same rows: the physics of that scene, not the look-ahead.
"""


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--at", type=float, default=700.0, help="fork time (s) [700]")
    ap.add_argument("--horizon", type=float, default=3600.0, help="look-ahead horizon (s) [3600]")
    ap.add_argument("--plan", default="hold", help="plan timed [hold]")
    ap.add_argument("--quick", action="store_true", help="a 10 min horizon")
    ap.add_argument("--no-doc", action="store_true", help="print only (do not write the docs page)")
    args = ap.parse_args(argv)
    horizon = 600.0 if args.quick else args.horizon
    load0 = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"look-ahead from t = {args.at:g} s on {DEFAULT_SCENE.name} and {SI_SCENE.name}, horizon "
          f"{horizon:g} s; {os.cpu_count()} cores, load average {load0:.1f} at the start", flush=True)
    rows = []
    for label, path in (("default (paper units)", DEFAULT_SCENE), ("SI", SI_SCENE)):
        sim, screening = run_to(Scene.from_toml(path), args.at)
        rows += speed(f"{label}, {sim.disc.free.size} free unknowns", sim, screening, horizon, args.plan, LADDERS)
    t1 = table(("scene", "what", "wall (s)", "CPU (s)", "steps", "Newton iterations", "factorisations",
                "result"), rows)
    print(t1, flush=True)
    cases = ((IMPERMEABLE, min(args.at, 300.0)), (DEFAULT_SCENE, min(args.at, 600.0)), (DEFAULT_SCENE, args.at),
             (SI_SCENE, args.at))
    t2 = table(("scene", "made at (s)", "plan", "steps", "to yellow (s)", "difference (s)",
                "max utilisation", "difference", "injection overpressure at horizon (MPa)",
                "relative difference", "steps taken", "wall (s)"),
               accuracy(list(dict.fromkeys(cases)), horizon, PLANS, LADDERS))
    print(t2, flush=True)
    if not args.no_doc:
        from doc_tables import write, write_readme

        intro = (f"Look-ahead from t = {args.at:g} s on `configs/{DEFAULT_SCENE.name}` (the scene "
                 f"`fault-screen run` runs) and on `configs/{SI_SCENE.name}`, horizon {horizon:g} s. Wall "
                 f"times on a busy machine are upper bounds; CPU times count this process.")
        lines = ["## Speed", "", *t1.splitlines(), "",
                 "## Step ladders against the scene's own steps", "", *t2.splitlines(), "",
                 "## What the modes mean", "", *NOTES.splitlines()]
        write("lookahead", "Look-ahead speed and accuracy", intro, lines, load0)
        # the README keeps it short: per scene the exact look-ahead, the ladder to 160 s once its
        # sizes are factorised, and the advice on it
        keep = ("the scene's steps", "ladder to 160 s, second", "advice, ladder to 160 s")
        write_readme("lookahead", t1.splitlines()[:2] + [r for r in t1.splitlines()[2:] if any(k in r for k in keep)],
                     load0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

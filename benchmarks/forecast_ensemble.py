"""Speed of an ensemble forecast (issue 29 item 6): N members x P plans on the Dask runner.

    python benchmarks/forecast_ensemble.py              # 32 members on the ladder, 4 on the
                                                        # scene's steps, both scenes, 3 plans
    python benchmarks/forecast_ensemble.py --quick      # 4 members, 10 min ahead (a smoke run)
    python benchmarks/forecast_ensemble.py --doc        # also write docs/performance/forecast-ensemble.md
    python benchmarks/forecast_ensemble.py --scene SI --malloc-ab 2   # the workers' malloc setting, A/B

Each member is the calibrated Rustrel scene (the default one in the paper's units, and the SI
one) with one draw of the varied parameters: it runs its history from 0 to ``--at`` (700 s, on
the scene's own 5-s steps), forks, and runs each plan over the horizon, screened. Members go to
the workers one member a task (``fault_screen.forecast.ensemble.run_members``: a worker keeps
one store for the ensemble's tasks, so the members it runs share the bulk's order and symbolic
analysis, and the factors of equal bulks). The look-aheads take the step ladder to 160 s that
``fault-screen forecast --members`` takes by default, and (fewer members: ``--exact-members``)
the scene's own steps, to show what the ladder saves.

The table gives the wall time of the ensemble on ``--workers`` local worker processes (one BLAS
thread each; the cluster's start-up is left out and given apart) and each member's CPU time,
which does not grow with the load of a shared machine as the wall time does: 32 times the
median over the workers is what 32 members would take on that many idle cores. Of that CPU, the
worker's other threads (Dask's event loop) take what the next column says.

A first table (``--profile N``, default 3) splits one member's CPU time into its phases, N
members run in turn in this process after one that loads the compiled kernels (as
``run_members`` runs them: one store of shared bulk data).
"""
from __future__ import annotations

import argparse
import os
import pickle
import statistics
import sys
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from fault_screen import Scene  # noqa: E402
from fault_screen.calibration import load_parameters, sample_parameters  # noqa: E402
from fault_screen.ensemble import Runner  # noqa: E402
from fault_screen.forecast import parse_plan  # noqa: E402
from fault_screen.forecast.ensemble import (ENSEMBLE_LADDER, MemberRun, chunks, member_steps,  # noqa: E402
                                            run_members, summarise)

NOTES = """\
Why the bulk's factors are shared so little here: the hydraulic aperture enters the storage of
the rock's pressure next to the fault, so every draw has a bulk of its own; the friction leaves
the bulk as it is but enters the contact's tangent and so the scaling of the fault's unknowns,
which borders the factorised matrix. Members that differ only in the number of fractures (the
source) factorise equal matrices and share them (tests/forecast/test_forecast_shared.py).
What is left of a member's CPU time is the model's own work (first table): its history (0 to the
forecast time on the scene's 5-s steps: each member needs its own), the factorisations of the
ladder's step sizes (made by the first plan, which the others reuse) and the look-aheads' steps.
The history on the look-ahead's ladder (the last table) costs a few of its steps instead of
the scene's.
"""

#: the scene `fault-screen run` runs (first yellow at 705 s), and its SI reading (stays green)
SCENES = {"default": ROOT / "configs" / "rustrel-2015-calibrated-paper-units.toml",
          "SI": ROOT / "configs" / "rustrel-2015-calibrated.toml"}
PARAMETERS = ROOT / "configs" / "calibration" / "rustrel-2015-parameters.toml"
#: the varied parameters: the friction, the fractures the rate enters and the fault's aperture
FREE = ("fault.friction", "injection.number_of_fractures", "fault.hydraulic_aperture")
PLANS = ("hold", "stop", "scale:1.5")
#: the issue's target: this many members with the three plans within TARGET_S on 2 cores
TARGET_MEMBERS, TARGET_S = 32, 30.0


def ensemble(scene, draws, at, horizon, plans, workers, steps=None, environ=None):
    """(wall of the batch (s), wall of the cluster's start (s), the member runs), and with
    ``environ`` (a variable's name) the workers' values of it."""
    calls = [(i, scene.to_dict(), d, [at], plans, horizon, None, None, None, steps)
             for i, d in enumerate(draws)]
    t0 = time.perf_counter()
    with Runner(workers) as runner:
        started = time.perf_counter() - t0
        seen = []
        if runner.client is not None:   # the workers import the package and load the numba cache
            runner.client.run(_warm)
            if environ is not None:
                seen = list(runner.client.run(os.environ.get, environ).values())
        t1 = time.perf_counter()
        runs = [None] * len(calls)
        dealt, ensemble_id = chunks(calls, workers), uuid.uuid4().hex
        for _, chunk in runner.each(run_members, [(ensemble_id, chunk) for chunk in dealt]):
            if isinstance(chunk, BaseException):
                raise chunk
            for run in chunk:
                runs[run.index] = run
        wall = time.perf_counter() - t1
    return (wall, started, runs) if environ is None else (wall, started, runs, seen)


def _warm():
    import fault_screen.stepper  # noqa: F401

    return True


def list_schedule(costs, workers):
    """When the last of ``workers`` idle cores ends, each taking the next task (cost: its CPU
    time, s) as it is free, in order: the wall time a dealing gives without other load."""
    free = [0.0] * max(workers, 1)
    for cost in costs:
        k = free.index(min(free))
        free[k] += cost
    return max(free)


def balance(runs, workers):
    """(CPU time of the busiest worker (s), the idle-core wall time of one member a task and
    of two tasks a worker, dealt round robin as before, both from the same members' CPU times)."""
    per_worker = {}
    for r in runs:
        per_worker[r.worker] = per_worker.get(r.worker, 0.0) + r.cpu_s
    cpu = [r.cpu_s for r in sorted(runs, key=lambda r: r.index)]
    tasks = [sum(cpu[i] for i in chunk) for chunk in chunks(list(range(len(cpu))), workers, per_worker=2)]
    return max(per_worker.values()), list_schedule(cpu, workers), list_schedule(tasks, workers)


def rows_for(scene_label, label, wall, started, runs, workers):
    ok = [r for r in runs if r.ok]
    busiest, one_each, in_tasks = balance(ok, workers)
    cpu = sorted(r.cpu_s for r in ok)
    others = statistics.median(r.cpu_s - r.thread_cpu_s for r in ok)
    spread = summarise(runs)
    p = "; ".join(f"{m.plan}: {m.p_yellow:.2f}" for m in spread)
    median = cpu[len(cpu) // 2]
    made, shared = sum(r.factorizations for r in ok), sum(r.shared_factorizations for r in ok)
    return [(scene_label, label, f"{len(ok)}/{len(runs)}", f"{wall:.1f}", f"{started:.1f}",
             f"{median:.2f}", f"{others:.2f}", f"{cpu[-1]:.2f}", f"{sum(cpu) / max(workers, 1):.1f}",
             f"{busiest:.1f}", f"{one_each:.1f} / {in_tasks:.1f}",
             f"{TARGET_MEMBERS * median / max(workers, 1):.0f}", f"{made} / {shared}", p)]


def profile(scene, draws, at, horizon, plans, ladder):
    """({phase: [CPU time (s) of each member]}, {phase: what it did, for the last member}) of
    ``draws[1:]`` run in turn in this process after ``draws[0]`` (which loads the compiled
    kernels), one store of shared bulk data for all, as ``run_members`` runs them: the phases of
    ``run_member`` taken apart."""
    from fault_screen.ensemble import scene_with
    from fault_screen.forecast.ensemble import BAND_METRICS
    from fault_screen.forecast.lookahead import LookAhead
    from fault_screen.screening.stepwise import StepScreening
    from fault_screen.shared_bulk import SharedBulk, sharing
    from fault_screen.stepper import Simulation

    phases, notes, scene_dict = {}, {}, scene.to_dict()
    with sharing(SharedBulk()):
        for k, draw in enumerate(draws):
            seen, clock = {}, [time.process_time()]

            def tick(phase, note=""):
                now = time.process_time()
                seen[phase] = seen.get(phase, 0.0) + now - clock[0]
                clock[0] = now
                notes[phase] = note

            member = scene_with(Scene.from_dict(scene_dict), draw)
            tick("scene with the draw")
            sim = Simulation(member)
            fp = sim.disc.fault_points
            screening = StepScreening.for_scene(member, fp.s - sim.disc.injection.s, fp.weight)
            screening.screen_simulation(sim)
            tick("set-up: discretisation, solver, screening")
            while sim.advance(at, align=True, max_steps=1):
                if sim.steps == 1:
                    tick("history: first step", "the bulk's fixed pattern, order, first factors")
                else:
                    tick("history: the other steps")
                screening.screen_simulation(sim)
                tick("history: screening every row")
            tick("history: the other steps", f"{sim.steps - 1} steps")
            ahead = LookAhead(sim, screening, **member_steps({"ladder": ladder}))
            tick("look-ahead: fork and screening state")
            forecasts = []
            for plan in plans:
                made = ahead.ladder.factorizations
                forecasts.append(ahead.run(plan, horizon))
                tick(f"look-ahead: plan {plan.name}", f"{len(forecasts[-1].time) - 1} steps, "
                     f"{ahead.ladder.factorizations - made} factorisations")
            for f in forecasts:
                f.metrics = {key: v for key, v in f.metrics.items() if key in BAND_METRICS}
            size = len(pickle.dumps(MemberRun(index=k, params=draw, ok=True, forecasts=forecasts)))
            tick("result: lean forecasts, pickled", f"{size / 1e3:.0f} kB")
            if k:
                for phase, cpu in seen.items():
                    phases.setdefault(phase, []).append(cpu)
    return phases, notes


def profile_rows(scene_label, phases, notes):
    total = [sum(cpu) for cpu in zip(*phases.values())]
    whole = statistics.median(total)
    rows = [(scene_label, phase, notes[phase], f"{statistics.median(cpu):.3f}",
             f"{100 * statistics.median(cpu) / whole:.0f} %") for phase, cpu in phases.items()]
    return rows + [(scene_label, "the member", f"median of {len(total)}", f"{whole:.3f}", "100 %")]


def history_cost(scene_label, label, exact_runs, runs):
    """The state at the forecast time and the forecasts of members whose history took longer
    steps, against the same members on the scene's own steps (both looking ahead alike)."""
    pairs = [(a, b) for a, b in zip(exact_runs, runs) if a.ok and b.ok]
    du, dp, dlevel, dtty, n = 0.0, 0.0, 0, 0.0, len(pairs)
    for a, b in pairs:
        for fa, fb in zip(a.forecasts, b.forecasts):
            ua, ub = fa.metrics["max_utilisation"][0], fb.metrics["max_utilisation"][0]
            pa, pb = fa.metrics["injection_overpressure"][0], fb.metrics["injection_overpressure"][0]
            du = max(du, abs(ub - ua))
            dp = max(dp, abs(pb - pa) / abs(pa) if pa else 0.0)
            if fa.time_to_yellow is not None and fb.time_to_yellow is not None:
                dtty = max(dtty, abs(fb.time_to_yellow - fa.time_to_yellow))
        dlevel += a.forecasts[0].level_now != b.forecasts[0].level_now
    pa = "; ".join(f"{m.plan}: {m.p_yellow:.2f}" for m in summarise([a for a, _ in pairs]))
    pb = "; ".join(f"{m.plan}: {m.p_yellow:.2f}" for m in summarise([b for _, b in pairs]))
    return [(scene_label, label, str(n), f"{du:.1e}", f"{dp:.1e}", str(dlevel), f"{dtty:.0f}", pa, pb)]


#: what Dask's nanny sets in its workers before it starts them unless told not to
#: (fault_screen.ensemble.WORKER_CONFIG unsets it): what the A/B of --malloc-ab puts back
DASK_MALLOC_TRIM = 65536


def malloc_ab(scene, draws, at, horizon, plans, workers, steps, rounds):
    """Rows of the ensemble run alternately with the workers' environment as the package sets it
    (MALLOC_TRIM_THRESHOLD_ unset) and with Dask's default put back, ``rounds`` times each, the
    order swapped every round (one session, the same members). The setting must be in the
    nanny's environment before it starts a worker (glibc reads it once, at the start), as
    Dask's own ``distributed.nanny.pre-spawn-environ`` puts it there."""
    from fault_screen import ensemble as runner_module

    environ = runner_module.WORKER_CONFIG["distributed"]["nanny"]["pre-spawn-environ"]
    out = []
    for k in range(rounds):
        for value in ((None, DASK_MALLOC_TRIM) if k % 2 == 0 else (DASK_MALLOC_TRIM, None)):
            saved, before = environ["MALLOC_TRIM_THRESHOLD_"], os.environ.get("MALLOC_TRIM_THRESHOLD_")
            environ["MALLOC_TRIM_THRESHOLD_"] = value
            try:
                wall, started, runs, seen = ensemble(scene, draws, at, horizon, plans, workers, steps,
                                                     environ="MALLOC_TRIM_THRESHOLD_")
            finally:
                environ["MALLOC_TRIM_THRESHOLD_"] = saved
                # (the nanny sets its pre-spawn variables in this process's environment too,
                # where the next cluster's workers would inherit them)
                if before is None:
                    os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
                else:
                    os.environ["MALLOC_TRIM_THRESHOLD_"] = before
            ok = [r for r in runs if r.ok]
            cpu = sorted(r.cpu_s for r in ok)
            out.append((f"{k + 1}", "unset" if value is None else str(value), ", ".join(map(str, seen)),
                        f"{len(ok)}/{len(runs)}", f"{wall:.1f}", f"{started:.1f}",
                        f"{cpu[len(cpu) // 2]:.2f}", f"{sum(cpu) / max(workers, 1):.1f}"))
            print(out[-1], flush=True)
    return out


def table(head, rows):
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--members", type=int, default=TARGET_MEMBERS, help=f"members on the ladder [{TARGET_MEMBERS}]")
    ap.add_argument("--exact-members", type=int, default=4,
                    help="members on the scene's own steps (0: none) [4]")
    ap.add_argument("--at", type=float, default=700.0, help="forecast time (s) [700]")
    ap.add_argument("--horizon", type=float, default=3600.0, help="horizon (s) [3600]")
    ap.add_argument("--workers", type=int, default=2, help="local worker processes [2]")
    ap.add_argument("--ladder", type=float, default=ENSEMBLE_LADDER, metavar="DT_MAX",
                    help=f"the ladder's largest step (s) [{ENSEMBLE_LADDER:g}, the --members default]")
    ap.add_argument("--history-dt-max", type=float, default=None, metavar="DT_MAX",
                    help="also the ladder's members with their history on steps doubling up to DT_MAX (s) "
                         "(0: not) [the ladder's: the history on the look-ahead's steps]")
    ap.add_argument("--profile", type=int, default=3, metavar="N",
                    help="members whose CPU time is split into phases, in this process (0: none) [3]")
    ap.add_argument("--scene", choices=("default", "SI", "both"), default="both", help="scenes [both]")
    ap.add_argument("--malloc-ab", type=int, default=0, metavar="ROUNDS",
                    help="only the A/B of the workers' MALLOC_TRIM_THRESHOLD_ (unset, as the package "
                         "starts them, against Dask's 65536), ROUNDS alternations on the ladder [0: not]")
    ap.add_argument("--quick", action="store_true", help="4 members, 10 min ahead")
    ap.add_argument("--doc", action="store_true", help="write docs/performance/forecast-ensemble.md")
    args = ap.parse_args(argv)
    members, exact, horizon = ((4, min(args.exact_members, 2), 600.0) if args.quick
                               else (args.members, args.exact_members, args.horizon))
    history = args.ladder if args.history_dt_max is None else args.history_dt_max
    profiled = min(args.profile, 1) if args.quick else args.profile
    load = os.getloadavg()[0]
    params = load_parameters(PARAMETERS).select(list(FREE))
    draws = sample_parameters(params, max(members, exact, profiled + 1), "normal", 1)
    plans = [parse_plan(p) for p in PLANS]
    print(f"{members} members on a ladder to {args.ladder:g} s and {exact} on the scene's steps x {len(plans)} "
          f"plans ({', '.join(PLANS)}) at {args.at:g} s, {horizon:g} s ahead, {args.workers} workers; "
          f"{os.cpu_count()} cores, load average {load:.1f} at the start", flush=True)
    if args.malloc_ab:
        ab = []
        for name in (("default", "SI") if args.scene == "both" else (args.scene,)):
            ab += [(name, *row) for row in malloc_ab(Scene.from_toml(SCENES[name]), draws[:members], args.at,
                                                     horizon, plans, args.workers, {"ladder": args.ladder},
                                                     args.malloc_ab)]
        print("\n".join(table(("scene", "round", "MALLOC_TRIM_THRESHOLD_ set", "the workers had",
                                "members ok", "wall (s)",
                                "cluster start (s)", "CPU per member, median (s)",
                                f"sum of CPU / {args.workers} workers (s)"), ab)), flush=True)
        return 0
    rows, costs, phases = [], [], []
    for name in (("default", "SI") if args.scene == "both" else (args.scene,)):
        scene = Scene.from_toml(SCENES[name])
        label = f"{name}, {SCENES[name].name}"
        if profiled > 0:
            phases += profile_rows(label, *profile(scene, draws[:profiled + 1], args.at, horizon, plans, args.ladder))
            print("\n".join(map(str, phases[-3:])), flush=True)
        laddered = ensemble(scene, draws[:members], args.at, horizon, plans, args.workers, {"ladder": args.ladder})
        rows += rows_for(label, f"ladder to {args.ladder:g} s", *laddered, args.workers)
        print(rows[-1], flush=True)
        if history > 0:
            what = f"ladder to {args.ladder:g} s, history on steps to {history:g} s"
            longer = ensemble(scene, draws[:members], args.at, horizon, plans, args.workers,
                              {"ladder": args.ladder, "history_dt_max": history})
            rows += rows_for(label, what, *longer, args.workers)
            costs += history_cost(label, f"history on steps to {history:g} s", laddered[2], longer[2])
            print(rows[-1], costs[-1], flush=True)
        if exact:
            rows += rows_for(label, "scene's own steps", *ensemble(
                scene, draws[:exact], args.at, horizon, plans, args.workers), args.workers)
            print(rows[-1], flush=True)
    head = ("scene", "look-ahead steps", "members ok", "wall (s)", "cluster start (s)",
            "CPU per member, median (s)", "of which the worker's other threads, median (s)",
            "CPU per member, most (s)", f"sum of CPU / {args.workers} workers (s)",
            "CPU of the busiest worker (s)",
            f"the same CPU times on {args.workers} idle cores, one member a task / {2 * args.workers} tasks (s)",
            f"{TARGET_MEMBERS} members on {args.workers} idle cores, from the median CPU (s)",
            "factorisations made / shared", "P(yellow) per plan")
    lines = table(head, rows)
    if phases:
        lines = ([f"One member's CPU time by phase ({profiled} members in turn in this process after one that "
                  f"loads the compiled kernels, sharing one store as `run_members` does; history on the scene's "
                  f"steps, look-ahead on the ladder to {args.ladder:g} s):", ""]
                 + table(("scene", "phase", "what", "CPU, median (s)", "share"), phases)
                 + ["", "The ensemble on the workers:", ""] + lines)
    if costs:
        lines += ["", "The history on longer steps against the scene's own (the same members, both looking ahead on "
                  "the ladder): the state at the forecast time and what the forecasts say.", ""]
        lines += table(("scene", "history", "members", "utilisation at the forecast time, largest difference",
                        "injection overpressure then, largest relative difference", "members whose level then differs",
                        "time to yellow, largest difference (s)", "P(yellow), scene's steps",
                        "P(yellow), longer steps"), costs)
    print("\n".join(lines), flush=True)
    if args.doc:
        from doc_tables import write

        intro = (f"Each member is a calibrated Rustrel scene (`default`: the paper's units, the scene "
                 f"`fault-screen run` runs; `SI`: the SI reading of the same table) with one draw of "
                 f"{', '.join(f'`{k}`' for k in FREE)} (normal, from "
                 f"`configs/calibration/rustrel-2015-parameters.toml`, seed 1), its history run from 0 to "
                 f"{args.at:g} s on the scene's own steps, then the plans {', '.join(f'`{p}`' for p in PLANS)} "
                 f"each {horizon:g} s ahead, screened: {members} members looking ahead on the step ladder to "
                 f"{args.ladder:g} s (the default of `fault-screen forecast --members`), {exact} on the scene's own "
                 f"steps. The members go to {args.workers} local workers one member a task, a free worker "
                 f"taking the next (`run_members`: the members one process runs share the bulk's order and "
                 f"symbolic analysis, the positions of its fixed pattern and the factors of equal bulks; the "
                 f"workers run without Dask's statistical profiler, and the workers, the scheduler and the "
                 f"nannies with slower ticks and monitors: `WORKER_CONFIG`). The target (issue 29): {TARGET_MEMBERS} "
                 f"members x 3 plans within {TARGET_S:g} s on 2 cores. The CPU time per member does not grow "
                 f"with the machine's load as the wall time does: {TARGET_MEMBERS} times its median over the "
                 f"workers estimates the target's wall time on idle cores; the balance columns give the CPU "
                 f"time of the busiest worker, and when the last of {args.workers} idle cores would end with "
                 f"the members' own CPU times dealt one a task (as now) or in {2 * args.workers} tasks of "
                 f"several members round robin (as before).")
        print(write("forecast-ensemble", "Ensemble forecast speed", intro, lines + ["", *NOTES.splitlines()], load))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The theta ladder (``time.theta_min``) on the paper-units Rustrel scene with growing steps
(growth 1.2, dt_max 600 s, 3 h of shut-in after the 1400 s of injection: the [stepsize] scene of
``performance.py``), against backward Euler's growing run (theta_min unset).

Timing: each setting's run advanced to its end in one call (as ``performance.py`` does), RUNS
times, the settings interleaved (a busy machine slows them alike); every step after the first is
"unchanged" (the size of the step before), "in rung" (a new size in the same rung: no bulk
factorisation) or "new rung" (a new size that factorises: every new size without the ladder).
Medians of each kind's wall and CPU time (the process's: both factorisation threads), and the
ratio of the changed kinds to the unchanged; "changed (all)" pools both changed kinds (what
``performance.py``'s [stepsize] row compares: issue 28's target, at most 3x).

Accuracy: the same settings advanced to the end of injection (1400 s) and then to the end; the
overpressure at the injection point and the slip at the fault point nearest it, there and then,
relative to backward Euler's growing run and to a run on fixed 5-s steps (the reference).

    python benchmarks/theta_ladder.py [--runs 3] [--theta-min 0.6667 0.6 0.75]
"""
from __future__ import annotations

import argparse
import dataclasses
import resource
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
#: the end of injection in the paper-units scene (s)
INJECTION_END = 1400.0


def growing_scene(theta_min=None):
    """performance.py's [stepsize] scene with ``time.theta_min`` set to ``theta_min`` (None:
    backward Euler's growing run)."""
    import fault_screen  # noqa: F401 (first: performance puts its own tree on sys.path)
    import performance

    s = performance._scene("paper-growing")
    return s.replace(time=dataclasses.replace(s.time, theta_min=theta_min))


def timed_run(theta_min):
    """Per step after the first: (kind, wall, CPU); the whole run's wall and CPU; steps and bulk
    factorisations."""
    from fault_screen import Simulation

    scene = growing_scene(theta_min)
    rows = []
    state = {}

    def progress(step, t, end, wall):
        now = (time.perf_counter(), time.process_time())
        dt, rung = sim.last_row["dt"], sim.rung
        if state:
            kind = ("unchanged" if dt == state["dt"]
                    else "in rung" if theta_min is not None and rung == state["rung"]
                    else "new rung")
            rows.append((kind, now[0] - state["at"][0], now[1] - state["at"][1]))
        state.update(dt=dt, rung=rung, at=now)

    t0, c0 = time.perf_counter(), time.process_time()
    sim = Simulation(scene)
    state.clear()
    sim.advance(scene.time.end, progress=progress)
    return dict(rows=rows, wall=time.perf_counter() - t0, cpu=time.process_time() - c0,
                steps=sim.steps, factorisations=sim.solver.factorizations)


def observed(scene):
    """(overpressure at the injection point (Pa), slip at the fault point nearest it (m)) at the
    end of injection and at the end of the scene."""
    from fault_screen import Simulation

    sim = Simulation(scene)
    nearest = int(np.argmin(np.abs(sim.disc.fault_points.s - sim.disc.injection.s)))
    out = []
    for t in (INJECTION_END, scene.time.end):
        sim.advance(t)
        out.append((float(sim.disc.injection_overpressure(sim.x)),
                    float(sim.last_row["slip"][nearest])))
    return np.array(out)


def _label(theta_min):
    return "backward Euler" if theta_min is None else f"theta_min {theta_min:.3g}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--theta-min", type=float, nargs="*", default=[2 / 3, 0.6, 0.75])
    args = parser.parse_args(argv)
    settings = [None] + list(args.theta_min)
    timed_run(None)   # (warm: kernels loaded, caches)
    runs = {s: [] for s in settings}
    for _ in range(args.runs):
        for s in settings:
            runs[s].append(timed_run(s))

    print(f"## Timing: paper-units Rustrel, growth 1.2, dt_max 600 s, +3 h shut-in; {args.runs} runs "
          "pooled (median ms; ratio to the unchanged size)")
    print("| setting | steps | bulk factorisations | kind | steps of it | wall ms | CPU ms | "
          "wall ratio | CPU ratio |")
    print("|---|---|---|---|---|---|---|---|---|")
    for s in settings:
        rows = [r for run in runs[s] for r in run["rows"]]
        med = {}
        for kind in ("unchanged", "in rung", "new rung", "changed (all)"):
            of = [r for r in rows if r[0] == kind or (kind == "changed (all)" and r[0] != "unchanged")]
            if of:
                med[kind] = (statistics.median(r[1] for r in of), statistics.median(r[2] for r in of),
                             len(of) // args.runs)
        base = med["unchanged"]
        for kind, (w, c, n) in med.items():
            print(f"| {_label(s)} | {runs[s][0]['steps']} | {runs[s][0]['factorisations']} | {kind} | "
                  f"{n} | {1e3 * w:.2f} | {1e3 * c:.2f} | {w / base[0]:.2f} | {c / base[1]:.2f} |")
    print()
    print("| setting | whole run wall s (median) | CPU s (median) |")
    print("|---|---|---|")
    for s in settings:
        print(f"| {_label(s)} | {statistics.median(r['wall'] for r in runs[s]):.3f} | "
              f"{statistics.median(r['cpu'] for r in runs[s]):.3f} |")

    reference_scene = growing_scene()
    reference_scene = reference_scene.replace(time=dataclasses.replace(
        reference_scene.time, growth=1.0, dt_max=None))
    reference = observed(reference_scene)
    euler = observed(growing_scene())
    print()
    print(f"## Accuracy at the injection point (reference: fixed 5-s steps: p {reference[0, 0]:.6g} Pa, "
          f"slip {reference[0, 1]:.6g} m at {INJECTION_END:g} s; p {reference[1, 0]:.6g} Pa, slip "
          f"{reference[1, 1]:.6g} m at the end)")
    print("| setting | p vs 5 s, 1400 s | slip vs 5 s, 1400 s | p vs 5 s, end | slip vs 5 s, end | "
          "p vs BE, 1400 s | slip vs BE, 1400 s | p vs BE, end | slip vs BE, end |")
    print("|---|---|---|---|---|---|---|---|---|")
    for s in settings:
        got = euler if s is None else observed(growing_scene(s))
        vs_ref = (got - reference) / np.abs(reference)
        vs_be = (got - euler) / np.abs(euler)
        cells = [f"{v:+.2e}" for v in (*vs_ref.ravel()[[0, 1, 2, 3]], *vs_be.ravel()[[0, 1, 2, 3]])]
        print(f"| {_label(s)} | " + " | ".join(cells) + " |")
    print()
    print(f"peak memory (max RSS): {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()

"""Long operations at default settings: peak memory, result file and wall time.

    python benchmarks/long_operation.py [--cases rustrel,steady-3d,basel,monitor-30d] [--write-docs]
    python benchmarks/long_operation.py --durations 1h,1d,3d,30d [--nx 20] [--dt-max 60]

The cases (issue 28's targets), each command in its own process (peak resident memory from
``ru_maxrss`` of the child), with the bundled calibrated Rustrel scene
(``configs/rustrel-2015-calibrated.toml``, 50 x 51 elements) and no ``[output]`` table, so the
automatic profile rule and the bounded reads are what is measured:

* ``rustrel``: ``fault-screen run`` of the scene (1400 s): the reference peak memory;
* ``steady-3d``: ``fault-screen replay`` of a steady synthetic log, one sample a minute for
  3 days (target: peak memory <= 1.5 x the reference, file <= 50 MB, every day in the series);
* ``basel``: ``fault-screen replay --plot`` of the Basel 2006 log
  (``../shared/data/basel-2006/``; target: peak memory <= 1.5 x the reference, file <= 100 MB);
* ``monitor-30d``: ``fault-screen monitor`` following 30 days of the synthetic disposal-like log
  below from its start, steps growing from 5 s by 1.2 to 10 min.

Each row also gives the estimate printed at the start of the run (steps, file, memory, wall
time: :mod:`fault_screen.run_estimate`) beside what was measured; the estimated wall time (an
idle machine's) beside the CPU time of the child. ``--write-docs`` writes the table to
``docs/performance/long-operations.md``.

``--sizes 20,50,100,200`` prints the data the estimates of memory and wall time are fitted to:
``fault-screen run`` of the scene on nx x (nx + 1) meshes, to its end and for its first step
alone (the start-up), CPU time and peak memory beside the estimate.

``--durations`` runs the older sweep instead: for each duration, a synthetic disposal-like
injection log at one sample every 5 s (steady rates with a few changes: 5, 8, 3 and 6 L/min in
turn, changing every 6 h of log time; a little noise) is written in full to a file, and
``fault-screen monitor`` follows it in a subprocess from its start (catching up, as after a
restart), with a state file, a streamed result file and ``--idle-exit``. The scene is the
calibrated Rustrel scene on an nx x (nx+1) mesh, with steps growing from 5 s by 1.2 up to
``--dt-max`` and ``[output] profile_interval = 1 h``. Prints, per duration: samples, model
steps, wall time, peak resident memory, result file size, and the ratio of the peak memory to
that of the first (shortest) duration.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = 5.0                          # s between samples
RATES = (5.0, 8.0, 3.0, 6.0)          # L/min, in turn
CHANGE = 6 * 3600.0                   # s between rate changes
UNITS = {"h": 3600.0, "d": 86400.0}


def duration(text: str) -> float:
    return float(text[:-1]) * UNITS[text[-1]]


def write_log(path: Path, seconds: float, seed: int = 1) -> int:
    """The synthetic log: elapsed seconds and L/min, one sample every SAMPLE s."""
    t = np.arange(0.0, seconds + 0.5 * SAMPLE, SAMPLE)
    q = np.array(RATES)[(t // CHANGE).astype(int) % len(RATES)]
    q = q * (1.0 + 0.01 * np.random.default_rng(seed).standard_normal(t.size))
    return _write_log(path, t, q, "synthetic disposal-like log")


def _write_log(path: Path, t: np.ndarray, q: np.ndarray, what: str) -> int:
    """Elapsed seconds ``t`` and rates ``q`` (L/min; the first set to 0) as a CSV log."""
    q[0] = 0.0
    with open(path, "w") as fh:
        fh.write(f"# {what} (benchmarks/long_operation.py), not measured data\n")
        fh.write("time[s],flow_rate[L/min]\n")
        np.savetxt(fh, np.column_stack([t, q]), fmt=["%.0f", "%.4f"], delimiter=",")
    return int(t.size)


def write_scene(path: Path, nx: int | None, dt_max: float, output="hourly") -> None:
    """The calibrated scene with growing steps; ``nx`` None: its own 50 x 51 mesh; ``output``
    None: no [output] table (the automatic rule)."""
    sys.path.insert(0, str(ROOT))
    from fault_screen import Scene
    from fault_screen.scene import OutputSpec

    s = Scene.from_toml(SCENE)
    if nx is not None:
        s = s.replace(mesh=dataclasses.replace(s.mesh, nx=nx, ny=nx + 1))
    s = s.replace(time=dataclasses.replace(s.time, dt=5.0, growth=1.2, dt_max=dt_max),
                  output=OutputSpec(profile_interval=3600.0) if output else OutputSpec())
    path.write_text(s.to_toml())


def run_monitor(scene: Path, log: Path, folder: Path) -> dict:
    out, state = folder / "result.h5", folder / "state.h5"
    r = run_child([*CLI, "monitor", scene, "--follow", log, "--out", out, "--state", state,
                   "--idle-exit", "1", "--poll", "0.1", "--checkpoint-every", "500", "--quiet"])
    wall, rss = r["wall"], r["rss"]
    import h5py

    with h5py.File(out, "r") as h5:
        steps = len(h5["time"]) - 1
        profiles = len(h5["fault/time"])
        t_end = float(h5["time"][-1])
    return dict(wall=wall, rss=rss, size=out.stat().st_size / 1e6,
                steps=steps, profiles=profiles, t_end=t_end)


SCENE = ROOT / "configs" / "rustrel-2015-calibrated.toml"
BASEL = ROOT.parent / "shared" / "data" / "basel-2006" / "basel-2006-injection-1min.csv"
CLI = [sys.executable, "-c", "from fault_screen.cli import main; main()"]
CASES = ("rustrel", "rustrel-plot", "steady-3d", "monitor-30d", "basel")


def run_child(cmd: list, ok=(0,)) -> dict:
    """Wall time (s), CPU time (s, user and system, of the child alone: on a shared machine the
    figure closest to an idle machine's wall time), peak resident memory (MB, ``ru_maxrss`` of
    the child alone) and standard output of ``cmd`` run in its own process (its output into
    files, so no pipe can fill)."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        wall0 = time.perf_counter()
        proc = subprocess.Popen([str(c) for c in cmd], env=env, stdout=out, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - wall0
        proc.returncode = code = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read().decode(), err.read().decode()
    if code not in ok:
        raise SystemExit(f"{' '.join(map(str, cmd))} failed ({code}):\n{stderr[-3000:]}")
    return dict(wall=wall, cpu=usage.ru_utime + usage.ru_stime, rss=usage.ru_maxrss / 1024.0,
                stdout=stdout)


def steady_log(path: Path, days: float, rate_l_min: float = 5.0, sample: float = 60.0) -> int:
    """A steady log: ``rate_l_min`` at one sample every ``sample`` s (first sample 0)."""
    t = np.arange(0.0, days * 86400.0 + 0.5 * sample, sample)
    return _write_log(path, t, np.full(t.size, rate_l_min), "steady synthetic log")


def file_facts(path: Path) -> dict:
    """Size (MB), series rows, profiles, days of model time with at least one row, days."""
    import h5py

    with h5py.File(path, "r") as h5:
        t = h5["time"][()]
        profiles = h5["fault/time"].shape[0]
    days = int(np.ceil(t[-1] / 86400.0)) if t.size else 0
    present = len(np.unique(np.minimum(t // 86400.0, max(days - 1, 0)))) if t.size else 0
    return dict(size=path.stat().st_size / 1e6, rows=int(t.size), profiles=int(profiles),
                days=days, present=present, gap=float(np.max(np.diff(t))) if t.size > 1 else 0.0)


def estimate_for(scene_path: Path, log: Path | None, plot: bool) -> dict:
    """The estimate printed at the start of the same run."""
    sys.path.insert(0, str(ROOT))
    from fault_screen import Scene
    from fault_screen.run_estimate import estimate_run

    scene, samples = Scene.from_toml(scene_path), 0
    if log is not None:
        from fault_screen.io import read_injection_log
        from fault_screen.io.replay import plan_replay

        plan = plan_replay(scene, read_injection_log(log), None)
        scene, samples = plan.scene, len(plan.log_arrays["time"])
    e = estimate_run(scene, plot=plot, log_samples=samples)
    # memory in the unit of ru_maxrss / 1024 (2**20 bytes), as measured
    return dict(steps=e.steps, size=e.file_bytes / 1e6, rss=e.memory_bytes / 2**20,
                wall=e.wall_seconds)


def monitor_estimate(scene_path: Path) -> dict:
    """What the monitor prints at its start that a row can stand beside: its peak memory (its
    other figures are per day of operation, at the first day's steps and profiles)."""
    sys.path.insert(0, str(ROOT))
    from fault_screen import Scene
    from fault_screen.run_estimate import estimate_monitor

    return dict(rss=estimate_monitor(Scene.from_toml(scene_path)).memory_bytes / 2**20)


def case(name: str, tmp: Path, basel: Path = BASEL) -> dict:
    folder = tmp / name
    folder.mkdir()
    out = folder / "result.h5"
    log, plot, scene = None, False, SCENE
    if name in ("rustrel", "rustrel-plot"):
        plot = name == "rustrel-plot"
        cmd = [*CLI, "run", SCENE, "--out", out, "--quiet"] + (["--plot", folder / "figs"] if plot else [])
    elif name == "steady-3d":
        log = folder / "log.csv"
        steady_log(log, 3.0)
        cmd = [*CLI, "replay", SCENE, "--log", log, "--out", out, "--quiet"]
    elif name == "basel":
        log, plot = basel, True
        cmd = [*CLI, "replay", SCENE, "--log", log, "--out", out, "--plot", folder / "figs", "--quiet"]
    elif name == "monitor-30d":
        log, scene = folder / "log.csv", folder / "scene.toml"
        write_log(log, 30 * 86400.0)
        write_scene(scene, None, 600.0, output=None)
        cmd = [*CLI, "monitor", scene, "--follow", log, "--out", out, "--state", folder / "state.h5",
               "--idle-exit", "1", "--poll", "0.1", "--checkpoint-every", "500", "--quiet"]
    else:
        raise SystemExit(f"unknown case {name}; one of {', '.join(CASES)}")
    est = estimate_for(scene, log, plot) if name != "monitor-30d" else monitor_estimate(scene)
    r = run_child(cmd, ok=(0, 4))
    return dict(name=name, est=est, **r, **file_facts(out))


def cases_main(names: list, page: str | None, basel: Path = BASEL) -> None:
    """Run the cases ``names``; ``page``: the docs/performance page to write (None: print only)."""
    load0 = os.getloadavg()[0]
    head = (f"{'case':>13} {'steps':>8} {'est.':>8} {'wall (s)':>9} {'CPU (s)':>8} {'est.':>7} "
            f"{'peak RSS (MB)':>13} {'est.':>6} {'x rustrel':>9} {'file (MB)':>9} {'est.':>7} "
            f"{'profiles':>8} {'days':>5}")
    print(f"load {load0:.2f} (1-min average), {os.cpu_count()} cores")
    print(head)
    rows, ref = [], None
    md = ["| case | steps (estimate) | wall time s | CPU time s (estimate) | "
          "peak memory MB (estimate) | x rustrel run | result file MB (estimate) | profiles | "
          "days with rows |",
          "|---|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            r = case(name, Path(tmp), basel)
            ref = r["rss"] if name == "rustrel" else ref
            ratio = r["rss"] / ref if ref else float("nan")
            e = r["est"] or {}
            fmt = lambda v, f: format(v, f) if v is not None else "-"  # noqa: E731
            print(f"{name:>13} {r['rows'] - 1:>8} {fmt(e.get('steps'), '>8'):>8} {r['wall']:>9.1f} "
                  f"{r['cpu']:>8.1f} {fmt(e.get('wall'), '.0f'):>7} {r['rss']:>13.0f} "
                  f"{fmt(e.get('rss'), '.0f'):>6} {ratio:>9.2f} {r['size']:>9.1f} "
                  f"{fmt(e.get('size'), '.1f'):>7} {r['profiles']:>8} "
                  f"{r['present']:>2}/{r['days']:<2}", flush=True)
            md.append(f"| {name} | {r['rows'] - 1:,} ({fmt(e.get('steps'), ',')}) | "
                      f"{_seconds(r['wall'])} | {_seconds(r['cpu'])} ({_seconds(e.get('wall'))}) | "
                      f"{r['rss']:.0f} ({fmt(e.get('rss'), '.0f')}) | {ratio:.2f} | "
                      f"{r['size']:.1f} ({fmt(e.get('size'), '.1f')}) | {r['profiles']:,} | "
                      f"{r['present']} of {r['days']} |")
            rows.append(r)
            if page:                # after every case: a long series leaves the rows it has
                _write_docs(page, md, load0)


def sizes_main(sizes: list) -> None:
    """The data the estimates are fitted to: ``fault-screen run`` of the bundled scene on
    nx x (nx + 1) meshes, to its end and for one step (the start-up: imports, kernels, the
    model), each in its own process: CPU time (start-up and per step), peak memory, beside
    the estimate of :func:`fault_screen.run_estimate.estimate_run`."""
    sys.path.insert(0, str(ROOT))
    from fault_screen import Scene
    from fault_screen.run_estimate import estimate_run

    base = Scene.from_toml(SCENE)
    print(f"load {os.getloadavg()[0]:.2f} (1-min average), {os.cpu_count()} cores; CPU: user + "
          "system time of the child")
    print(f"{'mesh':>9} {'unknowns':>8} {'steps':>5} {'wall (s)':>8} {'CPU (s)':>7} {'est.':>6} "
          f"{'start CPU':>9} {'ms/step':>7} {'est.':>6} {'peak RSS (MB)':>13} {'est.':>6}")
    with tempfile.TemporaryDirectory() as tmp:
        for nx in sizes:
            scene = base.replace(mesh=dataclasses.replace(base.mesh, nx=nx, ny=nx + 1))
            path = Path(tmp) / f"{nx}.toml"
            path.write_text(scene.to_toml())
            e = estimate_run(scene)
            run = [*CLI, "run", path, "--out", Path(tmp) / f"{nx}.h5", "--quiet"]
            full = run_child(run, ok=(0, 4))
            one = run_child([*run, "--set", f"time.end={scene.time.dt:g}"], ok=(0, 4))
            per_step = (full["cpu"] - one["cpu"]) / max(e.steps - 1, 1)
            e_step = (e.wall_seconds - estimate_run(scene.replace(time=dataclasses.replace(
                scene.time, end=scene.time.dt))).wall_seconds) / max(e.steps - 1, 1)
            print(f"{nx:>4} x {nx + 1:<3} {e.unknowns:>8} {e.steps:>5} {full['wall']:>8.1f} "
                  f"{full['cpu']:>7.1f} {e.wall_seconds:>6.1f} {one['cpu']:>9.2f} "
                  f"{1e3 * per_step:>7.1f} {1e3 * e_step:>6.1f} {full['rss']:>13.0f} "
                  f"{e.memory_bytes / 2**20:>6.0f}", flush=True)


def _seconds(s: float | None) -> str:
    """Seconds to the tenth below 10 s (a short run's estimate is to be read), else whole."""
    return "-" if s is None else f"{s:.1f}" if s < 10 else f"{s:.0f}"


def _write_docs(page: str, md: list, load0: float) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from doc_tables import write

    intro = ("The bundled calibrated Rustrel scene (50 x 51 elements) at default settings (no "
             "`[output]` table: the automatic profile rule; the summary and the figures read "
             "the file in bounded pieces), each command in its own process. `rustrel`: "
             "`fault-screen run` (1400 s), the reference memory; `rustrel-plot`: the same with "
             "`--plot`; `steady-3d`: `fault-screen replay` of a steady 5 L/min log sampled every "
             "minute for 3 days; `basel`: `fault-screen replay --plot` of the Basel 2006 log "
             "(6.46 days); `monitor-30d`: `fault-screen monitor` following 30 days of a "
             "disposal-like log from its start, steps growing from 5 s by 1.2 to 10 min. In "
             "brackets: the estimate the run prints at its start (`scene check` prints the "
             "same); the wall time it estimates is an idle machine's, so it stands beside the "
             "CPU time of the process (user and system), which the other processes on a shared "
             "machine change far less than the wall time. Memory: peak resident set "
             "(`ru_maxrss`), MB of 2^20 bytes as in the other tables; the monitor estimates "
             "per day of operation, so only its memory stands in its row. Targets: peak memory at most 1.5 x the `rustrel` run; result file at most "
             "50 MB (3 days) and 100 MB (Basel); every day of the run in the series.")
    write(page, "Long operations at default settings", intro, md, load0)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated, of " + ", ".join(CASES))
    ap.add_argument("--basel", type=Path, default=BASEL, help="the Basel 2006 log (CSV)")
    ap.add_argument("--write-docs", action="store_true",
                    help="write the table to docs/performance/<--page>.md")
    ap.add_argument("--page", default="long-operations", help="the page --write-docs writes")
    ap.add_argument("--durations", default=None, help="the older sweep: e.g. 1h,1d,3d,30d")
    ap.add_argument("--sizes", default=None,
                    help="the estimates' data instead: e.g. 20,50,100,200 (meshes nx x (nx + 1))")
    ap.add_argument("--nx", type=int, default=20, help="elements across the mesh")
    ap.add_argument("--dt-max", type=float, default=60.0, help="largest model step (s)")
    args = ap.parse_args(argv)
    if args.sizes is not None:
        sizes_main([int(n) for n in args.sizes.split(",")])
        return
    if args.durations is None:
        cases_main(args.cases.split(","), args.page if args.write_docs else None, args.basel)
        return
    print(f"mesh {args.nx} x {args.nx + 1}, steps 5 s growing by 1.2 to {args.dt_max:g} s, samples every "
          f"{SAMPLE:g} s, profiles every hour; load: {os.getloadavg()[0]:.2f} (1-min average), "
          f"{os.cpu_count()} cores")
    print(f"{'duration':>9} {'samples':>8} {'steps':>7} {'profiles':>8} {'wall (s)':>9} {'ms/step':>8} "
          f"{'peak RSS (MB)':>13} {'x first':>7} {'file (MB)':>9}")
    first = None
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scene = tmp / "scene.toml"
        write_scene(scene, args.nx, args.dt_max)
        for text in args.durations.split(","):
            folder = tmp / text
            folder.mkdir()
            n = write_log(folder / "log.csv", duration(text))
            r = run_monitor(scene, folder / "log.csv", folder)
            first = first or r["rss"]
            print(f"{text:>9} {n:>8} {r['steps']:>7} {r['profiles']:>8} {r['wall']:>9.1f} "
                  f"{1e3 * r['wall'] / max(r['steps'], 1):>8.1f} {r['rss']:>13.0f} "
                  f"{r['rss'] / first:>7.2f} {r['size']:>9.2f}", flush=True)


if __name__ == "__main__":
    main()

"""Memory, time and file size of the live monitor over long operations (bounded memory).

    python benchmarks/long_operation.py [--durations 1h,1d,3d,30d] [--nx 20] [--dt-max 60]

For each duration, a synthetic disposal-like injection log at one sample every 5 s (steady
rates with a few changes: 5, 8, 3 and 6 L/min in turn, changing every 6 h of log time; a
little noise) is written in full to a file, and ``fault-screen monitor`` follows it in a
subprocess from its start (catching up, as after a restart), with a state file, a streamed
result file and ``--idle-exit``. The scene is the calibrated Rustrel scene on an nx x (nx+1)
mesh, with steps growing from 5 s by 1.2 up to ``--dt-max`` (the model takes its own steps,
longer than the sample spacing, each receiving the samples' integral) and ``[output]
profile_interval = 1 h``. Prints, per duration: samples, model steps, wall time, peak resident
memory of the monitor process (``ru_maxrss`` of the child), result file size, and the ratio of
the peak memory to that of the first (shortest) duration. The target: within 1.5x of the 1-hour
run whatever the duration.
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
    q[0] = 0.0
    with open(path, "w") as fh:
        fh.write("# synthetic disposal-like log (benchmarks/long_operation.py), not measured data\n")
        fh.write("time[s],flow_rate[L/min]\n")
        np.savetxt(fh, np.column_stack([t, q]), fmt=["%.0f", "%.4f"], delimiter=",")
    return int(t.size)


def write_scene(path: Path, nx: int, dt_max: float) -> None:
    sys.path.insert(0, str(ROOT))
    from fault_screen import Scene
    from fault_screen.scene import OutputSpec

    s = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    s = s.replace(mesh=dataclasses.replace(s.mesh, nx=nx, ny=nx + 1),
                  time=dataclasses.replace(s.time, dt=5.0, growth=1.2, dt_max=dt_max),
                  output=OutputSpec(profile_interval=3600.0))
    path.write_text(s.to_toml())


def run_monitor(scene: Path, log: Path, folder: Path) -> dict:
    out, state = folder / "result.h5", folder / "state.h5"
    cmd = [sys.executable, "-c", "from fault_screen.cli import main; main()", "monitor", str(scene),
           "--follow", str(log), "--out", str(out), "--state", str(state), "--idle-exit", "1",
           "--poll", "0.1", "--checkpoint-every", "500", "--quiet"]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    wall0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - wall0
    err = proc.stderr.read().decode()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"monitor failed:\n{err[-3000:]}")
    import h5py

    with h5py.File(out, "r") as h5:
        steps = len(h5["time"]) - 1
        profiles = len(h5["fault/time"])
        t_end = float(h5["time"][-1])
    return dict(wall=wall, rss=usage.ru_maxrss / 1024.0, size=out.stat().st_size / 1e6,
                steps=steps, profiles=profiles, t_end=t_end)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--durations", default="1h,1d,3d", help="comma-separated, e.g. 1h,1d,3d,30d")
    ap.add_argument("--nx", type=int, default=20, help="elements across the mesh")
    ap.add_argument("--dt-max", type=float, default=60.0, help="largest model step (s)")
    args = ap.parse_args(argv)
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

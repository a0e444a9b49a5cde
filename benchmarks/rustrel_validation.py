"""The paper's findings on the Rustrel scenes, read both ways: peak overpressure, slip at the
injection point, when it starts, and where the injected fluid went. The last rows repeat two
paper-units scenes on the coarse mesh of the sensitivity studies (README "Calibration and
sensitivity"), to show its error against the shipped mesh.

Run: OPENBLAS_NUM_THREADS=1 python benchmarks/rustrel_validation.py
"""
import os
from pathlib import Path

from fault_screen import Scene, simulate
from fault_screen.budget import fluid_budget
from fault_screen.ensemble import default_summary, scene_with

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
SCENES = ["calibrated-paper-units", "initial-paper-units", "impermeable-paper-units", "calibrated",
          "initial", "impermeable"]
#: the sensitivity studies' coarse mesh (--set KEY=VALUE of the commands in the README)
STUDY_MESH = {"mesh.nx": 26, "mesh.ny": 25, "time.dt": 20.0, "mesh.fault_grading_growth": 1.5}
STUDY_SCENES = ["calibrated-paper-units", "initial-paper-units"]


def main():
    print(f"load average {os.getloadavg()[0]:.2f} at start")
    print(f"{'scene':<34} {'peak dp (MPa)':>13} {'slip end (mm)':>13} {'onset (s)':>9} {'yellow (s)':>10} "
          f"{'unknowns':>8} {'wall (s)':>8}  fluid budget")
    runs = [(name, {}) for name in SCENES] + [(name, STUDY_MESH) for name in STUDY_SCENES]
    for name, overrides in runs:
        scene = scene_with(Scene.from_toml(CONFIGS / f"rustrel-2015-{name}.toml"), overrides)
        r = simulate(scene)
        s = default_summary(r)
        label = name + (" 26x25 dt20" if overrides else "")
        print(f"{label:<34} {s['peak_overpressure'] / 1e6:>13.3f} {s['injection_slip'] * 1e3:>13.3f} "
              f"{s['slip_onset']:>9.0f} {s['time_first_yellow']:>10.0f} {s['unknowns']:>8d} "
              f"{r.meta['wall_time']:>8.1f}  {fluid_budget(r).summary()}", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()

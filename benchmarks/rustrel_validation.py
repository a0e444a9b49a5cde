"""The paper's findings on the Rustrel scenes, read both ways: peak overpressure, slip at the
injection point, when it starts, and where the injected fluid went.

Run: OPENBLAS_NUM_THREADS=1 python benchmarks/rustrel_validation.py
"""
from pathlib import Path

import numpy as np

from fault_screen import Scene, simulate
from fault_screen.budget import fluid_budget
from fault_screen.ensemble import slip_onset

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
SCENES = ["calibrated-paper-units", "initial-paper-units", "impermeable-paper-units", "calibrated",
          "initial", "impermeable"]


def main():
    print(f"{'scene':<26} {'peak dp (MPa)':>13} {'slip end (mm)':>13} {'onset (s)':>9} {'wall (s)':>8}  fluid budget")
    for name in SCENES:
        r = simulate(Scene.from_toml(CONFIGS / f"rustrel-2015-{name}.toml"))
        onset = slip_onset(r)
        print(f"{name:<26} {r.injection['overpressure'].max() / 1e6:>13.3f} "
              f"{abs(r.injection['slip'][-1]) * 1e3:>13.3f} {onset:>9.0f} {r.meta['wall_time']:>8.1f}  "
              f"{fluid_budget(r).summary()}")


if __name__ == "__main__":
    main()

"""Slip of the leak-off scene against the element height across the fault (issue 10).

Runs ``configs/verification/leak-off-convergence.toml`` at 50 x 25, 50 x 51 and 50 x 101 elements
with ``mesh.fault_grading`` off (the mesh as given) and auto (graded across the fault), and prints
the slip at the injection point and the slipping length at 1400 s, the unknowns and the wall time.

    python benchmarks/leak_off_convergence.py            # all six runs (about 6 min on 2 cores)
    python benchmarks/leak_off_convergence.py --ny 51 101 --grading auto
"""
from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "configs" / "verification" / "leak-off-convergence.toml"


def run(ny: int, grading: str) -> dict:
    from fault_screen import Scene, simulate
    from fault_screen.scene import SceneWarning

    scene = Scene.from_toml(SCENE)
    scene = scene.replace(mesh=replace(scene.mesh, ny=ny, fault_grading=grading))
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)  # 'off' on a coarse mesh warns: that is the point
        r = simulate(scene)
    wall = time.perf_counter() - t0
    k = int(np.argmin(np.abs(r.time - 1400.0)))
    sliding = r.fault["contact_state"][k] == 1
    return dict(height=scene.mesh.ly / ny, slip=r.injection["slip"][k],
                slipping=float(np.sum(r.fault_weights[sliding])), dofs=r.meta["dofs"], wall=wall)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ny", type=int, nargs="+", default=[25, 51, 101])
    ap.add_argument("--grading", nargs="+", default=["off", "auto"], choices=["off", "auto"])
    args = ap.parse_args()
    print("| mesh | element height across the fault | fault_grading | slip at injection (mm) "
          "| slipping length (m) | unknowns | wall (s) |")
    print("|---|---|---|---|---|---|---|")
    for grading in args.grading:
        for ny in args.ny:
            o = run(ny, grading)
            print(f"| 50 x {ny} | {o['height']:.3g} m | {grading} | {o['slip'] * 1e3:.3f} | "
                  f"{o['slipping']:.1f} | {o['dofs']} | {o['wall']:.1f} |", flush=True)


if __name__ == "__main__":
    main()

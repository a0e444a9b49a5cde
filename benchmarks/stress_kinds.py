"""The paper-units Rustrel scenes with their Table 1 stresses read as each stress kind:
peak injection overpressure, slip at the injection point and slip onset.

    OPENBLAS_NUM_THREADS=1 python benchmarks/stress_kinds.py
"""
import dataclasses
from pathlib import Path

import numpy as np

from fault_screen import Scene, SceneError
from fault_screen.simulate import simulate

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def main():
    print(f"{'scene':12s} {'stress_kind':16s} {'peak dp MPa':>11s} {'slip mm':>8s} {'onset s':>8s}")
    for name in ("calibrated", "initial", "impermeable"):
        base = Scene.from_toml(CONFIGS / f"rustrel-2015-{name}-paper-units.toml")
        given, _ = base.initial.stress_and_kind
        for kind in ("fault_effective", "biot_effective", "total"):
            ini = dataclasses.replace(base.initial, effective_stress=None, stress=given, stress_kind=kind)
            try:
                r = simulate(base.replace(initial=ini))
            except SceneError as exc:
                print(f"{name:12s} {kind:16s} refused: {exc}", flush=True)
                continue
            g = int(np.argmin(np.abs(r.fault_x)))
            sliding = np.flatnonzero(r.fault["contact_state"][:, g] == 1)
            onset = r.time[sliding[0]] if len(sliding) else float("nan")
            print(f"{name:12s} {kind:16s} {r.injection['overpressure'].max() / 1e6:11.3f} "
                  f"{abs(r.injection['slip']).max() * 1e3:8.4f} {onset:8.0f}", flush=True)


if __name__ == "__main__":
    main()

"""Calibration by recovery: synthetic noisy observations from known parameters, estimated back
from the mean values (the scenario of tests/test_calibration.py, printed).

Run: OPENBLAS_NUM_THREADS=1 python benchmarks/calibration_recovery.py
"""
import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from fault_screen import Scene  # noqa: E402
from fault_screen.calibration import calibrate, load_parameters  # noqa: E402
from fault_screen.ensemble import Runner  # noqa: E402
from test_calibration import synthetic  # noqa: E402


def main():
    base = Scene.from_toml(ROOT / "configs" / "rustrel-2015-initial-paper-units.toml")
    scene = base.replace(mesh=dataclasses.replace(base.mesh, nx=14, ny=15),
                         time=dataclasses.replace(base.time, dt=100.0))
    truth = {"injection.number_of_fractures": 70.0, "rock.youngs_modulus": 25e9, "fault.friction": 0.58}
    params = load_parameters(ROOT / "configs" / "calibration" / "rustrel-2015-parameters.toml").select(list(truth))
    with Runner(0) as runner:
        res = calibrate(scene, synthetic(scene, truth), params, runner)
    print(f"objective {res.initial_objective:.4g} -> {res.objective:.4g}, R2 {res.initial_r2:.4f} -> {res.r2:.6f}, "
          f"{len(res.iterations) - 1} iterations ({res.message})")
    ident = set(res.identifiable())
    print(f"{'parameter':<32} {'truth':>10} {'start':>10} {'estimate':>10} {'std err':>10} {'|err|/se':>8} identifiable")
    for p in params:
        k = p.key
        print(f"{k:<32} {truth[k]:>10.4g} {res.initial[k]:>10.4g} {res.values[k]:>10.4g} {res.std_error[k]:>10.3g} "
              f"{abs(res.values[k] - truth[k]) / res.std_error[k]:>8.2f} {'yes' if k in ident else 'no'}")
    print("correlation:")
    print(np.array2string(res.correlation, precision=3))


if __name__ == "__main__":
    main()

"""Calibration by recovery: synthetic noisy observations from known parameters, estimated back
from the mean values -- the two scenarios of tests/studies/test_calibration.py, printed: NoF, intact E and
mu0; and the fault-flow trio NoF, 2h0 and kappa.

Run: OPENBLAS_NUM_THREADS=1 python benchmarks/calibration_recovery.py
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from fault_screen.calibration import calibrate, load_parameters  # noqa: E402
from fault_screen.ensemble import Runner  # noqa: E402
from test_calibration import FLOW_TRUTH, PARAMS, synthetic, tiny_scene  # noqa: E402

SCENARIOS = {
    "NoF, intact E, mu0": {"injection.number_of_fractures": 70.0, "rock.youngs_modulus": 25e9,
                           "fault.friction": 0.58},
    "NoF, 2h0, kappa": FLOW_TRUTH,
}


def main():
    scene = tiny_scene()
    for title, truth in SCENARIOS.items():
        params = load_parameters(PARAMS).select(list(truth))
        with Runner(0) as runner:
            res = calibrate(scene, synthetic(scene, truth), params, runner)
        print(f"== {title}: objective {res.initial_objective:.4g} -> {res.objective:.4g}, "
              f"R2 {res.initial_r2:.4f} -> {res.r2:.6f}, {len(res.iterations) - 1} iterations")
        ident = set(res.identifiable())
        print(f"{'parameter':<32} {'truth':>10} {'start':>10} {'estimate':>10} {'std err':>10} {'|err|/se':>8} "
              f"identifiable")
        for p in params:
            k = p.key
            print(f"{k:<32} {truth[k]:>10.4g} {res.initial[k]:>10.4g} {res.values[k]:>10.4g} "
                  f"{res.std_error[k]:>10.3g} {abs(res.values[k] - truth[k]) / res.std_error[k]:>8.2f} "
                  f"{'yes' if k in ident else 'no'}")
        short = [p.label or p.key for p in params]
        pairs = [f"{short[i]}-{short[j]} {res.correlation[i, j]:+.4g}"
                 for i in range(len(short)) for j in range(i + 1, len(short))]
        print("correlation: " + ", ".join(pairs))


if __name__ == "__main__":
    main()

"""Numerical stability of the hard cases (configs/hard-cases, tests/hard_cases/stability_cases.py).

    python benchmarks/stability.py [CASE ...] [--markdown]

Run over every case (no CASE given), it also writes the markdown table to
docs/performance/stability.md.

Prints, per case: steps, step cuts, damped retries (steps that needed the line search), Newton
iterations of the accepted attempts (mean / max), smallest step, wall time, mass-balance error
and how the run ended. Wall times are for one warm process on this machine (2 cores shared).
"""
import os
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "hard_cases"))

from stability_cases import CASES, OPEN_CASES, balance_error, run_case, solver_stats  # noqa: E402


def main(argv):
    markdown = "--markdown" in argv
    given = [a for a in argv if not a.startswith("--")]
    names = given or list(CASES) + list(OPEN_CASES)
    load0 = os.getloadavg()[0]
    rows = []
    warnings.simplefilter("ignore")
    head = ("case", "steps", "cuts", "damped", "Newton mean", "Newton max", "smallest dt (s)", "wall (s)",
            "balance", "end")
    if markdown:
        print("| " + " | ".join(head) + " |")
        print("|" + "---|" * len(head))
    else:
        print(f"{head[0]:30s} {'steps':>6s} {'cuts':>5s} {'damped':>6s} {'it mean':>8s} {'it max':>6s} "
              f"{'min dt':>10s} {'wall':>7s} {'balance':>9s}  end")
    for name in names:
        try:
            run = run_case(name)
        except Exception as exc:  # noqa: BLE001 - a failing case is a row of the table
            rows.append(f"| {name} | FAILED: {str(exc).split(':')[0]} |" + " |" * (len(head) - 2))
            if markdown:
                print(rows[-1], flush=True)
            else:
                print(f"{name:30s} FAILED: {exc}", flush=True)
            continue
        s = solver_stats(run)
        end = f"stopped ({s['stopped']}) at {run.result.time[-1]:.4g} s" if s["stopped"] else "completed"
        cells = (name, s["steps"], s["cuts"], s["damped"], f"{s['it_mean']:.2f}", s["it_max"],
                 f"{s['dt_min']:.3g}", f"{s['wall']:.2f}", f"{balance_error(run.result):.1e}", end)
        rows.append("| " + " | ".join(str(c) for c in cells) + " |")
        if markdown:
            print(rows[-1], flush=True)
        else:
            print(f"{name:30s} {s['steps']:6d} {s['cuts']:5d} {s['damped']:6d} {s['it_mean']:8.2f} {s['it_max']:6d} "
                  f"{s['dt_min']:10.3g} {s['wall']:7.2f} {balance_error(run.result):9.1e}  {end}", flush=True)

    if not given:
        from doc_tables import write

        write("stability", "Hard cases",
              "Every hard case of `configs/hard-cases/` in one warm process: steps, step cuts, "
              "\"damped\" (steps that needed the line search), Newton iterations of the accepted "
              "attempts (mean and max), smallest step, wall time, fluid-balance error (of the injected "
              "volume) and how the run ended. See [Numerical stability](../stability.md).",
              ["| " + " | ".join(head) + " |", "|" + "---|" * len(head), *rows], load0)


if __name__ == "__main__":
    main(sys.argv[1:])

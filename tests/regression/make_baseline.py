"""Write the regression baseline: ``python tests/regression/make_baseline.py [CASE ...]``."""
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cases import BASELINE, CASES, arrays, run_case  # noqa: E402

if __name__ == "__main__":
    BASELINE.mkdir(exist_ok=True)
    for name in sys.argv[1:] or CASES:
        t0 = time.perf_counter()
        res = run_case(name)
        np.savez_compressed(BASELINE / f"{name}.npz", **arrays(res))
        print(f"{name:28s} {len(res.time) - 1:4d} steps  {time.perf_counter() - t0:6.2f} s", flush=True)

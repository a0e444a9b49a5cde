"""Results of every bundled scene agree with the stored baseline (see cases.py).

Tolerance: 1e-10 relative to the largest magnitude of each array (plus 1e-300 so that all-zero
arrays compare exactly). Refactoring reorders floating-point sums (round-off ~1e-16 relative),
which a converged Newton iteration carries through at about the solver tolerance times the
condition of the step; 1e-10 is far above that and far below any change in physics or numerics.
"""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cases import BASELINE, CASES, arrays, run_case  # noqa: E402

RTOL = 1e-10


def largest_difference(result, baseline) -> tuple[float, str]:
    """Largest relative difference over all arrays, and the array it is in."""
    got = arrays(result)
    assert set(got) == set(baseline.files), sorted(set(got) ^ set(baseline.files))
    worst, where = 0.0, ""
    for key in baseline.files:
        ref, new = baseline[key], got[key]
        assert ref.shape == new.shape, f"{key}: shape {new.shape} != baseline {ref.shape}"
        scale = max(float(np.max(np.abs(ref))) if ref.size else 0.0, 1e-300)
        diff = float(np.max(np.abs(new - ref))) / scale if ref.size else 0.0
        if diff > worst:
            worst, where = diff, key
    return worst, where


#: cases that are a whole bundled scene: their run is the one the other tests share (conftest)
SHARED_RUNS = {"rustrel-impermeable": "rustrel-2015-impermeable"}


#: cases left to `pytest -m slow` (CI runs them): the quick suite keeps the cheapest
#: fluid-driven-slip case; the others spend 10-40 s condensing the bulk onto ~800-1200 fault unknowns
SLOW_CASES = {"slip-T0.4-dip30", "slip-T0.7-horizontal", "slip-T0.7-dip30"}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW_CASES else n
                                  for n in sorted(CASES)])
def test_results_match_the_baseline(name, bundled_run):
    baseline = np.load(BASELINE / f"{name}.npz")
    result = bundled_run(SHARED_RUNS[name]) if name in SHARED_RUNS else run_case(name)
    worst, where = largest_difference(result, baseline)
    print(f"{name}: largest relative difference {worst:.3e} ({where})")
    assert worst <= RTOL, f"{name}: {where} differs by {worst:.3e} relative (> {RTOL})"

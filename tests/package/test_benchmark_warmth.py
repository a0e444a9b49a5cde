"""benchmarks/warmth.py: the check that a benchmark's "warm" process compiled no kernel itself
(issue 28: a process compiling kernels peaks 20-95 MB higher, which the performance table had
printed as warm)."""
import json
import os
import subprocess
import sys
import textwrap

from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
import numba  # noqa: E402
import warmth  # noqa: E402


@numba.njit
def halved(x):
    return 0.5 * x

#: a process that watches, then calls a cached kernel of its own module (in tmp_path)
_PROCESS = textwrap.dedent("""
    import json, sys
    sys.path[:0] = [{benchmarks!r}, {here!r}]
    import warmth
    compiled = warmth.watch()
    import kernel_here
    kernel_here.doubled(2.0)
    kernel_here.doubled(3.0)      # (the same types: no second compilation)
    print(json.dumps(compiled))
""")


def _run(tmp_path) -> list:
    code = _PROCESS.format(benchmarks=str(ROOT / "benchmarks"), here=str(tmp_path))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                         check=True, timeout=300)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_process_that_compiled_is_caught_and_one_that_loaded_from_the_cache_is_not(tmp_path):
    """An empty cache: the kernel's compilation is recorded (once, by module and name), and the
    check calls the process not warm; the next process loads it from the cache: nothing is
    recorded."""
    (tmp_path / "kernel_here.py").write_text(
        "import numba\n\n@numba.njit(cache=True)\ndef doubled(x):\n    return 2.0 * x\n")
    first = _run(tmp_path)
    assert warmth.kernels(first) == ["kernel_here.doubled"]
    assert "kernel_here.doubled" in warmth.describe(first)
    assert _run(tmp_path) == []
    assert warmth.describe([]) == ""


def test_a_run_that_compiled_is_discarded_and_a_second_that_compiled_too_is_flagged():
    """measure_warm keeps a first run that compiled nothing (one run); runs a case again after a
    run that compiled, keeping the second and saying what the first compiled; and when the
    second compiled too, says the row is not warm."""
    def runs(*compiled):
        made = iter(compiled)
        calls = []

        def run(case):
            calls.append(case)
            return dict(case=case, peak_mb=300.0 + len(calls), compiled=next(made))
        return run, calls

    run, calls = runs([], ["fault_screen.x.never"])
    r, note = warmth.measure_warm(run, "fine")
    assert (calls, r["peak_mb"], note) == (["fine"], 301.0, "")

    run, calls = runs(["fault_screen.kernels.contact.coulomb_law",
                       "numba.np.arrayobj.ol_np_empty.<locals>.impl"], [])
    r, note = warmth.measure_warm(run, "fine")
    assert calls == ["fine", "fine"] and r["peak_mb"] == 302.0
    assert "kernels.contact.coulomb_law" in note and "301 MB" in note and "discarded" in note
    assert "NOT WARM" not in note

    run, calls = runs(["fault_screen.ldl._eliminate"], ["fault_screen.ldl._eliminate"])
    r, note = warmth.measure_warm(run, "fine")
    assert calls == ["fine", "fine"] and "NOT WARM" in note


def test_an_attempt_with_types_the_kernel_does_not_take_is_not_a_compilation():
    """A stale compile_ahead.KERNELS entry (types the kernel no longer takes) fires numba's
    compile event without compiling anything: not recorded; a real compilation after it is."""
    import pytest

    compiled = warmth.watch()
    with pytest.raises(Exception):   # noqa: B017 (numba's typing error)
        halved.compile("(float64, float64)")
    assert compiled == []
    halved(1.0)
    assert warmth.kernels(compiled) == [f"{__name__}.halved"]

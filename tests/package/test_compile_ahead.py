"""A cold start's compilation done by child processes (fault_screen.compile_ahead): the list of
kernels is the one a run compiles, the kernels the children compiled are loaded from numba's
cache by the next process, and a child that cannot start leaves nothing uncompiled. Each case runs in a
fresh interpreter (its own numba cache where it must start cold), never timed."""
from __future__ import annotations

import json
import os
import subprocess
import sys

from fault_screen.compile_ahead import KERNELS

#: two of the listed kernels that compile in well under a second each, weighted as if they took
#: longer than a child's start, so that they are compiled ahead, one by each of two children
SMALL = [(m, n, 5.0, t) for m, n, _, t in KERNELS if (m, n) in
         {("fault_screen.linear_system", "_negated_at"), ("fault_screen.solver", "_scaled_field_norms")}]


def _python(code: str, **env) -> dict:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                         env={**os.environ, **env})
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_list_is_every_kernel_a_bundled_run_compiles_with_its_types():
    """The bundled `fault-screen run` (paper-units scene) calls exactly the listed kernels
    with exactly the listed argument types (24 at the time of writing): a kernel added, removed
    or called with other types shows here until ``cold_compile.py --kernels`` is pasted again."""
    code = (
        "import gc, json, sys, tempfile\n"
        "from numba.core.registry import CPUDispatcher\n"
        "from fault_screen.cli import main\n"
        "from fault_screen.compile_ahead import KERNELS, _arguments\n"
        "with tempfile.TemporaryDirectory() as tmp:\n"
        "    main(['run', '--out', tmp + '/r.h5', '--quiet'], prog_name='fault-screen',\n"
        "         standalone_mode=False)\n"
        "used = sorted(f'{d.py_func.__module__} {d.py_func.__name__} {s!r}'\n"
        "              for d in gc.get_objects() if isinstance(d, CPUDispatcher)\n"
        "              and d.py_func.__module__.startswith('fault_screen') for s in d.signatures\n"
        "              if not d.targetoptions.get('inline') == 'always')\n"
        "listed = sorted(f'{m} {n} {_arguments(t)!r}' for m, n, _, t in KERNELS)\n"
        "print(json.dumps({'used': used, 'listed': listed}))\n")
    got = _python(code, FAULT_SCREEN_COMPILE_AHEAD="0")
    assert len(got["listed"]) == len(KERNELS) >= 20
    assert got["used"] == got["listed"]


def test_the_children_compile_into_the_cache_the_next_process_loads(tmp_path):
    """With an empty cache, compile_ahead has the two kernels compiled by children: this
    process compiles neither; a later process finds both in the cache (one cache hit each, no
    miss) and compile_ahead there does nothing."""
    assert len(SMALL) == 2
    first = _python(
        "import json\n"
        "from fault_screen import compile_ahead as ca\n"
        f"kernels = {SMALL!r}\n"
        "did = ca.compile_ahead(kernels)\n"
        "d = [ca._dispatcher(m, n) for m, n, *_ in kernels]\n"
        "print(json.dumps({'did': did, 'here': [len(x.signatures) for x in d]}))\n",
        NUMBA_CACHE_DIR=str(tmp_path))
    assert first["did"] is True
    assert first["here"] == [0, 0]                  # nothing compiled in this process
    later = _python(
        "import json\n"
        "from fault_screen import compile_ahead as ca\n"
        f"kernels = {SMALL!r}\n"
        "out = []\n"
        "for m, n, _, t in kernels:\n"
        "    d, args = ca._dispatcher(m, n), ca._arguments(t)\n"
        "    cached = ca._cached(d, args)\n"
        "    d.compile(args)\n"
        "    out.append([cached, sum(d.stats.cache_hits.values()), sum(d.stats.cache_misses.values())])\n"
        "print(json.dumps({'out': out, 'again': ca.compile_ahead(kernels)}))\n",
        NUMBA_CACHE_DIR=str(tmp_path))
    assert later["out"] == [[True, 1, 0], [True, 1, 0]]
    assert later["again"] is False                  # a warm cache: nothing done ahead


def test_a_child_that_cannot_start_leaves_every_kernel_to_this_process(tmp_path):
    """No Python to start the child with: this process compiles both kernels itself."""
    got = _python(
        "import json, sys\n"
        "from fault_screen import compile_ahead as ca\n"
        "sys.executable = '/nonexistent/python'\n"
        f"kernels = {SMALL!r}\n"
        "did = ca.compile_ahead(kernels)\n"
        "print(json.dumps({'did': did, 'here': [len(ca._dispatcher(m, n).signatures)\n"
        "                                      for m, n, *_ in kernels]}))\n",
        NUMBA_CACHE_DIR=str(tmp_path))
    assert got == {"did": True, "here": [1, 1]}


def test_a_stale_entry_is_left_to_the_first_call():
    """An entry whose types the kernel does not accept (a kernel changed since the list was
    made) is skipped: of these three entries two compile, and no error escapes."""
    stale = [("fault_screen.linear_system", "_negated_at", 0.1, "(int64,)"),
             ("fault_screen.no_such_module", "kernel", 0.1, "(int64,)")]
    got = _python(
        "import json\n"
        "from fault_screen import compile_ahead as ca\n"
        f"print(json.dumps({{'done': ca.compile_kernels({stale + SMALL!r})}}))\n")
    assert got == {"done": 2}


def test_a_warm_start_asks_about_the_longest_kernels_only():
    """With every kernel cached, nothing is missing; a kernel among the longest to compile (half
    the whole time: 4 of 24) asked for with other types shows as missing, a short one does not
    (it is not asked about: compiled at its first call)."""
    from fault_screen.compile_ahead import _missing, compile_kernels

    assert compile_kernels(KERNELS) == len(KERNELS)          # (loaded from the cache when warm)
    assert _missing(KERNELS) == []
    by_time = sorted(KERNELS, key=lambda k: -k[2])
    head = sum(1 for i in range(len(by_time))
               if sum(k[2] for k in by_time[:i]) < 0.5 * sum(k[2] for k in KERNELS))
    assert head == 4
    for k, missing in ((by_time[0], True), (by_time[-1], False)):
        changed = [(m, n, w, "(int64,)") if (m, n) == k[:2] else (m, n, w, t) for m, n, w, t in KERNELS]
        assert [x[1] for x in _missing(changed)] == ([k[1]] if missing else [])

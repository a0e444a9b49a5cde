"""What a command imports before it does anything: the commands that only read or list
(``--help``, ``plugins``) never import numba, scipy or the model (fault_screen.stepper), and
``run`` imports the modules of no other command. Counted in a fresh interpreter (sys.modules),
never timed."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from fault_screen.cli import COMMANDS

#: modules that a command which builds no model must not import
MODEL_MODULES = ("numba", "scipy", "h5py", "fault_screen.stepper", "fault_screen.kernels")


def imported_after(*argv: str) -> set[str]:
    """Top modules and fault_screen modules in sys.modules after ``fault-screen ARGV`` (run
    in a fresh interpreter; the command's exit code is ignored)."""
    code = ("import sys, json, atexit\n"
            "atexit.register(lambda: print('MODULES=' + json.dumps(sorted(sys.modules)), file=sys.stderr))\n"
            "from fault_screen.cli import main\n"
            f"main({list(argv)!r}, prog_name='fault-screen')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    (line,) = [x for x in out.stderr.splitlines() if x.startswith("MODULES=")]
    return set(json.loads(line[len("MODULES="):]))


@pytest.mark.parametrize("argv", [("--help",), ("run", "--help")])
def test_help_imports_no_model(argv):
    modules = imported_after(*argv)
    loaded = sorted(m for m in modules if m.split(".")[0] in MODEL_MODULES or
                    any(m == p or m.startswith(p + ".") for p in MODEL_MODULES))
    assert loaded == [], loaded


def test_run_help_imports_no_other_command():
    """Of the 12 command modules, ``run --help`` imports exactly one: run's."""
    modules = imported_after("run", "--help")
    commands = sorted(c for c in COMMANDS if f"fault_screen.cli.{c}" in modules)
    assert len(COMMANDS) == 12
    assert commands == ["run"]


def test_every_command_is_listed_and_found():
    """The lazy group lists the 12 commands and resolves each to the command of that name."""
    from fault_screen.cli import main

    assert main.list_commands(None) == sorted(COMMANDS)
    for name in COMMANDS:
        assert main.get_command(None, name).name == name
    assert main.get_command(None, "no-such-command") is None


def test_package_names_resolve_to_their_definitions():
    """The package's names, imported on first use, are the objects of their modules; the
    function ``simulate`` stays the package's name after the module ``fault_screen.simulate``
    (which has the same name) is imported."""
    code = ("import sys, fault_screen as fs\n"
            "before = sorted(m for m in ('numba', 'scipy', 'fault_screen.stepper') if m in sys.modules)\n"
            "import fault_screen.simulate, fault_screen.api, fault_screen.stepper, fault_screen.scene\n"
            "print(before, fs.simulate is fault_screen.api.simulate,"
            " fs.Simulation is fault_screen.stepper.Simulation,"
            " fs.SceneError is fault_screen.scene.SceneError, callable(fs.simulate))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["[]", "True", "True", "True", "True"], out.stderr[-2000:]


def test_run_help_imports_no_numpy_and_no_run_machinery():
    """``run --help`` stops before the run's own modules: no numpy, no
    fault_screen.cli._running (the result file, the budget, the summary), no fault_screen.budget;
    of fault_screen, the package, the group, its options and the run command only."""
    modules = imported_after("run", "--help")
    assert "numpy" not in modules
    ours = sorted(m for m in modules if m.startswith("fault_screen"))
    assert ours == ["fault_screen", "fault_screen.cli", "fault_screen.cli._common",
                    "fault_screen.cli._options", "fault_screen.cli._verdict",
                    "fault_screen.cli.run"], ours


def _tiny_scene(tmp_path):
    """A 4 x 5 mesh run for 4 steps of 5 s, as a scene file."""
    from fault_screen import Scene

    scene = tmp_path / "tiny.toml"
    scene.write_text(Scene.from_dict({
        "mesh": {"nx": 4, "ny": 5, "lx": 50.0, "ly": 50.0},
        "initial": {"effective_stress": [-5.649e6, -3.351e6, 0.964e6], "pore_pressure": 2.764e6},
        "injection": {"number_of_fractures": 10, "schedule": [[0.0, 1e-3]]},
        "time": {"end": 20.0, "dt": 5.0}}).to_toml())
    return scene


def test_a_whole_run_imports_no_ensemble_and_starts_no_ldconfig(tmp_path):
    """A whole ``run`` of a scene without ``--set`` (a 4 x 5 mesh, 4 steps) imports
    fault_screen.ensemble (what ``--set`` changes a scene with) not at all, no other command's
    module, and not ctypes.util, whose ``find_library`` starts ``ldconfig`` in a child process
    (the heap trim finds glibc's malloc_trim in the C library already loaded)."""
    scene = _tiny_scene(tmp_path)
    modules = imported_after("run", str(scene), "--out", str(tmp_path / "r.h5"), "--quiet")
    assert (tmp_path / "r.h5").is_file()
    assert "fault_screen.stepper" in modules and "fault_screen.bordered_lu" in modules
    assert sorted(m for m in ("fault_screen.ensemble", "ctypes.util") if m in modules) == []
    assert sorted(c for c in COMMANDS if f"fault_screen.cli.{c}" in modules) == ["run"]


#: packages the project depends on that a ``run`` without ``--plot``, ``--events`` or ``--set``
#: never needs: figures, seismic catalogs, geodesics, the ensemble runner and its studies, the
#: live stage's clients (each an import a start would pay in time and memory, measured after
#: numpy, scipy, numba and h5py: matplotlib.pyplot 29 MB and 0.44 s, dask with distributed
#: 22 MB and 0.33 s)
NOT_FOR_A_PLAIN_RUN = ("matplotlib", "obspy", "pyproj", "dask", "distributed", "pandas", "SALib",
                       "requests", "prometheus_client", "PIL")


def test_a_whole_run_without_figures_imports_no_plotting_and_no_study_libraries(tmp_path):
    """A whole ``run`` (the tiny scene, result written, screened, summarised) imports none of
    NOT_FOR_A_PLAIN_RUN and not fault_screen's plotting; with ``--plot`` matplotlib is imported
    (the check sees an import when there is one)."""
    scene = _tiny_scene(tmp_path)
    modules = imported_after("run", str(scene), "--out", str(tmp_path / "r.h5"), "--quiet")
    assert (tmp_path / "r.h5").is_file()
    tops = {m.split(".")[0] for m in modules}
    assert sorted(p for p in NOT_FOR_A_PLAIN_RUN if p in tops) == []
    assert sorted(m for m in modules if m.startswith("fault_screen.plotting")) == []
    plotted = imported_after("run", str(scene), "--out", str(tmp_path / "p.h5"), "--quiet",
                             "--plot", str(tmp_path / "figs"))
    assert "matplotlib" in plotted and any(m.startswith("fault_screen.plotting") for m in plotted)


def test_the_heap_trim_is_glibcs_malloc_trim():
    """On glibc (this machine's C library) the trim is found, and trimming returns 0 or 1
    (whether memory was handed back), as glibc's malloc_trim does."""
    import platform

    from fault_screen.bordered_lu import _libc_malloc_trim

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("not glibc")
    trim = _libc_malloc_trim()
    assert trim is not None and trim(0) in (0, 1)


def test_the_console_script_leaves_its_objects_to_the_system_at_exit(tmp_path):
    """``main()`` as the console script calls it (the command line from sys.argv) hands every
    object to the system at exit (gc.freeze: tens of thousands of objects after a run, none
    before the command), and the result it wrote is whole: 5 rows, every dataset readable.
    The same run through a CliRunner (a caller that goes on) freezes nothing."""
    import gc

    from click.testing import CliRunner

    from fault_screen import Result
    from fault_screen.cli import main

    scene = _tiny_scene(tmp_path)
    out = tmp_path / "r.h5"
    code = ("import atexit, gc, sys\n"
            "atexit.register(lambda: print('FROZEN', gc.get_freeze_count(), file=sys.stderr))\n"
            "from fault_screen.cli import main\n"
            "before = gc.get_freeze_count()\n"
            f"sys.argv[:] = ['fault-screen', 'run', {str(scene)!r}, '--out', {str(out)!r}, '--quiet']\n"
            "print('BEFORE', before, file=sys.stderr)\n"
            "main()\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    counts = dict(line.split() for line in proc.stderr.splitlines()
                  if line.startswith(("BEFORE", "FROZEN")))
    assert int(counts["BEFORE"]) == 0 and int(counts["FROZEN"]) > 10_000, counts
    result = Result.load(out)
    assert len(result.time) == 5 and result.time[-1] == 20.0
    frozen = gc.get_freeze_count()
    again = CliRunner().invoke(main, ["run", str(scene), "--out", str(tmp_path / "s.h5"), "--quiet"])
    assert again.exit_code == 0, again.output
    assert gc.get_freeze_count() == frozen

"""fault_screen side by side with OpenGeoSys 6.5 (HYDRO_MECHANICS_WITH_LIE) on one scene.

    pip install "ogs==6.5.*"                          # OGS from the package index
    python benchmarks/peers/ogs_compare.py            # both meshes, table to docs/performance/peers.md
    python benchmarks/peers/ogs_compare.py --end 300  # a shorter run (OGS's wall grows with the end)
    python benchmarks/peers/ogs_compare.py --no-doc   # print only

The scene (rustrel-pressure.toml, its OGS twin rustrel-pressure.prj; what was reduced so that
both codes model the same thing is at the top of the TOML) runs on two meshes: OGS's uniform
5-m mesh (ours 50 x 51 elements, so that the fault crosses the middle of an element row; OGS
50 x 50 with the fault on the middle node line) and a mesh graded towards the fault and the
injection point (the same node lines for both, from fault_screen.mesh.graded_line; ours has the
fault in the middle of the finest element row, OGS on the node line below it).

One after the other on this machine: ours as a whole process (``fault-screen run``, numba's cache
and fault_screen's bytecode written by a discarded first run; the median of three), then ``ogs``
as a whole process (the median of ``--ogs-repeat`` runs). Each row: the process wall time, the
Newton iterations of the whole run (ours: the stepper's count; OGS: the iterations its log
reports), the slip at the injection point at the compared times, and the ratio of the wall
times. Beside the table: the start of a process that only imports numba and calls one cached
kernel, which bounds the ratio any whole process of ours can reach. The machine's load is printed and written
with the table.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
SCENE = HERE / "rustrel-pressure.toml"
PROJECT = HERE / "rustrel-pressure.prj"
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT / "benchmarks"))

from ogs_mesh import (FAULT_Y, GROWTH, HALF_WIDTH, INJECTION_X, SIZE, ogs_node_lines,  # noqa: E402
                      write_ogs_meshes)

#: the model times (s) at which the slip at the injection point is compared: step ends (OGS
#: would shorten a step to reach an output time between them)
COMPARE_TIMES = (120.0, 300.0, 900.0)
#: OGS's time step (s): the one of the scene, kept equal in both files
DT = 30.0
#: largest slip (m) either code may show after one step without injection (a fault shear
#: traction of the wrong sign in the twin would jump it by 2 tau0 / kS = 1.7e-4 m)
AT_REST_SLIP = 1e-8


OVERPRESSURE = 2.8e6


def our_scene_text(graded: bool, end: float, overpressure: float = OVERPRESSURE) -> str:
    """Our scene as TOML text: the bundled file, graded like OGS's graded mesh on request (the
    fault then in the middle of the finest element row), ended at ``end`` (s), the injection
    point held at ``overpressure`` (Pa)."""
    text = SCENE.read_text(encoding="utf-8").replace("end = 900.0", f"end = {end!r}")
    text = text.replace('"schedule[MPa]" = [[0.0, 2.8]]', f"schedule = [[0.0, {overpressure!r}]]")
    if graded:
        text = text.replace("[fault]\n", f"[fault]\npoint = [{INJECTION_X!r}, {FAULT_Y + 0.5 * SIZE!r}]\n")
        text += (f"\n[mesh.refinement]\ncenter = [{INJECTION_X!r}, {FAULT_Y!r}]\n"
                 f"half_width = [{HALF_WIDTH[0]!r}, {HALF_WIDTH[1]!r}]\nsize = {SIZE!r}\n"
                 f"growth = {GROWTH!r}\n")
    return text


def run_ours(graded: bool, end: float, work: Path, overpressure: float = OVERPRESSURE) -> dict:
    """One whole process of ours, as a user runs it: ``fault-screen run SCENE -o RESULT.h5 -q``
    (the model, its screening and its HDF5 result); its wall time, and what the result holds.
    Python writes and reads fault_screen's bytecode (.pyc) as for an installed package, even
    where PYTHONDONTWRITEBYTECODE is set: there every process would compile the package's
    modules from source again."""
    from fault_screen.discretisation import mesh_shape
    from fault_screen.result import Result

    scene, out = work / "ours.toml", work / "ours.h5"
    scene.write_text(our_scene_text(graded, end, overpressure), encoding="utf-8")
    out.unlink(missing_ok=True)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    # (the console script installed beside this interpreter)
    program = shutil.which("fault-screen", path=str(Path(sys.executable).parent)) or "fault-screen"
    command = [program, "run", str(scene), "-o", str(out), "-q"]
    t0 = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=env, cwd=work)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"fault-screen run failed (exit {done.returncode}):\n{done.stderr}")
    result = Result.load(out)
    t, slip = result.time, np.abs(result.injection["slip"])
    nx, ny = mesh_shape(result.scene)
    row = {"wall": wall, "run": float(result.meta["wall_time"]), "unknowns": int(result.meta["dofs"]),
           "iterations": int(np.sum(result.solver["iterations"])), "steps": len(t) - 1,
           "elements": nx * ny, "largest_slip": float(np.max(np.abs(result.fault["slip"][-1])))}
    row["slip_at"] = {c: float(np.interp(c, t, slip)) for c in compared_times(end)}
    return row


#: a module with one cached numba kernel: a process that imports it and calls the kernel pays
#: what every process of ours pays before any of its own work (numba's import and its set-up at
#: the first kernel load: its implementations' registries, its runtime)
_FLOOR_MODULE = """
import numba

@numba.njit(cache=True)
def one(x):
    return x + 1.0
"""


def numba_floor(work: Path, repeat: int = 3) -> float:
    """The median wall time (s) of a fresh process that imports numba and calls one cached
    kernel (its cache filled by a first, discarded run)."""
    (work / "floor_kernel.py").write_text(_FLOOR_MODULE, encoding="utf-8")
    # (its objects frozen at the end, as fault-screen's are: else the interpreter's last garbage
    # collections walk numba's objects, 0.15-0.2 s more)
    command = [sys.executable, "-c", "import gc, floor_kernel; floor_kernel.one(1.0); gc.freeze()"]
    walls = []
    for _ in range(repeat + 1):
        t0 = time.perf_counter()
        subprocess.run(command, check=True, cwd=work, capture_output=True)
        walls.append(time.perf_counter() - t0)
    return statistics.median(walls[1:])


def compared_times(end: float) -> tuple:
    return tuple(t for t in COMPARE_TIMES if t <= end + 1e-9) or (end,)


def ogs_project(end: float, path: Path, overpressure: float = OVERPRESSURE) -> Path:
    """rustrel-pressure.prj with its end, number of steps and output times set for ``end`` and
    the injection point held at ``overpressure`` (Pa)."""
    parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
    tree = ET.parse(PROJECT, parser=parser)
    stepping = tree.find("time_loop/processes/process/time_stepping")
    stepping.find("t_end").text = f"{end:g}"
    stepping.find("timesteps/pair/repeat").text = str(int(round(end / DT)))
    tree.find("time_loop/output/fixed_output_times").text = " ".join(f"{t:g}" for t in compared_times(end))
    for parameter in tree.iterfind("parameters/parameter"):
        if parameter.findtext("name") == "injection_overpressure":
            parameter.find("value").text = repr(float(overpressure))
    tree.write(path, encoding="ISO-8859-1", xml_declaration=True)
    return path


def read_point_array(vtu: Path, name: str, components: int) -> np.ndarray:
    """A point array of an ASCII VTU file OGS wrote (rows: nodes)."""
    for array in ET.parse(vtu).getroot().iter("DataArray"):
        if array.get("Name") == name:
            return np.array(array.text.split(), dtype=float).reshape(-1, components)
    raise KeyError(f"{vtu.name} has no point array {name!r}")


def run_ogs(graded: bool, end: float, work: Path, threads: int, overpressure: float = OVERPRESSURE,
            name: str | None = None) -> dict:
    """One whole ``ogs`` process on the mesh written by ogs_mesh.py: its wall time, the Newton
    iterations its log reports and the slip at the injection node at the compared times."""
    name = name or ("graded" if graded else "uniform")
    meshes, out = work / name / "meshes", work / name / "out"
    out.mkdir(parents=True, exist_ok=True)
    info = write_ogs_meshes(meshes, *ogs_node_lines(graded))
    project = ogs_project(end, work / name / "rustrel-pressure.prj", overpressure)
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    t0 = time.perf_counter()
    done = subprocess.run([shutil.which("ogs") or "ogs", "-m", str(meshes), "-o", str(out), str(project)],
                          capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    (work / name / "ogs.log").write_text(done.stdout + done.stderr, encoding="utf-8")
    if done.returncode != 0:
        raise RuntimeError(f"ogs failed on the {name} mesh (exit {done.returncode}); log in {work / name}")
    log = done.stdout
    slip_at = {}
    for t in compared_times(end):
        [vtu] = out.glob(f"ogs_ts_*_t_{t:.6f}.vtu")
        jump = read_point_array(vtu, "displacement_jump1", 2)
        slip_at[t] = float(abs(jump[info["injection_node"], 0]))   # the fault is along x
    largest_slip = float(np.max(np.abs(jump[:, 0])))             # zero off the fault
    executed = re.search(r"Simulation completed. It took ([0-9.eE+-]+) s", log)
    return {"wall": wall, "iterations": len(re.findall(r"Iteration #\d+ started", log)),
            "run": float(executed.group(1)) if executed else float("nan"),
            "steps": len(re.findall(r"Time step #\d+ started", log)) - 1,
            "elements": info["matrix_elements"], "nodes": info["nodes"], "slip_at": slip_at,
            "largest_slip": largest_slip,
            "linear_solves": [float(s) for s in re.findall(r"Linear solver took ([0-9.eE+-]+) s", log)]}


def median_run(runs: list[dict]) -> dict:
    """The run of median wall time, with the fastest and the slowest wall time of all."""
    runs = sorted(runs, key=lambda r: r["wall"])
    return {**runs[len(runs) // 2], "fastest": runs[0]["wall"], "slowest": runs[-1]["wall"],
            "runs": len(runs)}


def table(rows: list[dict], times: tuple) -> list[str]:
    slips = " | ".join(f"slip at {t:g} s (mm)" for t in times)
    lines = [f"| mesh | code | elements | steps | Newton iterations | runs | wall (s), median | "
             f"wall (s), fastest-slowest | in-process (s) | {slips} | OGS wall / ours, medians "
             f"| OGS's fastest / our slowest |",
             "|" + "---|" * (11 + len(times))]
    for r in rows:
        ratios = (f"{r['ratio']:.0f} | {r['worst_ratio']:.0f}" if "ratio" in r else " | ")
        slip = " | ".join(f"{1e3 * r['slip_at'][t]:.4f}" for t in times)
        lines.append(f"| {r['mesh']} | {r['code']} | {r['elements']} | {r['steps']} | {r['iterations']} "
                     f"| {r['runs']} | {r['wall']:.2f} | {r['fastest']:.2f}-{r['slowest']:.2f} "
                     f"| {r['run']:.2f} | {slip} | {ratios} |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--end", type=float, default=900.0, help="end time of both runs (s) [900]")
    ap.add_argument("--meshes", nargs="+", default=["uniform", "graded"], choices=["uniform", "graded"])
    ap.add_argument("--repeat", type=int, default=3, help="runs of ours, the median kept [3]")
    ap.add_argument("--ogs-repeat", type=int, default=1,
                    help="runs of OGS, the median kept [1; a graded run takes minutes]")
    ap.add_argument("--ogs-threads", type=int, default=1, help="OMP_NUM_THREADS for ogs [1]")
    ap.add_argument("--no-doc", action="store_true", help="print only")
    args = ap.parse_args(argv)
    if shutil.which("ogs") is None:
        print("ogs not found: pip install 'ogs==6.5.*' in this environment", file=sys.stderr)
        return 2
    if abs(args.end / DT - round(args.end / DT)) > 1e-9:
        ap.error(f"--end must be a multiple of the time step, {DT:g} s")
    version = subprocess.run(["ogs", "--version"], capture_output=True, text=True).stdout
    version = re.search(r"version:\s*(\S+)", version).group(1)
    load0 = os.getloadavg()[0]
    times = compared_times(args.end)
    rows = []
    with tempfile.TemporaryDirectory(prefix="ogs_compare_") as tmp:
        # both twins start from the same in-situ state in equilibrium: one step without injection
        # leaves the fault where it is (see AT_REST_SLIP); this also fills numba's cache before timing
        at_rest = (run_ours(False, DT, Path(tmp), 0.0)["largest_slip"],
                   run_ogs(False, DT, Path(tmp), args.ogs_threads, 0.0, name="at_rest")["largest_slip"])
        print(f"at rest, one step: largest slip {at_rest[0]:.1e} m (ours), {at_rest[1]:.1e} m (OGS)")
        if max(at_rest) > AT_REST_SLIP:
            raise SystemExit(f"the scene and its OGS twin do not start in equilibrium: slip {at_rest} m")
        floor = numba_floor(Path(tmp))
        print(f"a process that imports numba and calls one cached kernel: {floor:.2f} s", flush=True)
        for mesh in args.meshes:
            graded = mesh == "graded"
            ours = median_run([run_ours(graded, args.end, Path(tmp)) for _ in range(args.repeat)])
            ours.update(mesh=mesh, code="fault_screen")
            print(f"{mesh}: ours {ours['wall']:.2f} s ({ours['fastest']:.2f}-{ours['slowest']:.2f}; "
                  f"run {ours['run']:.2f} s, {ours['unknowns']} unknowns)", flush=True)
            ogs = median_run([run_ogs(graded, args.end, Path(tmp), args.ogs_threads)
                              for _ in range(args.ogs_repeat)])
            ogs.update(mesh=mesh, code=f"OGS {version}", ratio=ogs["wall"] / ours["wall"],
                       worst_ratio=ogs["fastest"] / ours["slowest"])
            print(f"{mesh}: OGS {ogs['wall']:.1f} s ({ogs['fastest']:.1f}-{ogs['slowest']:.1f}), median "
                  f"linear solve {statistics.median(ogs['linear_solves']):.2f} s", flush=True)
            rows += [ours, ogs]
    lines = table(rows, times)
    print("\n".join(lines))
    print(f"load average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end")
    if not args.no_doc:
        from doc_tables import write

        path = write("peers", "Side by side with OpenGeoSys", intro(args, version, at_rest, floor, rows),
                     lines, load0)
        print(f"written {path.relative_to(ROOT)}")
    return 0


def floor_note(floor: float, rows: list[dict]) -> str:
    """What the process start alone allows: the ratio a run of ours taking no time after
    numba's start could reach against each mesh's OGS run."""
    bounds = ", ".join(f"{r['wall'] / floor:.0f} on the {r['mesh']} mesh" for r in rows
                       if r["code"] != "fault_screen")
    return (f"\n\nThe start alone: a fresh process that imports numba and calls one cached kernel "
            f"takes {floor:.2f} s (numba's import and its set-up at the first kernel load), "
            f"before any work of ours. So no whole process of ours can be more than OGS's median "
            f"wall time / {floor:.2f} s times faster than OGS: {bounds}.")


def intro(args, version: str, at_rest: tuple, floor: float, rows: list[dict]) -> str:
    end = args.end
    shorter = ("" if end >= 900.0
               else f" (ended at {end:g} s instead of the scene's 900 s to keep OGS's runs short)")
    return (
        f"The scene `benchmarks/peers/rustrel-pressure.toml` and its OpenGeoSys {version} twin "
        "`benchmarks/peers/rustrel-pressure.prj` (HYDRO_MECHANICS_WITH_LIE, lower-interface "
        "elements; OGS from the package index, `pip install \"ogs==6.5.*\"`): a Rustrel-like fault "
        "held at 2.8 MPa of overpressure at the injection point, impermeable elastic rock, constant "
        "friction 0.68, constant hydraulic aperture; what differs from the bundled Rustrel scene "
        f"and why is at the top of the TOML. Fixed steps of {DT:g} s{shorter}, backward Euler in "
        "both.\n\n"
        "Both codes run one after the other as whole processes, each as its users run it; wall "
        "time from start to exit. Ours: `fault-screen run SCENE -o RESULT.h5 -q` (the model, its "
        f"screening and its HDF5 result), the median of {args.repeat} runs with numba's cache and "
        "Python's bytecode of the package in place, as after a pip install. OGS: `ogs -m MESHES -o "
        f"OUT PROJECT` (its VTU output), the median of {args.ogs_repeat} run(s). The last column "
        "sets OGS's fastest run against our slowest. OGS "
        "solves with Eigen's SparseLU (the wheel is built without MKL, so PardisoLU is refused) "
        f"with OMP_NUM_THREADS={args.ogs_threads} (on this loaded machine one thread factorised "
        "faster than OGS's default two). In-process: ours the run's own wall time from building "
        "the model to its last step (the result's `wall_time`; imports and numba's cache loads "
        "before it left out), OGS's own \"Simulation completed. It took\". "
        "Newton iterations: the whole run's. Slip: the tangential displacement jump at the "
        "injection point.\n\n"
        "Meshes: `uniform` is OGS's 5-m mesh (OGS 50 x 50 serendipity quadrilaterals with the "
        "fault on the middle node line; ours 50 x 51 bilinear elements, so that the fault crosses "
        f"the middle of a row); `graded` has {SIZE:g}-m elements within {HALF_WIDTH[0]:g} m of the "
        f"injection point along the fault and {HALF_WIDTH[1]:g} m across it, growing by "
        f"{GROWTH:g} outside (the same node lines in both; ours has the fault in the middle of the "
        "finest row, OGS on the node line below it). OGS's elements are quadratic (8 nodes), ours "
        "bilinear.\n\n"
        "Checked first: held at zero overpressure for one step, the largest slip on the fault is "
        f"{at_rest[0]:.1e} m (ours) and {at_rest[1]:.1e} m (OGS), so both start from the same "
        "in-situ state in equilibrium." + floor_note(floor, rows))

if __name__ == "__main__":
    raise SystemExit(main())

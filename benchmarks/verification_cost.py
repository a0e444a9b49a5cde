"""Cost versus accuracy of the verification scenes at three mesh sizes.

Prints a table: DOFs, steps, Newton iterations, wall time (cold = first run in a fresh process,
including numba's cache load or compilation; warm = second run), step latency, peak memory
(max RSS of the process) and the error against the analytical reference.

    python benchmarks/verification_cost.py            # all scenes, mesh factors 2, 1, 0.5
    python benchmarks/verification_cost.py --quick    # factors 2 and 1 only

Each case runs in its own subprocess so that peak memory is its own.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # analytical references

SCENES = ["terzaghi", "fault-diffusion", "mass-balance", "fluid-driven-slip-T0.4-horizontal",
          "fluid-driven-slip-T0.4-dip30", "fluid-driven-slip-T0.7-horizontal",
          "fluid-driven-slip-T0.7-dip30"]


def scaled_scene(name: str, factor: float):
    """The scene with element sizes multiplied by ``factor``."""
    from fault_screen import Scene

    scene = Scene.from_toml(ROOT / "configs" / "verification" / f"{name}.toml")
    m = scene.mesh
    if m.refinement is not None:
        mesh = replace(m, refinement=replace(m.refinement, size=m.refinement.size * factor))
    else:
        nx = max(1, round(m.nx / factor)) if m.nx > 1 else 1
        ny = max(1, round(m.ny / factor))
        if name == "mass-balance" and ny % 2 == 0:
            ny += 1  # keep the fault off node lines
        mesh = replace(m, nx=nx, ny=ny)
    return scene.replace(mesh=mesh)


def error_against_reference(name, scene, result, model, states):
    import analytical as an

    if name == "terzaghi":
        rk = scene.rock
        kw = dict(height=scene.mesh.ly, E=rk.youngs_modulus, nu=rk.poissons_ratio,
                  biot=rk.biot_coefficient, biot_modulus=1 / model.zone_props[0]["inv_M"],
                  mobility=rk.permeability / scene.fluid.viscosity)
        load = -scene.boundary.top.traction[1]
        t, x = states[len(states) // 2]
        col = model.coords[:, 0] == 0.0
        p_ref = an.terzaghi_pressure(model.coords[col, 1], t, load=load, **kw)
        p_u = an.terzaghi_undrained_pressure(load=load, E=rk.youngs_modulus, nu=rk.poissons_ratio,
                                             biot=rk.biot_coefficient, biot_modulus=kw["biot_modulus"])
        return "max|p-p_ref|/p_u", float(np.max(np.abs(x[model.blocks.p][col] - p_ref)) / p_u)
    if name == "fault-diffusion":
        f = scene.fault
        alpha = f.hydraulic_aperture ** 3 / (12 * scene.fluid.viscosity * f.kappa) / f.storativity
        dp = scene.injection.schedule[0][1]
        p_ref = an.fault_diffusion_pressure(result.fault_x, result.time[-1], dp=dp, alpha=alpha)
        return "max|p-p_ref|/dp", float(np.max(np.abs(result.fault["overpressure"][-1] - p_ref)) / dp)
    if name == "mass-balance":
        b = result.balance
        inj = result.injection["volume"][1:] / scene.injection.number_of_fractures
        tot = (b["stored_rock"] + b["stored_fault"] + b["leaked"])[1:]
        return "max volume imbalance", float(np.max(np.abs(tot - inj) / inj))
    # fluid-driven slip: the exact self-similar solution, with T read from the scene's stresses
    # (not from its file name) and the slip's sign from its initial shear stress, as
    # `fault-screen accuracy` measures it
    from fault_screen.accuracy import exact_family, exact_summary

    if exact_family(scene) != "fluid_driven_slip":
        raise ValueError(f"{name}: no exact reference for this scene")
    return "slip rel. L2", exact_summary(result, "fluid_driven_slip")["slip_l2"]


def run_case(name: str, factor: float) -> dict:
    from fault_screen import Simulation

    scene = scaled_scene(name, factor)
    timings = []
    for _ in range(2):  # cold, warm
        t0 = time.perf_counter()
        sim = Simulation(scene)
        model = sim.disc
        states = [(0.0, sim.x.copy())]
        keep = name == "terzaghi"
        sim.advance(scene.time.end,
                    observer=(lambda t, x, disc: states.append((t, x.copy()))) if keep else None)
        result = sim.result()
        timings.append(time.perf_counter() - t0)
    steps = len(result.time) - 1
    label, err = error_against_reference(name, scene, result, model, states)
    return dict(scene=name, factor=factor, dofs=model.n_dofs, steps=steps,
                newton=int(result.solver["iterations"].sum()), cold=timings[0], warm=timings[1],
                latency_ms=1e3 * timings[1] / steps,
                peak_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                error_name=label, error=err)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="mesh factors 2 and 1 only")
    ap.add_argument("--scenes", nargs="*", default=SCENES)
    ap.add_argument("--case", nargs=2, metavar=("SCENE", "FACTOR"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.case:
        print(json.dumps(run_case(args.case[0], float(args.case[1]))))
        return
    factors = [2.0, 1.0] if args.quick else [2.0, 1.0, 0.5]
    head = (f"{'scene':36s} {'h/h0':>5s} {'DOFs':>7s} {'steps':>5s} {'Newton':>6s} {'cold s':>7s} "
            f"{'warm s':>7s} {'ms/step':>8s} {'peak MB':>8s}  error")
    print(head)
    print("-" * len(head))
    for name in args.scenes:
        for factor in factors:
            out = subprocess.run([sys.executable, __file__, "--case", name, str(factor)],
                                 capture_output=True, text=True, cwd=ROOT)
            if out.returncode != 0:
                print(f"{name:36s} {factor:5.2f} failed: {out.stderr.strip().splitlines()[-1]}")
                continue
            r = json.loads(out.stdout.strip().splitlines()[-1])
            print(f"{r['scene']:36s} {r['factor']:5.2f} {r['dofs']:7d} {r['steps']:5d} {r['newton']:6d} "
                  f"{r['cold']:7.2f} {r['warm']:7.2f} {r['latency_ms']:8.2f} {r['peak_mb']:8.0f}  "
                  f"{r['error_name']} = {r['error']:.2e}", flush=True)


if __name__ == "__main__":
    main()

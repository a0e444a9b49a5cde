"""The regression cases: every bundled scene (short end times where the full run is slow), plus
variants that exercise what the bundled scenes leave out (rate-and-state with state evolution,
a replayed log). Used by ``make_baseline.py`` (writes the baseline) and ``test_regression.py``.

The baseline pins results so that refactoring cannot change them by accident. Work that changes
results on purpose regenerates it (``python tests/regression/make_baseline.py``) in the same
commit and says why in the commit message.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ROOT / "configs"
BASELINE = Path(__file__).resolve().parent / "baseline"


def _scene(path, end=None, **effects):
    from fault_screen import Scene

    scene = Scene.from_toml(CONFIGS / path)
    if end is not None:
        scene = scene.replace(time=dataclasses.replace(scene.time, end=end))
    if effects:
        scene = scene.replace(effects=dataclasses.replace(scene.effects, **effects))
    return scene


def _state_evolution():
    scene = _scene("rustrel-2015-impermeable.toml", end=900.0)
    fault = dataclasses.replace(scene.fault, rate_parameter=0.0269, state_parameter=0.02,
                                critical_slip_distance=1e-5)
    effects = dataclasses.replace(scene.effects, rate_friction=True, state_evolution=True)
    return scene.replace(fault=fault, effects=effects)


def _replay():
    from fault_screen.io.injection_log import read_injection_log

    log = read_injection_log(CONFIGS / "logs" / "rustrel-2015-standin.csv")
    return _scene("rustrel-2015-calibrated.toml", end=600.0), log.volume


def _paper_growing():
    # the bundled (paper-units) scene with growing steps and half an hour of shut-in: its
    # time.theta_min puts the steps of a rung at a lower time weight (the theta ladder)
    scene = _scene("rustrel-2015-calibrated-paper-units.toml")
    return scene.replace(time=dataclasses.replace(scene.time, growth=1.2, dt_max=600.0,
                                                  end=scene.time.end + 1800.0))


#: name -> () -> scene or (scene, injected_volume)
CASES = {
    "rustrel-calibrated": lambda: _scene("rustrel-2015-calibrated.toml", end=700.0),
    "rustrel-initial": lambda: _scene("rustrel-2015-initial.toml", end=400.0),
    "rustrel-impermeable": lambda: _scene("rustrel-2015-impermeable.toml"),
    "rustrel-state-evolution": _state_evolution,
    "rustrel-replay": _replay,
    "rustrel-paper-growing": _paper_growing,
    "terzaghi": lambda: _scene("verification/terzaghi.toml"),
    "fault-diffusion": lambda: _scene("verification/fault-diffusion.toml"),
    "mass-balance": lambda: _scene("verification/mass-balance.toml"),
    "slip-T0.4-horizontal": lambda: _scene("verification/fluid-driven-slip-T0.4-horizontal.toml", end=0.08),
    "slip-T0.4-dip30": lambda: _scene("verification/fluid-driven-slip-T0.4-dip30.toml", end=0.02),
    "slip-T0.7-horizontal": lambda: _scene("verification/fluid-driven-slip-T0.7-horizontal.toml", end=0.08),
    "slip-T0.7-dip30": lambda: _scene("verification/fluid-driven-slip-T0.7-dip30.toml", end=0.015),
}


def run_case(name):
    from fault_screen.simulate import simulate

    made = CASES[name]()
    scene, volume = made if isinstance(made, tuple) else (made, None)
    return simulate(scene, injected_volume=volume)


#: fault profiles (time, x) are kept at this many output times (evenly spaced, last included):
#: every later state depends on all earlier ones, so this pins the run while keeping the baseline small
PROFILE_ROWS = 12


def arrays(result) -> dict:
    """Every array of a result, flattened to 'group/name' keys (fault profiles at PROFILE_ROWS times)."""
    out = {"time": result.time, "fault/x": result.fault_x, "fault/xy": result.fault_xy,
           "fault/weight": result.fault_weights}
    rows = np.unique(np.linspace(0, len(result.time) - 1, PROFILE_ROWS).round().astype(int))
    for group in ("fault", "injection", "balance", "solver"):
        for k, v in getattr(result, group).items():
            v = np.asarray(v)
            out[f"{group}/{k}"] = v[rows] if group == "fault" else v
    return out

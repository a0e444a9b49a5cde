"""Eq. 10 (source), 29 (injection): every injection control with every fault-flow option runs, and
conserves fluid.

The unknowns are partitioned into a linear bulk and a condensed nonlinear set; a combination
that leaves an unknown without linear coupling in the bulk (the pressure-control multiplier when
an evolving aperture makes the fault pressures nonlinear) would make the bulk singular. Each
combination runs a few steps on a coarse mesh, and injected volume = stored + drained at every
step (the volume balance is independent of the solver: it integrates the fields).
"""
import dataclasses
import itertools

import numpy as np
import pytest

from conftest import VERIFICATION
from fault_screen import Scene
from fault_screen.simulate import simulate

# fault pressure carrier: the rock pressure's trace (leak-off), or the fault's own line with
# permeable or impermeable walls
CARRIERS = {
    "leak-off": dict(poroelastic=True, leak_off=True),
    "line, permeable rock": dict(poroelastic=True, leak_off=False),
    "line, impermeable rock": dict(poroelastic=False, leak_off=False),
}


def scene_for(control, carrier, evolving):
    s = Scene.from_toml(VERIFICATION / "mass-balance.toml")
    effects = dataclasses.replace(s.effects, aperture_evolution=evolving, dilation=True,
                                  **CARRIERS[carrier])
    fault = dataclasses.replace(s.fault, dilation_angle=2.0, asperity_height_std=1e-4)
    schedule = ((0.0, 1.0e6), (20.0, 3.0e6)) if control == "pressure" else s.injection.schedule
    injection = dataclasses.replace(s.injection, control=control, schedule=schedule)
    return s.replace(mesh=dataclasses.replace(s.mesh, nx=12, ny=13), fault=fault, effects=effects,
                     injection=injection, time=dataclasses.replace(s.time, end=40.0))


@pytest.mark.parametrize("control,carrier,evolving",
                         list(itertools.product(["rate", "pressure"], CARRIERS, [False, True])))
def test_combination_runs_and_conserves_fluid(control, carrier, evolving):
    scene = scene_for(control, carrier, evolving)
    r = simulate(scene)
    assert r.time[-1] == pytest.approx(40.0)  # reached the end (a step may be cut at the jump)
    injected = r.injection["volume"][1:] / scene.injection.number_of_fractures
    b = r.balance
    accounted = (b["stored_fault"] + b["stored_rock"] + b["leaked"])[1:]
    assert np.all(injected > 0)
    # a consistent discretisation conserves to round-off; 1e-6 leaves room for Newton's tolerance
    assert np.max(np.abs(accounted - injected) / injected) < 1e-6
    if control == "pressure":  # the multiplier holds the prescribed overpressure
        assert r.injection["overpressure"][-1] == pytest.approx(3.0e6, rel=1e-8)

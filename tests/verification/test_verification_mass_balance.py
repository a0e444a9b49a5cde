"""Fluid volume balance with leak-off: injected = stored in fault + stored in rock + drained.

The stored volumes are integrated from the fields at quadrature points
(the physics terms' ``stored_volume``), the drained volume from the reactions at drained nodes, and the
injected volume from the schedule: three independent routes that only agree if the assembled
storage, coupling, conduction and source terms conserve mass.
"""
import numpy as np
import pytest

from conftest import VERIFICATION
from fault_screen import Scene, simulate
from fault_screen.schedule import StepSchedule


@pytest.fixture(scope="module")
def run():
    scene = Scene.from_toml(VERIFICATION / "mass-balance.toml")
    return scene, simulate(scene)


def test_injected_volume_is_the_schedule_volume(run):
    scene, r = run
    expected = np.array([StepSchedule(scene.injection.schedule).volume(0.0, t) for t in r.time])
    assert np.allclose(r.injection["volume"], expected, rtol=1e-12, atol=0)


def test_balance_at_every_step(run):
    """Eq. 10 (source), 29 (injection): injected = stored in fault + stored in rock + leaked, within
    0.5 % at every step."""
    scene, r = run
    injected = r.injection["volume"][1:] / scene.injection.number_of_fractures  # into the model fault
    b = r.balance
    accounted = (b["stored_fault"] + b["stored_rock"] + b["leaked"])[1:]
    # 0.5 % (issue tolerance); a consistent discretisation conserves to round-off
    assert np.max(np.abs(accounted - injected) / injected) < 5e-3


def test_the_case_exercises_every_route(run):
    """The balance is only meaningful if fluid really leaks off, drains and the fault slips."""
    scene, r = run
    b = r.balance
    injected = r.injection["volume"][-1] / scene.injection.number_of_fractures
    assert b["stored_rock"][-1] > 0.5 * injected      # leak-off into the damage zone dominates
    assert b["leaked"][-1] > 0.01 * injected          # some left through drained edges
    assert (r.fault["contact_state"] == 1).any()      # the fault slipped at some point

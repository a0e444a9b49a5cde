"""An effect that is off costs nothing: no unknowns, no assembled terms, no per-step work."""
import dataclasses

import numpy as np
import pytest

from conftest import CONFIGS
from fault_screen import Scene, SceneError
from fault_screen.discretisation import discretise as Model
from fault_screen.physics import (ConstantApertureConduction, CoulombFriction, EvolvingApertureConduction,
                                  RateStateFriction)
from fault_screen.solver import NewtonSolver, assemble_constant


@pytest.fixture(scope="module")
def rustrel():
    scene = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    # one mesh for every switch: leak-off would otherwise grade it across the fault
    return scene.replace(mesh=dataclasses.replace(scene.mesh, fault_grading="off"))


def with_effects(scene, **switches):
    return scene.replace(effects=dataclasses.replace(scene.effects, **switches))


def test_unknowns_per_configuration(rustrel):
    full = Model(rustrel)
    nn = full.mesh.n_nodes
    n_cut_nodes = int(full.fault.pressure_enriched.sum())
    n_fault_nodes = len(full.fault.fault_node_s)
    c = full.dof_counts()
    # 51 x 52 nodes; the horizontal fault cuts one row of 50 elements: 102 nodes
    assert nn == 51 * 52 and n_cut_nodes == 102 and n_fault_nodes == 51
    assert c == {"u": 2 * nn, "a": 2 * n_cut_nodes, "p": nn, "c": n_cut_nodes, "pf": 0, "q": 0}

    no_leak = Model(with_effects(rustrel, leak_off=False)).dof_counts()
    assert no_leak == {"u": 2 * nn, "a": 2 * n_cut_nodes, "p": nn, "c": 0, "pf": n_fault_nodes, "q": 0}

    impermeable = Model(with_effects(rustrel, poroelastic=False, leak_off=False)).dof_counts()
    assert impermeable == {"u": 2 * nn, "a": 2 * n_cut_nodes, "p": 0, "c": 0, "pf": n_fault_nodes, "q": 0}

    rigid = Model(with_effects(rustrel, mechanics=False, poroelastic=False, leak_off=False,
                               rate_friction=False, dilation=False, aperture_evolution=False,
                               gravity=False)).dof_counts()
    assert rigid == {"u": 0, "a": 0, "p": 0, "c": 0, "pf": n_fault_nodes, "q": 0}

    silent = dataclasses.replace(rustrel.injection, schedule=((0.0, 0.0),))
    dry = Model(rustrel.replace(injection=silent, effects=dataclasses.replace(
        rustrel.effects, leak_off=False, fault_flow=False, aperture_evolution=False))).dof_counts()
    assert dry == {"u": 2 * nn, "a": 2 * n_cut_nodes, "p": nn, "c": 0, "pf": 0, "q": 0}

    no_fault = Model(rustrel.replace(injection=silent, effects=dataclasses.replace(
        rustrel.effects, fault=False, leak_off=False, fault_flow=False, rate_friction=False,
        dilation=False, aperture_evolution=False, damage_zone=False))).dof_counts()
    assert no_fault == {"u": 2 * nn, "a": 0, "p": nn, "c": 0, "pf": 0, "q": 0}

    pressure_control = Model(rustrel.replace(injection=dataclasses.replace(
        rustrel.injection, control="pressure", schedule=((0.0, 1e6),)))).dof_counts()
    assert pressure_control["q"] == 1


def test_switched_off_terms_are_not_assembled(rustrel):
    full = Model(with_effects(rustrel, aperture_evolution=False))
    no_flow = Model(with_effects(rustrel, fault_flow=False, aperture_evolution=False))
    # fault conduction and storage exist only with fault flow: fewer stored entries, no cubic law
    assert no_flow.physics.find(ConstantApertureConduction) is None
    assert full.physics.find(ConstantApertureConduction).transmissivity > 0.0
    Hf_full, Hf_no_flow = assemble_constant(full)[2], assemble_constant(no_flow)[2]
    assert no_flow.physics.find(ConstantApertureConduction) is None
    assert Hf_no_flow.nnz < Hf_full.nnz or np.abs(Hf_no_flow - Hf_full).max() > 0
    # evolving aperture: conduction leaves the constant matrix and becomes a per-iteration term
    evolving = Model(rustrel)
    assert isinstance(evolving.physics.find(EvolvingApertureConduction), EvolvingApertureConduction)
    assert np.abs(assemble_constant(evolving)[2] - Hf_full).max() > 0
    s_full, s_evolving = NewtonSolver(full), NewtonSolver(evolving)
    assert len(s_full.nonlinear_terms) == 1 and len(s_evolving.nonlinear_terms) == 2
    assert len(s_full.N) < len(s_evolving.N)  # only the Heaviside DOFs are nonlinear without it


def test_friction_law_is_chosen_once_by_the_scene(rustrel):
    from fault_screen.kernels.contact import TAN_DILATION

    assert isinstance(Model(rustrel).physics.contact.law, RateStateFriction)
    coulomb = Model(with_effects(rustrel, rate_friction=False)).physics.contact.law
    assert type(coulomb) is CoulombFriction
    # dilation off: no dilatancy coefficient even though the scene names an angle
    assert Model(with_effects(rustrel, dilation=False)).physics.contact.law.params[TAN_DILATION] == 0.0


def test_damage_zone_and_gravity_switches(rustrel):
    with_dz = Model(rustrel)
    without = Model(with_effects(rustrel, damage_zone=False))
    assert len(with_dz.zone_props) == 2 and len(without.zone_props) == 1
    # the damage zone is the 50 m band: element rows of 250/51 = 4.90 m whose centroids lie within
    # 50 m of the fault (the cut row and 10 rows on each side), 50 elements a row
    assert np.count_nonzero(with_dz.zone_of) == 50 * 21
    flat = Model(with_effects(rustrel, gravity=False))
    assert np.ptp(flat.fault_points.p0) == 0.0
    # with gravity, p0 grows by the hydrostatic gradient along the gravity direction
    g = np.array(rustrel.initial.gravity_direction)
    fp = with_dz.fault_points
    slope = np.polyfit(fp.xy @ g, fp.p0, 1)[0]
    assert slope == pytest.approx(rustrel.initial.pore_pressure_gradient, rel=1e-12)


@pytest.mark.parametrize("switches,key", [
    ({"poroelastic": False, "leak_off": True}, "effects.leak_off"),
    ({"rate_friction": False, "state_evolution": True}, "effects.state_evolution"),
    ({"fault_flow": False, "leak_off": False, "aperture_evolution": True}, "effects.aperture_evolution"),
])
def test_inconsistent_switches_are_refused(rustrel, switches, key):
    with pytest.raises(SceneError, match=key.replace(".", r"\.")):
        with_effects(rustrel, **switches)

"""The theta ladder (``time.theta_min``): a step size that changes within a rung keeps theta dt and
with it the poroelastic bulk's factors. What it must keep: the scaled bulk itself (to round-off),
the accuracy of backward Euler's growing run (Terzaghi, against a run with eight times finer
steps), stiff modes damped after a pressure jump, the volume balance, and bit-for-bit checkpoints
and forks."""
import dataclasses

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import analytical as an
from conftest import CONFIGS, VERIFICATION
from fault_screen import Scene, SceneError, Simulation, simulate

EPS = np.finfo(float).eps


def _with_time(scene, **changes):
    return scene.replace(time=dataclasses.replace(scene.time, **changes))


# ------------------------------------------------------------------ the scene field
@given(st.one_of(st.floats(max_value=0.5, exclude_max=True, allow_nan=False),
                 st.floats(min_value=0.8, exclude_min=True, allow_nan=False)))
def test_a_theta_min_outside_half_to_theta_is_refused(theta_min):
    """theta_min must lie in [0.5, theta] (theta = 0.8 here): below 1/2 the theta-method is not
    A-stable; above theta the rung would be empty."""
    with pytest.raises(SceneError, match=r"time\.theta_min"):
        Scene.from_dict({"time": {"theta": 0.8, "theta_min": theta_min}})


@given(st.floats(min_value=0.5, max_value=0.8))
def test_a_theta_min_inside_half_to_theta_is_taken(theta_min):
    assert Scene.from_dict({"time": {"theta": 0.8, "theta_min": theta_min}}).time.theta_min == theta_min


# ------------------------------------------------------------------ the bulk keeps its factors
@pytest.fixture(scope="module")
def paper_units():
    """The bundled paper-units Rustrel scene after one 5-s step (its scaling and order made)."""
    sim = Simulation(Scene.from_toml(CONFIGS / "rustrel-2015-calibrated-paper-units.toml"))
    sim.advance(sim.scene.time.dt)
    return sim


@pytest.mark.parametrize("name", ["rustrel-2015-calibrated-paper-units.toml",
                                  "rustrel-2015-calibrated.toml"])
def test_the_rustrel_bulks_depend_on_the_step_through_theta_dt_alone(name, paper_units):
    """On the free unknowns A has no flow rows, C and Hf no mechanical ones (both unit systems)."""
    sim = (paper_units if "paper" in name
           else Simulation(Scene.from_toml(CONFIGS / name)))
    assert sim.solver.system.keeps_factors_at_theta_dt


@pytest.mark.parametrize("growth", [1.2, 1.5])
def test_the_scaled_bulk_at_equal_theta_dt_is_the_same_to_round_off(paper_units, growth):
    """The symmetric scaled bulk (flow rows times -dt) at (dt1, theta0 dt0 / dt1) equals the one at
    (dt0, theta0) entry by entry to 8 units of round-off of its parts (storage and conduction
    terms, each scaled); at theta0 it differs by far more (the test's teeth)."""
    bulk = paper_units.solver.system.fixed_bulk()
    dt0, theta0 = 5.0, 1.0
    dt1 = growth * dt0
    v0 = bulk.values(dt0, theta0)
    storage = bulk.values(dt0, 0.0)   # (no A in the flow rows: the scaled storage there)
    parts = np.abs(storage) + np.abs(v0 - storage)
    v1 = bulk.values(dt1, theta0 * dt0 / dt1)
    assert np.all(np.abs(v1 - v0) <= 8 * EPS * parts)
    assert np.max(np.abs(bulk.values(dt1, theta0) - v0) / np.max(np.abs(v0))) > 1e-6


def test_steps_inside_a_rung_reuse_the_factors(paper_units):
    """Paper-units Rustrel with growing steps (growth 1.2 from 5 s to 60 s): with theta_min = 2/3
    a rung holds three steps (1, 1.2, 1.44 of its first), so the bulk is factorised at every third
    new size; every step's theta is in [2/3, 1] and theta dt is its rung's."""
    scene = _with_time(paper_units.scene, growth=1.2, dt_max=60.0, end=300.0, theta_min=None)
    plain = Simulation(scene)
    plain.advance(scene.time.end)
    ladder = Simulation(_with_time(scene, theta_min=2 / 3))
    seen = []
    ladder.advance(scene.time.end, observer=lambda t, x, disc: seen.append(
        (ladder.solver.time_weight, ladder.rung)))
    dts = np.diff(ladder.result().time)
    thetas, rungs = np.array(seen).T
    assert np.all((thetas >= 2 / 3) & (thetas <= 1.0))
    assert np.allclose(thetas * dts, rungs, rtol=4 * EPS, atol=0)
    new_sizes = np.count_nonzero(np.diff(dts)) + 1
    assert plain.solver.factorizations == new_sizes
    assert ladder.solver.factorizations == len(np.unique(rungs)) <= new_sizes // 3 + 2


def test_a_step_inside_a_rung_is_the_step_at_its_own_theta(paper_units):
    """Each step inside a rung (the factors of its first size, P's flow rows rescaled) equals the
    same step from the same state by a solver factorised at its own dt and theta (a scene with
    that theta), to 1e-7 of the step's change in each field: Newton's tolerance is 1e-8 of the
    residual's reference; measured 2e-11 to 5e-10. (P's flow rows left unscaled, 2-8 %.)"""
    scene = _with_time(paper_units.scene, growth=1.2, dt_max=600.0, theta_min=2 / 3)
    sim = Simulation(scene)
    value = sim._injection_value(None, None, scene.time.end)
    blocks = sim.disc.blocks
    checked = 0
    for _ in range(6):
        x_n, history, t = sim.x.copy(), sim.history.copy(), sim.time
        sim.advance(scene.time.end, max_steps=1)
        dt, theta = sim.time - t, sim.solver.time_weight
        if theta == scene.time.theta:   # (a rung's first step)
            continue
        own = Simulation(_with_time(scene, theta=theta, theta_min=None))
        x = own.solver.step(x_n, history, dt, value(t, t + dt)).x
        for field in (blocks.u, blocks.a, blocks.p):
            change = np.max(np.abs(sim.x[field] - x_n[field]))
            assert np.max(np.abs(x[field] - sim.x[field])) <= 1e-7 * change
        checked += 1
    assert checked == 4


def test_a_weight_off_its_rung_is_refused(paper_units):
    """The rung's factors serve only theta dt = theta0 dt0: a weight without a rung, or off it, is
    refused before anything is solved (a wrong weight would take the wrong factors)."""
    sim = paper_units
    value = sim._injection_value(None, None, sim.scene.time.end)(sim.time, sim.time + 6.0)
    for weight in (dict(time_weight=5.0 / 6.0), dict(time_weight=0.8, rung=5.0)):
        with pytest.raises(ValueError, match="theta ladder"):
            sim.solver.step(sim.x, sim.history, 6.0, value, **weight)


# ------------------------------------------------------------------ Terzaghi: accuracy, stiffness
TAUS = [0.01, 0.05, 0.2, 0.5, 1.0]


def _terzaghi(refine=1, **time):
    """Terzaghi's column with steps from 1 s growing by 1.2 to 400 s, every size and growth - 1
    divided by ``refine``, its pore pressures at TAUS consolidation times (Pa, one row each)."""
    base = Scene.from_toml(VERIFICATION / "terzaghi.toml")
    scene = _with_time(base, dt=1.0 / refine, dt_max=400.0 / refine, growth=1 + 0.2 / refine, **time)
    sim = Simulation(scene)
    rk = scene.rock
    t_c = an.terzaghi_time_scale(height=scene.mesh.ly, E=rk.youngs_modulus, nu=rk.poissons_ratio,
                                 biot=rk.biot_coefficient,
                                 biot_modulus=1.0 / sim.disc.zone_props[0]["inv_M"],
                                 mobility=rk.permeability / scene.fluid.viscosity)
    out = []
    for tau in TAUS:
        sim.advance(tau * t_c)
        out.append(sim.x[sim.disc.blocks.p].copy())
    return np.array(out), sim


@pytest.fixture(scope="module")
def terzaghi_errors():
    """Each run's largest pressure error at each of TAUS against backward Euler with 8x finer
    steps, over the 1 MPa load; and the runs' bulk factorisations."""
    reference, _ = _terzaghi(refine=8)
    errors, factorisations = {}, {}
    for refine in (1, 2):
        for theta_min in (None, 2 / 3):
            p, sim = _terzaghi(refine, theta_min=theta_min)
            errors[refine, theta_min] = np.max(np.abs(p - reference), axis=1) / 1e6
            factorisations[refine, theta_min] = sim.solver.factorizations
    return errors, factorisations


def test_the_ladder_is_no_less_accurate_than_backward_euler(terzaghi_errors):
    """At every output time the ladder's error is at most backward Euler's (same steps), which
    measured 0.8e-3 to 3.4e-3 of the load at the coarser steps, the ladder's 0.4e-3 to 2.7e-3
    (its local error coefficient 1/2 - theta is smaller than backward Euler's); and it
    factorises the bulk at most half as often."""
    errors, factorisations = terzaghi_errors
    for refine in (1, 2):
        assert np.all(errors[refine, 2 / 3] <= errors[refine, None])
        assert factorisations[refine, 2 / 3] <= factorisations[refine, None] / 2


def test_the_ladder_converges_as_the_steps_shrink(terzaghi_errors):
    """Halving every step (and growth - 1) at least halves the ladder's error minus a fifth of the
    reference's own (first order; measured 0.2-0.45 of it)."""
    errors, _ = terzaghi_errors
    assert np.all(errors[2, 2 / 3] <= 0.6 * errors[1, 2 / 3])


def _pressure_history(**time):
    """Terzaghi's column with a first step of 20 s (the load's pressure jump at the drained top is
    a stiff mode: the diffusion time of an element there is ~0.4 s): the column's pressures at
    every step, over the undrained pressure, bottom to top."""
    scene = _with_time(Scene.from_toml(VERIFICATION / "terzaghi.toml"), dt=20.0, growth=1.2,
                       dt_max=2000.0, **time)
    sim = Simulation(scene)
    column = sim.disc.coords[:, 0] == 0.0
    order = np.argsort(sim.disc.coords[column, 1])
    rows = []
    sim.advance(scene.time.end, observer=lambda t, x, disc: rows.append(
        x[disc.blocks.p][column][order]))
    rows = np.array(rows)
    return rows / rows[0].max(), sim


def test_stiff_modes_stay_damped_after_the_pressure_jump():
    """The consolidating column's pressure never rises at any point, and never falls below zero
    (to 1e-9 of the undrained pressure): each rung starts at backward Euler, which removes the
    stiff mode of the jump, and theta >= 2/3 damps a stiff mode by at least half a step after.
    Crank-Nicolson (theta 0.5 throughout), whose stiff amplification is -1, rises by 6 % and goes
    negative on the same steps: the bound is not idle."""
    ladder, sim = _pressure_history(theta_min=2 / 3)
    assert sim.solver.factorizations < sim.steps / 2
    assert np.max(np.diff(ladder, axis=0)) <= 1e-9
    assert ladder.min() >= -1e-9
    crank_nicolson, _ = _pressure_history(theta=0.5)
    assert np.max(np.diff(crank_nicolson, axis=0)) > 0.01


# ------------------------------------------------------------------ balance, checkpoints, forks
def test_volume_balance_holds_to_round_off_with_a_varying_theta():
    """The mass-balance scene with steps growing by 1.2 to 40 s, theta_min = 2/3 (theta at 1,
    0.83, 0.69 of each rung): injected = stored in fault and rock + drained, to 1e-13 relative at
    every step (measured 4e-16)."""
    scene = _with_time(Scene.from_toml(VERIFICATION / "mass-balance.toml"), growth=1.2,
                       dt_max=40.0, theta_min=2 / 3)
    r = simulate(scene)
    injected = r.injection["volume"][1:] / scene.injection.number_of_fractures
    b = r.balance
    accounted = (b["stored_fault"] + b["stored_rock"] + b["leaked"])[1:]
    assert np.max(np.abs(accounted - injected) / injected) < 1e-13


def _ladder_scene():
    """The calibrated Rustrel scene, coarse, steps growing by 1.1 from 2 s with theta_min 2/3."""
    s = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    return s.replace(mesh=dataclasses.replace(s.mesh, nx=20, ny=21),
                     time=dataclasses.replace(s.time, end=400.0, dt=2.0, growth=1.1, dt_max=20.0,
                                              theta_min=2 / 3))


@pytest.fixture(scope="module")
def ladder_run():
    scene = _ladder_scene()
    sim = Simulation(scene)
    sim.advance(scene.time.end)
    return scene, sim


def _mid_rung_steps(scene):
    """A step count after which the next step is inside the current rung (not its first)."""
    sim = Simulation(scene)
    for k in range(1, 40):
        sim.advance(scene.time.end, max_steps=1)
        if sim.rung != sim.dt and sim.rung * scene.time.theta / sim.dt >= scene.time.theta_min:
            if k > 3:
                return k
    raise AssertionError("no step inside a rung")


def test_a_checkpoint_inside_a_rung_continues_bit_for_bit(ladder_run, tmp_path):
    scene, reference = ladder_run
    steps = _mid_rung_steps(scene)
    sim = Simulation(scene)
    sim.advance(scene.time.end, max_steps=steps)
    path = sim.checkpoint(tmp_path / "state.h5")
    restored = Simulation.restore(path)
    assert restored.rung == sim.rung
    restored.advance(scene.time.end)
    assert restored.steps == reference.steps
    assert np.array_equal(restored.x, reference.x)
    assert restored.injected == reference.injected and restored.leaked == reference.leaked


def test_a_fork_inside_a_rung_continues_bit_for_bit(ladder_run):
    scene, reference = ladder_run
    sim = Simulation(scene)
    sim.advance(scene.time.end, max_steps=_mid_rung_steps(scene))
    fork = sim.fork()
    fork.advance(scene.time.end)
    sim.advance(scene.time.end)
    assert np.array_equal(fork.x, reference.x) and np.array_equal(sim.x, reference.x)
    assert fork.injected == reference.injected and fork.leaked == reference.leaked

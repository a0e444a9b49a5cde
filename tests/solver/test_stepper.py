"""The stepper: a run advanced in chunks, or checkpointed and restored at any step, gives exactly
the arrays of an uninterrupted run (bit for bit: the same operations on the same numbers)."""
import dataclasses

import numpy as np
import pytest

from conftest import CONFIGS, ROOT, VERIFICATION
from fault_screen import Scene, Simulation
from fault_screen.simulate import simulate


def _arrays(result) -> dict:
    out = {"time": result.time}
    for group in ("fault", "injection", "balance", "solver"):
        out.update({f"{group}/{k}": v for k, v in getattr(result, group).items()})
    return out


def _assert_identical(a, b):
    a, b = _arrays(a), _arrays(b)
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].shape == b[k].shape, k
        assert np.array_equal(a[k], b[k]), f"{k}: largest difference {np.max(np.abs(a[k] - b[k])):.3e}"


def hard_rustrel():
    """Impermeable Rustrel on a coarse mesh with every history-carrying effect on: rate-and-state
    friction with the aging law, dilation, an aperture that follows the opening; growing steps.
    It slips from ~200 s, so the checkpoints below fall before, at and after slip onset."""
    s = Scene.from_toml(CONFIGS / "rustrel-2015-impermeable.toml")
    return s.replace(
        mesh=dataclasses.replace(s.mesh, nx=20, ny=21),
        fault=dataclasses.replace(s.fault, state_parameter=0.02, critical_slip_distance=1e-5),
        effects=dataclasses.replace(s.effects, rate_friction=True, state_evolution=True,
                                    aperture_evolution=True, dilation=True),
        time=dataclasses.replace(s.time, end=400.0, dt=2.0, growth=1.08, dt_max=12.0))


def pressure_controlled():
    """The T = 0.4 slip scene on a coarse mesh (4 m at the fault: 2710 unknowns, slipping at 168
    fault points by the end). Its graded mesh ignores nx and ny: the refinement sets the size."""
    s = Scene.from_toml(VERIFICATION / "fluid-driven-slip-T0.4-horizontal.toml")
    coarse = dataclasses.replace(s.mesh.refinement, size=4.0)
    return s.replace(mesh=dataclasses.replace(s.mesh, refinement=coarse),
                     time=dataclasses.replace(s.time, end=0.05))


def poroelastic_growing():
    """The calibrated (poroelastic) Rustrel scene on a coarse mesh with growing steps: its bulk
    factors depend on the step size, so each new size condenses the bulk anew, and a restored
    run forms its condensed block again from the condensation of the checkpoint's step size
    (steps grow to dt_max by about step 40: checkpoints before and after)."""
    s = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    return s.replace(mesh=dataclasses.replace(s.mesh, nx=20, ny=21),
                     time=dataclasses.replace(s.time, end=600.0, dt=2.0, growth=1.05, dt_max=12.0))


def poroelastic_theta_ladder():
    """``poroelastic_growing`` with the theta ladder (time.theta_min 2/3): a step inside a rung
    keeps the bulk's and the condensed block's factors of the rung's first size, which a
    restored run makes again (the rung is in the checkpoint)."""
    s = poroelastic_growing()
    return s.replace(time=dataclasses.replace(s.time, theta_min=2 / 3))


def extrapolated_guess():
    """``hard_rustrel`` with an extrapolated first Newton iterate: each step starts from the last
    three accepted states (growing steps: unequal intervals), which a checkpoint, a chunk
    boundary and a fork carry on."""
    s = hard_rustrel()
    return s.replace(solver=dataclasses.replace(s.solver, first_guess="extrapolated"))


def constant_friction():
    """The OpenGeoSys peer scene (benchmarks/peers): held overpressure, constant friction. Each
    step's first Newton iteration finds the fault stuck and its second the slipping patch
    again; from about 600 s the patch is too wide for a low-rank change of one block, and the
    condensed solver recalls the block factorised before the last (2 LUs and 18 recalls in
    the 30 steps): a restored run and a fork make both blocks again."""
    return Scene.from_toml(ROOT / "benchmarks" / "peers" / "rustrel-pressure.toml")


CASES = {"rate, rate-and-state, evolving aperture": hard_rustrel,
         "constant friction, recalled blocks": constant_friction,
         "extrapolated first guess": extrapolated_guess,
         "pressure control": pressure_controlled,
         "poroelastic, growing steps": poroelastic_growing,
         "poroelastic, growing steps, theta ladder": poroelastic_theta_ladder}


@pytest.fixture(scope="module", params=list(CASES))
def case(request):
    scene = CASES[request.param]()
    reference = simulate(scene)
    assert np.max(np.abs(reference.fault["slip"])) > 0  # the case does slip
    return scene, reference


def test_chunks_aligned_to_data_give_the_uninterrupted_run(case):
    scene, reference = case
    sim = Simulation(scene)
    for t_data in np.linspace(0.0, scene.time.end, 7)[1:-1] + 0.37 * scene.time.dt:
        sim.advance(t_data, align=True)
        assert sim.time <= t_data  # never ahead of the data
    sim.advance(scene.time.end)
    _assert_identical(sim.result(), reference)


@pytest.mark.parametrize("fraction", [0.0, 0.4, 0.8])
def test_checkpoint_and_restore_continue_bit_identically(case, fraction, tmp_path):
    """Checkpoints after the first step, and at 40 % and 80 % of the run."""
    scene, reference = case
    steps = max(1, int(fraction * (len(reference.time) - 1)))
    sim = Simulation(scene)
    sim.advance(scene.time.end, max_steps=steps)
    assert sim.steps == steps
    path = sim.checkpoint(tmp_path / "state.h5")
    del sim
    restored = Simulation.restore(path)
    assert restored.steps == steps
    restored.advance(scene.time.end)
    _assert_identical(restored.result(), reference)


def test_a_step_ending_on_a_chunk_boundary_keeps_the_step_sequence():
    """Rustrel's 5 s steps: chunks ending on multiples of 5 s take exactly the same steps."""
    s = Scene.from_toml(CONFIGS / "rustrel-2015-initial.toml")
    scene = s.replace(mesh=dataclasses.replace(s.mesh, nx=20, ny=21),
                      time=dataclasses.replace(s.time, end=200.0))
    reference = simulate(scene)
    sim = Simulation(scene)
    for t in (35.0, 100.0, 200.0):
        sim.advance(t)
    _assert_identical(sim.result(), reference)


def test_volume_and_pressure_drivers_are_checked():
    sim = Simulation(pressure_controlled())
    with pytest.raises(ValueError, match="volume= drives rate control"):
        sim.advance(0.01, volume=1e-3)
    # a constant overpressure equals the scene's own one-step schedule
    dp = sim.scene.injection.schedule[0][1]
    sim.advance(0.01, pressure=dp)
    ref = Simulation(pressure_controlled())
    ref.advance(0.01)
    assert np.array_equal(sim.x, ref.x)


def test_a_volume_spread_over_an_interval_is_injected_exactly():
    s = Scene.from_toml(CONFIGS / "rustrel-2015-initial.toml")
    scene = s.replace(mesh=dataclasses.replace(s.mesh, nx=20, ny=21))
    sim = Simulation(scene)
    sim.advance(60.0, volume=0.012)      # 12 L over the first minute
    sim.advance(95.0, volume=lambda t0, t1: 1e-4 * (t1 - t0))  # 0.1 L/s
    assert sim.result().injection["volume"][-1] == pytest.approx(0.012 + 35 * 1e-4, rel=1e-12)


@pytest.mark.parametrize("name", ["rustrel-2015-calibrated", "rustrel-2015-calibrated-paper-units"])
def test_a_zero_rate_start_converges_at_round_off(name):
    """With nothing injected the fault's internal forces stay near zero: the convergence test's
    reference must still accept the round-off of the contact forces (differences of tractions of
    ~4 MPa), which before was rejected for 120 iterations at each of 8 cuts (scaled residuals
    ~3e-15 against a tolerance of 1e-8 of a reference of ~1e-7). The state stays at rest:
    overpressure below 1e-2 Pa (what the tolerance 1e-8 resolves of in-situ stresses of a few
    MPa; the fault's response to its in-situ state is ~1e-3 Pa), jumps below 1e-12 m, and the stored
    volumes balance the zero injected to 1e-15 m3 (each ~3e-12 m3 of round-off)."""
    sim = Simulation(Scene.from_toml(CONFIGS / f"{name}.toml"))
    taken = sim.advance(1.0, volume=0.0)
    row = sim.last_row
    assert taken == 1 and sim.time == 1.0 and row["cuts"] == 0
    assert np.max(np.abs(row["overpressure"])) < 1e-2
    assert np.max(np.abs(row["slip"])) < 1e-12 and np.max(np.abs(row["opening"])) < 1e-12
    assert row["inj_volume"] == 0.0
    assert abs(row["stored_rock"] + row["stored_fault"] + row["leaked"]) < 1e-15


def test_a_converging_fault_brings_the_bulk_up_to_date_once_a_step(monkeypatch):
    """The stalled rule (``solver.STALLED_ITERATIONS``) fires only near the tolerance
    (``STALLED_NEAR_TOLERANCE``): on the coarse T = 0.4 slip scene, whose slip front crosses a
    few fault points an iteration without halving the residual, the deferred bulk is completed
    (one backward sweep) exactly once in each of its 24 steps, where the rule without that
    bound completed it 26 times; each step takes the same Newton iterations as with the
    unbounded rule, and the slip agrees to 1e-10 of its largest value (round-off: the bulk's
    answer summed over other updates)."""
    from fault_screen import linear_system, solver

    completed = []
    complete_bulk = linear_system.CondensedSystem.complete_bulk

    def counted(self, *args):
        completed.append(1)
        return complete_bulk(self, *args)

    monkeypatch.setattr(linear_system.CondensedSystem, "complete_bulk", counted)
    bounded = simulate(pressure_controlled())
    steps, sweeps = len(bounded.time) - 1, len(completed)
    monkeypatch.setattr(solver, "STALLED_NEAR_TOLERANCE", np.inf)
    completed.clear()
    unbounded = simulate(pressure_controlled())
    assert steps == 24 and sweeps == steps and len(completed) > steps
    assert np.array_equal(bounded.solver["iterations"], unbounded.solver["iterations"])
    slip = bounded.fault["slip"]
    assert np.max(np.abs(slip)) > 0
    assert np.max(np.abs(slip - unbounded.fault["slip"])) <= 1e-10 * np.max(np.abs(slip))


def test_a_restored_run_recalls_the_block_its_run_kept(tmp_path):
    """A checkpoint holds both condensed blocks (the recalled one too): the restored run makes
    them again, and its next step recalls where the run recalls, with no LU the run did not
    make (without the recalled block it would factorise the stuck block again: one recall
    fewer), and ends the step with the same factors bit for bit."""
    scene = constant_friction()
    sim = Simulation(scene)
    sim.advance(scene.time.end, max_steps=24)
    restored = Simulation.restore(sim.checkpoint(tmp_path / "state.h5"))
    run = sim.solver.system._dense
    recalls, factorizations = run.recalls, run.factorizations
    next_time = sim.time + scene.time.dt
    for each in (sim, restored):
        each.advance(next_time)
    again = restored.solver.system._dense
    assert run.recalls - recalls == again.recalls == 2
    assert run.factorizations == factorizations and again.factorizations == 2   # (its two made again)
    assert np.array_equal(run.factors[0], again.factors[0])
    assert np.array_equal(run._recalled["factors"][0], again._recalled["factors"][0])
    assert np.array_equal(sim.x, restored.x)

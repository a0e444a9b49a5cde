"""An extrapolated first Newton iterate (``solver.first_guess = 'extrapolated'``): the weights
are those of the Lagrange polynomial, and the steps converge to the same tolerance as from the
previous state, in fewer Newton iterations where the state evolves smoothly."""
import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import CONFIGS
from fault_screen import Scene
from fault_screen.scene import SceneError
from fault_screen.simulate import simulate
from fault_screen.stepper import extrapolation_weights


finite_or_not = st.floats(width=64, allow_subnormal=True)


@settings(deadline=None)   # (the first call loads the kernel)
@given(st.integers(1, 4).flatmap(lambda k: st.tuples(
    st.lists(st.floats(-1e3, 1e3), min_size=k, max_size=k),
    st.lists(st.lists(finite_or_not, min_size=6, max_size=6), min_size=k, max_size=k))))
def test_weighted_sum_gives_the_floats_of_numpy_products_added_in_place(case):
    """The extrapolation's sums (the guess, and the products summed instead of made whole):
    bit for bit those of ``w0 * a0`` with ``+= w * a`` for each further array (the solver's
    bit-for-bit results rest on it), infinities and NaN included, for 1 to 4 arrays."""
    from fault_screen.solver import weighted_sum

    weights, arrays = np.array(case[0]), [np.array(a) for a in case[1]]
    with np.errstate(all="ignore"):
        expected = weights[0] * arrays[0]
        for w, a in zip(weights[1:], arrays[1:]):
            expected += w * a
        got = weighted_sum(weights, arrays)
    assert got.dtype == np.float64 and got.shape == (6,)
    assert np.array_equal(got, expected, equal_nan=True)
    assert np.array_equal(np.signbit(got), np.signbit(expected))   # (zeros' signs too)


@settings(deadline=None)   # (the first call loads the kernel)
@given(st.integers(1, 2600).flatmap(lambda n: st.tuples(
    st.just(n), st.lists(st.tuples(st.integers(0, n - 1), finite_or_not), max_size=6),
    st.lists(st.integers(0, n - 1), max_size=40), st.integers(0, 2**32 - 1))))
def test_where_changed_classifies_as_the_difference_and_its_counts(case):
    """The solver's test of where an iterate moved since its products were made (0: nowhere,
    1: at condensed unknowns only, 2: elsewhere too), against the numpy it replaced
    (count_nonzero of x - before, and of its condensed entries): the same answer for changes
    anywhere in arrays that span several blocks (CHANGE_BLOCK = 1024), NaN and infinity
    included (inf - inf is NaN: a change)."""
    from fault_screen.solver import _where_changed

    n, changes, condensed, seed = case
    before = np.random.default_rng(seed).normal(size=n)
    before[::97] = np.inf
    x = before.copy()
    for k, v in changes:
        x[k] = v
    n_index = np.full(n, -1, dtype=np.int64)
    N = np.unique(np.array(condensed, dtype=np.int64))
    n_index[N] = np.arange(len(N))
    with np.errstate(invalid="ignore"):
        d = x - before
    n_changed, n_changed_N = np.count_nonzero(d), np.count_nonzero(d[N])
    expected = 0 if n_changed == 0 else (1 if n_changed == n_changed_N else 2)
    assert _where_changed(x, before, n_index) == expected


@pytest.mark.parametrize("times, at", [([0.0, 5.0, 10.0], 15.0), ([1.0, 1.7, 4.2], 5.5),
                                       ([2.0, 3.0], 3.6), ([0.3, 0.6, 1.2], 1.21)])
def test_weights_reproduce_a_polynomial_of_their_degree(times, at):
    """Against numpy's least-squares fit through the same points (exact for len(times) points
    and degree len(times) - 1): 1e-12 relative; uniform steps give (1, -3, 3)."""
    rng = np.random.default_rng(7)
    coefficients = rng.normal(size=len(times))
    values = np.polyval(coefficients, times)
    weights = extrapolation_weights(times, at)
    expected = np.polyval(np.polyfit(times, values, len(times) - 1), at)
    assert abs(weights @ values - expected) <= 1e-12 * max(1.0, abs(expected))
    assert abs(weights.sum() - 1.0) <= 1e-14 * np.abs(weights).sum()   # constants kept
    if times == [0.0, 5.0, 10.0]:
        assert np.array_equal(weights, [1.0, -3.0, 3.0])


def _paper_units(first_guess):
    """The bundled paper-units scene on a coarse mesh for its first 600 s (slip from ~300 s)."""
    s = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated-paper-units.toml")
    return s.replace(mesh=dataclasses.replace(s.mesh, nx=20, ny=21),
                     time=dataclasses.replace(s.time, end=600.0),
                     solver=dataclasses.replace(s.solver, first_guess=first_guess))


@pytest.fixture(scope="module")
def both_guesses():
    return {guess: simulate(_paper_units(guess)) for guess in ("previous", "extrapolated")}


def test_an_extrapolated_guess_saves_newton_iterations(both_guesses):
    """At most 3/4 of the iterations from the previous state (measured 0.5 on the bundled mesh),
    and no step cut."""
    previous = both_guesses["previous"].solver
    extrapolated = both_guesses["extrapolated"].solver
    assert extrapolated["iterations"].sum() <= 0.75 * previous["iterations"].sum()
    assert not extrapolated["step_cuts"].any()


def test_both_guesses_converge_to_the_same_states(both_guesses):
    """Each step's answer is fixed up to the Newton tolerance (1e-8 of the reference
    magnitudes): pressures, slip and tractions agree to 1e-6 relative to their largest value,
    a thousand times below the smallest effect of physics the regression baseline detects (1e-4),
    over 120 steps that each carry the last one's difference on."""
    a, b = both_guesses["previous"], both_guesses["extrapolated"]
    assert np.max(np.abs(a.fault["slip"])) > 0   # the fault slips in this window
    for key in ("slip", "pressure", "effective_normal_stress", "shear_traction"):
        scale = np.max(np.abs(a.fault[key]))
        assert np.max(np.abs(a.fault[key] - b.fault[key])) <= 1e-6 * scale, key


@given(st.text(max_size=20).filter(lambda v: v not in ("previous", "extrapolated")))
def test_an_unknown_first_guess_is_a_scene_error(value):
    with pytest.raises(SceneError, match=r"^solver\.first_guess = .*must be 'previous' or 'extrapolated'$"):
        Scene.from_dict({"solver": {"first_guess": value}})


def test_a_fork_continues_with_the_runs_extrapolation():
    """A fork made mid-run takes the run's remaining steps bit for bit: it starts from the same
    earlier states (growing steps, rate-and-state: ``test_stepper.extrapolated_guess``)."""
    from fault_screen import Simulation
    from test_stepper import extrapolated_guess

    scene = extrapolated_guess()
    sim = Simulation(scene)
    sim.advance(0.5 * scene.time.end)
    assert len(sim.earlier_states) == 2
    twin = sim.fork()
    twin.advance(scene.time.end)
    sim.advance(scene.time.end)
    assert twin.steps == sim.steps
    assert np.array_equal(twin.x, sim.x)
    assert np.array_equal(twin.history, sim.history)


def test_the_guess_products_are_the_sums_of_the_states_whole_products(monkeypatch):
    """An extrapolated guess's [A; Hf] x0 and C x0 are summed from the whole products kept at
    the states it extrapolates: equal to the whole products at x0 to 1e-12 of their largest
    magnitude, and one whole product a step is made (at the convergence test), not two."""
    import fault_screen.solver as solver_module
    from fault_screen import Simulation

    scene = _paper_units("extrapolated")
    scene = scene.replace(time=dataclasses.replace(scene.time, end=100.0))
    sim = Simulation(scene)
    sim.advance(50.0)
    solver = sim.solver
    guess, (weights, states) = sim._extrapolated_guess(sim.dt)
    AHx, Cx = solver._combined_products(guess, weights, states)
    AHx_whole, Cx_whole, _ = solver_module._whole_products(*solver._csr_arrays, guess,
                                                           np.zeros_like(guess))
    assert np.max(np.abs(AHx - AHx_whole)) <= 1e-12 * np.max(np.abs(AHx_whole))
    assert np.max(np.abs(Cx - Cx_whole)) <= 1e-12 * np.max(np.abs(Cx_whole))
    # a prescribed value that moves between the states: no sum (made whole instead)
    moved = [x.copy() for x in states]
    moved[0][solver._fixed[0]] += 1.0
    assert solver._combined_products(guess, weights, moved) is None

    calls = []
    whole = solver_module._whole_products
    monkeypatch.setattr(solver_module, "_whole_products", lambda *a: calls.append(1) or whole(*a))
    steps = sim.advance(scene.time.end)
    assert steps == 10 and len(calls) == steps


def test_state_products_are_kept_only_for_an_extrapolated_guess():
    """From the previous state nothing sums them: no state's products are held (three vectors
    of 3 n values each would stay alive for nothing); extrapolating, the last three, the newest
    at the current state and equal to the whole products there to the bit."""
    import fault_screen.solver as solver_module
    from fault_screen import Simulation

    for guess, kept in (("previous", 0), ("extrapolated", 3)):
        sim = Simulation(_paper_units(guess))
        sim.advance(25.0)
        products = sim.solver._state_products
        assert len(products) == kept, guess
    state, AHx, Cx = products[-1]
    assert state is sim.x
    AHx_whole, Cx_whole, _ = solver_module._whole_products(*sim.solver._csr_arrays, sim.x,
                                                           np.zeros_like(sim.x))
    assert np.array_equal(AHx, AHx_whole) and np.array_equal(Cx, Cx_whole)

"""Members of an ensemble run in one process share the bulk's order, symbolic analyses, the
positions of its fixed pattern and, where their bulks are equal, its factors (fault_screen/shared_bulk.py, forecast.ensemble.run_members):
every array of every forecast must equal the member's run alone, bit for bit.

The scene: the SI calibrated Rustrel scene (rock pore pressure: the bulk is factorised per step
size) on a 20 x 21 mesh, 60 s of history, then 60 s ahead on a step ladder to 40 s (steps of
5, 10, 20, 20 and 5 s): three factorisations a member, 5, 10 and 20 s. The number of fractures
enters the source only, so members varying it factorise equal matrices. The friction leaves the
bulk as it is but enters the contact's tangent, and so the scaling of the fault's unknowns, which
borders the factorised matrix: a member of another friction makes its own factors (their
order and symbolic analysis are the pattern's, shared). The hydraulic aperture enters the
storage of the rock's pressure next to the fault: the bulk itself differs."""
import dataclasses
import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import CONFIGS
from fault_screen import Scene
from fault_screen.ensemble import Runner
from fault_screen.forecast import parse_plan
from fault_screen.forecast.ensemble import LiveEnsemble, MemberRun, chunks, release, run_member, run_members
from fault_screen.shared_bulk import SharedBulk, active, sharing

AT, HORIZON = 60.0, 60.0
PLANS = [parse_plan(p) for p in ("hold", "stop")]
EQUAL_BULKS = [{"injection.number_of_fractures": 40.0}, {"injection.number_of_fractures": 90.0}, {}]
OTHERS = [{"fault.friction": 0.62, "injection.number_of_fractures": 40.0}, {"fault.hydraulic_aperture": 2.0e-5}]


@pytest.fixture(scope="module")
def scene_dict():
    s = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
    small = dataclasses.replace(s.mesh, nx=20, ny=21)
    return s.replace(mesh=small, time=dataclasses.replace(s.time, end=AT + HORIZON)).to_dict()


def _calls(scene_dict, draws, steps={"ladder": 40.0}):
    return [(i, scene_dict, d, [AT], PLANS, HORIZON, None, None, None, steps) for i, d in enumerate(draws)]


@pytest.fixture(scope="module")
def alone(scene_dict):
    return [run_member(*c) for c in _calls(scene_dict, EQUAL_BULKS + OTHERS)]


def _assert_same(a, b):
    assert a.ok and b.ok, (a.error, b.error)
    assert len(a.forecasts) == len(b.forecasts) == len(PLANS)
    for fa, fb in zip(a.forecasts, b.forecasts):
        ra, rb = fa.row(), fb.row()
        ra.pop("wall_s"), rb.pop("wall_s")
        assert ra == rb
        assert np.array_equal(fa.time, fb.time) and np.array_equal(fa.level, fb.level)
        assert fa.metrics.keys() == fb.metrics.keys() and fa.metrics
        for k in fa.metrics:
            assert np.array_equal(fa.metrics[k], fb.metrics[k]), k


def test_members_sharing_factors_equal_each_member_run_alone(scene_dict, alone):
    from fault_screen.forecast import ensemble

    shared = run_members("test-shared", _calls(scene_dict, EQUAL_BULKS + OTHERS))
    store = ensemble._STORES["test-shared"]
    assert release("test-shared") and not release("test-shared")
    for a, b in zip(alone, shared):
        _assert_same(a, b)
    # the 5, 10 and 20-s factors: made by the first member, taken from the store by the next
    # two (equal matrices); the friction's and the aperture's members make their own
    assert [r.factorizations for r in shared] == [3, 0, 0, 3, 3]
    assert [r.shared_factorizations for r in shared] == [0, 3, 3, 0, 0]
    assert all(r.factorizations == r.shared_factorizations == 0 for r in alone)
    assert len(store._orders) == 1 and len(store.analyses._held) == 1   # one pattern
    # the positions of the bulk's fixed pattern: made by the first member, whose values alone
    # differ from the next four's (the friction's scaling and the aperture's storage included)
    assert (store.patterns_made, store.patterns_shared) == (1, 4)


def test_a_chunked_dask_run_equals_the_per_member_run(scene_dict, alone):
    """One task a member on one Dask worker process: the later tasks' members find the factors
    the first task's made (the worker keeps the ensemble's store between its tasks)."""
    calls = _calls(scene_dict, EQUAL_BULKS + OTHERS)
    dealt = chunks(calls, workers=1)
    assert [[c[0] for c in chunk] for chunk in dealt] == [[0], [1], [2], [3], [4]]
    runs = {}
    with Runner(1) as runner:
        for k, chunk in runner.each(run_members, [("test-dask", chunk) for chunk in dealt]):
            assert not isinstance(chunk, BaseException), chunk
            runs.update((r.index, r) for r in chunk)
    assert sorted(runs) == [0, 1, 2, 3, 4]
    for a in alone:
        _assert_same(a, runs[a.index])
    assert [runs[i].shared_factorizations for i in range(5)] == [0, 3, 3, 0, 0]
    # the task's own thread's CPU time is measured and is a part of the worker process's (how
    # large a part depends on the machine's load: the worker's other threads, not a fact to test)
    assert all(0.0 < r.thread_cpu_s <= r.cpu_s for r in runs.values())
    assert len({r.worker for r in runs.values()}) == 1 and runs[0].worker != alone[0].worker


def test_live_ensemble_members_share_one_store_and_equal_each_member_run_alone(scene_dict, alone):
    """LiveEnsemble steps its members inside its own store: every forecast equals the member's
    run alone, and the store made each equal bulk's 5, 10 and 20-s factors once (3 for the three
    equal bulks, 3 each for the friction's and the aperture's members: 9 made, 6 shared)."""
    live = LiveEnsemble(Scene.from_dict(scene_dict), EQUAL_BULKS + OTHERS, base=False, steps={"ladder": 40.0})
    live.advance(AT, align=True)
    made, _ = live.run(PLANS, HORIZON)
    assert [m.plan for m in made] == [p.name for p in PLANS] and all(m.members == 5 for m in made)
    for j, a in enumerate(alone):
        _assert_same(a, MemberRun(index=j, params={}, ok=True, forecasts=[m.forecasts[j] for m in made]))
    store = live.store
    assert (store.made, store.shared) == (9, 6)
    assert len(store._orders) == 1 and (store.patterns_made, store.patterns_shared) == (1, 4)
    assert len(store._factors) == 0   # shared within the round, dropped after it


def test_live_members_of_distinct_bulks_leave_no_factors_in_the_store(scene_dict, alone):
    """Three live members whose bulks all differ (the scene, another friction, another
    aperture): each makes its own 5-s factors in the history and its 10 and 20-s ones in the
    look-ahead (9 made, none shared), and after each round (advance, run) the store holds no
    factor set (it held min(9, MAX_FACTORS) = 8 before it dropped them), only the one order and
    fixed pattern; the forecasts equal each member's run alone, and stepping on after the drop
    makes no factorisation (each member kept its own 5-s factors)."""
    live = LiveEnsemble(Scene.from_dict(scene_dict), EQUAL_BULKS[2:] + OTHERS, base=False,
                        steps={"ladder": 40.0})
    store = live.store
    live.advance(AT, align=True)
    assert (store.made, store.shared, len(store._factors)) == (3, 0, 0)
    made, _ = live.run(PLANS, HORIZON)
    assert (store.made, store.shared, len(store._factors)) == (9, 0, 0)
    assert len(store._orders) == 1 and (store.patterns_made, store.patterns_shared) == (1, 2)
    for j, a in enumerate(alone[2:]):
        _assert_same(a, MemberRun(index=j, params={}, ok=True, forecasts=[m.forecasts[j] for m in made]))
    live.advance(AT + 10.0, align=True)
    assert live.time == AT + 10.0 and (store.made, len(store._factors)) == (9, 0)


def test_dropping_the_factors_keeps_the_order_and_patterns(scene_dict):
    store = SharedBulk()
    with sharing(store):
        run = run_member(*_calls(scene_dict, [{}])[0])
    assert run.ok and store.made == 3 and len(store._factors) == 3
    assert store.drop_factors() == 3 and store.drop_factors() == 0
    assert len(store._factors) == 0 and len(store._orders) == 1 and len(store._patterns) == 1


def test_two_threads_on_one_store_make_equal_factors_once(scene_dict, alone):
    """Two members of equal bulks run at the same time in two threads inside one store: the
    lock makes each of the three factorisations once (3 made, 3 shared), and both forecasts
    equal their runs alone."""
    store, calls, out = SharedBulk(), _calls(scene_dict, EQUAL_BULKS[:2]), {}

    def member(call):
        with sharing(store):
            out[call[0]] = run_member(*call)

    threads = [threading.Thread(target=member, args=(c,)) for c in calls]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert (store.made, store.shared) == (3, 3)
    for j in (0, 1):
        _assert_same(alone[j], out[j])


def test_a_store_keeps_at_most_its_number_of_factorisations(scene_dict):
    store = SharedBulk(max_factors=2)
    with sharing(store):
        assert active() is store
        run = run_member(*_calls(scene_dict, [{}])[0])
    assert active() is None
    assert run.ok and store.made == 3 and len(store._factors) == 2


def test_chunks_deal_every_call_once():
    calls = list(range(7))
    for workers, per_worker, n in ((0, None, 1), (1, None, 7), (2, None, 7), (1, 2, 2), (2, 2, 4), (8, 2, 7)):
        dealt = chunks(calls, workers, per_worker)
        assert len(dealt) == n
        assert sorted(sum(dealt, [])) == calls
        assert max(map(len, dealt)) - min(map(len, dealt)) <= 1
    assert chunks(calls, 2) == [[c] for c in calls] and chunks([], 2) == chunks([], 0) == []


def test_a_history_on_longer_steps_ends_on_the_forecast_time(scene_dict):
    """history_dt_max = 20 s: the history steps 5, 10, 20, 20 s (55 s), then 5 s to end on 60 s,
    and its next step is 20 s again (where a ladder starts); the scene's own steps take twelve
    of 5 s."""
    from fault_screen.forecast.ensemble import lookaheads

    scene = Scene.from_dict(scene_dict)
    longer = next(lookaheads(scene, [AT], steps={"history_dt_max": 20.0}))
    own = next(lookaheads(scene, [AT]))
    assert longer.made_at == own.made_at == AT
    assert (longer.state.steps, own.state.steps) == (5, 12)
    assert longer.state.time == AT and (longer.state.dt, own.state.dt) == (20.0, 5.0)
    bad = run_member(0, scene_dict, {}, [AT], PLANS, HORIZON, steps={"history_dt_max": 0.0})
    assert not bad.ok and "history steps: dt_max 0.0 must be > 0" in bad.error


def test_a_kept_entry_is_found_by_bit_equal_arrays_only():
    """The store finds what it kept by a sum of the arrays' bits and then compares them: arrays
    of equal sums (a permutation), values equal but not in their bits (-0.0 against 0.0) and
    another dtype or shape of the same values all miss; equal bits (a NaN included) hit."""
    from fault_screen.shared_bulk import _Kept

    kept = _Kept()
    values = np.array([0.0, 1.5, -2.0, np.nan])
    kept.add(_Kept.key([values, np.arange(4, dtype=np.int32)]), "made")
    assert kept.find(_Kept.key([values.copy(), np.arange(4, dtype=np.int32)])) == "made"
    for other in ([values[[1, 0, 2, 3]], np.arange(4, dtype=np.int32)],
                  [np.array([-0.0, 1.5, -2.0, np.nan]), np.arange(4, dtype=np.int32)],
                  [values, np.arange(4, dtype=np.int64)],
                  [values.reshape(2, 2), np.arange(4, dtype=np.int32)],
                  [values, np.array([0, 1, 3, 2], dtype=np.int32)]):
        assert kept.find(_Kept.key(other)) is None
    assert len(kept) == 1


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(allow_nan=True, width=64), min_size=1, max_size=6),
       st.lists(st.floats(allow_nan=True, width=64), min_size=1, max_size=6))
def test_the_store_shares_exactly_when_the_bytes_are_equal(a, b):
    from fault_screen.shared_bulk import _Kept

    a, b = np.array(a), np.array(b)
    kept = _Kept()
    kept.add(_Kept.key([a]), "a")
    assert (kept.find(_Kept.key([b])) == "a") == (a.shape == b.shape and a.tobytes() == b.tobytes())


def test_an_order_is_shared_only_for_the_same_fault_coupling():
    """The bulk's order reads which unknowns couple to the fault (ordering.nested_dissection's
    ``fault_coupling``): two faults in one mesh share B's pattern and coordinates but not their
    order."""
    import scipy.sparse as sp

    store, made = SharedBulk(), []
    pattern = sp.random(30, 30, density=0.2, random_state=1, format="csr") + sp.eye(30)
    coordinates = np.arange(60.0).reshape(30, 2)
    near, far = np.zeros(30, dtype=np.int64), np.zeros(30, dtype=np.int64)
    near[:5], far[-5:] = 8, 8

    def make(tag):
        return lambda: made.append(tag) or tag

    assert store.order(pattern, coordinates, make("near"), near) == "near"
    assert store.order(pattern, coordinates, make("again"), near.copy()) == "near"
    assert store.order(pattern, coordinates, make("far"), far) == "far"
    assert store.order(pattern, coordinates, make("none")) == "none"
    assert made == ["near", "far", "none"]

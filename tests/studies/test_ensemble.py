"""The Dask ensemble runner: scene variants by dotted keys, failures kept, HDF5 stream."""
from __future__ import annotations

import dataclasses
import os

import pytest

from conftest import CONFIGS
from fault_screen import Scene, simulate
from fault_screen.ensemble import (Runner, TaskOutcome, Variant, default_summary, reach_probabilities,
                                   read_ensemble, run_ensemble, scene_with)
from fault_screen.scene import SceneError


@pytest.fixture(scope="module")
def tiny():
    """The paper-units calibrated Rustrel scene on a 14 x 15 mesh with 50 s steps (~0.2 s)."""
    base = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated-paper-units.toml")
    # the mesh as given: machinery on a tiny scene, not leak-off accuracy (docs/verification.md, 'Leak-off and mesh')
    return base.replace(mesh=dataclasses.replace(base.mesh, nx=14, ny=15, fault_grading="off"),
                        time=dataclasses.replace(base.time, dt=50.0))


def test_scene_with_dotted_keys(tiny):
    s = scene_with(tiny, {"injection.number_of_fractures": 46.0, "rock.youngs_modulus": 12.8e9,
                          "damage_zone.mobility": 1e-14})
    assert s.injection.number_of_fractures == 46.0
    assert s.rock.youngs_modulus == 12.8e9
    assert s.damage_zone.mobility == 1e-14
    assert s.fault == tiny.fault                       # the rest untouched
    # the paper's zero lower bounds switch the effect off instead of being refused
    off = scene_with(tiny, {"fault.rate_parameter": 0.0, "fault.dilation_angle": 0.0})
    assert not off.effects.rate_friction and not off.effects.dilation
    # a permeability replaces a mobility
    assert scene_with(tiny, {"damage_zone.permeability": 1e-15}).damage_zone.mobility is None


@pytest.mark.parametrize("key, message", [
    ("injection.number_of_fracture", r"\[injection\] has no 'number_of_fracture'"),
    ("rocks.porosity", r"\[scene\] has no 'rocks'"),
    ("rock", r"does not name a single value|must be a table"),
])
def test_scene_with_bad_key(tiny, key, message):
    with pytest.raises(SceneError, match=message):
        scene_with(tiny, {key: 1.0})


def test_in_process_run_keeps_failures_and_streams(tiny, tmp_path):
    variants = [Variant("nof46", {"injection.number_of_fractures": 46.0}),
                Variant("bad", {"fault.friction": -1.0}),
                Variant("nof120", {"injection.number_of_fractures": 120.0})]
    seen = []
    out = run_ensemble(tiny, variants, workers=0, out=tmp_path / "e.h5",
                       progress=lambda done, total, failed: seen.append((done, total, failed)))
    assert [o.ok for o in out] == [True, False, True]
    assert "fault.friction = -1.0" in out[1].error and out[1].params == {"fault.friction": -1.0}
    assert seen[-1] == (3, 3, 1)
    # same numbers as a direct run of the same variant
    direct = default_summary(simulate(scene_with(tiny, {"injection.number_of_fractures": 46.0})))
    assert out[0].summary["peak_overpressure"] == direct["peak_overpressure"]
    # fewer fractures share the flow: more pressure (Eq. 29)
    assert out[0].summary["peak_overpressure"] > 1.1 * out[2].summary["peak_overpressure"]
    stored = read_ensemble(tmp_path / "e.h5")
    assert [o.name for o in stored] == ["nof46", "bad", "nof120"]
    assert not stored[1].ok and stored[1].error == out[1].error
    assert stored[2].summary["peak_overpressure"] == out[2].summary["peak_overpressure"]


def test_local_dask_cluster_gives_the_in_process_numbers(tiny, tmp_path):
    variants = [Variant("a", {"fault.hydraulic_aperture": 3e-5}), Variant("b", {"rock.porosity": 0.2})]
    here = run_ensemble(tiny, variants, workers=0)
    there = run_ensemble(tiny, variants, workers=1, out=tmp_path / "d.h5")
    for h, t in zip(here, there):
        assert t.ok and t.wall_s > 0
        assert t.summary["peak_overpressure"] == h.summary["peak_overpressure"]
        assert t.summary["injection_slip"] == h.summary["injection_slip"]
    assert len(read_ensemble(tmp_path / "d.h5")) == 2


def test_local_workers_run_without_the_profiler_and_keep_the_users_settings():
    """The local workers' own settings (WORKER_CONFIG: no statistical profiler, a 500-ms tick, a
    1-s memory monitor, no MALLOC_TRIM_THRESHOLD_) go on top of the user's: a setting of the
    user's elsewhere in the same sections reaches them."""
    import dask
    import distributed  # noqa: F401  (its defaults in this process's settings before they are changed)

    keys = ("distributed.worker.profile.enabled", "distributed.admin.tick.interval",
            "distributed.worker.memory.monitor-interval", "distributed.worker.memory.target")
    with dask.config.set({"distributed.worker.memory.target": 0.55}):
        with Runner(1) as runner:
            seen = [list(runner.client.run(dask.config.get, key).values()) for key in keys]
            # glibc's malloc left to its own thresholds (Dask sets MALLOC_TRIM_THRESHOLD_=65536)
            trim = list(runner.client.run(os.environ.get, "MALLOC_TRIM_THRESHOLD_").values())
            # the scheduler and the nanny, in this process, tick and monitor at the same pace
            # (ms; Dask's defaults: a 20-ms tick, a 100-ms memory monitor, a 500-ms system monitor)
            scheduler, (nanny,) = runner.cluster.scheduler, runner.cluster.workers.values()
            paces = [scheduler.periodic_callbacks["tick"].callback_time,
                     scheduler.periodic_callbacks["monitor"].callback_time,
                     nanny.periodic_callbacks["tick"].callback_time,
                     nanny.periodic_callbacks["memory_monitor"].callback_time]
    assert seen == [[False], ["500ms"], ["1s"], [0.55]]
    assert trim == [os.environ.get("MALLOC_TRIM_THRESHOLD_")]   # (the user's own, if any: None here)
    assert paces == [500, 2000, 500, 1000]
    assert dask.config.get(keys[0]) is True   # this process's settings untouched
    assert dask.config.get(keys[1]) == "20ms" and dask.config.get(keys[3]) == 0.6


def test_existing_scheduler_gives_the_in_process_numbers(tiny):
    """``scheduler="tcp://..."``: the tasks go to a cluster the runner did not start (here an
    in-process one, started by the test) and come back with the same numbers."""
    from distributed import LocalCluster

    variants = [Variant("nof46", {"injection.number_of_fractures": 46.0})]
    here = run_ensemble(tiny, variants, workers=0)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp",
                      host="127.0.0.1", dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://")
        there = run_ensemble(tiny, variants, scheduler=cluster.scheduler_address)
        assert "run_task" in cluster.scheduler.task_prefixes   # the task ran there
        assert len(cluster.scheduler.workers) == 1          # and the runner left the cluster as it was
    assert there[0].ok
    assert there[0].summary["peak_overpressure"] == here[0].summary["peak_overpressure"]


def test_reach_probabilities_count_the_successful_runs():
    nan = float("nan")
    times = [(100.0, 40.0, nan), (nan, 60.0, nan), (300.0, 80.0, 500.0), (nan, nan, nan)]
    outs = [TaskOutcome(i, f"r{i}", {}, True, {"slip_onset": a, "time_first_yellow": b, "time_first_red": c})
            for i, (a, b, c) in enumerate(times)]
    outs.append(TaskOutcome(4, "failed", {"fault.friction": -1.0}, False, error="SceneError"))  # not counted
    p = reach_probabilities(outs)
    assert p["slip"] == (0.5, pytest.approx(1.96 * (0.25 / 4) ** 0.5))
    assert p["yellow"][0] == 0.75 and p["yellow"][1] == pytest.approx(1.96 * (0.75 * 0.25 / 4) ** 0.5)
    assert p["red"][0] == 0.25

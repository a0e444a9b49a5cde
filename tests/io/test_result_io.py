"""HDF5 layout of results (the contract other layers and users rely on)."""
import tomllib

import h5py
import numpy as np
import pytest

from fault_screen import Result, Scene, simulate

FAULT_KEYS = ["pressure", "overpressure", "slip", "opening", "slip_rate", "shear_traction",
              "effective_normal_stress", "friction"]


@pytest.fixture(scope="module")
def result():
    scene = Scene.from_dict({
        "mesh": {"nx": 10, "ny": 11, "lx": 50.0, "ly": 50.0},
        "initial": {"effective_stress": [-5.649e6, -3.351e6, 0.964e6], "pore_pressure": 2.764e6},
        "injection": {"number_of_fractures": 10, "schedule": [[0.0, 1e-3]]},
        "time": {"end": 20.0, "dt": 5.0},
    })
    return simulate(scene)


def test_layout_units_and_shapes(result, tmp_path):
    path = result.save(tmp_path / "r.h5")
    assert not (tmp_path / "r.h5.part").exists()
    with h5py.File(path, "r") as h5:
        nt = len(h5["time"])
        nx = len(h5["fault/x"])
        assert nt == 5 and h5["time"].attrs["unit"] == "s"
        for k in FAULT_KEYS:
            assert h5[f"fault/{k}"].shape == (nt, nx), k
        assert h5["fault/pressure"].attrs["unit"] == "Pa"
        assert h5["fault/slip_rate"].attrs["unit"] == "m/s"
        for k in ("flow_rate", "pressure", "slip", "opening", "volume"):
            assert h5[f"injection/{k}"].shape == (nt,)
        scene = Scene.from_dict(tomllib.loads(h5.attrs["scene"]))
        assert scene == result.scene
        # x is measured from the injection point: it changes sign there
        x = h5["fault/x"][()]
        assert x.min() < 0 < x.max()
        # pressure = initial pore pressure + overpressure
        assert np.allclose(h5["fault/pressure"][()] - h5["fault/overpressure"][()], 2.764e6)
        # volume is the time integral of the flow rate (1 L/s for 20 s)
        assert h5["injection/volume"][-1] == pytest.approx(20.0 * 1e-3, rel=1e-12)


def test_round_trip(result, tmp_path):
    path = result.save(tmp_path / "r.h5")
    back = Result.load(path)
    assert back.scene == result.scene
    for k in FAULT_KEYS:
        assert np.array_equal(back.fault[k], result.fault[k])
    assert np.array_equal(back.injection["volume"], result.injection["volume"])


def test_injection_point_values_come_from_the_nearest_fault_point(result):
    k = int(np.argmin(np.abs(result.fault_x)))
    assert abs(result.fault_x[k]) <= 0.25 * 5.0  # within a quarter of the 5 m elements
    for key in ("slip_rate", "shear_traction", "effective_normal_stress", "friction"):
        assert np.array_equal(result.injection[key], result.fault[key][:, k])


# ---------------------------------------------------------------------------------------------
# results streamed to the file as the run goes
# ---------------------------------------------------------------------------------------------
SMALL = {
    "mesh": {"nx": 10, "ny": 11, "lx": 50.0, "ly": 50.0},
    "initial": {"effective_stress": [-5.649e6, -3.351e6, 0.964e6], "pore_pressure": 2.764e6},
    "injection": {"number_of_fractures": 10, "schedule": [[0.0, 1e-3], [40.0, 3e-3]]},
    "time": {"end": 100.0, "dt": 5.0},
    # a level change at an arbitrary step: the overpressure passes 30 kPa
    "monitor": {"rules": [{"name": "pressure up", "level": "yellow", "hold": 0.0,
                           "when": "injection_overpressure > 3e4", "action": "watch"}]},
}


def _every_array(res) -> dict:
    out = {"time": res.time, "fault/time": res.profile_time}
    for group in ("fault", "injection", "balance", "solver"):
        out.update({f"{group}/{k}": v for k, v in getattr(res, group).items()})
    out.update({f"screening/{k}": v for k, v in res.extra["screening"].items()})
    return out


def _streamed(scene, path, monkeypatch=None):
    from fault_screen.api import run_streamed

    sim, screening = run_streamed(scene, path)
    assert sim.recorder.rows == []          # nothing but the newest row stays in memory
    sim.close_stream()
    return Result.load(path), screening


@pytest.fixture(scope="module")
def full():
    """The in-memory run, screened over the whole result: the reference."""
    from fault_screen.screening import screen_result

    scene = Scene.from_dict(SMALL)
    res = simulate(scene)
    screen_result(res)
    assert len(res.time) == 21 and len(res.extra["screening"]["transitions"]) == 1
    return res


def test_a_streamed_run_equals_the_in_memory_run_array_for_array(full, tmp_path):
    got, _ = _streamed(Scene.from_dict(SMALL), tmp_path / "s.h5")
    want = _every_array(full)
    have = _every_array(got)
    assert have.keys() == want.keys()
    for k, v in want.items():
        assert np.array_equal(have[k], v, equal_nan=v.dtype.kind == "f"), k
    with h5py.File(tmp_path / "s.h5", "r") as h5:
        assert h5["injection/volume"].maxshape == (None,) and h5["injection/volume"].chunks
        assert h5["fault/slip"].maxshape[0] is None and h5["fault/time"].attrs["unit"] == "s"


@pytest.mark.parametrize("output, rows", [
    # every 6 steps: rows 0, 6, 12, 18, the level change and the last (20)
    ({"profile_every": 6}, "0 6 12 18 20 T"),
    # the first step at or after each multiple of 32 s (steps of 5 s: 35, 65, 100), the level
    # change, the last
    ({"profile_interval": "32 s"}, "0 7 13 20 T"),
])
def test_output_table_thins_the_profiles_not_the_series(full, tmp_path, output, rows):
    scene = Scene.from_dict({**SMALL, "output": output})
    got, screening = _streamed(scene, tmp_path / "s.h5")
    t_change = float(full.extra["screening"]["transitions"]["time"][0])
    i_change = int(np.flatnonzero(full.time == t_change)[0])
    want_rows = sorted({i_change if r == "T" else int(r) for r in rows.split()})
    assert np.array_equal(got.profile_time, full.time[want_rows])
    for k, v in full.fault.items():
        assert np.array_equal(got.fault[k], v[want_rows]), k
    # the series and the screening: every step, unchanged
    for group in ("injection", "balance", "solver"):
        for k, v in getattr(full, group).items():
            assert np.array_equal(getattr(got, group)[k], v), (group, k)
    assert np.array_equal(got.extra["screening"]["level"], full.extra["screening"]["level"])
    # the in-memory path thins the same way
    # fault_screen.simulate, in memory, keeps the same rows
    mem = simulate(scene)
    assert np.array_equal(mem.profile_time, got.profile_time)
    assert np.array_equal(mem.fault["slip"], got.fault["slip"])


def test_output_table_is_validated():
    from fault_screen.scene import SceneError

    with pytest.raises(SceneError, match="output.profile_every = 0: must be >= 1"):
        Scene.from_dict({"output": {"profile_every": 0}})
    with pytest.raises(SceneError, match="output.profile_interval"):
        Scene.from_dict({"output": {"profile_interval": "-1 h"}})
    assert Scene.from_dict({"output": {"profile_interval": "2 h"}}).output.profile_interval == 7200.0


def test_a_streamed_run_checkpointed_and_restored_continues_its_file(full, tmp_path):
    """The checkpoint keeps the rows' count; rows written after it (a run that went on, then
    died) are cut away on restore and written again, to the same arrays."""
    from fault_screen import Simulation
    from fault_screen.api import StepScreening

    scene = Scene.from_dict(SMALL)
    sim = Simulation(scene)
    path = tmp_path / "s.h5"
    sim.stream_to(path)
    sim.advance(50.0)
    sim.checkpoint(tmp_path / "state.h5")
    sim.advance(80.0)                         # rows past the checkpoint reach the file...
    sim.flush()
    sim.writer.abandon()                      # ...and the writer stops there
    with h5py.File(path, "r") as h5:
        assert len(h5["time"]) == 17
    back = Simulation.restore(tmp_path / "state.h5")
    assert back.writer.counts()["rows"] == 11
    back.advance(100.0)
    back.close_stream()
    got = Result.load(path)
    for k in ("time", "fault/slip", "injection/overpressure", "balance/leaked", "solver/dt"):
        assert np.array_equal(_every_array_core(got)[k], _every_array_core(full)[k]), k
    assert StepScreening.streams()["screening"].keys() >= {"/screening/level"}


def _every_array_core(res) -> dict:
    out = {"time": res.time}
    for group in ("fault", "injection", "balance", "solver"):
        out.update({f"{group}/{k}": v for k, v in getattr(res, group).items()})
    return out


def test_streamed_profiles_are_stored_compressed_and_unchanged(bundled_run, tmp_path):
    """The calibrated Rustrel scene's 281 x 200 profiles streamed through the writer: every
    array reads back bit for bit, and the compressed streams (byte shuffle, then gzip) take at
    most 0.65 of their raw bytes (0.59 measured; gzip at level 4 without the shuffle, the
    writer's former setting, took 0.73)."""
    from fault_screen.result_stream import ResultWriter

    res = bundled_run("rustrel-2015-calibrated")
    profiles = {"/fault/time": res.profile_time, **{f"/fault/{k}": v for k, v in res.fault.items()}}
    assert len(res.profile_time) == 281 and res.fault["slip"].shape == (281, 200)
    spec = {p: (v.dtype.str, v.shape[1:]) for p, v in profiles.items()}
    path = tmp_path / "p.h5"
    writer = ResultWriter.create(path, streams={"profiles": spec}, fixed={}, attrs={})
    for i in range(len(res.profile_time)):
        writer.append("profiles", {p: v[i] for p, v in profiles.items()})
    writer.close()
    raw = stored = 0
    with h5py.File(path, "r") as h5:
        for p, v in profiles.items():
            assert np.array_equal(h5[p][...], v), p
            raw += v.nbytes
            stored += h5[p].id.get_storage_size()
    assert stored <= 0.65 * raw, stored / raw


def _light_and_heavy_streams():
    """A series stream of 19 scalars (152 bytes a record, as the runs' rows), a compressed
    profile stream of 2 x 1000 doubles, and an uncompressed stream of 1000 doubles a record."""
    rows = {f"/series/v{k}": ("<f8", ()) for k in range(19)}
    profiles = {"/fault/a": ("<f8", (1000,)), "/fault/b": ("<f8", (1000,))}
    wide = {"/wide/w": ("<f8", (1000,))}
    return {"rows": rows, "profiles": profiles, "wide": wide}


def test_each_stream_buffers_as_many_records_as_its_kind_allows(tmp_path):
    """Records are written in batches: 64 for a compressed stream (its chunks filled once),
    1024 for a stream of a few scalars (a write costs a call per dataset whatever its length),
    and 64 for an uncompressed stream whose 1024 records would pass 256 kB."""
    from fault_screen.result_stream import ResultWriter

    streams = _light_and_heavy_streams()
    writer = ResultWriter.create(tmp_path / "b.h5", streams=streams, fixed={}, attrs={})
    assert writer.batches == {"rows": 1024, "profiles": 64, "wide": 64}
    try:
        for i in range(1025):
            writer.append("rows", {p: float(i) for p in streams["rows"]})
        for i in range(65):
            writer.append("profiles", {p: np.full(1000, float(i)) for p in streams["profiles"]})
            writer.append("wide", {p: np.full(1000, float(i)) for p in streams["wide"]})
        # the 1025th row and the 65th profile wrote the full batch before them, no more
        assert writer.counts_written == {"rows": 1024, "profiles": 64, "wide": 64}
        assert writer.count("rows") == 1025 and writer.count("profiles") == 65
    finally:
        writer.close()
    with h5py.File(tmp_path / "b.h5", "r") as h5:
        assert np.array_equal(h5["series/v3"][...], np.arange(1025.0))
        assert np.array_equal(h5["wide/w"][:, 7], np.arange(65.0))


def test_batched_streams_read_back_bit_for_bit_across_flushes(tmp_path):
    """2,500 rows and 130 profiles of random doubles, flushed part way (as a checkpoint or the
    monitor does), read back equal to what was appended, array for array."""
    from fault_screen.result_stream import ResultWriter

    rng = np.random.default_rng(7)
    streams = _light_and_heavy_streams()
    want = {p: rng.standard_normal((2500, *shape)) for p, (_, shape) in streams["rows"].items()}
    want.update({p: rng.standard_normal((130, *shape)) for s in ("profiles", "wide")
                 for p, (_, shape) in streams[s].items()})
    writer = ResultWriter.create(tmp_path / "r.h5", streams=streams, fixed={}, attrs={})
    for i in range(2500):
        writer.append("rows", {p: want[p][i] for p in streams["rows"]})
        if i < 130:
            for s in ("profiles", "wide"):
                writer.append(s, {p: want[p][i] for p in streams[s]})
        if i == 1500:
            writer.flush()
            assert writer.counts() == {"rows": 1501, "profiles": 130, "wide": 130}
    writer.close()
    with h5py.File(tmp_path / "r.h5", "r") as h5:
        for p, v in want.items():
            assert np.array_equal(h5[p][...], v), p


def _written_file_bytes(path, streams, want, flush_every):
    from fault_screen.result_stream import ResultWriter

    writer = ResultWriter.create(path, streams=streams, fixed={}, attrs={})
    try:
        for i in range(len(want["/fault/a"])):
            for s in ("profiles", "wide"):
                writer.append(s, {p: want[p][i] for p in streams[s]})
            writer.append("rows", {p: want[p][i] for p in streams["rows"]})
            if i % flush_every == flush_every - 1:
                writer.flush()
        cache = writer.h5.id.get_access_plist().get_cache()[2]
    finally:
        writer.close()
    return path.stat().st_size, cache


def test_the_writers_chunk_cache_holds_the_chunk_being_filled_not_the_run(tmp_path, monkeypatch):
    """HDF5 caches up to 1 MiB of chunks per dataset by default, which kept a long run's written
    chunks (40-odd growing datasets) in memory. The writer's file has a CHUNK_CACHE_BYTES cache
    (256 kB), every chunk it makes fits in it (a smaller cache fails here), and the file it
    writes (profiles compressed, flushed every 10 records as the monitor does) has the same
    bytes as with the default cache."""
    from fault_screen import result_stream

    rng = np.random.default_rng(3)
    streams = _light_and_heavy_streams()
    want = {p: rng.standard_normal((300, *shape)) for s in streams.values()
            for p, (_, shape) in s.items()}
    size, cache = _written_file_bytes(tmp_path / "c.h5", streams, want, 10)
    assert cache == result_stream.CHUNK_CACHE_BYTES < 1024 * 1024
    with h5py.File(tmp_path / "c.h5", "r") as h5:
        for group in ("fault", "wide", "series"):
            for ds in h5[group].values():
                assert ds.dtype.itemsize * np.prod(ds.chunks) <= result_stream.CHUNK_CACHE_BYTES
    monkeypatch.setattr(result_stream, "CHUNK_CACHE_BYTES", 1024 * 1024)
    default_size, _ = _written_file_bytes(tmp_path / "d.h5", streams, want, 10)
    assert size == default_size


def test_a_result_is_read_with_the_writers_chunk_cache(tmp_path):
    """Results are read (summary, figures, `fault-screen plot`) with the writer's chunk cache,
    not HDF5's 1 MiB a dataset, whether the writer has closed the file or still holds it."""
    from fault_screen import result_stream
    from fault_screen.result import _open_for_reading
    from fault_screen.result_stream import ResultWriter

    streams = _light_and_heavy_streams()
    writer = ResultWriter.create(tmp_path / "r.h5", streams=streams, fixed={}, attrs={})
    writer.append("rows", {p: 1.0 for p in streams["rows"]})
    writer.flush()
    try:   # (the writer holds it: opened as a SWMR reader)
        with _open_for_reading(tmp_path / "r.h5") as h5:
            assert h5.id.get_access_plist().get_cache()[2] == result_stream.CHUNK_CACHE_BYTES
    finally:
        writer.close()
    with _open_for_reading(tmp_path / "r.h5") as h5:
        assert h5.id.get_access_plist().get_cache()[2] == result_stream.CHUNK_CACHE_BYTES

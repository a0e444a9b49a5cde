"""Results of a run and their HDF5 form.

Every dataset and its unit is declared in :mod:`fault_screen.outputs` (SI units; fault arrays
are shaped (time, x) at the fault's Gauss points; ``/balance/*`` per m of fault-plane
thickness); the root attribute ``scene`` holds the resolved scene as TOML, ``meta`` the run's
metadata (versions, unknowns, wall times) as JSON. Groups in ``extra`` (e.g. ``/log``, added by
callers) are written as they come. The file is written to a temporary name and renamed, so a
failed write leaves no partial file.
"""
from __future__ import annotations

import json
import os
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .outputs import unit
from .result_stream import CHUNK_CACHE_BYTES
from .scene import Scene


@contextmanager
def atomic_hdf5(path):
    """An HDF5 file written under a temporary name, synced and renamed only when complete, so a
    failed or killed write leaves the previous file intact and no partial one."""
    import h5py

    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    try:
        with h5py.File(tmp, "w") as h5:
            yield h5
            h5.flush()
            os.fsync(h5.id.get_vfd_handle())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _open_for_reading(path):
    """h5py.File for reading; a file a writer holds open in SWMR mode is opened as its reader.
    Its chunk cache is the writer's (CHUNK_CACHE_BYTES a dataset): the bounded reads take each
    chunk once, and HDF5's default of 1 MiB a dataset kept what they had read (`fault-screen
    plot` of the Basel 2006 result: 171 -> 145 MB, the same time)."""
    import h5py

    try:
        return h5py.File(path, "r", rdcc_nbytes=CHUNK_CACHE_BYTES)
    except OSError as exc:
        if "already open for write" not in str(exc):
            raise
        return h5py.File(path, "r", libver="latest", swmr=True, rdcc_nbytes=CHUNK_CACHE_BYTES)


@dataclass
class Result:
    scene: Scene
    time: np.ndarray
    fault_x: np.ndarray
    fault_xy: np.ndarray
    fault_weights: np.ndarray
    fault: dict
    injection: dict
    balance: dict
    solver: dict
    meta: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    #: model times of the rows of the ``fault`` profiles (s); None: every time of ``time``
    fault_time: np.ndarray | None = None

    @property
    def profile_time(self) -> np.ndarray:
        """The model times of the rows of the fault profiles (s)."""
        return self.time if self.fault_time is None else self.fault_time

    def save(self, path) -> Path:
        path = Path(path)
        with atomic_hdf5(path) as h5:
            h5.attrs["scene"] = self.scene.to_toml()
            h5.attrs["meta"] = json.dumps(self.meta, default=float)
            h5.create_dataset("time", data=self.time).attrs["unit"] = unit("", "time")
            g = h5.create_group("fault")
            for k, v in (("x", self.fault_x), ("xy", self.fault_xy), ("weight", self.fault_weights),
                         ("time", self.profile_time)):
                g.create_dataset(k, data=v).attrs["unit"] = unit("fault", k)
            for k, v in self.fault.items():
                g.create_dataset(k, data=v, compression="gzip").attrs["unit"] = unit("fault", k)
            for name in ("injection", "balance", "solver"):
                grp = h5.create_group(name)
                for k, v in getattr(self, name).items():
                    grp.create_dataset(k, data=v).attrs["unit"] = unit(name, k)
            for name, arrays in self.extra.items():
                grp = h5.require_group(name)
                for k, v in arrays.items():
                    grp.create_dataset(k, data=v).attrs["unit"] = unit(name, k)
        return path

    def check_lengths(self) -> None:
        """Raise ValueError (one line) unless every per-time array has one row per output
        time and every fault profile one column per fault point."""
        n, n_x = len(self.time), len(self.fault_x)
        n_profiles = len(self.profile_time)
        want = [(f"/{g}/{k}", v, n) for g in ("injection", "balance", "solver")
                for k, v in getattr(self, g).items()]
        want += [(f"/screening/{k}", v, n) for k, v in (self.extra.get("screening") or {}).items()
                 if k != "transitions"]
        want += [(f"/fault/{k}", v, n_profiles) for k, v in self.fault.items()]
        for name, v, rows in want:
            shape = np.shape(v)
            if not shape or shape[0] != rows:
                got = shape[0] if shape else "no"
                raise ValueError(f"damaged result: {name} has {got} rows for {rows} output times")
        for k, v in self.fault.items():
            if np.ndim(v) != 2 or np.shape(v)[1] != n_x:
                raise ValueError(f"damaged result: /fault/{k} has shape {np.shape(v)} for "
                                 f"{n_profiles} times and {n_x} fault points")
        if len(self.fault_weights) != n_x or np.shape(self.fault_xy)[:1] != (n_x,):
            raise ValueError(f"damaged result: /fault/weight and /fault/xy do not have one row "
                             f"per fault point ({n_x})")

    @classmethod
    def load(cls, path) -> "Result":
        """A result file, also one still being streamed (opened as a single-writer/multiple-
        reader reader then: what the last flush wrote).  A complete file whose arrays disagree
        in length is refused (ValueError, one line)."""
        import tomllib

        with _open_for_reading(path) as h5:
            growing = h5.swmr_mode        # a writer may be between two datasets' flushes
            scene = Scene.from_dict(tomllib.loads(h5.attrs["scene"]))
            read = lambda grp: {k: grp[k][()] for k in grp}
            fault = read(h5["fault"])
            fx, fxy, fw = fault.pop("x"), fault.pop("xy"), fault.pop("weight")
            time = h5["time"][()]
            ft = fault.pop("time", None)         # files before [output] have a profile per time
            if ft is not None and np.array_equal(ft, time):
                ft = None
            extra = {k: read(h5[k]) for k in h5 if k not in ("time", "fault", "injection", "balance", "solver")}
            out = cls(scene=scene, time=time, fault_x=fx, fault_xy=fxy, fault_weights=fw, fault=fault,
                      injection=read(h5["injection"]), balance=read(h5["balance"]),
                      solver=read(h5["solver"]), meta=json.loads(h5.attrs["meta"]), extra=extra,
                      fault_time=ft)
        if not growing:
            out.check_lengths()
        return out


# ---------------------------------------------------------------------------------------------
# bounded reads: what the summary, the verdict and the figures need from a result of any length
# ---------------------------------------------------------------------------------------------
#: rows of a growing dataset read at once
READ_ROWS = 65536
#: points per series in a view (:meth:`ResultFile.view`): min/max pairs of buckets of rows
VIEW_POINTS = 10000
#: fault profiles in a view
VIEW_PROFILES = 400
#: groups whose (time,) arrays follow /time (the log has its own time axis)
_SERIES_GROUPS = ("injection", "balance", "solver", "screening")


class ResultFile:
    """A result file read in pieces of at most ``read_rows`` rows, so memory does not grow with
    the length of the run: reductions over whole datasets (:meth:`maximum`,
    :meth:`profile_reduce`) and a :class:`Result` small enough to plot (:meth:`view`). A file
    still being streamed is read as its single-writer/multiple-reader reader sees it."""

    def __init__(self, path, read_rows: int = READ_ROWS):
        import tomllib

        self.path = Path(path)
        self.read_rows = int(read_rows)
        self.largest_read = 0          # rows of the largest single read so far
        self.h5 = _open_for_reading(path)
        self._datasets = {}
        try:
            self.scene = Scene.from_dict(tomllib.loads(self.h5.attrs["scene"]))
            self.meta = json.loads(self.h5.attrs["meta"])
            self.rows = int(self.h5["time"].shape[0])
            self.profiles = int(self.h5["fault/slip"].shape[0])
            self.growing = bool(self.h5.swmr_mode)   # a writer may be between two flushes
        except BaseException:
            self.h5.close()
            raise

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self.h5.close()

    # -- reads -------------------------------------------------------------------------------
    def _dataset(self, path: str):
        """The dataset ``path``, looked up once: h5py's lookup by path costs about as much as
        reading a short series (a view asks for each dataset five times)."""
        ds = self._datasets.get(path)
        if ds is None:
            ds = self._datasets[path] = self.h5[path]
        return ds

    def _read(self, path: str, index):
        """Rows ``index`` (a slice or increasing integer array) of dataset ``path``: the one
        place rows are read, so :attr:`largest_read` holds the largest read."""
        ds = self._dataset(path)
        n = len(range(*index.indices(ds.shape[0]))) if isinstance(index, slice) else len(index)
        self.largest_read = max(self.largest_read, n)
        return ds[index]

    def blocks(self, path: str):
        """(first row, rows) of dataset ``path`` in blocks of at most ``read_rows`` rows."""
        n = self._dataset(path).shape[0]
        for i0 in range(0, n, self.read_rows):
            yield i0, self._read(path, slice(i0, min(n, i0 + self.read_rows)))

    def last(self, path: str):
        """The last row of dataset ``path``."""
        n = self._dataset(path).shape[0]
        return self._read(path, slice(n - 1, n))[0]

    def maximum(self, path: str) -> float:
        """The largest value of dataset ``path`` (NaN ignored; NaN if there is none)."""
        best = np.nan
        for _, block in self.blocks(path):
            if block.size and np.any(~np.isnan(block)):
                best = np.fmax(best, np.nanmax(block))
        return float(best)

    def profile_reduce(self, name: str, transform, ufunc=np.maximum) -> np.ndarray:
        """``ufunc`` over time of ``transform(rows)`` of the fault profile ``name``: one value per
        fault point (e.g. the largest |slip| of each point: ``profile_reduce("slip", np.abs)``)."""
        path = f"fault/{name}"
        ds = self._dataset(path)
        rows = max(1, self.read_rows // max(1, ds.shape[1]))
        out = None
        n = ds.shape[0]
        for i0 in range(0, n, rows):
            part = ufunc.reduce(transform(self._read(path, slice(i0, min(n, i0 + rows)))), axis=0)
            out = part if out is None else ufunc(out, part)
        return out if out is not None else np.zeros(ds.shape[1])

    def row_blocks(self, paths: list, rows: int | None = None):
        """(first row, {path: its rows}) of the datasets ``paths`` side by side, first ``rows``
        rows (default: every output time), in blocks of at most ``read_rows`` values of the
        widest of them (at least one row)."""
        n = self.rows if rows is None else int(rows)
        widest = max((int(np.prod(self._dataset(p).shape[1:], dtype=np.int64)) or 1 for p in paths),
                     default=1)
        step = max(1, self.read_rows // widest)
        for i0 in range(0, n, step):
            index = slice(i0, min(n, i0 + step))
            yield i0, {p: self._read(p, index) for p in paths}

    def group(self, name: str) -> dict:
        """The datasets of the group ``name`` read whole: for the small ones (events, level
        changes, the log's settings); empty when there is no such group."""
        if name not in self.h5:
            return {}
        return {k: self.h5[name][k][()] for k in self.h5[name]}

    def profiles_per_row(self) -> bool:
        """Whether the file holds a fault profile for every output time (no ``[output]``
        thinning), as :attr:`Result.fault_time` is None after :meth:`Result.load`."""
        if self.profiles != self.rows:
            return False
        if "time" not in self.h5["fault"]:
            return True
        return all(np.array_equal(b["time"], b["fault/time"])
                   for _, b in self.row_blocks(["time", "fault/time"]))

    def check(self) -> None:
        """ValueError (one line) unless every per-time array has one row per output time and
        every fault profile one column per fault point (:meth:`Result.check_lengths`, without
        reading the arrays); a file still being streamed is not checked."""
        if self.growing:
            return
        h5 = self.h5
        series = {g: [k for k in h5[g] if not (g == "screening" and k == "transitions")]
                  for g in _SERIES_GROUPS if g in h5}
        self._check_shapes(series)
        if "time" in h5["fault"] and h5["fault/time"].shape[0] != self.profiles:
            raise ValueError(f"damaged result: /fault/time has {h5['fault/time'].shape[0]} rows "
                             f"for {self.profiles} fault profiles")
        n_x = h5["fault/x"].shape[0]
        if h5["fault/weight"].shape[:1] != (n_x,) or h5["fault/xy"].shape[:1] != (n_x,):
            raise ValueError(f"damaged result: /fault/weight and /fault/xy do not have one row "
                             f"per fault point ({n_x})")

    def copy_to(self, h5, skip=()) -> None:
        """Every group, dataset and attribute of the file into the open h5py file ``h5`` but
        the groups or datasets named in ``skip`` (e.g. ``"screening"``), each dataset with its
        type, chunks and compression, copied at most ``read_rows`` values at a time."""
        import h5py

        for k, v in self.h5.attrs.items():
            h5.attrs[k] = v

        def copy(src, dst):
            for k, v in src.attrs.items():
                dst.attrs[k] = v
            for name, obj in src.items():
                if obj.name.lstrip("/") in skip:
                    continue
                if isinstance(obj, h5py.Group):
                    copy(obj, dst.create_group(name))
                    continue
                chunked = obj.chunks is not None
                ds = dst.create_dataset(name, shape=obj.shape, dtype=obj.dtype,
                                        chunks=obj.chunks if chunked else None,
                                        maxshape=obj.maxshape if chunked else None,
                                        compression=obj.compression,
                                        compression_opts=obj.compression_opts,
                                        shuffle=obj.shuffle)
                for a, val in obj.attrs.items():
                    ds.attrs[a] = val
                if obj.ndim == 0:
                    ds[()] = obj[()]
                    continue
                path = obj.name.lstrip("/")
                for i0, block in self.row_blocks([path], obj.shape[0]):
                    ds[i0:i0 + len(block[path])] = block[path]

        copy(self.h5, h5)

    # -- a view to plot ----------------------------------------------------------------------
    def view(self, points: int = VIEW_POINTS, profiles: int = VIEW_PROFILES) -> Result:
        """The result with every series reduced to about ``points`` values and at most
        ``profiles`` fault profiles, read in bounded pieces. A result with fewer rows is read
        as it is. Longer series keep their first and last rows and, for each bucket of rows
        between, the bucket's smallest and largest value in the order they came, at the
        bucket's first and last time: the envelope, so no peak is lost. The profiles are
        spread evenly over the run, the first and last among them."""
        h5, ds = self.h5, self._dataset
        series = {g: [k for k in h5[g]
                      if ds(f"{g}/{k}").ndim == 1 and ds(f"{g}/{k}").dtype.names is None]
                  for g in _SERIES_GROUPS if g in h5}
        if not self.growing:
            self._check_shapes(series)
        paths = ["time"] + [f"{g}/{k}" for g, ks in series.items() for k in ks]
        values = self._envelope(paths, self.rows, points)
        groups = {g: {k: values[f"{g}/{k}"] for k in ks} for g, ks in series.items()}
        extra = {}
        for g in h5:
            if g in ("time", "fault", "injection", "balance", "solver"):
                continue
            arrays = dict(groups.get(g, {}))
            if g == "log" and "time" in h5[g]:
                n_log = h5[g]["time"].shape[0]
                log_paths = [f"log/{k}" for k in h5[g] if h5[g][k].shape[:1] == (n_log,)]
                arrays.update({p.split("/", 1)[1]: v for p, v in
                               self._envelope(log_paths, n_log, points).items()})
            for k in h5[g]:               # the rest (events, level changes): small, read whole
                if k not in arrays:
                    arrays[k] = h5[g][k][()]
            extra[g] = arrays
        kept = self._profile_rows(profiles)
        fault = {k: self._rows_of(f"fault/{k}", kept) for k in h5["fault"]
                 if k not in ("x", "xy", "weight", "time")}
        # files before [output] have a profile per output time and no /fault/time
        ft = self._rows_of("fault/time" if "time" in h5["fault"] else "time", kept)
        return Result(scene=self.scene, time=values["time"], fault_x=h5["fault/x"][()],
                      fault_xy=h5["fault/xy"][()], fault_weights=h5["fault/weight"][()], fault=fault,
                      injection=groups.get("injection", {}), balance=groups.get("balance", {}),
                      solver=groups.get("solver", {}), meta=dict(self.meta), extra=extra,
                      fault_time=ft)

    def _check_shapes(self, series: dict) -> None:
        """ValueError (one line) unless every series has a row per output time and every
        profile a row per profile time and a column per fault point (as Result.check_lengths)."""
        h5, ds, n_x = self.h5, self._dataset, self._dataset("fault/x").shape[0]
        for g, keys in series.items():
            for k in keys:
                if ds(f"{g}/{k}").shape[0] != self.rows:
                    raise ValueError(f"damaged result: /{g}/{k} has {ds(f'{g}/{k}').shape[0]} rows "
                                     f"for {self.rows} output times")
        for k in h5["fault"]:
            shape = ds(f"fault/{k}").shape
            if k not in ("x", "xy", "weight", "time") and shape != (self.profiles, n_x):
                raise ValueError(f"damaged result: /fault/{k} has shape {shape} for "
                                 f"{self.profiles} times and {n_x} fault points")

    def _profile_rows(self, profiles: int) -> np.ndarray:
        n = self.profiles
        if n <= profiles:
            return np.arange(n)
        return np.unique(np.round(np.linspace(0, n - 1, profiles)).astype(np.int64))

    def _rows_of(self, path: str, rows: np.ndarray) -> np.ndarray:
        """Rows ``rows`` (increasing) of ``path``, read at most ``read_rows`` values at once."""
        ds = self._dataset(path)
        width = int(np.prod(ds.shape[1:], dtype=np.int64)) or 1
        step = max(1, self.read_rows // width)
        parts = [self._read(path, rows[i:i + step]) for i in range(0, len(rows), step)]
        return np.concatenate(parts) if parts else np.zeros((0, *ds.shape[1:]), ds.dtype)

    def _envelope(self, paths: list, n: int, points: int) -> dict:
        """path -> the envelope of :meth:`view` of datasets of ``n`` rows."""
        if n <= max(points, 2):
            return {p: np.concatenate([b for _, b in self.blocks(p)]) if n else self._dataset(p)[()]
                    for p in paths}
        inner = n - 2                                     # rows 1 .. n - 2 go into buckets
        size = -(-inner // max(1, points // 2))           # rows per bucket
        buckets = -(-inner // size)
        out = {}
        for p in paths:
            ds = self._dataset(p)
            env = np.empty(2 * buckets + 2, dtype=ds.dtype)
            env[0], env[-1] = self._read(p, slice(0, 1))[0], self.last(p)
            # the times increase: their envelope is each bucket's first and last time
            for b0, pair in self._bucket_extremes(p, n, size):
                env[1 + 2 * b0:1 + 2 * b0 + pair.size] = pair
            out[p] = env
        return out

    def _bucket_extremes(self, path: str, n: int, size: int):
        """(first bucket, its [min, max] pairs in time order, flattened), block by block."""
        per_read = max(1, self.read_rows // size)         # whole buckets per read
        r = 1
        b0 = 0
        while r < n - 1:
            if size <= self.read_rows:
                r1 = min(n - 1, r + per_read * size)
                block = self._read(path, slice(r, r1)).astype(float)
            else:                                         # a bucket spans reads: one at a time
                r1 = min(n - 1, r + size)
                block, pairs = None, None
                for i0 in range(r, r1, self.read_rows):
                    part = self._read(path, slice(i0, min(r1, i0 + self.read_rows))).astype(float)
                    lo, i_lo, hi, i_hi = _bucket_pair(part[None, :])
                    piece = (lo, i_lo + (i0 - r), hi, i_hi + (i0 - r))
                    pairs = piece if pairs is None else _merge_pair(pairs, piece)
            if block is not None:
                k = -(-block.size // size)
                padded = np.full(k * size, np.nan)
                padded[:block.size] = block
                pairs = _bucket_pair(padded.reshape(k, size))
            else:
                k = 1
            yield b0, _ordered(pairs)
            b0 += k
            r = r1


def _bucket_pair(a: np.ndarray):
    """Per row of ``a``: (min, position, max, position), NaN ignored (all NaN: NaN)."""
    finite = ~np.isnan(a)
    i_lo = np.argmin(np.where(finite, a, np.inf), axis=1)
    i_hi = np.argmax(np.where(finite, a, -np.inf), axis=1)
    rows = np.arange(a.shape[0])
    some = finite.any(axis=1)
    lo = np.where(some, a[rows, i_lo], np.nan)
    hi = np.where(some, a[rows, i_hi], np.nan)
    return lo, i_lo, hi, i_hi


def _merge_pair(first, second):
    """The (min, position, max, position) of two consecutive pieces of one bucket."""
    (lo1, il1, hi1, ih1), (lo2, il2, hi2, ih2) = first, second
    take_lo = np.isnan(lo1) | (lo2 < lo1)
    take_hi = np.isnan(hi1) | (hi2 > hi1)
    return (np.where(take_lo, lo2, lo1), np.where(take_lo, il2, il1),
            np.where(take_hi, hi2, hi1), np.where(take_hi, ih2, ih1))


def _ordered(pairs) -> np.ndarray:
    """[first, second] per bucket: its min and max in the order they came, flattened."""
    lo, i_lo, hi, i_hi = pairs
    low_first = i_lo <= i_hi
    return np.column_stack([np.where(low_first, lo, hi), np.where(low_first, hi, lo)]).ravel()

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
    """h5py.File for reading; a file a writer holds open in SWMR mode is opened as its reader."""
    import h5py

    try:
        return h5py.File(path, "r")
    except OSError as exc:
        if "already open for write" not in str(exc):
            raise
        return h5py.File(path, "r", libver="latest", swmr=True)


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

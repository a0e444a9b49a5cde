"""Results of a run and their HDF5 form.

Layout (SI units; every fault array is shaped (time, x)):
``/time`` s; ``/fault/x`` m along the fault (0 at the injection point) at the fault's Gauss
points; ``/fault/xy`` m; ``/fault/weight`` m (Gauss weights: integrals along the fault are sums);
``/fault/{pressure, overpressure, shear_traction, effective_normal_stress}`` Pa (effective normal
stress compression-positive); ``/fault/{slip, opening}`` m (opening positive apart);
``/fault/slip_rate`` m/s; ``/fault/friction`` -; ``/fault/contact_state`` 0 stick 1 slip 2 open;
``/injection/{flow_rate (m^3/s, whole interval), pressure, overpressure (Pa), slip, opening,
hydraulic_aperture (m), volume (m^3, cumulative, whole interval), fault_inflow_velocity (m/s,
Eq. 29: flow_rate / (NoF 2h)), slip_rate, shear_traction, effective_normal_stress, friction (at
the fault Gauss point nearest to the injection point)}``; ``/balance/*`` m^3 per m of fault-plane thickness;
``/solver/*``; root attribute ``scene`` holds the resolved scene as TOML.
The file is written to a temporary name and renamed, so a failed write leaves no partial file.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .scene import Scene


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

    def save(self, path) -> Path:
        import h5py

        path = Path(path)
        tmp = path.with_name(path.name + ".part")
        try:
            with h5py.File(tmp, "w") as h5:
                h5.attrs["scene"] = self.scene.to_toml()
                h5.attrs["meta"] = json.dumps(self.meta, default=float)
                h5.create_dataset("time", data=self.time).attrs["unit"] = "s"
                g = h5.create_group("fault")
                g.create_dataset("x", data=self.fault_x).attrs["unit"] = "m"
                g.create_dataset("xy", data=self.fault_xy).attrs["unit"] = "m"
                g.create_dataset("weight", data=self.fault_weights).attrs["unit"] = "m"
                for k, v in self.fault.items():
                    g.create_dataset(k, data=v, compression="gzip").attrs["unit"] = _UNITS.get(k, "")
                for name in ("injection", "balance", "solver"):
                    grp = h5.create_group(name)
                    for k, v in getattr(self, name).items():
                        grp.create_dataset(k, data=v).attrs["unit"] = _UNITS.get(k, "")
                for name, arrays in self.extra.items():
                    grp = h5.require_group(name)
                    for k, v in arrays.items():
                        grp.create_dataset(k, data=v).attrs["unit"] = _UNITS.get(k, "")
            os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()
        return path

    @classmethod
    def load(cls, path) -> "Result":
        import h5py
        import tomllib

        with h5py.File(path, "r") as h5:
            scene = Scene.from_dict(tomllib.loads(h5.attrs["scene"]))
            read = lambda grp: {k: grp[k][()] for k in grp}
            fault = read(h5["fault"])
            fx, fxy, fw = fault.pop("x"), fault.pop("xy"), fault.pop("weight")
            extra = {k: read(h5[k]) for k in h5 if k not in ("time", "fault", "injection", "balance", "solver")}
            return cls(scene=scene, time=h5["time"][()], fault_x=fx, fault_xy=fxy, fault_weights=fw, fault=fault,
                       injection=read(h5["injection"]), balance=read(h5["balance"]),
                       solver=read(h5["solver"]), meta=json.loads(h5.attrs["meta"]), extra=extra)


_UNITS = {"pressure": "Pa", "overpressure": "Pa", "shear_traction": "Pa",
          "effective_normal_stress": "Pa", "slip": "m", "opening": "m", "slip_rate": "m/s",
          "friction": "1", "hydraulic_aperture": "m", "fault_inflow_velocity": "m/s", "flow_rate": "m3/s", "volume": "m3", "stored_rock": "m3/m",
          "stored_fault": "m3/m", "leaked": "m3/m", "dt": "s",
          # groups added by callers (/log, /events)
          "time": "s", "magnitude": "1", "latitude": "degree", "longitude": "degree", "depth": "m",
          "x": "m", "y": "m", "z": "m", "distance_to_injection": "m", "distance_to_fault": "m"}

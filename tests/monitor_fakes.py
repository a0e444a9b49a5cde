"""Small stand-ins with the interfaces the monitor stage drives (for fast tests of its data
handling): a stepper with ``fault_screen.Simulation``'s methods and a threshold screener; and an
HTTP receiver on 127.0.0.1 for the alert plugins.

The fake stepper takes fixed steps ``k * dt`` (dt from the scene) and records, per step, the
volume it was given; its fault "state" is a made-up function of the injected volume, so that
levels change as volume accumulates.
"""
from __future__ import annotations

import http.server
import json
import math
import threading
import time

import numpy as np

from fault_screen import Result

N_POINTS = 5
FAULT_XY = np.column_stack([np.linspace(-20.0, 20.0, N_POINTS), np.zeros(N_POINTS)])
V_FAIL = 0.5     # m3: utilisation reaches 1 at the injection point when this much is in


class FakeSimulation:
    def __init__(self, scene):
        self.scene = scene
        self.dt = float(scene.time.dt)
        self.k = 0
        self.time = 0.0
        self.rows = [self._row(0.0, 0.0, 0.0)]

    def _row(self, t, vol, rate):
        u = (0.5 + vol / V_FAIL) * np.exp(-np.abs(FAULT_XY[:, 0]) / 20.0)
        sn = np.full(N_POINTS, 1e6)
        tau = u * self.scene.fault.friction * sn
        return {"time": t, "volume": vol, "flow_rate": rate,
                "slip_rate": np.where(u >= 1, 1e-5 * u, 0.0),
                "contact_state": (u >= 1).astype(np.int64),
                "shear_traction": tau, "effective_normal_stress": sn,
                "inj_overpressure": 1e5 * vol, "inj_slip": 0.0}

    @property
    def last_row(self):
        return self.rows[-1]

    def advance(self, t_next, volume=None, align=True, max_steps=None):
        n = 0
        while max_steps is None or n < max_steps:
            t1 = (self.k + 1) * self.dt
            if t1 > t_next:
                if align or self.time >= t_next:
                    break
                t1 = t_next
            v = volume(self.time, t1)
            self.rows.append(self._row(t1, self.rows[-1]["volume"] + v, v / (t1 - self.time)))
            self.time = t1
            self.k += 1
            n += 1
        return n

    def result(self):
        stack = lambda k: np.array([r[k] for r in self.rows])  # noqa: E731
        fault = {k: stack(k) for k in ("slip_rate", "contact_state", "shear_traction",
                                       "effective_normal_stress")}
        return Result(scene=self.scene, time=stack("time"), fault_x=FAULT_XY[:, 0].copy(),
                      fault_xy=FAULT_XY.copy(), fault_weights=np.full(N_POINTS, 10.0),
                      fault=fault, injection={"volume": stack("volume"),
                                              "flow_rate": stack("flow_rate")},
                      balance={}, solver={}, meta={})

    def checkpoint(self, path):
        import h5py

        with h5py.File(path, "w") as h5:
            h5.attrs["scene"] = self.scene.to_toml()
            h5.attrs["fake"] = json.dumps({"k": self.k, "time": self.time, "rows": [
                {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in r.items()}
                for r in self.rows]})

    @classmethod
    def restore(cls, path):
        import tomllib

        import h5py

        from fault_screen import Scene

        with h5py.File(path, "r") as h5:
            scene = Scene.from_dict(tomllib.loads(h5.attrs["scene"]))
            d = json.loads(h5.attrs["fake"])
        sim = cls(scene)
        sim.k, sim.time = d["k"], d["time"]
        sim.rows = [{k: (np.array(v) if isinstance(v, list) else v) for k, v in r.items()}
                    for r in d["rows"]]
        return sim


class ThresholdScreener:
    """Level = number of thresholds of ``max_utilisation`` exceeded (0.9 yellow, 1.0 red), or
    red when ``event_magnitude >= 2``; returns transitions as dicts."""

    def __init__(self):
        self.level = 0

    def state(self):
        return {"level": self.level}

    @classmethod
    def from_state(cls, state):
        out = cls()
        out.level = int(state["level"])
        return out

    def update(self, time, metrics, events=()):
        u = metrics.get("max_utilisation", 0.0)
        new = 2 if u >= 1.0 else 1 if u >= 0.9 else 0
        rule = "max_utilisation > 1.0" if new == 2 else "max_utilisation > 0.9"
        mag = metrics.get("event_magnitude", math.nan)
        if mag >= 2.0:
            new, rule = 2, "event_magnitude >= 2"
        if new == self.level:
            return []
        tr = {"time": time, "previous": self.level, "level": new, "rule": rule,
              "action": "reduce rate" if new == 1 else "stop injection" if new == 2 else ""}
        self.level = new
        return [tr]


def run_service(scene_path, follow, state, out, alerts_path, idle_exit=1.0,
                checkpoint_every=3, poll=0.02, **options):
    """The monitor service with the fake stepper and screener (for subprocess tests)."""
    from pathlib import Path

    from fault_screen import Scene
    from fault_screen.monitor.service import MonitorConfig, MonitorService

    scene = Scene.from_toml(scene_path)
    cfg = MonitorConfig(follow=str(follow), state=Path(state), out=Path(out),
                        idle_exit=idle_exit, alerts=[f"jsonl:{alerts_path}"],
                        poll_interval=poll, checkpoint_every=checkpoint_every, **options)
    service = MonitorService(scene, cfg, simulation_class=FakeSimulation,
                             screener=ThresholdScreener())
    service.install_signal_handlers()
    return service.run()


class Receiver:
    """HTTP receiver on 127.0.0.1 answering ``codes`` in turn (then 200; a 3xx with a Location
    header to ``location``), recording each request as (headers, body, time) and its method."""

    def __init__(self, codes=(), location=None):
        self.codes = list(codes)
        self.requests = []
        self.methods = []
        outer = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def _answer(self):
                n = int(self.headers.get("content-length") or 0)
                body = self.rfile.read(n) if n else b""
                outer.methods.append(self.command)
                outer.requests.append(({k.lower(): v for k, v in self.headers.items()}, body,
                                       time.time()))
                code = outer.codes.pop(0) if outer.codes else 200
                self.send_response(code)
                if 300 <= code < 400 and location:
                    self.send_header("Location", location)
                self.send_header("content-length", "0")
                self.end_headers()

            do_POST = do_GET = _answer

            def log_message(self, *a):
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_port}/hook"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def ids(self):
        """The alert ids received, in order."""
        return [json.loads(body)["id"] for _, body, _ in self.requests if body]

    def close(self):
        self.server.shutdown()
        self.server.server_close()

"""The package-level API: what ``import fault_screen`` users call.

It sits above the core (which reads no files) and adds what a user expects of a whole run: a
scene that names an injection log is driven by that log, and the result is screened with the
scene's ``[monitor]`` rules (``/screening/``). The core alone is
:func:`fault_screen.simulate.simulate`.
"""
from __future__ import annotations

import numpy as np

from .result import Result
from .scene import Scene
# imported here, before the package binds the name ``simulate`` to the function below: a first
# import of the submodule later would rebind ``fault_screen.simulate`` to the module
from .simulate import SimulationError


def scene_injected_volume(scene: Scene):
    """The volume function ``V(t0, t1)`` (m^3) of the scene's ``injection.log``, or None."""
    inj = scene.injection
    if inj.log is None:
        return None
    from .io.injection_log import read_injection_log

    log = read_injection_log(inj.log, flow_unit=inj.log_flow_unit, max_gap=inj.log_max_gap,
                             policy=inj.log_policy, flowback=inj.allow_flowback)
    return log.volume


def simulate(scene: Scene, *, events=None, injected_volume=None, progress=None,
             observer=None) -> Result:
    """Run ``scene`` to its end time (``progress``, ``observer`` as
    :func:`fault_screen.simulate.simulate`) and screen it step by step with the scene's
    ``[monitor]`` rules (``/screening/``, the numbers :func:`screen_result` gives over the
    whole result; a level change keeps its fault profile when ``[output]`` thins them). A scene
    with ``injection.log`` is driven by that log unless ``injected_volume`` is given.
    ``events``: seismic events (``.time`` s of model time, ``.magnitude``, optional
    ``.distance`` m) the rules may use."""
    from .stepper import Simulation

    if injected_volume is None:
        injected_volume = scene_injected_volume(scene)
    sim = Simulation(scene)
    if observer is not None:
        observer(0.0, sim.x, sim.disc)
    screening = _screened_run(sim, events, injected_volume, progress, observer)
    result = sim.result()
    result.extra["screening"] = screening.arrays()
    return result


class StepScreening:
    """The screening of a run step by step, written beside its streamed results: the metrics and
    level of every row (``/screening/<metric>``, ``/screening/level``) and each level change
    (``/screening/transitions``) as :func:`~fault_screen.screening.screen_result` gives them
    over a whole result (the same numbers: the same tracker and screener, row by row).

    ``events``: seismic events known from the start (a catalogue), each counted at its origin
    time; more may come with each row (``update(..., events=...)``, the live monitor)."""

    def __init__(self, scene: Scene, fault_x, fault_weights, events=None):
        from .screening import Events, MetricsTracker, Screener

        self.tracker = MetricsTracker(fault_x, fault_weights, scene.fault.friction)
        self.screener = Screener(scene.monitor)
        self.screener.add_events(Events.coerce(events))
        self.records: list[dict] = []     # the rows screened, when kept in memory

    def arrays(self) -> dict:
        """The ``/screening/`` group of the rows screened in memory (``Result.extra``)."""
        from .screening import TRANSITION_DTYPE

        out = {p.rsplit("/", 1)[1]: np.array([r[p] for r in self.records])
               for p in self.streams()["screening"]}
        out["level"] = out["level"].astype(np.int8)
        tr = [self.transition_record(t)["/screening/transitions"] for t in self.screener.transitions]
        out["transitions"] = np.array(tr, dtype=TRANSITION_DTYPE).reshape(-1)
        return out

    @staticmethod
    def streams() -> dict:
        """The streams to declare to :meth:`~fault_screen.Simulation.stream_to`."""
        from .rules import METRICS
        from .screening import TRANSITION_DTYPE

        rows = {f"/screening/{name}": ("<f8", ()) for name in METRICS}
        rows["/screening/level"] = ("|i1", ())
        return {"screening": rows, "transitions": {"/screening/transitions": (TRANSITION_DTYPE, ())}}

    def update(self, row: dict, point: int, *, unstable: bool = False, events=None):
        """Screen one recorded row of the stepper (``Simulation.last_row``; ``point``: index of
        the fault point nearest to the injection). Returns ``(record, transitions)``: the
        ``screening`` stream's record and the level changes (Transition list)."""
        from .screening.metrics import FAULT_FIELDS

        at = lambda k: float(row[k][point]) if len(row[k]) else 0.0  # noqa: E731
        metrics = self.tracker.update({k: row[k] for k in FAULT_FIELDS},
                                      {"overpressure": row["inj_overpressure"], "slip": row["inj_slip"],
                                       "shear_traction": at("shear_traction"),
                                       "effective_normal_stress": at("effective_normal_stress")})
        transitions = self.screener.update(row["time"], metrics, events=events, unstable=unstable)
        record = {f"/screening/{k}": float(v) for k, v in metrics.items()}
        record["/screening/level"] = self.screener.level
        return record, transitions

    @staticmethod
    def transition_record(tr) -> dict:
        from .screening import TRANSITION_DTYPE

        rec = np.zeros((), dtype=TRANSITION_DTYPE)
        rec[()] = (tr.time, tr.from_level, tr.to_level, tr.rule.encode("utf-8")[:64])
        return {"/screening/transitions": rec}

    def screen(self, sim, *, events=None) -> list:
        """Screen the newest row of ``sim`` and append it to its result file (or keep it, for
        :meth:`arrays`, when ``sim`` keeps its results in memory); a level change keeps that
        row's fault profile. Returns the level changes."""
        stopped = (sim.stopped or {}).get("reason") == "unstable"
        record, transitions = self.update(sim.last_row, sim.disc.injection.nearest_point,
                                          unstable=stopped, events=events)
        writer = sim.writer
        if writer is not None:
            writer.append("screening", record)
            for tr in transitions:
                writer.append("transitions", self.transition_record(tr))
        else:
            self.records.append(record)
        if transitions:
            sim.recorder.keep_profile()
        return transitions

    def screening(self, result) -> "object":
        """The :class:`~fault_screen.screening.Screening` of the streamed run (its verdict and
        level changes; the per-row values from ``result``, the file read back)."""
        from .screening import Screening

        arrays = result.extra.get("screening", {})
        metrics = {k: v for k, v in arrays.items() if k not in ("level", "transitions")}
        return Screening(result.time, metrics, arrays.get("level"), self.screener.transitions,
                         self.screener.verdict, self.screener.spec)


def run_streamed(scene: Scene, path, *, events=None, injected_volume=None, progress=None):
    """Run ``scene`` to its end time streaming the results, screened step by step, to the HDF5
    file ``path`` (memory bounded whatever the duration). Returns ``(simulation, screening)``;
    the caller finishes the file with ``simulation.close_stream(meta=..., groups=...)``. On an
    error the file is closed as the last flush left it and the error raised."""
    from .stepper import Simulation

    sim = Simulation(scene)
    sim.stream_to(path, streams=StepScreening.streams())
    try:
        screening = _screened_run(sim, events, injected_volume, progress, None)
    except BaseException:
        sim.writer.abandon()
        raise
    return sim, screening


def _screened_run(sim, events, injected_volume, progress, observer) -> StepScreening:
    """Advance ``sim`` to its scene's end, screening every row as it comes."""
    scene = sim.scene
    if scene.injection.log is not None and injected_volume is None:
        raise SimulationError(f"the scene reads the injection log {scene.injection.log}: read it with "
                              f"fault_screen.io.read_injection_log and pass injected_volume=log.volume")
    fp = sim.disc.fault_points
    screening = StepScreening(scene, fp.s - sim.disc.injection.s, fp.weight, events)
    screening.screen(sim)                       # the in-situ state at t = 0
    # one step per call: each row is screened before the next (the same steps as one call)
    while sim.advance(scene.time.end, volume=injected_volume, max_steps=1, progress=progress,
                      observer=observer):
        screening.screen(sim)
    return screening

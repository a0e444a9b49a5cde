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
from .screening import screen_result
from .simulate import simulate as simulate_core


def scene_injected_volume(scene: Scene):
    """The volume function ``V(t0, t1)`` (m^3) of the scene's ``injection.log``, or None."""
    inj = scene.injection
    if inj.log is None:
        return None
    from .io.injection_log import read_injection_log

    log = read_injection_log(inj.log, flow_unit=inj.log_flow_unit, max_gap=inj.log_max_gap,
                             policy=inj.log_policy, flowback=inj.allow_flowback)
    return log.volume


def simulate(scene: Scene, *, events=None, injected_volume=None, **options) -> Result:
    """Run ``scene`` to its end time (options as :func:`fault_screen.simulate.simulate`:
    ``progress``, ``observer``) and screen the result with the scene's ``[monitor]`` rules. A
    scene with ``injection.log`` is driven by that log unless ``injected_volume`` is given.
    ``events``: seismic events (``.time`` s of model time, ``.magnitude``, optional
    ``.distance`` m) the rules may use."""
    if injected_volume is None:
        injected_volume = scene_injected_volume(scene)
    result = simulate_core(scene, injected_volume=injected_volume, **options)
    screen_result(result, events=events)
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

    @staticmethod
    def streams() -> dict:
        """The streams to declare to :meth:`~fault_screen.Simulation.stream_to`."""
        from .rules import METRICS
        from .screening import TRANSITION_DTYPE

        rows = {f"/screening/{name}": ("<f8", ()) for name in METRICS}
        rows["/screening/level"] = ("|i1", ())
        return {"screening": rows, "transitions": {"/screening/transitions": (TRANSITION_DTYPE, ())}}

    def update(self, row: dict, point: int, *, unstable: bool = False, events=None, metrics=None):
        """Screen one recorded row of the stepper (``Simulation.last_row``; ``point``: index of
        the fault point nearest to the injection). Returns ``(record, transitions)``: the
        ``screening`` stream's record and the level changes (Transition list)."""
        from .screening.metrics import FAULT_FIELDS

        if metrics is None:
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
        """Screen the newest row of ``sim`` and append it to its result file; a level change
        keeps that row's fault profile. Returns the level changes."""
        stopped = (sim.stopped or {}).get("reason") == "unstable"
        record, transitions = self.update(sim.last_row, sim.disc.injection.nearest_point,
                                          unstable=stopped, events=events)
        writer = sim.writer
        if writer is not None:
            writer.append("screening", record)
            for tr in transitions:
                writer.append("transitions", self.transition_record(tr))
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
    fp = sim.disc.fault_points
    screening = StepScreening(scene, fp.s - sim.disc.injection.s, fp.weight, events)
    try:
        screening.screen(sim)                       # the in-situ state at t = 0
        end = scene.time.end
        # one step per call: each row is screened before the next (the same steps as one call)
        while sim.advance(end, volume=injected_volume, max_steps=1, progress=progress):
            screening.screen(sim)
    except BaseException:
        sim.writer.abandon()
        raise
    return sim, screening

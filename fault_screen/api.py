"""The package-level API: what ``import fault_screen`` users call.

It sits above the core (which reads no files) and adds what a user expects of a whole run: a
scene that names an injection log is driven by that log, and the result is screened with the
scene's ``[monitor]`` rules (``/screening/``). The core alone is
:func:`fault_screen.simulate.simulate`.
"""
from __future__ import annotations

from .result import Result
from .scene import Scene
from .screening.stepwise import StepScreening
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
    screening = StepScreening.for_scene(scene, fp.s - sim.disc.injection.s, fp.weight, events)
    screening.screen_simulation(sim)            # the in-situ state at t = 0
    # one step per call: each row is screened before the next (the same steps as one call)
    while sim.advance(scene.time.end, volume=injected_volume, max_steps=1, progress=progress,
                      observer=observer):
        screening.screen_simulation(sim)
    return screening

"""A whole run: the scene's stepper advanced from the in-situ state to ``time.end``.

The core reads no files: a scene that names an injection log needs the log's volume function
from the caller (``fault_screen.io``; the CLI and the package-level API do that).
"""
from __future__ import annotations

from typing import Callable

from .result import Result
from .scene import Scene
from .stepper import Simulation, SimulationError

__all__ = ["simulate", "Simulation", "SimulationError"]


def simulate(scene: Scene, *, progress: Callable | None = None, injected_volume=None,
             observer: Callable | None = None) -> Result:
    """Run ``scene`` to its end time. ``injected_volume(t0, t1)`` (m^3 of the whole interval)
    replaces the scene's rate schedule (logs); ``progress(step, t, end, wall)`` after each step;
    ``observer(t, x, disc)`` sees every accepted state vector (checks on nodal fields)."""
    if scene.injection.log is not None and injected_volume is None:
        raise SimulationError(f"the scene reads the injection log {scene.injection.log}: read it with "
                              f"fault_screen.io.read_injection_log and pass injected_volume=log.volume")
    sim = Simulation(scene)
    if observer is not None:
        observer(0.0, sim.x, sim.disc)
    sim.advance(scene.time.end, volume=injected_volume, progress=progress, observer=observer)
    return sim.result()

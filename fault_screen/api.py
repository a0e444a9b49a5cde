"""The package-level API: what ``import fault_screen`` users call.

It sits above the core (which reads no files) and adds what a user expects of a whole run:
a scene that names an injection log is driven by that log.
"""
from __future__ import annotations

from typing import Callable

from .result import Result
from .scene import Scene
from .simulate import simulate as simulate_core


def scene_injected_volume(scene: Scene):
    """The volume function ``V(t0, t1)`` (m^3) of the scene's ``injection.log``, or None."""
    inj = scene.injection
    if inj.log is None:
        return None
    from .io.injection_log import read_injection_log

    log = read_injection_log(inj.log, flow_unit=inj.log_flow_unit, max_gap=inj.log_max_gap,
                             policy=inj.log_policy)
    return log.volume


def simulate(scene: Scene, *, progress: Callable | None = None, injected_volume=None,
             observer: Callable | None = None) -> Result:
    """Run ``scene`` to its end time (see :func:`fault_screen.simulate.simulate`); a scene with
    ``injection.log`` is driven by that log unless ``injected_volume`` is given."""
    if injected_volume is None:
        injected_volume = scene_injected_volume(scene)
    return simulate_core(scene, progress=progress, injected_volume=injected_volume, observer=observer)

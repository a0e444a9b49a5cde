"""The package-level API: what ``import fault_screen`` users call.

It sits above the core (which reads no files) and adds what a user expects of a whole run: a
scene that names an injection log is driven by that log, and the result is screened with the
scene's ``[monitor]`` rules (``/screening/``). The core alone is
:func:`fault_screen.simulate.simulate`.
"""
from __future__ import annotations

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

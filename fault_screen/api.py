"""The package's public :func:`simulate`: the core's run followed by screening.

``fault_screen.simulate(scene, ...)`` returns a :class:`~fault_screen.Result` that holds the
``/screening/`` group (metrics, levels and transitions of the scene's ``[monitor]`` rules); the
core alone is :func:`fault_screen.simulate.simulate` (module ``fault_screen.simulate``).
"""
from __future__ import annotations

from .result import Result
from .scene import Scene
from .screening import screen_result
from .simulate import simulate as _simulate_core


def simulate(scene: Scene, *, events=None, **options) -> Result:
    """Run ``scene`` (options as :func:`fault_screen.simulate.simulate`: ``progress``,
    ``injected_volume``, ``model``, ``observer``) and screen the result with the scene's
    ``[monitor]`` rules; ``events``: seismic events (``.time`` s of model time, ``.magnitude``,
    optional ``.distance`` m) the rules may use."""
    result = _simulate_core(scene, **options)
    screen_result(result, events=events)
    return result

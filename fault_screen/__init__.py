"""fault_screen: coupled hydro-mechanical X-FEM screening of fluid injection into faults."""
__version__ = "0.1.0"

from .scene import Scene, SceneError  # noqa: E402
from .result import Result  # noqa: E402
from .stepper import Simulation, SimulationError  # noqa: E402
from .api import simulate  # noqa: E402  (core run + screening)

__all__ = ["Scene", "SceneError", "Result", "Simulation", "simulate", "SimulationError", "__version__"]

"""fault_screen: coupled hydro-mechanical X-FEM screening of fluid injection into faults.

The names below are imported on first use (PEP 562): a command that only reads a scene or a
result (``fault-screen scene check``, ``plot``, ``--help``) does not pay for numba, scipy and
the model's kernels, which ``Simulation`` brings in.
"""
import sys
import types

__version__ = "0.1.0"

__all__ = ["Scene", "SceneError", "Result", "Simulation", "simulate", "SimulationError", "__version__"]


def __getattr__(name):
    # each import written out, so that the import graph (tests/package/test_import_cycles.py) sees it
    if name in ("Scene", "SceneError"):
        from . import scene as module
    elif name == "Result":
        from . import result as module
    elif name in ("Simulation", "SimulationError"):
        from . import stepper as module
    else:
        raise AttributeError(f"module 'fault_screen' has no attribute {name!r}")
    value = getattr(module, name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """``fault_screen.simulate`` is the function of :mod:`fault_screen.api`, although a module
    of that name exists: importing the module ``fault_screen.simulate`` (the core run, which
    ``api`` imports) sets the package's attribute of that name, so the function is a property
    here and that assignment is let go."""

    @property
    def simulate(self):
        from .api import simulate

        return simulate

    @simulate.setter
    def simulate(self, value):
        if not isinstance(value, types.ModuleType):
            raise AttributeError("fault_screen.simulate is the function fault_screen.api.simulate")


sys.modules[__name__].__class__ = _Package

"""Where the injected fluid went: a fluid budget from a Result (no core imports).

The run records, for the single model fault, the fluid stored since the in-situ state in the
fault (opening and compressibility) and in the rock (Biot storage), and what left through the
drained edges (``Result.balance``, m^3 per m of thickness). The injection point takes the
interval's volume divided by the number of fractures (Eq. 29), so the three shares are fractions
of ``injection["volume"] / NoF``; whatever they do not add up to is the balance error.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the budget's destinations, in the order they are reported
DESTINATIONS = (("fault", "stored_fault"), ("rock", "stored_rock"), ("leaked", "leaked"))


@dataclass(frozen=True)
class FluidBudget:
    injected: float
    """Volume injected into the interval (m^3, whole interval, per m of thickness)."""
    model_fault: float
    """Volume that entered the single model fault: injected / NoF (m^3)."""
    volumes: dict
    """Destination (fault, rock, leaked) -> volume for the model fault (m^3)."""
    percent: dict
    """Destination -> percentage of the model fault's injected volume; empty if nothing injected."""
    unaccounted_percent: float | None
    """100 minus the percentages: the volume-balance error (%); None if nothing injected."""

    def summary(self) -> str:
        """One line for a run summary, e.g. ``fault 29.4 %, rock 69.9 %, leaked through edges 0.7 %``."""
        if not self.percent:
            return "nothing injected"
        label = {"fault": "fault", "rock": "rock", "leaked": "leaked through edges"}
        return ", ".join(f"{label[k]} {self.percent[k]:.3g} %" for k, _ in DESTINATIONS)


def fluid_budget(result, index: int = -1) -> FluidBudget:
    """The fluid budget at time index ``index`` (default: the end of the run)."""
    injected = float(np.asarray(result.injection["volume"])[index])
    nof = float(result.scene.injection.number_of_fractures)
    model_fault = injected / nof
    volumes = {name: float(np.asarray(result.balance[key])[index]) for name, key in DESTINATIONS}
    if model_fault <= 0.0:
        return FluidBudget(injected, model_fault, volumes, {}, None)
    percent = {name: 100.0 * v / model_fault for name, v in volumes.items()}
    return FluidBudget(injected, model_fault, volumes, percent, 100.0 - sum(percent.values()))

"""The declared output schema: every array a run records, with its shape, unit and meaning.

The HDF5 writer, the README's results table (``python -m fault_screen.outputs``) and the
figures' axis units all read this table, so a unit lives in one place. Shapes: ``(time, x)``
along the fault's Gauss points at every output time, ``(time,)`` one value per output time,
``(x,)`` and ``(x, 2)`` fixed along the fault. The ``(time, x)`` profiles are recorded at the
times ``/fault/time``: as the scene's ``[output]`` says; without it, every output time of a
result kept in memory (``fault_screen.simulate``) and the automatic rule below
(:func:`automatic_profile_due`) for a result written as the run goes (run, replay, monitor,
``Simulation.stream_to``).

The automatic rule, for results of any length written as they go (a row already in the file is
never removed, so the rule can only space out the rows still to come): every step's profile for
the first ``AUTO_PROFILE_STEPS`` steps, then one in 2 steps until step 2 x that, one in 4 until
4 x that, and so on, the spacing doubling each time the run doubles. A run of ``n`` steps keeps
about ``AUTO_PROFILE_STEPS x (1 + log2(n / AUTO_PROFILE_STEPS) / 2)`` profiles
(:func:`automatic_profile_count`), besides those always kept: the first and the last step and
every change of the screening level. The series (``(time,)`` arrays) keep every step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .rules import METRICS


@dataclass(frozen=True)
class Output:
    group: str
    name: str
    shape: str
    unit: str
    description: str

    @property
    def path(self) -> str:
        return f"/{self.group}/{self.name}" if self.group else f"/{self.name}"


_F, _I, _B, _S = "fault", "injection", "balance", "solver"
SCHEMA: tuple[Output, ...] = (
    Output("", "time", "(time,)", "s", "model time of each output (0 = start of injection)"),
    Output(_F, "x", "(x,)", "m", "along-fault coordinate of the fault Gauss points, 0 at the injection point"),
    Output(_F, "xy", "(x, 2)", "m", "model coordinates of the fault Gauss points"),
    Output(_F, "weight", "(x,)", "m", "Gauss weights: integrals along the fault are sums"),
    Output(_F, "time", "(profiles,)", "s",
           "model time of each fault profile (rows of the (time, x) arrays; [output] sets how often)"),
    Output(_F, "pressure", "(time, x)", "Pa", "fault pore pressure"),
    Output(_F, "overpressure", "(time, x)", "Pa", "fault pore pressure minus its in-situ value"),
    Output(_F, "slip", "(time, x)", "m", "tangential jump u+ - u- (along the fault tangent)"),
    Output(_F, "opening", "(time, x)", "m", "normal jump (positive apart) from the in-situ state"),
    Output(_F, "slip_rate", "(time, x)", "m/s", "slip change over the step divided by the step"),
    Output(_F, "shear_traction", "(time, x)", "Pa", "shear stress on the fault (in-situ included)"),
    Output(_F, "effective_normal_stress", "(time, x)", "Pa",
           "fault effective normal stress, compression positive (in-situ included)"),
    Output(_F, "friction", "(time, x)", "1", "friction coefficient in effect"),
    Output(_F, "contact_state", "(time, x)", "1", "0 stick, 1 slip, 2 open"),
    Output(_F, "hydraulic_aperture", "(time, x)", "m", "hydraulic aperture 2h"),
    Output(_I, "flow_rate", "(time,)", "m3/s", "flow rate of the whole interval (all NoF fractures), step average"),
    Output(_I, "pressure", "(time,)", "Pa", "pore pressure at the injection point"),
    Output(_I, "overpressure", "(time,)", "Pa", "overpressure at the injection point"),
    Output(_I, "slip", "(time,)", "m", "slip at the injection point"),
    Output(_I, "opening", "(time,)", "m", "opening at the injection point"),
    Output(_I, "volume", "(time,)", "m3", "cumulative injected volume of the whole interval"),
    Output(_I, "hydraulic_aperture", "(time,)", "m", "hydraulic aperture at the injection point"),
    Output(_I, "slip_rate", "(time,)", "m/s", "slip rate at the fault point nearest to the injection"),
    Output(_I, "shear_traction", "(time,)", "Pa", "shear stress at the fault point nearest to the injection"),
    Output(_I, "effective_normal_stress", "(time,)", "Pa",
           "effective normal stress at the fault point nearest to the injection"),
    Output(_I, "friction", "(time,)", "1", "friction at the fault point nearest to the injection"),
    Output(_I, "fault_inflow_velocity", "(time,)", "m/s", "Eq. 29: flow_rate / (NoF 2h)"),
    Output(_B, "stored_rock", "(time,)", "m3/m", "fluid stored in the rock since t = 0, per m of thickness"),
    Output(_B, "stored_fault", "(time,)", "m3/m", "fluid stored in the fault since t = 0, per m of thickness"),
    Output(_B, "leaked", "(time,)", "m3/m", "fluid that left through drained edges, per m of thickness"),
    Output(_S, "iterations", "(time,)", "1", "Newton iterations of the step"),
    Output(_S, "step_cuts", "(time,)", "1", "times the step was halved before it converged"),
    Output(_S, "dt", "(time,)", "s", "step size"),
    Output(_S, "theta", "(time,)", "1", "time weight of the step's flow terms (the scene's time.theta; "
           "lower inside a rung of the theta ladder, time.theta_min)"),
)

# the screening layer's metrics (rules.METRICS is their one definition), its traffic light and
# the replayed log that callers store beside the results
SCHEMA += tuple(Output("screening", name, "(time,)", unit_, meaning)
                for name, (unit_, meaning) in METRICS.items())
SCHEMA += (
    Output("screening", "level", "(time,)", "0 green, 1 yellow, 2 red", "traffic-light level"),
    Output("screening", "transitions", "(n,)", "time: s",
           "level changes: compound (time s, from, to, rule)"),
    Output("log", "time", "(samples,)", "s", "injection-log sample times used by the run (model time)"),
    Output("log", "flow_rate", "(samples,)", "m3/s", "logged flow rate of the whole interval"),
    Output("log", "pressure", "(samples,)", "Pa", "logged (wellhead or downhole) pressure"),
    Output("events", "time", "(events,)", "s", "origin time of each event read (model time)"),
    Output("events", "magnitude", "(events,)", "1", "magnitude (its type in magnitude_type)"),
    Output("events", "magnitude_type", "(events,)", "", "magnitude type as the catalog gives it (ML, Mw, mb)"),
    Output("events", "in_run", "(events,)", "1", "1 if the event falls inside the run's time span"),
    Output("events", "latitude", "(events,)", "degree", "epicentre latitude (geographic catalogs)"),
    Output("events", "longitude", "(events,)", "degree", "epicentre longitude (geographic catalogs)"),
    Output("events", "depth", "(events,)", "m", "hypocentre depth (positive down)"),
    Output("events", "x", "(events,)", "m", "local easting (local catalogs)"),
    Output("events", "y", "(events,)", "m", "local northing (local catalogs)"),
    Output("events", "z", "(events,)", "m", "local elevation (local catalogs)"),
    Output("events", "distance_to_injection", "(events,)", "m", "distance to the injection point ([site])"),
    Output("events", "distance_to_fault", "(events,)", "m", "distance to the modelled fault plane ([site])"),
)

#: steps recorded with their profile before the automatic rule starts spacing them out
AUTO_PROFILE_STEPS = 512


def automatic_profile_due(k: int, first: int = AUTO_PROFILE_STEPS) -> bool:
    """Whether row ``k`` (0: the in-situ state) keeps its profile under the automatic rule:
    every row below ``first``; below ``first * 2**j`` (j >= 1), every ``2**j``-th row."""
    if k < first:
        return True
    stride = 1 << (k // first).bit_length()
    return k % stride == 0


def automatic_profile_count(rows: int, first: int = AUTO_PROFILE_STEPS) -> int:
    """Rows among ``0 .. rows - 1`` :func:`automatic_profile_due` keeps (the last row, kept
    as well, and the level changes not counted)."""
    n = min(rows, first)
    j = 1
    while first << (j - 1) < rows:
        lo, hi = first << (j - 1), min(rows, first << j)
        stride = 1 << j
        n += (hi - 1) // stride - (lo - 1) // stride
        j += 1
    return n


#: unit of each named dataset (the same name means the same unit in every group)
UNITS = {o.name: o.unit for o in SCHEMA}


#: how the figures show a quantity: SI unit -> (display unit, factor from SI); slips and
#: openings are millimetres, every stress and pressure megapascals
_DISPLAY = {"Pa": ("MPa", 1e-6)}
_MILLIMETRES = ("slip", "opening", "induced_slip")


def display(group: str, name: str) -> tuple[float, str]:
    """(factor from SI, unit) in which the figures show ``/group/name``."""
    if name in _MILLIMETRES:
        return 1e3, "mm"
    u = unit(group, name)
    shown, factor = _DISPLAY.get(u, (u, 1.0))
    return factor, shown


def by_group(group: str) -> list[Output]:
    return [o for o in SCHEMA if o.group == group]


def unit(group: str, name: str) -> str:
    for o in SCHEMA:
        if o.group == group and o.name == name:
            return o.unit
    return UNITS.get(name, "")


def markdown_table() -> str:
    """The README's results table."""
    lines = ["| dataset | shape | unit | meaning |", "|---|---|---|---|"]
    cell = lambda text: text.replace("|", "\\|")  # a bar inside a cell would end it
    lines += [f"| `{o.path}` | {o.shape} | {cell(o.unit)} | {cell(o.description)} |" for o in SCHEMA]
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown_table())

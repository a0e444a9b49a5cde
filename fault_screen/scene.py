"""Scenes: what to simulate, in one validated, immutable object loaded from TOML or a dict.

Every field is SI (unit in its docstring). Validation happens once, here, and errors name the
key and the offending value (``SceneError``). ``Scene.to_toml()`` writes the fully resolved scene
(defaults included) back out.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import re
import reprlib
import tomllib
import warnings
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from . import units

EDGES = ("bottom", "right", "top", "left")


class SceneError(ValueError):
    """A scene that cannot be simulated; the message names the key and the value."""


class SceneWarning(UserWarning):
    """A value inside its physical range but outside the range met in practice."""


def _spec(cls):
    return dataclass(frozen=True, kw_only=True)(cls)


@_spec
class Refinement:
    """Graded mesh: spacing ``size`` within ``half_width`` of ``center``, growing outside."""
    center: tuple[float, float]
    """Centre of the fine region (m)."""
    half_width: tuple[float, float]
    """Half widths of the fine region along x and y (m)."""
    size: float
    """Element size in the fine region (m)."""
    growth: float = 1.15
    """Ratio of consecutive element sizes outside the fine region (-)."""


@_spec
class MeshSpec:
    nx: int = 50
    """Elements along x (-); ignored with ``refinement``."""
    ny: int = 51
    """Elements along y (-); ignored with ``refinement``."""
    lx: float = 250.0
    """Domain width (m)."""
    ly: float = 250.0
    """Domain height (m)."""
    origin: tuple[float, float] = (0.0, 0.0)
    """Lower-left corner (m)."""
    refinement: Refinement | None = None
    fault_grading: str = "auto"
    """'auto': with leak-off, grade the node lines across a fault parallel to x or y down to a
    fraction of the leak-off length sqrt(c dt) of the first step (docs/verification.md, "Leak-off and mesh");
    'off': keep the lines as given."""
    fault_grading_size: float | None = None
    """Height of the element the fault cuts with fault_grading (m); default 0.5 sqrt(c dt)."""
    fault_grading_growth: float = 1.2
    """Ratio of consecutive element heights away from the fault with fault_grading (-)."""


@_spec
class FaultSpec:
    point: tuple[float, float] | None = None
    """A point on the fault, origin of the along-fault coordinate (m); default: domain centre."""
    angle: float = 0.0
    """Fault angle counter-clockwise from the x axis (degrees)."""
    normal_stiffness: float = 31.8e9
    """Apparent normal penalty stiffness kN (Pa/m)."""
    shear_stiffness: float = 13.0e9
    """Apparent tangential penalty stiffness kT (Pa/m)."""
    friction: float = 0.61
    """Friction coefficient mu0 (-)."""
    hydraulic_aperture: float = 5.57e-5
    """Initial hydraulic aperture 2h0 (m)."""
    kappa: float = 1.2
    """Deviation from the parallel-plate cubic law: transmissivity (2h)^3/(12 mu kappa) (-)."""
    storativity: float | None = None
    """Fault storativity (m/Pa); default 2h0/Kf (fluid compressibility in the aperture)."""
    rate_parameter: float = 0.0
    """a of rate(-and-state) friction (-); used with effects.rate_friction."""
    state_parameter: float = 0.0
    """b of rate-and-state friction (-); used with effects.state_evolution."""
    reference_velocity: float = 1e-7
    """V0 of rate(-and-state) friction (m/s)."""
    critical_slip_distance: float = 1e-4
    """Dc of the aging law (m); used with effects.state_evolution."""
    initial_state: float | None = None
    """Initial state theta0 (s); default Dc / V0 (steady state at the reference velocity)."""
    dilation_angle: float = 0.0
    """Dilation angle (degrees); used with effects.dilation."""
    asperity_height_std: float = 0.0
    """sigma_h of Renshaw's aperture law (m); used with effects.aperture_evolution."""
    length: float | None = None
    """Length of a fault that ends in the rock (m), centred on ``point``; each tip is snapped to
    the nearest element edge along the fault (a warning gives the modelled length). Default:
    the fault crosses the whole model. Needs effects.leak_off = false."""


@_spec
class RockSpec:
    youngs_modulus: float = 31.3e9
    """Drained Young's modulus E (Pa)."""
    poissons_ratio: float = 0.30
    """Drained Poisson's ratio (-), in (-1, 0.5)."""
    biot_coefficient: float = 0.77
    """Biot coefficient alpha (-), in (porosity, 1]."""
    porosity: float = 0.148
    """Porosity n (-)."""
    permeability: float | None = 6.77e-19
    """Intrinsic permeability (m^2); the flow uses permeability / fluid viscosity."""
    mobility: float | None = None
    """Mobility k/mu (m^2/(Pa s)), instead of permeability (give one; from a file, giving
    mobility unsets permeability). The paper's k_f is written in m^3 s/kg: a mobility."""
    solid_bulk_modulus: float | None = None
    """Grain bulk modulus Ks (Pa); default K_drained / (1 - alpha), consistent with alpha."""
    density: float = 2364.0
    """Solid grain density (kg/m^3)."""

    def mobility_at(self, viscosity: float) -> float:
        """Darcy mobility (m^2/(Pa s)): ``mobility`` if given, else permeability / viscosity."""
        return self.mobility if self.mobility is not None else self.permeability / viscosity

    def with_overrides(self, overrides: dict) -> "RockSpec":
        """This rock with a zone's overrides; a zone's permeability replaces a mobility and
        vice versa (the most specific table decides how the flow property is given)."""
        over = dict(overrides)
        if "mobility" in over:
            over.setdefault("permeability", None)
        if "permeability" in over:
            over.setdefault("mobility", None)
        return dataclasses.replace(self, **over)


@_spec
class Zone:
    """A region with its own rock properties: a band around the fault or a box."""
    name: str = "zone"
    """Name of the zone in messages and in ``scene show``."""
    band: float | None = None
    """Half width of a band on both sides of the fault (m)."""
    box: tuple[float, float, float, float] | None = None
    """xmin, xmax, ymin, ymax (m)."""
    rock: dict = field(default_factory=dict)
    """Overrides of ``[rock]`` keys in this zone (same units)."""


@_spec
class DamageZoneSpec:
    """Damaged rock on both sides of the fault (effects.damage_zone); unset values: intact rock."""
    width: float = 50.0
    """Distance from the fault to the edge of the damage zone, on each side (m)."""
    youngs_modulus: float | None = None
    """Young's modulus in the damage zone (Pa)."""
    poissons_ratio: float | None = None
    """Poisson's ratio in the damage zone (-)."""
    permeability: float | None = None
    """Permeability in the damage zone (m^2)."""
    mobility: float | None = None
    """Mobility k/mu in the damage zone (m^2/(Pa s)), instead of permeability."""

    def rock_overrides(self) -> dict:
        """The ``[rock]`` keys this damage zone overrides (for ``RockSpec.with_overrides``)."""
        keys = ("youngs_modulus", "poissons_ratio", "permeability", "mobility")
        return {k: getattr(self, k) for k in keys if getattr(self, k) is not None}


@_spec
class FluidSpec:
    viscosity: float = 8.9e-4
    """Dynamic viscosity (Pa s)."""
    bulk_modulus: float = 2.15e9
    """Fluid bulk modulus Kf (Pa)."""
    density: float = 999.4
    """Fluid density (kg/m^3)."""


#: What an in-situ stress given in a scene means; each converts through the total stress sigma:
#: Biot-effective = sigma + alpha p0 (the rock's), fault-effective = sigma + p0 (the fault's,
#: Biot coefficient 1 on the fault).
STRESS_KINDS = ("total", "biot_effective", "fault_effective")


@_spec
class InitialSpec:
    stress: tuple[float, float, float] | None = None
    """In-situ stress sxx, syy, sxy at the reference point (Pa, tension positive), of the kind
    ``stress_kind`` names; give both together. Neither: no in-situ stress."""
    stress_kind: str | None = None
    """'total' (hydraulic fracturing tests, overcoring, regional models usually give these),
    'biot_effective' (sigma + alpha p0) or 'fault_effective' (sigma + p0: what the fault's
    effective normal stress is projected from, as in the paper's Eq. 19)."""
    effective_stress: tuple[float, float, float] | None = None
    """Older key, read as ``stress`` with ``stress_kind = "biot_effective"`` (Pa)."""
    pore_pressure: float = 0.0
    """Initial pore pressure at the reference point (Pa)."""
    reference_point: tuple[float, float] | None = None
    """Where effective_stress and pore_pressure hold (m); default: the injection point."""
    gravity: float = 9.81
    """Gravitational acceleration (m/s^2), with effects.gravity."""
    gravity_direction: tuple[float, float] = (0.0, -1.0)
    """Unit vector of gravity in model coordinates (rotate it with the model) (-)."""
    pore_pressure_gradient: float | None = None
    """Hydrostatic gradient along gravity (Pa/m); default fluid density * gravity."""
    lateral_stress_ratio: float | None = None
    """Effective-stress gradient across gravity over that along it (-); default nu/(1-nu)."""

    @property
    def stress_and_kind(self) -> tuple[tuple[float, float, float], str]:
        """The in-situ stress as given and its kind (the older key: Biot-effective)."""
        if self.stress is not None:
            return self.stress, self.stress_kind
        if self.effective_stress is not None:
            return self.effective_stress, "biot_effective"
        return (0.0, 0.0, 0.0), "biot_effective"


@_spec
class EdgeSpec:
    mechanical: str = "pinned"
    """'pinned' (both displacements fixed), 'roller' (normal fixed) or 'free'."""
    hydraulic: str = "no_flow"
    """'drained' (overpressure 0) or 'no_flow'."""
    traction: tuple[float, float] = (0.0, 0.0)
    """Change of applied traction tx, ty on a free or roller edge (Pa); applied from t > 0."""


@_spec
class BoundarySpec:
    bottom: EdgeSpec = EdgeSpec()
    right: EdgeSpec = EdgeSpec()
    top: EdgeSpec = EdgeSpec()
    left: EdgeSpec = EdgeSpec()


@_spec
class InjectionSpec:
    control: str = "rate"
    """'rate' (flow rate of the whole interval, m^3/s) or 'pressure' (overpressure, Pa)."""
    position: float = 0.0
    """Injection point along the fault from ``fault.point`` (m)."""
    number_of_fractures: float = 1.0
    """NoF: fractures sharing the interval's flow (Eq. 29); the model fault takes rate/NoF (-)."""
    schedule: tuple[tuple[float, float], ...] = ((0.0, 0.0),)
    """Steps (time s, value): value holds from its time to the next (m^3/s or Pa)."""
    log: str | None = None
    """An injection-rate log (CSV, see docs/injection-logs.md) that replaces the schedule under rate control;
    a relative path is taken from the scene file's folder. Model time 0 = its first stamp."""
    log_flow_unit: str | None = None
    """Flow-rate unit of the log when its header names none (e.g. 'L/min')."""
    log_max_gap: float = 600.0
    """Longest gap between log samples before it counts as a problem (s)."""
    log_policy: str = "stop"
    """What to do with a bad log line: 'stop', 'skip' or 'hold' (see docs/injection-logs.md)."""
    allow_flowback: bool = False
    """Accept negative flow rates (fluid produced back from the interval: flowback after
    shut-in) in the schedule and in volumes passed to the stepper; refused otherwise, so that a
    sign error in a schedule is caught."""


@_spec
class TimeSpec:
    end: float = 1400.0
    """End time (s)."""
    dt: float = 5.0
    """First time step (s)."""
    growth: float = 1.0
    """Each step is ``growth`` times the previous one (-), up to ``dt_max``."""
    dt_max: float | None = None
    """Largest step (s); default ``dt``."""
    theta: float = 1.0
    """Time integration weight of the flow terms: 1 backward Euler, 0.5 Crank-Nicolson (-)."""
    theta_min: float | None = None
    """Lowest time weight of the theta ladder (-), in [0.5, theta]; default off (theta fixed).
    When set, a step size that changes within a "rung" [dt0, dt0 theta / theta_min] (dt0 the
    rung's first step, taken at ``theta``) is taken at theta dt = theta dt0, so the poroelastic
    bulk's factors of dt0 serve it; a step outside starts a new rung. 2/3 keeps stiff modes
    damped by at least half a step. Only a bulk with rock pore pressure uses it."""


@_spec
class SolverSpec:
    tolerance: float = 1e-8
    """Newton converges when every field's scaled residual is below this fraction of its
    reference (-)."""
    max_iterations: int = 30
    """Newton iterations of a step before it counts as failed (-)."""
    max_step_cuts: int = 8
    """A step whose Newton iteration fails is halved and retried at most this often (-)."""
    first_guess: str = "previous"
    """The first Newton iterate of a step (-): 'previous', the state the step starts from;
    'extrapolated', the last three accepted states extrapolated to the step's end (quadratic in
    time; linear after the first step). Where the state evolves smoothly (a pressure front, slip
    from mid-injection) that starts Newton closer to the answer and saves iterations; a step
    whose extrapolated start fails is solved again from the previous state. Either converges to
    ``tolerance``."""
    unstable_slip_rate: float = 1e-3
    """Slip rate beyond which the fault counts as unstable (m/s): the quasi-static model cannot
    follow dynamic slip, so the run stops there, keeps every result up to that moment and says
    so (``Result.meta["stopped"]``; the CLI exits with code 3). 1 mm/s is the usual onset of
    seismic slip in earthquake-cycle models (e.g. the SCEC SEAS benchmarks, Erickson et al.
    2020), the same figure as the screening default ``monitor.slip_rate_red``. This is a limit of
    the model, not a screening threshold."""


@_spec
class EffectsSpec:
    fault: bool = True
    """An embedded fault (enrichment, contact, fault flow, injection); off = intact rock."""
    mechanics: bool = True
    """Deformable rock and fault contact; off = rigid rock (no displacement unknowns)."""
    poroelastic: bool = True
    """Pore pressure in the rock (Biot); off = impermeable rock, pressure lives on the fault only."""
    leak_off: bool = True
    """Fault and rock share the pressure field (enriched), so fluid leaks off into the rock."""
    fault_flow: bool = True
    """Flow along the fault (cubic law) and fault storage."""
    rate_friction: bool = False
    """Friction mu0 + a ln(V/V0) (regularised); off = constant Coulomb friction mu0."""
    state_evolution: bool = False
    """Rate-and-state friction with the aging law (b, Dc); needs rate_friction."""
    dilation: bool = False
    """Normal opening from shear slip through the dilation angle (Eq. 21)."""
    aperture_evolution: bool = False
    """Hydraulic aperture from the mechanical opening (Renshaw, Eq. 28); off = constant 2h0."""
    gravity: bool = False
    """Body force and depth-dependent in-situ stress and hydrostatic pore pressure."""
    damage_zone: bool = False
    """A band of damaged rock on both sides of the fault, properties from [damage_zone]."""


@_spec
class MonitorRule:
    """One screening rule of ``[[monitor.rules]]``: while ``when`` holds, the level is at least
    ``level``; it is released ``hold`` seconds after ``when`` last held."""
    level: str
    """'yellow' or 'red' (green is the absence of any rule in force)."""
    when: str
    """Condition over the screening metrics and the [monitor] thresholds, e.g.
    ``"max_utilisation > utilisation_yellow"`` (grammar: fault_screen.rules; SI values)."""
    hold: float = 600.0
    """Time the rule stays in force after its condition last held (s): a level does not flicker
    when a metric oscillates about a threshold. Default 10 min, 120 steps of the bundled scenes."""
    action: str = ""
    """What the operator should do, shown with the verdict and in alerts."""
    name: str | None = None
    """Name in transitions and messages; default ``rules[i]``."""


_DEFAULT_ACTION_RED = "stop injection and bleed off; inform the regulator"
_DEFAULT_ACTION_YELLOW = "reduce the injection rate by half and watch the fault closely"


@_spec
class MonitorSpec:
    """Screening thresholds and rules (``[monitor]``): the one place for screening thresholds.

    Rules may name every threshold below as well as the metrics (fault_screen.rules.METRICS)."""
    slip_rate_yellow: float = 1e-6
    """Peak slip rate that means the fault is sliding (m/s): 1 um/s is ~1000 times tectonic
    creep (mm to cm a year, ~1e-10 to 1e-9 m/s) and a million times below seismic slip (~1 m/s);
    the aseismic slip Guglielmi et al. (2015) measured at Rustrel reached a few um/s."""
    slip_rate_red: float = 1e-3
    """Peak slip rate that means the slip is becoming dynamic (m/s): 1 mm/s is the usual onset of
    seismic slip in earthquake-cycle models (e.g. the SCEC SEAS benchmarks, Erickson et al. 2020),
    beyond which a quasi-static model no longer holds."""
    utilisation_yellow: float = 0.9
    """Fraction of the frictional strength mu0 sigma'_n that the shear stress uses (-) at which a
    point is close to failure: a 10 % margin, the usual reactivation screening margin."""
    magnitude_yellow: float = 2.0
    """Event magnitude of the amber light (ML): Alberta AER Subsurface Order No. 2 (Duvernay, 2015)
    ML 2.0 report and reduce (and ML 4.0 stop); Oklahoma OCC protocol ML 2.5 review, 3.0 pause."""
    magnitude_red: float = 2.9
    """Event magnitude of the red light (ML): Basel 2006 stop level (ML 2.9); Oklahoma suspends at
    ML 3.5; the UK shale-gas protocol (2011) pauses at ML 0.5: set it lower for shallow sites."""
    event_rate_window: float = 3600.0
    """Trailing window of the event_rate metric (s); event_rate is in events per hour, so the
    default of 1 h counts the events of the last hour as they are."""
    rules: tuple[MonitorRule, ...] = (
        MonitorRule(level="red", name="dynamic slip", when="peak_slip_rate > slip_rate_red",
                    hold=3600.0, action=_DEFAULT_ACTION_RED),
        MonitorRule(level="red", name="large event", when="event_magnitude >= magnitude_red",
                    hold=3600.0, action=_DEFAULT_ACTION_RED),
        MonitorRule(level="yellow", name="fault sliding", when="peak_slip_rate > slip_rate_yellow",
                    action=_DEFAULT_ACTION_YELLOW),
        MonitorRule(level="yellow", name="near failure", when="max_utilisation > utilisation_yellow",
                    action=_DEFAULT_ACTION_YELLOW),
        MonitorRule(level="yellow", name="felt-size event", when="event_magnitude >= magnitude_yellow",
                    action=_DEFAULT_ACTION_YELLOW),
    )
    """Ordered rules; the highest level in force wins, the first rule of that level names it.
    Default holds: red 1 h (a red light stands until reviewed), yellow 10 min."""


@_spec
class SiteSpec:
    """Where the model is in the seismic catalogue's frame, for event distances: the injection
    point either geographic (latitude, longitude, depth) or local (x, y and z or depth, the
    catalogue's metres: x east, y north, z up), and the modelled fault's orientation."""
    latitude: float | None = None
    """Latitude of the injection point (degrees north)."""
    longitude: float | None = None
    """Longitude of the injection point (degrees east)."""
    depth: float | None = None
    """Depth of the injection point below the catalogue's datum (m, positive down)."""
    x: float | None = None
    """Local easting of the injection point in the catalogue's frame (m)."""
    y: float | None = None
    """Local northing of the injection point in the catalogue's frame (m)."""
    z: float | None = None
    """Local elevation of the injection point in the catalogue's frame (m, up)."""
    strike: float | None = None
    """Strike of the fault plane, clockwise from north (degrees)."""
    dip: float | None = None
    """Dip of the fault plane, down to the right of the strike (degrees)."""


@_spec
class OutputSpec:
    """How often the full fault profiles ((time, x) arrays under ``/fault``) are recorded
    (``[output]``). The injection-point series, the fluid balance, the solver record and the
    screening metrics are recorded at every step whatever this says. With neither key set
    (the default) profiles are recorded at every step of a result kept in memory, and by the
    automatic rule of :mod:`fault_screen.outputs` in a result streamed to its file (run,
    replay, monitor: every step for the first 512 steps, then ever more sparsely;
    ``profile_every = 1`` keeps every step); with one or both, a profile is recorded
    when either is due, and always at the first and the last step and at every change of the
    screening level (run, replay, monitor). ``/fault/time`` holds the profiles' own times."""
    profile_every: int | None = None
    """Record the profiles every this many steps (-)."""
    profile_interval: float | None = None
    """Record the profiles at least every this long in model time (s)."""


@_spec
class Scene:
    title: str = "untitled"
    """What the scene models, shown in summaries and stored with results."""
    mesh: MeshSpec = MeshSpec()
    fault: FaultSpec = FaultSpec()
    rock: RockSpec = RockSpec()
    zones: tuple[Zone, ...] = ()
    damage_zone: DamageZoneSpec = DamageZoneSpec()
    fluid: FluidSpec = FluidSpec()
    initial: InitialSpec = InitialSpec()
    boundary: BoundarySpec = BoundarySpec()
    injection: InjectionSpec = InjectionSpec()
    time: TimeSpec = TimeSpec()
    solver: SolverSpec = SolverSpec()
    effects: EffectsSpec = EffectsSpec()
    monitor: MonitorSpec = MonitorSpec()
    site: SiteSpec = SiteSpec()
    output: OutputSpec = OutputSpec()

    # ---- loading -------------------------------------------------------------------------
    @classmethod
    def from_toml(cls, path) -> "Scene":
        path = Path(path)
        try:
            data = loads_toml(path.read_bytes(), str(path))
        except FileNotFoundError:
            raise SceneError(f"scene file not found: {path}") from None
        except (OSError, ValueError) as exc:  # a folder, no permission, a NUL in the path
            raise SceneError(f"{_shown(str(path))}: cannot read the scene file: "
                             f"{getattr(exc, 'strerror', None) or exc}") from None
        return cls.from_dict(data, base_dir=path.resolve().parent)

    @classmethod
    def from_toml_text(cls, text: str | bytes, base_dir=None, name: str = "scene") -> "Scene":
        """A scene from TOML text (``name`` names it in errors)."""
        return cls.from_dict(loads_toml(text, name), base_dir=base_dir)

    @classmethod
    def from_dict(cls, data: dict, base_dir=None) -> "Scene":
        """``base_dir``: folder that relative paths in the scene (injection.log) start from."""
        scene = _build(cls, data, "")
        if scene.injection.log is not None and base_dir is not None:
            log = Path(base_dir) / scene.injection.log
            scene = dataclasses.replace(scene, injection=dataclasses.replace(scene.injection, log=str(log)))
        sink: list = []
        _validate(scene, sink)
        for text in sink:
            warnings.warn(text, SceneWarning, stacklevel=2)
        return scene

    def plausibility(self) -> list[str]:
        """Warnings for the values outside their plausible range (see ``RANGES``)."""
        sink: list = []
        _validate(self, sink)
        return sink

    def replace(self, **changes) -> "Scene":
        """A copy with top-level sections replaced (validated)."""
        new = dataclasses.replace(self, **changes)
        _validate(new)
        return new

    def to_dict(self) -> dict:
        return _to_plain(self)

    def to_toml(self) -> str:
        return dumps_toml(self.to_dict())

    # ---- derived quantities --------------------------------------------------------------
    def flow_summary(self) -> list[str]:
        """One line per rock region: its permeability and mobility at this scene's viscosity
        (both printed whichever was given), e.g. for ``scene show``."""
        mu = self.fluid.viscosity
        regions = [("rock", self.rock)]
        if self.effects.damage_zone:
            regions.append(("damage_zone", self.rock.with_overrides(self.damage_zone.rock_overrides())))
        regions += [(f"zones[{i}] ({z.name})", self.rock.with_overrides(z.rock)) for i, z in enumerate(self.zones)]
        lines = []
        for name, rock in regions:
            m = rock.mobility_at(mu)
            given = "mobility" if rock.mobility is not None else "permeability"
            lines.append(f"{name}: permeability {m * mu:.6g} m2, mobility {m:.6g} m2/(Pa s) "
                         f"(given as {given}; viscosity {mu:g} Pa s)")
        return lines

    @property
    def fault_point(self) -> tuple[float, float]:
        if self.fault.point is not None:
            return self.fault.point
        m = self.mesh
        return (m.origin[0] + 0.5 * m.lx, m.origin[1] + 0.5 * m.ly)


def loads_toml(text: str | bytes, name: str = "scene") -> dict:
    """The table of TOML ``text`` (bytes must be UTF-8); SceneError naming ``name`` otherwise."""
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise SceneError(f"{name}: not UTF-8 text (byte {exc.start}: {text[exc.start:exc.start + 1]!r}); "
                             f"save the scene as UTF-8") from None
    try:
        return tomllib.loads(text)
    except ValueError as exc:  # TOMLDecodeError, or an integer of more digits than Python converts
        raise SceneError(f"{name}: not valid TOML: {exc}") from None
    except RecursionError:
        raise SceneError(f"{name}: arrays or tables nested too deeply to read") from None


def _shown(value) -> str:
    """``repr(value)`` cut short: a bad value in a message stays one readable line whatever its
    size or nesting."""
    return _SHORT_REPR.repr(value)


_SHORT_REPR = reprlib.Repr()
_SHORT_REPR.maxlevel, _SHORT_REPR.maxstring, _SHORT_REPR.maxother = 3, 120, 120
_SHORT_REPR.maxlist = _SHORT_REPR.maxtuple = _SHORT_REPR.maxdict = 12
#: the largest integer a scene takes (|n|); every int is used as a float somewhere
LARGEST_INT = 2 ** 53


#: the units a field's docstring may give, in parentheses: SI (angles in degrees, magnitudes in
#: their own scale); "-" is dimensionless
DOC_UNITS = frozenset({"-", "m", "m^2", "m/s", "m/s^2", "s", "Pa", "Pa/m", "Pa s", "m/Pa", "m^2/(Pa s)",
                       "kg/m^3", "degrees", "degrees north", "degrees east", "ML"})


def _paren_groups(text: str) -> list[str]:
    """The contents of the outermost parentheses of ``text``, in order."""
    groups, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        if ch == "(":
            depth += 1
            if depth == 1:
                start = i + 1
        elif ch == ")" and depth:
            depth -= 1
            if depth == 0:
                groups.append(text[start:i])
    return groups


@functools.cache
def field_docs() -> dict:
    """(section class name, field name) -> the field's docstring (the string literal after it
    in this module's source)."""
    import ast

    docs = {}
    for node in ast.parse(Path(__file__).read_text(encoding="utf-8")).body:
        if not isinstance(node, ast.ClassDef):
            continue
        for field_node, after in zip(node.body, node.body[1:]):
            if (isinstance(field_node, ast.AnnAssign) and isinstance(after, ast.Expr)
                    and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)):
                docs[(node.name, field_node.target.id)] = " ".join(after.value.value.split())
    return docs


def field_unit(cls, name: str) -> str | None:
    """The SI unit a field's docstring gives: the first parenthesised group (before a comma)
    that is one of ``DOC_UNITS``; None when it gives none (text and switches)."""
    for group in _paren_groups(field_docs().get((cls.__name__, name), "")):
        head = group.split(",")[0].strip()
        if head in DOC_UNITS:
            return head
    return None


def _to_plain(obj):
    if dataclasses.is_dataclass(obj):
        out = {}
        for f in fields(obj):
            v = getattr(obj, f.name)
            if v is None:
                continue
            out[f.name] = _to_plain(v)
        return out
    if isinstance(obj, (tuple, list)):
        return [_to_plain(v) for v in obj]
    if isinstance(obj, dict):
        return {k: _to_plain(v) for k, v in obj.items()}
    return obj


#: What each dimensional field measures, so that values may carry units (see ``units.py``):
#: as a key suffix, ``"youngs_modulus[GPa]" = 29.2``, or in a string, ``youngs_modulus = "29.2 GPa"``.
QUANTITY = {
    **dict.fromkeys(["youngs_modulus", "solid_bulk_modulus", "bulk_modulus", "effective_stress", "stress",
                     "pore_pressure", "traction"], "pressure"),
    **dict.fromkeys(["normal_stiffness", "shear_stiffness", "pore_pressure_gradient"], "stiffness"),
    **dict.fromkeys(["lx", "ly", "origin", "center", "half_width", "size", "point",
                     "hydraulic_aperture", "critical_slip_distance", "asperity_height_std", "width",
                     "band", "box", "position", "reference_point", "length"], "length"),
    "permeability": "permeability",
    "mobility": "mobility",
    **dict.fromkeys(["end", "dt", "dt_max", "initial_state", "log_max_gap"], "time"),
    **dict.fromkeys(["hold", "event_rate_window"], "time"),
    "profile_interval": "time",
    "viscosity": "viscosity",
    **dict.fromkeys(["angle", "dilation_angle", "latitude", "longitude", "strike", "dip"], "angle"),
    **dict.fromkeys(["depth", "x", "y", "z"], "length"),
}
_UNIT_KEY = re.compile(r"^\s*([A-Za-z_][A-Za-z0-9_]*)\s*\[(.+)\]\s*$")


#: keys that moved, with where they went
MOVED_KEYS = {
    "fault.slip_rate_threshold": "screening thresholds are set in [monitor] (slip_rate_yellow, "
                                 "slip_rate_red and the rules); the contact state counts a point as "
                                 "sliding above 1e-9 m/s (fault_screen.physics.contact.SLIDING_SLIP_RATE)",
}


def _build(cls, data, where):
    if not isinstance(data, dict):
        raise SceneError(f"[{where or 'scene'}] must be a table, got {_shown(data)}")
    known = {f.name: f for f in fields(cls)}
    hints = {f.name: f.type for f in fields(cls)}
    kwargs = {}
    for raw, value in data.items():
        m = _UNIT_KEY.match(raw)
        name, unit = (m.group(1), m.group(2).strip()) if m else (raw, None)
        if _key(where, name) in MOVED_KEYS:
            raise SceneError(f"{_key(where, raw)} = {_shown(value)} is no longer read: "
                             f"{MOVED_KEYS[_key(where, name)]}")
        if name not in known and isinstance(value, dict):
            tables = sorted(k for k, f in known.items() if str(f.type).replace(" | None", "") in _SECTIONS
                            or k == "zones")
            raise SceneError(f"unknown section [{_key(where, raw)}]; known sections"
                             f"{' in [' + where + ']' if where else ''}: {', '.join(tables)}")
        if name not in known:
            raise SceneError(f"unknown key {_key(where, raw)!s} = {_shown(value)}; "
                             f"known keys in [{where or 'scene'}]: {', '.join(sorted(known))}")
        if name in kwargs:
            raise SceneError(f"{_key(where, name)} is given twice (with and without a unit)")
        quantity = QUANTITY.get(name)
        if name == "schedule":
            quantity = "pressure" if data.get("control") == "pressure" else "flow_rate"
        if unit is not None and quantity is None:
            raise SceneError(f"{_key(where, raw)}: {name} takes no unit")
        kwargs[name] = _coerce(hints[name], value, _key(where, raw), quantity, unit)
    _one_flow_property(kwargs, where)
    if cls is RockSpec and "mobility" in kwargs:
        kwargs.setdefault("permeability", None)
    missing = [f.name for f in fields(cls) if f.name not in kwargs
               and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if missing:
        raise SceneError(f"{_key(where, missing[0])} is missing: [{where or 'scene'}] needs "
                         f"{', '.join(missing)}")
    return cls(**kwargs)


def _one_flow_property(table: dict, where: str):
    """Permeability (m^2, divided by the viscosity) and mobility (m^2/(Pa s)) say the same thing
    two ways: a table may give one of them only."""
    if "permeability" in table and "mobility" in table:
        raise SceneError(f"[{where or 'scene'}] gives both permeability = {_shown(table['permeability'])} "
                         f"and mobility = {_shown(table['mobility'])}; give one (mobility = "
                         f"permeability / fluid viscosity)")


def _key(where, name):
    if len(name) > 64 or not name.isprintable():
        name = _shown(name)  # a key as TOML quotes it may hold anything: one line in messages
    return f"{where}.{name}" if where else name


_SECTIONS = {}


def _coerce(hint, value, key, quantity=None, unit=None):
    hint = str(hint)
    base = hint.replace(" | None", "")
    if base in _SECTIONS:
        return _build(_SECTIONS[base], value, key)
    if base == "tuple[Zone, ...]":
        if not isinstance(value, list):
            raise SceneError(f"{key} must be an array of tables ([[zones]]), got {_shown(value)}")
        return tuple(_build(Zone, v, f"{key}[{i}]") for i, v in enumerate(value))
    if base == "tuple[MonitorRule, ...]":
        if not isinstance(value, list):
            raise SceneError(f"{key} must be an array of tables ([[monitor.rules]]), got {_shown(value)}")
        return tuple(_build(MonitorRule, v, f"{key}[{i}]") for i, v in enumerate(value))
    if base == "bool":
        if not isinstance(value, bool):
            raise SceneError(f"{key} = {_shown(value)} must be true or false")
        return value
    if base == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneError(f"{key} = {_shown(value)} must be an integer")
        if abs(value) > LARGEST_INT:
            raise SceneError(f"{key} = {_shown(value)} must be an integer of at most {LARGEST_INT}")
        return value
    if base == "float":
        return _number(value, key, quantity, unit)
    if base == "str":
        if not isinstance(value, str):
            raise SceneError(f"{key} = {_shown(value)} must be a string")
        return value
    if base == "dict":  # rock overrides of a zone: same keys (and units) as [rock]
        if not isinstance(value, dict):
            raise SceneError(f"{key} = {_shown(value)} must be a table")
        out = {}
        for raw, v in value.items():
            m = _UNIT_KEY.match(raw)
            name, u = (m.group(1), m.group(2).strip()) if m else (raw, None)
            out[name] = _number(v, f"{key}.{raw}", QUANTITY.get(name), u) if name in QUANTITY or u else v
        _one_flow_property(out, key)
        return out
    if base.startswith("tuple[tuple[float, float]"):
        if not isinstance(value, list) or not value:
            raise SceneError(f"{key} = {_shown(value)} must be a non-empty array of [time, value] pairs")
        out = []
        for i, pair in enumerate(value):
            if not isinstance(pair, list) or len(pair) != 2:
                raise SceneError(f"{key}[{i}] = {_shown(pair)} must be a [time, value] pair")
            out.append((_number(pair[0], f"{key}[{i}][0]", "time"),
                        _number(pair[1], f"{key}[{i}][1]", quantity, unit)))
        return tuple(out)
    if base.startswith("tuple[float"):
        n = base.count("float")
        if not isinstance(value, list) or len(value) != n:
            raise SceneError(f"{key} = {_shown(value)} must be an array of {n} numbers")
        return tuple(_number(v, f"{key}[{i}]", quantity, unit) for i, v in enumerate(value))
    raise SceneError(f"{key}: cannot read {_shown(value)}")  # pragma: no cover - schema error


def _number(value, key, quantity=None, unit=None):
    """A float in SI (angles in degrees) from a number, or a "number unit" string."""
    text = value
    if isinstance(value, str):
        try:
            value, written = units.split_value(value)   # "100 mD" and "100mD" alike
        except ValueError:
            raise SceneError(f"{key} = {_shown(text)} must be a number, optionally with a unit "
                             f"(\"29.2 GPa\")") from None
        if written is not None:
            if unit is not None:
                raise SceneError(f"{key} = {_shown(text)}: the unit is already given in the key")
            if quantity is None:
                raise SceneError(f"{key} = {_shown(text)}: this value takes no unit")
            unit = written
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(f"{key} = {_shown(text)} must be a number (SI units unless a unit is given)")
    if isinstance(value, int) and abs(value) > LARGEST_INT:
        raise SceneError(f"{key} = {_shown(text)} is beyond the range of numbers a scene takes "
                         f"(write it as a float, e.g. 1e20)")
    if not math.isfinite(value):
        raise SceneError(f"{key} = {_shown(text)} must be finite")
    if unit is None:
        return float(value)
    try:
        si = float(units.to_si(float(value), unit, quantity))
    except units.UnitError as exc:
        raise SceneError(f"{key} = {_shown(text)}: {exc}") from None
    if not math.isfinite(si):
        raise SceneError(f"{key} = {_shown(text)} is beyond the float range in SI units")
    return math.degrees(si) if quantity == "angle" else si


for _cls in (Refinement, MeshSpec, FaultSpec, RockSpec, DamageZoneSpec, FluidSpec, InitialSpec, EdgeSpec,
             BoundarySpec, InjectionSpec, TimeSpec, SolverSpec, EffectsSpec, MonitorRule, MonitorSpec,
             SiteSpec, OutputSpec):
    _SECTIONS[_cls.__name__] = _cls


#: Every physical parameter's range, in SI (angles in degrees): key -> (unit, physical range,
#: plausible range).  Outside the physical range a scene is refused (the value cannot describe
#: rock, fluid or an operation); outside the plausible range it is accepted with a warning
#: (possible, but usually a unit slip).  Bounds are inclusive; strict positivity and the
#: coupled bounds (Biot coefficient above porosity, ...) are checked in ``_validate``.
#: ``rock.*`` also applies to ``zones[i].rock`` and ``damage_zone``.
RANGES: dict[str, tuple[str, tuple, tuple]] = {
    "mesh.lx": ("m", (0.0, 1e6), (0.1, 1e5)),
    "mesh.ly": ("m", (0.0, 1e6), (0.1, 1e5)),
    "fault.angle": ("deg", (-360.0, 360.0), (-180.0, 180.0)),
    "fault.normal_stiffness": ("Pa/m", (0.0, 1e16), (1e8, 1e13)),
    "fault.shear_stiffness": ("Pa/m", (0.0, 1e16), (1e8, 1e13)),
    "fault.friction": ("-", (0.0, 2.0), (0.2, 1.0)),
    "fault.hydraulic_aperture": ("m", (0.0, 0.1), (1e-7, 1e-2)),
    "fault.kappa": ("-", (0.0, 1e6), (1.0, 100.0)),
    "fault.storativity": ("m/Pa", (0.0, 1e-6), (1e-17, 1e-8)),
    "fault.rate_parameter": ("-", (0.0, 1.0), (0.0, 0.05)),
    "fault.state_parameter": ("-", (0.0, 1.0), (0.0, 0.05)),
    "fault.reference_velocity": ("m/s", (0.0, 1.0), (1e-12, 1e-3)),
    "fault.critical_slip_distance": ("m", (0.0, 10.0), (1e-7, 0.1)),
    "fault.dilation_angle": ("deg", (0.0, 90.0), (0.0, 30.0)),
    "fault.asperity_height_std": ("m", (0.0, 0.1), (0.0, 1e-3)),
    "fault.slip_rate_threshold": ("m/s", (0.0, 1.0), (1e-12, 1e-3)),
    "rock.youngs_modulus": ("Pa", (0.0, 1e12), (1e8, 1.5e11)),
    "rock.poissons_ratio": ("-", (-1.0, 0.5), (0.0, 0.45)),
    "rock.biot_coefficient": ("-", (0.0, 1.0), (0.3, 1.0)),
    "rock.porosity": ("-", (0.0, 1.0), (0.0, 0.5)),
    "rock.permeability": ("m2", (0.0, 1e-7), (0.0, 1e-10)),
    # mobility k/mu: the permeability ranges over water's viscosity at reservoir temperatures (~1e-3 Pa s)
    "rock.mobility": ("m2/(Pa s)", (0.0, 1e-4), (0.0, 1e-7)),
    "rock.solid_bulk_modulus": ("Pa", (0.0, 1e12), (1e9, 1e11)),
    "rock.density": ("kg/m3", (0.0, 2e4), (1500.0, 5000.0)),
    "damage_zone.width": ("m", (0.0, 1e5), (0.0, 1e4)),
    "fluid.viscosity": ("Pa s", (0.0, 1e3), (1e-5, 1.0)),
    "fluid.bulk_modulus": ("Pa", (0.0, 1e11), (1e7, 5e9)),
    "fluid.density": ("kg/m3", (0.0, 2e4), (100.0, 1500.0)),
    "initial.effective_stress": ("Pa", (-1e10, 1e10), (-3e8, 3e7)),
    "initial.stress": ("Pa", (-1e10, 1e10), (-3e8, 3e7)),
    "initial.pore_pressure": ("Pa", (-1e8, 1e10), (-1e6, 3e8)),
    "initial.gravity": ("m/s2", (0.0, 100.0), (0.0, 30.0)),
    "initial.pore_pressure_gradient": ("Pa/m", (-1e6, 1e6), (0.0, 3e4)),
    "initial.lateral_stress_ratio": ("-", (0.0, 100.0), (0.1, 10.0)),
    "boundary.traction": ("Pa", (-1e10, 1e10), (-3e8, 3e8)),
    # Rustrel 2015: 46-120 within one SD (Tables 1-2); 2 SD of its log-normal spread reach ~220
    "injection.number_of_fractures": ("-", (1.0, 1e4), (1.0, 300.0)),
    # the same bound as an injection log's flow rate (fault_screen.io.injection_log)
    "injection.schedule.rate": ("m3/s", (0.0, 10.0), (0.0, 1.0)),
    "injection.schedule.flowback_rate": ("m3/s", (-10.0, 10.0), (-1.0, 1.0)),
    "injection.schedule.pressure": ("Pa", (-1e9, 1e9), (-1e8, 1e8)),
    "injection.log_max_gap": ("s", (0.0, 1e9), (1.0, 86400.0)),
    "time.end": ("s", (0.0, 1e12), (1e-3, 3.2e9)),
    "time.dt": ("s", (0.0, 1e12), (1e-3, 3.2e8)),
    "time.growth": ("-", (1.0, 10.0), (1.0, 2.0)),
    "solver.tolerance": ("-", (0.0, 1.0), (1e-14, 1e-4)),
    "site.latitude": ("deg", (-90.0, 90.0), (-90.0, 90.0)),
    "site.longitude": ("deg", (-180.0, 360.0), (-180.0, 360.0)),
    "site.depth": ("m", (-1e4, 1e5), (-5e3, 1.5e4)),
    "site.strike": ("deg", (0.0, 360.0), (0.0, 360.0)),
    "site.dip": ("deg", (0.0, 90.0), (0.0, 90.0)),
}


def _fmt(v: float) -> str:
    return f"{v:g}"


def _in_range(key: str, value, where: str | None = None, sink: list | None = None):
    """Refuse ``value`` outside the physical range of ``key``; add a warning to ``sink``
    outside the plausible range.  ``where`` is the key as the user wrote its section."""
    unit, (plo, phi), (qlo, qhi) = RANGES[key]
    name = where or key
    values = value if isinstance(value, (tuple, list)) else (value,)
    u = "" if unit == "-" else f" {unit}"
    for v in values:
        if v is None:
            continue
        if not plo <= v <= phi:
            raise SceneError(f"{name} = {_shown(value)}: outside the physical range {_fmt(plo)} to "
                             f"{_fmt(phi)}{u} (plausible: {_fmt(qlo)} to {_fmt(qhi)}{u})")
    if sink is not None:
        for v in values:
            if v is not None and not qlo <= v <= qhi:
                sink.append(f"{name} = {_shown(value)} is outside the plausible range {_fmt(qlo)} to "
                            f"{_fmt(qhi)}{u}: accepted, but check the value and its unit")
                break


def _check(ok, key, value, why):
    if not ok:
        raise SceneError(f"{key} = {_shown(value)}: {why}")


def _validate_rock(rock: RockSpec, where: str, sink: list | None = None, keys=None):
    """``keys``: the keys to range-check (default all; a zone checks only its overrides, so a
    value of [rock] is not reported once more for every zone)."""
    for name in (keys if keys is not None else [fl.name for fl in fields(RockSpec)]):
        _in_range(f"rock.{name}", getattr(rock, name), f"{where}.{name}", sink)
    _check(rock.youngs_modulus > 0, f"{where}.youngs_modulus", rock.youngs_modulus, "must be > 0 Pa")
    _check(-1.0 < rock.poissons_ratio < 0.5, f"{where}.poissons_ratio", rock.poissons_ratio,
           "must be in (-1, 0.5)")
    _check(0.0 <= rock.porosity < 1.0, f"{where}.porosity", rock.porosity, "must be in [0, 1)")
    _check(rock.porosity <= rock.biot_coefficient <= 1.0, f"{where}.biot_coefficient",
           rock.biot_coefficient, f"must be in [porosity = {rock.porosity}, 1]")
    if rock.mobility is not None:
        _check(rock.mobility >= 0, f"{where}.mobility", rock.mobility, "must be >= 0 m^2/(Pa s)")
    else:
        _check(rock.permeability is not None, f"{where}.permeability", rock.permeability,
               "give a permeability (m^2) or a mobility (m^2/(Pa s))")
        _check(rock.permeability >= 0, f"{where}.permeability", rock.permeability, "must be >= 0 m^2")
    _check(rock.density >= 0, f"{where}.density", rock.density, "must be >= 0 kg/m^3")
    if rock.solid_bulk_modulus is not None:
        _check(rock.solid_bulk_modulus > 0, f"{where}.solid_bulk_modulus", rock.solid_bulk_modulus,
               "must be > 0 Pa")


def _validate_site(site: SiteSpec):
    geo = [k for k in ("latitude", "longitude") if getattr(site, k) is not None]
    loc = [k for k in ("x", "y") if getattr(site, k) is not None]
    _check(len(geo) in (0, 2), f"site.{'longitude' if 'latitude' in geo else 'latitude'}", None,
           "give both latitude and longitude")
    _check(len(loc) in (0, 2), f"site.{'y' if 'x' in loc else 'x'}", None, "give both x and y")
    _check(not (geo and loc), "site", "latitude/longitude and x/y",
           "give the injection point in one frame: latitude/longitude/depth or local x/y/z")
    _check(not (geo and site.z is not None), "site.z", site.z,
           "z is for local x/y frames; with latitude/longitude give depth (m, positive down)")
    _check(site.z is None or site.depth is None, "site.z", site.z, "give z (up) or depth (down), not both")
    _check((site.strike is None) == (site.dip is None), "site.strike" if site.dip is not None else "site.dip",
           None, "give both strike and dip of the fault plane")


def _validate(s: Scene, sink: list | None = None):
    """Refuse what cannot be simulated; append plausibility warnings to ``sink``. One validator
    per section, then those of the switch combinations, in a fixed order (the first error wins)."""
    _validate_ranges(s, sink)
    _validate_site(s.site)
    _validate_mesh(s.mesh)
    _validate_fault(s)
    _validate_rock(s.rock, "rock", sink)
    _validate_zones(s, sink)
    _validate_fluid(s.fluid)
    _validate_boundary(s.boundary)
    _validate_injection(s.injection)
    _validate_time(s.time)
    _validate_solver(s.solver)
    _validate_friction(s.fault, s.effects)
    _validate_initial(s)
    _validate_damage_zone(s, sink)
    _validate_effects(s.effects, s.injection)
    _validate_monitor(s.monitor)
    _validate_output(s.output)


def _validate_ranges(s: Scene, sink: list | None):
    """Every value with an entry in ``RANGES``: refused outside its physical range, a warning in
    ``sink`` outside its plausible one."""
    for section in ("mesh", "fault", "fluid", "initial", "injection", "time", "solver",
                    "damage_zone", "site"):
        spec = getattr(s, section)
        for fl in fields(spec):
            key = f"{section}.{fl.name}"
            if key in RANGES:
                _in_range(key, getattr(spec, fl.name), None, sink)
    for edge in EDGES:
        _in_range("boundary.traction", getattr(s.boundary, edge).traction,
                  f"boundary.{edge}.traction", sink)
    which = "rate" if s.injection.control == "rate" else "pressure"
    if which == "rate" and any(v < 0 for _, v in s.injection.schedule):
        which = "flowback_rate"  # the sign is checked with injection.allow_flowback
    _in_range(f"injection.schedule.{which}", tuple(v for _, v in s.injection.schedule),
              "injection.schedule", sink)


def _validate_mesh(m: MeshSpec):
    _check(m.nx >= 1, "mesh.nx", m.nx, "must be >= 1")
    _check(m.ny >= 1, "mesh.ny", m.ny, "must be >= 1")
    _check(m.lx > 0, "mesh.lx", m.lx, "must be > 0 m")
    _check(m.ly > 0, "mesh.ly", m.ly, "must be > 0 m")
    if m.refinement is not None:
        r = m.refinement
        _check(r.size > 0, "mesh.refinement.size", r.size, "must be > 0 m")
        _check(1.0 <= r.growth <= 2.0, "mesh.refinement.growth", r.growth, "must be in [1, 2]")
        _check(min(r.half_width) >= 0, "mesh.refinement.half_width", r.half_width, "must be >= 0 m")
        x0, y0 = m.origin
        _check(_in_domain(m, r.center), "mesh.refinement.center", r.center,
               f"must lie in the domain [{x0}, {x0 + m.lx}] x [{y0}, {y0 + m.ly}] m")
    _check(m.fault_grading in ("auto", "off"), "mesh.fault_grading", m.fault_grading, "must be 'auto' or 'off'")
    _check(m.fault_grading_size is None or m.fault_grading_size > 0, "mesh.fault_grading_size",
           m.fault_grading_size, "must be > 0 m")
    _check(1.0 < m.fault_grading_growth <= 2.0, "mesh.fault_grading_growth", m.fault_grading_growth,
           "must be in (1, 2]")


def _in_domain(m: MeshSpec, point) -> bool:
    x0, y0 = m.origin
    return x0 <= point[0] <= x0 + m.lx and y0 <= point[1] <= y0 + m.ly


def _validate_fault(s: Scene):
    f, m = s.fault, s.mesh
    x0, y0 = m.origin
    _check(_in_domain(m, s.fault_point), "fault.point", f.point,
           f"must lie in the domain [{x0}, {x0 + m.lx}] x [{y0}, {y0 + m.ly}] m")
    for key in ("normal_stiffness", "shear_stiffness", "hydraulic_aperture", "kappa"):
        _check(getattr(f, key) > 0, f"fault.{key}", getattr(f, key), "must be > 0")
    _check(f.friction >= 0, "fault.friction", f.friction, "must be >= 0")
    if f.length is not None:
        _check(f.length > 0, "fault.length", f.length, "must be > 0 m")
        _check(not s.effects.leak_off, "fault.length", f.length,
               "a fault that ends in the rock needs effects.leak_off = false (its pressure on its own "
               "line; the leak-off enrichment has no tip treatment)")
    if f.storativity is not None:
        _check(f.storativity >= 0, "fault.storativity", f.storativity, "must be >= 0 m/Pa")


def _validate_zones(s: Scene, sink: list | None):
    rock_keys = {fl.name for fl in fields(RockSpec)}
    for i, z in enumerate(s.zones):
        where = f"zones[{i}]"
        _check((z.band is None) != (z.box is None), where, z.name, "give exactly one of band or box")
        if z.band is not None:
            _check(z.band > 0, f"{where}.band", z.band, "must be > 0 m")
        bad = sorted(set(z.rock) - rock_keys)
        _check(not bad, f"{where}.rock.{bad[0] if bad else ''}", z.rock.get(bad[0]) if bad else None,
               f"unknown rock key; known: {', '.join(sorted(rock_keys))}")
        for k, v in z.rock.items():
            _number(v, f"{where}.rock.{k}")
        _validate_rock(s.rock.with_overrides(z.rock), f"{where}.rock", sink, z.rock)


def _validate_fluid(fl: FluidSpec):
    for key in ("viscosity", "bulk_modulus"):
        _check(getattr(fl, key) > 0, f"fluid.{key}", getattr(fl, key), "must be > 0")


def _validate_boundary(b: BoundarySpec):
    for edge in EDGES:
        e = getattr(b, edge)
        _check(e.mechanical in ("pinned", "roller", "free"), f"boundary.{edge}.mechanical",
               e.mechanical, "must be 'pinned', 'roller' or 'free'")
        _check(e.hydraulic in ("drained", "no_flow"), f"boundary.{edge}.hydraulic", e.hydraulic,
               "must be 'drained' or 'no_flow'")
        _check(e.mechanical != "pinned" or e.traction == (0.0, 0.0), f"boundary.{edge}.traction",
               e.traction, "a pinned edge cannot carry an applied traction")


def _validate_injection(inj: InjectionSpec):
    _check(inj.control in ("rate", "pressure"), "injection.control", inj.control,
           "must be 'rate' or 'pressure'")
    _check(inj.number_of_fractures >= 1, "injection.number_of_fractures", inj.number_of_fractures,
           "must be >= 1")
    times = [t for t, _ in inj.schedule]
    _check(all(b > a for a, b in zip(times, times[1:])), "injection.schedule", inj.schedule,
           "times must increase strictly")
    if inj.control == "rate" and not inj.allow_flowback:
        _check(all(v >= 0 for _, v in inj.schedule), "injection.schedule", inj.schedule,
               "flow rates must be >= 0 m^3/s (set injection.allow_flowback = true for flowback)")
    _check(inj.log_policy in ("stop", "skip", "hold"), "injection.log_policy", inj.log_policy,
           "must be 'stop', 'skip' or 'hold'")
    _check(inj.log_max_gap > 0, "injection.log_max_gap", inj.log_max_gap, "must be > 0 s")
    if inj.log is not None:
        _check(inj.control == "rate", "injection.log", inj.log, "a flow-rate log needs control = 'rate'")
        _check(_is_file(inj.log), "injection.log", inj.log, "no such file")


def _validate_time(t: TimeSpec):
    _check(t.end > 0, "time.end", t.end, "must be > 0 s")
    _check(0 < t.dt <= t.end, "time.dt", t.dt, f"must be in (0, end = {t.end}] s")
    _check(t.growth >= 1.0, "time.growth", t.growth, "must be >= 1")
    if t.dt_max is not None:
        _check(t.dt_max >= t.dt, "time.dt_max", t.dt_max, f"must be >= dt = {t.dt} s")
    _check(0.5 <= t.theta <= 1.0, "time.theta", t.theta, "must be in [0.5, 1] (unconditionally stable)")
    if t.theta_min is not None:
        _check(0.5 <= t.theta_min <= t.theta, "time.theta_min", t.theta_min,
               f"must be in [0.5, theta = {t.theta}] (unconditionally stable, at most theta)")


def _validate_solver(sv: SolverSpec):
    _check(0 < sv.tolerance < 1, "solver.tolerance", sv.tolerance, "must be in (0, 1)")
    _check(sv.max_iterations >= 1, "solver.max_iterations", sv.max_iterations, "must be >= 1")
    _check(sv.max_step_cuts >= 0, "solver.max_step_cuts", sv.max_step_cuts, "must be >= 0")
    _check(sv.first_guess in ("previous", "extrapolated"), "solver.first_guess", sv.first_guess,
           "must be 'previous' or 'extrapolated'")
    _check(sv.unstable_slip_rate > 0, "solver.unstable_slip_rate", sv.unstable_slip_rate, "must be > 0 m/s")


def _validate_friction(f: FaultSpec, ef: EffectsSpec):
    """Friction, dilation and aperture parameters, and the switches that need them."""
    for key in ("rate_parameter", "state_parameter", "dilation_angle", "asperity_height_std"):
        _check(getattr(f, key) >= 0, f"fault.{key}", getattr(f, key), "must be >= 0")
    for key in ("reference_velocity", "critical_slip_distance"):
        _check(getattr(f, key) > 0, f"fault.{key}", getattr(f, key), "must be > 0")
    _check(f.dilation_angle < 90, "fault.dilation_angle", f.dilation_angle, "must be below 90 degrees")
    if f.initial_state is not None:
        _check(f.initial_state > 0, "fault.initial_state", f.initial_state, "must be > 0 s")
    if ef.rate_friction:
        _check(f.rate_parameter > 0, "fault.rate_parameter", f.rate_parameter,
               "must be > 0 with effects.rate_friction = true (a = 0 is constant friction: "
               "switch rate_friction off)")
    _check(not ef.state_evolution or ef.rate_friction, "effects.state_evolution", ef.state_evolution,
           "state evolution is part of rate-and-state friction: needs effects.rate_friction = true")
    if ef.state_evolution:
        _check(f.state_parameter > 0, "fault.state_parameter", f.state_parameter,
               "must be > 0 with effects.state_evolution = true")
    if ef.dilation:
        _check(f.dilation_angle > 0, "fault.dilation_angle", f.dilation_angle,
               "must be > 0 with effects.dilation = true")
        _check(ef.mechanics, "effects.dilation", ef.dilation, "needs effects.mechanics = true")
    if ef.aperture_evolution:
        _check(ef.fault_flow and ef.mechanics, "effects.aperture_evolution", ef.aperture_evolution,
               "needs effects.fault_flow = true and effects.mechanics = true (the aperture follows "
               "the mechanical opening)")
    if ef.rate_friction:
        _check(ef.mechanics, "effects.rate_friction", ef.rate_friction, "needs effects.mechanics = true")


def _validate_initial(s: Scene):
    ini = s.initial
    d = ini.gravity_direction
    _check(abs(math.hypot(d[0], d[1]) - 1.0) < 1e-6, "initial.gravity_direction", d, "must be a unit vector")
    _check(ini.gravity >= 0, "initial.gravity", ini.gravity, "must be >= 0 m/s^2")
    _check((ini.stress is None) == (ini.stress_kind is None), "initial.stress_kind", ini.stress_kind,
           "initial.stress and initial.stress_kind go together: say which kind of stress the numbers "
           f"are ({', '.join(STRESS_KINDS)}); the tool does not guess")
    _check(ini.stress_kind is None or ini.stress_kind in STRESS_KINDS, "initial.stress_kind",
           ini.stress_kind, f"must be one of {', '.join(STRESS_KINDS)}")
    _check(ini.stress is None or ini.effective_stress is None, "initial.effective_stress",
           ini.effective_stress, "give either initial.stress with initial.stress_kind or the older "
           "initial.effective_stress (Biot-effective), not both")
    if ini.reference_point is not None:
        _check(_in_domain(s.mesh, ini.reference_point), "initial.reference_point",
               ini.reference_point, "must lie in the domain")


def _validate_damage_zone(s: Scene, sink: list | None):
    dz, ef = s.damage_zone, s.effects
    _check(dz.width > 0, "damage_zone.width", dz.width, "must be > 0 m")
    if ef.damage_zone:
        _check(ef.fault, "effects.damage_zone", ef.damage_zone, "a damage zone needs a fault")
        over = dz.rock_overrides()
        _validate_rock(s.rock.with_overrides(over), "damage_zone", sink, over)


def _validate_effects(ef: EffectsSpec, inj: InjectionSpec):
    """Switch combinations that leave nothing to simulate or nowhere to inject."""
    if not ef.fault:
        for key in ("fault_flow", "leak_off"):
            _check(not getattr(ef, key), f"effects.{key}", getattr(ef, key),
                   "needs a fault: set effects.fault = true or this switch to false")
        _check(all(v == 0 for _, v in inj.schedule), "injection.schedule", inj.schedule,
               "injection happens on the fault; without a fault the schedule must be zero")
    _check(not (ef.leak_off and not ef.poroelastic), "effects.leak_off", ef.leak_off,
           "leak-off needs a permeable rock: set effects.poroelastic = true or leak_off = false")
    if ef.fault and not (ef.fault_flow or ef.leak_off):
        # a dry fault: contact only, no fluid of its own
        _check(all(v == 0 for _, v in inj.schedule), "injection.schedule", inj.schedule,
               "a fault without fault_flow or leak_off holds no fluid, so nothing can be injected")
    _check(ef.mechanics or ef.poroelastic or ef.fault_flow, "effects", "all off", "nothing to simulate")
    if not ef.mechanics:
        _check(not ef.poroelastic, "effects.poroelastic", ef.poroelastic,
               "Biot rock needs mechanics = true (rigid rock has no pore volume change)")


def _validate_output(out: OutputSpec):
    if out.profile_every is not None:
        _check(out.profile_every >= 1, "output.profile_every", out.profile_every, "must be >= 1 step")
    if out.profile_interval is not None:
        _check(out.profile_interval > 0, "output.profile_interval", out.profile_interval, "must be > 0 s")


def _is_file(path: str) -> bool:
    """Does ``path`` name a file (False for a path the system cannot take, e.g. with a NUL)?"""
    try:
        return Path(path).is_file()
    except (OSError, ValueError):
        return False


#: longest rule condition (characters): far beyond any written by hand (a 100-term ``or`` chain
#: of thresholds is ~3,000), and short enough that parsing it stays well below a second
MAX_CONDITION = 10_000


def _validate_monitor(mon: MonitorSpec):
    from .rules import METRICS, RuleError, parse_condition

    for key in ("slip_rate_yellow", "slip_rate_red", "event_rate_window"):
        _check(getattr(mon, key) > 0, f"monitor.{key}", getattr(mon, key), "must be > 0")
    _check(0 < mon.utilisation_yellow, "monitor.utilisation_yellow", mon.utilisation_yellow, "must be > 0")
    known = set(METRICS) | {f.name for f in fields(MonitorSpec) if f.name != "rules"}
    names = set()
    for i, rule in enumerate(mon.rules):
        where = f"monitor.rules[{i}]" + (f" ({_shown(rule.name)})" if rule.name else "")
        _check(rule.level in ("yellow", "red"), f"{where}.level", rule.level, "must be 'yellow' or 'red'")
        _check(rule.hold >= 0, f"{where}.hold", rule.hold, "must be >= 0 s")
        _check(len(rule.when) <= MAX_CONDITION, f"{where}.when", rule.when,
               f"a condition of {len(rule.when)} characters; at most {MAX_CONDITION} (split it into rules)")
        try:
            parse_condition(rule.when, known)
        except RuleError as exc:
            raise SceneError(f"{where}.when = {_shown(rule.when)}: {exc}") from None
        except RecursionError:  # the parser recurses on parentheses
            raise SceneError(f"{where}.when = {_shown(rule.when)}: nested too deeply") from None
        name = rule.name or f"rules[{i}]"
        _check(name not in names, f"{where}.name", name, "two rules have this name")
        _check(0 < len(name.encode()) <= 64, f"{where}.name", name,
               "must have 1 to 64 bytes (stored in /screening/transitions)")
        names.add(name)


# ---- a small TOML writer for resolved scenes (tables, arrays of tables, scalars, arrays) ----
#: TOML basic-string escapes; every other control character is written as \uXXXX
_TOML_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f",
                 "\r": "\\r"}
_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _toml_string(text: str) -> str:
    """A TOML basic string that reads back as ``text`` (control characters escaped, so a
    multi-line value stays on one line)."""
    out = []
    for ch in text:
        if ch in _TOML_ESCAPES:
            out.append(_TOML_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.match(key) else _toml_string(key)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {v!r} as TOML")


def dumps_toml(data: dict, prefix: str = "") -> str:
    lines, tables = [], []
    for k, v in data.items():
        if isinstance(v, dict) and not (prefix.endswith("rock") or k == "rock" and prefix.startswith("zones")):
            tables.append((k, v))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            tables.append((k, v))
        else:
            lines.append(f"{_toml_key(k)} = {_toml_value(v)}")
    out = "\n".join(lines)
    for k, v in tables:
        name = f"{prefix}.{k}" if prefix else k
        if isinstance(v, list):
            for item in v:
                out += f"\n\n[[{name}]]\n" + dumps_toml(item, name)
        else:
            out += f"\n\n[{name}]\n" + dumps_toml(v, name)
    return out.strip() + "\n"

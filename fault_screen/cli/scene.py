"""``fault-screen scene show FILE`` and ``fault-screen scene check FILE``."""
from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import click

from ._options import check_size, log_format_options, log_path_option, reading
from ._common import load_scene, read_driving_log, read_scene_log

FILE = click.Path(dir_okay=False, path_type=Path)


@click.group()
def scene():
    """Inspect scene files (TOML)."""


# ---- the fault at the injection point --------------------------------------------------------
def fault_state_lines(disc) -> list[str]:
    """What the in-situ state means for the fault at the injection point (MPa)."""
    from ..kernels.contact import MU0
    from ..physics.contact import failure_state

    lines = []
    if disc.scene.initial.effective_stress is not None:
        lines.append("notice: initial.effective_stress is read as a Biot-effective stress (sigma + alpha p0); "
                     "say which kind the numbers are with initial.stress and initial.stress_kind")
    contact = disc.physics.contact
    if contact is None:
        return lines
    st = failure_state(disc, float(contact.law.params[MU0]))
    lines += [
        f"in-situ state at the injection point (initial.stress_kind = {disc.in_situ.stress_kind!r}):",
        f"  total normal stress          {st['total_normal_stress'] / 1e6:.3f} MPa (compression +)",
        f"  pore pressure                {st['pore_pressure'] / 1e6:.3f} MPa",
        f"  effective normal stress      {st['effective_normal_stress'] / 1e6:.3f} MPa (fault, Biot 1)",
        f"  shear stress                 {st['shear_stress'] / 1e6:.3f} MPa",
        f"  friction mu0                 {st['friction']:g}",
        f"overpressure to failure at the injection point: {st['overpressure_to_failure'] / 1e6:.2f} MPa",
    ]
    return lines


# ---- show ----------------------------------------------------------------------------------
def _unit(cls, name: str, value, scene) -> str:
    """What the value of ``cls.name`` is measured in, as its docstring gives it (SI, e.g. m2 for
    m^2; angles in deg): "- (dimensionless)" for a pure number, "text" and "true/false" for the
    others."""
    from ..scene import Zone, field_unit

    if name == "schedule":
        return "[s, m3/s]" if scene.injection.control == "rate" else "[s, Pa]"
    if cls is Zone and name == "rock":
        return "units of [rock]"
    unit = field_unit(cls, name)
    if unit == "-":
        return "- (dimensionless)"
    if unit is not None:  # written as the unit parser and the range table write it
        return "deg" if unit.startswith("degrees") else unit.replace("^", "")
    if isinstance(value, bool):
        return "true/false"
    return "text"


def _derived(scene) -> dict:
    """Values the scene computes when a key is left unset: key -> (value, how)."""
    from ..physics.materials import drained_bulk_modulus

    f, r, fl, ini, t = scene.fault, scene.rock, scene.fluid, scene.initial, scene.time
    k_drained = drained_bulk_modulus(r.youngs_modulus, r.poissons_ratio)
    a = math.radians(f.angle)
    px, py = scene.fault_point
    pos = scene.injection.position
    return {
        "fault.point": ([px, py], "the domain's centre"),
        "fault.storativity": (f.hydraulic_aperture / fl.bulk_modulus, "2h0 / fluid.bulk_modulus"),
        "fault.initial_state": (f.critical_slip_distance / f.reference_velocity,
                                "critical_slip_distance / reference_velocity"),
        "rock.solid_bulk_modulus": (k_drained / (1 - r.biot_coefficient) if r.biot_coefficient < 1
                                    else math.inf, "K_drained / (1 - biot_coefficient)"),
        "initial.reference_point": ([px + pos * math.cos(a), py + pos * math.sin(a)],
                                    "the injection point"),
        "initial.pore_pressure_gradient": (fl.density * ini.gravity, "fluid.density * gravity"),
        "initial.lateral_stress_ratio": (r.poissons_ratio / (1 - r.poissons_ratio), "nu / (1 - nu)"),
        "time.dt_max": (t.dt, "time.dt"),
        "damage_zone.youngs_modulus": (r.youngs_modulus, "rock.youngs_modulus"),
        "damage_zone.poissons_ratio": (r.poissons_ratio, "rock.poissons_ratio"),
        "damage_zone.permeability": (r.permeability, "rock.permeability"),
    }


def _written(raw: dict | None, name: str):
    """(key as written, value as written) of ``name`` in a raw TOML table, or None."""
    from ..scene import _UNIT_KEY

    if not isinstance(raw, dict):
        return None
    for k, v in raw.items():
        m = _UNIT_KEY.match(k)
        if (m.group(1) if m else k) == name:
            return k, v
    return None


def _show_table(obj, section: str, raw, scene, derived, lines: list) -> None:
    from ..scene import _toml_value

    tables, arrays = [], []
    for fld in dataclasses.fields(obj):
        name, value = fld.name, getattr(obj, fld.name)
        if dataclasses.is_dataclass(value):
            tables.append((name, value))
            continue
        if isinstance(value, tuple) and value and all(dataclasses.is_dataclass(v) for v in value):
            arrays.append((name, value))  # arrays of tables: [[zones]], [[monitor.rules]]
            continue
        if name == "zones":
            continue
        key = f"{section}.{name}" if section else name
        unit = _unit(type(obj), name, value, scene)
        written = _written(raw, name)
        if written is not None:
            k, v = written
            # show what was written when it carried a unit (in the key or in the value)
            with_unit = k != name or (isinstance(v, str) and not isinstance(value, str))
            src = f"file: {k} = {_toml_value(v)}" if with_unit else "file"
        else:
            src = "default"
        if value is None:
            if key in derived and derived[key][0] is not None:  # (a mobility leaves permeability unset)
                dv, how = derived[key]
                lines.append(f"# {name} = {_toml_value(dv)}".ljust(43)
                             + f" # {unit}, derived: {how}")
            else:
                lines.append(f"# {name}: not set".ljust(43) + f" # {unit}, default")
            continue
        lines.append(f"{name} = {_toml_value(value)}".ljust(43) + f" # {unit}, {src}")
    for name, value in tables:
        sub = f"{section}.{name}" if section else name
        lines.append("")
        lines.append(f"[{sub}]")
        _show_table(value, sub, raw.get(name) if isinstance(raw, dict) else None, scene, derived,
                    lines)
    for name, items in arrays:
        sub = f"{section}.{name}" if section else name
        written = raw.get(name) if isinstance(raw, dict) else None
        for i, item in enumerate(items):
            raw_item = written[i] if isinstance(written, list) and i < len(written) else None
            lines.append("")
            lines.append(f"[[{sub}]]" + ("" if raw_item is not None else "  # default"))
            _show_table(item, f"{sub}[{i}]", raw_item, scene, {}, lines)


@scene.command()
@click.argument("path", type=FILE)
def show(path):
    """Print the fully resolved scene: every key, in SI units (angles in degrees), with its unit
    and where its value comes from (file, default, or derived from other values; derived and
    unset keys are shown as comments, so the output is itself a scene file)."""
    sc = load_scene(path)
    with reading(path):
        raw = tomllib.loads(Path(path).read_text())
    lines = [f"# {path}: resolved scene, SI units (angles in degrees).",
             "# After each value: its unit and its source (file, default, derived)."]
    _show_table(sc, "", raw, sc, _derived(sc), lines)
    from ..discretisation import discretise

    with reading(path):
        lines += [""] + ["# " + line for line in fault_state_lines(discretise(sc))]
    lines += ["# " + line for line in sc.flow_summary()]  # permeability and mobility, both
    click.echo("\n".join(lines) + "\n", nl=False)


# ---- check ---------------------------------------------------------------------------------
def _estimate_lines(scene, log, plan=None) -> list[str]:
    """The run's cost (:mod:`fault_screen.run_estimate`): for ``plan`` (a replay planned from
    --log: to the log's end, or --end), else with the scene's own log to the end the run would
    take (``time.end``), as ``fault-screen run`` plans it."""
    from ..run_estimate import estimate_run

    samples = 0
    if plan is None and log is not None:
        from ..io.replay import plan_replay

        plan = plan_replay(scene, log, scene.time.end, end_name="time.end")
    if plan is not None:
        scene, samples = plan.scene, len(plan.log_arrays.get("time", ()))
    return estimate_run(scene, log_samples=samples).lines()


@scene.command()
@click.argument("path", type=FILE)
@log_path_option(required=False, help="Estimate the run for this injection log, as 'fault-screen "
                 "replay PATH --log LOG' would take it (the same log options): steps to the "
                 "log's end, wall time, result file, memory, and how to thin or coarsen.")
@log_format_options
def check(path, log_path, flow_unit, pressure_unit, max_gap, policy, end, log_date, log_tz,
          time_column, flow_column, pressure_column, time_unit, volume_column,
          cumulative_volume_column, volume_unit, accept_implausible):
    """Validate a scene: keys, values and their physical ranges, units, switch combinations,
    the memory it needs, its injection log (if any) and the geometry (fault in the domain,
    injection point on the fault, in-situ equilibrium). Prints what it would simulate and what
    the run would cost; with --log, a replay of that log."""
    from ..discretisation import discretise

    sc = load_scene(path)
    check_size(sc, str(path))
    plan = None
    if log_path is not None:        # read as replay reads it: a bad log stops here (exit 2)
        log, plan = read_driving_log(
            sc, Path(path), log_path, end, accept_implausible=accept_implausible, quiet=True,
            flow_unit=flow_unit, pressure_unit=pressure_unit, max_gap=max_gap, policy=policy,
            date=log_date, tz=log_tz, time_column=time_column, flow_column=flow_column,
            pressure_column=pressure_column, time_unit=time_unit, volume_column=volume_column,
            cumulative_volume_column=cumulative_volume_column, volume_unit=volume_unit)
    else:
        log = read_scene_log(sc) if sc.injection.log is not None else None
    import warnings

    from ..scene import SceneWarning

    with reading(path), warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", SceneWarning)
        model = discretise(sc)  # terms may warn about the discretised scene (e.g. leak-off mesh)
    for w in caught:
        if issubclass(w.category, SceneWarning):
            click.echo(f"Warning: {path}: {w.message}", err=True)
    counts = ", ".join(f"{k} {v}" for k, v in model.dof_counts().items() if v)
    click.echo(f"{path}: ok -- {sc.title}")
    click.echo(f"  mesh {model.mesh.nx} x {model.mesh.ny} elements, fault cuts "
               f"{len(model.cut_elements)} of them")
    click.echo(f"  unknowns {model.n_dofs} ({counts})")
    if plan is not None:
        click.echo(f"  replay of {log_path}: 0 to {plan.scene.time.end:g} s")
    for line in _estimate_lines(sc, log, plan):
        click.echo(f"  {line}")
    click.echo(f"  physics terms: {', '.join(model.physics.names())}")
    for line in fault_state_lines(model):
        click.echo(("  " if not line.startswith("notice") else "") + line)
    if log is not None:
        click.echo(f"  log: {log.summary}")
        if plan is None:        # read_driving_log has warned already
            for w in log.warnings:
                click.echo(f"Warning: {w}", err=True)

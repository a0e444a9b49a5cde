"""``fault-screen screen RESULT.h5``: re-evaluate the screening rules on a saved result; and the
verdict block and exit code that ``run`` and ``replay`` end with.

Exit codes of a completed run: 0 whatever the level; with ``--fail-on yellow|red``, 4 when that
level was reached; 3 when the fault became unstable (the run stopped early), which takes
precedence.
"""
from __future__ import annotations

import math
from pathlib import Path

import click

from ._options import FILE, BadInput, events_option, parse_iso, reading, t0_option, version_option

EXIT_UNSTABLE = 3
EXIT_LEVEL_REACHED = 4

fail_on_option = click.option(
    "--fail-on", type=click.Choice(["yellow", "red"]), default=None,
    help="Exit with code 4 when the screening reaches this level (for scripts); an unstable "
         "fault exits with 3 regardless.")


def _format_value(name: str, value: float) -> str:
    from ..rules import METRICS

    unit = METRICS.get(name, ("", ""))[0]
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if unit == "Pa":  # operators read stresses in MPa
        return f"{value * 1e-6:.4g} MPa"
    return f"{value:.4g}" + ("" if unit in ("", "1") else f" {unit}")


def verdict_lines(screening) -> list[str]:
    """The verdict block: highest level, when, by which rule, what to do, the metrics then."""
    from ..screening import LEVEL_NAMES

    v = screening.verdict
    when = {r.name or f"rules[{i}]": r.when for i, r in enumerate(screening.spec.rules)}
    lines = [f"verdict: {v.level_name.upper()}"]
    if v.rule is None:
        lines.append("  no rule fired: the fault stayed below every threshold of [monitor]")
        return lines
    rule = v.rule + (f": {when[v.rule]}" if v.rule in when else "")
    rows = [("reached at", f"t = {v.time:.6g} s"), ("rule", rule), ("action", v.action or "-"),
            ("level at the end", LEVEL_NAMES[v.final_level]),
            ("level changes", str(len(screening.transitions)))]
    lines += [f"  {k:<28} {val}" for k, val in rows]
    lines.append("  metrics then:")
    lines += [f"    {k:<26} {_format_value(k, val)}" for k, val in v.metrics.items()]
    return lines


def exit_code(result, screening, fail_on: str | None) -> int:
    """3 for a fault that became unstable, 4 when ``fail_on`` was reached, else 0."""
    from ..screening import LEVEL_NAMES, stopped_unstable

    if stopped_unstable(result) is not None:
        return EXIT_UNSTABLE
    if fail_on is not None and screening.verdict.level >= LEVEL_NAMES.index(fail_on):
        return EXIT_LEVEL_REACHED
    return 0


def conclude(result, fail_on: str | None, screening=None) -> None:
    """Print the verdict of ``result`` and exit with its code (returns when the code is 0)."""
    from ..screening import screen_result, stopped_unstable

    if screening is None:
        screening = screen_result(result, store=False)  # as stored: the result's rules and events
    for line in verdict_lines(screening):
        click.echo(line)
    code = exit_code(result, screening, fail_on)
    if code == EXIT_UNSTABLE:
        click.echo(f"fault became unstable at t = {stopped_unstable(result):.6g} s: exit code 3",
                   err=True)
    elif code == EXIT_LEVEL_REACHED:
        click.echo(f"--fail-on {fail_on}: level {screening.verdict.level_name} reached at "
                   f"t = {screening.verdict.time:.6g} s: exit code 4", err=True)
    if code:
        raise click.exceptions.Exit(code)


@click.command("screen")
@click.argument("result_path", type=FILE, metavar="RESULT.h5")
@click.option("--scene", "scene_path", type=FILE, default=None, metavar="SCENE",
              help="Take the [monitor] thresholds and rules of this scene (its physics is not used: "
                   "the saved result is not re-run) [default: the result's own scene].")
@events_option
@t0_option
@fail_on_option
@click.option("--out", "-o", type=FILE, default=None, metavar="NEW.h5",
              help="Write the result with the new /screening/ group (and [monitor]) to NEW.h5.")
@version_option
def screen(result_path, scene_path, events, t0, fail_on, out):
    """Re-evaluate the screening rules on a saved RESULT.h5 without re-running the model: the
    metrics, the level at each output time, the level changes and the verdict.

    Events come from --events (placed relative to --t0, else the start stored in the result),
    else from those stored in the result.
    """
    from ..result import Result
    from ..screening import LEVEL_NAMES, screen_result
    from .run import load_events, load_scene

    result_path = Path(result_path)
    with reading(result_path):
        result = Result.load(result_path)
    if scene_path is not None:
        monitor = load_scene(Path(scene_path)).monitor
        with reading(scene_path):
            result.scene = result.scene.replace(monitor=monitor)
    catalog = None
    if events is not None:
        start = t0
        if start is None and result.meta.get("start"):
            start = parse_iso(result.meta["start"], f"{result_path}: meta start")
        catalog = load_events(events, start)
        result.extra["events"] = {"time": catalog.time, "magnitude": catalog.magnitude}
    screening = screen_result(result, events=catalog)
    source = scene_path if scene_path is not None else f"{result_path} (its own scene)"
    click.echo(f"screening {result_path}: {len(result.time)} output times, rules of {source}")
    for tr in screening.transitions:
        click.echo(f"  {tr.describe()}")
    if not screening.transitions:
        click.echo(f"  level {LEVEL_NAMES[0]} throughout")
    if out is not None:
        if Path(out).resolve() == result_path.resolve():
            raise BadInput(f"--out {out}: is RESULT.h5 itself; write to a new file")
        result.save(out)
        click.echo(f"  written {out}")
    conclude(result, fail_on, screening)

"""The verdict block and exit code that ``run``, ``replay`` and ``screen`` end with.

Exit codes of a completed run: 0 whatever the level; with ``--fail-on yellow|red``, 4 when that
level was reached; 3 when the fault became unstable (the run stopped early), which takes
precedence.
"""
from __future__ import annotations

import math

import click

from ._options import EXIT_LEVEL_REACHED, EXIT_UNSTABLE

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


def watched_lines(spec) -> list[str]:
    """One line per threshold the rules of ``spec`` compare a metric with: the level it raises,
    the rule, and the threshold in the metric's unit."""
    from ..plotting.screening import rule_thresholds
    from ..screening import LEVEL_NAMES

    return [f"{LEVEL_NAMES[level]}: {label} ({_format_value(metric, value)})"
            for metric, value, level, label in rule_thresholds(spec)]


def verdict_lines(screening) -> list[str]:
    """The verdict block: highest level, when, by which rule, what to do, the metrics then."""
    from ..screening import LEVEL_NAMES

    v = screening.verdict
    when = {r.name or f"rules[{i}]": r.when for i, r in enumerate(screening.spec.rules)}
    lines = [f"verdict: {v.level_name.upper()}"]
    if v.rule is None:
        lines.append(f"  {'action':<28} keep injecting as planned and keep the screening running: "
                     f"no threshold was reached")
        watched = watched_lines(screening.spec)
        if watched:
            lines.append("  watching (level: when):")
            lines += [f"    {line}" for line in watched]
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


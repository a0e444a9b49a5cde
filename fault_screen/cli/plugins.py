"""``fault-screen plugins [NAME]``: the installed alert and source plugins."""
from __future__ import annotations

import inspect

import click

from ._options import BadInput, version_option


def _summary(cls) -> str:
    doc = inspect.getdoc(cls) or ""
    return doc.split("\n\n")[0].replace("\n", " ")


@click.command("plugins")
@click.argument("name", required=False)
@click.option("--outbox", "outbox", default=None, metavar="FILE",
              help="Show the deliveries of a monitor's alert outbox instead: pending, delivered "
                   "and refused for good (dead letters) per sink, and each dead letter.")
@version_option
def plugins(name, outbox):
    """List the installed monitoring plugins (entry-point groups fault_screen.alerts and
    fault_screen.sources), or describe the plugin NAME with its options."""
    from ..monitor.plugins import GROUPS, PluginError, available, load

    if outbox is not None:
        _outbox_report(outbox)
        return

    found = {kind: available(kind) for kind in GROUPS}
    if name is None:
        for kind, eps in found.items():
            click.echo(f"{kind}s ({GROUPS[kind]}):")
            for n, ep in eps.items():
                try:
                    text = _summary(ep.load())
                except Exception as exc:  # noqa: BLE001 - a broken plugin is listed as such
                    text = f"cannot be loaded: {type(exc).__name__}: {exc}"
                click.echo(f"  {n:10s} {ep.value}\n  {'':10s} {text}")
        return
    kinds = [k for k, eps in found.items() if name in eps]
    if not kinds:
        names = sorted({n for eps in found.values() for n in eps})
        raise BadInput(f"unknown plugin {name!r}; supported: {', '.join(names) or 'none'}")
    for kind in kinds:
        try:
            cls = load(kind, name)
        except PluginError as exc:
            raise BadInput(str(exc)) from None
        params = [p for p in inspect.signature(cls).parameters.values()
                  if p.name not in ("decoder", "log", "stream") and p.kind != p.VAR_KEYWORD]
        opts = ", ".join(p.name + ("" if p.default is p.empty else f"={p.default!r}")
                         for p in params)
        click.echo(f"{name} ({kind}, {found[kind][name].value})\n  options: {opts}\n")
        click.echo(inspect.getdoc(cls) or "")


def _outbox_report(path) -> None:
    from ..monitor.outbox import outbox_status

    try:
        status = outbox_status(path)
    except ValueError as exc:
        raise BadInput(f"--outbox {exc}") from None
    click.echo(f"outbox {path}:")
    for sink, n in status["sinks"].items():
        click.echo(f"  {sink}: {n['pending']} pending, {n['delivered']} delivered, "
                   f"{n['dead']} refused for good")
    for d in status["dead_letters"]:
        click.echo(f"  dead letter {d['id']} (level {d['level']}) to {d['sink']}: {d['error']}")

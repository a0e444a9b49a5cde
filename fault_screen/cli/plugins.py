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
@version_option
def plugins(name):
    """List the installed monitoring plugins (entry-point groups fault_screen.alerts and
    fault_screen.sources), or describe the plugin NAME with its options."""
    from ..monitor.plugins import GROUPS, PluginError, available, load

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

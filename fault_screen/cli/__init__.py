"""Command-line interface: ``fault-screen run | replay | monitor | plot | screen | scene |
forecast | accuracy | calibrate | sensitivity | ensemble | plugins`` (one module per command).

Exit codes: see :mod:`fault_screen.cli._options` (the one place they are decided) and
``fault-screen --help``.
"""
from __future__ import annotations

import click

from ._options import Group, version_option

__all__ = ["main"]

#: the commands; each is the function of that name in the module of that name in this package
COMMANDS = ("accuracy", "calibrate", "ensemble", "forecast", "monitor", "plot", "plugins", "replay",
            "run", "scene", "screen", "sensitivity")


class LazyGroup(Group):
    """The command group, importing a command's module only when that command is asked for:
    ``fault-screen run`` does not import the monitor's, the forecast's or the plots' modules,
    and ``fault-screen --help`` none of them until it lists them."""

    def list_commands(self, ctx):
        return sorted(set(COMMANDS) | set(self.commands))

    def get_command(self, ctx, cmd_name):
        if cmd_name in self.commands or cmd_name not in COMMANDS:
            return self.commands.get(cmd_name)
        command = _import_command(cmd_name)
        self.add_command(command, cmd_name)
        return command


def _import_command(name: str) -> click.Command:
    # each import written out, so that the import graph (tests/package/test_import_cycles.py) sees it
    if name == "accuracy":
        from .accuracy import accuracy as command
    elif name == "calibrate":
        from .calibrate import calibrate as command
    elif name == "ensemble":
        from .ensemble import ensemble as command
    elif name == "forecast":
        from .forecast import forecast as command
    elif name == "monitor":
        from .monitor import monitor as command
    elif name == "plot":
        from .plot import plot as command
    elif name == "plugins":
        from .plugins import plugins as command
    elif name == "replay":
        from .replay import replay as command
    elif name == "run":
        from .run import run as command
    elif name == "scene":
        from .scene import scene as command
    elif name == "screen":
        from .screen import screen as command
    else:
        from .sensitivity import sensitivity as command
    return command


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@version_option
def main():
    """Induced-seismicity screening: coupled hydro-mechanical X-FEM model of fluid injection
    into a fault.

    \b
    fault-screen run                      the bundled Rustrel 2015 scene (paper units)
    fault-screen run SCENE.toml --plot figs --set time.end=600
    fault-screen replay SCENE.toml --log injection.csv --events catalog.xml --plot figs
    fault-screen plot result.h5 --out-dir figs
    fault-screen scene check SCENE.toml   (scene show SCENE.toml: resolved, in SI)
    fault-screen screen result.h5 --scene new-thresholds.toml
    fault-screen monitor SCENE.toml --follow live.csv --state state.h5 --alert jsonl:alerts.jsonl
    fault-screen forecast SCENE.toml --at 300 --horizon 30min --plan hold --plan stop --advise
    fault-screen accuracy SCENE.toml --target 5%
    fault-screen calibrate SCENE.toml --observations obs.csv --parameters params.toml
    fault-screen sensitivity SCENE.toml --parameters params.toml
    fault-screen ensemble SCENE.toml --vary params.toml --samples 50
    fault-screen plugins                  installed alert hooks and sample sources

    Exit codes: 0 success, 1 run failed or output not written, 2 bad usage or bad input,
    3 the fault became unstable, 4 the --fail-on screening level was reached.
    """


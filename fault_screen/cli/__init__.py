"""Command-line interface: ``fault-screen run | replay | monitor | plot | screen | scene |
forecast | accuracy | calibrate | sensitivity | ensemble | plugins`` (one module per command).

Exit codes: see :mod:`fault_screen.cli._options` (the one place they are decided) and
``fault-screen --help``.
"""
from __future__ import annotations

import click

from ._options import Group, version_option
from .accuracy import accuracy
from .calibrate import calibrate
from .ensemble import ensemble
from .forecast import forecast
from .monitor import monitor
from .plot import plot
from .plugins import plugins
from .replay import replay
from .run import run
from .scene import scene
from .screen import screen
from .sensitivity import sensitivity

__all__ = ["main"]


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
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


main.add_command(run)
main.add_command(replay)
main.add_command(plot)
main.add_command(scene)
main.add_command(screen)
main.add_command(calibrate)
main.add_command(sensitivity)
main.add_command(ensemble)
main.add_command(accuracy)
main.add_command(monitor)
main.add_command(plugins)
main.add_command(forecast)

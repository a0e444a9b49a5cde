"""The ensemble options of the look-ahead commands (``forecast`` and ``monitor``): the parameter
draws of ``--vary PARAMS.toml --members N`` and their checks, in one place."""
from __future__ import annotations

import click

from ._options import FILE, BadInput


def ensemble_options(command):
    """``--vary``, ``--members``, ``--distribution``, ``--seed``, ``--free``, ``--confidence``
    (the keywords ``params_path``, ``members``, ``distribution``, ``seed``, ``free``,
    ``confidence`` of the command); :func:`member_draws` checks them and makes the draws."""
    for option in reversed((
        click.option("--vary", "params_path", type=FILE, default=None, metavar="PARAMS.toml",
                     help="Ensemble: parameters to vary, with their means and bounds (mean -/+ 1 "
                          "SD), the file `fault-screen ensemble --vary` takes; needs --members."),
        click.option("--members", type=int, default=None, metavar="N",
                     help="Ensemble: number of parameter draws, each running its own history."),
        click.option("--distribution", type=click.Choice(["normal", "uniform"]), default="normal",
                     show_default=True, help="Ensemble: how the draws are made (as `ensemble`)."),
        click.option("--seed", type=int, default=1, show_default=True,
                     help="Ensemble: the draws' seed."),
        click.option("--free", default=None, metavar="KEY,KEY",
                     help="Ensemble: vary only these parameters of PARAMS.toml [default: all]."),
        click.option("--confidence", type=float, default=None, metavar="C",
                     help="Ensemble advice: the largest rate whose probability of reaching the "
                          "advice's level is at most 1 - C [default with --members: 0.9]."),
    )):
        command = option(command)
    return command


def member_draws(scene, params_path, members, distribution, seed, free, confidence, advise,
                 ensemble_only=None):
    """The members' parameter draws (dicts of dotted scene keys to SI values; None without
    --members), every ensemble option checked. ``ensemble_only``: other options of the command
    that mean something only for an ensemble ({"--scheduler": value}): refused without one."""
    if params_path is None and members is None:
        others = {"--confidence": confidence, "--free": free, **(ensemble_only or {})}
        for name, value in others.items():
            if value is not None:
                raise BadInput(f"{name} is for an ensemble: give --vary PARAMS.toml --members N")
        return None
    if params_path is None:
        raise BadInput("--members needs --vary PARAMS.toml (the parameters to draw)")
    if members is None:
        raise BadInput("--vary needs --members N (how many draws)")
    if members < 1:
        raise BadInput(f"--members {members}: must be >= 1")
    if confidence is not None:
        if not advise:
            raise BadInput("--confidence is for the advice: add --advise")
        if not 0.0 < confidence < 1.0:
            raise BadInput(f"--confidence {confidence!r}: must be between 0 and 1 (e.g. 0.9)")
    from ..calibration import sample_parameters
    from .calibrate import load_parameters_option

    params = load_parameters_option(params_path, scene, free)
    return sample_parameters(params, members, distribution, seed)

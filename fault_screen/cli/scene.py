"""``fault-screen scene show FILE`` and ``fault-screen scene check FILE``."""
from __future__ import annotations

from pathlib import Path

import click

from ._options import reading
from .run import load_scene

FILE = click.Path(dir_okay=False, path_type=Path)


@click.group()
def scene():
    """Inspect scene files (TOML)."""


@scene.command()
@click.argument("path", type=FILE)
def show(path):
    """Print the fully resolved scene, defaults included, in SI units."""
    click.echo(load_scene(path).to_toml(), nl=False)


@scene.command()
@click.argument("path", type=FILE)
def check(path):
    """Validate a scene: keys, values, units, switch combinations and the geometry (fault in the
    domain, injection point on the fault, in-situ equilibrium). Prints what it would simulate."""
    from ..discretisation import discretise

    sc = load_scene(path)
    with reading(path):
        model = discretise(sc)
    counts = ", ".join(f"{k} {v}" for k, v in model.dof_counts().items() if v)
    click.echo(f"{path}: ok -- {sc.title}")
    click.echo(f"  mesh {model.mesh.nx} x {model.mesh.ny} elements, fault cuts "
               f"{len(model.cut_elements)} of them")
    click.echo(f"  unknowns {model.n_dofs} ({counts})")
    click.echo(f"  physics terms: {', '.join(model.physics.names())}")

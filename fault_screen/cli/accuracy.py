"""``fault-screen accuracy SCENE``: what accuracy costs in time, rung by rung."""
from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from ._options import FILE, BadInput, version_option
from ._common import apply_sets, load_scene
from ._runner import TaskBar, open_runner, runner_options


def _target_callback(ctx, param, value):
    if value is None:
        return None
    text = value.strip()
    try:
        x = float(text[:-1]) / 100 if text.endswith("%") else float(text)
    except ValueError:
        raise BadInput(f"--target {value!r}: expected a relative error like 5% or 0.05") from None
    if not 0 < x < 10:
        raise BadInput(f"--target {value!r}: must be a positive relative error (e.g. 5%)")
    return x


@click.command("accuracy")
@click.argument("scene_path", type=FILE, metavar="SCENE")
@click.option("--levels", type=int, default=3, show_default=True,
              help="Rungs per ladder: element size and time step x2, x1, x1/2, ...")
@click.option("--target", default=None, metavar="5%", callback=_target_callback,
              help="Name the cheapest rung whose errors are all below this relative error.")
@click.option("--quantities", default=None, metavar="Q,Q",
              help="Quantities to compare [default: the exact ones on a verification scene, else every screened one].")
@click.option("--no-effects", is_flag=True, help="Skip the rungs with one effect switched off.")
@runner_options
@version_option
def accuracy(scene_path, levels, target, quantities, no_effects, out_dir, workers, scheduler, quiet, sets):
    """Run SCENE on a ladder of mesh sizes and time steps (and with each effect off in turn) and
    show each rung's cost (wall time, peak memory, unknowns, steps, Newton iterations) against
    its error in the screened quantities.

    The reference is the exact solution where the scene has one: along-fault diffusion (rigid
    impermeable rock, constant injection pressure: configs/verification/fault-diffusion.toml)
    and self-similar fluid-driven slip (elastic impermeable rock, constant friction:
    configs/verification/fluid-driven-slip-*.toml); any other quantity is measured against
    Richardson extrapolation from the three finest rungs of each ladder, with the observed
    order printed. The table marks each quantity [exact] or [richardson]. Effect rungs are
    compared with the full scene. Writes accuracy.csv and accuracy.png (error against wall time,
    Pareto front) to --out-dir. Wall times are warm (each task runs its scene once for one step
    first); with more workers than free cores they include the contention.
    """
    from ..accuracy import known_quantities, plot_study, run_study, write_csv

    if levels < 3:
        raise BadInput(f"--levels {levels}: must be >= 3 (Richardson extrapolation needs three rungs)")
    scene_path = Path(scene_path)
    scene = apply_sets(load_scene(scene_path), sets)
    known = known_quantities(scene)
    qs = None
    if quantities is not None:
        qs = [q.strip() for q in quantities.split(",") if q.strip()]
        bad = [q for q in qs if q not in known]
        if bad or not qs:
            raise BadInput(f"--quantities {quantities!r}: unknown {bad[0] if bad else 'empty'}; "
                           f"this scene supports: {', '.join(known)}")
    out = Path(out_dir) if out_dir is not None else Path.cwd() / f"accuracy-{scene_path.stem}"
    out.mkdir(parents=True, exist_ok=True)
    runner = open_runner(workers, scheduler)
    try:
        study = run_study(scene, runner, levels=levels, quantities=qs, effects=not no_effects,
                          progress=TaskBar("accuracy", quiet), out=out / "runs.h5")
    finally:
        runner.close()
    write_csv(study, out / "accuracy.csv")
    plot_study(study, out / "accuracy.png", title=scene.title)
    exact = [q for q in study.quantities if study.references.get(q) == "exact"]
    rich = [q for q in study.quantities if q not in exact]
    click.echo("reference: " + "; ".join(
        ([f"{study.reference} for {', '.join(exact)}"] if exact else [])
        + ([f"Richardson extrapolation for {', '.join(rich)}"] if rich else [])))
    head = (["rung", "h (m)", "dt (s)", "wall (s)", "MB", "unknowns", "steps", "newton"]
            + [f"{q} [{study.references.get(q, 'richardson')}]" for q in study.quantities])
    rows = []
    for r in study.rows:
        rows.append([r["rung"], f"{r['element_size']:.3g}", f"{r['dt']:.3g}", f"{r['wall_s']:.3g}",
                     f"{r['peak_memory_mb']:.0f}", r["unknowns"], r["steps"], r["newton_iterations"]]
                    + ["" if not np.isfinite(r[f"error_{q}"]) else f"{100 * r[f'error_{q}']:.3g}%"
                       for q in study.quantities] + (["FAILED: " + r["failed"][:60]] if r["failed"] else []))
    widths = [max(len(str(x)) for x in col) for col in zip(head, *[r[:len(head)] for r in rows])]
    for r in [head, *rows]:
        click.echo("  ".join(str(x).ljust(w) for x, w in zip(r, widths)) + ("  " + r[-1] if len(r) > len(head) else ""))
    for (kind, q), ex in study.orders.items():
        click.echo(f"observed order, {kind}: {q} {ex.order:.2f}" + ("" if ex.asymptotic else f"  (warning: {ex.note or 'not asymptotic'})"))
    for name, why in study.skipped:
        click.echo(f"effect {name} not switched off alone: {why}")
    for w in study.warnings:
        click.echo(f"Warning: {w}", err=True)
    if target is not None:
        best = study.cheapest(target)
        if best is None:
            click.echo(f"no rung meets {100 * target:g}% on every quantity"
                       + (f" (no converged reference, so no rung is certified on: {', '.join(study.uncertified)};"
                          f" leave them out with --quantities)" if study.uncertified else ""))
        else:
            click.echo(f"cheapest rung within {100 * target:g}%: {best['rung']} (h {best['element_size']:.3g} m, "
                       f"dt {best['dt']:.3g} s, {best['wall_s']:.3g} s)")
    click.echo(f"wrote {out / 'accuracy.csv'}")
    click.echo(f"wrote {out / 'accuracy.png'}")

"""``fault-screen forecast SCENE (--at T ... | --every S) --horizon H --plan P ...``: look-aheads
under injection plans from past states of a scene or of a replayed log (see
:mod:`fault_screen.forecast`), a table, ``forecast.csv`` and, with ``--plot``, the figure."""
from __future__ import annotations

import csv
import math
import uuid
from pathlib import Path

import click

# the command line's shared pieces, in one place per file
from ._options import DIR, FILE, BadInput, check_size, log_options, t0_option, version_option
from ._progress import format_duration
from ._common import default_scene_path, load_scene, read_driving_log, read_scene_log
from ._runner import _scheduler_callback, _workers_callback
from ._draws import ensemble_options, member_draws

DEFAULT_PLANS = ("scene", "hold", "stop")


def _duration(what):
    def check(ctx, param, value):
        from ..forecast import PlanError, parse_duration

        if value is None:
            return None
        values = value if isinstance(value, tuple) else (value,)
        try:
            out = tuple(parse_duration(v, what) for v in values)
        except PlanError as exc:
            raise BadInput(str(exc)) from None
        return out if isinstance(value, tuple) else out[0]
    return check


@click.command("forecast")
@click.argument("scene_path", type=FILE, required=False, metavar="[SCENE]")
@log_options
@click.option("--at", "at", multiple=True, metavar="T", callback=_duration("--at"),
              help="Model time of a forecast: seconds or a duration (300, 5 min, 2h); repeat "
                   "for several. The forecast is made at the last step of the run ending by T.")
@click.option("--every", default=None, metavar="S", callback=_duration("--every"),
              help="A forecast every S (seconds or a duration) from S to the end of the run.")
@click.option("--horizon", required=True, metavar="H", callback=_duration("--horizon"),
              help="How far each forecast looks ahead: seconds or a duration (1h, 30 min).")
@click.option("--plan", "plans", multiple=True, metavar="P",
              help="Injection plan from the forecast time on: scene, hold, stop, 'rate:30 L/min', "
                   "'pressure:4 MPa', 'scale:1.2', or an injection log file (elapsed column: "
                   "from now). Repeat for several [default: scene, hold, stop].")
@click.option("--advise", is_flag=True,
              help="Also find the largest constant rate (pressure control: overpressure) that "
                   "stays below --advise-level over the horizon, to 2 %.")
@click.option("--advise-level", type=click.Choice(["yellow", "red"]), default="yellow",
              show_default=True, help="The level the advised rate stays below.")
@click.option("--max-rate", default=None, metavar="Q",
              help="Largest rate the advice tries, with a unit (e.g. '80 L/min'; pressure "
                   "control: '8 MPa') [default: twice the largest rate so far].")
@click.option("--ladder", "ladder_dt_max", default=None, metavar="DT_MAX", callback=_duration("--ladder"),
              help="Look ahead on steps doubling from the run's step up to DT_MAX (seconds or a "
                   "duration), each size factorised once for all plans: faster, the time to "
                   "yellow late by up to DT_MAX [default: the scene's own steps, exact; with "
                   "--members: a ladder to 160 s].")
@click.option("--scene-steps", is_flag=True,
              help="Look ahead on the scene's own steps (exact) also with --members.")
@click.option("--out", "-o", "out", type=FILE, default=Path("forecast.csv"), show_default=True,
              metavar="CSV", help="The forecasts, one row per time and plan.")
@click.option("--plot", "plot_dir", type=DIR, default=None, metavar="DIR",
              help="Write <scene-stem>-forecast.png (one per forecast time when several) into DIR.")
@t0_option
@click.option("--quiet", "-q", is_flag=True, help="Only the table.")
@ensemble_options
@click.option("--workers", type=int, default=2, show_default=True, callback=_workers_callback,
              help="Ensemble: worker processes of the local Dask cluster (0: this process).")
@click.option("--scheduler", default=None, metavar="tcp://HOST:PORT", callback=_scheduler_callback,
              help="Ensemble: use an existing Dask scheduler instead of a local cluster.")
@version_option
def forecast(scene_path, log_path, flow_unit, pressure_unit, max_gap, policy, end, log_date, log_tz,
             time_column, flow_column, pressure_column, time_unit, volume_column,
             cumulative_volume_column, volume_unit, accept_implausible, at, every, horizon, plans,
             advise, advise_level, max_rate, ladder_dt_max, scene_steps, out, plot_dir, t0, quiet, params_path,
             members,
             distribution, seed, free, confidence, workers, scheduler):
    """Forecast what the fault of SCENE does over the next H under injection plans, from one or
    more times of its run (or of the replay of --log LOG, with replay's log options).

    \b
    fault-screen forecast configs/rustrel-2015-impermeable.toml --at 5min --horizon 10min
    fault-screen forecast SCENE --every 10min --horizon 1h --plan hold --plan 'rate:30 L/min' --advise
    fault-screen forecast SCENE --log pump.csv --at 2h --horizon 1h --plan stop --plot figs

    Each forecast forks the run at the time, runs each plan for the horizon and screens it with
    the scene's [monitor] rules (their holds and the level so far included). The table and the
    CSV give, per time and plan: the level now, at the horizon and the highest, the time to
    yellow and to red, the peak slip rate, the largest utilisation, the induced slip at the
    horizon and, with --advise, the advised rate.

    With --vary PARAMS.toml --members N, N parameter draws each run their own history (as
    Dask tasks, --workers/--scheduler) and the CSV gets, per time and plan, P(yellow) and
    P(red) within the horizon, the 10/50/90 % time to yellow and the number of members; the
    deterministic columns are the scene's own forecast; --advise gives the largest rate whose
    probability of reaching --advise-level is at most 1 - --confidence.
    """
    from ..forecast import PlanError, parse_plan
    from ..screening import LEVEL_NAMES

    if (not at) == (every is None):
        raise BadInput("give the forecast times: --at T (repeatable) or --every S, not both")
    if not horizon > 0:
        raise BadInput("--horizon must be > 0")
    if ladder_dt_max is not None and not ladder_dt_max > 0:
        raise BadInput("--ladder must be > 0 (the largest look-ahead step)")
    if scene_steps and ladder_dt_max is not None:
        raise BadInput("--scene-steps or --ladder, not both")
    scene_path = Path(scene_path) if scene_path is not None else default_scene_path()
    scene = load_scene(scene_path)
    check_size(scene, str(scene_path))
    draws = member_draws(scene, params_path, members, distribution, seed, free, confidence, advise,
                         {"--scheduler": scheduler})
    drive, start, scene = _drive(scene, scene_path, log_path, end, t0, quiet,
                                 dict(flow_unit=flow_unit, pressure_unit=pressure_unit, max_gap=max_gap,
                                      policy=policy, date=log_date, tz=log_tz, time_column=time_column,
                                      flow_column=flow_column, pressure_column=pressure_column,
                                      time_unit=time_unit, volume_column=volume_column,
                                      cumulative_volume_column=cumulative_volume_column,
                                      volume_unit=volume_unit, accept_implausible=accept_implausible))
    plan_log_options = dict(flow_unit=flow_unit, pressure_unit=pressure_unit, max_gap=max_gap,
                            policy=policy, date=log_date, tz=log_tz)
    try:
        plan_list = [parse_plan(p, log_options=plan_log_options).check(scene.injection.control)
                     for p in (plans or DEFAULT_PLANS)]
    except PlanError as exc:
        raise BadInput(str(exc)) from None
    run_end = scene.time.end
    times = sorted(at) if at else _every(every, run_end)
    late = [t for t in times if t > run_end]
    if late:
        raise BadInput(f"--at {late[0]:g} s is after the end of the run ({run_end:g} s)")
    if not times:
        raise BadInput(f"--every {every:g} s gives no forecast time before the end of the run "
                       f"({run_end:g} s)")
    level = LEVEL_NAMES.index(advise_level)
    max_rate_si = _max_rate(max_rate, scene) if advise else None
    _check_outputs(out, plot_dir)

    if not quiet:
        click.echo(f"forecasting {scene_path} ({scene.title}) at {len(times)} time(s), "
                   f"{len(plan_list)} plan(s), horizon {format_duration(horizon)}")
    if draws is not None:
        if ladder_dt_max is None and not scene_steps:
            from ..forecast.ensemble import ENSEMBLE_LADDER

            ladder_dt_max = ENSEMBLE_LADDER
        if not quiet:
            click.echo("look-aheads on the scene's own steps" if ladder_dt_max is None else
                       f"look-aheads on a step ladder to {ladder_dt_max:g} s (times to yellow late by up "
                       f"to {ladder_dt_max:g} s; --scene-steps for the exact steps)")
        return _forecast_ensemble(scene, scene_path, drive, start, times, plan_list, horizon, draws,
                                  dict(level=level, max_rate=max_rate_si) if advise else None,
                                  confidence if confidence is not None else 0.9, workers, scheduler,
                                  out, plot_dir, quiet, ladder_dt_max)
    made = _forecasts(scene, drive, start, times, plan_list, horizon, advise, level, max_rate_si,
                      ladder_dt_max)
    click.echo(_table([f for f, _ in made], scene.injection.control))
    for line in dict.fromkeys(a.describe() for _, a in made if a is not None):
        click.echo(line)
    _write_csv(out, [f for f, _ in made])
    if not quiet:
        click.echo(f"forecasts: {out}")
    if plot_dir is not None:
        from ..plotting.forecast import plot_forecast

        by_time = {}
        for f, a in made:
            by_time.setdefault(f.made_at, ([], a))[0].append(f)
        for made_at, (fs, a) in by_time.items():
            name = (f"{scene_path.stem}-forecast.png" if len(by_time) == 1
                    else f"{scene_path.stem}-forecast-at-{made_at:g}s.png")
            path = plot_forecast(fs, plot_dir / name, spec=scene.monitor, advice=a, title=scene.title)
            if not quiet:
                click.echo(f"figure: {path}")


# replay's log options, with the log optional here (without it the scene's own drive runs)
next(p for p in forecast.params if p.name == "log_path").required = False


def _drive(scene, scene_path, log_path, end, t0, quiet, log_kw):
    """(what drives the run, date-time of model time 0, the scene to run)."""
    if log_path is None:
        if end is not None:
            raise BadInput("--end is for --log: the scene's own run ends at its time.end")
        if scene.injection.log is not None:
            return read_scene_log(scene), t0, scene
        return None, t0, scene
    log, replay = read_driving_log(scene, scene_path, log_path, end, quiet=quiet,
                                   what="a log", **log_kw)
    return log, (t0 if t0 is not None else log.start), replay.scene


def _every(step, run_end):
    if not step > 0:
        raise BadInput("--every must be > 0")
    n = int(math.floor(run_end / step * (1 + 1e-12)))
    return [k * step for k in range(1, n + 1)]


def _max_rate(text, scene):
    if text is None:
        return None
    from ..units import UnitError, split_value, to_si

    quantity = "flow_rate" if scene.injection.control == "rate" else "pressure"
    try:
        value, unit = split_value(text)
        if unit is None:
            raise ValueError(f"give the unit (e.g. {'80 L/min' if quantity == 'flow_rate' else '8 MPa'})")
        si = to_si(value, unit, quantity)
    except (ValueError, UnitError) as exc:
        raise BadInput(f"--max-rate {text!r}: {exc}") from None
    if not (math.isfinite(si) and si > 0):
        raise BadInput(f"--max-rate {text!r}: must be > 0")
    return si


def _check_outputs(out, plot_dir):
    if out.parent and not out.parent.exists():
        raise BadInput(f"--out {out}: the directory {out.parent} does not exist")
    if plot_dir is not None:
        plot_dir.mkdir(parents=True, exist_ok=True)


def _forecasts(scene, drive, start, times, plans, horizon, advise, level, max_rate, ladder_dt_max=None):
    """Run the scene through the forecast times, screened at every row; at each, the look-aheads
    of every plan (and the advice), on one step ladder when ``ladder_dt_max`` is given.
    Returns [(Forecast, Advice or None)] in order."""
    from ..screening.stepwise import StepScreening
    from ..forecast import LookAhead
    from ..forecast.lookahead import StepLadder
    from ..forecast import advise as find_advice
    from ..stepper import Simulation

    sim = Simulation(scene)
    fp = sim.disc.fault_points
    screening = StepScreening.for_scene(scene, fp.s - sim.disc.injection.s, fp.weight)
    screening.screen_simulation(sim)
    volume = drive.volume if drive is not None else None
    ladder = StepLadder(ladder_dt_max) if ladder_dt_max is not None else None
    made = []
    for t in times:
        while sim.advance(t, volume=volume, align=True, max_steps=1):
            screening.screen_simulation(sim)
        ahead = LookAhead(sim, screening, drive=drive, start=start, ladder=ladder)
        advice = find_advice(ahead, horizon, level=level, max_rate=max_rate) if advise else None
        for plan in plans:
            f = ahead.run(plan, horizon)
            if advice is not None:
                f.advised_rate = advice.rate
            made.append((f, advice))
    return made


def _fmt_time(v):
    return "-" if v is None else format_duration(v)


#: slip rates below this are shown as such, not as a number: a fault that sticks has a slip
#: rate of round-off (1e-22 to 1e-20 m/s: slip of a millimetre times 1e-16 over a step), which
#: printed as a number reads as creep; 1e-15 m/s is 30 nm a year, nine orders of magnitude
#: below the yellow rule's 1e-6 m/s (forecast.csv keeps the computed value)
SLIP_RATE_SHOWN_ABOVE = 1e-15


def _slip_rate_text(v):
    return f"< {SLIP_RATE_SHOWN_ABOVE:g} m/s" if abs(v) < SLIP_RATE_SHOWN_ABOVE else f"{v:.3g} m/s"


def _table(forecasts, control: str) -> str:
    from ..screening import LEVEL_NAMES

    head = ("made at", "plan", "now", "at horizon", "max", "to yellow", "to red", "peak slip rate",
            "max util.", "advised")
    rows = [head]
    for f in forecasts:
        advised = "-" if f.advised_rate is None else (
            f"{f.advised_rate * 60e3:.4g} L/min" if control == "rate" else f"{f.advised_rate / 1e6:.4g} MPa")
        rows.append((f"{f.made_at:g} s", f.plan, LEVEL_NAMES[f.level_now], LEVEL_NAMES[f.level_at_horizon],
                     LEVEL_NAMES[f.max_level], _fmt_time(f.time_to_yellow), _fmt_time(f.time_to_red),
                     _slip_rate_text(f.peak_slip_rate), f"{f.max_utilisation:.3f}", advised))
    return _aligned(rows)


def _aligned(rows) -> str:
    """The rows (the heading first) as left-aligned text columns."""
    widths = [max(len(str(r[i])) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(str(c).ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)


def _write_csv(path, forecasts) -> None:
    from ..forecast import COLUMNS

    _write_rows(path, COLUMNS, [f.row() for f in forecasts])


def _write_rows(path, columns, rows) -> None:
    def cell(v):
        if v is None:
            return ""
        if isinstance(v, float):
            return repr(v)
        return str(v)

    tmp = path.with_name(path.name + ".part")
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for row in rows:
            w.writerow([cell(row[c]) for c in columns])
    tmp.replace(path)


# ---- --vary/--members: the ensemble -----------------------------------------------------------
def _forecast_ensemble(scene, scene_path, drive, start, times, plans, horizon, draws, advice,
                       confidence, workers, scheduler, out, plot_dir, quiet, ladder_dt_max=None):
    """The scene's own forecasts and every member's, as tasks on the ensemble runner; the
    table, the CSV (the ensemble columns added) and the figure."""
    from ..forecast import COLUMNS
    from ..forecast.ensemble import ENSEMBLE_COLUMNS, chunks, ensemble_advice, release, run_members, summarise
    from ._runner import TaskBar, open_runner
    from ._options import RunFailed

    scene_dict = scene.to_dict()
    steps = dict(ladder=ladder_dt_max) if ladder_dt_max is not None else None   # a ladder per member
    calls = [(i, scene_dict, d, times, plans, horizon, drive, start, advice, steps)
             for i, d in enumerate(draws)]
    calls.append((-1, scene_dict, {}, times, plans, horizon, drive, start, None, steps))   # the scene itself
    if not quiet:
        click.echo(f"ensemble: {len(draws)} members and the scene itself, "
                   f"{'in this process' if workers == 0 and scheduler is None else scheduler or f'{workers} workers'}")
    calls.insert(0, calls.pop())   # the scene itself first: it and the members share a process's factors
    runs = {}
    bar = TaskBar("forecast", quiet)
    runner = open_runner(workers, scheduler)
    ensemble_id = uuid.uuid4().hex
    try:
        # one task a member: a free worker takes the next, so the workers end together; the
        # members a worker runs share the bulk's order and the factors of equal bulks
        # (forecast.ensemble.run_members)
        dealt = chunks(calls, len(runner.client.scheduler_info()["workers"]) if runner.client else 0)
        for k, chunk in runner.each(run_members, [(ensemble_id, chunk) for chunk in dealt]):
            if isinstance(chunk, BaseException):   # the worker died: its members failed
                from ..forecast.ensemble import MemberRun

                chunk = [MemberRun(index=c[0], params=c[2], error=f"worker lost: {type(chunk).__name__}: {chunk}")
                         for c in dealt[k]]
            runs.update((r.index, r) for r in chunk)
            bar(len(runs), len(calls), sum(not r.ok for r in runs.values()))
    finally:
        release(ensemble_id)   # (in this process, with --workers 0)
        runner.close()
    base, members = runs[-1], [runs[i] for i in range(len(draws))]
    ok = [r for r in members if r.ok]
    for r in members:
        if not r.ok:
            click.echo(f"member {r.index} failed ({_params_text(r.params)}): {r.error}", err=True)
    if not base.ok:
        click.echo(f"the scene itself failed: {base.error} (the deterministic columns are empty)", err=True)
    if not ok:
        raise RunFailed(f"all {len(members)} members failed; first: {members[0].error}")
    made = summarise(members, base)
    advices = {}
    if advice is not None:
        per_time = len(ok[0].advice)
        for k in range(per_time):
            found = ensemble_advice([r.advice[k] for r in ok], confidence)
            advices[found.made_at] = found
        for m in made:
            m.advised_rate = advices[m.made_at].rate
    click.echo(_ensemble_table(made, scene.injection.control))
    for found in advices.values():
        click.echo(found.describe())
    cpu = sorted(r.cpu_s for r in ok)
    if not quiet:
        click.echo(f"{len(ok)} of {len(members)} members succeeded; CPU time per member "
                   f"{cpu[len(cpu) // 2]:.3g} s (median), {cpu[-1]:.3g} s (most)")
    _write_rows(out, COLUMNS + ENSEMBLE_COLUMNS, [m.row() for m in made])
    if not quiet:
        click.echo(f"forecasts: {out}")
    if plot_dir is not None:
        from ..plotting.forecast import plot_forecast

        by_time = {}
        for m in made:
            by_time.setdefault(m.made_at, []).append(m)
        for made_at, ms in by_time.items():
            if any(m.base is None for m in ms):
                continue
            name = (f"{scene_path.stem}-forecast.png" if len(by_time) == 1
                    else f"{scene_path.stem}-forecast-at-{made_at:g}s.png")
            heading = scene.title + (f"\n{advices[made_at].describe()}" if made_at in advices else "")
            path = plot_forecast([m.base for m in ms], plot_dir / name, spec=scene.monitor,
                                 title=heading, ensemble=ms)
            if not quiet:
                click.echo(f"figure: {path}")


def _params_text(params):
    return ", ".join(f"{k} = {v:.4g}" for k, v in params.items())


def _ensemble_table(made, control: str) -> str:
    from ..screening import LEVEL_NAMES

    head = ("made at", "plan", "now", "to yellow", "P(yellow)", "P(red)", "to yellow p10", "p50",
            "p90", "members", "advised")
    rows = [head]
    for m in made:
        b = m.base
        advised = "-" if m.advised_rate is None else (
            f"{m.advised_rate * 60e3:.4g} L/min" if control == "rate" else f"{m.advised_rate / 1e6:.4g} MPa")
        rows.append((f"{m.made_at:g} s", m.plan, "-" if b is None else LEVEL_NAMES[b.level_now],
                     "-" if b is None else _fmt_time(b.time_to_yellow), f"{m.p_yellow:.2f}",
                     f"{m.p_red:.2f}", *(_fmt_time(m.percentile(q)) for q in (10, 50, 90)),
                     str(m.members), advised))
    return _aligned(rows)

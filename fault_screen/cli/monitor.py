"""``fault-screen monitor SCENE --follow LOG|-``: the live-monitoring service."""
from __future__ import annotations

import logging
import sys
from pathlib import Path

import click

from ._options import (DIR, FILE, FILE_OR_URL, BadInput, _positive_callback, _t0_callback,
                       _unit_callback, check_size, log_reading_options, reading, version_option)
from ._common import load_scene
from ._draws import ensemble_options, member_draws
from .forecast import _duration


def _sta_lta_callback(ctx, param, value):
    if value is None:
        return {}
    try:
        sta, lta, on, off = (float(x) for x in value.split(","))
    except ValueError:
        raise BadInput(f"--sta-lta {value!r}: expected STA_S,LTA_S,ON,OFF "
                       f"(e.g. 0.5,10,3.5,1)") from None
    if not (0 < sta < lta and on > off > 0):
        raise BadInput(f"--sta-lta {value!r}: need 0 < STA < LTA and ON > OFF > 0")
    return {"sta": sta, "lta": lta, "on": on, "off": off}


def _address_callback(ctx, param, value):
    if value is None:
        return None
    host, sep, port = value.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise BadInput(f"--seedlink {value!r}: expected HOST:PORT (e.g. localhost:18000)")
    return value


def _count_callback(ctx, param, value):
    if value is not None and value < 1:
        raise BadInput(f"--{param.name.replace('_', '-')} {value!r}: must be >= 1")
    return value


@click.command("monitor")
@click.argument("scene_path", type=FILE, metavar="SCENE")
@click.option("--follow", "follow", required=True, metavar="LOG|-|URL",
              help="Injection log to follow as it grows (CSV, the replay format), '-' to "
                   "read it from standard input, or the URL of a HYDWS borehole section.")
@click.option("--events", type=FILE_OR_URL, default=None, metavar="CATALOG|URL",
              help="Seismic catalogue (QuakeML, CSV or FDSN text) polled as it grows, or an "
                   "FDSN event service URL polled for new, revised and deleted events.")
@click.option("--waveforms", type=DIR, default=None, metavar="SDS_DIR",
              help="SDS waveform archive: classic STA/LTA detections as it fills.")
@click.option("--seedlink", default=None, metavar="HOST:PORT", callback=_address_callback,
              help="SeedLink server: classic STA/LTA detections on its records as they arrive "
                   "(with --seedlink-streams).")
@click.option("--seedlink-streams", default=None, metavar="NET_STA[:SEL],...",
              help="Streams to ask the SeedLink server for, e.g. 'BW_RJOB:EH?,GE_APE:BHZ'.")
@click.option("--state", type=FILE, default=None, metavar="STATE.h5",
              help="Checkpoint file: written every --checkpoint-every steps and on "
                   "SIGINT/SIGTERM; an existing one is resumed.")
@click.option("--out", "-o", type=FILE, default=None, metavar="RESULT.h5",
              help="HDF5 result file, written as the monitor goes (readable meanwhile, HDF5 "
                   "SWMR; without --state under RESULT.h5.part, renamed when it stops) and "
                   "completed when it stops. An existing file is refused unless --overwrite "
                   "(resuming from --state continues its own file).")
@click.option("--overwrite", is_flag=True,
              help="Replace an existing --out file (of an earlier run).")
@click.option("--idle-exit", type=float, default=None, metavar="SECONDS",
              callback=_positive_callback,
              help="Stop cleanly (state and results written) after this long without a new "
                   "sample; without it, run until SIGINT/SIGTERM.")
@click.option("--alert", "alerts", multiple=True, metavar="NAME[:CONFIG]",
              help="Alert plugin (repeatable): jsonl:FILE, webhook:url=URL,secret_env=VAR, "
                   "command:[\"prog\",\"arg\"]; 'fault-screen plugins' lists them.")
@click.option("--source", default=None, metavar="NAME",
              help="Source plugin [default: csv; stdin for '--follow -', hydws for a URL].")
@click.option("--poll", "poll_interval", type=float, default=0.5, show_default=True,
              metavar="S", callback=_positive_callback, help="Polling interval (s).")
@click.option("--checkpoint-every", type=int, default=50, show_default=True, metavar="N",
              callback=_count_callback, help="Steps between checkpoints.")
@click.option("--outbox", type=FILE, default=None, metavar="FILE",
              help="Alert outbox (SQLite) [default: STATE.h5.outbox.sqlite, or next to --out].")
@click.option("--flow-unit", default=None, metavar="U", callback=_unit_callback("flow_rate"),
              help="Unit of the flow-rate column when its header has none.")
@click.option("--pressure-unit", default=None, metavar="U", callback=_unit_callback("pressure"),
              help="Unit of the pressure column when its header has none.")
@click.option("--max-gap", type=float, default=600.0, show_default=True, metavar="S",
              callback=_positive_callback, help="Longest accepted interval between samples (s).")
@click.option("--policy", type=click.Choice(["stop", "skip", "hold"]), default="stop",
              show_default=True, help="On a bad line or gap: stop, skip the row, or hold the "
                                      "last good value (as replay).")
@click.option("--date", "log_date", default=None, metavar="YYYY-MM-DD",
              help="Day of the first row of a log whose stamps are times of day (as replay).")
@click.option("--tz", "log_tz", default=None, metavar="ZONE",
              help="Time zone of stamps written without an offset (IANA name, as replay).")
@click.option("--time-column", default=None, metavar="NAME|N",
              help="The log's time column, by header or 1-based position [default: detected].")
@click.option("--flow-column", default=None, metavar="NAME|N",
              help="The log's flow-rate column, by header or 1-based position.")
@click.option("--pressure-column", default=None, metavar="NAME|N",
              help="The log's pressure column, by header or 1-based position.")
@log_reading_options
@click.option("--t0", type=str, default=None, metavar="ISO", callback=_t0_callback,
              help="Date-time of model time 0 when the log has elapsed times (places events).")
@click.option("--sta-lta", "sta_lta", default=None, metavar="STA,LTA,ON,OFF",
              callback=_sta_lta_callback,
              help="STA/LTA windows (s) and trigger thresholds [default: 0.5,10,3.5,1].")
@click.option("--metrics-port", type=click.IntRange(0, 65535), default=None, metavar="PORT",
              help="Serve Prometheus metrics at http://ADDRESS:PORT/metrics.")
@click.option("--metrics-address", default="127.0.0.1", show_default=True, metavar="ADDRESS",
              help="Address the metrics are served on (0.0.0.0: every interface).")
@click.option("--plan", "plans", multiple=True, metavar="P",
              help="Look ahead under this injection plan (repeatable; the first is the one "
                   "followed): hold, stop, scene (the scene's schedule), 'rate:30 L/min', "
                   "'scale:1.2' or a log file. Forecasts are refreshed on forks of the live "
                   "model in a worker thread, stored in /lookahead of --out and alerted "
                   "(kind 'forecast') when they change [default with --horizon/--advise: hold, stop].")
@click.option("--horizon", default=None, metavar="H", callback=_duration("--horizon"),
              help="How far each look-ahead goes: seconds or a duration (1h, 30 min) [default: 1h].")
@click.option("--lookahead-every", default=None, metavar="S", callback=_duration("--lookahead-every"),
              help="Model time between look-ahead refreshes (a refresh still running when the "
                   "next is due skips it) [default: 60 s].")
@click.option("--advise", is_flag=True,
              help="Each refresh also finds the largest constant rate that stays green over "
                   "the horizon (its bisection seeks the bracket around the previous advice first).")
@click.option("--ladder", "ladder_dt_max", default=None, metavar="DT_MAX", callback=_duration("--ladder"),
              help="Look ahead on steps doubling from the live step up to DT_MAX (seconds or a "
                   "duration), each size factorised once for the whole run: faster refreshes, the "
                   "time to yellow late by up to DT_MAX [default: the scene's own steps, exact].")
@ensemble_options
@click.option("--quiet", "-q", is_flag=True, help="Only warnings and errors on stderr.")
@version_option
def monitor(scene_path, follow, events, waveforms, seedlink, seedlink_streams, state, out, overwrite, idle_exit, alerts, source,
            poll_interval, checkpoint_every, outbox, flow_unit, pressure_unit, max_gap, policy,
            log_date, log_tz, time_column, flow_column, pressure_column, time_unit,
            volume_column, cumulative_volume_column, volume_unit, accept_implausible, t0,
            sta_lta, metrics_port, metrics_address, plans, horizon, lookahead_every, advise,
            ladder_dt_max, params_path, members, distribution, seed, free, confidence, quiet):
    """Follow a growing injection log with the model of SCENE, screen every step, and alert.

    The model advances only as far as the samples allow (whole steps ending at or before the
    last sample, each receiving the log's exact volume), so a monitor run over a complete log
    takes the same steps as 'fault-screen replay' of that log.  Level changes of the scene's
    [monitor] rules go to the --alert plugins through a durable outbox (retried, also after a
    restart).  Example:

    \b
        fault-screen monitor configs/rustrel-2015-calibrated.toml --follow live.csv \\
            --state live-state.h5 --out live.h5 --alert jsonl:alerts.jsonl --idle-exit 30

    With --plan/--horizon the forecasts under the plans are refreshed on forks in a worker
    thread; with --vary PARAMS.toml --members N as well on N parameter draws, each a model of
    its own stepping with the data in that worker (P(yellow), P(red), the 10/50/90 % time to
    yellow; with --advise the largest rate whose P(yellow) is at most 1 - --confidence).
    """
    from ..io.injection_log import CLI_OPTION_NAMES, InjectionLogError
    from ..monitor.plugins import PluginError
    from ..monitor.service import MonitorConfig, MonitorInputError, MonitorService

    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(message)s")
    scene_path = Path(scene_path)
    scene = load_scene(scene_path)
    check_size(scene, str(scene_path))
    if scene.injection.control != "rate":
        raise BadInput(f"{scene_path}: injection.control = {scene.injection.control!r}: the "
                       f"monitor drives the flow rate; use a scene with control = 'rate'")
    if follow != "-" and Path(follow).is_dir():
        raise BadInput(f"--follow {follow}: is a directory, expected a log file")
    for opt, p in (("--out", out), ("--state", state)):
        if p is not None and not (p.parent if str(p.parent) else Path(".")).is_dir():
            raise BadInput(f"{opt} {p}: directory {p.parent} does not exist")
    if isinstance(events, str):      # an FDSN event service: it must answer at the start
        from ..io.fdsn_events import check_event_service

        with reading(f"--events {events}"):
            check_event_service(events)
    elif events is not None and not events.is_file():
        raise BadInput(f"--events {events}: file not found")
    if waveforms is not None and not waveforms.is_dir():
        raise BadInput(f"--waveforms {waveforms}: folder not found")
    if waveforms is not None and seedlink is not None:
        raise BadInput("--waveforms and --seedlink: give one waveform source")
    if (seedlink is None) != (seedlink_streams is None):
        raise BadInput("--seedlink and --seedlink-streams go together: the server, and the "
                       "streams to ask it for (e.g. --seedlink-streams BW_RJOB:EH?)")
    if seedlink_streams is not None:
        import re

        token = r"[A-Za-z0-9]+_[A-Za-z0-9]+(:[A-Za-z0-9?*. ]+)?"
        if not re.fullmatch(rf"{token}(,{token})*", seedlink_streams.replace(", ", ",")):
            raise BadInput(f"--seedlink-streams {seedlink_streams!r}: expected NET_STA[:SELECTORS],"
                           f"... (e.g. BW_RJOB:EH?)")
    draws = member_draws(scene, params_path, members, distribution, seed, free, confidence, advise)
    lookahead = _lookahead(plans, horizon, lookahead_every, advise, dict(
        flow_unit=flow_unit, pressure_unit=pressure_unit, max_gap=max_gap, policy=policy,
        date=log_date, tz=log_tz), ladder=ladder_dt_max,
        ensemble=None if draws is None else {"draws": draws, "confidence": confidence})
    cfg = MonitorConfig(follow=follow, state=state, out=out, events=events, waveforms=waveforms,
                        seedlink=seedlink, seedlink_streams=seedlink_streams or "",
                        idle_exit=idle_exit, alerts=list(alerts), source=source,
                        poll_interval=poll_interval, checkpoint_every=checkpoint_every,
                        outbox=outbox, flow_unit=flow_unit, pressure_unit=pressure_unit,
                        max_gap=max_gap, policy=policy, t0=t0, sta_lta=sta_lta,
                        label=str(scene_path), overwrite=overwrite, lookahead=lookahead,
                        log_options=dict(date=log_date, tz=log_tz, time_column=time_column,
                                         flow_column=flow_column, pressure_column=pressure_column,
                                         time_unit=time_unit, volume_column=volume_column,
                                         cumulative_volume_column=cumulative_volume_column,
                                         volume_unit=volume_unit,
                                         accept_implausible=accept_implausible,
                                         option_names=CLI_OPTION_NAMES))
    exporter = None
    if metrics_port is not None:
        from ..monitor.metrics_exporter import MetricsExporter

        exporter = MetricsExporter(scene)
    try:
        service = MonitorService(scene, cfg, on_update=exporter.update if exporter else None)
    except (PluginError, InjectionLogError, MonitorInputError) as exc:
        raise BadInput(str(exc)) from None
    except (ValueError, OSError) as exc:
        with reading(state):
            raise exc
    if exporter is not None:
        exporter.attach(service)
        with reading(f"--metrics-port {metrics_port}"):
            exporter.start(metrics_port, metrics_address)
    if not quiet:        # what a day of operation costs (fault_screen.run_estimate)
        from ..run_estimate import estimate_monitor
        click.echo("\n".join(estimate_monitor(scene).lines()))
    service.install_signal_handlers()
    try:
        summary = service.run()
    except (InjectionLogError, MonitorInputError) as exc:
        raise BadInput(str(exc)) from None
    finally:
        if exporter is not None:
            exporter.stop()
    if not quiet:
        click.echo(f"monitor stopped ({summary['ended']}): {summary['steps']} steps to "
                   f"t = {summary['time']:g} s from {summary['samples']} samples; level "
                   f"{summary['level']}, {summary['alerts']} alert(s)"
                   + (f", {summary['pending_alerts']} still pending"
                      if summary["pending_alerts"] else "")
                   + (f", {summary['dead_alerts']} refused for good (fault-screen plugins "
                      f"--outbox {summary['outbox']})" if summary["dead_alerts"] else ""))


def _lookahead(plans, horizon, every, advise, log_options, ladder=None, ensemble=None):
    """The look-ahead settings (MonitorConfig.lookahead), or None when none was asked for."""
    if not plans and horizon is None and every is None and not advise and ladder is None \
            and ensemble is None:
        return None
    from ..forecast import PlanError, parse_plan

    import math

    if horizon is not None and not (math.isfinite(horizon) and horizon > 0):
        raise BadInput(f"--horizon {horizon!r}: must be a finite duration > 0")
    if every is not None and not (math.isfinite(every) and every > 0):
        raise BadInput(f"--lookahead-every {every!r}: must be a finite duration > 0")
    if ladder is not None and not (math.isfinite(ladder) and ladder > 0):
        raise BadInput(f"--ladder {ladder!r}: must be a finite duration > 0 (the largest look-ahead step)")
    try:
        for p in plans:
            parse_plan(p, log_options=log_options).check("rate")
    except PlanError as exc:
        raise BadInput(str(exc)) from None
    return {"plans": list(plans) or ["hold", "stop"], "horizon": 3600.0 if horizon is None else horizon,
            "every": 60.0 if every is None else every, "advise": bool(advise),
            "plan_log_options": log_options, "ladder": ladder, "ensemble": ensemble}

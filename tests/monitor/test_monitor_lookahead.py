"""The look-ahead refreshed live in the monitor's stage: forecasts made on forks in a worker thread
while the live steps go on, stored in /lookahead, alerted when they change.

One live run of the impermeable Rustrel scene (10 s steps, the stand-in log fed sample by
sample, a refresh every 60 s of model time with the plans hold and stop, 5 min ahead) is
shared: the forecast alert it sends before the level change at 390 s, its rows against
``fault-screen forecast`` at the same model time, its arrays against the same run without
look-ahead, and a restart from its checkpoint."""
from __future__ import annotations

import csv
import math
import threading

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import CONFIGS
from fault_screen import Scene
from fault_screen.cli import main
from fault_screen.cli._options import BadInput
from fault_screen.cli.monitor import _lookahead
from fault_screen.monitor import Stage
from fault_screen.monitor.lookahead import (LOOKAHEAD_COLUMNS, LiveLookAhead, bracket,
                                            forecast_text)
from fault_screen.monitor.outbox import Outbox
from fault_screen.monitor.stage import Update

LOG = CONFIGS / "logs" / "rustrel-2015-standin.csv"
DT = 10.0
HORIZON = 300.0
EVERY = 60.0
CHECKPOINT_AT = 250.0      # model time after which the shared run writes its checkpoint
END = 460.0
FIRST_YELLOW = 390.0       # the impermeable scene's first yellow ("near failure")


def log_written_up_to(path, stamp):
    """``path``: the stand-in log as written up to the date-time ``stamp`` (ISO, as in the log)."""
    lines = LOG.read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("time,"))
    stamps = [line for line in lines[head + 1:] if line.split(",")[0] <= stamp]
    path.write_text("\n".join(lines[:head + 1] + stamps) + "\n")
    return path


def live_run(scene, log, *, lookahead=None, stage=None, checkpoint=None, end=END):
    """Feed the log sample by sample up to ``end``, waiting for each refresh (so that every due
    refresh is made: the worker is never busy at the next one); the alerts in the order the
    stage hands them out: ("level"|"forecast", alert)."""
    stage = stage or Stage(scene, start=log.start, lookahead=lookahead)
    events = []
    for k in range(log.time.size):
        upd = stage.feed_samples(log.time[k:k + 1], log.flow_rate[k:k + 1])
        done = stage.wait_forecasts()
        events += [("level", a) for a in upd.alerts]
        events += [("forecast", a) for a in upd.forecast_alerts + done.forecast_alerts]
        if checkpoint is not None and stage.time >= CHECKPOINT_AT:
            stage.checkpoint(checkpoint)
            checkpoint = None
        if stage.time >= end:
            break
    return stage, events


@pytest.fixture(scope="module")
def shared(scene_file, log, tmp_path_factory):
    scene = Scene.from_toml(scene_file)
    ckpt = tmp_path_factory.mktemp("ckpt") / "state.h5"
    la = LiveLookAhead(plans=["hold", "stop"], horizon=HORIZON, every=EVERY)
    stage, events = live_run(scene, log, lookahead=la, checkpoint=ckpt)
    return scene, stage, events, ckpt


def test_forecast_alert_precedes_the_level_change_by_its_time_to_yellow(shared):
    _, stage, events, _ = shared
    kinds = [(kind, a["model_time"]) for kind, a in events]
    level = next(i for i, (kind, a) in enumerate(events) if kind == "level" and a["level"] == "yellow")
    t_yellow = events[level][1]["model_time"]
    assert t_yellow == FIRST_YELLOW
    ahead = [a for kind, a in events[:level] if kind == "forecast"]
    assert ahead, kinds
    first = ahead[0]
    hold = first["forecasts"][0]
    assert hold["plan"] == "hold" and hold["max_level"] == "yellow"
    assert first["kind"] == "forecast" and first["summary"][0] == ["yellow", "<15 min"]
    # the lead time is the forecast's time to yellow, to one step
    lead = t_yellow - first["model_time"]
    assert first["model_time"] == 180.0 and lead == 210.0
    assert hold["time_to_yellow"] == 220.0 and abs(lead - hold["time_to_yellow"]) <= DT
    # the plan stop stays green: the text says both
    assert "yellow expected" in first["text"] and "under plan hold" in first["text"]
    assert "plan stop stays green for 5 min" in first["text"]
    # the same summaries afterwards send nothing until the level is reached ("now")
    later = [a for kind, a in events[level:] if kind == "forecast"]
    assert [a["summary"][0][1] for a in later] == ["now"]


def test_the_forecast_alert_text_places_the_yellow_on_the_clock():
    row = dict(made_at=600.0, plan="hold", horizon=3600.0, level_now="green",
               level_at_horizon="yellow", max_level="yellow", time_to_yellow=38 * 60.0,
               time_to_red=None, advised_rate=31e-3 / 60)
    stop = dict(row, plan="stop", level_at_horizon="green", max_level="green", time_to_yellow=None)
    from datetime import datetime, timezone

    start = datetime(2015, 3, 12, 13, 44, tzinfo=timezone.utc)
    text = forecast_text([row, stop], start)
    # 13:44 + 600 s + 38 min = 14:32 UTC
    assert text == ("forecast: yellow expected 14:32 UTC (in 38 min) under plan hold; plan stop "
                    "stays green for 1 h; largest rate green for 1 h: 31 L/min")


@pytest.mark.parametrize("seconds, name", [(None, "none"), (0.0, "now"), (1.0, "<15 min"),
                                           (899.9, "<15 min"), (900.0, "15-30 min"),
                                           (1799.0, "15-30 min"), (1800.0, "30-60 min"),
                                           (3600.0, ">60 min"), (7200.0, ">60 min")])
def test_time_to_yellow_brackets(seconds, name):
    assert bracket(seconds) == name


def test_lookahead_rows_equal_the_forecast_command_at_the_same_time(shared, scene_file, tmp_path):
    _, stage, _, _ = shared
    rows = stage.result().extra["lookahead"]
    assert list(rows) == list(LOOKAHEAD_COLUMNS)
    made = np.unique(rows["made_at"])
    assert list(made) == [k * EVERY for k in range(1, int(END // EVERY) + 1)]
    meta = stage.result().meta
    assert (meta["lookahead_made"], meta["lookahead_skipped"], meta["lookahead_failed"]) == (7, 0, 0)
    out = tmp_path / "f.csv"
    res = CliRunner().invoke(main, ["forecast", str(scene_file), "--log", str(LOG), "--at", "180",
                                    "--at", "300", "--horizon", str(HORIZON), "--plan", "hold",
                                    "--plan", "stop", "--out", str(out), "--quiet"])
    assert res.exit_code == 0, res.output
    with open(out, newline="") as fh:
        cli = list(csv.DictReader(fh))
    assert len(cli) == 4
    for want in cli:
        i = np.flatnonzero((rows["made_at"] == float(want["made_at"]))
                           & (rows["plan"] == want["plan"].encode()))
        assert i.size == 1
        got = {c: rows[c][i[0]] for c in LOOKAHEAD_COLUMNS}
        for c in ("level_now", "level_at_horizon", "max_level"):
            assert got[c].decode() == want[c]
        for c in ("horizon", "time_to_yellow", "time_to_red", "peak_slip_rate", "max_utilisation",
                  "induced_slip_at_horizon", "advised_rate"):
            expected = math.nan if want[c] == "" else float(want[c])
            assert got[c] == pytest.approx(expected, rel=1e-9, abs=1e-30, nan_ok=True), c
        assert got["made_at_utc"].decode().endswith("+00:00")
    # held at the rate of 180 s (the log's noise aside), yellow comes one step after the live 390 s
    hold_180 = next(r for r in cli if r["made_at"] == "180.0" and r["plan"] == "hold")
    assert float(hold_180["time_to_yellow"]) == 220.0


def _arrays(res) -> dict:
    out = {"time": res.time, "fault_x": res.fault_x}
    for group in ("fault", "injection", "balance", "solver"):
        out.update({f"{group}/{k}": v for k, v in getattr(res, group).items()})
    for group, arrays in res.extra.items():
        if group != "lookahead" and isinstance(arrays, dict):
            out.update({f"{group}/{k}": v for k, v in arrays.items() if isinstance(v, np.ndarray)})
    return out


def test_live_steps_are_bit_identical_with_and_without_lookahead(shared, log):
    scene, stage, _, _ = shared
    plain, _ = live_run(scene, log)
    a, b = _arrays(stage.result()), _arrays(plain.result())
    assert sorted(a) == sorted(b) and len(a) > 20
    for key in a:
        nan = np.asarray(a[key]).dtype.kind == "f"     # (a metric undefined at a row: NaN in both)
        assert np.array_equal(a[key], b[key], equal_nan=nan), key
    assert "lookahead" in stage.result().extra and "lookahead" not in plain.result().extra


def test_restart_makes_the_same_forecast_alerts_under_the_same_ids(shared, log, tmp_path):
    scene, stage, events, ckpt = shared
    restored, _ = Stage.restore(ckpt, scene=scene)
    resumed_at = restored.time
    assert restored.lookahead.plans[0].name == "hold" and resumed_at >= CHECKPOINT_AT
    _, again = live_run(scene, log, stage=restored)
    before = [a["id"] for kind, a in events if kind == "forecast" and a["model_time"] > resumed_at]
    after = [a["id"] for kind, a in again if kind == "forecast"]
    assert after == before and len(after) == 1
    # the outbox of the first run does not take them again
    box = Outbox(tmp_path / "box.sqlite", {"hook": object()})
    try:
        assert sum(box.put(a) for _, a in events) == len(events)
        assert sum(box.put(a) for _, a in again) == 0
    finally:
        box.close()


class Blocking:
    """A forecaster that waits for ``release`` (counting the steps the stage takes meanwhile)."""

    def __init__(self):
        self.started, self.release = threading.Event(), threading.Event()
        self.calls = []

    def forecast(self, sim_fork, plans, horizon, now_utc, *, screening, drive, start):
        self.calls.append(float(sim_fork.time))
        self.steps_at_call = sim_fork.steps   # (the live run's steps when the refresh was made)
        self.started.set()
        assert self.release.wait(60.0)
        return [dict.fromkeys(LOOKAHEAD_COLUMNS) | dict(made_at=float(sim_fork.time), plan=p.name,
                                                        horizon=horizon, level_now="green",
                                                        level_at_horizon="green", max_level="green",
                                                        made_at_utc=now_utc.isoformat())
                for p in plans]


def test_a_refresh_never_blocks_the_live_steps(scene_file, log, caplog):
    scene = Scene.from_toml(scene_file)
    slow = Blocking()
    stage = Stage(scene, start=log.start,
                  lookahead=LiveLookAhead(plans=["stop"], horizon=60.0, every=20.0, forecaster=slow))
    k = 0
    # (captured from the first sample: on a loaded machine the worker thread may start the
    # forecast a few steps after the refresh, and refreshes due meanwhile are skipped already)
    with caplog.at_level("INFO", logger="fault_screen.monitor.lookahead"):
        while not slow.started.is_set():
            stage.feed_samples(log.time[k:k + 1], log.flow_rate[k:k + 1])
            k += 1
        while stage.time < 150.0:
            upd = stage.feed_samples(log.time[k:k + 1], log.flow_rate[k:k + 1])
            assert upd.forecasts == []
            k += 1
    # refresh made at 20 s of model time -> 130 s stepped while the forecaster was blocked: 13
    # steps of 10 s (counted from the refresh: the worker thread may start its forecast later)
    assert stage.steps - slow.steps_at_call >= 12 and not slow.release.is_set()
    assert slow.calls == [20.0]
    assert stage.lookahead.skipped == 6          # due at 40, 60, ..., 140 s
    assert sum("skipped" in r.getMessage() for r in caplog.records) == 6
    slow.release.set()
    done = stage.wait_forecasts(30.0)
    assert [r["made_at"] for r in done.forecasts] == [20.0]
    assert stage.forecasts["stop"]["made_at"] == 20.0


def test_prometheus_forecast_gauges_follow_the_plan_followed():
    pytest.importorskip("prometheus_client")
    from fault_screen.monitor.metrics_exporter import MetricsExporter

    exp = MetricsExporter()
    value = lambda name: exp.registry.get_sample_value(name)  # noqa: E731
    assert math.isnan(value("fault_screen_forecast_time_to_yellow_seconds"))
    rows = [dict(plan="hold", made_at=180.0, time_to_yellow=210.0, time_to_red=None),
            dict(plan="stop", made_at=180.0, time_to_yellow=None, time_to_red=None)]
    exp.update(Update(level=0, forecasts=rows))
    assert value("fault_screen_forecast_time_to_yellow_seconds") == 210.0
    assert math.isnan(value("fault_screen_forecast_time_to_red_seconds"))
    assert math.isnan(value("fault_screen_forecast_p_yellow"))          # no ensemble
    # an ensemble's rows: the probabilities of the plan followed
    exp.update(Update(level=0, forecasts=[dict(rows[0], p_yellow=2 / 3, p_red=0.0),
                                          dict(rows[1], p_yellow=0.0, p_red=0.0)]))
    assert value("fault_screen_forecast_p_yellow") == 2 / 3 and value("fault_screen_forecast_p_red") == 0.0


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(plans=st.lists(st.text(max_size=30), max_size=3),
       horizon=st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True)))
def test_monitor_lookahead_options_parse_or_say_why(plans, horizon):
    try:
        got = _lookahead(tuple(plans), horizon, None, False, {})
    except BadInput as exc:
        assert str(exc)
        return
    if got is not None:
        assert got["horizon"] > 0 and len(got["plans"]) >= 1
        LiveLookAhead(**got)


def test_an_alert_is_handed_over_before_the_fork_of_its_step(scene_file, log):
    """The yellow at 390 s and a refresh due at 390 s: the alert reaches ``on_alert`` (the
    service's outbox) before the fork is taken, so the fork's wall time never delays it."""
    scene = Scene.from_toml(scene_file)
    order = []
    slow = Blocking()
    slow.release.set()
    stage = Stage(scene, start=log.start, on_alert=lambda a: order.append(("alert", a["model_time"])),
                  lookahead=LiveLookAhead(plans=["stop"], horizon=30.0, every=FIRST_YELLOW,
                                          forecaster=slow))
    fork = stage.sim.fork

    def recorded_fork():
        order.append(("fork", stage.time))
        return fork()
    stage.sim.fork = recorded_fork
    k = 0
    while stage.time < FIRST_YELLOW:
        stage.feed_samples(log.time[k:k + 1], log.flow_rate[k:k + 1])
        k += 1
    stage.wait_forecasts(30.0)
    assert order == [("alert", FIRST_YELLOW), ("fork", FIRST_YELLOW)]
    assert slow.calls == [FIRST_YELLOW]


@pytest.mark.parametrize("args, message", [
    (["--plan", "bogus"], "unknown plan 'bogus'"),
    (["--plan", "rate:30"], "give the unit"),
    (["--horizon", "5 parsecs"], "--horizon '5 parsecs': not a duration"),
    (["--lookahead-every", "0"], "--lookahead-every 0.0: must be a finite duration > 0"),
])
def test_monitor_refuses_bad_lookahead_options(args, message, tmp_path):
    log = tmp_path / "live.csv"
    log.write_text("elapsed[s],flow_rate[L/min]\n0,10\n")
    r = CliRunner().invoke(main, ["monitor", str(CONFIGS / "rustrel-2015-impermeable.toml"),
                                  "--follow", str(log), "--idle-exit", "1", *args])
    assert r.exit_code == 2 and message in r.output, r.output


def test_monitor_command_stores_forecasts_and_alerts_them(scene_file, tmp_path_factory):
    """The command on a log already written up to 450 s (read at once): the refresh due at
    120 s is made (the worker is idle then; the later ones may be skipped while it runs),
    stored in /lookahead and alerted as in the stage above."""
    import json

    import monitor_env
    from fault_screen import Result

    d = tmp_path_factory.mktemp("cli")
    monitor_env.activate(d / "dist")
    log_written_up_to(d / "live.csv", "2015-03-12T10:07:30")
    r = CliRunner().invoke(main, ["monitor", str(scene_file), "--follow", str(d / "live.csv"),
                                  "--idle-exit", "0.5", "--out", str(d / "live.h5"),
                                  "--alert", f"jsonl:{d / 'alerts.jsonl'}", "--plan", "scene",
                                  "--plan", "stop", "--horizon", "5min", "--lookahead-every", "2min"])
    assert r.exit_code == 0, r.output
    rows = Result.load(d / "live.h5").extra["lookahead"]
    first = np.flatnonzero(rows["made_at"] == 120.0)
    assert [rows["plan"][i].decode() for i in first] == ["scene", "stop"]
    assert rows["time_to_yellow"][first[0]] == FIRST_YELLOW - 120.0     # the scene's schedule
    assert math.isnan(rows["time_to_yellow"][first[1]])                 # stop: not within 5 min
    alerts = [json.loads(line) for line in (d / "alerts.jsonl").read_text().splitlines()]
    forecast = [a for a in alerts if a.get("kind") == "forecast"]
    assert forecast[0]["model_time"] == 120.0 and forecast[0]["summary"][0] == ["yellow", "<15 min"]
    assert [a["model_time"] for a in alerts if a.get("kind") != "forecast"] == [FIRST_YELLOW]


def test_refreshes_running_beside_the_live_steps_change_neither(shared, log):
    """Fed without waiting: the worker runs the plans while the live thread steps (refreshes due
    meanwhile are skipped). The live arrays are those of the run without look-ahead, and every
    forecast made equals the shared run's at the same model time (every column but wall_s and
    made_at_utc): the fork and the live run share the scene, the discretisation and the physics
    terms and neither writes what the other reads."""
    scene, waited, _, _ = shared
    stage = Stage(scene, start=log.start,
                  lookahead=LiveLookAhead(plans=["hold", "stop"], horizon=HORIZON, every=EVERY))
    k = 0
    overlapped = 0
    while stage.time < END:
        stage.feed_samples(log.time[k:k + 1], log.flow_rate[k:k + 1])
        overlapped += stage.lookahead.busy
        k += 1
    stage.wait_forecasts(120.0)
    assert overlapped >= 5                     # steps taken while a refresh ran
    plain, _ = live_run(scene, log)
    a, b = _arrays(stage.result()), _arrays(plain.result())
    for key in a:
        nan = np.asarray(a[key]).dtype.kind == "f"
        assert np.array_equal(a[key], b[key], equal_nan=nan), key
    mine, ref = stage.result().extra["lookahead"], waited.result().extra["lookahead"]
    assert mine["made_at"].size >= 2
    for i in range(mine["made_at"].size):
        j = np.flatnonzero((ref["made_at"] == mine["made_at"][i]) & (ref["plan"] == mine["plan"][i]))
        assert j.size == 1
        for c in LOOKAHEAD_COLUMNS:
            if c not in ("wall_s", "made_at_utc"):
                nan = ref[c].dtype.kind == "f"
                assert np.array_equal(mine[c][i], ref[c][j[0]], equal_nan=nan), c


class Recording:
    """A forecaster that records which thread runs each refresh (one quiet row per plan)."""

    def __init__(self):
        self.threads = []

    def forecast(self, sim_fork, plans, horizon, now_utc, *, screening, drive, start):
        self.threads.append(threading.current_thread())   # (an ident is reused once a thread ends)
        return [dict.fromkeys(LOOKAHEAD_COLUMNS) | dict(made_at=float(sim_fork.time), plan=p.name,
                                                        horizon=horizon, level_now="green",
                                                        level_at_horizon="green", max_level="green",
                                                        made_at_utc=now_utc.isoformat())
                for p in plans]


def test_refreshes_go_to_one_worker_thread_started_once(scene_file, log):
    """The live thread starts the worker at the first refresh only: the refreshes at 20, 40,
    ..., 120 s (6) all run in that one thread, never the live one; after close() the worker
    ends, and a refresh after it starts a new one that makes it (7 made)."""
    scene = Scene.from_toml(scene_file)
    rec = Recording()
    la = LiveLookAhead(plans=["stop"], horizon=60.0, every=20.0, forecaster=rec)
    stage = Stage(scene, start=log.start, lookahead=la)
    k = 0
    while stage.time < 120.0:
        stage.feed_samples(log.time[k:k + 1], log.flow_rate[k:k + 1])
        stage.wait_forecasts(30.0)
        k += 1
    first = la._thread
    assert la.made == 6 and len(rec.threads) == 6 and len(set(rec.threads)) == 1
    assert rec.threads[0] is first is not threading.current_thread()
    la.close()
    first.join(30.0)
    assert not first.is_alive()
    while la.made < 7:
        stage.feed_samples(log.time[k:k + 1], log.flow_rate[k:k + 1])
        stage.wait_forecasts(30.0)
        k += 1
    assert len(set(rec.threads)) == 2 and rec.threads[-1] is la._thread is not first
    la.close()

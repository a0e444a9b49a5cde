"""The monitor plugged into web services (local stand-ins of fault_screen.testing.servers, bound
to 127.0.0.1): a HYDWS section followed while it grows and goes down (the result equals a
replay of the same samples array for array), an FDSN event service revising and deleting events,
the Prometheus exposition scraped during a run, and the messages for bad services."""
from __future__ import annotations

import json
import logging
import math
import socket
import urllib.request
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

import monitor_env
from fault_screen import Result, Scene
from fault_screen.cli import main
from fault_screen.io.injection_log import read_injection_log
from fault_screen.testing.servers import EVENT_ID, FakeServices

ROOT = Path(__file__).resolve().parents[2]
STANDIN = ROOT / "configs" / "logs" / "rustrel-2015-standin.csv"


@pytest.fixture(scope="module", autouse=True)
def entry_points_visible(tmp_path_factory):
    monitor_env.activate(tmp_path_factory.mktemp("dist"))


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    """The calibrated Rustrel scene with 10 s steps (fewer steps: a faster test)."""
    return monitor_env.calibrated_scene_with_step(tmp_path_factory.mktemp("scene"), 10.0)


def short_log(folder: Path, samples: int) -> Path:
    """The bundled stand-in log cut after ``samples`` samples."""
    lines = STANDIN.read_text().splitlines()
    head = [i for i, x in enumerate(lines) if x.startswith("time,")][0]
    path = folder / f"standin-{samples}.csv"
    path.write_text("\n".join(lines[: head + 1 + samples]) + "\n")
    return path


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def datasets(path: Path) -> dict:
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, o: out.__setitem__(name, o[()])
                     if isinstance(o, h5py.Dataset) else None)
    return out


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -------------------------------------------------------------------------------------------
# HYDWS: growing, going down, the same result as a replay of the same samples
# -------------------------------------------------------------------------------------------
def test_hydws_section_followed_through_an_outage_equals_its_replay(scene_file, tmp_path,
                                                                    monkeypatch, caplog):
    monkeypatch.chdir(tmp_path)
    log = short_log(tmp_path, 100)
    caplog.set_level(logging.INFO, logger="fault_screen.sources.hydws")
    with FakeServices(log, visible=3, grow_per_request=8, down_after=5, down_for=1.0) as srv:
        r = invoke("monitor", scene_file, "--source", "hydws", "--follow", srv.hydws_url,
                   "-o", "monitor.h5", "--idle-exit", "8", "--poll", "0.1", "-q")
        # (the backoff asks again 0.2, 0.6, 1.4, 3.0 and 6.2 s after the outage: the 1 s outage
        # is over long before the idle exit, even when restarting the server is slow)
        assert r.exit_code == 0, r.output
        assert srv.outages == 1
        r = invoke("replay", scene_file, "--log", srv.hydws_url, "-o", "replay.h5", "-q")
        assert r.exit_code == 0, r.output
    # the outage logged once, and its end
    lost = [m for m in caplog.messages if "unreachable" in m]
    back = [m for m in caplog.messages if "answers again" in m]
    assert len(lost) == 1 and srv.hydws_url in lost[0] and len(back) == 1
    mon, rep = datasets(tmp_path / "monitor.h5"), datasets(tmp_path / "replay.h5")
    # no sample lost or doubled: the 100 samples of the log, at its own times
    expected = read_injection_log(log)
    assert np.array_equal(mon["log/time"], expected.time)
    assert np.array_equal(mon["log/flow_rate"], expected.flow_rate)
    assert sorted(mon) == sorted(rep) and len(mon) > 30
    different = [k for k in mon if not np.array_equal(mon[k], rep[k],
                                                      equal_nan=mon[k].dtype.kind == "f")]
    assert different == []
    assert mon["time"][-1] == expected.time[-1]          # the run ends at the last sample


def test_hydws_monitor_restarted_with_its_state_asks_from_there_and_equals_the_replay(
        scene_file, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    log = short_log(tmp_path, 60)
    args = ["monitor", scene_file, "--source", "hydws", "-o", "m.h5", "--state", "s.h5",
            "--idle-exit", "1", "--poll", "0.05", "-q"]
    with FakeServices(log, visible=30) as srv:
        r = invoke(*args, "--follow", srv.hydws_url)
        assert r.exit_code == 0, r.output
        first = len(srv.hydws_queries)
        srv.reveal(30)
        r = invoke(*args, "--follow", srv.hydws_url)
        assert r.exit_code == 0, r.output
        # the restart asked from the checkpoint's last sample (the 30th), not from the start
        resumed = srv.hydws_queries[first]
        assert resumed["starttime"] == _utc_stamp(srv.stamps[29])
        r = invoke("replay", scene_file, "--log", srv.hydws_url, "-o", "r.h5", "-q")
        assert r.exit_code == 0, r.output
    mon, rep = datasets(tmp_path / "m.h5"), datasets(tmp_path / "r.h5")
    assert np.array_equal(mon["log/time"], read_injection_log(log).time)
    assert sorted(mon) == sorted(rep)
    assert [k for k in mon if not np.array_equal(mon[k], rep[k],
                                                 equal_nan=mon[k].dtype.kind == "f")] == []


def _utc_stamp(dt):
    from datetime import timezone

    return dt.astimezone(timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")


def test_bad_answers_while_running_are_logged_once_and_asked_again(tmp_path, caplog):
    from datetime import datetime, timezone

    from fault_screen.io.log_stream import LogDecoder
    from fault_screen.monitor.event_service import EventServiceFeed
    from fault_screen_plugins.hydws import HydwsSource

    caplog.set_level(logging.INFO)
    log = short_log(tmp_path, 30)
    with FakeServices(log, visible=10) as srv:
        source = HydwsSource(srv.hydws_url, decoder=LogDecoder(srv.hydws_url),
                             poll_interval=0.01, max_backoff=0.05)
        feed = EventServiceFeed(srv.fdsn_url, datetime(2015, 3, 12, 9, tzinfo=timezone.utc),
                                interval=0.0)
        got = source.read(0.0)
        assert len(got) == 10 and len(feed.poll()) == 3
        for answer in ("malformed", "404", "html"):
            srv.answer = answer
            srv.reveal(5)
            assert source.read(0.2) == [] and feed.poll() == []
        srv.answer = "ok"
        got += source.read(0.5)
        assert feed.poll() == []                 # nothing new, nothing twice
    # the 15 samples revealed meanwhile arrive, none lost or doubled
    assert [s.time for s in got] == list(read_injection_log(log).time[:25])
    warned = [m for m in caplog.messages if "asking again" in m]
    # one warning per service, at its first bad answer (the section is asked first)
    assert len(warned) == 2 and "malformed JSON" in warned[0] and "not QuakeML" in warned[1]
    assert sum("answers again" in m for m in caplog.messages) == 2
    assert source.outages == 1 and source.failures == 0


def test_hydws_bottom_position_and_window_reach_replay(scene_file, tmp_path, monkeypatch):
    from fault_screen_plugins.hydws import hydraulics_url, read_log

    log = short_log(tmp_path, 40)
    with FakeServices(log) as srv:
        base, query, pos = hydraulics_url(srv.hydws_url[:-len("/hydraulics")] + "#bottom")
        assert (base, query, pos) == (srv.hydws_url, {}, "bottom")
        # a window of the section: stamps 09:01:00 to 09:03:00 UTC inclusive
        win = read_log(srv.hydws_url + "?starttime=2015-03-12T09:01:00&endtime=2015-03-12T09:03:00")
        full = read_injection_log(log)
        inside = [(t >= 60.0) and (t <= 180.0) for t in full.time]
        assert np.array_equal(win.time, full.time[inside] - full.time[inside][0])
        assert np.array_equal(win.flow_rate, full.flow_rate[inside])
        assert full.time[inside][0] == 70.0 and full.time[inside][-1] == 180.0
        assert win.start.isoformat() == "2015-03-12T09:01:10+00:00"


# -------------------------------------------------------------------------------------------
# FDSN event service: revised and deleted events
# -------------------------------------------------------------------------------------------
def test_fdsn_events_revised_and_deleted_while_followed(scene_file, tmp_path, monkeypatch,
                                                         caplog):
    from fault_screen.monitor import event_service

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(event_service, "POLL_INTERVAL", 0.0)
    caplog.set_level(logging.INFO, logger="fault_screen.monitor.events")
    # about 8 samples (75 s) a poll: the revision comes when the model is at ~800-900 s, past
    # event 2 (700 s, ML 1.2, below every rule) and before event 3 (1000 s)
    with FakeServices(short_log(tmp_path, 130), visible=3, grow_per_request=8,
                      revise_after=11, revised_magnitude=3.1) as srv:
        r = invoke("monitor", scene_file, "--source", "hydws", "--follow", srv.hydws_url,
                   "--events", srv.fdsn_url, "-o", "out.h5", "--alert", "jsonl:alerts.jsonl",
                   "--idle-exit", "2", "--poll", "0.05", "-q")
        assert r.exit_code == 0, r.output
        assert srv.fdsn_requests > 12
    ev = Result.load(tmp_path / "out.h5").extra["events"]
    # each event once, with its latest values; the deleted one gone
    assert list(ev["time"]) == [400.0, 700.0]
    assert list(ev["magnitude"]) == [0.6, 3.1]
    alerts = [json.loads(x) for x in (tmp_path / "alerts.jsonl").read_text().splitlines()]
    assert [(a["previous_level"], a["level"], a["rule"]) for a in alerts] == \
        [("green", "red", "large event")]
    assert alerts[0]["metrics"]["event_magnitude"] == 3.1
    assert alerts[0]["metrics"]["event_rate"] == 2.0      # events 1 and 2 in the last hour, once
    assert 700.0 < alerts[0]["model_time"] < 1000.0
    assert any(f"1 event(s) revised: {EVENT_ID.format(2)}" in m for m in caplog.messages)
    assert any(f"1 event(s) deleted: {EVENT_ID.format(3)}" in m for m in caplog.messages)


def test_fdsn_revision_while_the_monitor_was_down_is_seen_after_its_restart(
        scene_file, tmp_path, monkeypatch):
    from fault_screen.monitor import event_service

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(event_service, "POLL_INTERVAL", 0.0)
    args = ["monitor", scene_file, "--source", "hydws", "--state", "s.h5", "-o", "out.h5",
            "--alert", "jsonl:alerts.jsonl", "--idle-exit", "1", "--poll", "0.05", "-q"]
    # first run to ~750 s: events 1 and 2 (ML 1.2) screened, event 3 (1000 s) pending
    with FakeServices(short_log(tmp_path, 110), visible=80) as srv:
        r = invoke(*args, "--follow", srv.hydws_url, "--events", srv.fdsn_url)
        assert r.exit_code == 0, r.output
        assert not (tmp_path / "alerts.jsonl").exists() or \
            (tmp_path / "alerts.jsonl").read_text() == ""
        # while it is down: event 2 revised to ML 3.1, event 3 deleted; the section grows
        srv.revise_after = srv.fdsn_requests
        srv.reveal(30)
        r = invoke(*args, "--follow", srv.hydws_url, "--events", srv.fdsn_url)
        assert r.exit_code == 0, r.output
    ev = Result.load(tmp_path / "out.h5").extra["events"]
    assert list(ev["time"]) == [400.0, 700.0] and list(ev["magnitude"]) == [0.6, 3.1]
    alerts = [json.loads(x) for x in (tmp_path / "alerts.jsonl").read_text().splitlines()]
    assert [(a["level"], a["metrics"]["event_magnitude"]) for a in alerts] == [("red", 3.1)]


def test_fdsn_window_for_run_replay_and_screen(scene_file, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    log = short_log(tmp_path, 60)           # 09:00:00 to ~09:09:30 UTC: events 1 (400 s) only
    with FakeServices(log) as srv:
        r = invoke("replay", scene_file, "--log", log, "--events", srv.fdsn_url,
                   "-o", "r.h5", "-q")
        assert r.exit_code == 0, r.output
        ev = Result.load(tmp_path / "r.h5").extra["events"]
        assert list(ev["time"]) == [400.0] and list(ev["magnitude"]) == [0.6]
        # screen asks the service from the result's start on: events 1 to 3
        r = invoke("screen", tmp_path / "r.h5", "--events", srv.fdsn_url)
        assert r.exit_code == 0, r.output
        assert srv.fdsn_requests == 2
        bad = srv.base + "/broken/fdsnws/event/1/query"
        r = invoke("screen", tmp_path / "r.h5", "--events", bad)
    assert r.exit_code == 2
    assert r.output.strip().count("\n") == 0 and bad in r.output and "not QuakeML" in r.output


def test_event_service_failing_while_running_is_logged_once_and_asked_again(tmp_path, caplog):
    from datetime import datetime, timezone

    from fault_screen.monitor.event_service import EventServiceFeed

    caplog.set_level(logging.INFO, logger="fault_screen.monitor.events")
    with FakeServices(short_log(tmp_path, 20)) as srv:
        feed = EventServiceFeed(srv.fdsn_url, datetime(2015, 3, 12, 9, tzinfo=timezone.utc),
                                interval=0.0)
        assert [e.id for e in feed.poll()] == [EVENT_ID.format(k) for k in (1, 2, 3)]
        port = srv.port
        srv.stop()
        assert feed.poll() == [] and feed.poll() == []
        srv.port = port
        srv.start()
        assert feed.poll() == []                      # nothing new: each event handed on once
    warned = [m for m in caplog.messages if "unreachable" in m]
    assert len(warned) == 1 and srv.fdsn_url in warned[0]
    assert sum("answers again" in m for m in caplog.messages) == 1


def test_event_service_box_of_the_site_and_events_without_depth(tmp_path):
    from datetime import datetime, timezone

    from fault_screen.io.fdsn_events import EventServiceFollower, read_event_service, site_box
    from fault_screen.scene import SiteSpec
    from fault_screen.testing.servers import TestEvent

    start = datetime(2015, 3, 12, 9, tzinfo=timezone.utc)
    box = site_box(SiteSpec(latitude=43.9411, longitude=5.4834), half_width=20_000.0)
    assert box["maxlatitude"] - 43.9411 == pytest.approx(math.degrees(20_000.0 / 6_371_000.0),
                                                         rel=1e-12)      # 0.17987 deg
    assert box["maxlongitude"] - 5.4834 == pytest.approx(
        math.degrees(20_000.0 / 6_371_000.0) / math.cos(math.radians(43.9411)), rel=1e-12)
    events = [TestEvent(1, 400.0, 0.6), TestEvent(2, 500.0, 0.7, depth=None),
              TestEvent(3, 600.0, 0.8, latitude=44.5)]            # 62 km north of the site
    with FakeServices(short_log(tmp_path, 20), events=events) as srv:
        near = read_event_service(srv.fdsn_url, start, site=SiteSpec(latitude=43.9411,
                                                                     longitude=5.4834))
        assert list(near.time) == [400.0, 500.0]
        far = read_event_service(srv.fdsn_url, start, site=SiteSpec(latitude=46.0, longitude=8.0))
        assert len(far) == 0
        # the URL's own bounds win over the site's box
        wide = read_event_service(srv.fdsn_url + "?minlatitude=40&maxlatitude=50", start,
                                  site=SiteSpec(latitude=46.0, longitude=8.0))
        assert list(wide.time) == [400.0, 500.0, 600.0]
        follower = EventServiceFollower(srv.fdsn_url, start)
        assert len(follower.poll().ids) == 3
        again = follower.poll()            # the event without a depth is not "revised"
        assert (again.ids, again.revised, again.deleted) == ([], [], [])


# -------------------------------------------------------------------------------------------
# Prometheus
# -------------------------------------------------------------------------------------------
def scrape(port: int) -> dict:
    from prometheus_client.parser import text_string_to_metric_families

    text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read().decode()
    out = {}
    for fam in text_string_to_metric_families(text):
        for s in fam.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def test_metrics_scraped_during_a_run_hold_the_result_files_values(scene_file, tmp_path):
    from fault_screen import __version__
    from fault_screen.monitor.metrics_exporter import SCREENING, MetricsExporter, metric_name
    from fault_screen.monitor.service import MonitorConfig, MonitorService

    scene = Scene.from_toml(scene_file)
    scrapes = []
    with FakeServices(short_log(tmp_path, 60), visible=3, grow_per_request=10) as srv:
        exporter = MetricsExporter(scene)
        cfg = MonitorConfig(follow=srv.hydws_url, out=tmp_path / "out.h5", idle_exit=1.0,
                            poll_interval=0.05)      # the source of a URL: hydws

        def on_update(upd):
            exporter.update(upd)
            if upd.steps:
                scrapes.append(scrape(port))

        service = MonitorService(scene, cfg, on_update=on_update)
        assert type(service.source).__name__ == "HydwsSource"
        exporter.attach(service)
        port = exporter.start(0)
        try:
            service.run()
        finally:
            exporter.stop()
    assert len(scrapes) >= 4
    res = datasets(tmp_path / "out.h5")
    for s in scrapes:
        t = s[("fault_screen_model_time_seconds", ())]
        k = int(np.flatnonzero(res["time"] == t)[0])      # the step the scrape saw
        for m, (_, factor) in SCREENING.items():
            got, want = s[(metric_name(m), ())], res[f"screening/{m}"][k] * factor
            assert (math.isnan(got) and math.isnan(want)) or got == pytest.approx(want, rel=1e-15)
        assert s[("fault_screen_level", ())] == res["screening/level"][k]
        n = int(s[("fault_screen_samples_received_total", ())])
        assert s[("fault_screen_model_lag_seconds", ())] == res["log/time"][n - 1] - t
        assert s[("fault_screen_step_wall_seconds_count", ())] == k   # row 0: the in-situ state
        assert s[("fault_screen_events_received", ())] == 0
        assert s[("fault_screen_alerts_pending", ())] == 0
        assert s[("fault_screen_alerts_dead_letters", ())] == 0
        assert math.isnan(s[("fault_screen_forecast_time_to_yellow_seconds", ())])
        assert math.isnan(s[("fault_screen_forecast_time_to_red_seconds", ())])
        info = (("scene_title", scene.title), ("version", __version__))
        assert s[("fault_screen_info", info)] == 1.0
    assert metric_name("peak_slip_rate") == "fault_screen_peak_slip_rate_meters_per_second"
    assert metric_name("min_coulomb_margin") == "fault_screen_min_coulomb_margin_pascals"


def test_metrics_port_in_use_is_bad_input(scene_file, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        r = invoke("monitor", scene_file, "--follow", STANDIN, "--metrics-port", port,
                   "--idle-exit", "0.2")
    assert r.exit_code == 2 and f"--metrics-port {port}" in r.output
    assert "Traceback" not in r.output


# -------------------------------------------------------------------------------------------
# bad services: one line naming the URL, exit 2 at the start
# -------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def services(tmp_path_factory):
    with FakeServices(short_log(tmp_path_factory.mktemp("log"), 20)) as srv:
        yield srv


BAD = {   # (service, what is wrong) -> (URL path on the test servers, message)
    ("hydws", "unreachable"): ("/hydws/v1/boreholes/BH1/sections/S1",
                               "HYDWS server unreachable (connection refused)"),
    ("hydws", "404"): ("/hydws/v1/boreholes/BH1/sections/NOPE",
                       "HTTP 404 Not Found (no such borehole section"),
    ("hydws", "malformed"): ("/broken/hydws/v1/boreholes/BH1/sections/S1",
                             "malformed JSON in the HYDWS answer"),
    ("fdsn", "unreachable"): ("/fdsnws/event/1/query", "event service unreachable"),
    ("fdsn", "404"): ("/fdsnws/event/9/query", "event service answered with an error"),
    ("fdsn", "html"): ("/broken/fdsnws/event/1/query",
                       "the answer is not QuakeML (it starts with '<html><body>Service moved"),
}


@pytest.mark.parametrize("service,which", sorted(BAD))
@pytest.mark.parametrize("live", [True, False], ids=["monitor", "past-window"])
def test_bad_service_is_one_line_naming_it(service, which, live, services, scene_file,
                                           tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path, message = BAD[service, which]
    base = f"http://127.0.0.1:{free_port()}" if which == "unreachable" else services.base
    url = base + path
    if service == "hydws":
        args = (["monitor", scene_file, "--source", "hydws", "--follow", url] if live else
                ["replay", scene_file, "--log", url])
    else:
        args = (["monitor", scene_file, "--follow", STANDIN, "--events", url] if live else
                ["run", scene_file, "--events", url, "--t0", "2015-03-12T09:00:00Z"])
    r = invoke(*args, "-q")
    assert r.exit_code == 2, r.output
    lines = [x for x in r.output.splitlines() if x.strip()]
    assert len(lines) == 1 and url in lines[0] and message in lines[0], r.output

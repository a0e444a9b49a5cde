"""The monitor service end to end (fake stepper and screener from tests/monitor_fakes.py, real
source and alert plugins through entry points): a log written while it is followed, idle exit,
SIGTERM, standard input, catalogue events.  kill -9 and resume with the real stepper:
tests/monitor/test_monitor_resume.py."""
from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import monitor_env
from fault_screen import Result, Scene
from fault_screen.io.injection_log import read_injection_log
from fault_screen.monitor.service import MonitorConfig, MonitorService
from monitor_fakes import FakeSimulation, ThresholdScreener, run_service

ROOT = Path(__file__).resolve().parents[2]
STANDIN = ROOT / "configs" / "logs" / "rustrel-2015-standin.csv"


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    return monitor_env.calibrated_scene_with_step(tmp_path_factory.mktemp("scene"), 7.0)


def append_lines(path, lines, pause):
    with open(path, "ab") as fh:
        for line in lines:
            fh.write(line)
            fh.flush()
            time.sleep(pause)


def replay_reference(scene_file):
    """Step times and volumes of a replay of the complete log with the fake's step sequence."""
    log = read_injection_log(STANDIN)
    dt = Scene.from_toml(scene_file).time.dt
    n = int(math.floor(log.duration / dt))
    t = np.append(np.arange(n + 1) * dt, log.duration)
    return t, np.cumsum(np.concatenate(([0.0], log.step_volumes(t))))


def test_service_follows_a_log_being_written_and_exits_when_idle(dist, scene_file, tmp_path):
    live = tmp_path / "live.csv"
    live.write_bytes(b"")
    lines = STANDIN.read_bytes().splitlines(keepends=True)
    writer = threading.Thread(target=append_lines, args=(live, lines, 0.001))
    writer.start()
    summary = run_service(scene_file, live, tmp_path / "s.h5", tmp_path / "out.h5",
                          tmp_path / "alerts.jsonl", idle_exit=0.5)
    writer.join()
    assert summary["ended"] == "no new sample for 0.5 s"
    assert summary["samples"] == 162 and summary["pending_alerts"] == 0
    res = Result.load(tmp_path / "out.h5")
    t, vol = replay_reference(scene_file)
    assert np.array_equal(res.time, t)                       # the replay's steps, last one partial
    assert np.allclose(res.injection["volume"], vol, rtol=1e-14, atol=0)
    alerts = [json.loads(x) for x in (tmp_path / "alerts.jsonl").read_text().splitlines()]
    assert [(a["previous_level"], a["level"]) for a in alerts] == [("green", "yellow"),
                                                                  ("yellow", "red")]
    tr = res.extra["monitor_transitions"]
    assert list(tr["time"]) == [a["model_time"] for a in alerts]


def test_sigterm_checkpoints_and_writes_the_results_so_far(dist, scene_file, tmp_path):
    live = tmp_path / "log.csv"
    lines = STANDIN.read_bytes().splitlines(keepends=True)
    live.write_bytes(b"".join(lines[:80]))
    code = (f"import monitor_fakes as m; m.run_service({str(scene_file)!r}, {str(live)!r}, "
            f"{str(tmp_path / 's.h5')!r}, {str(tmp_path / 'out.h5')!r}, "
            f"{str(tmp_path / 'a.jsonl')!r}, idle_exit=60.0)")
    proc = subprocess.Popen([sys.executable, "-c", code], env=monitor_env.pythonpath(dist),
                            stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while not (tmp_path / "s.h5").exists() and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.3)
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 0, proc.stderr.read().decode()[-2000:]
    res = Result.load(tmp_path / "out.h5")
    log = read_injection_log(STANDIN)
    t80 = log.time[74]            # 80 lines = 5 comment/header lines + 75 samples
    assert res.time[-1] == 7.0 * math.floor(t80 / 7.0)      # aligned: no partial step
    from fault_screen.monitor import Stage

    back, extra = Stage.restore(tmp_path / "s.h5", simulation_class=FakeSimulation,
                              screener=ThresholdScreener())
    assert back.samples.count == 75 and back.time == res.time[-1]
    assert extra["decoder"]["last"][0] == t80


def test_stdin_source_through_the_service(dist, scene_file, tmp_path):
    code = (f"import monitor_fakes as m; print(m.run_service({str(scene_file)!r}, '-', "
            f"{str(tmp_path / 's.h5')!r}, {str(tmp_path / 'out.h5')!r}, "
            f"{str(tmp_path / 'a.jsonl')!r}, idle_exit=60.0)['ended'])")
    proc = subprocess.run([sys.executable, "-c", code], env=monitor_env.pythonpath(dist),
                          input=STANDIN.read_bytes(), capture_output=True, timeout=120)
    assert proc.returncode == 0, proc.stderr.decode()[-2000:]
    assert proc.stdout.decode().strip() == "source ended"
    res = Result.load(tmp_path / "out.h5")
    t, _ = replay_reference(scene_file)
    assert np.array_equal(res.time, t)


def test_unknown_alert_plugin_names_the_supported_ones(dist, scene_file, tmp_path):
    cfg = MonitorConfig(follow=str(STANDIN), alerts=["pager:x"], out=tmp_path / "o.h5")
    with pytest.raises(ValueError, match="supported: command, jsonl, webhook"):
        MonitorService(Scene.from_toml(scene_file), cfg, simulation_class=FakeSimulation,
                       screener=ThresholdScreener())


def test_catalogue_events_reach_the_rules_and_the_results(dist, scene_file, tmp_path):
    from fault_screen.scene import SiteSpec

    # the injection point in the catalogue's frame: the scene's [site]
    scene = Scene.from_toml(scene_file)
    sited = tmp_path / "sited.toml"
    sited.write_text(scene.replace(site=SiteSpec(latitude=43.9, longitude=5.5, depth=280.0,
                                                 strike=0.0, dip=90.0)).to_toml())
    cat = tmp_path / "cat.txt"            # FDSN text; the log starts 2015-03-12T09:00:00Z
    cat.write_text("#EventID | Time | Latitude | Longitude | Depth/km | Author | Catalog | "
                   "Contributor | ContributorID | MagType | Magnitude | MagAuthor | Name\n"
                   "e1|2015-03-12T09:00:30|43.9|5.5|0.38|L|c|c|1|Mw|0.4|L|R\n"
                   "e2|2015-03-12T09:00:33|43.9|5.5|0.28|L|c|c|2|Mw|2.3|L|R\n")
    run_service(sited, STANDIN, tmp_path / "s.h5", tmp_path / "out.h5",
                tmp_path / "a.jsonl", idle_exit=0.3, events=cat)
    res = Result.load(tmp_path / "out.h5")
    ev = res.extra["events"]
    assert list(ev["time"]) == [30.0, 33.0] and list(ev["magnitude"]) == [0.4, 2.3]
    assert list(ev["model_time"]) == [35.0, 35.0]          # the step (28, 35] s holds both
    assert list(ev["distance_to_injection"]) == pytest.approx([100.0, 0.0], abs=1e-6)
    first = json.loads((tmp_path / "a.jsonl").read_text().splitlines()[0])
    assert (first["level"], first["rule"], first["model_time"]) == \
        ("red", "event_magnitude >= 2", 35.0)
    assert first["metrics"]["event_magnitude"] == 2.3
    assert first["model_datetime"] == "2015-03-12T10:00:35+01:00"


class SlowSimulation(FakeSimulation):
    """A stepper slower than the idle limit: the first advance takes 0.6 s."""

    def advance(self, t_next, volume=None, align=True, max_steps=None):
        if self.k == 0:
            time.sleep(0.6)
        return super().advance(t_next, volume=volume, align=align, max_steps=max_steps)


def test_idle_time_counts_from_the_end_of_the_work(dist, scene_file, tmp_path):
    lines = STANDIN.read_bytes().splitlines(keepends=True)
    live = tmp_path / "log.csv"
    live.write_bytes(b"".join(lines[:40]))
    # the rest arrives while the first samples are being stepped (longer than --idle-exit)
    writer = threading.Timer(0.3, lambda: append_lines(live, lines[40:], 0.0))
    cfg = MonitorConfig(follow=str(live), idle_exit=0.4, poll_interval=0.02,
                        out=tmp_path / "o.h5")
    service = MonitorService(Scene.from_toml(scene_file), cfg, simulation_class=SlowSimulation,
                             screener=ThresholdScreener())
    writer.start()
    summary = service.run()
    writer.join()
    assert summary["samples"] == 162


def test_sds_detections_reach_the_results(dist, scene_file, tmp_path):
    import obspy
    from datetime import datetime, timezone

    from test_monitor_seismicity import write_sds

    write_sds(tmp_path / "sds", obspy.read())          # 30 s from 2009-08-24T00:20:03Z
    log = tmp_path / "elapsed.csv"
    log.write_text("elapsed[s],flow_rate[L/min]\n"
                   + "".join(f"{t},10\n" for t in range(0, 36, 5)))
    run_service(scene_file, log, tmp_path / "s.h5", tmp_path / "out.h5", tmp_path / "a.jsonl",
                idle_exit=0.3, waveforms=tmp_path / "sds",
                t0=datetime(2009, 8, 24, 0, 20, 3, tzinfo=timezone.utc),
                sta_lta=dict(sta=0.5, lta=5.0, on=3.0, off=1.0, merge=1.0, min_channels=2))
    ev = Result.load(tmp_path / "out.h5").extra["events"]
    # the P arrival on the three channels, merged: one detection at the earliest onset
    assert ev["kind"][0] == b"detection" and ev["time"][0] == pytest.approx(4.99, abs=1e-9)
    assert ev["model_time"][0] == 7.0                  # the first step (dt = 7 s) holds it
    assert np.isnan(ev["magnitude"][0])


def test_seedlink_detections_reach_the_results(dist, scene_file, tmp_path):
    """The same P arrival as from the SDS archive, streamed by a SeedLink server on loopback."""
    import obspy
    from datetime import datetime, timezone

    from seedlink_fake import FakeSeedLinkServer, records_of

    server = FakeSeedLinkServer(records_of(obspy.read(), interleave=True))
    log = tmp_path / "elapsed.csv"
    log.write_text("elapsed[s],flow_rate[L/min]\n"
                   + "".join(f"{t},10\n" for t in range(0, 36, 5)))
    try:
        run_service(scene_file, log, tmp_path / "s.h5", tmp_path / "out.h5", tmp_path / "a.jsonl",
                    idle_exit=2.0, seedlink=server.address, seedlink_streams="BW_RJOB:EH?",
                    t0=datetime(2009, 8, 24, 0, 20, 3, tzinfo=timezone.utc),
                    sta_lta=dict(sta=0.5, lta=5.0, on=3.0, off=1.0, merge=1.0, min_channels=2))
    finally:
        server.close()
    assert server.sent == len(server.records)
    ev = Result.load(tmp_path / "out.h5").extra["events"]
    assert ev["kind"][0] == b"detection" and ev["time"][0] == pytest.approx(4.99, abs=1e-9)
    assert ev["model_time"][0] == 7.0                  # the first step (dt = 7 s) holds it


def test_the_monitor_says_at_once_what_it_follows_and_its_first_sample(dist, scene_file,
                                                                        tmp_path, caplog):
    """Before the model is built: the log, the source, the scene, the outputs and the alert
    sinks; then the first sample's time and flow rate as read from the log."""
    import logging

    log = read_injection_log(STANDIN)
    cfg = MonitorConfig(follow=str(STANDIN), out=tmp_path / "o.h5", state=tmp_path / "s.h5",
                        alerts=[f"jsonl:{tmp_path / 'a.jsonl'}"], idle_exit=0.2,
                        poll_interval=0.02, label=str(scene_file))
    built = []

    class Recorded(FakeSimulation):
        def __init__(self, scene):
            built.append(len(caplog.records))       # how much was said before the model
            super().__init__(scene)
    with caplog.at_level(logging.INFO, logger="fault_screen.monitor"):
        service = MonitorService(Scene.from_toml(scene_file), cfg, simulation_class=Recorded,
                                 screener=ThresholdScreener())
        service.run()
    said = [r.getMessage() for r in caplog.records if r.name == "fault_screen.monitor"]
    first = said[0]
    assert built[0] >= 1 and first.startswith(f"following {STANDIN} (source csv) with the scene "
                                              f"{scene_file}")
    for part in (f"results: {tmp_path / 'o.h5'}", f"state: {tmp_path / 's.h5'}",
                 f"alerts: jsonl:{(tmp_path / 'a.jsonl').resolve()}"):
        assert part in first
    sample = next(m for m in said if m.startswith("first sample"))
    assert f"model time {log.time[0]:.6g} s, flow rate {log.flow_rate[0]:.6g} m3/s" in sample

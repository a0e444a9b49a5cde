"""``fault-screen plugins`` and the input checks of ``fault-screen monitor`` (exit 2, the option
or file named)."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from click.testing import CliRunner

import monitor_env
from fault_screen import Scene
from fault_screen.cli import main

ROOT = Path(__file__).resolve().parents[2]
SCENE = ROOT / "configs" / "rustrel-2015-calibrated.toml"
LOG = ROOT / "configs" / "logs" / "rustrel-2015-standin.csv"


@pytest.fixture(scope="module", autouse=True)
def entry_points_visible(tmp_path_factory):
    monitor_env.activate(tmp_path_factory.mktemp("dist"))


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def test_plugins_lists_every_builtin_and_describes_one():
    r = invoke("plugins")
    assert r.exit_code == 0, r.output
    for name, where in [("jsonl", "fault_screen_plugins.alerts:JsonlAlert"),
                        ("webhook", "fault_screen_plugins.alerts:WebhookAlert"),
                        ("command", "fault_screen_plugins.alerts:CommandAlert"),
                        ("csv", "fault_screen_plugins.sources:CsvFollower"),
                        ("stdin", "fault_screen_plugins.sources:StdinSource"),
                        ("hydws", "fault_screen_plugins.hydws:HydwsSource")]:
        assert f"{name:10s} {where}" in r.output
    r = invoke("plugins", "webhook")
    assert r.exit_code == 0
    assert "options: url, secret_env=None, retries=4, backoff=0.5" in r.output
    r = invoke("plugins", "pager")
    assert r.exit_code == 2
    assert "unknown plugin 'pager'; supported: command, csv, hydws, jsonl, stdin, webhook" in r.output


@pytest.mark.parametrize("args,message", [
    (["--alert", "pager"], "unknown alert plugin 'pager'; supported: command, jsonl, webhook"),
    (["--alert", "webhook:colour=red"], "alert plugin 'webhook'"),
    (["--alert", "command:ls -l"], "not a shell string"),
    (["--source", "mqtt"], "unknown source plugin 'mqtt'; supported: csv, hydws, stdin"),
    (["--sta-lta", "10,1,3,1"], "--sta-lta '10,1,3,1': need 0 < STA < LTA"),
    (["--events", "no-such-catalog.xml"], "--events no-such-catalog.xml: file not found"),
    (["--waveforms", "no-such-sds"], "--waveforms no-such-sds: folder not found"),
    (["--seedlink", "localhost"], "--seedlink 'localhost': expected HOST:PORT"),
    (["--seedlink", "localhost:18000"], "--seedlink and --seedlink-streams go together"),
    (["--seedlink", "localhost:18000", "--seedlink-streams", "RJOB"],
     "--seedlink-streams 'RJOB': expected NET_STA[:SELECTORS]"),
    (["--state", "no-such-dir/state.h5"], "--state no-such-dir/state.h5: directory"),
    (["--idle-exit", "0"], "--idle-exit 0.0: must be > 0"),
    (["--checkpoint-every", "0"], "--checkpoint-every 0: must be >= 1"),
    (["--flow-unit", "furlong"], "--flow-unit 'furlong'"),
])
def test_monitor_refuses_bad_input_naming_it(args, message, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = invoke("monitor", SCENE, "--follow", LOG, *args)
    assert r.exit_code == 2, r.output
    assert message in r.output


def test_monitor_refuses_a_pressure_controlled_scene_and_a_foreign_state(tmp_path):
    s = Scene.from_toml(SCENE)
    p = tmp_path / "p.toml"
    p.write_text(s.replace(injection=dataclasses.replace(s.injection, control="pressure",
                                                         schedule=((0.0, 1e5),))).to_toml())
    r = invoke("monitor", p, "--follow", LOG)
    assert r.exit_code == 2 and "control = 'rate'" in r.output
    bad = tmp_path / "state.h5"
    bad.write_bytes(b"not hdf5")
    r = invoke("monitor", SCENE, "--follow", LOG, "--state", bad)
    assert r.exit_code == 2 and "state.h5" in r.output
    r = invoke("monitor", SCENE)
    assert r.exit_code == 2 and "--follow" in r.output


def test_events_with_an_elapsed_log_need_t0(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    log = tmp_path / "elapsed.csv"
    log.write_text("elapsed[s],flow_rate[L/min]\n0,0\n5,10\n")
    cat = tmp_path / "cat.txt"
    cat.write_text("#EventID | Time | Latitude | Longitude | Depth/km | Author | Catalog | "
                   "Contributor | ContributorID | MagType | Magnitude | MagAuthor | Name\n")
    r = invoke("monitor", SCENE, "--follow", log, "--events", cat, "--idle-exit", "1")
    assert r.exit_code == 2
    assert "--events need the date-time of model time 0" in r.output and "--t0" in r.output

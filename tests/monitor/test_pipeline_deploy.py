"""The deployment examples of docs/deploy use what the monitor serves and accepts: every metric
the Grafana dashboard and the alerting rules name is exported (and every exported metric is on
the dashboard), and the systemd unit's command line parses with the monitor's own options."""
from __future__ import annotations

import json
import re
import shlex
from pathlib import Path

import yaml

from fault_screen import Scene
from fault_screen.monitor.metrics_exporter import MetricsExporter

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "docs" / "deploy"
NAME = re.compile(r"\bfault_screen_[a-z_]+\b")


def exported() -> set:
    reg = MetricsExporter(Scene()).registry
    return {s.name for fam in reg.collect() for s in fam.samples}


def test_dashboard_and_rules_name_only_exported_metrics_and_the_dashboard_shows_them_all():
    names = exported()
    dash = json.loads((DEPLOY / "grafana-dashboard.json").read_text())
    exprs = [t["expr"] for p in dash["panels"] for t in p["targets"]]
    on_dashboard = {n for e in exprs for n in NAME.findall(e)}
    rules = yaml.safe_load((DEPLOY / "fault-screen-alerts.yml").read_text())
    exprs = [r["expr"] for g in rules["groups"] for r in g["rules"]]
    in_rules = {n for e in exprs for n in NAME.findall(e)}
    assert sorted(on_dashboard - names) == [] and sorted(in_rules - names) == []
    families = {n for n in names if not n.endswith(("_created", "_bucket", "_count", "_sum"))}
    families |= {"fault_screen_step_wall_seconds_bucket"}
    families -= {"fault_screen_step_wall_seconds"}
    assert sorted(families - on_dashboard) == []
    # level, 11 screening metrics, 2 forecast times and the ensemble's 2 probabilities, model
    # time and lag, step wall time, samples, events, pending and dead-letter alerts, info
    assert len(families) == 24
    assert {r["alert"] for g in rules["groups"] for r in g["rules"]} >= {"FaultScreenRed",
                                                                         "FaultScreenYellow"}


def test_systemd_unit_runs_the_monitor_with_options_it_accepts():
    from fault_screen.cli.monitor import monitor

    text = (DEPLOY / "fault-screen-monitor.service").read_text()
    exec_start = re.search(r"^ExecStart=(.*?)(?<!\\)$", text, re.S | re.M).group(1)
    argv = shlex.split(exec_start.replace("\\\n", " "))
    assert argv[0].endswith("/fault-screen") and argv[1] == "monitor"
    ctx = monitor.make_context("monitor", argv[2:])
    assert ctx.params["state"] == Path("/var/lib/fault-screen/state.h5")
    assert ctx.params["metrics_port"] == 9108 and ctx.params["source"] == "hydws"
    assert "Restart=always" in text.splitlines()

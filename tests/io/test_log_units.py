"""Time units, volume columns and the plausibility check, on the Basel 2006 stimulation log as
published (days since a date, per-minute and cumulative volumes) and on misreadings of it.

The reference figures are computed here from the file with the csv module, independently of
the reader: its last time cell (days), its last cumulative volume and the sum of its per-minute
volumes.
"""
from __future__ import annotations

import csv
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from fault_screen.io.injection_log import InjectionLogError, read_injection_log
from fault_screen.io.log_stream import LogDecoder
from fault_screen.io.plausibility import check_plausible

ROOT = Path(__file__).resolve().parents[2]
#: the team's shared data lie beside the checkout (as CI lays them out)
BASEL = ROOT.parent / "shared" / "data" / "basel-2006" / "basel-2006-injection-1min.csv"
pytestmark = pytest.mark.skipif(not BASEL.exists(), reason="the Basel 2006 log is not here")


@pytest.fixture(scope="module")
def basel_cells():
    with open(BASEL, newline="") as fh:
        rows = list(csv.reader(fh))
    days = np.array([float(r[0]) for r in rows[1:]])
    per_minute = np.array([float(r[1]) for r in rows[1:]])
    cumulative = np.array([float(r[2]) for r in rows[1:]])
    return days, per_minute, cumulative


def test_basel_as_published_has_its_duration_and_volume(basel_cells):
    days, per_minute, cumulative = basel_cells
    log = read_injection_log(BASEL)            # no option: units from the column names
    assert "cumulative volume 'V_cumulative_m3' (m3)" in log.summary
    assert "(elapsed day)" in log.summary and "9310 rows" in log.summary
    # 6.4646 days, the last time cell; 11,580.7 m3, the last cumulative cell
    assert log.duration / 86400.0 == pytest.approx(days[-1] - days[0], rel=1e-12)
    assert log.total_volume == pytest.approx(cumulative[-1], rel=1e-9)
    # the volume up to a row is the file's cumulative volume there (to the steps' 1 ns ramps)
    for k in (1440, 4000, 8000):
        assert log.volume(0.0, days[k] * 86400.0) == pytest.approx(cumulative[k], abs=1e-6)
    # the peak rate, 3.65 m3/min as the README of the data says
    assert np.max(log.flow_rate) * 60 == pytest.approx(np.max(np.diff(cumulative)), rel=1e-9)


def test_basel_per_minute_volumes_give_the_same_injection(basel_cells):
    _, per_minute, cumulative = basel_cells
    log = read_injection_log(BASEL, volume_column=2)
    assert "volume per interval 'dV_m3_in_preceding_minute' (m3)" in log.summary
    # the sum of the per-minute volumes after the first row (the first is before the start)
    assert log.total_volume == pytest.approx(per_minute[1:].sum(), rel=1e-9)
    assert log.total_volume == pytest.approx(cumulative[-1], rel=1e-6)


def test_the_origin_in_the_time_columns_name_is_the_start_with_a_zone():
    log = read_injection_log(BASEL, tz="Europe/Zurich")
    assert log.start == datetime(2006, 12, 2, tzinfo=timezone(timedelta(hours=1)))


def test_time_unit_option_and_its_conflict_with_the_header(tmp_path, basel_cells):
    days, _, cumulative = basel_cells
    text = BASEL.read_text().splitlines()
    bare = tmp_path / "bare.csv"
    bare.write_text("\n".join(["elapsed,flow,V_cumulative_m3"] + text[1:]) + "\n")
    log = read_injection_log(bare, time_unit="d", cumulative_volume_column=3)
    assert log.duration == pytest.approx((days[-1] - days[0]) * 86400.0, rel=1e-12)
    assert log.total_volume == pytest.approx(cumulative[-1], rel=1e-9)
    with pytest.raises(InjectionLogError, match="conflicts with time_unit='s'"):
        read_injection_log(BASEL, time_unit="s")


def test_days_read_as_seconds_are_implausible(tmp_path):
    text = BASEL.read_text().splitlines()
    bare = tmp_path / "bare.csv"
    bare.write_text("\n".join(["elapsed,flow,V_cumulative_m3"] + text[1:]) + "\n")
    misread = read_injection_log(bare, flow_column=2, flow_unit="m3/min")
    assert misread.duration == pytest.approx(6.464583, rel=1e-6)     # days taken as seconds
    findings = check_plausible(misread.time, misread.flow_rate)
    assert [f.level for f in findings] == ["stop"] and "0.694 ms" in findings[0].message
    assert check_plausible(read_injection_log(BASEL).time, read_injection_log(BASEL).flow_rate) == []
    # the live decoder stops after the first 11 rows, as the monitor reads them
    dec = LogDecoder(str(bare), flow_column=2, flow_unit="m3/min", accept_implausible=False)
    with pytest.raises(InjectionLogError, match="ms apart") as e:
        dec.feed_lines(enumerate(bare.read_text().splitlines(), start=1))
    assert e.value.line == 12
    # a rate column in m3/min read as m3/s: 3.65 m3/s at the peak
    rates = read_injection_log(BASEL, flow_column=2, flow_unit="m3/s")
    findings = check_plausible(rates.time, rates.flow_rate)
    assert [f.level for f in findings] == ["stop"] and "3.64678 m3/s" in findings[0].message


def test_replay_stops_a_misread_with_one_line_naming_the_option(tmp_path):
    from fault_screen.cli import main

    text = BASEL.read_text().splitlines()
    bare = tmp_path / "bare.csv"
    bare.write_text("\n".join(["elapsed,flow,V_cumulative_m3"] + text[1:]) + "\n")
    scene = ROOT / "configs" / "rustrel-2015-calibrated.toml"
    res = CliRunner().invoke(main, ["replay", str(scene), "--log", str(bare), "--flow-column",
                                    "2", "--flow-unit", "m3/min", "--out",
                                    str(tmp_path / "r.h5"), "-q"])
    assert res.exit_code == 2, res.output
    error = [ln for ln in res.output.splitlines() if ln.startswith("Error:")]
    assert len(error) == 1 and "--time-unit" in error[0] and "--accept-implausible" in error[0]
    assert "9310 samples over 6.46 s" in error[0]
    assert not (tmp_path / "r.h5").exists()


def test_monitor_stops_a_misread_after_eleven_rows(tmp_path, tmp_path_factory):
    import monitor_env
    from fault_screen.cli import main

    monitor_env.activate(tmp_path_factory.mktemp("dist"))
    text = BASEL.read_text().splitlines()
    bare = tmp_path / "bare.csv"
    bare.write_text("\n".join(["elapsed,flow,V_cumulative_m3"] + text[1:]) + "\n")
    scene = ROOT / "configs" / "rustrel-2015-calibrated.toml"
    res = CliRunner().invoke(main, ["monitor", str(scene), "--follow", str(bare),
                                    "--flow-column", "2", "--flow-unit", "m3/min",
                                    "--idle-exit", "1", "-q"])
    assert res.exit_code == 2, res.output
    assert "line 12" in res.output and "0.694 ms apart" in res.output
    assert "--accept-implausible" in res.output


def test_a_replay_window_of_the_basel_log_gets_the_files_volume(basel_cells):
    from fault_screen import Scene
    from fault_screen.io.replay import plan_replay

    days, _, cumulative = basel_cells
    scene = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    log = read_injection_log(BASEL)
    end = days[2000] * 86400.0                          # the first 2000 minutes
    plan = plan_replay(scene, log, end)
    assert plan.scene.time.end == end
    assert plan.meta["log_volume"] == pytest.approx(cumulative[2000], abs=1e-6)
    # what the steps of the run receive adds up to it: 5 s steps over the window
    edges = np.append(np.arange(0.0, end, 5.0), end)
    steps = [plan.injected_volume(a, b) for a, b in zip(edges[:-1], edges[1:])]
    assert sum(steps) == pytest.approx(cumulative[2000], abs=1e-6)


@pytest.mark.parametrize("stamp", ["0001-01-01T00:00:00+05:00", "9999-12-31T23:59:59-05:00"])
def test_catalogue_stamps_at_the_calendar_edges_are_bad_rows(tmp_path, stamp):
    from fault_screen.io.events import EventsError, read_events

    cat = tmp_path / "cat.csv"
    cat.write_text(f"time,mag\n2015-03-12T10:00:00Z,1.5\n{stamp},2\n")
    with pytest.raises(EventsError, match="row 3"):
        read_events(cat)
    assert read_events(cat, bad_rows="skip").magnitude.tolist() == [1.5]

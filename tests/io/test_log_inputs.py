"""What field data does to the log and catalogue readers: line ends, encodings, cells csv cannot
split, stamps at the calendar's edges, bad rows in catalogues, and a bad line after good ones.

Each test reads the same bytes with the file reader and with the monitor's path (the csv source
plugin: LineSplitter + LogDecoder) and checks the numbers both give.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pytest

import monitor_env
from fault_screen import Result, Scene
from fault_screen.io.events import EventsError, read_events
from fault_screen.io.injection_log import InjectionLogError, read_injection_log
from fault_screen.monitor.seismicity import CatalogFollower
from fault_screen.units import parse_header

ROOT = Path(__file__).resolve().parents[2]
HEADER = "elapsed[s],flow_rate[L/min]"


@pytest.fixture(scope="module", autouse=True)
def entry_points_visible(tmp_path_factory):
    monitor_env.activate(tmp_path_factory.mktemp("dist"))


def follow(path, **options):
    """Samples and warnings of the monitor's csv source reading ``path`` to its end."""
    src, dec = monitor_env.csv_follower(path, log_name="test.inputs", **options)
    got = src.read(0.05) + src.flush() + dec.end()
    src.close()
    return got, dec


def times(samples):
    return np.array([s.time for s in samples])


def rates(samples):
    return np.array([s.flow_rate for s in samples])


# ---- line ends and encodings: the monitor reads what replay reads ----------------------------
def test_old_mac_line_ends_give_every_sample(tmp_path):
    # 3 rows at 0, 5, 10 s: 60, 120, 180 L/min = 1, 2, 3 L/s; volume 5*1.5 + 5*2.5 = 20 L
    path = tmp_path / "mac.csv"
    path.write_bytes(b"elapsed[s],flow_rate[L/min]\r0,60\r5,120\r10,180\r")
    log = read_injection_log(path)
    got, _ = follow(path)
    assert np.array_equal(times(got), [0.0, 5.0, 10.0])
    assert np.array_equal(times(got), log.time) and np.array_equal(rates(got), log.flow_rate)
    assert log.total_volume == pytest.approx(0.020, rel=1e-12)


def test_a_lone_cr_inside_a_line_is_a_line_end_and_bad_halves_follow_the_policy(tmp_path):
    # "5,\r120": the halves "5," (a stamp without value) and "120" (a stamp without value):
    # both dropped under skip; kept rows 0 s and 10 s, 1 and 3 L/s
    path = tmp_path / "cr.csv"
    path.write_bytes(b"elapsed[s],flow_rate[L/min]\n0,60\n5,\r120\n10,180\n")
    log = read_injection_log(path, policy="skip")
    got, dec = follow(path, policy="skip")
    assert np.array_equal(times(got), [0.0, 10.0]) and np.array_equal(rates(got), [1e-3, 3e-3])
    assert np.array_equal(times(got), log.time) and dec.warnings == list(log.warnings)
    assert len(log.warnings) == 2 and "line 3" in log.warnings[0] and "line 4" in log.warnings[1]
    with pytest.raises(InjectionLogError) as e:
        read_injection_log(path, policy="stop")
    assert e.value.line == 3


def test_a_huge_cell_is_a_bad_row_not_a_csv_error(tmp_path):
    # a 200,000-character cell (beyond csv's field limit of 131,072) on line 3
    path = tmp_path / "huge.csv"
    path.write_text(f"{HEADER}\n0,60\n5,\"{'9' * 200_000}\"\n10,180\n")
    for policy in ("skip", "hold"):
        log = read_injection_log(path, policy=policy)
        got, dec = follow(path, policy=policy)
        assert np.array_equal(times(got), log.time) and np.array_equal(rates(got), log.flow_rate)
        assert "line 3" in log.warnings[0] and "cannot be split into cells" in log.warnings[0]
    # the row's time is unknown too: dropped under hold as under skip
    for policy in ("skip", "hold"):
        log = read_injection_log(path, policy=policy)
        assert np.array_equal(log.time, [0.0, 10.0]) and np.array_equal(log.flow_rate, [1e-3, 3e-3])
    with pytest.raises(InjectionLogError, match="line 3"):
        read_injection_log(path)


def test_an_unbalanced_quote_is_a_bad_row(tmp_path):
    path = tmp_path / "quote.csv"
    path.write_text(f'{HEADER}\n0,60\n5,"1"2"\n10,180\n')
    log = read_injection_log(path, policy="skip")
    got, _ = follow(path, policy="skip")
    assert np.array_equal(times(got), [0.0, 10.0]) and np.array_equal(times(got), log.time)


@pytest.mark.parametrize("encoding", ["latin-1", "utf-16", "utf-8-sig"])
def test_the_monitor_reads_latin1_and_utf16_headers(tmp_path, encoding):
    # Débit in l/min with a decimal comma: 0, 6 and 12 l/min at 0, 10, 20 s -> 0.5 + 1.5 L
    text = "Zeit[s];Débit[l/min]\n0;0,0\n10;6,0\n20;12,0\n"
    path = tmp_path / "enc.csv"
    path.write_bytes(text.encode(encoding))
    log = read_injection_log(path)
    got, dec = follow(path)
    assert np.array_equal(times(got), log.time) and np.array_equal(rates(got), log.flow_rate)
    assert np.array_equal(rates(got), [0.0, 1e-4, 2e-4])
    assert log.total_volume == pytest.approx(2e-3, rel=1e-12)


def test_crlf_split_between_two_reads_is_one_line_end(tmp_path):
    from fault_screen.io.log_format import LineSplitter

    lines = LineSplitter()
    got = lines.push(b"a,b\r") + lines.push(b"\n1,2\r") + lines.push(b"\n") + lines.rest()
    assert got == [(1, "a,b"), (2, "1,2")]


# ---- stamps at the edges of the calendar -----------------------------------------------------
@pytest.mark.parametrize("stamp,why", [("0001-01-01T00:00:00+05:00", "calendar"),
                                       ("9999-12-31T23:59:59-05:00", "calendar"),
                                       ("9999-12-31T23:59:59Z", "years 1800 to 2300"),
                                       ("1799-12-31T23:59:59Z", "years 1800 to 2300")])
def test_stamps_at_the_calendar_edges_are_bad_rows(tmp_path, stamp, why):
    path = tmp_path / "edge.csv"
    path.write_text(f"time,flow_rate[L/min]\n2015-03-12T10:00:00Z,60\n{stamp},1\n"
                    f"2015-03-12T10:00:10Z,120\n")
    log = read_injection_log(path, policy="skip")
    assert np.array_equal(log.time, [0.0, 10.0]) and why in log.warnings[0]
    got, _ = follow(path, policy="skip")
    assert np.array_equal(times(got), log.time)
    with pytest.raises(InjectionLogError, match="line 3"):
        read_injection_log(path)


def test_elapsed_times_beyond_the_float_range_are_bad_rows(tmp_path):
    path = tmp_path / "big.csv"
    path.write_text("elapsed[d],flow_rate[L/min]\n0,60\n1e307,1\n1,60\n")
    assert np.array_equal(read_injection_log(path, policy="skip").time, [0.0, 86400.0])


# ---- header parsing: linear time -------------------------------------------------------------
def test_header_with_an_unclosed_bracket_and_many_blanks_is_parsed_at_once():
    # the old expression backtracked cubically: ~10 s for 3,000 blanks; a scan is linear, so
    # the header's 200,000 characters are read in a few operations per character
    header = "flow_rate[" + " " * 200_000 + "x"
    assert parse_header(header) == (header, None)
    assert parse_header("flow_rate [ L/min ]") == ("flow_rate", "L/min")
    assert parse_header("a[b]c(d)") == ("a[b]c", "d")


def test_log_and_catalogue_with_such_a_header_are_read(tmp_path):
    path = tmp_path / "hdr.csv"
    path.write_text("time[" + " " * 5000 + ",flow_rate[L/min]\n0,60\n1,60\n")
    assert read_injection_log(path).total_volume == pytest.approx(1e-3, rel=1e-12)
    cat = tmp_path / "cat.csv"
    cat.write_text("time,mag[" + " " * 5000 + "\n2015-03-12T10:00:00Z,1.0\n")
    assert read_events(cat).magnitude.tolist() == [1.0]


# ---- catalogues ------------------------------------------------------------------------------
@pytest.mark.parametrize("mag", ["inf", "-inf", "nan", "Infinity"])
def test_csv_catalogues_refuse_non_finite_magnitudes(tmp_path, mag):
    cat = tmp_path / "cat.csv"
    cat.write_text(f"time,mag\n2015-03-12T10:00:00Z,1.5\n2015-03-12T10:01:00Z,{mag}\n")
    with pytest.raises(EventsError, match="row 3, column mag: not a finite number"):
        read_events(cat)
    skipped = read_events(cat, bad_rows="skip")
    assert skipped.magnitude.tolist() == [1.5] and "row 3" in skipped.notes[0]


def test_catalog_follower_names_a_bad_row_and_still_delivers_later_events(tmp_path, caplog):
    start = datetime(2015, 3, 12, 10, 0, tzinfo=timezone.utc)
    cat = tmp_path / "cat.csv"
    cat.write_text("time,mag\n2015-03-12T10:00:10Z,0.5\nnot a time,9\n")
    follower = CatalogFollower(cat, start)
    with caplog.at_level(logging.WARNING):
        first = follower.poll()
        with open(cat, "a") as fh:
            fh.write("2015-03-12T10:00:30Z,inf\n2015-03-12T10:00:40Z,2.5\n")
        time.sleep(0.01)
        second = follower.poll()
    assert [(e.time, e.magnitude) for e in first] == [(10.0, 0.5)]
    assert [(e.time, e.magnitude) for e in second] == [(40.0, 2.5)]
    named = [r.getMessage() for r in caplog.records if "row skipped" in r.getMessage()]
    assert len(named) == 2 and "row 3" in named[0] and "row 4" in named[1]


def test_catalog_follower_never_raises_on_bad_content(tmp_path, caplog):
    start = datetime(2015, 3, 12, 10, 0, tzinfo=timezone.utc)
    cat = tmp_path / "cat.csv"
    cat.write_bytes(b"\x00\x01\x02 binary \n")
    follower = CatalogFollower(cat, start)
    with caplog.at_level(logging.WARNING):
        assert follower.poll() == [] and follower.poll() == []
    assert sum("cannot read the catalogue" in r.getMessage() for r in caplog.records) == 1
    cat.write_text("time,mag\n2015-03-12T10:00:10Z,0.5\n")
    assert [e.magnitude for e in follower.poll()] == [0.5]


# ---- a bad line after good ones in the monitor's first batch ---------------------------------
def test_a_bad_line_in_the_first_batch_keeps_the_samples_before_it(tmp_path):
    from fault_screen.monitor.service import MonitorConfig, MonitorService
    from monitor_fakes import FakeSimulation, ThresholdScreener

    scene = Scene.from_toml(ROOT / "configs" / "rustrel-2015-calibrated.toml")
    scene = scene.replace(time=dataclasses.replace(scene.time, dt=7.0))
    log = tmp_path / "live.csv"
    rows = "".join(f"{t},60\n" for t in range(0, 65, 5))       # 0..60 s, 1 L/s
    log.write_text(f"{HEADER}\n{rows}70,abc\n75,60\n")
    cfg = MonitorConfig(follow=str(log), out=tmp_path / "out.h5", state=tmp_path / "st.h5",
                        idle_exit=0.5, poll_interval=0.02)
    service = MonitorService(scene, cfg, simulation_class=FakeSimulation,
                             screener=ThresholdScreener())
    with pytest.raises(InjectionLogError, match="line 15"):
        service.run()
    res = Result.load(tmp_path / "out.h5")
    # whole 7 s steps up to the last good sample (60 s): 8 steps, 56 s, 56 L
    assert res.time[-1] == 56.0 and len(res.time) == 9
    assert service.stage.samples.count == 13
    assert service.stage.sim.rows[-1]["volume"] == pytest.approx(0.056, rel=1e-12)

"""Sample sources: a followed log that grows (writer thread), partial lines, rotation and
truncation, the replay's policies on bad lines, standard input."""
from __future__ import annotations

import io
import logging
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import monitor_env
from fault_screen.io.injection_log import InjectionLogError, read_injection_log
from fault_screen.io.log_stream import LogDecoder
from fault_screen.monitor import plugins

ROOT = Path(__file__).resolve().parents[2]
LOGS = ROOT / "configs" / "logs"
STANDIN = LOGS / "rustrel-2015-standin.csv"
GAPS = LOGS / "standin-with-gaps.csv"


# the plugins are found by their entry points (tests/monitor/conftest.py)
pytestmark = pytest.mark.usefixtures("dist")


follower = monitor_env.csv_follower


def arrays(samples):
    return (np.array([s.time for s in samples]), np.array([s.flow_rate for s in samples]))


@pytest.mark.parametrize("path,policy", [(STANDIN, "stop"), (GAPS, "skip"), (GAPS, "hold")])
def test_decoder_gives_the_replay_samples(path, policy):
    log = read_injection_log(path, policy=policy)
    dec = LogDecoder(str(path), policy=policy)
    got = []
    for n, line in enumerate(path.read_text().splitlines(), start=1):
        got += dec.feed_line(line, n)
    t, q = arrays(got)
    assert np.array_equal(t, log.time) and np.array_equal(q, log.flow_rate)
    assert dec.warnings == list(log.warnings) and dec.start == log.start


def test_decoder_stops_where_the_replay_stops():
    dec = LogDecoder(str(GAPS), policy="stop")
    with pytest.raises(InjectionLogError) as got:
        for n, line in enumerate(GAPS.read_text().splitlines(), start=1):
            dec.feed_line(line, n)
    with pytest.raises(InjectionLogError) as want:
        read_injection_log(GAPS, policy="stop")
    assert str(got.value) == str(want.value) and got.value.line == 21


def test_follower_reads_a_log_while_a_thread_writes_it(tmp_path):
    lines = STANDIN.read_bytes().splitlines(keepends=True)
    path = tmp_path / "live.csv"
    path.write_bytes(b"")
    src, dec = follower(path)
    done = threading.Event()

    def writer():
        rng = np.random.default_rng(1)
        with open(path, "ab") as fh:
            for line in lines:
                # half lines too: the reader must wait for the line end
                cut = int(rng.integers(0, len(line)))
                fh.write(line[:cut])
                fh.flush()
                time.sleep(0.0005)
                fh.write(line[cut:])
                fh.flush()
        done.set()

    th = threading.Thread(target=writer)
    th.start()
    got, reads = [], 0
    while True:
        finished = done.is_set()       # read after the writer finished: nothing may be left
        new = src.read(0.02)
        got += new
        reads += 1
        if finished and not new:
            break
    th.join()
    assert reads > 3                   # the lines did come in over several polls
    log = read_injection_log(STANDIN)
    t, q = arrays(got)
    assert np.array_equal(t, log.time) and np.array_equal(q, log.flow_rate)
    src.close()


def test_partial_last_line_waits_for_its_end_or_a_flush(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("elapsed[s],flow_rate[L/min]\n0,0\n5,10\n10,1")
    src, _ = follower(path)
    assert [s.time for s in src.poll()] == [0.0, 5.0]
    with open(path, "a") as fh:
        fh.write("2")                       # the writer completes the number: 12 L/min
    assert src.poll() == []
    assert [(s.time, s.flow_rate * 60000) for s in src.flush()] == [(10.0, pytest.approx(12.0))]


def test_rotation_and_truncation_are_followed_and_logged(tmp_path, caplog):
    path = tmp_path / "r.csv"
    header = "time,flow_rate[L/min]\n"
    path.write_text(header + "2015-03-12T10:00:00+01:00,0\n2015-03-12T10:00:05+01:00,10\n")
    src, dec = follower(path)
    caplog.set_level(logging.INFO)
    assert [s.time for s in src.poll()] == [0.0, 5.0]
    # rotation: the writer appends one more line to the old file, then a new file replaces it
    with open(path, "a") as fh:
        fh.write("2015-03-12T10:00:10+01:00,11\n")
    os.rename(path, tmp_path / "r.csv.1")
    path.write_text(header + "2015-03-12T10:00:20+01:00,12\n")
    assert [s.time for s in src.poll()] == [10.0, 20.0]   # old file finished, same clock
    assert "rotated" in caplog.text and src.rotations == 1
    # truncation (copytruncate): the file is emptied and written again, without a header
    with open(path, "w") as fh:
        fh.write("2015-03-12T10:00:30+01:00,13\n")
    assert [(s.time, round(s.flow_rate * 60000, 9)) for s in src.poll()] == [(30.0, 13.0)]
    assert "truncated" in caplog.text and src.truncations == 1
    # an old line after the truncation is checked like any other (policy stop)
    with open(path, "a") as fh:
        fh.write("2015-03-12T10:00:25+01:00,13\n")
    with pytest.raises(InjectionLogError, match="time going backwards"):
        src.poll()


def test_bad_lines_follow_the_replay_policies(tmp_path):
    text = ("elapsed[s],flow_rate[L/min],pressure[bar]\n"
            "0,0,1\n5,10,2\n5,11,2\n3,10,2\nx,10,2\n10,-1,2\n15,abc,3\n20,12,\n1000,12,4\n")
    path = tmp_path / "bad.csv"
    path.write_text(text)
    for policy in ("skip", "hold"):
        log = read_injection_log(path, policy=policy)
        src, dec = follower(path, policy=policy)
        got = src.read(0.1)
        t, q = arrays(got)
        assert np.array_equal(t, log.time) and np.array_equal(q, log.flow_rate), policy
        assert np.array_equal([s.pressure for s in got], log.pressure), policy
        assert dec.warnings == list(log.warnings), policy
    assert len(read_injection_log(path, policy="hold").warnings) == 7


def test_resume_skips_what_was_consumed_and_checks_the_rest(tmp_path):
    path = tmp_path / "res.csv"
    lines = STANDIN.read_text().splitlines()
    path.write_text("\n".join(lines[:60]) + "\n")
    src, dec = follower(path)
    first = src.read(0.1)
    state = dec.state()
    path.write_text("\n".join(lines) + "\n")        # grows, and the monitor restarts
    src2, dec2 = follower(path, resume=state)
    rest = src2.read(0.1)
    assert dec2.replayed == len(first)
    log = read_injection_log(STANDIN)
    t, q = arrays(first + rest)
    assert np.array_equal(t, log.time) and np.array_equal(q, log.flow_rate)


def test_stdin_source_reads_to_the_end():
    data = STANDIN.read_bytes()
    dec = LogDecoder("<stdin>")
    src = plugins.instantiate("source", "stdin", "-", decoder=dec, poll_interval=0.01,
                              log=logging.getLogger("test.stdin"), stream=io.BytesIO(data))
    got = []
    while not src.finished:
        got += src.read(0.2)
    t, _ = arrays(got)
    assert np.array_equal(t, read_injection_log(STANDIN).time)


DIALECTS = {
    # semicolon, decimal comma, a units row, local stamps of a named zone, Latin-1 name
    "semicolon.csv": ("Zeit;Durchfluss;Druck\n;l/min;bar\n"
                      "12.03.2015 10:00:00;0,0;1,0\n12.03.2015 10:00:05;10,5;1,5\n"
                      "12.03.2015 10:00:15;22,25;2,0\n12.03.2015 10:00:30;22,0;2,5\n",
                      dict(tz="Europe/Paris")),
    # tab-separated elapsed hh:mm:ss, flow in US gallons per minute
    "tabs.csv": ("elapsed\tflow_rate[gpm]\n00:00:00\t0\n00:00:10\t5.5\n00:01:10\t6\n"
                 "00:02:00\t6.25\n", {}),
    # times of day crossing midnight, with the day and the zone given
    "midnight.csv": ("time,rate[L/min]\n23:59:50,10\n23:59:58,11\n00:00:07,12\n00:00:20,12\n",
                     dict(date="2015-03-12", tz="UTC")),
    # a last row with a stamp but no values (a logger stopping)
    "partial.csv": ("time,flow_rate[L/min]\n2015-03-12T10:00:00Z,0\n2015-03-12T10:00:05Z,10\n"
                    "2015-03-12T10:00:10Z,11\n2015-03-12T10:00:15Z,\n", {}),
}


@pytest.mark.parametrize("name", sorted(DIALECTS))
def test_decoder_reads_the_replay_dialects_line_by_line(name, tmp_path):
    text, options = DIALECTS[name]
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    log = read_injection_log(path, **options)
    dec = LogDecoder(str(path), **options)
    got = []
    for n, line in enumerate(text.splitlines(), start=1):
        got += dec.feed_line(line, n)
    got += dec.end()
    t, q = arrays(got)
    assert np.array_equal(t, log.time) and np.array_equal(q, log.flow_rate), name
    if log.pressure is not None:
        assert np.array_equal([s.pressure for s in got], log.pressure)
    assert dec.warnings == list(log.warnings) and dec.start == log.start, name

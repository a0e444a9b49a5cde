"""Operators' log dialects (issues 13 and 14): each file is written here in the shape a
logger produces, and read back to the trapezoid volume of the values written (the reference
is computed from the written numbers with numpy, not by the reader).  Tolerance 1e-9
relative: the reader integrates exactly, so anything looser would hide a lost or shifted row
(issue 13 asks for 0.1 %)."""
from __future__ import annotations

from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from fault_screen.io import InjectionLogError, read_injection_log
from fault_screen.io.injection_log import CLI_OPTION_NAMES

LPM = 1e-3 / 60.0
GPM = 3.785411784e-3 / 60.0
RTOL = 1e-9


def trapezoid(t_s, q_si):
    t, q = np.asarray(t_s, float), np.asarray(q_si, float)
    return float(np.sum(0.5 * (q[1:] + q[:-1]) * np.diff(t)))


def rates(n, seed=1):
    """A stimulation-like rate history (L/min, 3 decimals as a logger writes them)."""
    k = np.arange(n)
    return np.round(10 + 50 * np.sin(np.pi * k / n) ** 2 + np.random.default_rng(seed).uniform(0, 2, n), 3)


def put(tmp_path, name, text, encoding="utf-8"):
    p = tmp_path / name
    p.write_bytes(text.encode(encoding))
    return p


def test_semicolon_decimal_comma_latin1_units_row_date_and_time_columns(tmp_path):
    q = rates(120)
    lines = ["# Débit mesuré au puits (enregistreur XY)", "Datum;Zeit;Débit;Druck", ";;l/min;bar"]
    t0 = datetime(2015, 3, 12, 10, 0, 0)
    for k in range(120):
        stamp = t0 + timedelta(seconds=5 * k)
        # decimal commas in both value columns; the date stays dotted
        lines.append(f"{stamp:%d.%m.%Y};{stamp:%H:%M:%S};{q[k]:.3f};{20 + k / 10:.1f}".replace(".", ",")
                     .replace(f"{stamp:%d,%m,%Y}", f"{stamp:%d.%m.%Y}"))
    text = "\r\n".join(lines) + "\r\n"
    p = put(tmp_path, "puits.csv", text, "latin-1")
    log = read_injection_log(p, tz="Europe/Zurich")
    assert log.total_volume == pytest.approx(trapezoid(5 * np.arange(120), q * LPM), rel=RTOL)
    np.testing.assert_allclose(log.pressure[[0, -1]], [20e5, (20 + 11.9) * 1e5], rtol=1e-12)
    # 10:00 CET is 09:00 UTC
    assert log.start == datetime(2015, 3, 12, 9, 0, tzinfo=timezone.utc)
    assert log.flow_unit == "L/min" and log.pressure_unit == "bar"
    for part in ("Latin-1", "semicolon-separated", "decimal comma", "units row (line 3)",
                 "time 'Zeit'", "date column 'Datum'", "Europe/Zurich", "flow 'Débit' (L/min)",
                 "pressure 'Druck' (bar)", "120 samples"):
        assert part in log.summary, (part, log.summary)


def test_tab_separated_elapsed_hhmmss_in_gpm(tmp_path):
    q = np.round(rates(50) / 3.785, 2)           # gpm values
    rows = [f"{k * 30 // 3600:02d}:{k * 30 // 60 % 60:02d}:{k * 30 % 60:02d}\t{q[k]}" for k in range(50)]
    p = put(tmp_path, "tab.txt", "elapsed\tRate (gpm)\n" + "\n".join(rows) + "\n")
    log = read_injection_log(p)
    assert log.duration == 49 * 30
    assert log.total_volume == pytest.approx(trapezoid(30 * np.arange(50), q * GPM), rel=RTOL)
    assert "tab-separated" in log.summary and "elapsed hh:mm:ss" in log.summary
    assert log.flow_unit == "gpm"


def test_time_of_day_crossing_midnight(tmp_path):
    # 23:50:00 to 00:20:00 every 10 s, local time in Zurich on 2015-03-12 (CET, +01:00)
    n = 181
    q = rates(n, seed=3)
    first = datetime(2015, 3, 12, 23, 50, 0)
    rows = [f"{first + timedelta(seconds=10 * k):%H:%M:%S},{q[k]}" for k in range(n)]
    p = put(tmp_path, "night.csv", "Time,Flowrate[L/min]\n" + "\n".join(rows) + "\n")
    log = read_injection_log(p, date="2015-03-12", tz="Europe/Zurich")
    np.testing.assert_array_equal(log.time, 10.0 * np.arange(n))
    assert log.total_volume == pytest.approx(trapezoid(10 * np.arange(n), q * LPM), rel=RTOL)
    assert log.start == datetime(2015, 3, 12, 22, 50, tzinfo=timezone.utc)
    assert len(log.warnings) == 1
    w = log.warnings[0]
    assert "line 62" in w and "00:00:00" in w and "next day" in w and "2015-03-13" in w
    assert "1 midnight roll-over" in log.summary


def test_time_of_day_needs_date_and_zone(tmp_path):
    p = put(tmp_path, "tod.csv", "Time,Flowrate[L/min]\n08:50:05,1\n08:50:10,1\n")
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(p)
    assert str(ei.value) == ("tod.csv line 2, column Time: time of day '08:50:05' without a date: "
                             "pass date=YYYY-MM-DD (the day of the first row) and tz=ZONE")
    with pytest.raises(InjectionLogError, match="--date YYYY-MM-DD"):
        read_injection_log(p, option_names=CLI_OPTION_NAMES)
    with pytest.raises(InjectionLogError, match="the time zone is unknown; pass --tz ZONE"):
        read_injection_log(p, date="2015-03-12", option_names=CLI_OPTION_NAMES)
    with pytest.raises(InjectionLogError, match="--tz 'Mars/Olympus': unknown time zone"):
        read_injection_log(p, date="2015-03-12", tz="Mars/Olympus", option_names=CLI_OPTION_NAMES)
    with pytest.raises(InjectionLogError, match="--date '12/03/2015': not a date"):
        read_injection_log(p, date="12/03/2015", tz="UTC", option_names=CLI_OPTION_NAMES)


def test_local_iso_times_with_zone_and_dst(tmp_path):
    # the spring-forward night in Zurich: 01:59:50 CET, then 03:00:00 CEST is 10 s later
    p = put(tmp_path, "dst.csv", "timestamp,q[L/s]\n2015-03-29 01:59:50,1\n2015-03-29 03:00:00,1\n")
    log = read_injection_log(p, tz="Europe/Zurich")
    np.testing.assert_array_equal(log.time, [0.0, 10.0])
    with pytest.raises(InjectionLogError, match="timestamp without time zone .* --tz ZONE"):
        read_injection_log(p, option_names=CLI_OPTION_NAMES)


def test_renamed_columns_units_in_parentheses_and_column_options(tmp_path):
    q = np.round(rates(40) / 60, 4)              # L/s
    body = "\n".join(f"{5 * k},{q[k]},{30 + k},{k % 7}" for k in range(40))
    p = put(tmp_path, "renamed.csv", "t (s),Q_inj (l/s),WHP (bar),pump\n" + body + "\n")
    log = read_injection_log(p)
    assert log.total_volume == pytest.approx(trapezoid(5 * np.arange(40), q * 1e-3), rel=RTOL)
    assert log.pressure[-1] == pytest.approx(69e5, rel=1e-12)
    assert "flow 'Q_inj (l/s)' (L/s)" in log.summary and "pressure 'WHP (bar)' (bar)" in log.summary
    # the same columns named by the user, by header and by position; 'pump' as the flow column
    log2 = read_injection_log(p, time_column="t", flow_column="4", pressure_column="WHP (bar)",
                              flow_unit="L/min")
    assert log2.total_volume == pytest.approx(
        trapezoid(5 * np.arange(40), (np.arange(40) % 7) * LPM), rel=RTOL)
    with pytest.raises(InjectionLogError, match=r"--flow-column 'Debit': no such column; columns: "
                                                r"t \(s\), Q_inj \(l/s\), WHP \(bar\), pump"):
        read_injection_log(p, flow_column="Debit", option_names=CLI_OPTION_NAMES)
    with pytest.raises(InjectionLogError, match="--time-column '9': the header has 4 columns"):
        read_injection_log(p, time_column=9, option_names=CLI_OPTION_NAMES)


def test_several_candidate_columns_name_the_option(tmp_path):
    p = put(tmp_path, "two.csv", "time,flow_in[L/min],flow_out[L/min]\n0,1,1\n5,1,1\n")
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(p, option_names=CLI_OPTION_NAMES)
    assert "several flow-rate columns (flow_in[L/min], flow_out[L/min]): choose one " \
           "with --flow-column" in str(ei.value)
    assert read_injection_log(p, flow_column="flow_in").total_volume == pytest.approx(5 * LPM)


def test_trailing_partial_row_dropped_with_warning(tmp_path):
    q = rates(30)
    body = "\n".join(f"2015-03-12T17:0{k // 12}:{k % 12 * 5:02d}+01:00,{q[k]},{10 + k}" for k in range(30))
    p = put(tmp_path, "end.csv", "Time,Flowrate[L/min],Pressure[bar]\n" + body
            + "\n2015-03-12T17:10:00+01:00,,\n")
    log = read_injection_log(p)          # default policy "stop"
    assert log.time.size == 30
    assert log.total_volume == pytest.approx(trapezoid(5 * np.arange(30), q * LPM), rel=RTOL)
    assert log.warnings == ("end.csv line 32: last row has a time stamp but no values (a partial "
                            "row written when the logger stopped); dropped",)
    # an empty value in the middle is still an error under "stop"
    p = put(tmp_path, "mid.csv", "time,q[L/min]\n0,1\n5,\n10,1\n")
    with pytest.raises(InjectionLogError, match="line 3, column q.L/min.: bad|empty cell"):
        read_injection_log(p)


@pytest.mark.parametrize("head, sign", [(b"PK\x03\x04\x14\x00\x06\x00", "Excel .xlsx"),
                                        (b"\x00\x01\x98\x00\xff" * 20, "not a text file")])
def test_binary_file_one_clear_message(tmp_path, head, sign):
    p = tmp_path / "log.xlsx"
    p.write_bytes(head + bytes(range(256)))
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(p)
    msg = str(ei.value)
    assert msg.startswith("log.xlsx: not a text file") and sign in msg
    assert "codec" not in msg


def test_utf16_and_cp1252_text(tmp_path):
    text = "# Débit\ntime;débit[l/min]\n0;1,5\n60;1,5\n"
    for enc, name in (("utf-16", "UTF-16"), ("cp1252", "Latin-1")):
        p = put(tmp_path, f"{enc}.csv", text, enc)
        log = read_injection_log(p)
        assert log.total_volume == pytest.approx(90 * LPM, rel=1e-12)
        assert name in log.summary


@pytest.mark.parametrize("cell, needle", [
    ("1e9", "flow rate 1e9 L/min is outside the plausible range 0 to 600000 L/min (0 to 10 m3/s)"),
    ("-5", "negative flow rate -5"),
])
def test_absurd_flow_refused_with_range(tmp_path, cell, needle):
    p = put(tmp_path, "big.csv", f"time,flow_rate[L/min]\n0,1\n5,{cell}\n10,1\n")
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(p)
    assert ei.value.line == 3 and needle in str(ei.value)


def test_absurd_pressure_refused_with_range(tmp_path):
    p = put(tmp_path, "p.csv", "time,flow_rate[L/min],pressure[psi]\n0,1,100\n5,1,2e6\n")
    with pytest.raises(InjectionLogError, match=r"line 3, column pressure\[psi\]: pressure 2e6 psi "
                                                r"is outside the plausible range -145.038 to 145038 psi"):
        read_injection_log(p)


def test_messages_name_the_keyword_or_the_option(tmp_path):
    p = put(tmp_path, "nounit.csv", "time,rate\n0,1\n60,1\n")
    with pytest.raises(InjectionLogError, match="or pass flow_unit=;"):
        read_injection_log(p)
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(p, option_names=CLI_OPTION_NAMES)
    assert "or pass --flow-unit;" in str(ei.value) and "flow_unit=" not in str(ei.value)
    p = put(tmp_path, "gap.csv", "time,rate[L/min]\n0,1\n700,1\n")
    with pytest.raises(InjectionLogError, match="exceeds --max-gap 600 s"):
        read_injection_log(p, option_names=CLI_OPTION_NAMES)

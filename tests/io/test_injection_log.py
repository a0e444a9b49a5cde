from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest

from fault_screen.io.injection_log import (
    HOLD_EPS,
    InjectionLog,
    InjectionLogError,
    read_injection_log,
)

LOGS = Path(__file__).resolve().parents[2] / "configs" / "logs"
LPM = 1e-3 / 60.0  # 1 L/min in m3/s


def write(tmp_path, text, name="log.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


# Hand log: rates 0, 60, 30, 30, 0 L/min at t = 0, 10, 25, 60, 65 s.
# Trapezoids: 0-10: 30 L/min*10 s = 5 L; 10-25: 45*15/60 = 11.25 L;
#             25-60: 30*35/60 = 17.5 L; 60-65: 15*5/60 = 1.25 L.  Total 35 L.
HAND = """# hand-made test log
elapsed[s],flow_rate[L/min],pressure[MPa]
0,0,1.0
10,60,2.0
25,30,1.5
60,30,1.5
65,0,1.0
"""


@pytest.fixture
def hand(tmp_path):
    return read_injection_log(write(tmp_path, HAND, "hand.csv"))


def test_hand_log_arrays(hand):
    np.testing.assert_array_equal(hand.time, [0, 10, 25, 60, 65])
    np.testing.assert_allclose(hand.flow_rate, np.array([0, 60, 30, 30, 0]) * LPM, rtol=1e-15)
    np.testing.assert_allclose(hand.pressure, [1e6, 2e6, 1.5e6, 1.5e6, 1e6])
    assert hand.start is None
    assert hand.source.endswith("hand.csv")
    assert hand.warnings == ()
    assert hand.time.dtype == np.float64


def test_hand_log_volumes(hand):
    assert hand.total_volume == pytest.approx(35e-3, rel=1e-13)
    # 5-10 s: rate 30 -> 60 L/min: 45*5/60 = 3.75 L; 10-25: 11.25 L; 25-40: 7.5 L
    assert hand.volume(5, 40) == pytest.approx(22.5e-3, rel=1e-13)
    assert hand.volume(-100, 1000) == pytest.approx(35e-3, rel=1e-13)
    assert hand.volume(70, 80) == 0.0
    assert hand.volume(40, 5) == pytest.approx(-22.5e-3, rel=1e-13)
    # within one segment: 10-25 s, rate 60 -> 30 (-2 L/min per s); 12-14 s: 56 -> 52, 54*2/60 L
    assert hand.volume(12, 14) == pytest.approx(54 * 2 / 60 * 1e-3, rel=1e-13)


def test_rate_at(hand):
    assert hand.rate_at(5.0) == pytest.approx(30 * LPM)
    assert hand.rate_at(17.5) == pytest.approx(45 * LPM)
    assert hand.rate_at(-1.0) == 0.0
    assert hand.rate_at(70.0) == 0.0
    np.testing.assert_allclose(hand.rate_at([0, 10, 65]), [0, 60 * LPM, 0])


def test_step_volumes(hand):
    v = hand.step_volumes([0, 10, 25, 60, 65])
    np.testing.assert_allclose(v, np.array([5, 11.25, 17.5, 1.25]) * 1e-3, rtol=1e-13)
    times = np.linspace(-7.0, 90.0, 23)
    assert hand.step_volumes(times).sum() == pytest.approx(hand.total_volume, rel=1e-13)
    with pytest.raises(ValueError):
        hand.step_volumes([10, 5])


def test_log_is_frozen(hand):
    with pytest.raises(Exception):
        hand.time = np.zeros(5)
    with pytest.raises(ValueError):
        hand.time[0] = 1.0  # read-only array


def test_to_csv_roundtrip(hand, tmp_path):
    out = tmp_path / "out.csv"
    hand.to_csv(out)
    back = read_injection_log(out)
    np.testing.assert_array_equal(back.time, hand.time)
    np.testing.assert_array_equal(back.flow_rate, hand.flow_rate)
    np.testing.assert_array_equal(back.pressure, hand.pressure)


# ---------------------------------------------------------------------------
# time stamps
# ---------------------------------------------------------------------------


def test_timestamps_different_zones(tmp_path):
    p = write(tmp_path, "time,flow_rate[L/min]\n"
                        "2015-03-12T10:00:00+01:00,6\n"
                        "2015-03-12T09:00:30Z,6\n"
                        "2015-03-12T04:01:00-05:00,6\n"
                        "2015-03-12 11:01:30.5+02:00,6\n")
    log = read_injection_log(p)
    np.testing.assert_array_equal(log.time, [0.0, 30.0, 60.0, 90.5])
    assert log.start == datetime(2015, 3, 12, 9, 0, tzinfo=timezone.utc)
    assert log.start.utcoffset() == timedelta(hours=1)  # zone of the first stamp kept
    assert log.total_volume == pytest.approx(6 * LPM * 90.5, rel=1e-14)


def test_timestamp_without_zone_refused(tmp_path):
    p = write(tmp_path, "time,flow_rate[L/min]\n"
                        "2015-03-12T10:00:00+01:00,6\n"
                        "2015-03-12T10:00:30,6\n")
    for policy in ("stop", "skip", "hold"):
        with pytest.raises(InjectionLogError) as ei:
            read_injection_log(p, policy=policy)
        assert ei.value.line == 3
        assert "time zone" in str(ei.value) and "2015-03-12T10:00:30" in str(ei.value)


def test_elapsed_minutes_header(tmp_path):
    p = write(tmp_path, "elapsed[min],q[m3/h]\n0,3.6\n1,3.6\n2.5,0\n")
    log = read_injection_log(p)
    np.testing.assert_array_equal(log.time, [0, 60, 150])
    assert log.total_volume == pytest.approx(1e-3 * 60 + 1e-3 * 90 / 2, rel=1e-14)


def test_elapsed_time_shifted_to_first_stamp(tmp_path):
    log = read_injection_log(write(tmp_path, "time,rate[L/s]\n100,1\n110,1\n"))
    np.testing.assert_array_equal(log.time, [0, 10])


# ---------------------------------------------------------------------------
# units
# ---------------------------------------------------------------------------


def test_flow_unit_argument(tmp_path):
    p = write(tmp_path, "time,rate,pressure\n0,1,100\n60,1,200\n")
    log = read_injection_log(p, flow_unit="bbl/min", pressure_unit="psi")
    assert log.total_volume == pytest.approx(0.158987294928, rel=1e-12)
    np.testing.assert_allclose(log.pressure, [689475.7293168, 1378951.4586336])


def test_missing_unit_names_column(tmp_path):
    p = write(tmp_path, "# c\ntime,rate\n0,1\n60,1\n")
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(p)
    assert ei.value.column == "rate" and ei.value.line == 2
    assert "flow_unit" in str(ei.value) and "column rate" in str(ei.value)
    p = write(tmp_path, "time,q[L/min],pressure\n0,1,1\n60,1,1\n")
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(p)
    assert ei.value.column == "pressure" and "pressure_unit" in str(ei.value)


def test_bad_and_conflicting_units(tmp_path):
    p = write(tmp_path, "time,flow_rate[gal/fortnight]\n0,1\n60,1\n")
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(p)
    assert "gal/fortnight" in str(ei.value) and "L/min" in str(ei.value)
    p = write(tmp_path, "time,flow_rate[L/min]\n0,1\n60,1\n")
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(p, flow_unit="m3/s")
    assert "conflicts" in str(ei.value)
    assert read_injection_log(p, flow_unit="lpm").total_volume == pytest.approx(1e-3)


def test_missing_columns(tmp_path):
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(write(tmp_path, "date,flow_rate[L/min]\n0,1\n1,1\n"))
    assert "time" in str(ei.value) and ei.value.line == 1
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(write(tmp_path, "time,level[m]\n0,1\n1,1\n"))
    assert "flow-rate" in str(ei.value) and "--volume-column" not in str(ei.value)


def test_a_volume_column_is_read_as_the_volume_of_each_interval(tmp_path):
    # 1 L in the interval 0-1 s and 3 L in 1-3 s: 4 L in all, 1 L/s then 1.5 L/s; the first
    # row's litre was injected before the first stamp and is not part of the run
    log = read_injection_log(write(tmp_path, "time,volume[L]\n0,1\n1,1\n3,3\n"))
    assert log.total_volume == pytest.approx(4e-3, rel=1e-12)
    assert log.volume(0.0, 1.0) == pytest.approx(1e-3, rel=1e-8)
    assert log.rate_at(2.0) == pytest.approx(1.5e-3, rel=1e-12)
    assert any("before the log's first stamp" in w for w in log.warnings)


# ---------------------------------------------------------------------------
# bad input: line numbers and messages
# ---------------------------------------------------------------------------

BASE = ["# comment line 1", "", "time,flow_rate[L/min]",  # header is line 3
        "0,10", "10,10", "20,10", "30,10", "40,10"]       # data on lines 4..8


def with_line(lineno, text, name="rustrel.csv"):
    lines = list(BASE)
    lines[lineno - 1] = text
    return "\n".join(lines) + "\n", name


@pytest.mark.parametrize(
    "lineno, text, column, needles",
    [
        (6, "20,-3.2", "flow_rate[L/min]", ["negative flow rate -3.2"]),
        (5, "10,abc", "flow_rate[L/min]", ["non-numeric", "abc"]),
        (7, "30,", "flow_rate[L/min]", ["empty cell"]),
        (7, "30,nan", "flow_rate[L/min]", ["nan"]),
        (6, "5,10", "time", ["backwards", "5"]),
        (6, "10,10", "time", ["duplicate", "10", "line 5"]),
        (6, "x12,10", "time", ["x12"]),
        (8, "1000,10", "time", ["gap", "970", "600"]),
    ],
)
def test_bad_input_stop(tmp_path, lineno, text, column, needles):
    body, name = with_line(lineno, text)
    p = write(tmp_path, body, name)
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(p)
    err = ei.value
    assert isinstance(err, ValueError)
    assert err.line == lineno
    assert err.column == column
    msg = str(err)
    assert msg.startswith(f"rustrel.csv line {lineno}, column {column}: ")
    for n in needles:
        assert n in msg


def test_negative_message_exact(tmp_path):
    body, name = with_line(6, "20,-3.2")
    with pytest.raises(InjectionLogError, match=r"^rustrel\.csv line 6, column "
                       r"flow_rate\[L/min\]: negative flow rate -3\.2 \(flowback: set "
                       r"injection\.allow_flowback = true in the scene\)$"):
        read_injection_log(write(tmp_path, body, name))


def test_too_few_rows(tmp_path):
    p = write(tmp_path, "time,flow_rate[L/min]\n0,1\n")
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(p)
    assert ei.value.line == 2 and "too few" in str(ei.value)
    p = write(tmp_path, "time,flow_rate[L/min]\n0,1\n10,-1\n")
    with pytest.raises(InjectionLogError, match="too few"):
        read_injection_log(p, policy="skip")


def test_max_gap_configurable(tmp_path):
    p = write(tmp_path, "time,flow_rate[L/min]\n0,1\n700,1\n")
    with pytest.raises(InjectionLogError, match="gap"):
        read_injection_log(p)
    assert read_injection_log(p, max_gap=800).total_volume == pytest.approx(700 * LPM)
    assert read_injection_log(p, max_gap=None).warnings == ()
    with pytest.raises(InjectionLogError, match="gap"):
        read_injection_log(write(tmp_path, "time,flow_rate[L/min]\n0,1\n10,1\n21,1\n"), max_gap=10)


def test_bad_policy(tmp_path):
    with pytest.raises(ValueError):
        read_injection_log(write(tmp_path, HAND), policy="guess")


# ---------------------------------------------------------------------------
# policies
# ---------------------------------------------------------------------------


def test_skip_negative(tmp_path):
    body, name = with_line(6, "20,-3.2")
    log = read_injection_log(write(tmp_path, body, name), policy="skip")
    np.testing.assert_array_equal(log.time, [0, 10, 30, 40])
    assert log.total_volume == pytest.approx(400 * 1e-3 / 60)
    assert len(log.warnings) == 1
    w = log.warnings[0]
    assert "line 6" in w and "flow_rate[L/min]" in w and "-3.2" in w and "dropped" in w


def test_hold_negative_and_empty(tmp_path):
    lines = list(BASE)
    lines[4] = "10,20"   # line 5 good
    lines[5] = "20,-3.2"  # line 6 -> held at 20
    lines[6] = "30,"      # line 7 -> held at 20
    log = read_injection_log(write(tmp_path, "\n".join(lines) + "\n"), policy="hold")
    np.testing.assert_array_equal(log.time, [0, 10, 20, 30, 40])
    np.testing.assert_allclose(log.flow_rate / LPM, [10, 20, 20, 20, 10])
    assert len(log.warnings) == 2
    assert "line 6" in log.warnings[0] and "held" in log.warnings[0]
    assert "line 7" in log.warnings[1] and "empty" in log.warnings[1]
    # 0-10: 15*10, 10-30: 20*20, 30-40: 15*10 (L/min * s)
    assert log.total_volume == pytest.approx((150 + 400 + 150) * LPM)


def test_hold_first_row_bad_is_dropped(tmp_path):
    body, _ = with_line(4, "0,-1")
    log = read_injection_log(write(tmp_path, body), policy="hold")
    assert log.time[0] == 0.0 and log.time.size == 4  # origin = first kept stamp
    assert "line 4" in log.warnings[0] and "no previous value" in log.warnings[0]


@pytest.mark.parametrize("policy", ["skip", "hold"])
def test_time_problems_drop_row(tmp_path, policy):
    lines = list(BASE)
    lines[5] = "10,99"  # line 6 duplicates line 5
    lines[6] = "5,99"   # line 7 goes backwards
    log = read_injection_log(write(tmp_path, "\n".join(lines) + "\n"), policy=policy)
    np.testing.assert_array_equal(log.time, [0, 10, 40])
    np.testing.assert_allclose(log.flow_rate / LPM, [10, 10, 10])
    assert len(log.warnings) == 2
    assert "line 6" in log.warnings[0] and "duplicate" in log.warnings[0]
    assert "line 7" in log.warnings[1] and "backwards" in log.warnings[1]


GAP = "time,flow_rate[L/min],pressure[bar]\n0,10,5\n100,20,6\n1000,40,8\n1010,40,8\n"


def test_gap_skip_interpolates_linearly(tmp_path):
    log = read_injection_log(write(tmp_path, GAP), policy="skip")
    np.testing.assert_array_equal(log.time, [0, 100, 1000, 1010])
    assert log.total_volume == pytest.approx((15 * 100 + 30 * 900 + 40 * 10) * LPM)
    assert len(log.warnings) == 1 and "line 4" in log.warnings[0] and "gap of 900 s" in log.warnings[0]


def test_gap_hold_holds_rate(tmp_path):
    log = read_injection_log(write(tmp_path, GAP), policy="hold")
    assert log.time.size == 5
    assert log.time[3] == 1000.0 and log.time[2] == pytest.approx(1000.0 - HOLD_EPS, abs=1e-9)
    np.testing.assert_allclose(log.flow_rate / LPM, [10, 20, 20, 40, 40])
    np.testing.assert_allclose(log.pressure, [5e5, 6e5, 6e5, 8e5, 8e5])
    exact_hold = (15 * 100 + 20 * 900 + 40 * 10) * LPM
    assert log.total_volume == pytest.approx(exact_hold, rel=1e-9)
    assert log.rate_at(999.0) == pytest.approx(20 * LPM)
    assert len(log.warnings) == 1 and "line 4" in log.warnings[0] and "held" in log.warnings[0]


def test_skip_pressure_bad(tmp_path):
    text = "time,flow_rate[L/min],pressure[bar]\n0,10,5\n10,10,oops\n20,10,5\n"
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(write(tmp_path, text))
    assert ei.value.line == 3 and ei.value.column == "pressure[bar]" and "oops" in str(ei.value)
    log = read_injection_log(write(tmp_path, text), policy="hold")
    np.testing.assert_allclose(log.pressure, [5e5, 5e5, 5e5])


# ---------------------------------------------------------------------------
# step schedules
# ---------------------------------------------------------------------------


def test_from_steps_exact():
    t = [0.0, 100.0, 250.0, 400.0]
    q = [1e-3, 2e-3, 0.5e-3]
    log = InjectionLog.from_steps(t, q)
    assert log.total_volume == pytest.approx(0.1 + 0.3 + 0.075, rel=1e-9)
    np.testing.assert_allclose(log.step_volumes(t), [0.1, 0.3, 0.075], rtol=1e-9)
    assert log.rate_at(100.0) == 2e-3 and log.rate_at(99.0) == 1e-3  # [t_i, t_i+1)
    assert log.rate_at(401.0) == 0.0
    assert log.volume(50, 300) == pytest.approx(0.05 + 0.3 + 0.025, rel=1e-9)


def test_from_steps_shut_in_form():
    log = InjectionLog.from_steps([0, 60, 120, 180], [1e-3, 3e-3, 2e-3, 0.0])
    assert log.total_volume == pytest.approx(0.36, rel=1e-9)
    assert log.rate_at(180.0) == 0.0
    with pytest.raises(ValueError):
        InjectionLog.from_steps([0, 60], [1e-3, 2e-3])  # last rate without an end
    with pytest.raises(ValueError):
        InjectionLog.from_steps([0, 60, 50], [1e-3, 2e-3])
    with pytest.raises(ValueError):
        InjectionLog.from_steps([0, 60], [-1e-3])


def test_from_steps_large_times():
    # ramps stay representable far from t = 0 (3 years)
    t0 = 1e8
    log = InjectionLog.from_steps([t0, t0 + 3600, t0 + 7200], [1e-3, 5e-3])
    assert log.total_volume == pytest.approx(3.6 + 18.0, rel=1e-9)


# ---------------------------------------------------------------------------
# the example logs
# ---------------------------------------------------------------------------


def test_rustrel_standin(tmp_path):
    path = LOGS / "rustrel-2015-standin.csv"
    first = path.read_text().splitlines()[0]
    assert first.startswith("#") and "STAND-IN" in first
    log = read_injection_log(path)
    assert log.warnings == ()
    assert log.total_volume * 1e3 == pytest.approx(950.0, abs=5.0)
    assert log.total_volume * 1e3 == pytest.approx(950.63, abs=0.01)
    assert log.flow_rate.max() / LPM == pytest.approx(61.0, abs=0.5)
    assert log.start == datetime(2015, 3, 12, 10, 0, tzinfo=timezone(timedelta(hours=1)))
    assert log.flow_rate[-1] == 0.0
    times = np.arange(0.0, log.time[-1] + 60.0, 60.0)
    assert log.step_volumes(times).sum() == pytest.approx(log.total_volume, rel=1e-12)
    # ISO round trip
    out = tmp_path / "rt.csv"
    log.to_csv(out)
    back = read_injection_log(out)
    np.testing.assert_array_equal(back.time, log.time)
    np.testing.assert_allclose(back.flow_rate, log.flow_rate, rtol=1e-15)
    assert back.start == log.start


def test_gaps_standin_policies(tmp_path):
    path = LOGS / "standin-with-gaps.csv"
    with pytest.raises(InjectionLogError) as ei:
        read_injection_log(path)
    assert ei.value.line == 21 and ei.value.column == "time" and "duplicate" in str(ei.value)
    skip = read_injection_log(path, policy="skip")
    hold = read_injection_log(path, policy="hold")
    for log in (skip, hold):
        assert len(log.warnings) == 2
        assert "line 21" in log.warnings[0] and "line 43" in log.warnings[1]
    assert hold.time.size == skip.time.size + 1
    # gap 09:07:32Z (35.2 L/min) -> 09:22:32Z (34.8 L/min): hold adds 900*0.2 L/min*s
    assert hold.total_volume - skip.total_volume == pytest.approx(900 * 0.2 * LPM, rel=1e-6)
    # round trip of a held log: the held interval is longer than max_gap
    out = tmp_path / "rt.csv"
    hold.to_csv(out)
    with pytest.raises(InjectionLogError, match="gap"):
        read_injection_log(out)
    back = read_injection_log(out, max_gap=None)
    np.testing.assert_array_equal(back.time, hold.time)
    np.testing.assert_allclose(back.flow_rate, hold.flow_rate, rtol=1e-15)


def test_negative_rates_need_flowback_and_then_integrate_signed(tmp_path):
    """Flowback: a log that goes negative is refused unless the scene allows flowback; then the
    volume is the signed trapezoid (60 L/min in for 60 s, -30 L/min back for 60 s, ramps 30 s)."""
    from fault_screen.io.injection_log import InjectionLogError, read_injection_log

    p = tmp_path / "flowback.csv"
    p.write_text("elapsed[s],flow_rate[L/min]\n0,60\n60,60\n90,-30\n150,-30\n")
    with pytest.raises(InjectionLogError, match="allow_flowback"):
        read_injection_log(p)
    log = read_injection_log(p, flowback=True)
    litres = 60 * 1.0 + 0.5 * (60 - 30) * 0.5 - 30 * 1.0   # L: in, the ramp (net), back
    assert log.volume(0.0, 150.0) == pytest.approx(litres * 1e-3, rel=1e-12)

"""Hypothesis strategies for hostile injection logs and event catalogues (shared by the property
tests and benchmarks/fuzz_inputs.py): tables of plausible and broken cells, any separator, line
end and encoding, and raw bytes."""
from __future__ import annotations

from hypothesis import strategies as st

LOG_HEADERS = ["time", "elapsed[s]", "elapsed", "t_days_since_2006-12-02T00:00", "Zeit",
               "flow_rate[L/min]", "flow_rate", "Débit (l/min)", "q[m3/s]", "pressure[bar]",
               "WHP (psi)", "dV_m3_in_preceding_minute", "V_cumulative_m3", "volume[L]",
               "date", "x", "flow_rate[", "time[" + " " * 300, "[", "(", ""]
CATALOG_HEADERS = ["time", "isotime", "origin_time", "mag", "ml", "magnitude", "mag_type",
                   "latitude", "longitude", "depth", "depth[m]", "x", "y", "z", "x[km]", "mag[",
                   "junk", ""]
SEPARATORS = [",", ";", "\t", "|", " "]
LINE_ENDS = ["\n", "\r\n", "\r"]
ENCODINGS = ["utf-8", "utf-8-sig", "latin-1", "utf-16"]

stamps = st.datetimes(timezones=st.one_of(st.none(), st.timezones())).map(lambda d: d.isoformat())
numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**6, 10**6).map(str),
    st.floats(0, 1e4).map(lambda v: f"{v:.3f}".replace(".", ",")),
    st.sampled_from(["inf", "nan", "-0", "1e309", "1e-320", "", " ", "0x10", "1_000"]))
clock = st.tuples(st.integers(0, 99), st.integers(0, 99), st.integers(0, 99)).map(
    lambda t: "%02d:%02d:%02d" % t)
junk = st.text(max_size=12)
quoted = st.text(max_size=8).map(lambda s: '"' + s)
cells = st.one_of(numbers, stamps, clock, junk, quoted,
                  st.sampled_from(["l/min", "[bar]", "m3", "hh:mm:ss", "#", "0001-01-01T00:00:00+14:00",
                                   "9999-12-31T23:59:59-12:00", "12.03.2015 10:00:00"]))


@st.composite
def tables(draw, headers, max_rows=12):
    """Bytes of a table: a header of known and broken names, rows of mixed cells."""
    sep = draw(st.sampled_from(SEPARATORS))
    end = draw(st.sampled_from(LINE_ENDS))
    ncol = draw(st.integers(1, 4))
    header = draw(st.lists(st.sampled_from(headers), min_size=ncol, max_size=ncol))
    rows = draw(st.lists(st.lists(cells, min_size=0, max_size=ncol + 1), max_size=max_rows))
    lines = [sep.join(header)] + [sep.join(r) for r in rows]
    if draw(st.booleans()):
        lines.insert(draw(st.integers(0, len(lines))), "# a comment")
    text = end.join(lines) + draw(st.sampled_from(["", end]))
    return text.encode(draw(st.sampled_from(ENCODINGS)), errors="replace")


@st.composite
def mutated(draw, data):
    """``data`` with a few bytes flipped, inserted or removed."""
    b = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "insert", "delete"]))
        k = draw(st.integers(0, max(0, len(b))))
        if kind == "insert" or not b:
            b[k:k] = draw(st.binary(min_size=1, max_size=4))
        elif kind == "flip":
            b[min(k, len(b) - 1)] ^= draw(st.integers(1, 255))
        else:
            del b[min(k, len(b) - 1)]
    return bytes(b)


log_options = st.fixed_dictionaries({}, optional={
    "policy": st.sampled_from(["stop", "skip", "hold"]),
    "tz": st.sampled_from(["UTC", "Europe/Zurich"]),
    "date": st.sampled_from(["2015-03-12", "0001-01-01", "9999-12-31"]),
    "max_gap": st.sampled_from([1e-9, 1.0, None]),
    "time_unit": st.sampled_from(["s", "min", "d"]),
    "flow_unit": st.sampled_from(["L/min", "m3/s"]),
    "pressure_unit": st.sampled_from(["bar"]),
    "volume_unit": st.sampled_from(["m3", "L"]),
})

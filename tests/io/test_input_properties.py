"""Property tests: every log and catalogue, however broken, ends as a parse or as the project's
own error with a message, and the work done grows in proportion to the input's size.

The work is counted, not timed: the number of Python and C-function calls while reading
(``sys.setprofile``), which a hang or a super-linear loop in Python code would blow up. (The
one super-linear piece found, the header regular expression, is now a scan; a regular
expression's own backtracking is a single call and is checked by
test_log_inputs.test_header_with_an_unclosed_bracket_and_many_blanks_is_parsed_at_once.)
"""
from __future__ import annotations

import sys

import numpy as np
import pytest

pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from fault_screen.io.events import EventCatalog, EventsError, read_events  # noqa: E402
from fault_screen.io.injection_log import (  # noqa: E402
    InjectionLog, InjectionLogError, read_injection_log)
from fault_screen.io.log_format import LineSplitter  # noqa: E402
from fault_screen.io.log_stream import LogDecoder  # noqa: E402
from input_strategies import (  # noqa: E402
    CATALOG_HEADERS, LOG_HEADERS, log_options, mutated, tables)

#: calls allowed: a fixed part (imports of zone data, unit tables) and a part per input byte
CALLS_FIXED, CALLS_PER_BYTE = 60_000, 400
SETTINGS = settings(max_examples=40, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


class Calls:
    """Count the calls made inside a ``with`` block."""

    def __enter__(self):
        self.n = 0

        def count(frame, event, arg):
            if event in ("call", "c_call"):
                self.n += 1
        sys.setprofile(count)
        return self

    def __exit__(self, *exc):
        sys.setprofile(None)
        return False


def bounded(calls, data):
    assert calls.n <= CALLS_FIXED + CALLS_PER_BYTE * len(data), (calls.n, len(data))


log_bytes = st.one_of(tables(LOG_HEADERS), tables(LOG_HEADERS).flatmap(mutated),
                      st.binary(max_size=400))
catalog_bytes = st.one_of(tables(CATALOG_HEADERS), tables(CATALOG_HEADERS).flatmap(mutated),
                          st.binary(max_size=400))


@SETTINGS
@given(data=log_bytes, options=log_options)
def test_the_file_reader_parses_or_refuses_every_log(tmp_path_factory, data, options):
    path = tmp_path_factory.mktemp("log") / "log.csv"
    path.write_bytes(data)
    with Calls() as calls:
        try:
            log = read_injection_log(path, **options)
        except InjectionLogError as exc:
            assert str(exc).strip() and exc.problem
        else:
            assert isinstance(log, InjectionLog) and log.time.size >= 2
    bounded(calls, data)


@SETTINGS
@given(data=log_bytes, options=log_options, chunk=st.integers(1, 64))
def test_the_stream_decoder_parses_or_refuses_every_log(data, options, chunk):
    dec = LogDecoder("<stream>", **options)
    lines = LineSplitter()
    with Calls() as calls:
        try:
            got = []
            for k in range(0, len(data), chunk):
                got += dec.feed_lines(lines.push(data[k:k + chunk]))
            got += dec.feed_lines(lines.rest()) + dec.end()
        except InjectionLogError as exc:
            assert str(exc).strip()
        else:
            t = [s.time for s in got]
            assert all(b > a for a, b in zip(t, t[1:])), "times not increasing"
    bounded(calls, data)


@SETTINGS
@given(data=log_bytes, options=log_options)
def test_the_deferring_decoder_keeps_its_error_and_never_raises(data, options):
    dec = LogDecoder("<stream>", defer_errors=True, **options)
    lines = LineSplitter()
    dec.feed_lines(lines.push(data))
    dec.feed_lines(lines.rest())
    dec.end()
    assert dec.error is None or isinstance(dec.error, InjectionLogError)


@SETTINGS
@given(data=catalog_bytes, bad_rows=st.sampled_from(["raise", "skip"]))
def test_the_catalogue_reader_parses_or_refuses_every_catalogue(tmp_path_factory, data,
                                                                 bad_rows):
    path = tmp_path_factory.mktemp("cat") / "cat.csv"
    path.write_bytes(data)
    with Calls() as calls:
        try:
            cat = read_events(path, bad_rows=bad_rows, format="CSV")
        except EventsError as exc:
            assert str(exc).strip()
        else:
            assert isinstance(cat, EventCatalog)
            assert not np.any(np.isinf(cat.magnitude)), "an infinite magnitude was accepted"
    bounded(calls, data)


@SETTINGS
@given(text=st.text(alphabet=st.sampled_from("ab,;é\r\n€ ")), cuts=st.lists(st.integers(0, 200)))
def test_the_line_splitter_gives_the_file_readers_lines_whatever_the_pieces(text, cuts):
    from fault_screen.io.log_format import split_lines

    data = text.encode("utf-8")
    lines = LineSplitter()
    got = []
    k = 0
    for c in sorted(cuts):
        got += lines.push(data[k:c])
        k = max(k, c)
    got += lines.push(data[k:]) + lines.rest()
    want = split_lines(text)
    if want and not want[-1].strip():
        want = want[:-1] if not text.endswith(("\n", "\r")) else want
    assert [t for _, t in got] == want
    assert [n for n, _ in got] == list(range(1, len(got) + 1))

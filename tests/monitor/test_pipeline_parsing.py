"""What the web services answer, parsed (Hypothesis): HYDWS JSON and section URLs, FDSN event
service URLs and QuakeML.  Any answer ends in the samples/events or in the project's own error
naming the URL; well-formed answers give back their numbers exactly."""
from __future__ import annotations

import io
import math
from datetime import datetime, timedelta, timezone

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import monitor_env
from fault_screen.io.fdsn_events import EventServiceError, _service, parse_quakeml

URL = "http://127.0.0.1:9/hydws/v1/boreholes/BH1/sections/S1/hydraulics"
EVENTS_URL = "http://127.0.0.1:9/fdsnws/event/1/query"
T0 = datetime(2015, 3, 12, 9, tzinfo=timezone.utc)


@pytest.fixture(scope="module", autouse=True)
def plugins_importable(tmp_path_factory):
    monitor_env.activate(tmp_path_factory.mktemp("dist"))


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=True) | st.text(max_size=30),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(
        st.sampled_from(["datetime", "topflow", "toppressure", "bottomflow", "value",
                         "sections", "hydraulics", "publicid"]) | st.text(max_size=8),
        inner, max_size=5),
    max_leaves=20)


@settings(max_examples=150, deadline=None)
@given(doc=json_values)
def test_any_json_answer_is_samples_or_a_hydws_error(doc):
    import json

    from fault_screen_plugins.hydws import HydwsError, parse_hydraulics

    try:
        rows = parse_hydraulics(json.dumps(doc), URL)
    except HydwsError as exc:
        assert str(exc).startswith(URL + ": ")
        return
    for dt, q, p in rows:
        assert dt.utcoffset() == timedelta(0)
        assert q is None or math.isfinite(q)


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=200) | st.text(max_size=200).map(str.encode))
def test_any_bytes_answer_is_samples_or_a_hydws_error(data):
    from fault_screen_plugins.hydws import HydwsError, parse_hydraulics

    try:
        parse_hydraulics(data, URL)
    except HydwsError as exc:
        assert URL in str(exc)


finite = st.floats(min_value=-1e9, max_value=1e9, allow_nan=False)


@settings(max_examples=100, deadline=None)
@given(samples=st.lists(st.tuples(st.integers(0, 10**12), finite, st.none() | finite),
                        min_size=1, max_size=20, unique_by=lambda s: s[0]),
       position=st.sampled_from(["top", "bottom"]))
def test_well_formed_hydraulics_give_back_their_numbers(samples, position):
    import json

    from fault_screen_plugins.hydws import parse_hydraulics, replay_lines

    doc = []
    for us, q, p in samples:
        s = {"datetime": {"value": (T0 + timedelta(microseconds=us)).replace(tzinfo=None)
                          .isoformat()}, f"{position}flow": {"value": q}}
        if p is not None:
            s[f"{position}pressure"] = {"value": p}
        doc.append(s)
    rows = parse_hydraulics(json.dumps(doc), URL, position)
    want = sorted((T0 + timedelta(microseconds=us), q, p) for us, q, p in samples)
    assert rows == want
    # the replay-format lines carry the same floats back
    for line, (dt, q, p) in zip(replay_lines(rows, True), want):
        cells = line.split(",")
        assert datetime.fromisoformat(cells[0]) == dt and float(cells[1]) == q
        assert (cells[2] == "") == (p is None) and (p is None or float(cells[2]) == p)


@settings(max_examples=300, deadline=None)
@given(url=st.text(max_size=80) | st.builds(
    lambda a, b, c: f"http://h{a}/boreholes/{b}/sections/{c}",
    st.text(max_size=6), st.text(max_size=6), st.text(max_size=6)))
def test_any_section_url_is_parsed_or_refused_naming_it(url):
    from fault_screen_plugins.hydws import HydwsError, hydraulics_url

    try:
        base, query, position = hydraulics_url(url)
    except HydwsError as exc:
        assert url in str(exc) or "position" in str(exc)
        return
    assert base.endswith("/hydraulics") and position in ("top", "bottom")


@settings(max_examples=300, deadline=None)
@given(url=st.text(max_size=80))
def test_any_event_service_url_is_parsed_or_refused_naming_it(url):
    try:
        base, root, params = _service(url)
    except EventServiceError as exc:
        assert str(exc).startswith(f"{url}: ")
        return
    assert root.startswith(base) and not root.endswith("/query")


xmlish = st.builds(lambda a, b: a + b, st.sampled_from([
    "", "<?xml version='1.0'?>", "<q:quakeml xmlns:q='http://quakeml.org/xmlns/quakeml/1.2'>",
    "<?xml version='1.0'?><q:quakeml xmlns:q='http://quakeml.org/xmlns/quakeml/1.2' "
    "xmlns='http://quakeml.org/xmlns/bed/1.2'><eventParameters publicID='smi:x'>",
    "<html>", "quakeml"]), st.text(max_size=120))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=xmlish | st.binary(max_size=120).map(lambda b: b.decode("latin-1")))
def test_any_event_service_answer_is_events_or_an_error_naming_it(text):
    try:
        cat, ids = parse_quakeml(text.encode("utf-8", "surrogatepass"), EVENTS_URL, T0)
    except EventServiceError as exc:
        assert str(exc).startswith(f"{EVENTS_URL}: ")
        assert "\n" not in str(exc)
        return
    assert len(ids) == len(cat)


@settings(max_examples=30, deadline=None)
@given(events=st.lists(st.tuples(st.integers(-10**9, 10**10), st.floats(-2, 7)),
                       min_size=1, max_size=6))
def test_quakeml_answers_give_back_times_magnitudes_and_public_ids(events):
    from obspy import UTCDateTime
    from obspy.core.event import Catalog, Event, Magnitude, Origin, ResourceIdentifier

    cat = Catalog()
    for k, (us, m) in enumerate(events):
        org = Origin(time=UTCDateTime((T0 + timedelta(microseconds=us)).replace(tzinfo=None)),
                     latitude=43.9, longitude=5.5, depth=300.0)
        mag = Magnitude(mag=m, magnitude_type="ML")
        ev = Event(resource_id=ResourceIdentifier(f"smi:test/event/{k}"), origins=[org],
                   magnitudes=[mag])
        ev.preferred_origin_id, ev.preferred_magnitude_id = org.resource_id, mag.resource_id
        cat.append(ev)
    buf = io.BytesIO()
    cat.write(buf, format="QUAKEML")
    got, ids = parse_quakeml(buf.getvalue(), EVENTS_URL, T0)
    order = sorted(range(len(events)), key=lambda k: events[k][0])
    assert ids == [f"smi:test/event/{k}" for k in order]
    assert list(got.time) == [events[k][0] / 1e6 for k in order]
    assert list(got.magnitude) == pytest.approx([events[k][1] for k in order], rel=1e-12)
    assert got.source == EVENTS_URL

"""Earthquake catalogues as CSV and FDSN text (issue 14): times, magnitudes with their types
(negative ones included), locations, and distances to the injection point and the fault plane,
checked against hand geometry and obspy's geodesic distance."""
from __future__ import annotations

import math
from datetime import datetime, timezone

import numpy as np
import pytest

from fault_screen.io.events import EventsError, fault_normal, read_events
from fault_screen.scene import SiteSpec as Site

START = datetime(2015, 3, 12, 9, 0, tzinfo=timezone.utc)


LOCAL = """isotime,magnitude,mag_type,x,y,z
2015-03-12T09:00:30Z,-2.5,Mw,100,200,-300
2015-03-12T09:00:10Z,-1.0,ML,100,190,-310
2015-03-12T09:01:00Z,-3.1,Mw,110,200,-300
2015-03-12T08:00:00Z,-0.5,ML,100,200,-280
"""


def test_csv_local_coordinates_negative_magnitudes_and_fault_distance(tmp_path):
    p = tmp_path / "lab.csv"
    p.write_text(LOCAL)
    # injection point at (100, 200, -300); fault striking east, dipping 45 deg to the south
    cat = read_events(p, START, site=Site(x=100.0, y=200.0, z=-300.0, strike=90.0, dip=45.0))
    np.testing.assert_array_equal(cat.time, [-3600.0, 10.0, 30.0, 60.0])     # sorted by time
    np.testing.assert_array_equal(cat.magnitude, [-0.5, -1.0, -2.5, -3.1])
    assert cat.magnitude_type == ("ML", "ML", "Mw", "Mw")
    # offsets (east, north, up): (0,0,20), (0,-10,-10), (0,0,0), (10,0,0)
    np.testing.assert_allclose(cat.distance_to_injection, [20.0, math.sqrt(200), 0.0, 10.0],
                               rtol=1e-14, atol=1e-12)
    # 10 m south and 10 m down lies on the plane; 20 m up is 20 cos 45 from it; east is in it
    np.testing.assert_allclose(cat.distance_to_fault, [20 / math.sqrt(2), 0.0, 0.0, 0.0],
                               rtol=1e-12, atol=1e-12)
    assert len(cat.window(0.0, 45.0)) == 2
    arrays = cat.to_arrays(0.0, 45.0)
    np.testing.assert_array_equal(arrays["in_run"], [0, 1, 1, 0])
    assert arrays["magnitude_type"].tolist() == [b"ML", b"ML", b"Mw", b"Mw"]


def test_fault_normal_is_orthogonal_to_strike_and_dip():
    for strike, dip in ((0, 90), (30, 60), (215, 10)):
        n = fault_normal(strike, dip)
        s, d = math.radians(strike), math.radians(dip)
        along = np.array([math.sin(s), math.cos(s), 0.0])
        down = np.array([math.cos(d) * math.cos(s), -math.cos(d) * math.sin(s), -math.sin(d)])
        assert abs(n @ along) < 1e-15 and abs(n @ down) < 1e-15 and abs(n @ n - 1) < 1e-15
    # a vertical plane striking north has the east axis as its normal
    np.testing.assert_allclose(fault_normal(0.0, 90.0), [1.0, 0.0, 0.0], atol=1e-16)


FDSN = """#EventID|Time|Latitude|Longitude|Depth/km|Author|Catalog|Contributor|ContributorID|MagType|Magnitude|MagAuthor|EventLocationName
ev1|2015-03-12T09:10:00.5|43.9100|5.5100|0.50|X|X|X|1|ML|0.8|X|Rustrel
ev2|2015-03-12T09:20:00|43.8950|5.4900|1.20|X|X|X|2|mb|-0.4|X|Rustrel
ev3|2015-03-12T09:30:00||||X|X|X|3|ML|1.1|X|Rustrel
"""


def test_fdsn_text_geographic_distances(tmp_path):
    from obspy.geodetics import gps2dist_azimuth

    p = tmp_path / "fdsn.txt"
    p.write_text(FDSN)
    site = Site(latitude=43.9, longitude=5.5, depth=280.0)
    cat = read_events(p, START, site=site)
    np.testing.assert_allclose(cat.time, [600.5, 1200.0, 1800.0])
    assert cat.magnitude_type == ("ML", "mb", "ML")
    np.testing.assert_allclose(cat.depth[:2], [500.0, 1200.0])               # km -> m
    for i, (lat, lon, dep) in enumerate(((43.91, 5.51, 500.0), (43.895, 5.49, 1200.0))):
        h = gps2dist_azimuth(43.9, 5.5, lat, lon)[0]
        assert cat.distance_to_injection[i] == pytest.approx(math.hypot(h, dep - 280.0), rel=1e-9)
    assert math.isnan(cat.distance_to_injection[2])                          # no location
    assert np.all(np.isnan(cat.distance_to_fault))
    assert any("strike and dip" in n for n in cat.notes)
    assert any("without a zone taken as UTC" in n for n in cat.notes)


def test_usgs_style_csv_with_time_and_mag_columns_without_site(tmp_path):
    p = tmp_path / "usgs.csv"
    p.write_text("time,latitude,longitude,depth,mag,magType\n"
                 "2015-03-12T09:00:05.000Z,43.9,5.5,0.3,1.2,ml\n"
                 "2015-03-12T10:00:05+01:00,43.9,5.5,0.3,,\n")
    cat = read_events(p, START)
    np.testing.assert_array_equal(cat.time, [5.0, 5.0])
    assert cat.magnitude[0] == 1.2 and math.isnan(cat.magnitude[1])
    assert cat.distance_to_injection is None
    assert any("add a [site] table" in n for n in cat.notes)
    assert cat.depth[0] == pytest.approx(300.0)


def test_semicolon_catalog_with_origin_time_and_local_depth(tmp_path):
    p = tmp_path / "local.csv"
    p.write_text("origin_time;ML;x (m);y (m);depth (m)\n2015-03-12T09:00:01Z;-1.5;0;0;40\n")
    cat = read_events(p, START, site=Site(x=0.0, y=0.0, depth=10.0))
    assert cat.magnitude_type == ("ML",)            # the magnitude column's name is the type
    assert cat.distance_to_injection[0] == pytest.approx(30.0)


@pytest.mark.parametrize("text, needle", [
    ("when,mag\n2015-03-12T09:00:00Z,1\n", "no origin-time column in the header (when, mag)"),
    ("time,mag\nyesterday,1\n", "row 2, column time: not an ISO 8601 time 'yesterday'"),
    ("time,mag\n2015-03-12T09:00:00Z,big\n", "row 2, column mag: not a number 'big'"),
])
def test_bad_csv_catalogs_name_file_row_and_column(tmp_path, text, needle):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(EventsError) as ei:
        read_events(p, START)
    assert str(ei.value).startswith(str(p)) and needle in str(ei.value)


def test_quakeml_locations_give_distances(tmp_path):
    from obspy import UTCDateTime
    from obspy.core.event import Catalog, Event, Magnitude, Origin
    from obspy.geodetics import gps2dist_azimuth

    ev = Event(origins=[Origin(time=UTCDateTime("2015-03-12T09:00:20Z"), latitude=43.905,
                               longitude=5.502, depth=400.0)],
               magnitudes=[Magnitude(mag=-1.2, magnitude_type="Mw")])
    p = tmp_path / "q.xml"
    Catalog(events=[ev]).write(str(p), format="QUAKEML")
    cat = read_events(p, START, site=Site(latitude=43.9, longitude=5.5, depth=280.0,
                                          strike=0.0, dip=90.0))
    h = gps2dist_azimuth(43.9, 5.5, 43.905, 5.502)[0]
    assert cat.time[0] == 20.0 and cat.magnitude[0] == -1.2
    assert cat.distance_to_injection[0] == pytest.approx(math.hypot(h, 120.0), rel=1e-9)
    # a vertical north-striking fault: the distance is the eastward offset
    east = gps2dist_azimuth(43.905, 5.5, 43.905, 5.502)[0]
    assert cat.distance_to_fault[0] == pytest.approx(east, rel=2e-3)

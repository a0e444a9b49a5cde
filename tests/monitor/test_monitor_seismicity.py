"""Seismicity beside the model with obspy's own example data: catalogues that grow, STA/LTA on
an SDS archive, hypocentre distances."""
from __future__ import annotations

import math
from datetime import datetime, timezone

import numpy as np
import obspy
import pytest
from obspy.signal.trigger import classic_sta_lta, trigger_onset

from fault_screen.monitor.seismicity import (
    EARTH_RADIUS, CatalogFollower, SdsDetector, SeismicEvent, Site, associate)

UTC = timezone.utc


def test_quakeml_catalogue_events_once_each_as_it_grows(tmp_path):
    cat = obspy.read_events()            # obspy's example: three events of 2012-04-04
    ordered = sorted(cat, key=lambda e: e.origins[0].time)
    path = tmp_path / "cat.xml"
    obspy.core.event.Catalog(ordered[:2]).write(str(path), format="QUAKEML")
    start = datetime(2012, 4, 4, 14, 0, 0, tzinfo=UTC)
    follow = CatalogFollower(path, start)
    first = follow.poll()
    assert [e.time for e in first] == [526.0, 1117.0]       # 14:08:46 and 14:18:37
    assert [e.magnitude for e in first] == [3.0, 4.3]
    assert first[0].depth == 7000.0                          # m, as QuakeML stores it
    assert follow.poll() == []                               # unchanged file: nothing new
    path.write_text("<?xml version='1.0' encoding='utf-8'?>\n<q:quakeml")   # being rewritten
    assert follow.poll() == []
    obspy.core.event.Catalog(ordered).write(str(path), format="QUAKEML")
    new = follow.poll()
    assert [(e.time, e.magnitude) for e in new] == [(pytest.approx(1302.3, abs=1e-6), 4.4)]


FDSN_HEADER = ("#EventID | Time | Latitude | Longitude | Depth/km | Author | Catalog | "
               "Contributor | ContributorID | MagType | Magnitude | MagAuthor | "
               "EventLocationName\n")


def test_fdsn_text_catalogue_partial_lines_wait(tmp_path):
    path = tmp_path / "cat.txt"
    path.write_text(FDSN_HEADER + "ev1|2015-03-12T09:05:00.5|43.93|5.48|0.3|L|c|c|1|Mw|-1.2|L|R\n"
                    "ev2|2015-03-12T09:10:00|43.931|5.4")
    start = datetime(2015, 3, 12, 9, 0, 0, tzinfo=UTC)
    follow = CatalogFollower(path, start)
    got = follow.poll()
    assert [(e.time, e.magnitude, e.depth) for e in got] == [(300.5, -1.2, 300.0)]
    with open(path, "a") as fh:
        fh.write("81|0.31|L|c|c|2|Mw|0.5|L|R\n")
    got = follow.poll()
    assert [(e.time, e.longitude) for e in got] == [(600.0, 5.481)]


def write_sds(root, st):
    for tr in st:
        s = tr.stats
        folder = root / str(s.starttime.year) / s.network / s.station / f"{s.channel}.D"
        folder.mkdir(parents=True, exist_ok=True)
        name = f"{tr.id}.D.{s.starttime.year}.{s.starttime.julday:03d}"
        tr.write(str(folder / name), format="MSEED")


def whole_trace_onsets(st, sta, lta, on, off, ref):
    out = []
    for tr in st:
        df = tr.stats.sampling_rate
        cft = classic_sta_lta(tr.data.astype(np.float64), int(round(sta * df)),
                              int(round(lta * df)))
        out += [float(tr.stats.starttime + i / df - ref) for i, _ in trigger_onset(cft, on, off)]
    return sorted(out)


def test_sta_lta_on_an_sds_archive_in_chunks_finds_the_whole_trace_onsets(tmp_path):
    st = obspy.read()                    # obspy's example: 30 s at 100 Hz, BW.RJOB, 3 channels
    write_sds(tmp_path, st)
    start = datetime(2009, 8, 24, 0, 20, 3, tzinfo=UTC)     # first sample = model time 0
    opts = dict(sta=0.5, lta=5.0, on=3.0, off=1.0)
    det = SdsDetector(tmp_path, start, merge=1.0, **opts)
    onsets = []
    for until in (6.0, 13.5, 21.0, 30.0):                   # the archive read in four chunks
        onsets += det.onsets(until)
    want = whole_trace_onsets(st, ref=obspy.UTCDateTime(2009, 8, 24, 0, 20, 3), **opts)
    # the whole-trace run, channel by channel: 5.01 s (Z), 5.02 s (N), 4.99 s (E), ...
    assert len(want) == 8 and want[:3] == pytest.approx([4.99, 5.01, 5.02], abs=1e-9)
    assert onsets == pytest.approx(want, abs=0.5 / 100)     # within half a sample
    # merged across channels (1 s): the P arrival is one detection at the earliest onset
    det2 = SdsDetector(tmp_path, start, merge=1.0, min_channels=2, **opts)
    dets = det2.poll(30.0)
    assert dets[0].kind == "detection" and dets[0].time == pytest.approx(4.99, abs=1e-9)
    assert math.isnan(dets[0].magnitude)
    assert det2.poll(30.0) == []                             # nothing reported twice
    with pytest.raises(FileNotFoundError):
        SdsDetector(tmp_path / "none", start)


def test_site_distances_and_association():
    site = Site(latitude=43.9, longitude=5.5, depth=280.0, azimuth=90.0)   # x axis east
    ev = SeismicEvent(time=10.0, magnitude=0.1, latitude=43.9,
                      longitude=5.5 + math.degrees(30.0 / (EARTH_RADIUS *
                                                           math.cos(math.radians(43.9)))),
                      depth=240.0)
    along, up, off = site.local(ev)
    assert along == pytest.approx(30.0, rel=1e-12) and up == pytest.approx(40.0) and \
        abs(off) < 1e-9
    xy = np.column_stack([np.linspace(-50, 50, 11), np.zeros(11)])     # fault along x, y = 0
    row = {"time": 10.0, "contact_state": np.array([0] * 8 + [1] * 3),   # slipping x >= 30 m
           "slip_rate": np.linspace(0, 1e-6, 11), "shear_traction": np.full(11, 0.6e6),
           "effective_normal_stress": np.full(11, 1e6)}
    a = associate(ev, row, site=site, fault_xy=xy, injection_xy=(0.0, 0.0), friction=0.6)
    assert a.distance_injection == pytest.approx(50.0)                   # 3-4-5
    assert a.distance_slipping == pytest.approx(40.0)                    # straight above x=30
    assert a.slip_rate == pytest.approx(0.8e-6) and a.utilisation == pytest.approx(1.0)
    unlocated = associate(SeismicEvent(time=1.0), row, site=site, fault_xy=xy,
                          injection_xy=(0.0, 0.0), friction=0.6)
    assert math.isnan(unlocated.distance_injection)


def test_site_from_the_scene_puts_the_dip_section_in_the_model_plane():
    from fault_screen.scene import SiteSpec

    site = Site.from_spec(SiteSpec(x=0.0, y=0.0, z=0.0, strike=45.0, dip=60.0))
    assert site.azimuth == 135.0                      # down-dip: strike + 90 deg
    ev = SeismicEvent(time=0.0, offset=(10.0, -10.0, -5.0), distance=15.0)
    along, up, off = site.local(ev)
    assert along == pytest.approx(math.sqrt(200.0)) and abs(off) < 1e-12 and up == -5.0
    assert Site.from_spec(SiteSpec(latitude=43.9, longitude=5.5, depth=280.0)).azimuth == 90.0


def test_sta_lta_on_seedlink_records_finds_what_the_sds_archive_gives(tmp_path):
    """obspy's example waveforms served as 512-byte records by a SeedLink server on loopback
    (tests/seedlink_fake.py): the same onsets and detections as the SDS path, also when one
    channel's records come late (the detector waits for every channel, so the P arrival on the
    three channels is one detection at the earliest onset, 4.99 s on EHE)."""
    import time

    from fault_screen.monitor import SeedLinkDetector
    from seedlink_fake import FakeSeedLinkServer, records_of

    st = obspy.read()                    # EHZ, EHN, EHE, in that order
    records = records_of(st)
    late = 2 * len(records) // 3 + 2     # EHZ and EHN whole, the first 2 records of EHE
    server = FakeSeedLinkServer(records, hold_after=late)
    start = datetime(2009, 8, 24, 0, 20, 3, tzinfo=UTC)
    opts = dict(sta=0.5, lta=5.0, on=3.0, off=1.0)
    det = SeedLinkDetector(server.address, "BW_RJOB:EH?", start, merge=1.0, min_channels=2, **opts)

    def received(n):
        deadline = time.monotonic() + 30
        while det.client.records < n and time.monotonic() < deadline:
            time.sleep(0.05)
        assert det.client.records == n

    try:
        received(late)
        said = [" ".join(c.split()) for c in server.commands]
        assert said == ["HELLO", "STATION RJOB BW", "SELECT EH?", "DATA", "END"]
        # EHE has 2.2 s so far: nothing is analysed beyond it, although EHZ and EHN hold 30 s
        # (without the wait, their onsets would make a detection at 5.01 s without EHE's 4.99 s)
        assert det.poll(30.0) == []
        assert max(det.done.values()) < obspy.UTCDateTime(start) + 3.0
        server.release()
        received(len(records))
        assert sorted(".".join(c) for c in det.client.get_all_nslc()) == \
            ["BW.RJOB..EHE", "BW.RJOB..EHN", "BW.RJOB..EHZ"]
        write_sds(tmp_path, st)
        sds = SdsDetector(tmp_path, start, merge=1.0, min_channels=2, **opts)
        dets, want = [], []
        for until in (6.0, 13.5, 21.0, 30.0):               # read in four chunks, as the SDS
            dets += det.poll(until)
            want += sds.poll(until)
        assert [d.time for d in dets] == [d.time for d in want]
        assert dets[0].time == pytest.approx(4.99, abs=1e-9) and dets[0].kind == "detection"
        # the buffer keeps only the lead-in of the next chunk (two LTA windows and a second)
        kept = min(tr.stats.starttime for trs in det.client.traces.values() for tr in trs)
        assert kept >= obspy.UTCDateTime(start) + 30.0 - 2 * 5.0 - 1.0 - 2.0
    finally:
        det.close()
        server.close()

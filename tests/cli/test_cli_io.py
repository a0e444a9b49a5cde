"""Operators' files on the command line (issues 13 and 14): logs in field shapes, catalogues
with locations, scene ranges and sizes, and the messages and exit codes of each case."""
from __future__ import annotations

import dataclasses
import json
import math
from datetime import datetime, timedelta
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from fault_screen import Scene
from fault_screen.cli import main
from fault_screen.plotting import flow_unit, magnitude_groups
from fault_screen.plotting._canvas import _title
from fault_screen.result import Result

ROOT = Path(__file__).resolve().parents[2]
BUNDLED = ROOT / "configs" / "rustrel-2015-calibrated.toml"
LPM = 1e-3 / 60.0


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args], catch_exceptions=False)


def errors(r):
    return [ln for ln in r.stderr.splitlines() if ln.startswith("Error:")]


def small_scene_text(**site) -> str:
    s = Scene.from_toml(BUNDLED)
    s = s.replace(mesh=dataclasses.replace(s.mesh, nx=10, ny=11),
                  time=dataclasses.replace(s.time, end=60.0, dt=7.0),
                  site=dataclasses.replace(s.site, **site))
    return s.to_toml()


SITE = dict(x=100.0, y=200.0, z=-300.0, strike=90.0, dip=45.0)


def night_log(n=13, step=5):
    """A logger file: time of day only, crossing midnight, the pressure in bar, a final
    partial row.  Returns (text, times s, rates L/min)."""
    first = datetime(2015, 3, 12, 23, 59, 30)
    q = np.round(20 + 10 * np.sin(np.arange(n) / 3.0), 2)
    rows = [f"{first + timedelta(seconds=step * k):%H:%M:%S},{q[k]},{30 + k / 10:.1f}" for k in range(n)]
    last = first + timedelta(seconds=step * n)
    text = "Time,Flowrate (l/min),WHP (bar)\n" + "\n".join(rows) + f"\n{last:%H:%M:%S},,\n"
    return text, step * np.arange(n, dtype=float), q


def trapezoid(t, q):
    return float(np.sum(0.5 * (q[1:] + q[:-1]) * np.diff(t)))


CATALOG = """isotime,magnitude,mag_type,x,y,z
2015-03-12T22:59:40Z,-2.5,Mw,100,200,-300
2015-03-12T23:00:10Z,-1.0,ML,100,190,-310
2015-03-12T23:05:00Z,-3.1,Mw,110,200,-300
2015-03-12T21:00:00Z,-0.5,ML,100,200,-280
"""


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    """One replay shared by the checks below: night log, local catalogue, figures."""
    d = tmp_path_factory.mktemp("replay")
    scene = d / "lab.toml"
    scene.write_text(small_scene_text(**SITE))
    text, t, q = night_log()
    (d / "night.csv").write_text(text)
    (d / "cat.csv").write_text(CATALOG)
    r = invoke("replay", scene, "--log", d / "night.csv", "--date", "2015-03-12", "--tz",
               "Europe/Zurich", "--events", d / "cat.csv", "--out", d / "out.h5", "--plot",
               d / "figs", "--quiet")
    return r, d, t, q


def test_replay_time_of_day_log_crossing_midnight(replayed):
    r, d, t, q = replayed
    assert r.exit_code == 0, r.output + r.stderr
    assert ("log: night.csv: UTF-8, comma-separated; time 'Time' (time of day on 2015-03-12, "
            "zone Europe/Zurich, 1 midnight roll-over), flow 'Flowrate (l/min)' (L/min), "
            "pressure 'WHP (bar)' (bar); 13 samples over 60 s") in r.output
    assert "Warning: night.csv line 8, column Time: time of day went back" in r.stderr
    assert "Warning: night.csv line 15: last row has a time stamp but no values" in r.stderr
    res = Result.load(d / "out.h5")
    # the model received the trapezoid volume of the written rates (issue: within 0.1 %)
    assert res.injection["volume"][-1] == pytest.approx(trapezoid(t, q * LPM), rel=1e-3)
    assert res.meta["start"] == "2015-03-12T23:59:30+01:00"


def test_log_and_event_datasets_carry_units(replayed):
    _, d, _, _ = replayed
    with h5py.File(d / "out.h5") as h5:
        assert {k: h5["log"][k].attrs["unit"] for k in h5["log"]} == \
            {"time": "s", "flow_rate": "m3/s", "pressure": "Pa"}
        assert h5["log/pressure"][0] == pytest.approx(30e5)
        ev = h5["events"]
        assert ev["distance_to_injection"].attrs["unit"] == "m" and ev["time"].attrs["unit"] == "s"
        np.testing.assert_array_equal(ev["time"][()], [-7170.0, 10.0, 40.0, 330.0])
        np.testing.assert_array_equal(ev["in_run"][()], [0, 1, 1, 0])
        np.testing.assert_allclose(ev["distance_to_injection"][()], [20, 0, math.sqrt(200), 10],
                                   atol=1e-12)
        np.testing.assert_allclose(ev["distance_to_fault"][()], [20 / math.sqrt(2), 0, 0, 0],
                                   atol=1e-12)
        assert ev["magnitude_type"][()].tolist() == [b"ML", b"Mw", b"ML", b"Mw"]


def test_replay_summary_and_figures(replayed):
    r, d, _, _ = replayed
    assert "seismic events               4 read, 2 within the run" in r.output
    assert "nearest event in the run     0 m from the injection point" in r.output
    assert sorted(p.name for p in (d / "figs").iterdir()) == ["out-injection-point.png",
                                                             "out-screening.png", "out-space-time.png"]
    res = Result.load(d / "out.h5")
    assert _title(res).endswith(", replay of night.csv") and "schedule" not in _title(res)
    assert flow_unit(res) == (pytest.approx(1 / LPM), "L/min")


def test_plot_of_stored_events_and_a_catalog_outside_the_run(replayed):
    _, d, _, _ = replayed
    r = invoke("plot", d / "out.h5", "--out-dir", d / "figs2")
    assert r.exit_code == 0 and "Warning" not in r.stderr
    late = d / "late.csv"
    late.write_text("time,mag\n2015-03-14T10:00:00Z,1.0\n")
    r = invoke("plot", d / "out.h5", "--out-dir", d / "figs3", "--events", late)
    assert r.exit_code == 0
    assert (f"Warning: none of the 1 events of {late} is inside the run (0 to 60 s after "
            f"2015-03-12T23:59:30+01:00)") in r.stderr
    assert (f"Note: {late}: the catalogue has no local x/y but [site] gives x/y: distances left "
            f"empty") in r.output


def test_magnitude_groups_keep_types_apart():
    from fault_screen.io.events import EventCatalog
    ev = EventCatalog(np.array([1.0, 2.0, 3.0, 4.0]), np.array([-1.0, 0.5, -2.0, 1.0]),
                      ("ML", "mb", "ML", ""))
    groups = magnitude_groups(ev)
    assert [(k, v.tolist()) for k, v in groups] == [("?", [3]), ("ML", [0, 2]), ("mb", [1])]


def test_marker_sizes_for_negative_magnitudes():
    from fault_screen.plotting.events import _marker_sizes
    s = _marker_sizes(np.array([-4.0, -2.5, -1.0, np.nan]))
    np.testing.assert_allclose(s, [25.0, 70.0, 115.0, 25.0])


# ---- logs: bad input, exit 2, one line naming the option ----------------------------------
@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("scene") / "small.toml"
    p.write_text(small_scene_text())
    return p


BAD = {
    "time of day without --date": ("Time,Flowrate[L/min]\n08:50:05,1\n08:50:10,1\n", [],
                                   "Error: bad.csv line 2, column Time: time of day '08:50:05' "
                                   "without a date: pass --date YYYY-MM-DD"),
    "no --tz": ("Time,Flowrate[L/min]\n08:50:05,1\n08:50:10,1\n", ["--date", "2015-03-12"],
                "local times of day '08:50:05': the time zone is unknown; pass --tz ZONE"),
    "absurd rate": ("time,flow_rate[L/min]\n0,1\n5,1e9\n10,1\n", [],
                    "line 3, column flow_rate[L/min]: flow rate 1e9 L/min is outside the "
                    "plausible range 0 to 600000 L/min (0 to 10 m3/s); check the unit"),
    "no unit": ("time,rate\n0,1\n10,1\n", [], "or pass --flow-unit; accepted flow_rate units"),
    "conflict": ("time,rate[L/min]\n0,1\n10,1\n", ["--flow-unit", "gpm"],
                 "the file's unit 'L/min' conflicts with --flow-unit 'gpm'"),
    "unknown column": ("time,rate[L/min]\n0,1\n10,1\n", ["--flow-column", "Q"],
                       "--flow-column 'Q': no such column; columns: time, rate[L/min]"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_logs_exit_2_with_the_option_named(tmp_path, scene_file, case):
    text, extra, needle = BAD[case]
    (tmp_path / "bad.csv").write_text(text)
    r = invoke("replay", scene_file, "--log", tmp_path / "bad.csv", "--out", tmp_path / "o.h5",
               "--quiet", *extra)
    assert r.exit_code == 2
    assert len(errors(r)) == 1 and needle in errors(r)[0], r.stderr
    assert "flow_unit=" not in r.stderr and not (tmp_path / "o.h5").exists()


def test_binary_log_one_line(tmp_path, scene_file):
    (tmp_path / "log.xlsx").write_bytes(b"PK\x03\x04\x14\x00\x06\x00" + bytes(range(256)) * 4)
    r = invoke("replay", scene_file, "--log", tmp_path / "log.xlsx", "--quiet")
    assert r.exit_code == 2
    assert errors(r) == ["Error: log.xlsx: not a text file (a zip archive or an Excel .xlsx "
                         "workbook? export it as CSV): an injection log is a CSV text file "
                         "(time, flow rate, optional pressure)"]


def test_end_after_the_log_is_a_shut_in_with_a_warning(tmp_path, scene_file):
    (tmp_path / "short.csv").write_text("elapsed[s];Rate [gpm]\n0;10,5\n30;10,5\n")
    r = invoke("replay", scene_file, "--log", tmp_path / "short.csv", "--end", "50",
               "--out", tmp_path / "o.h5", "--quiet")
    assert r.exit_code == 0, r.stderr
    assert ("Warning: --end 50 s is after the log's last sample (30 s): the rate is taken as 0 "
            "from 30 s to 50 s (shut-in)") in r.stderr
    res = Result.load(tmp_path / "o.h5")
    assert res.time[-1] == pytest.approx(50.0)
    assert res.injection["volume"][-1] == pytest.approx(10.5 * 3.785411784e-3 / 60 * 30, rel=1e-9)
    assert res.injection["flow_rate"][-1] == 0.0
    assert json.loads(h5py.File(tmp_path / "o.h5").attrs["meta"])["log_flow_unit"] == "gpm"


# ---- scenes: ranges, size, log, show ------------------------------------------------------
def scene_with(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("text, needle", [
    ("[fault]\nfriction = 12\n", "fault.friction = 12.0: outside the physical range 0 to 2 "
                                 "(plausible: 0.2 to 1)"),
    ("[rock]\npermeability = \"1 m2\"\n", "rock.permeability = 1.0: outside the physical range "
                                          "0 to 1e-07 m2"),
    ("[faults]\nfriction = 0.6\n", "unknown section [faults]; known sections: boundary, "
                                   "damage_zone, effects, fault, fluid"),
    ("[site]\nlatitude = 95\nlongitude = 5\n", "site.latitude = 95.0: outside the physical range "
                                               "-90 to 90 deg"),
    ("[site]\nx = 1\n", "site.y = None: give both x and y"),
])
def test_scene_check_refuses_out_of_range_values(tmp_path, text, needle):
    r = invoke("scene", "check", scene_with(tmp_path, text))
    assert r.exit_code == 2 and len(errors(r)) == 1 and needle in errors(r)[0], r.stderr


def test_scene_check_warns_on_implausible_values(tmp_path):
    r = invoke("scene", "check", scene_with(tmp_path, "[mesh]\nnx = 10\nny = 11\n[fault]\nfriction = 1.5\n"))
    assert r.exit_code == 0
    assert "fault.friction = 1.5 is outside the plausible range 0.2 to 1: accepted" in r.stderr


def test_absurd_mesh_refused_with_the_estimate_before_building(tmp_path):
    p = scene_with(tmp_path, "[mesh]\nnx = 100000\nny = 100000\n")
    for args in (("scene", "check", p), ("run", p, "--out", tmp_path / "o.h5")):
        r = invoke(*args)
        assert r.exit_code == 2
        (line,) = errors(r)
        assert ("mesh.nx = 100000, mesh.ny = 100000 gives about 1e+10 elements and 3e+10 "
                "unknowns, needing about") in line and "GB of memory; this machine has" in line
        assert "running" not in r.output


def test_scene_check_reads_the_scene_log(tmp_path):
    (tmp_path / "pump.csv").write_text("time,rate\n0,1\n10,1\n")
    p = scene_with(tmp_path, '[mesh]\nnx = 10\nny = 11\n[injection]\nlog = "pump.csv"\n')
    r = invoke("scene", "check", p)
    assert r.exit_code == 2
    assert "pump.csv line 1, column rate: column needs a unit" in errors(r)[0]
    assert "or pass injection.log_flow_unit;" in errors(r)[0]
    (tmp_path / "pump.csv").write_text("time,rate[L/min]\n0,1\n10,1\n")
    r = invoke("scene", "check", p)
    assert r.exit_code == 0 and "log: pump.csv: UTF-8" in r.output


def test_scene_show_units_every_key_and_sources(tmp_path):
    import tomllib

    p = scene_with(tmp_path, '[rock]\npermeability = "100mD"\n[fault]\nfriction = 0.7\n'
                             '[[zones]]\nband = 2.0\nrock = {permeability = "5 µD"}\n')
    r = invoke("scene", "show", p)
    assert r.exit_code == 0
    lines = r.output.splitlines()

    def line(start):
        return next(ln for ln in lines if ln.startswith(start))
    assert line("permeability = 9.869233e-14").endswith('# m2, file: permeability = "100mD"')
    assert line("friction = 0.7").endswith("# - (dimensionless), file")
    assert line("kappa = 1.2").endswith("# - (dimensionless), default")
    assert line("# storativity = 2.59069767441").endswith("# m/Pa, derived: 2h0 / fluid.bulk_modulus")
    assert line("# dt_max = 5.0").endswith("# s, derived: time.dt")
    assert line("rock = {permeability = 4.93461").endswith("# units of [rock], file")
    shown = tomllib.loads(r.output)
    assert Scene.from_dict(shown) == Scene.from_toml(p)
    # every field of every section appears, set or not
    for section in ("mesh", "fault", "rock", "fluid", "initial", "injection", "time", "site"):
        spec = getattr(Scene(), section)
        for f in dataclasses.fields(spec):
            if not dataclasses.is_dataclass(getattr(spec, f.name)):
                assert any(ln.lstrip("# ").startswith(f"{f.name} ") or
                           ln.startswith(f"# {f.name}:") for ln in lines), (section, f.name)


@pytest.mark.parametrize("content, needle", [
    (b"not hdf5 at all", "not a fault_screen result (not an HDF5 file)"),
    (b"\x89HDF\r\n\x1a\n" + b"\x00" * 40, "truncated or damaged HDF5 file"),
])
def test_plot_non_result_one_line(tmp_path, content, needle):
    p = tmp_path / "x.h5"
    p.write_bytes(content)
    r = invoke("plot", p, "--out-dir", tmp_path)
    assert r.exit_code == 2 and len(errors(r)) == 1 and needle in errors(r)[0]
    assert "h5py" not in r.stderr and "Traceback" not in r.stderr


def test_plot_hdf5_that_is_not_a_result(tmp_path):
    p = tmp_path / "other.h5"
    with h5py.File(p, "w") as h5:
        h5["data"] = np.zeros(3)
    r = invoke("plot", p, "--out-dir", tmp_path)
    assert r.exit_code == 2
    assert errors(r) == [f"Error: {p}: an HDF5 file but not a fault_screen result (no readable "
                         f"scene, /time, /fault or /injection)"]


FDSN_NIGHT = """#EventID|Time|Latitude|Longitude|Depth/km|Author|Catalog|Contributor|ContributorID|MagType|Magnitude|MagAuthor|EventLocationName
a|2015-03-12T22:59:35|43.91|5.51|0.5|X|X|X|1|ML|0.8|X|lab
b|2015-03-12T23:00:29|43.90|5.50|0.3|X|X|X|2|mb|-0.4|X|lab
c|2015-03-12T23:00:31|43.90|5.50|0.3|X|X|X|3|ML|1.1|X|lab
"""


def test_plot_counts_fdsn_text_events_in_the_run(replayed):
    _, d, _, _ = replayed
    (d / "fdsn.txt").write_text(FDSN_NIGHT)
    r = invoke("plot", d / "out.h5", "--out-dir", d / "figs4", "--events", d / "fdsn.txt")
    assert r.exit_code == 0, r.stderr
    # run: 22:59:30 UTC + 60 s; the third event is 1 s after its end
    assert "seismic events: 3 read, 2 within the run" in r.output
    # the scene's [site] is local x/y: a geographic catalogue gets no distances, and says so
    assert "the catalogue has no local x/y but [site] gives x/y" in r.output


def test_figure_shows_measured_pressure_clock_time_log_unit_and_distances(replayed, monkeypatch):
    import fault_screen.plotting.injection_point as plotting
    from fault_screen.cli.plot import stored_events

    _, d, t, _ = replayed
    res = Result.load(d / "out.h5")
    res.meta["log_flow_unit"] = "gpm"
    figs = []
    monkeypatch.setattr(plotting, "_save", lambda fig, path: figs.append(fig) or Path(path))
    plotting.plot_injection_point(res, d / "x.png", stored_events(res))
    (fig,) = figs
    by_label = {ax.get_ylabel(): ax for ax in fig.axes}
    meas = by_label["injection pressure (MPa)"]
    lines = {ln.get_label(): ln for ln in meas.get_lines()}
    np.testing.assert_allclose(lines["pressure, measured (log) (MPa)"].get_ydata(),
                               3.0 + np.arange(13) / 100, rtol=1e-12)     # 30.0 bar + k/10 bar
    np.testing.assert_allclose(lines["pressure, model at the injection point (MPa)"].get_ydata(),
                               res.injection["pressure"] * 1e-6)
    assert "flow rate (gpm)" in by_label
    assert "distance to injection (m)" in by_label                          # colour bar
    labels = [ax.get_xlabel() for ax in fig.axes] + [c.get_xlabel() for ax in fig.axes
                                                     for c in ax.child_axes]
    assert "clock time (UTC+01:00, 2015-03-12)" in labels


def test_python_replay_helper(tmp_path):
    from fault_screen.io import read_injection_log, replay

    text, t, q = night_log()
    (tmp_path / "n.csv").write_text(text)
    log = read_injection_log(tmp_path / "n.csv", date="2015-03-12", tz="Europe/Zurich")
    scene = Scene.from_dict(__import__("tomllib").loads(small_scene_text()))
    res = replay(scene, log, end=80.0)
    assert res.time[-1] == pytest.approx(80.0)
    assert res.injection["volume"][-1] == pytest.approx(trapezoid(t, q * LPM), rel=1e-9)
    assert res.meta["notes"] == ["end 80 s is after the log's last sample (60 s): the rate is "
                                 "taken as 0 from 60 s to 80 s (shut-in)"]
    np.testing.assert_array_equal(res.extra["log"]["time"], t)


def test_run_reads_the_scene_log_as_input(tmp_path):
    text, t, q = night_log()
    (tmp_path / "n.csv").write_text("elapsed[s],rate[L/min]\n" + "\n".join(
        f"{a:g},{b}" for a, b in zip(t, q)) + "\n")
    s = small_scene_text().replace('[injection]\n', '[injection]\nlog = "n.csv"\n')
    p = scene_with(tmp_path, s)
    r = invoke("run", p, "--out", tmp_path / "o.h5", "--quiet")
    assert r.exit_code == 0, r.stderr
    assert "log: n.csv: UTF-8, comma-separated; time 'elapsed[s]' (elapsed s)" in r.output
    res = Result.load(tmp_path / "o.h5")
    assert res.injection["volume"][-1] == pytest.approx(trapezoid(t, q * LPM), rel=1e-9)
    with h5py.File(tmp_path / "o.h5") as h5:
        assert h5["log/flow_rate"].attrs["unit"] == "m3/s"


def test_summary_says_distances_need_a_site(replayed, capsys):
    from fault_screen.cli._running import _summary
    from fault_screen.io.events import EventCatalog

    _, d, _, _ = replayed
    res = Result.load(d / "out.h5")
    _summary(res, d / "out.h5", [], EventCatalog(np.array([5.0, 500.0]), np.array([-1.0, 0.2])))
    out = capsys.readouterr().out
    assert "seismic events               2 read, 1 within the run" in out
    assert "event distances              need a [site] table in the scene" in out

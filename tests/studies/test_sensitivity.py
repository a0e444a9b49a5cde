"""Sensitivities and Monte Carlo samples, checked on a scene whose response is known exactly:
along-fault diffusion in rigid impermeable rock under rate control is linear in the injection
rate, so the overpressure scales as 1/NoF and the rock density has no effect at all."""
from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import VERIFICATION
from fault_screen import Scene, simulate
from fault_screen.calibration import load_parameters, sample_parameters
from fault_screen.cli import main
from fault_screen.ensemble import Runner, scene_with
from fault_screen import sensitivity as sa

PARAMS = """
[observations]
pressure = { weight = 0.2565, unit = "MPa" }

[[parameter]]
key = "injection.number_of_fractures"
mean = 83.0
lower = 46.0
upper = 120.0
transform = "log"
paper_rank = 1

[[parameter]]
key = "rock.density"
mean = 2364.0
lower = 2225.0
upper = 2503.0
paper_rank = 2
"""


@pytest.fixture(scope="module")
def linear(tmp_path_factory):
    d = tmp_path_factory.mktemp("sens")
    s = Scene.from_toml(VERIFICATION / "fault-diffusion.toml")
    s = s.replace(mesh=dataclasses.replace(s.mesh, nx=40),
                  injection=dataclasses.replace(s.injection, control="rate", schedule=((0.0, 1e-4),)),
                  time=dataclasses.replace(s.time, end=0.5, dt=0.05, growth=1.0, dt_max=None))
    (d / "linear.toml").write_text(s.to_toml())
    (d / "params.toml").write_text(PARAMS)
    return s, load_parameters(d / "params.toml"), d


def overpressure_at(scene, times, nof):
    r = simulate(scene_with(scene, {"injection.number_of_fractures": nof}))
    return np.interp(times, r.time, r.injection["overpressure"])


def test_composite_scaled_sensitivity_of_a_linear_response(linear):
    scene, params, _ = linear
    with Runner(0) as runner:
        res = sa.local(scene, params, runner)
    times = sa.observation_times(scene)
    dp = overpressure_at(scene, times, 83.0)
    # p - p0 ~ 1/NoF: a 1 % forward step changes it by (1/1.01 - 1) dp
    expected = abs(1 / 1.01 - 1) / 0.01 * 0.2565 * np.sqrt(np.mean((dp / 1e6) ** 2))
    assert res.composite[0] == pytest.approx(expected, rel=1e-6)
    assert res.composite[1] == 0.0
    assert res.rank.tolist() == [1, 2] and res.spearman_paper == pytest.approx(1.0)


def test_one_at_a_time_of_a_linear_response(linear):
    scene, params, _ = linear
    with Runner(0) as runner:
        res = sa.one_at_a_time(scene, params, runner)
    times = sa.observation_times(scene)
    dp = overpressure_at(scene, times, 83.0)
    phi = lambda nof: np.sum((0.2565 * dp * (83.0 / nof - 1.0) / 1e6) ** 2)
    assert res.objective_lower[0] == pytest.approx(phi(46.0), rel=1e-6)
    assert res.objective_upper[0] == pytest.approx(phi(120.0), rel=1e-6)
    assert res.change["peak_overpressure"][0][0] == pytest.approx(83.0 / 46.0 - 1.0, rel=1e-6)
    assert res.objective_lower[1] == 0.0 and res.objective_upper[1] == 0.0
    assert res.rank.tolist() == [1, 2]


def test_morris_and_sobol_find_the_only_influential_parameter(linear):
    scene, params, _ = linear
    with Runner(0) as runner:
        m = sa.morris(scene, params, runner, trajectories=3)
        s = sa.sobol(scene, params, runner, base_samples=8)
    mu = m["peak_overpressure"]["mu_star"]
    assert mu[1] == 0.0 and mu[0] > 0.0
    assert np.all(m["injection_slip"]["mu_star"] == 0.0)       # rigid rock: never slips
    assert s["peak_overpressure"]["ST"][1] == 0.0
    assert s["peak_overpressure"]["S1"][0] > 0.8


def test_monte_carlo_samples():
    params = load_parameters(VERIFICATION.parent / "calibration" / "rustrel-2015-parameters.toml")
    sets = sample_parameters(params, 4000, "normal", seed=3)
    for p in params:
        v = np.array([s[p.key] for s in sets])
        z, zm = p.to_z(v), float(p.to_z(p.mean))
        sd = 0.5 * float(p.to_z(p.upper) - p.to_z(p.lower))
        assert np.all(np.abs(z - zm) <= 2 * sd + 1e-12), p.key
        if p.transform == "linear" and p.lower >= 0:
            assert v.min() >= 0, p.key
        else:  # symmetric truncation: the mean stays the mean (4 standard errors)
            assert abs(z.mean() - zm) < 4 * sd / np.sqrt(len(v)), p.key
    uni = sample_parameters(params, 500, "uniform", seed=3)
    for p in params:
        v = np.array([s[p.key] for s in uni])
        assert p.lower <= v.min() and v.max() <= p.upper


def test_ensemble_and_sensitivity_commands(linear, tmp_path):
    _, _, d = linear
    r = CliRunner().invoke(main, ["ensemble", str(d / "linear.toml"), "--vary", str(d / "params.toml"),
                                  "--samples", "5", "--workers", "0", "--out-dir", str(tmp_path), "-q"])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(open(tmp_path / "distribution.csv")))
    assert list(rows[0]) == ["quantity", "unit", "runs", "mean", "sd", "p5", "p50", "p95"]
    runs = list(csv.DictReader(open(tmp_path / "ensemble.csv")))
    assert len(runs) == 5 and all(x["ok"] == "True" for x in runs)
    assert "probability that the fault slips at the injection point: 0.000" in r.output
    # the traffic light's levels, as often as the runs' first-yellow / first-red times are set
    for level in ("yellow", "red"):
        reached = np.mean([x[f"time_first_{level}"] != "nan" for x in runs])
        assert f"probability that the traffic light reaches {level}: {reached:.3f}" in r.output
    r = CliRunner().invoke(main, ["sensitivity", str(d / "linear.toml"), "--parameters", str(d / "params.toml"),
                                  "--workers", "0", "--out-dir", str(tmp_path), "-q"])
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(open(tmp_path / "sensitivity.csv")))
    assert [x["parameter"] for x in rows] == ["injection.number_of_fractures", "rock.density"]
    assert list(rows[0])[:1] + list(rows[0])[2:4] == ["parameter", "composite_sensitivity", "rank"]


@pytest.mark.parametrize("args, message", [
    (["--method", "sobol", "--samples", "6"], "power of 2"),
    (["--method", "local", "--samples", "4"], "only for --method morris or sobol"),
    (["--method", "fast"], "Invalid value for '--method'"),
])
def test_sensitivity_bad_options(linear, args, message):
    _, _, d = linear
    r = CliRunner().invoke(main, ["sensitivity", str(d / "linear.toml"), "--parameters", str(d / "params.toml"),
                                  *args])
    assert r.exit_code == 2 and message in r.output, r.output

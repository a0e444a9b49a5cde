"""Every bundled Rustrel scene runs and behaves physically (paper Sect. 3, 6.2.1)."""
import numpy as np
import pytest

from fault_screen.kernels.contact import SLIP
from fault_screen.discretisation import discretise

NAMES = ["rustrel-2015-calibrated", "rustrel-2015-initial", "rustrel-2015-impermeable"]


@pytest.fixture(scope="module")
def runs(bundled_run):
    return {name: bundled_run(name) for name in NAMES}


@pytest.mark.parametrize("name", NAMES)
def test_no_nan_and_in_situ_equilibrium(runs, name):
    r = runs[name]
    for key, arr in list(r.fault.items()) + list(r.injection.items()):
        assert np.all(np.isfinite(arr)), key
    disc = discretise(r.scene)
    out, ref = disc.physics.in_situ.equilibrium_residual(disc)
    assert out < 1e-12 * ref  # gravity, hydrostatic pressure and stress gradient balance


@pytest.mark.parametrize("name", NAMES)
def test_injection_pressure_rises_with_the_rate_steps(runs, name):
    """Across every rate step the injection pressure rises, as long as the fault's hydraulic
    aperture has not grown: once dilatant slip opens it (impermeable scene), the transmissivity
    grows with the cube of the aperture and the pressure levels off instead."""
    r = runs[name]
    ends = [t for t, _ in r.scene.injection.schedule[1:]]  # end of each rate step
    k = [int(np.argmin(np.abs(r.time - t))) for t in ends]
    p = r.injection["overpressure"][k]
    at_inj = int(np.argmin(np.abs(r.fault_x)))
    aperture = r.fault["hydraulic_aperture"][k, at_inj]
    locked = aperture < 1.1 * r.scene.fault.hydraulic_aperture
    rising = np.diff(p) > 0
    assert rising[locked[1:]].all(), (p, aperture)
    if name == "rustrel-2015-impermeable":
        assert not locked[-1]  # dilatant slip opened the fault ...
        assert abs(p[-1] / p[1:].max() - 1) < 0.1  # ... and the pressure plateaued within 10 %
    else:
        assert rising.all()


def test_slip_starts_only_when_coulomb_is_met(runs):
    """Constant friction (impermeable scene): before the first slipping point, every point is
    below mu0; at that step the slipping points sit exactly on the Coulomb line."""
    r = runs["rustrel-2015-impermeable"]
    mu0 = r.scene.fault.friction
    state = r.fault["contact_state"]
    first = int(np.argmax((state == SLIP).any(axis=1)))
    assert first > 1  # the fault does not slip under the in-situ stress alone
    ratio = np.abs(r.fault["shear_traction"]) / r.fault["effective_normal_stress"]
    assert ratio[:first].max() < mu0
    slipping = state[first] == SLIP
    assert np.allclose(ratio[first][slipping], mu0, rtol=1e-9)


def test_impermeable_rock_gives_higher_pressure_and_more_slip(runs):
    """Paper Sect. 6.2.1: without fluid exchange with the rock, the same injection raises the
    pressure more and slips the fault more."""
    perm, imp = runs["rustrel-2015-calibrated"], runs["rustrel-2015-impermeable"]
    assert imp.injection["overpressure"].max() > 2 * perm.injection["overpressure"].max()
    assert np.abs(imp.fault["slip"]).max() > 10 * max(np.abs(perm.fault["slip"]).max(), 1e-9)


def test_same_injected_volume_in_every_scene(runs):
    v = [runs[n].injection["volume"][-1] for n in NAMES]
    assert np.allclose(v, 0.93833333333, rtol=1e-9)  # m3 of the stand-in schedule

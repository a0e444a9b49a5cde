"""Along-fault diffusion from a held overpressure: dp * erfc(|x| / sqrt(4 alpha t))."""
import numpy as np
import pytest

import analytical as an
from conftest import VERIFICATION
from fault_screen import Scene, simulate


@pytest.fixture(scope="module")
def run():
    scene = Scene.from_toml(VERIFICATION / "fault-diffusion.toml")
    return scene, simulate(scene)


def test_rigid_impermeable_rock_has_only_fault_pressure_unknowns(run):
    _, result = run
    c = result.meta["dof_counts"]
    assert c["u"] == c["a"] == c["p"] == c["c"] == 0
    assert c["pf"] > 0 and c["q"] == 1


@pytest.mark.parametrize("fraction", [0.25, 0.5, 1.0])
def test_fault_pressure_is_erfc(run, fraction):
    """Eq. 10, 16 (fault storage, cubic law): the fault pressure is dp erfc(|x| / sqrt(4 alpha t))
    within 2 % of dp, and the injected volume is what the fault stores."""
    scene, result = run
    f = scene.fault
    alpha = f.hydraulic_aperture ** 3 / (12 * scene.fluid.viscosity * f.kappa) / f.storativity
    dp = scene.injection.schedule[0][1]
    i = int(np.argmin(np.abs(result.time - fraction * scene.time.end)))
    t = result.time[i]
    p_ref = an.fault_diffusion_pressure(result.fault_x, t, dp=dp, alpha=alpha)
    # 2 % of dp (issue tolerance); 1 m elements resolve sqrt(4 alpha t) >= 16 m well
    assert np.max(np.abs(result.fault["overpressure"][i] - p_ref)) / dp < 0.02
    # injected volume = fluid stored in the fault (pure storage: nothing else exists)
    stored = np.sum(f.storativity * result.fault["overpressure"][i] * result.fault_weights)
    assert result.injection["volume"][i] == pytest.approx(stored, rel=1e-6)


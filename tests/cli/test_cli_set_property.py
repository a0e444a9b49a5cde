"""--set KEY=VALUE is text from a user: whatever it holds, the scene is changed or the answer is
bad input (exit 2) with a message naming --set, never another exception."""
import click
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import CONFIGS
from fault_screen import Scene
from fault_screen.cli._common import apply_sets
from fault_screen.cli._options import BadInput

SCENE = Scene.from_toml(CONFIGS / "rustrel-2015-calibrated.toml")
KEYS = ["time.end", "time.dt", "mesh.nx", "fault.friction", "fluid.viscosity", "monitor.slip_rate_yellow",
        "injection.control", "no.such", "time", "", "mesh.nx.deeper"]
VALUES = st.one_of(st.text(max_size=12), st.integers(-10**6, 10**6).map(str),
                   st.floats(allow_nan=True, allow_infinity=True).map(repr),
                   st.sampled_from(["true", "false", "nan", "-inf", "1e400", "0", "rate", "[1,2]"]))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.one_of(st.sampled_from(KEYS), st.text(max_size=15)), value=VALUES,
       sep=st.sampled_from(["=", "", "==", " = "]))
def test_any_set_text_changes_the_scene_or_is_bad_input(key, value, sep):
    item = f"{key}{sep}{value}"
    try:
        scene = apply_sets(SCENE, [item])
    except BadInput as exc:
        assert exc.exit_code == 2
        assert exc.message.strip()
        return
    assert isinstance(scene, Scene)


def test_set_a_number_lands_in_si():
    """time.end=600 gives a 600 s run; mesh.nx=26 an integer mesh size; an unknown key or a
    missing '=' is bad input naming it."""
    scene = apply_sets(SCENE, ["time.end=600", "mesh.nx=26"])
    assert scene.time.end == 600.0 and scene.mesh.nx == 26 and isinstance(scene.mesh.nx, int)
    with pytest.raises(click.ClickException, match="no_such"):
        apply_sets(SCENE, ["time.no_such=1"])
    with pytest.raises(BadInput, match="expected KEY=VALUE"):
        apply_sets(SCENE, ["time.end"])

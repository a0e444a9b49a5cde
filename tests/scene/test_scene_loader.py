"""The scene loader on hostile input: every input ends as a Scene or a SceneError with a one-line
message naming the key, and a loaded scene is written back to TOML that reads back equal.

Measured before these tests (benchmarks/fuzz_scenes.py): about one mutated scene in six ended in
another exception (UnicodeDecodeError on bytes that are not UTF-8, RecursionError on deep
nesting, OverflowError on integers beyond the float range, TypeError on a rule without ``when``);
a rule ``action`` of several lines was written back as a TOML string with raw newlines, which
does not read back (result files, ``monitor --state``). Hangs (no answer within 2 s) are counted
by the fuzz script, not here: tests carry no wall-clock limits.
"""
import dataclasses
import tomllib
import warnings

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fault_screen.scene import MAX_CONDITION, MonitorRule, Scene, SceneError, Zone

from conftest import CONFIGS

SETTINGS = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
BUNDLED = (CONFIGS / "rustrel-2015-calibrated.toml").read_bytes()


def _outcome(load, *args):
    """'loaded' or the SceneError's message (asserted to be one non-empty line)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            load(*args)
        except SceneError as exc:
            text = str(exc)
            assert text and "\n" not in text, repr(text)
            return text
    return "loaded"


# ---- the flaws, one test each ------------------------------------------------------------------
def test_bytes_that_are_not_utf8_are_a_scene_error(tmp_path):
    path = tmp_path / "latin1.toml"
    path.write_bytes('title = "Bâle"'.encode("latin-1"))
    with pytest.raises(SceneError, match=r"not UTF-8 text \(byte 10: b'\\xe2'\)"):
        Scene.from_toml(path)


@pytest.mark.parametrize("value", ["[" * 5000 + "1" + "]" * 5000, "{a = " * 5000 + "1" + "}" * 5000])
def test_deep_nesting_is_a_scene_error(value):
    with pytest.raises(SceneError, match="nested too deeply"):
        Scene.from_toml_text(f"[mesh]\nlx = {value}\n")


@pytest.mark.parametrize("text, match", [
    ("[mesh]\nlx = 1e400", r"mesh.lx = inf must be finite"),                  # tomllib reads inf
    ("[mesh]\nnx = " + "1" * 400, r"mesh.nx = 1+\.\.\.1+ must be an integer of at most 9007199254740992"),
    ("[rock]\nporosity = " + "1" * 400, r"rock.porosity = .* beyond the range of numbers"),
    ("[fault]\nfriction = " + "1" * 5000, r"not valid TOML: Exceeds the limit"),  # Python's int limit
    ('[rock]\nyoungs_modulus = "1e308 GPa"', r"rock.youngs_modulus = '1e308 GPa' is beyond the float range"),
])
def test_numbers_beyond_the_float_range_are_a_scene_error(text, match):
    with pytest.raises(SceneError, match=match):
        Scene.from_toml_text(text)


@pytest.mark.parametrize("rule, missing", [('level = "red"', "when"), ('when = "peak_slip_rate > 1"', "level")])
def test_a_rule_without_a_required_key_is_a_scene_error(rule, missing):
    with pytest.raises(SceneError, match=rf"^monitor.rules\[0\].{missing} is missing"):
        Scene.from_toml_text(f"[[monitor.rules]]\n{rule}\n")


def test_rule_conditions_too_long_or_too_deep_are_a_scene_error():
    chain = " or ".join(["peak_slip_rate > slip_rate_red"] * 400)   # 400 x 30 + 399 x 4 = 13,596 characters
    with pytest.raises(SceneError, match=rf"a condition of 13596 characters; at most {MAX_CONDITION}"):
        Scene.from_dict({"monitor": {"rules": [{"level": "red", "when": chain}]}})
    deep = "(" * 2000 + "peak_slip_rate > 1" + ")" * 2000
    text = _outcome(Scene.from_dict, {"monitor": {"rules": [{"level": "red", "when": deep}]}})
    assert text.startswith("monitor.rules[0].when = '((((")


def test_a_multi_line_action_is_written_back_escaped():
    scene = Scene.from_toml_text('[[monitor.rules]]\nlevel = "red"\nwhen = "peak_slip_rate > 1"\n'
                                 'action = """stop the pumps\n\tcall "the regulator" \\\\ now\\r\n"""\n')
    text = scene.to_toml()
    assert 'action = "stop the pumps\\n\\tcall \\"the regulator\\" \\\\ now\\r\\n"' in text
    assert tomllib.loads(text)["monitor"]["rules"][0]["action"] == scene.monitor.rules[0].action
    assert Scene.from_toml_text(text) == scene


# ---- properties ----------------------------------------------------------------------------------
@SETTINGS
@given(st.binary(max_size=2000))
def test_any_bytes_end_as_a_scene_or_a_scene_error(data):
    _outcome(Scene.from_toml_text, data)


@SETTINGS
@given(st.data())
def test_mutated_bundled_scenes_end_as_a_scene_or_a_scene_error(data):
    out = bytearray(BUNDLED)
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(out)))
        cut = data.draw(st.integers(0, 50))
        out[i:i + cut] = data.draw(st.binary(max_size=50))
    _outcome(Scene.from_toml_text, bytes(out))


_SCALARS = (st.booleans() | st.integers() | st.floats(allow_nan=True) | st.text(max_size=30)
            | st.sampled_from(["1 GPa", "5 L/min", "1e999 MPa", "nan m", "12 parsecs", "rate", "off"]))
_VALUES = st.recursive(_SCALARS, lambda inner: st.lists(inner, max_size=4)
                       | st.dictionaries(st.text(max_size=10), inner, max_size=4), max_leaves=12)
_SECTIONS = {f.name: f.type for f in dataclasses.fields(Scene)}
_KEYS = {name: [f.name for f in dataclasses.fields(Scene.__dataclass_fields__[name].default.__class__)]
         for name in _SECTIONS if name not in ("title", "zones")}


@st.composite
def _tables(draw):
    """Scene tables of known sections and keys (and some unknown) with values of any TOML type."""
    data = {}
    for section in draw(st.lists(st.sampled_from(sorted(_KEYS)), max_size=4, unique=True)):
        keys = st.sampled_from(_KEYS[section]) | st.text(min_size=1, max_size=12)
        data[section] = draw(st.dictionaries(keys, _VALUES, max_size=4))
    if draw(st.booleans()):
        data["zones"] = draw(st.lists(st.dictionaries(st.sampled_from(["name", "band", "box", "rock"]),
                                                      _VALUES, max_size=3), max_size=2))
    return data


@SETTINGS
@given(_tables())
def test_tables_of_any_values_end_as_a_scene_or_a_scene_error(data):
    _outcome(Scene.from_dict, data)


_TEXT = st.text(max_size=60)
_NAMES = st.text(min_size=1, max_size=16)


@SETTINGS
@given(title=_TEXT, actions=st.lists(_TEXT, min_size=1, max_size=3), names=st.lists(_NAMES, min_size=1, max_size=3,
                                                                                    unique=True),
       zone=_TEXT)
def test_written_scenes_read_back_equal(title, actions, names, zone):
    """load(dump(scene)) == scene for any text in the free-text fields (control characters,
    quotes, backslashes, newlines, any script)."""
    rules = tuple(MonitorRule(level="red", when="peak_slip_rate > slip_rate_red", action=a, name=n)
                  for a, n in zip(actions, names) if 0 < len(n.encode()) <= 64)
    base = Scene()
    scene = dataclasses.replace(base, title=title, zones=(Zone(name=zone, band=5.0, rock={"porosity": 0.1}),),
                                monitor=dataclasses.replace(base.monitor, rules=rules))
    text = scene.to_toml()
    assert Scene.from_toml_text(text) == scene
    assert tomllib.loads(text)["title"] == title


@pytest.mark.parametrize("where", ["folder", "nul"])
def test_a_path_that_is_no_readable_file_is_a_scene_error(tmp_path, where):
    path = tmp_path if where == "folder" else tmp_path / "a\x00b.toml"
    text = _outcome(Scene.from_toml, path)
    assert "cannot read the scene file" in text

"""The rule language against any input (Hypothesis): every text ends as a parsed condition or a
one-line RuleError; evaluation follows three-valued logic (checked against a separate reference
evaluator); chains of any length and nesting of any depth never blow the Python stack."""
from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fault_screen import Scene, SceneError
from fault_screen.rules import MAX_NESTING, RuleError, parse_condition
from fault_screen.screening import Screener

NAMES = ("a", "b", "c")
VALUES = st.fixed_dictionaries({n: st.one_of(st.just(math.nan), st.floats(-3, 3, allow_nan=False),
                                             st.sampled_from([0.0, 1.0, 2.0])) for n in NAMES})

# -- any text ------------------------------------------------------------------------------------
PIECES = st.sampled_from(["a", "b", "zz", " ", "(", ")", "not ", " and ", " or ", "<", "<=", ">",
                          ">=", "==", "!=", "1", "-", "+", ".5", "1e9999", "2E-3", "1um", "_",
                          "\x00", "é", "٣", "\r", "\n", ";", "'", "((((", "))))", "=", "!"])


@settings(max_examples=400, deadline=None)
@given(st.one_of(st.lists(PIECES, max_size=40).map("".join), st.text(max_size=60)), VALUES)
def test_any_text_parses_or_is_a_one_line_rule_error(text, values):
    try:
        cond = parse_condition(text, set(NAMES))
    except RuleError as exc:
        msg = str(exc)
        assert msg and "\n" not in msg and exc.column >= 0
        return
    assert cond.evaluate(values) in (True, False)
    assert cond.truth(values) in (True, False, None)


# -- well-formed conditions against a reference evaluator ----------------------------------------
COMPARISON = st.tuples(st.sampled_from(NAMES), st.sampled_from(["<", "<=", ">", ">=", "==", "!="]),
                       st.sampled_from([-1.0, 0.0, 1.0, 2.0]))
TREE = st.recursive(COMPARISON.map(lambda c: ("cmp",) + c),
                    lambda sub: st.one_of(sub.map(lambda t: ("not", t)),
                                          st.tuples(st.sampled_from(["and", "or"]),
                                                    st.lists(sub, min_size=2, max_size=4))),
                    max_leaves=12)


def text_of(t) -> str:
    if t[0] == "cmp":
        return f"{t[1]} {t[2]} {t[3]!r}"
    if t[0] == "not":
        return f"not ({text_of(t[1])})"
    return "(" + f" {t[0]} ".join(text_of(x) for x in t[1]) + ")"


def reference(t, values):
    """Kleene logic written out: truth tables over {True, False, None}."""
    if t[0] == "cmp":
        v = values[t[1]]
        if math.isnan(v):
            return None
        return {"<": v < t[3], "<=": v <= t[3], ">": v > t[3], ">=": v >= t[3], "==": v == t[3],
                "!=": v != t[3]}[t[2]]
    if t[0] == "not":
        v = reference(t[1], values)
        return None if v is None else not v
    vs = [reference(x, values) for x in t[1]]
    if t[0] == "and":
        return False if False in vs else (None if None in vs else True)
    return True if True in vs else (None if None in vs else False)


@settings(max_examples=400, deadline=None)
@given(TREE, VALUES)
def test_evaluation_is_three_valued_logic(tree, values):
    cond = parse_condition(text_of(tree), set(NAMES))
    want = reference(tree, values)
    assert cond.truth(values) is want
    assert cond.evaluate(values) is (want is True)
    # a rule and its negation never both hold; with a missing value neither may
    neg = parse_condition(f"not ({text_of(tree)})", set(NAMES))
    assert not (cond.evaluate(values) and neg.evaluate(values))


# -- size ----------------------------------------------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(st.integers(1, 20000), st.sampled_from(["(", "not ", "not ("]))
def test_nesting_of_any_depth_evaluates_or_is_refused_in_one_line(depth, opener):
    closer = ")" * opener.count("(")
    text = opener * depth + "a > 1" + closer * depth
    if depth * (opener.count("not") + opener.count("(")) <= MAX_NESTING:
        cond = parse_condition(text, set(NAMES))
        negations = opener.count("not") * depth
        assert cond.evaluate({"a": 2.0}) is (negations % 2 == 0)
    else:
        with pytest.raises(RuleError, match=f"deeper than {MAX_NESTING} levels") as err:
            parse_condition(text, set(NAMES))
        assert "\n" not in str(err.value)


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 30000), st.sampled_from(["or", "and"]), st.data())
def test_chains_of_any_length_evaluate(n, op, data):
    k = data.draw(st.integers(0, n - 1))
    # term k differs from the others: it decides the chain
    terms = ["a > 1" if i == k else ("a > 5" if op == "or" else "a > 0") for i in range(n)]
    cond = parse_condition(f" {op} ".join(terms), set(NAMES))
    assert cond.evaluate({"a": 2.0}) is True
    assert cond.evaluate({"a": 0.5}) is False
    assert cond.truth({"a": math.nan}) is None


def test_a_scene_with_a_long_or_chain_screens_and_deep_nesting_is_a_scene_error():
    # 400 terms: within the scene's limit on a condition's length (10,000 characters)
    chain = " or ".join(["max_utilisation > 2"] * 400 + ["peak_slip_rate > 1e-6"])
    scene = Scene.from_dict({"monitor": {"rules": [{"level": "red", "name": "long", "when": chain}]}})
    screener = Screener(scene.monitor)
    screener.update(0.0, {"max_utilisation": 0.1, "peak_slip_rate": 0.0})
    screener.update(1.0, {"max_utilisation": 0.1, "peak_slip_rate": 2e-6})
    assert [(t.time, t.to_level, t.rule) for t in screener.transitions] == [(1.0, 2, "long")]
    longer = " or ".join(["max_utilisation > 2"] * 5000)
    with pytest.raises(SceneError) as err:
        Scene.from_dict({"monitor": {"rules": [{"level": "red", "name": "long", "when": longer}]}})
    msg = str(err.value)
    assert "monitor.rules[0] ('long').when" in msg and "at most 10000" in msg and "\n" not in msg
    deep = "(" * 2000 + "max_utilisation > 2" + ")" * 2000
    with pytest.raises(SceneError) as err:
        Scene.from_dict({"monitor": {"rules": [{"level": "red", "name": "deep", "when": deep}]}})
    msg = str(err.value)
    assert "monitor.rules[0] ('deep').when" in msg and f"deeper than {MAX_NESTING}" in msg
    assert "\n" not in msg


def test_a_negated_event_rule_does_not_fire_without_an_event():
    scene = Scene.from_dict({"monitor": {"rules": [
        {"level": "red", "name": "big", "when": "not event_magnitude < 2"}]}})
    screener = Screener(scene.monitor)
    for t in range(5):                        # no event: the condition is unknown, not true
        screener.update(float(t), {})
    assert screener.transitions == [] and screener.level == 0
    screener.update(10.0, {}, events={"time": [9.5], "magnitude": [1.5]})
    assert screener.level == 0
    screener.update(11.0, {}, events={"time": [10.5], "magnitude": [2.0]})
    assert screener.level == 2

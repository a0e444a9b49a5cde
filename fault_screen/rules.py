"""The expression language of the ``[monitor]`` rules: a tokenizer, a parser and an evaluator.

A rule's ``when`` is a condition over the screening metrics (:data:`METRICS`) and the thresholds
of ``[monitor]``, for example::

    peak_slip_rate > slip_rate_yellow or (max_utilisation >= 0.9 and not injection_overpressure < 1e5)
    event_magnitude >= 1.0 and event_distance < 500

Grammar (keywords lower case; every operand in SI units)::

    condition  := conjunct ('or' conjunct)*
    conjunct   := negation ('and' negation)*
    negation   := 'not' negation | '(' condition ')' | comparison
    comparison := operand ('<' | '<=' | '>' | '>=' | '==' | '!=') operand
    operand    := NAME | ['+' | '-'] NUMBER          (NUMBER: 12, 0.5, .5, 1e-6, 2.5E+3)

Missing values.  A comparison with a missing value (a metric that is NaN or
absent, e.g. ``event_magnitude`` when no event occurred) is *unknown*, and
``not``, ``and``, ``or`` follow three-valued (Kleene) logic: ``not unknown`` is unknown,
``false and unknown`` is false, ``true or unknown`` is true, otherwise unknown.  A rule holds
only when its condition is *true*: so ``not event_magnitude < 2`` does not hold when there is
no event (it holds for an event of magnitude 2 or more), and ``event_magnitude >= 2 or
peak_slip_rate > 1e-6`` holds on the slip rate alone.

Size.  ``and``/``or`` chains of any length are evaluated without recursion; parentheses and
``not`` may nest :data:`MAX_NESTING` levels deep (deeper is a :class:`RuleError`).  Expressions
are parsed by the code below, never by ``eval``, so a rule can only compare numbers.  This
module sits beside the scene (which validates rules at load time) and imports nothing of the
package.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = ["METRICS", "EVENT_METRICS", "MAX_NESTING", "RuleError", "Condition", "parse_condition"]

#: deepest nesting of parentheses and ``not`` in a condition
MAX_NESTING = 64

#: Screening metrics a rule may name: unit and meaning (stored per output time in /screening/).
METRICS = {
    "peak_slip_rate": ("m/s", "largest |slip rate| over the fault"),
    "x_peak_slip_rate": ("m", "where along the fault (from the injection point) the slip rate peaks"),
    "slipping_length": ("m", "length of fault in sliding contact"),
    "max_utilisation": ("1", "largest |tau| / (mu0 sigma'_n) over the fault; open points count 1"),
    "min_coulomb_margin": ("Pa", "smallest mu0 sigma'_n - |tau| over the fault"),
    "delta_cff": ("Pa", "change of |tau| - mu0 sigma'_n at the injection point since t = 0"),
    "injection_overpressure": ("Pa", "overpressure at the injection point"),
    "induced_slip": ("m", "slip at the injection point while it slides (see screening)"),
    "event_magnitude": ("1", "magnitude of a seismic event of the step"),
    "event_distance": ("m", "distance of that event from the injection point"),
    "event_rate": ("1/h", "seismic events per hour over the trailing event_rate_window"),
}
#: metrics that belong to one event: a rule naming them is evaluated event by event
EVENT_METRICS = ("event_magnitude", "event_distance")

_COMPARE = {"<": lambda a, b: a < b, "<=": lambda a, b: a <= b, ">": lambda a, b: a > b,
            ">=": lambda a, b: a >= b, "==": lambda a, b: a == b, "!=": lambda a, b: a != b}
_KEYWORDS = ("and", "or", "not")
_TOKEN = re.compile(r"""
    (?P<space>\s+)
  | (?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<op><=|>=|==|!=|<|>)
  | (?P<sign>[+-])
  | (?P<paren>[()])
""", re.VERBOSE)


class RuleError(ValueError):
    """A rule expression that cannot be parsed; ``token`` and ``column`` (1-based) say where."""

    def __init__(self, message: str, token: str = "", column: int = 0):
        super().__init__(message)
        self.token = token
        self.column = column


@dataclass(frozen=True)
class _Token:
    kind: str    # number, name, keyword, op, sign, paren, end
    text: str
    column: int  # 1-based


def _tokens(text: str) -> list[_Token]:
    out, pos = [], 0
    while pos < len(text):
        m = _TOKEN.match(text, pos)
        if m is None:
            bad = re.match(r"\S+", text[pos:]).group(0)
            raise RuleError(f"unexpected {bad!r} at column {pos + 1}", bad, pos + 1)
        kind = m.lastgroup
        word = m.group(0)
        if kind == "number" and m.end() < len(text) and (text[m.end()].isalpha() or text[m.end()] == "_"):
            bad = re.match(r"[\w.+-]+", text[pos:]).group(0)
            raise RuleError(f"bad number {bad!r} at column {pos + 1} (units are not allowed: "
                            f"write SI values, e.g. 1e-6 for 1 um/s)", bad, pos + 1)
        if kind == "name" and word in _KEYWORDS:
            kind = "keyword"
        if kind != "space":
            out.append(_Token(kind, word, pos + 1))
        pos = m.end()
    out.append(_Token("end", "", len(text) + 1))
    return out


class Condition:
    """A parsed rule condition; call :meth:`evaluate` with a mapping name -> value."""

    def __init__(self, text: str, tree, names: frozenset[str]):
        self.text = text
        self._tree = tree
        self.names = names
        """Every name the condition reads."""
        self._uses_events = any(n in EVENT_METRICS for n in names)

    @property
    def uses_events(self) -> bool:
        return self._uses_events

    def evaluate(self, values) -> bool:
        """True when the condition holds for ``values`` (name -> number; NaN or absent:
        missing); false when it is false or unknown (see the module docstring)."""
        return _eval(self._tree, values) is True

    def truth(self, values):
        """True, False, or None (unknown: it depends on a missing value)."""
        return _eval(self._tree, values)

    def comparisons(self):
        """Every comparison as (left, op, right), operands a name (str) or a number (float)."""
        out, stack = [], [self._tree]
        while stack:
            node = stack.pop()
            if node[0] == "cmp":
                out.append((node[2][1], node[1], node[3][1]))
            elif node[0] == "not":
                stack.append(node[1])
            else:
                stack.extend(reversed(node[1]))
        return out

    def __repr__(self):
        return f"Condition({self.text!r})"


def _value(operand, values):
    kind, v = operand
    if kind == "num":
        return v
    got = values.get(v)
    return None if got is None else float(got)


def _eval(node, values):
    """Three-valued value of ``node``: True, False or None (unknown).  ``and``/``or`` nodes
    hold their operands in a list (no recursion along a chain); nesting is bounded by the
    parser."""
    tag = node[0]
    if tag == "cmp":
        a, b = _value(node[2], values), _value(node[3], values)
        if a is None or b is None or a != a or b != b:   # missing: absent or NaN
            return None
        return bool(_COMPARE[node[1]](a, b))
    if tag == "not":
        v = _eval(node[1], values)
        return None if v is None else not v
    decisive = tag == "or"          # the operand value that decides the whole chain
    unknown = False
    for child in node[1]:
        v = _eval(child, values)
        if v is decisive:
            return decisive
        unknown = unknown or v is None
    return None if unknown else not decisive


class _Parser:
    def __init__(self, text: str, known):
        self.text = text
        self.toks = _tokens(text)
        self.i = 0
        self.known = known
        self.names = set()

    def peek(self) -> _Token:
        return self.toks[self.i]

    def take(self) -> _Token:
        tok = self.toks[self.i]
        self.i += 1
        return tok

    def fail(self, tok: _Token, expected: str):
        shown = "the end of the expression" if tok.kind == "end" else repr(tok.text)
        raise RuleError(f"expected {expected} at column {tok.column}, found {shown}",
                        tok.text or "<end>", tok.column)

    def parse(self):
        if self.peek().kind == "end":
            raise RuleError("empty condition: expected a comparison at column 1", "<end>", 1)
        tree = self.condition()
        tok = self.peek()
        if tok.kind != "end":
            self.fail(tok, "'and', 'or' or ')'" if tok.kind != "paren" or tok.text != ")"
                      else "the end (unbalanced ')')")
        return tree

    def condition(self, depth: int = 0):
        terms = [self.conjunct(depth)]
        while self.peek().kind == "keyword" and self.peek().text == "or":
            self.take()
            terms.append(self.conjunct(depth))
        return terms[0] if len(terms) == 1 else ("or", terms)

    def conjunct(self, depth: int):
        terms = [self.negation(depth)]
        while self.peek().kind == "keyword" and self.peek().text == "and":
            self.take()
            terms.append(self.negation(depth))
        return terms[0] if len(terms) == 1 else ("and", terms)

    def negation(self, depth: int):
        tok = self.peek()
        if tok.kind in ("keyword", "paren") and tok.text in ("not", "("):
            if depth >= MAX_NESTING:
                raise RuleError(f"nesting of parentheses and 'not' deeper than {MAX_NESTING} "
                                f"levels at column {tok.column}", tok.text, tok.column)
        if tok.kind == "keyword" and tok.text == "not":
            self.take()
            return ("not", self.negation(depth + 1))
        if tok.kind == "paren" and tok.text == "(":
            self.take()
            node = self.condition(depth + 1)
            close = self.peek()
            if not (close.kind == "paren" and close.text == ")"):
                self.fail(close, "')'")
            self.take()
            return node
        return self.comparison()

    def comparison(self):
        left = self.operand()
        tok = self.peek()
        if tok.kind != "op":
            self.fail(tok, "a comparison (<, <=, >, >=, ==, !=)")
        self.take()
        right = self.operand()
        if self.peek().kind == "op":
            self.fail(self.peek(), "'and' or 'or' (chained comparisons are not supported)")
        return ("cmp", tok.text, left, right)

    def operand(self):
        tok = self.take()
        if tok.kind == "sign":
            num = self.take()
            if num.kind != "number":
                self.fail(num, f"a number after {tok.text!r}")
            value = float(num.text)
            return ("num", -value if tok.text == "-" else value)
        if tok.kind == "number":
            return ("num", float(tok.text))
        if tok.kind == "name":
            if self.known is not None and tok.text not in self.known:
                raise RuleError(f"unknown name {tok.text!r} at column {tok.column}; known: "
                                f"{', '.join(sorted(self.known))}", tok.text, tok.column)
            self.names.add(tok.text)
            return ("name", tok.text)
        self.fail(tok, "a metric name, a threshold name or a number")


def parse_condition(text: str, known=None) -> Condition:
    """Parse ``text``; ``known``: the names it may use (None: any). Raises :class:`RuleError`
    naming the offending token and its column."""
    if not isinstance(text, str):
        raise RuleError(f"a condition must be a string, got {text!r}", repr(text), 0)
    p = _Parser(text, None if known is None else frozenset(known))
    tree = p.parse()
    return Condition(text, tree, frozenset(p.names))

"""Klartext numbers, values and Q-parameter formulas.

A value in a block is a number (kept with how it was written: decimals, sign, comma), a Q parameter
(``Q12``, ``-Q3``) or a formula in parentheses, compiled once to a function of the parameters
(``SIN``/``COS``/... in degrees, as the TNC computes them). The lexer (:mod:`ilcnc.program.heidenhain_lexer`)
uses them for every word.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any

from ilcnc.program.model import (
    STYLE_COMMA,
    STYLE_LITERAL,
    STYLE_NO_LEADING_ZERO,
    STYLE_PLUS,
    STYLE_TRAILING_DOT,
)

__all__ = [
    "FUNCS",
    "MAX_DECIMALS",
    "MAX_EXPR_DEPTH",
    "MAX_EXPR_TOKENS",
    "MAX_NUMBER",
    "TERM",
    "FormulaSyntaxError",
    "parse_expr",
    "qget",
    "scan_value",
    "skip_ws",
    "token_at"
]

#: Largest magnitude of a number (the TNC itself takes at most 99999.9999 for a coordinate).
MAX_NUMBER = 1e9
#: Most decimals of a number.
MAX_DECIMALS = 12
#: Deepest nesting of parentheses in a Q formula.
MAX_EXPR_DEPTH = 48
#: Longest Q formula (tokens); keeps the evaluation far from Python's recursion limit.
MAX_EXPR_TOKENS = 400


# --------------------------------------------------------------------------------------------
# numbers, values, expressions
# --------------------------------------------------------------------------------------------
_WS = frozenset(" \t\r\n~\f\v")
TERM = _WS | {";"}
_SPACES = frozenset(" \t")
_NUMBER = re.compile(r"\d+(?:[.,]\d*)?|[.,]\d+")
_QREF = re.compile(r"Q[LR]?\d+")
_INT = re.compile(r"\d+")


def skip_ws(s: str, i: int) -> int:
    n = len(s)
    while i < n and s[i] in _WS:
        i += 1
    return i


def token_at(s: str, i: int) -> str:
    """The run of non-blank characters starting at ``i`` (for messages)."""
    j = i
    n = len(s)
    while j < n and s[j] not in TERM:
        j += 1
    return s[i:j] or s[i:i + 1]


def _number_style(txt: str, sign: str) -> tuple[float, int, int]:
    """(value, decimals, style) of a literal number ``txt`` with its sign."""
    style = STYLE_LITERAL
    if sign == "+":
        style |= STYLE_PLUS
    sep = "," if "," in txt else "."
    if sep == ",":
        style |= STYLE_COMMA
    dec = 0
    if sep in txt:
        head, tail = txt.split(sep, 1)
        dec = len(tail)
        if not head:
            style |= STYLE_NO_LEADING_ZERO
        if not tail:
            style |= STYLE_TRAILING_DOT
    if dec > MAX_DECIMALS:
        raise FormulaSyntaxError(f"number {sign}{txt[:20]}... has {dec} decimals (at most {MAX_DECIMALS})")
    value = float(txt.replace(",", "."))
    if value > MAX_NUMBER:
        raise FormulaSyntaxError(f"number {sign}{txt[:20]} out of range")
    return (-value if sign == "-" else value), dec, style


def qget(key: str, negative: bool) -> Callable[[dict[str, float]], float]:
    if negative:
        return lambda q: -q[key]
    return lambda q: q[key]


class FormulaSyntaxError(Exception):
    """A syntax error inside a block (offset-free; the caller adds the line)."""


def scan_value(s: str, i: int, line_end: int | None = None) -> tuple[Any, int, int, int, int, int] | None:
    """Read an optional value at ``i`` (spaces, sign, spaces, number / Q parameter / (formula)).

    Returns ``(value, start, end, decimals, style, next)`` or None when there
    is no value. A bare sign returns ``("+"|"-", start, end, 0, 0, next)``.
    Raises :class:`FormulaSyntaxError` for a malformed number.
    """
    n = len(s) if line_end is None else line_end
    j = i
    while j < n and s[j] in _SPACES:
        j += 1
    start = j
    sign = ""
    if j < n and s[j] in "+-":
        sign = s[j]
        j += 1
        while j < n and s[j] in _SPACES:
            j += 1
    m = _NUMBER.match(s, j)
    if m is not None:
        end = m.end()
        if end < n and s[end] not in TERM:
            raise FormulaSyntaxError(f"malformed number {token_at(s, start)!r}")
        value, dec, style = _number_style(m.group(), sign)
        return value, start, end, dec, style, end
    m = _QREF.match(s, j)
    if m is not None:
        end = m.end()
        if end < n and s[end] not in TERM:
            raise FormulaSyntaxError(f"malformed parameter {token_at(s, start)!r}")
        return qget(m.group(), sign == "-"), start, end, 0, (STYLE_PLUS if sign == "+" else 0), end
    if j < n and s[j] == "(":
        fn, end = parse_expr(s, j, n, paren=True)
        if end < n and s[end] not in TERM:
            raise FormulaSyntaxError(f"unexpected {token_at(s, end)!r} after a formula")
        if sign == "-":
            inner = fn
            fn = lambda q: -inner(q)  # noqa: E731
        return fn, start, end, 0, (STYLE_PLUS if sign == "+" else 0), end
    if sign:
        if j < n and s[j] not in TERM:
            raise FormulaSyntaxError(f"malformed number {token_at(s, start)!r}")
        return sign, start, start + 1, 0, 0, start + 1
    return None


# ---- Q formulas --------------------------------------------------------------------------


def _deg_fn(f: Callable[[float], float]) -> Callable[[float], float]:
    return lambda x: f(math.radians(x))


def _inv_deg_fn(f: Callable[[float], float]) -> Callable[[float], float]:
    return lambda x: math.degrees(f(x))


def _trunc(x: float) -> float:
    return float(math.trunc(x))


FUNCS: dict[str, Callable[[float], float]] = {
    "SIN": _deg_fn(math.sin),
    "COS": _deg_fn(math.cos),
    "TAN": _deg_fn(math.tan),
    "ASIN": _inv_deg_fn(math.asin),
    "ACOS": _inv_deg_fn(math.acos),
    "ATAN": _inv_deg_fn(math.atan),
    "SQRT": math.sqrt,
    "SQ": lambda x: x * x,
    "ABS": abs,
    "INT": _trunc,
    "FRAC": lambda x: x - _trunc(x),
    "NEG": lambda x: -x,
    "LN": math.log,
    "LOG": math.log10,
    "EXP": math.exp,
    "SGN": lambda x: float((x > 0) - (x < 0)),
}
_EXPR_TOKEN = re.compile(r"\d+(?:[.,]\d*)?|[.,]\d+|Q[LR]?\d+|[A-Z]+|[-+*/^()]")


_EXPR_NAMESPACE: dict[str, Any] = {"__builtins__": {}, "_pow": math.pow, "_PI": math.pi}
_EXPR_NAMESPACE.update({f"_F_{name}": f for name, f in FUNCS.items()})


class _ExprParser:
    """Recursive-descent parser of a TNC formula into Python source (numbers, ``q[...]``, operators).

    The source only ever holds numbers, Q parameter look-ups, arithmetic
    operators and the functions of ``FUNCS``; :func:`parse_expr` compiles it
    once into a function ``f(q) -> float``.
    """

    def __init__(self, s: str, i: int, end: int) -> None:
        self.s = s
        self.i = i
        self.end = end
        self.depth = 0
        self.count = 0

    def peek(self) -> str | None:
        s, n = self.s, self.end
        i = self.i
        while i < n and s[i] in _WS:
            i += 1
        self.i = i
        if i >= n or s[i] == ";":
            return None
        m = _EXPR_TOKEN.match(s, i)
        if m is None:
            raise FormulaSyntaxError(f"unexpected {token_at(s, i)!r} in formula")
        return m.group()

    def take(self) -> str:
        tok = self.peek()
        if tok is None:
            raise FormulaSyntaxError("formula ends too early")
        self.i += len(tok)
        self.count += 1
        if self.count > MAX_EXPR_TOKENS:
            raise FormulaSyntaxError(f"formula longer than {MAX_EXPR_TOKENS} terms")
        return tok

    def enter(self) -> None:
        self.depth += 1
        if self.depth > MAX_EXPR_DEPTH:
            raise FormulaSyntaxError("formula nested too deeply")

    def expr(self) -> str:
        self.enter()
        f = self.term()
        while self.peek() in ("+", "-"):
            op = self.take()
            f = f"({f} {op} {self.term()})"
        self.depth -= 1
        return f

    def term(self) -> str:
        f = self.power()
        while self.peek() in ("*", "/"):
            op = self.take()
            f = f"({f} {op} {self.power()})"
        return f

    def power(self) -> str:
        f = self.unary()
        if self.peek() == "^":
            self.take()
            f = f"_pow({f}, {self.unary()})"
        return f

    def unary(self) -> str:
        self.enter()
        tok = self.take()
        if tok in ("+", "-"):
            f = self.unary()
            if tok == "-":
                f = f"(-{f})"
        elif tok in FUNCS:
            f = f"_F_{tok}({self.unary()})"
        else:
            f = self.primary(tok)
        self.depth -= 1
        return f

    def primary(self, tok: str) -> str:
        if tok == "(":
            f = self.expr()
            if self.take() != ")":
                raise FormulaSyntaxError("missing ')' in formula")
            return f
        if tok == "PI":
            return "_PI"
        if _QREF.fullmatch(tok):
            return f"q[{tok!r}]"
        if tok[0].isdigit() or tok[0] in ".,":
            value, _dec, _style = _number_style(tok, "")
            return repr(value)
        raise FormulaSyntaxError(f"unexpected {tok!r} in formula")


def _compile(src: str) -> Callable[[dict[str, float]], float]:
    code = compile(f"lambda q: {src}", "<Klartext formula>", "eval")
    # the source holds only numbers, q[...] look-ups, operators and FUNCS: see _ExprParser
    return eval(code, dict(_EXPR_NAMESPACE))


def parse_expr(s: str, i: int, end: int, *, paren: bool = False) -> tuple[Callable, int]:
    """Parse a formula from ``i``; with ``paren`` exactly one parenthesised group."""
    p = _ExprParser(s, i, end)
    if paren:
        p.take()
        src = p.primary("(")
        return _compile(src), p.i
    src = p.expr()
    if p.peek() is not None:
        raise FormulaSyntaxError(f"unexpected {token_at(s, p.i)!r} in formula")
    return _compile(src), p.i



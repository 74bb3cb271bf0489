"""RS-274/NGC parameters and bracketed expressions (LinuxCNC semantics).

Values of words may be numbers, parameters (``#12``, ``#<name>``) or
expressions in square brackets with LinuxCNC's operators and functions.
This module evaluates them; anything it cannot evaluate exactly raises
:class:`ExprError`, which the G-code reader turns into a clear error with the
line number. Angles are in degrees, as in LinuxCNC.
"""

from __future__ import annotations

import math
import re

__all__ = ["ExprError", "ExprValueError", "Parameters", "read_value"]


class ExprError(Exception):
    """An expression or parameter reference that is malformed (a syntax error)."""


class ExprValueError(ExprError):
    """A well-formed expression whose value is undefined (unset parameter, division by zero)."""


_NUMBER = re.compile(r"[+-]?[ \t]*(?:\d+(?:\.\d*)?|\.\d+)")
_SPACE = re.compile(r"\s*")

_BINARY_PRECEDENCE = {
    "**": 4,
    "*": 3, "/": 3, "MOD": 3,
    "+": 2, "-": 2,
    "EQ": 1, "NE": 1, "GT": 1, "GE": 1, "LT": 1, "LE": 1,
    "AND": 0, "OR": 0, "XOR": 0,
}
_OPERATOR = re.compile(r"\s*(\*\*|\*|/|\+|-|MOD|EQ|NE|GT|GE|LT|LE|AND|OR|XOR)", re.IGNORECASE)
_FUNCTION = re.compile(r"\s*(ABS|ACOS|ASIN|ATAN|COS|EXP|FIX|FUP|ROUND|LN|SIN|SQRT|TAN|EXISTS)\s*\[", re.IGNORECASE)
_NAMED = re.compile(r"<([^>]*)>")


class Parameters:
    """Numbered and named parameters of one interpreter run.

    Numbered parameters default to 0 (LinuxCNC reads them from its var file;
    ilcnc starts from zeros like a fresh ``rs274``). Named parameters must be
    set before use.
    """

    __slots__ = ("named", "numbered", "permissive", "position_read")

    def __init__(self, *, permissive: bool = False) -> None:
        self.numbered: dict[int, float] = {}
        self.named: dict[str, float] = {}
        #: syntax checking only: undefined values read as 0 instead of raising
        self.permissive = permissive
        #: a current-position parameter (#5420..#5428, LinuxCNC) was read since :meth:`take_position_read`
        self.position_read = False

    def take_position_read(self) -> bool:
        """True if #5420..#5428 (the current position) were read since the last call; clears the mark."""
        read, self.position_read = self.position_read, False
        return read

    def get_numbered(self, n: int) -> float:
        if n < 1 or n > 5601:
            if self.permissive:
                return 0.0
            raise ExprValueError(f"parameter number #{n} out of range 1..5601")
        if 5420 <= n <= 5428:
            self.position_read = True
        return self.numbered.get(n, 0.0)

    def get_named(self, name: str) -> float:
        key = name.replace(" ", "").lower()
        if key not in self.named:
            if self.permissive:
                return 0.0
            raise ExprValueError(f"named parameter #<{name}> used before it was set")
        return self.named[key]

    def exists(self, name: str) -> bool:
        return name.replace(" ", "").lower() in self.named


def _skip(text: str, pos: int) -> int:
    m = _SPACE.match(text, pos)
    return m.end() if m else pos


def read_param_ref(text: str, pos: int, params: Parameters) -> tuple[str | int, int]:
    """Read the parameter after a ``#`` at ``pos``; returns (key, end)."""
    pos = _skip(text, pos + 1)
    if pos < len(text) and text[pos] == "<":
        m = _NAMED.match(text, pos)
        if m is None:
            raise ExprError("unclosed named parameter '<'")
        return m.group(1).replace(" ", "").lower(), m.end()
    if pos < len(text) and text[pos] == "#":
        v, end = read_value(text, pos, params)
        return _as_index(v), end
    if pos < len(text) and text[pos] == "[":
        v, end = _read_bracket(text, pos, params)
        return _as_index(v), end
    m = _NUMBER.match(text, pos)
    if m is None:
        raise ExprError("'#' without a parameter number or name")
    return _as_index(float(m.group(0).replace(" ", "").replace("\t", ""))), m.end()


def _as_index(v: float) -> int:
    if not math.isfinite(v) or abs(v) > 1e9:
        raise ExprValueError(f"parameter number {v!r} out of range")
    if abs(v - round(v)) > 1e-4:
        raise ExprValueError(f"parameter number {v!r} is not an integer")
    return round(v)


def _param_value(key: str | int, params: Parameters) -> float:
    if isinstance(key, int):
        return params.get_numbered(key)
    return params.get_named(key)


def read_value(text: str, pos: int, params: Parameters) -> tuple[float, int]:
    """Read a real value (number, parameter, ``[expr]``, unary function) at ``pos``.

    Returns
    -------
    (value, end)
        The value and the offset just past it.
    """
    pos = _skip(text, pos)
    if pos >= len(text):
        raise ExprError("missing value")
    ch = text[pos]
    if ch in "+-":
        nxt = _skip(text, pos + 1)
        if nxt < len(text) and (text[nxt] in "#[" or text[nxt].isalpha()):
            v, end = read_value(text, nxt, params)
            return (-v if ch == "-" else v), end
    if ch == "[":
        return _read_bracket(text, pos, params)
    if ch == "#":
        key, end = read_param_ref(text, pos, params)
        return _param_value(key, params), end
    m = _FUNCTION.match(text, pos)
    if m is not None:
        return _read_function(m.group(1).upper(), text, m.end() - 1, params)
    m = _NUMBER.match(text, pos)
    if m is None:
        raise ExprError(f"bad number near '{text[pos:pos + 10]}'")
    v = float(m.group(0).replace(" ", "").replace("\t", ""))
    if not math.isfinite(v):
        raise ExprError(f"number {m.group(0)[:20]}... out of range")
    return v, m.end()


def _read_bracket(text: str, pos: int, params: Parameters) -> tuple[float, int]:
    v, end = _read_expression(text, pos + 1, params)
    end = _skip(text, end)
    if end >= len(text) or text[end] != "]":
        raise ExprError("unclosed '[' in expression")
    return v, end + 1


def _read_function(name: str, text: str, pos: int, params: Parameters) -> tuple[float, int]:
    if name == "EXISTS":
        inner = _skip(text, pos + 1)
        if inner < len(text) and text[inner] == "#":
            m = _NAMED.match(text, _skip(text, inner + 1))
            if m is None:
                raise ExprError("EXISTS needs a named parameter")
            end = _skip(text, m.end())
            if end >= len(text) or text[end] != "]":
                raise ExprError("unclosed '[' after EXISTS")
            return (1.0 if params.exists(m.group(1)) else 0.0), end + 1
        raise ExprError("EXISTS needs a named parameter")
    a, end = _read_bracket(text, pos, params)
    if name == "ATAN":
        end = _skip(text, end)
        if end >= len(text) or text[end] != "/":
            raise ExprError("ATAN needs the form ATAN[y]/[x]")
        end = _skip(text, end + 1)
        if end >= len(text) or text[end] != "[":
            raise ExprError("ATAN needs the form ATAN[y]/[x]")
        b, end = _read_bracket(text, end, params)
        return math.degrees(math.atan2(a, b)), end
    try:
        return _UNARY[name](a), end
    except (ValueError, OverflowError) as exc:
        if params.permissive:
            return 0.0, end
        raise ExprValueError(f"{name}[{a:g}] is undefined: {exc}") from None


def _round_half_away(x: float) -> float:
    return float(math.floor(abs(x) + 0.5)) * (1.0 if x >= 0 else -1.0)


_UNARY = {
    "ABS": abs,
    "ACOS": lambda x: math.degrees(math.acos(x)),
    "ASIN": lambda x: math.degrees(math.asin(x)),
    "COS": lambda x: math.cos(math.radians(x)),
    "EXP": math.exp,
    "FIX": lambda x: float(math.floor(x)),
    "FUP": lambda x: float(math.ceil(x)),
    "ROUND": _round_half_away,
    "LN": math.log,
    "SIN": lambda x: math.sin(math.radians(x)),
    "SQRT": math.sqrt,
    "TAN": lambda x: math.tan(math.radians(x)),
}


def _apply(op: str, a: float, b: float) -> float:
    try:
        if op == "+":
            return a + b
        if op == "-":
            return a - b
        if op == "*":
            return a * b
        if op == "/":
            if b == 0.0:
                raise ExprValueError("division by zero in expression")
            return a / b
        if op == "MOD":
            if b == 0.0:
                raise ExprValueError("MOD by zero in expression")
            return math.fmod(a, b) if (a >= 0) == (b >= 0) or math.fmod(a, b) == 0 else math.fmod(a, b) + b
        if op == "**":
            r = a**b
            if isinstance(r, complex):
                raise ExprValueError(f"{a:g}**{b:g} is not real")
            return float(r)
    except OverflowError:
        raise ExprValueError("number too large in expression") from None
    tol = 1e-6
    if op == "EQ":
        return float(abs(a - b) < tol)
    if op == "NE":
        return float(abs(a - b) >= tol)
    if op == "GT":
        return float(a > b)
    if op == "GE":
        return float(a >= b)
    if op == "LT":
        return float(a < b)
    if op == "LE":
        return float(a <= b)
    if op == "AND":
        return float(a != 0.0 and b != 0.0)
    if op == "OR":
        return float(a != 0.0 or b != 0.0)
    if op == "XOR":
        return float((a != 0.0) != (b != 0.0))
    raise ExprError(f"unknown operator {op}")


def _apply_checked(op: str, a: float, b: float, params: Parameters) -> float:
    try:
        return _apply(op, a, b)
    except ExprValueError:
        if params.permissive:
            return 0.0
        raise


def _read_expression(text: str, pos: int, params: Parameters) -> tuple[float, int]:
    """Operator-precedence evaluation of the inside of ``[ ... ]``."""
    values: list[float] = []
    ops: list[str] = []
    v, pos = read_value(text, pos, params)
    values.append(v)
    depth_guard = 0
    while True:
        depth_guard += 1
        if depth_guard > 10000:
            raise ExprError("expression too long")
        p = _skip(text, pos)
        if p < len(text) and text[p] == "]":
            break
        m = _OPERATOR.match(text, pos)
        if m is None:
            if p >= len(text):
                raise ExprError("unclosed '[' in expression")
            raise ExprError(f"unexpected '{text[p]}' in expression")
        op = m.group(1).upper()
        prec = _BINARY_PRECEDENCE[op]
        while ops and _BINARY_PRECEDENCE[ops[-1]] >= prec:
            b = values.pop()
            a = values.pop()
            values.append(_apply_checked(ops.pop(), a, b, params))
        ops.append(op)
        v, pos = read_value(text, m.end(), params)
        values.append(v)
    while ops:
        b = values.pop()
        a = values.pop()
        values.append(_apply_checked(ops.pop(), a, b, params))
    return values[0], pos

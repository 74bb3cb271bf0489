"""Heidenhain Klartext (TNC conversational) reader and writer.

Reading happens in two layers.

Lexical layer
    The text is split into lines on ``"\\n"`` only (a trailing ``"\\r"`` is
    part of the line ending, a stray CR inside a line is just a character);
    lines ending in ``~`` are joined with the next one into one block; every
    block is parsed into a small record that keeps the character span of each
    coordinate number. Syntax errors raise :class:`~ilcnc.errors.ProgramError`
    naming the line. The whole file is always lexed, so a syntax error is
    reported even after a construct the interpreter does not model.

Interpretation
    The blocks are executed as the control would: Q parameters (``FN 0..8``,
    ``FN 13``, formulas), conditional jumps (``FN 9..12``), label calls and
    repeats, datum shift (cycle 7), straight lines, circles (``CC``/``C``,
    ``CR``, ``CT``, polar ``LP``/``CP``), rounding and chamfers (``RND``,
    ``CHF``), tangential and normal approach / departure (``APPR``/``DEP`` LT
    and LN). Every motion goes into a :class:`~ilcnc.program.model.MoveTable`
    in execution order. A construct that cannot be evaluated faithfully (values
    read from the machine, tilted or mirrored frames, cycles whose motion is
    not modelled, ...) stops the interpretation and is recorded in
    :attr:`~ilcnc.program.model.Program.unsupported`; the moves read so far
    are kept.

Conventions
-----------
* Positions start at (0, 0, 0) in the program frame (the control's position
  before the program is unknown). Unprogrammed axes do not move.
* ``offset_mm`` is the datum shift of cycle 7 (absolute or incremental);
  ``end_mm - offset_mm`` is what the program wrote.
* ``M91``/``M92`` coordinates are machine coordinates; they are recorded as
  written (like G-code ``G53``: the axes of the block get offset 0) and the
  move carries ``FLAG_MACHINE``.
* A command (the G01 equivalent, index k) is an ``L`` with a feed (not
  ``FMAX``) whose X/Y/Z words are plain numbers, that runs exactly once, is
  not ``M91``/``M92``, does not touch a helper move of ``APPR``/``RND``/
  ``CHF``/``DEP`` (its end or direction shapes it) and is followed by a move
  whose words can absorb a changed start (not polar, parametric or repeated). When the interpretation stopped early, no
  move after the first label that a call or jump can reach is a command (it
  might run again).
* ``CC`` spans go to the first ``C``/``CP`` after it (an incremental ``CC``
  only when no move lies between); later arcs around the same pole have
  ``center_mm`` but no centre spans.
* ``RND`` and ``CHF`` are modelled between two straight lines in the working
  plane; ``APPR``/``DEP`` ``LT`` and ``LN`` in the working plane. Their helper
  moves carry ``FLAG_DERIVED``. Other cases stop the interpretation.
* ``CALL LBL n`` runs the label once, ``CALL LBL n REP r`` jumps to it r
  times (a section repeat therefore runs r + 1 times); a subprogram returns at
  ``LBL 0``. Moves of text that ran more than once get ``FLAG_REPEATED``.
* Q parameters that are read from the control (``FN 18``), set by a caller or
  the tool table are unknown; an unknown value stops the interpretation only
  where it is used for a position, a jump or a repeat count.
* The old fixed cycles 1-5, 17 and 18 return the tool to where they started;
  their calls (``CYCL CALL``, ``M99``, ``M89``) are recorded as warnings, their
  internal motion is not in the table. Every other cycle call stops the
  interpretation, as do mirrored, rotated, scaled or tilted frames when a move
  is made in them (cycles 8, 10, 11, 19, 26, ``PLANE``, ``M128``).
* In inch programs (``BEGIN PGM .. INCH``) lengths and feeds are read as
  inch and inch/min and converted to mm and mm/min.
* Cycle 32 (``CYCL DEF 32.0 TOLERANZ`` / ``TOLERANCE``, ``CYCL DEF 32.1 T0.02``) sets the
  path tolerance of the moves after it (``MoveTable.blend_tol_mm``, mm; ``T0`` is an exact
  path, stop at every corner); a ``32.1`` without ``T`` resets it to the machine's (the
  profile's) tolerance. ``32.2`` (HSC mode, rotary tolerance ``TA``) is read and ignored.
* Runs of plain ``L`` blocks (no M word) are read with numpy; everything
  else block by block. Both give the same table.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ilcnc.errors import ProgramError
from ilcnc.program.model import (
    BLEND_PROFILE,
    FLAG_CUTTER_COMP,
    FLAG_DERIVED,
    FLAG_MACHINE,
    FLAG_PARAMETRIC,
    FLAG_POLAR,
    FLAG_REPEATED,
    MM_PER_INCH,
    MOVE_ARC_CCW,
    MOVE_ARC_CW,
    MOVE_LINE,
    MOVE_RAPID,
    PLANE_AXES,
    PLANE_XY,
    PLANE_XZ,
    PLANE_YZ,
    STYLE_COMMA,
    STYLE_LITERAL,
    STYLE_NO_LEADING_ZERO,
    STYLE_PLUS,
    STYLE_TRAILING_DOT,
    MoveTable,
    MoveTableBuilder,
    Program,
    arc_off_circle,
    decode_source,
    looks_binary,
    named_axes,
)

__all__ = ["read_heidenhain", "write_klartext"]

#: Blocks executed before the interpreter gives up on a loop.
MAX_BLOCKS = 600_000
#: Blocks executed without any motion before the interpreter gives up on a loop.
MAX_IDLE_BLOCKS = 100_000
#: Moves produced before the interpreter gives up.
MAX_MOVES = 100_000
#: Largest magnitude of a number (the TNC itself takes at most 99999.9999 for a coordinate).
MAX_NUMBER = 1e9
#: Most decimals of a number.
MAX_DECIMALS = 12
#: Difference of start and end radius of a C above which a warning is given, mm.
ARC_TOLERANCE_MM = 0.01
#: Deepest nesting of label calls (the TNC allows far fewer).
MAX_CALL_DEPTH = 64
#: Deepest nesting of parentheses in a Q formula.
MAX_EXPR_DEPTH = 48
#: Longest Q formula (tokens); keeps the evaluation far from Python's recursion limit.
MAX_EXPR_TOKENS = 400

_NAN = float("nan")
_NAN3 = (_NAN, _NAN, _NAN)
_NONE3 = (-1, -1, -1)
_ZERO3 = (0, 0, 0)
_FALSE3 = (False, False, False)

# (first, second, normal) axis of each plane; angles are measured from the first axis
_TOOL_AXIS_PLANE = {2: PLANE_XY, 1: PLANE_XZ, 0: PLANE_YZ}
_PAIR_PLANE = {frozenset((0, 1)): PLANE_XY, frozenset((0, 2)): PLANE_XZ, frozenset((1, 2)): PLANE_YZ}
_AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}

# old fixed cycles that end where they started (the tool returns to the starting position)
_RETURNING_CYCLES = frozenset((1, 2, 3, 4, 5, 17, 18))
# cycles that act when defined (never called)
_DEF_ACTIVE = frozenset((7, 8, 9, 10, 11, 13, 14, 19, 20, 26, 32, 247))

# --------------------------------------------------------------------------------------------
# block kinds
# --------------------------------------------------------------------------------------------
(K_BEGIN, K_END, K_L, K_LP, K_C, K_CC, K_CR, K_CT, K_CP, K_RND, K_CHF, K_APPR, K_DEP, K_M, K_STOP,
 K_FN_ARITH, K_FN_JUMP, K_FN_ERROR, K_FN_SYSREAD, K_FN_OTHER, K_Q, K_QS, K_LBL, K_CALL_LBL, K_CALL_PGM,
 K_CYCL_DEF, K_CYCL_CALL, K_TOOL_CALL, K_TOOL_DEF, K_PLANE, K_LOOSE, K_FASTL, K_RUN) = range(33)
#: Shortest run of plain ``L`` blocks read with numpy instead of block by block.
MIN_RUN = 16


class _Block:
    """One lexed block: its kind, first line, offset of its text and payload."""

    __slots__ = ("data", "hold", "kind", "line", "pos")

    def __init__(self, kind: int, line: int, pos: int, data: Any) -> None:
        self.kind = kind
        self.line = line
        self.pos = pos
        self.data = data
        self.hold = False


class _Motion:
    """Words of a motion block (L, LP, C, CC, CR, CT, CP, RND, CHF, APPR, DEP, M-only, STOP).

    ``coords`` holds ``(axis, incremental, value, start, end, decimals, style)``
    per X/Y/Z word; ``value`` is a float for a literal number or a callable of
    the Q parameter dict for a parameter or an expression.
    """

    __slots__ = ("coords", "dr", "extra", "feed", "insert_at", "ms", "polar", "radius", "rcomp", "rotary", "sub")

    def __init__(self) -> None:
        self.coords: list[tuple] = []
        self.rotary = False
        self.feed: Any = None
        self.rcomp: str | None = None
        self.ms: list[int] = []
        self.dr = 0
        self.radius: Any = None
        self.polar: dict[str, tuple[Any, bool]] = {}
        self.extra: dict[str, Any] = {}
        self.insert_at = -1
        self.sub = ""


class _Stop(Exception):
    """Interpretation stops here: a construct that is valid but not modelled."""

    def __init__(self, line: int, problem: str) -> None:
        super().__init__(problem)
        self.line = line
        self.problem = problem


# --------------------------------------------------------------------------------------------
# numbers, values, expressions
# --------------------------------------------------------------------------------------------
_WS = frozenset(" \t\r\n~\f\v")
_TERM = _WS | {";"}
_SPACES = frozenset(" \t")
_NUMBER = re.compile(r"\d+(?:[.,]\d*)?|[.,]\d+")
_QREF = re.compile(r"Q[LR]?\d+")
_INT = re.compile(r"\d+")


def _skip_ws(s: str, i: int) -> int:
    n = len(s)
    while i < n and s[i] in _WS:
        i += 1
    return i


def _token_at(s: str, i: int) -> str:
    """The run of non-blank characters starting at ``i`` (for messages)."""
    j = i
    n = len(s)
    while j < n and s[j] not in _TERM:
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
        raise _Syntax(f"number {sign}{txt[:20]}... has {dec} decimals (at most {MAX_DECIMALS})")
    value = float(txt.replace(",", "."))
    if value > MAX_NUMBER:
        raise _Syntax(f"number {sign}{txt[:20]} out of range")
    return (-value if sign == "-" else value), dec, style


def _qget(key: str, negative: bool) -> Callable[[dict[str, float]], float]:
    if negative:
        return lambda q: -q[key]
    return lambda q: q[key]


class _Syntax(Exception):
    """A syntax error inside a block (offset-free; the caller adds the line)."""


def _scan_value(s: str, i: int, line_end: int | None = None) -> tuple[Any, int, int, int, int, int] | None:
    """Read an optional value at ``i`` (spaces, sign, spaces, number / Q parameter / (formula)).

    Returns ``(value, start, end, decimals, style, next)`` or None when there
    is no value. A bare sign returns ``("+"|"-", start, end, 0, 0, next)``.
    Raises :class:`_Syntax` for a malformed number.
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
        if end < n and s[end] not in _TERM:
            raise _Syntax(f"malformed number {_token_at(s, start)!r}")
        value, dec, style = _number_style(m.group(), sign)
        return value, start, end, dec, style, end
    m = _QREF.match(s, j)
    if m is not None:
        end = m.end()
        if end < n and s[end] not in _TERM:
            raise _Syntax(f"malformed parameter {_token_at(s, start)!r}")
        return _qget(m.group(), sign == "-"), start, end, 0, (STYLE_PLUS if sign == "+" else 0), end
    if j < n and s[j] == "(":
        fn, end = _parse_expr(s, j, n, paren=True)
        if end < n and s[end] not in _TERM:
            raise _Syntax(f"unexpected {_token_at(s, end)!r} after a formula")
        if sign == "-":
            inner = fn
            fn = lambda q: -inner(q)  # noqa: E731
        return fn, start, end, 0, (STYLE_PLUS if sign == "+" else 0), end
    if sign:
        if j < n and s[j] not in _TERM:
            raise _Syntax(f"malformed number {_token_at(s, start)!r}")
        return sign, start, start + 1, 0, 0, start + 1
    return None


# ---- Q formulas --------------------------------------------------------------------------


def _deg_fn(f: Callable[[float], float]) -> Callable[[float], float]:
    return lambda x: f(math.radians(x))


def _inv_deg_fn(f: Callable[[float], float]) -> Callable[[float], float]:
    return lambda x: math.degrees(f(x))


def _trunc(x: float) -> float:
    return float(math.trunc(x))


_FUNCS: dict[str, Callable[[float], float]] = {
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
_EXPR_NAMESPACE.update({f"_F_{name}": f for name, f in _FUNCS.items()})


class _ExprParser:
    """Recursive-descent parser of a TNC formula into Python source (numbers, ``q[...]``, operators).

    The source only ever holds numbers, Q parameter look-ups, arithmetic
    operators and the functions of ``_FUNCS``; :func:`_parse_expr` compiles it
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
            raise _Syntax(f"unexpected {_token_at(s, i)!r} in formula")
        return m.group()

    def take(self) -> str:
        tok = self.peek()
        if tok is None:
            raise _Syntax("formula ends too early")
        self.i += len(tok)
        self.count += 1
        if self.count > MAX_EXPR_TOKENS:
            raise _Syntax(f"formula longer than {MAX_EXPR_TOKENS} terms")
        return tok

    def enter(self) -> None:
        self.depth += 1
        if self.depth > MAX_EXPR_DEPTH:
            raise _Syntax("formula nested too deeply")

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
        elif tok in _FUNCS:
            f = f"_F_{tok}({self.unary()})"
        else:
            f = self.primary(tok)
        self.depth -= 1
        return f

    def primary(self, tok: str) -> str:
        if tok == "(":
            f = self.expr()
            if self.take() != ")":
                raise _Syntax("missing ')' in formula")
            return f
        if tok == "PI":
            return "_PI"
        if _QREF.fullmatch(tok):
            return f"q[{tok!r}]"
        if tok[0].isdigit() or tok[0] in ".,":
            value, _dec, _style = _number_style(tok, "")
            return repr(value)
        raise _Syntax(f"unexpected {tok!r} in formula")


def _compile(src: str) -> Callable[[dict[str, float]], float]:
    code = compile(f"lambda q: {src}", "<Klartext formula>", "eval")
    # the source holds only numbers, q[...] look-ups, operators and _FUNCS: see _ExprParser
    return eval(code, dict(_EXPR_NAMESPACE))


def _parse_expr(s: str, i: int, end: int, *, paren: bool = False) -> tuple[Callable, int]:
    """Parse a formula from ``i``; with ``paren`` exactly one parenthesised group."""
    p = _ExprParser(s, i, end)
    if paren:
        p.take()
        src = p.primary("(")
        return _compile(src), p.i
    src = p.expr()
    if p.peek() is not None:
        raise _Syntax(f"unexpected {_token_at(s, p.i)!r} in formula")
    return _compile(src), p.i


# --------------------------------------------------------------------------------------------
# lexer
# --------------------------------------------------------------------------------------------
_FAST_L = re.compile(
    r" *(?:\d+ +)?(L)"
    r"(?: +(I?)X([+-]?\d{1,7}(?:\.(\d{1,7}))?))?"
    r"(?: +(I?)Y([+-]?\d{1,7}(?:\.(\d{1,7}))?))?"
    r"(?: +(I?)Z([+-]?\d{1,7}(?:\.(\d{1,7}))?))?"
    r"(?: +(R[0LR]))?"
    r"(?: +F(MAX|\d{1,7}(?:\.\d{1,7})?))?"
    r"((?: +M\d{1,4})*) *\Z"
)
_FAST_C = re.compile(
    r" *(?:\d+ +)?(C|CC)"
    r"(?: +(I?)X([+-]?\d{1,7}(?:\.(\d{1,7}))?))?"
    r"(?: +(I?)Y([+-]?\d{1,7}(?:\.(\d{1,7}))?))?"
    r"(?: +(I?)Z([+-]?\d{1,7}(?:\.(\d{1,7}))?))?"
    r"(?: +DR([+-]))?"
    r"(?: +F(MAX|\d{1,7}(?:\.\d{1,7})?))?"
    r"((?: +M\d{1,4})*) *\Z"
)
_M_WORDS = re.compile(r"M(\d+)")
_PREFIX = re.compile(r"[ \t]*(/)?[ \t]*(?:(\d+)(?:[ \t]+|(?=[;*/])|\Z))?(/)?[ \t]*")
_KEYWORD = re.compile(
    r"BEGIN\s+PGM|END\s+PGM|TOOL\s+CALL|TOOL\s+DEF|BLK\s+FORM|CYCLE?\s+DEF|CYCL\s+CALL|CALL\s+LBL|"
    r"CALL\s+SELECTED\s+PGM|CALL\s+PGM|TCH\s+PROBE|SEL\s+[A-Z]+|DECLARE|FUNCTION|PATTERN\s+DEF|CONTOUR\s+DEF|"
    r"TRANS\s+DATUM|SQL|PRESET|FPOL|FSELECT|FCT|FLT|FC|FL|APPR|DEP|PLANE|STOP|LBL|FN\s*\d{1,3}\s*:|RND|CHF|"
    r"LP|LN|CC|CR|CT|CP|L|C|M(?=\d)|QS\d+|Q[LR]?\d+|;|\*"
)
_WORD = re.compile(r"IPA|IPR|PA|PR|LEN|CCA|DR[+-]|FMAX|FAUTO|FU|FZ|MB|LA|I[XYZABCUVW]|[XYZABCUVWRFM]")

_MOTION_KINDS = {"L": K_L, "LP": K_LP, "C": K_C, "CC": K_CC, "CR": K_CR, "CT": K_CT, "CP": K_CP,
                 "APPR": K_APPR, "DEP": K_DEP}
_ALLOWED = {
    K_L: frozenset(("coord", "rot", "rcomp", "feed", "m", "mb", "la")),
    K_LP: frozenset(("polar", "coord", "rot", "rcomp", "feed", "m", "mb", "la")),
    K_C: frozenset(("coord", "rot", "dr", "rcomp", "feed", "m")),
    K_CC: frozenset(("coord",)),
    K_CR: frozenset(("coord", "rot", "dr", "rcomp", "radius", "feed", "m")),
    K_CT: frozenset(("coord", "rot", "rcomp", "feed", "m")),
    K_CP: frozenset(("polar", "coord", "rot", "dr", "rcomp", "feed", "m")),
    K_APPR: frozenset(("coord", "polar", "len", "cca", "radius", "rcomp", "feed", "m")),
    K_DEP: frozenset(("coord", "polar", "len", "cca", "radius", "rcomp", "feed", "m")),
    K_M: frozenset(("m", "mb", "la", "feed")),
    K_STOP: frozenset(("m",)),
    K_CYCL_CALL: frozenset(("coord", "rot", "rcomp", "feed", "m")),
}
_BLOCK_NAMES = {K_L: "L", K_LP: "LP", K_C: "C", K_CC: "CC", K_CR: "CR", K_CT: "CT", K_CP: "CP",
                K_APPR: "APPR", K_DEP: "DEP", K_M: "M", K_STOP: "STOP", K_CYCL_CALL: "CYCL CALL"}
_APPR_SUBS = ("PLCT", "PLT", "PLN", "PCT", "LCT", "LT", "LN", "CT")

_BEGIN_RE = re.compile(r"BEGIN\s+PGM\s+(\S+)\s+(MM|INCH)\s*(?:;.*)?\Z", re.S)
_END_RE = re.compile(r"END\s+PGM\s+(\S+)(?:\s+(MM|INCH))?\s*(?:;.*)?\Z", re.S)
_LABEL = r"(\d{1,9}|\"[^\"]*\"|'[^']*'|Q[LRS]?\d{1,9})"
_LBL_RE = re.compile(r"LBL\s*" + _LABEL + r"\s*(?:;.*)?\Z", re.S)
_CALL_LBL_RE = re.compile(
    r"CALL\s+LBL\s*" + _LABEL + r"(?:\s*REP\s*(?:(\d{1,9})(?:\s*/\s*(\d{1,9}))?|(Q[LR]?\d+))?)?\s*(?:;.*)?\Z", re.S)
_FN_RE = re.compile(r"FN\s*(\d{1,3})\s*:\s*")
_FN_TARGET = re.compile(r"(Q[LR]?\d+)\s*=\s*")
_FN_OPS = {1: "+", 2: "-", 3: "*", 4: "DIV", 8: "LEN", 13: "ANG"}
_FN_UNARY = {5: "SQRT", 6: "SIN", 7: "COS"}
_FN_CMP = {9: "EQU", 10: "NE", 11: "GT", 12: "LT"}
# An FN 9..12 jump is parsed in two linear steps (one pattern with two lazy groups before GOTO
# backtracks cubically on a long line): the GOTO tail, then the comparison before it.
_FN_GOTO_RE = re.compile(r"[ \t]*GOTO\s+LBL\s*" + _LABEL + r"\s*(?:;.*)?\Z", re.S)
_FN_COND_RE = re.compile(r"IF\s*(.*?)\s*(EQU|NE|GT|LT)\s*(.*)\Z", re.S)
_SYSREAD_RE = re.compile(r"SYSREAD\s+(Q[LRS]?\d+)\s*=\s*(.*?)\s*(?:;.*)?\Z", re.S)
_ERROR_RE = re.compile(r"ERROR\s*=\s*(\S+)")
_Q_RE = re.compile(r"(Q[LR]?\d+)\s*=")
_CYCL_RE = re.compile(r"CYCLE?\s+DEF\s+(\d{1,4})(?:\.(\d{1,3}))?\b[ \t]*")
_TOOL_WORD = re.compile(r"DR2|DL|DR|S|F|L|R2|R")
_BLK_SUB = re.compile(r"0\.([12])\b")
_TOOL_ID = re.compile(r"\d{1,9}(?:\.\d{1,3})?|Q[LR]?\d+")


def _comment_free(s: str) -> str:
    """The block text without its ``;`` comments (which end at ``~``)."""
    return re.sub(r";[^~\n]*", "", s)


class _Lexer:
    """Split the text into blocks and parse each one."""

    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        self.text = text
        self.blocks: list[_Block] = []
        self.labels: dict[Any, int] = {}
        self.label_lines: dict[Any, int] = {}
        self.targets: set[Any] = set()
        self.dynamic_targets = False
        self.begin: tuple[str, str, int] | None = None
        self.end: tuple[str, int] | None = None
        self.warnings: list[str] = []
        self.skipped_lines: list[int] = []
        self.cycle_misspelled: int | None = None
        self.last_line = 0
        self.run_m: list[re.Match[str]] = []
        self.run_l: list[int] = []
        self.run_b: list[int] = []

    def error(self, line: int, problem: str) -> ProgramError:
        return ProgramError(self.path, line, problem)

    # ---- driver ----------------------------------------------------------------------------
    def run(self) -> None:
        text = self.text
        parts = text.split("\n")
        if parts and parts[-1] == "":
            parts.pop()
        offset = 0
        line_no = 0
        n = len(parts)
        k = 0
        fast = _FAST_L.match
        run_m, run_l, run_b = self.run_m, self.run_l, self.run_b
        while k < n:
            part = parts[k]
            line_no += 1
            first_line = line_no
            start = offset
            content = part[:-1] if part[-1:] == "\r" else part
            offset += len(part) + 1
            k += 1
            tail = content[-1:]
            if tail == "~" or (tail in (" ", "\t") and content.rstrip(" \t").endswith("~")):
                end = start + len(content)
                while content.rstrip(" \t").endswith("~") and k < n:
                    part = parts[k]
                    content = part[:-1] if part[-1:] == "\r" else part
                    end = offset + len(content)
                    offset += len(part) + 1
                    line_no += 1
                    k += 1
                self.block(text[start:end], start, first_line)
                continue
            m = fast(content)
            if m is not None and not m.group(13) and self.begin is not None and self.end is None:
                run_m.append(m)
                run_l.append(first_line)
                run_b.append(start)
                continue
            self.block(content, start, first_line)
        self.close_run(False)
        self.finish(line_no)

    def close_run(self, hold_last: bool) -> None:
        """Turn the open run of plain L blocks into one numpy run (or single blocks when short)."""
        ms, ls, bs = self.run_m, self.run_l, self.run_b
        if not ms:
            return
        last = None
        if hold_last:
            last = _Block(K_FASTL, ls.pop(), bs.pop(), ms.pop())
            last.hold = True
        blocks = self.blocks
        if len(ms) >= MIN_RUN:
            blocks.append(_Block(K_RUN, ls[0], bs[0], _Run(list(ms), list(ls), list(bs))))
        else:
            for m, ln, b in zip(ms, ls, bs, strict=True):
                blocks.append(_Block(K_FASTL, ln, b, m))
        if last is not None:
            blocks.append(last)
        ms.clear()
        ls.clear()
        bs.clear()

    def finish(self, last_line: int) -> None:
        self.last_line = last_line
        if self.begin is None:
            raise self.error(1, "empty program (no BEGIN PGM)")
        if self.end is None:
            raise self.error(max(last_line, 1), "no END PGM block (truncated program?)")
        blocks = self.blocks
        for k in range(len(blocks) - 1):
            if blocks[k + 1].kind in (K_RND, K_CHF):
                blocks[k].hold = True

    # ---- one block --------------------------------------------------------------------------
    def block(self, s: str, base: int, line: int) -> None:
        if line == 1 and s.startswith("\xef\xbb\xbf"):  # a UTF-8 byte order mark added by an editor
            s = s[3:]
            base += 3
        if self.end is not None:
            if s.strip(" \t\r\n\x1a"):
                raise self.error(line, f"text after END PGM: {s.strip()[:40]!r}")
            return
        if self.begin is not None:
            m = _FAST_L.match(s)
            if m is not None:
                self.close_run(False)
                self.blocks.append(_Block(K_FASTL, line, base, m))
                return
            m = _FAST_C.match(s)
            if m is not None and (m.group(1) == "C" or not any(m.groups()[10:])):
                self.close_run(False)
                kind = K_CC if m.group(1) == "CC" else K_C
                self.blocks.append(_Block(kind, line, base, _fast_motion(m, base, False)))
                return
        pm = _PREFIX.match(s)
        i = pm.end()
        if i >= len(s) or not s[i:].strip(" \t\r\n~"):
            if pm.group(2) is not None:
                raise self.error(line, f"block {pm.group(2)} is empty")
            return
        skip = pm.group(1) is not None or pm.group(3) is not None
        try:
            self.dispatch(s, i, base, line, skip)
        except _Syntax as exc:
            raise self.error(line, str(exc)) from None

    def dispatch(self, s: str, i: int, base: int, line: int, skip: bool) -> None:
        km = _KEYWORD.match(s, i)
        if km is None:
            raise _Syntax(f"unknown block {_token_at(s, i)!r}")
        kw = km.group()
        j = km.end()
        head = kw.split()[0] if kw[0] not in ";*" else kw
        if self.begin is None and not kw.startswith("BEGIN"):
            if kw in (";", "*"):
                raise _Syntax("a comment before BEGIN PGM; the program must start with BEGIN PGM")
            raise _Syntax(f"expected BEGIN PGM, found {_token_at(s, i)!r}")
        if kw[0] in ";*":
            return
        alpha = kw[-1].isalpha()
        if alpha and j < len(s) and s[j] not in _TERM and not (head in ("LBL", "CHF") or kw[0] == "M"):
            raise _Syntax(f"unknown block {_token_at(s, i)!r}")
        if skip:
            self.skipped_lines.append(line)
        self.close_run(kw in ("RND", "CHF"))
        rest_at = j
        blk = self.keyword(kw, s, i, rest_at, base, line)
        if blk is not None:
            self.blocks.append(blk)

    def keyword(self, kw: str, s: str, i: int, j: int, base: int, line: int) -> _Block | None:
        first = kw.split()[0]
        if kw in _MOTION_KINDS:
            kind = _MOTION_KINDS[kw]
            return _Block(kind, line, base, self.motion(kind, s, j, base))
        if kw == "M":
            return _Block(K_M, line, base, self.motion(K_M, s, i, base))
        if kw == "STOP":
            return _Block(K_STOP, line, base, self.motion(K_STOP, s, j, base))
        if kw == "RND":
            return _Block(K_RND, line, base, self.rnd(s, j))
        if kw == "CHF":
            return _Block(K_CHF, line, base, self.chf(s, j))
        if first == "BEGIN":
            return self.begin_pgm(s, i, base, line)
        if first == "END":
            return self.end_pgm(s, i, base, line)
        if kw == "LBL":
            return self.lbl(s, i, base, line)
        if first == "CALL" and kw.split()[1] == "LBL":
            return self.call_lbl(s, i, base, line)
        if first.startswith("FN"):
            return self.fn(s, i, base, line)
        if kw[0] == "Q":
            return self.q_formula(s, i, base, line)
        if first in ("CYCL", "CYCLE") and kw.split()[1] == "DEF":
            return self.cycl_def(s, i, base, line)
        if kw.startswith("CYCL") and "CALL" in kw:
            return self.cycl_call(s, j, base, line)
        if kw.startswith("TOOL") and kw.endswith("CALL"):
            return _Block(K_TOOL_CALL, line, base, self.tool_call(s, j))
        if kw.startswith("TOOL") and kw.endswith("DEF"):
            return _Block(K_TOOL_DEF, line, base, self.tool_def(s, j))
        if first == "BLK":
            self.blk_form(s, j)
            return None
        if kw == "PLANE":
            return _Block(K_PLANE, line, base, _comment_free(s[j:]).split())
        if kw == "CALL PGM" or " ".join(kw.split()) == "CALL PGM":
            return _Block(K_CALL_PGM, line, base, s[j:].strip())
        return _Block(K_LOOSE, line, base, (" ".join(kw.split()), _comment_free(s[j:]).split()))

    # ---- program frame ---------------------------------------------------------------------
    def begin_pgm(self, s: str, i: int, base: int, line: int) -> _Block:
        if self.begin is not None:
            raise _Syntax(f"second BEGIN PGM (the first is at line {self.begin[2]})")
        m = _BEGIN_RE.match(s, i)
        if m is None:
            raise _Syntax("malformed BEGIN PGM (expected 'BEGIN PGM name MM' or 'BEGIN PGM name INCH')")
        self.begin = (m.group(1), m.group(2), line)
        return _Block(K_BEGIN, line, base, None)

    def end_pgm(self, s: str, i: int, base: int, line: int) -> _Block:
        m = _END_RE.match(s, i)
        if m is None:
            raise _Syntax("malformed END PGM (expected 'END PGM name MM')")
        assert self.begin is not None
        name, unit = m.group(1), m.group(2)
        if unit is not None and unit != self.begin[1]:
            raise _Syntax(f"END PGM unit {unit} differs from BEGIN PGM unit {self.begin[1]}")
        if name != self.begin[0]:
            self.warnings.append(
                f"line {line}: END PGM names {name!r} but BEGIN PGM (line {self.begin[2]}) names {self.begin[0]!r}")
        self.end = (name, line)
        return _Block(K_END, line, base, None)

    # ---- motion words ----------------------------------------------------------------------
    def motion(self, kind: int, s: str, i: int, base: int) -> _Motion:
        mo = _Motion()
        allowed = _ALLOWED[kind]
        n = len(s)
        mo.insert_at = base + i
        if kind in (K_APPR, K_DEP):
            i = self.appr_sub(mo, s, i)
            mo.insert_at = base + i
        seen: set[str] = set()
        i = _skip_ws(s, i)
        while i < n:
            if s[i] == ";":
                break
            wm = _WORD.match(s, i)
            if wm is None:
                raise _Syntax(f"unknown word {_token_at(s, i)!r} in {_BLOCK_NAMES[kind]} block")
            i = self.word(kind, allowed, mo, seen, s, wm.group(), wm.end(), base)
            i = _skip_ws(s, i)
        if kind == K_CR and mo.radius is None:
            raise _Syntax("CR needs a radius R")
        return mo

    def appr_sub(self, mo: _Motion, s: str, i: int) -> int:
        j = _skip_ws(s, i)
        for sub in _APPR_SUBS:
            if s.startswith(sub, j) and (j + len(sub) >= len(s) or s[j + len(sub)] in _TERM):
                mo.sub = sub
                return j + len(sub)
        raise _Syntax(f"unknown approach/departure type {_token_at(s, j)!r} (LT, LN, CT, LCT, PLT, PLN, PCT, PLCT)")

    def word(self, kind: int, allowed: frozenset[str], mo: _Motion, seen: set[str], s: str, name: str, j: int,
             base: int) -> int:
        bname = _BLOCK_NAMES[kind]
        if name == "F":  # "F AUTO" / "F MAX" (a space between, as the TNC 640 also writes them)
            k = _skip_ws(s, j)
            for tail, word in (("AUTO", "FAUTO"), ("MAX", "FMAX")):
                if k > j and s.startswith(tail, k) and (k + len(tail) >= len(s) or s[k + len(tail)] in _TERM):
                    name, j = word, k + len(tail)
                    break
        cls = _word_class(name)
        if name == "R":
            return self.r_word(kind, allowed, mo, s, j, base)
        if cls not in allowed:
            raise _Syntax(f"word {_token_at(s, j - len(name))!r} is not allowed in a {bname} block")
        if cls == "dr" or name in ("FMAX", "FAUTO"):
            if j < len(s) and s[j] not in _TERM:
                raise _Syntax(f"unknown word {_token_at(s, j - len(name))!r} in {bname} block")
            if cls == "dr":
                mo.dr = 1 if name[2] == "+" else -1
            elif name == "FMAX":
                mo.feed = "MAX"
            else:
                mo.feed = "AUTO"
            return j
        if name == "MB" and s.startswith("MAX", _skip_ws(s, j)):
            k = _skip_ws(s, j) + 3
            mo.extra["MB"] = "MAX"
            return k
        got = _scan_value(s, j)
        if name in ("F", "M"):
            return self.f_or_m(mo, name, got, s, j)
        if name in ("FU", "FZ"):
            if got is None or isinstance(got[0], str):
                raise _Syntax(f"missing number after {name!r}")
            mo.feed = (name[1], got[0])
            return got[5]
        key = name[1:] if name[0] == "I" and name not in ("I",) else name
        if got is None or isinstance(got[0], str):
            what = f"{name}{got[0]}" if got is not None else name
            raise _Syntax(f"missing number after {what!r}")
        value, start, end, dec, style, nxt = got
        inc = name[0] == "I"
        if key in seen:
            raise _Syntax(f"{key} given twice in one block")
        seen.add(key)
        if cls == "coord":
            if key in _AXIS_INDEX:
                mo.coords.append((_AXIS_INDEX[key], inc, value, base + start, base + end, dec, style))
                mo.insert_at = base + end
            else:
                mo.rotary = True
        elif cls == "rot":  # A, B, C, U, V, W (and IA ..): read, not modelled; the block is never corrected
            mo.rotary = True
        elif cls == "polar":
            mo.polar[key] = (value, inc)
        elif cls in ("len", "cca", "mb", "la"):
            mo.extra[name] = value
        return nxt

    def f_or_m(self, mo: _Motion, name: str, got: tuple | None, s: str, j: int) -> int:
        if got is None:
            return j
        value, start, _end, _dec, _style, nxt = got
        if isinstance(value, str):
            raise _Syntax(f"missing number after {name}{value!r}")
        if name == "F":
            if mo.feed is not None and mo.ms and mo.ms[-1] in (103, 128):
                return nxt  # M103 F.. / M128 F..: a factor or a feed for the M function
            mo.feed = value
            return nxt
        if callable(value) or value != int(value) or value < 0:
            raise _Syntax(f"malformed M function {_token_at(s, start)!r}")
        mo.ms.append(int(value))
        return nxt

    def r_word(self, kind: int, allowed: frozenset[str], mo: _Motion, s: str, j: int, base: int) -> int:
        n = len(s)
        bname = _BLOCK_NAMES[kind]
        if j < n and s[j] in "LR" and (j + 1 >= n or s[j + 1] in _TERM):
            if "rcomp" not in allowed:
                raise _Syntax(f"radius compensation R{s[j]} is not allowed in a {bname} block")
            mo.rcomp = "R" + s[j]
            return j + 1
        got = _scan_value(s, j)
        if got is None:
            if "rcomp" not in allowed:
                raise _Syntax(f"word 'R' is not allowed in a {bname} block")
            return j
        value, start, end, dec, _style, nxt = got
        if isinstance(value, str):
            if kind != K_L:
                raise _Syntax(f"missing number after 'R{value}'")
            mo.rcomp = "R" + value
            return nxt
        if not callable(value) and value == 0 and dec == 0 and s[start:end].strip("+ \t") == "0" and "rcomp" in allowed:
            mo.rcomp = "R0"
            return nxt
        if "radius" not in allowed:
            raise _Syntax(f"radius {_token_at(s, j - 1)!r} is not allowed in a {bname} block")
        mo.radius = value
        return nxt

    def rnd(self, s: str, i: int) -> _Motion:
        mo = _Motion()
        j = _skip_ws(s, i)
        if not s.startswith("R", j):
            raise _Syntax("RND needs a radius R")
        got = _scan_value(s, j + 1)
        if got is None or isinstance(got[0], str):
            raise _Syntax("RND needs a radius R")
        mo.radius = got[0]
        self.tail_feed(mo, s, got[5], "RND")
        return mo

    def chf(self, s: str, i: int) -> _Motion:
        mo = _Motion()
        got = _scan_value(s, i)
        if got is None or isinstance(got[0], str):
            raise _Syntax("CHF needs a chamfer length")
        mo.radius = got[0]
        self.tail_feed(mo, s, got[5], "CHF")
        return mo

    def tail_feed(self, mo: _Motion, s: str, i: int, what: str) -> None:
        i = _skip_ws(s, i)
        n = len(s)
        while i < n and s[i] != ";":
            if s.startswith("F", i):
                got = _scan_value(s, i + 1)
                if got is None or isinstance(got[0], str):
                    raise _Syntax(f"missing number after 'F' in {what} block")
                mo.feed = got[0]
                i = _skip_ws(s, got[5])
                continue
            wm = _M_WORDS.match(s, i)
            if wm is not None and (wm.end() >= n or s[wm.end()] in _TERM):
                i = _skip_ws(s, wm.end())
                continue
            raise _Syntax(f"unexpected {_token_at(s, i)!r} in {what} block")

    # ---- labels and calls --------------------------------------------------------------------
    def lbl(self, s: str, i: int, base: int, line: int) -> _Block:
        m = _LBL_RE.match(s, i)
        if m is None:
            raise _Syntax(f"malformed label {_token_at(s, i)!r} (expected LBL number or LBL \"name\")")
        key = _label_key(m.group(1))
        if isinstance(key, tuple):
            raise _Syntax("a label cannot be a Q parameter")
        if key != 0:
            if key in self.labels:
                raise _Syntax(f"label {m.group(1)} defined twice (first at line {self.label_lines[key]})")
            self.labels[key] = len(self.blocks)
            self.label_lines[key] = line
        return _Block(K_LBL, line, base, key)

    def call_lbl(self, s: str, i: int, base: int, line: int) -> _Block:
        m = _CALL_LBL_RE.match(s, i)
        if m is None:
            raise _Syntax(f"malformed label call {s[i:].strip()[:40]!r}")
        key = _label_key(m.group(1))
        self.note_target(key)
        if m.group(4) is not None:
            rep: Any = _qget(m.group(4), False)
        elif m.group(2) is not None:
            rep = int(m.group(2))
            if m.group(3) is not None and int(m.group(3)) != rep:
                self.warnings.append(f"line {line}: REP {m.group(2)}/{m.group(3)}: {m.group(2)} repetitions used")
        else:
            rep = 0
        if key == 0:
            raise _Syntax("CALL LBL 0 is not allowed (LBL 0 ends a subprogram)")
        return _Block(K_CALL_LBL, line, base, (key, rep))

    def note_target(self, key: Any) -> None:
        if isinstance(key, tuple):
            self.dynamic_targets = True
        else:
            self.targets.add(key)

    # ---- FN and formulas ---------------------------------------------------------------------
    def fn(self, s: str, i: int, base: int, line: int) -> _Block:
        m = _FN_RE.match(s, i)
        if m is None:
            raise _Syntax(f"malformed FN block {_token_at(s, i)!r}")
        num = int(m.group(1))
        j = m.end()
        if num in _FN_OPS or num in _FN_UNARY or num == 0:
            return _Block(K_FN_ARITH, line, base, self.fn_arith(num, s, j))
        if num in _FN_CMP:
            return _Block(K_FN_JUMP, line, base, self.fn_jump(num, s, j))
        if num == 14:
            em = _ERROR_RE.match(s, j)
            if em is None:
                raise _Syntax("malformed FN 14 (expected 'FN 14: ERROR= number')")
            return _Block(K_FN_ERROR, line, base, em.group(1))
        if num == 18:
            sm = _SYSREAD_RE.match(s, j)
            if sm is None:
                raise _Syntax("malformed FN 18 (expected 'FN 18: SYSREAD Qn = ID.. NR..')")
            return _Block(K_FN_SYSREAD, line, base, sm.group(1))
        if num > 45:
            raise _Syntax(f"unknown function FN {num}")
        return _Block(K_FN_OTHER, line, base, (num, s[j:].strip()))

    def fn_operand(self, s: str, j: int) -> tuple[Any, int]:
        got = _scan_value(s, j)
        if got is None or isinstance(got[0], str):
            raise _Syntax(f"missing operand at {_token_at(s, _skip_ws(s, j))!r}")
        return got[0], got[5]

    def fn_arith(self, num: int, s: str, j: int) -> tuple[str, Callable]:
        tm = _FN_TARGET.match(s, _skip_ws(s, j))
        if tm is None:
            raise _Syntax(f"malformed FN {num} (expected 'FN {num}: Qn = ...')")
        target = tm.group(1)
        j = tm.end()
        if num in _FN_UNARY:
            word = _FN_UNARY[num]
            k = _skip_ws(s, j)
            if not s.startswith(word, k):
                raise _Syntax(f"FN {num} expects {word}")
            a, j = self.fn_operand(s, k + len(word))
            fn = _FUNCS[word]
            fa = _as_fn(a)
            f: Callable = lambda q: fn(fa(q))  # noqa: E731
        else:
            a, j = self.fn_operand(s, j)
            f = _as_fn(a)
            if num != 0:
                op = _FN_OPS[num]
                k = _skip_ws(s, j)
                if not s.startswith(op, k):
                    raise _Syntax(f"FN {num} expects the operator {op}")
                b, j = self.fn_operand(s, k + len(op))
                f = _fn_op(op, f, _as_fn(b))
        k = _skip_ws(s, j)
        if k < len(s) and s[k] != ";":
            raise _Syntax(f"unexpected {_token_at(s, k)!r} after FN {num}")
        return target, f

    def fn_jump(self, num: int, s: str, j: int) -> tuple[str, Callable, Callable, Any]:
        bad = f"malformed FN {num} (expected 'FN {num}: IF a {_FN_CMP[num]} b GOTO LBL n')"
        g = _FN_GOTO_RE.search(s, j)
        if g is None:
            raise _Syntax(bad)
        m = _FN_COND_RE.match(s[:g.start()], j)
        if m is None:
            raise _Syntax(bad)
        if m.group(2) != _FN_CMP[num]:
            raise _Syntax(f"FN {num} compares with {_FN_CMP[num]}, not {m.group(2)}")
        a = self.operand_text(m.group(1), s, m.start(1))
        b = self.operand_text(m.group(3).rstrip(), s, m.start(3))
        key = _label_key(g.group(1))
        self.note_target(key)
        return m.group(2), a, b, key

    def operand_text(self, txt: str, s: str, at: int) -> Callable:
        got = _scan_value(txt, 0)
        if got is None or isinstance(got[0], str) or _skip_ws(txt, got[5]) != len(txt):
            raise _Syntax(f"malformed operand {txt!r}")
        return _as_fn(got[0])

    def q_formula(self, s: str, i: int, base: int, line: int) -> _Block:
        if s.startswith("QS", i):
            return _Block(K_QS, line, base, s[i:].split("=")[0].strip())
        m = _Q_RE.match(s, i)
        if m is None:
            raise _Syntax(f"malformed Q parameter formula {_token_at(s, i)!r} (expected 'Qn = formula')")
        f, _end = _parse_expr(s, m.end(), len(s))
        return _Block(K_Q, line, base, (m.group(1), f))

    # ---- cycles -----------------------------------------------------------------------------
    def cycl_def(self, s: str, i: int, base: int, line: int) -> _Block:
        m = _CYCL_RE.match(s, i)
        if m is None:
            raise _Syntax(f"malformed cycle definition {s[i:].strip()[:40]!r}")
        if m.group(0).startswith("CYCLE") and self.cycle_misspelled is None:
            self.cycle_misspelled = line
        num = int(m.group(1))
        sub = int(m.group(2)) if m.group(2) is not None else None
        rest = s[m.end():]
        data: Any = rest
        if sub is not None and sub >= 1 and num in (7, 10, 11, 19):
            data = self.cycle_words(num, rest)
        elif sub == 1 and num == 32:
            data = self.tolerance_word(rest)
        elif sub is not None and sub >= 1 and num == 8:
            axes = _comment_free(rest).split()
            for a in axes:
                if a not in ("X", "Y", "Z", "U", "V", "W"):
                    raise _Syntax(f"unknown mirror axis {a!r}")
            data = axes
        else:
            self.check_cycle_params(rest)
        return _Block(K_CYCL_DEF, line, base, (num, sub, data))

    def cycle_words(self, num: int, rest: str) -> Any:
        body = _comment_free(rest).strip()
        if num == 7 and body.startswith("#"):
            return ("#", body)
        words: list[tuple[str, Any]] = []
        i = _skip_ws(rest, 0)
        n = len(rest)
        names = {7: r"I?[XYZABCUVW]", 10: r"I?ROT", 11: r"SCL", 19: r"[ABC]|F|ABST"}[num]
        rx = re.compile(names)
        while i < n and rest[i] != ";":
            m = rx.match(rest, i)
            if m is None:
                raise _Syntax(f"unexpected {_token_at(rest, i)!r} in cycle {num}")
            got = _scan_value(rest, m.end())
            if got is None or isinstance(got[0], str):
                raise _Syntax(f"missing number after {m.group()!r} in cycle {num}")
            words.append((m.group(), got[0]))
            i = _skip_ws(rest, got[5])
        return words

    def tolerance_word(self, rest: str) -> Any:
        """The ``T`` value of ``CYCL DEF 32.1`` (a number or a Q closure), None when the block has none."""
        body = _comment_free(rest)
        m = re.match(r"[ \t]*T(?=[ \t]*[-+0-9.,Q(]|[ \t]*$)", body)
        if m is None:
            return None
        got = _scan_value(body, m.end())
        if got is None or isinstance(got[0], str):
            raise _Syntax("missing number after T in cycle 32.1")
        return got[0]

    def check_cycle_params(self, rest: str) -> None:
        for m in re.finditer(r"\bQ\d+\s*=\s*([^\s;~]+)", _comment_free(rest)):
            txt = m.group(1)
            got = _scan_value(txt, 0)
            if got is None or isinstance(got[0], str) or got[5] != len(txt):
                raise _Syntax(f"malformed cycle parameter {m.group(0)!r}")

    def cycl_call(self, s: str, j: int, base: int, line: int) -> _Block:
        k = _skip_ws(s, j)
        mode = ""
        for word in ("POS", "PAT"):
            if s.startswith(word, k) and (k + 3 >= len(s) or s[k + 3] in _TERM):
                mode = word
                k += 3
        mo = self.motion(K_CYCL_CALL, s, k, base)
        if mode != "POS" and mo.coords:
            raise _Syntax("coordinates in CYCL CALL need POS")
        mo.sub = mode
        return _Block(K_CYCL_CALL, line, base, mo)

    # ---- tools, blank ------------------------------------------------------------------------
    def tool_id(self, s: str, i: int) -> tuple[Any, int]:
        i = _skip_ws(s, i)
        if i < len(s) and s[i] in "\"'":
            q = s.find(s[i], i + 1)
            if q < 0:
                raise _Syntax("tool name without closing quote")
            return s[i + 1:q], q + 1
        m = _TOOL_ID.match(s, i)
        if m is not None and (m.end() >= len(s) or s[m.end()] in _TERM):
            txt = m.group()
            return (_qget(txt, False) if txt[0] == "Q" else float(txt)), m.end()
        return None, i

    def tool_call(self, s: str, j: int) -> dict[str, Any]:
        out: dict[str, Any] = {}
        tool, i = self.tool_id(s, j)
        out["tool"] = tool
        i = _skip_ws(s, i)
        if i < len(s) and s[i] in "XYZUVW" and (i + 1 >= len(s) or s[i + 1] in _TERM):
            out["axis"] = s[i]
            i += 1
        self.tool_words(s, i, out, ("S", "F", "DL", "DR", "DR2"), "TOOL CALL")
        return out

    def tool_def(self, s: str, j: int) -> dict[str, Any]:
        out: dict[str, Any] = {}
        tool, i = self.tool_id(s, j)
        out["tool"] = tool
        self.tool_words(s, i, out, ("L", "R", "R2", "DL", "DR", "DR2"), "TOOL DEF")
        return out

    def tool_words(self, s: str, i: int, out: dict[str, Any], allowed: tuple[str, ...], what: str) -> None:
        i = _skip_ws(s, i)
        n = len(s)
        while i < n and s[i] != ";":
            m = _TOOL_WORD.match(s, i)
            if m is None or m.group() not in allowed:
                raise _Syntax(f"unexpected {_token_at(s, i)!r} in {what}")
            got = _scan_value(s, m.end())
            if got is None or isinstance(got[0], str):
                raise _Syntax(f"missing number after {m.group()!r} in {what}")
            out[m.group()] = got[0]
            i = _skip_ws(s, got[5])

    def blk_form(self, s: str, j: int) -> None:
        k = _skip_ws(s, j)
        m = _BLK_SUB.match(s, k)
        if m is None:
            return  # BLK FORM CYLINDER / ROTATION / FILE: accepted as they are
        i = _skip_ws(s, m.end())
        if m.group(1) == "1" and i < len(s) and s[i] in "XYZ" and (i + 1 >= len(s) or s[i + 1] in _TERM):
            i += 1
        self.motion(K_CC, s, i, 0)  # checks the coordinate words


def _fast_motion(m: re.Match[str], base: int, is_l: bool) -> _Motion:
    """The words of a block matched by ``_FAST_L`` / ``_FAST_C``."""
    mo = _Motion()
    coords = mo.coords
    last = m.end(1)
    for axis, g in ((0, 2), (1, 5), (2, 8)):
        txt = m.group(g + 1)
        if txt is None:
            continue
        frac = m.group(g + 2)
        style = STYLE_LITERAL | STYLE_PLUS if txt[0] == "+" else STYLE_LITERAL
        last = m.end(g + 1)
        coords.append((axis, m.group(g) == "I", float(txt), base + m.start(g + 1), base + last,
                       len(frac) if frac else 0, style))
    mo.insert_at = base + last
    groups = m.groups()
    if groups[10] is not None:
        if is_l:
            mo.rcomp = groups[10]
        else:
            mo.dr = 1 if groups[10] == "+" else -1
    feed = groups[11]
    if feed is not None:
        mo.feed = "MAX" if feed == "MAX" else float(feed)
    if groups[-1]:
        mo.ms = [int(x) for x in _M_WORDS.findall(groups[-1])]
    return mo


class _Run:
    """A run of plain ``L`` blocks (``_FAST_L`` matches without M words), read as numpy columns."""

    __slots__ = ("_blocks", "_cols", "bases", "lines", "matches")

    def __init__(self, matches: list[re.Match[str]], lines: list[int], bases: list[int]) -> None:
        self.matches = matches
        self.lines = lines
        self.bases = bases
        self._blocks: list[_Block] | None = None
        self._cols: dict[str, np.ndarray] | None = None

    def blocks(self) -> list[_Block]:
        """The blocks one by one (for the block-by-block path)."""
        if self._blocks is None:
            self._blocks = [_Block(K_L, ln, b, _fast_motion(m, b, True))
                            for m, ln, b in zip(self.matches, self.lines, self.bases, strict=True)]
        return self._blocks

    def columns(self, tb: np.ndarray) -> dict[str, np.ndarray] | None:
        """Values, spans and styles of all blocks of the run as arrays (built once).

        ``tb`` is the whole text as bytes. Every number is parsed from the
        bytes with integer arithmetic (digits -> integer mantissa -> one
        division), which gives exactly ``float(text)``. Returns None for a run
        with a number too long for that (read block by block instead).
        """
        if self._cols is not None:
            return self._cols
        bases = np.array(self.bases, dtype=np.int64)
        seg0 = int(bases[0])
        seg1 = int(bases[-1]) + self.matches[-1].end()
        t = tb[seg0:seg1]
        rel = bases - seg0
        newlines = np.append(np.flatnonzero(t == 10), t.shape[0])
        line_end = newlines[np.searchsorted(newlines, rel)]
        mark = np.zeros(t.shape[0] + 1, dtype=np.int8)
        mark[rel] = 1
        mark[line_end] = -1
        inrun = np.cumsum(mark[:-1]) > 0
        prev = np.empty_like(t)
        prev[0] = 32
        prev[1:] = t[:-1]
        word_at = inrun & (prev == 32)
        isval = ((t >= 48) & (t <= 57)) | (t == 43) | (t == 45) | (t == 46)
        stops = np.append(np.flatnonzero(~isval), t.shape[0])
        n = bases.shape[0]
        cols: dict[str, np.ndarray] = {}
        vals = np.full((n, 3), np.nan)
        ws = np.full((n, 3), -1, dtype=np.int64)
        we = np.full((n, 3), -1, dtype=np.int64)
        dec = np.zeros((n, 3), dtype=np.int8)
        style = np.zeros((n, 3), dtype=np.int8)
        inc = np.zeros((n, 3), dtype=bool)
        for a, letter in enumerate(b"XYZ"):
            pos = np.flatnonzero((t == letter) & inrun & ((prev == 32) | (prev == 73)))
            row = np.searchsorted(rel, pos, side="right") - 1
            parsed = _parse_numbers(t, pos + 1, stops)
            if parsed is None:
                return None
            value, start, end, d, plus = parsed
            vals[row, a] = value
            ws[row, a] = start + seg0
            we[row, a] = end + seg0
            dec[row, a] = d
            style[row, a] = STYLE_LITERAL | np.where(plus, STYLE_PLUS, 0)
            inc[row, a] = prev[pos] == 73
        fpos = np.flatnonzero((t == 70) & word_at)
        frow = np.searchsorted(rel, fpos, side="right") - 1
        rapid = np.zeros(n, dtype=bool)
        fval = np.full(n, np.nan)
        is_max = t[np.minimum(fpos + 1, t.shape[0] - 1)] == 77
        rapid[frow[is_max]] = True
        parsed = _parse_numbers(t, fpos[~is_max] + 1, stops)
        if parsed is None:
            return None
        fval[frow[~is_max]] = parsed[0]
        rpos = np.flatnonzero((t == 82) & word_at)
        rcomp = np.zeros(n, dtype=np.int8)
        nxt = t[np.minimum(rpos + 1, t.shape[0] - 1)]
        rcomp[np.searchsorted(rel, rpos, side="right") - 1] = np.where(nxt == 48, 1, np.where(nxt == 76, 2, 3))
        lpos = np.flatnonzero((t == 76) & inrun & ((prev == 32) | (prev == 9) | (prev == 10)))
        if lpos.shape[0] != n:
            return None
        ins = lpos + 1 + seg0
        for a in range(3):
            ins = np.where(ws[:, a] >= 0, we[:, a], ins)
        cols.update(vals=vals, has=~np.isnan(vals), inc=inc, ws=ws, we=we, dec=dec, style=style, ins=ins,
                    rapid=rapid, fval=fval, rcomp=rcomp, line=np.array(self.lines, dtype=np.int32))
        self._cols = cols
        return cols


def _parse_numbers(t: np.ndarray, start: np.ndarray, stops: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Parse the numbers ``[+-]digits[.digits]`` that begin at ``start`` in the byte array ``t``.

    Returns (value, start, end, decimals, explicit plus), or None when a number
    has more than 15 digits.
    """
    if start.size == 0:
        e = np.zeros(0, dtype=np.int64)
        return np.zeros(0), e, e, e, np.zeros(0, dtype=bool)
    end = stops[np.searchsorted(stops, start)]
    first = t[start]
    signed = (first == 43) | (first == 45)
    ds = start + signed
    length = end - ds
    if int(length.max()) > 16:
        return None
    total = int(length.sum())
    offs = np.cumsum(length) - length
    owner = np.repeat(np.arange(start.shape[0]), length)
    p = np.arange(total) - offs[owner] + ds[owner]
    ch = t[p]
    isdot = ch == 46
    dot_at = np.full(start.shape[0], -1, dtype=np.int64)
    dot_at[owner[isdot]] = p[isdot]
    has_dot = dot_at >= 0
    dotpos = np.where(has_dot, dot_at, end)
    exponent = (end[owner] - 1 - p) - (has_dot[owner] & (p < dotpos[owner]))
    digits = np.where(isdot, 0, ch.astype(np.int64) - 48)
    mant = np.add.reduceat(digits * 10 ** np.maximum(exponent, 0), offs) if total else np.zeros(0, np.int64)
    decimals = np.where(has_dot, end - dotpos - 1, 0)
    value = mant / 10.0 ** decimals
    value = np.where(first == 45, -value, value)
    return value, start, end, decimals, first == 43


_RCOMP_CODE = {"R0": 1, "RL": 2, "RR": 3}
_RCOMP_NAME = {1: "R0", 2: "RL", 3: "RR"}


def _ffill(values: np.ndarray, present: np.ndarray, initial: float) -> np.ndarray:
    """Forward-fill ``values`` where ``present`` is False, starting from ``initial``."""
    idx = np.where(present, np.arange(values.shape[0]), -1)
    last = np.maximum.accumulate(idx)
    return np.where(last >= 0, values[np.maximum(last, 0)], initial)


def _word_class(name: str) -> str:
    if name in ("PA", "PR", "IPA", "IPR"):
        return "polar"
    if name in ("DR+", "DR-"):
        return "dr"
    if name in ("F", "FMAX", "FAUTO", "FU", "FZ"):
        return "feed"
    if name == "M":
        return "m"
    if name == "LEN":
        return "len"
    if name == "CCA":
        return "cca"
    if name == "MB":
        return "mb"
    if name == "LA":
        return "la"
    axis = name[-1]
    if axis in _AXIS_INDEX:
        return "coord"
    return "rot"


def _cycle_name(rest: str) -> str:
    """The name of a cycle from the text after ``CYCL DEF n``: up to ``~``, a comment or a parameter."""
    head = re.split(r"[~;]|\bQ\d+\s*=", rest, maxsplit=1)[0]
    return " ".join(head.split())


def _label_key(txt: str) -> Any:
    if txt[0] in "\"'":
        return txt[1:-1]
    if txt[0] == "Q":
        return ("Q", txt)
    return int(txt)


def _as_fn(v: Any) -> Callable:
    if callable(v):
        return v
    return lambda q: v


def _fn_op(op: str, f: Callable, g: Callable) -> Callable:
    if op == "+":
        return lambda q: f(q) + g(q)
    if op == "-":
        return lambda q: f(q) - g(q)
    if op == "*":
        return lambda q: f(q) * g(q)
    if op == "DIV":
        return lambda q: f(q) / g(q)
    if op == "LEN":
        return lambda q: math.hypot(f(q), g(q))
    return lambda q: math.degrees(math.atan2(g(q), f(q)))


# --------------------------------------------------------------------------------------------
# interpreter
# --------------------------------------------------------------------------------------------
# fields of a move record (a list, so a held move can still be shortened by RND / CHF)
(R_KIND, R_LINE, R_START, R_END, R_FEED, R_OFF, R_CEN, R_PLANE, R_TURNS, R_CORR, R_FLAGS, R_WS, R_WE, R_WD,
 R_WST, R_WI, R_CS, R_CE, R_CD, R_CST, R_CI, R_INS) = range(22)
_EPS = 1e-9
_NEVER_SET = "is never set in this program (its value comes from the control or a calling program)"
_LOOSE_STOP = {
    "TCH PROBE": "touch probe cycles move the tool; their motion is not modelled",
    "FPOL": "FK free contour programming is not modelled",
    "FL": "FK free contour programming is not modelled",
    "FLT": "FK free contour programming is not modelled",
    "FC": "FK free contour programming is not modelled",
    "FCT": "FK free contour programming is not modelled",
    "FSELECT": "FK free contour programming is not modelled",
    "LN": "LN blocks (3-D tool compensation with surface normals) are not modelled",
    "CALL SELECTED PGM": "CALL SELECTED PGM: the called program is not read",
    "SQL": "SQL functions set Q parameters from tables; their values are not known",
    "PRESET": "PRESET changes the workpiece datum; the new datum is not known",
}


def _rec(kind: int, line: int, start: list[float], end: list[float], feed: float, off: list[float],
         plane: int, flags: int) -> list:
    """A move record with no word spans (derived moves)."""
    return [kind, line, start, end, feed, tuple(off), _NAN3, plane, 1, False, flags, _NONE3, _NONE3, _ZERO3,
            _ZERO3, _FALSE3, _NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3, -1]


def _spans(mo: _Motion) -> tuple[list[int], list[int], list[int], list[int], list[bool]]:
    ws = [-1, -1, -1]
    we = [-1, -1, -1]
    wd = [0, 0, 0]
    wst = [0, 0, 0]
    wi = [False, False, False]
    for ax, inc, _v, s, e, dec, style in mo.coords:
        ws[ax] = s
        we[ax] = e
        wd[ax] = dec
        wst[ax] = style
        wi[ax] = inc
    return ws, we, wd, wst, wi


class _Interp:
    """Executes the lexed blocks and collects the moves."""

    def __init__(self, lex: _Lexer, unit: float) -> None:
        self.path = lex.path
        self.text = lex.text
        self._tb: np.ndarray | None = None
        self.blocks = lex.blocks
        self.labels = lex.labels
        self.unit = unit
        self.b = MoveTableBuilder()
        self.q: dict[str, float] = {}
        self.unknown: dict[str, tuple[str, str]] = {}
        self.pos = [0.0, 0.0, 0.0]
        self.off = [0.0, 0.0, 0.0]
        self.feed = _NAN
        self.tool_feed = _NAN
        self.spindle = _NAN
        self.rcomp = "R0"
        self.plane = PLANE_XY
        self.pole: tuple[list[float], int] | None = None
        self.cc_spans: tuple | None = None
        self.dr = 0
        self.rot = 0.0
        self.frame: dict[str, tuple[int, str]] = {}
        self.cycle: tuple[int, str, int] | None = None
        self.m89 = False
        self.cycle_calls: dict[int, list] = {}
        self.stack: list[list[int]] = []
        self.pending: list | None = None
        self.pending_tol = BLEND_PROFILE  # path tolerance when the held move was programmed
        self.tol = BLEND_PROFILE  # cycle 32 tolerance (MoveTable.blend_tol_mm), mm
        self.corner: tuple[str, float, float, int] | None = None
        self.appr: tuple | None = None
        self.last: list | None = None
        self.tools: dict[float, float] = {}
        self.tool: float | None = None
        self.warnings: list[str] = []
        self.warned: set[str] = set()
        self.unsupported: tuple[int, str] | None = None
        self.n_moves = 0
        self.counts = [0] * len(self.blocks)
        self.handlers: dict[int, Callable[[_Block, int], int | None]] = {
            K_BEGIN: self.h_nothing, K_END: self.h_end, K_L: self.h_l, K_LP: self.h_lp, K_C: self.h_c,
            K_CC: self.h_cc, K_CR: self.h_cr, K_CT: self.h_ct, K_CP: self.h_cp, K_RND: self.h_corner,
            K_CHF: self.h_corner, K_APPR: self.h_appr, K_DEP: self.h_dep, K_M: self.h_m, K_STOP: self.h_m,
            K_FN_ARITH: self.h_assign, K_Q: self.h_assign, K_FN_JUMP: self.h_jump, K_FN_ERROR: self.h_fn_error,
            K_FN_SYSREAD: self.h_sysread, K_FN_OTHER: self.h_fn_other, K_QS: self.h_qs, K_LBL: self.h_lbl,
            K_CALL_LBL: self.h_call_lbl, K_CALL_PGM: self.h_call_pgm, K_CYCL_DEF: self.h_cycl_def,
            K_CYCL_CALL: self.h_cycl_call, K_TOOL_CALL: self.h_tool_call, K_TOOL_DEF: self.h_tool_def,
            K_PLANE: self.h_plane, K_LOOSE: self.h_loose, K_FASTL: self.h_fastl, K_RUN: self.h_run,
        }
        self.executed = 0
        self.moved_at = 0
        self.loop_saved: tuple | None = None
        self.loop_power = 1
        self.loop_count = 0

    def text_bytes(self) -> np.ndarray:
        if self._tb is None:
            self._tb = np.frombuffer(self.text.encode("latin-1"), dtype=np.uint8)
        return self._tb

    # ---- driver -------------------------------------------------------------------------------
    def run(self) -> None:
        blocks = self.blocks
        counts = self.counts
        handlers = self.handlers
        n = len(blocks)
        i = 0
        try:
            while i < n:
                blk = blocks[i]
                counts[i] += 1
                self.executed += 1
                if self.executed > MAX_BLOCKS:
                    raise _Stop(blk.line, f"loop does not terminate (more than {MAX_BLOCKS:,} blocks executed)")
                nxt = handlers[blk.kind](blk, i)
                if nxt is None:
                    i += 1
                elif nxt < 0:
                    break
                else:
                    if nxt <= i:
                        self.loop_check(nxt, blk.line)
                    i = nxt
            self.finish(blocks[min(i, n - 1)].line)
        except _Stop as stop:
            self.unsupported = (stop.line, stop.problem)
            if self.corner is None and self.pending is not None:
                self.add(self.pending, self.pending_tol)
            self.pending = None
        self.cycle_warnings()

    def control_state(self) -> tuple:
        """Everything that steers the program flow besides the Q parameters (positions never do)."""
        feed = None if self.feed != self.feed else self.feed
        tool_feed = None if self.tool_feed != self.tool_feed else self.tool_feed
        return (tuple(tuple(f) for f in self.stack), tuple(self.off), feed, tool_feed, self.plane, self.rcomp,
                self.cycle, tuple(sorted(self.frame)), self.m89, self.dr, self.rot, self.tool,
                None if self.pole is None else (tuple(self.pole[0]), self.pole[1]),
                self.corner is None, self.appr is None, self.pending is None)

    def loop_check(self, target: int, line: int) -> None:
        """Detect a program that jumps back into a state it was in before (Brent's cycle detection).

        Control flow depends only on the Q parameters and the state of
        :meth:`control_state`, so coming back to the same block in the same
        state means the program repeats itself forever.
        """
        if self.executed - self.moved_at > MAX_IDLE_BLOCKS:
            raise _Stop(line, f"loop does not terminate (more than {MAX_IDLE_BLOCKS:,} blocks without a move)")
        saved = self.loop_saved
        if (saved is not None and saved[0] == target and saved[1] == self.q and saved[2] == self.unknown
                and saved[3] == self.control_state()):
            raise _Stop(line, f"endless loop: the program jumps back to line {self.blocks[target].line} in the "
                              "same state again and again")
        self.loop_count += 1
        if self.loop_count >= self.loop_power:
            self.loop_saved = (target, dict(self.q), dict(self.unknown), self.control_state())
            self.loop_power *= 2
            self.loop_count = 0

    def finish(self, line: int) -> None:
        if self.corner is not None:
            raise _Stop(self.corner[3], f"{self.corner[0]} without a following contour element")
        if self.appr is not None:
            raise _Stop(self.appr[0], "APPR without a following contour element")
        if self.pending is not None:
            self.add(self.pending, self.pending_tol)
            self.pending = None

    def warn(self, key: str, text: str) -> None:
        if key not in self.warned:
            self.warned.add(key)
            self.warnings.append(text)

    # ---- values -------------------------------------------------------------------------------
    def num(self, v: Any, line: int) -> float:
        """Evaluate a word value (float or Q closure); unknown values stop the interpretation."""
        if type(v) is float:
            return v
        try:
            r = v(self.q)
        except KeyError as exc:
            raise _Stop(line, self.unknown_text(str(exc.args[0]))) from None
        except (ZeroDivisionError, ValueError, OverflowError) as exc:
            raise _Stop(line, f"Q parameter arithmetic fails ({exc}); the control stops here") from None
        if not math.isfinite(r):
            raise _Stop(line, f"Q parameter arithmetic gives {r}; the control stops here")
        return float(r)

    def root(self, key: str) -> tuple[str, str]:
        return self.unknown.get(key, (key, _NEVER_SET))

    def unknown_text(self, key: str) -> str:
        root, why = self.root(key)
        if root == key:
            return f"{key} is not known: it {why}"
        return f"{key} is not known: it depends on {root}, which {why}"

    def assign(self, key: str, f: Callable, line: int) -> None:
        try:
            r = f(self.q)
        except KeyError as exc:
            self.q.pop(key, None)
            self.unknown[key] = self.root(str(exc.args[0]))
            return
        except (ZeroDivisionError, ValueError, OverflowError) as exc:
            raise _Stop(line, f"{key}: Q parameter arithmetic fails ({exc}); the control stops here") from None
        if not math.isfinite(r):
            raise _Stop(line, f"{key}: Q parameter arithmetic gives {r}; the control stops here")
        self.q[key] = float(r)

    def set_unknown(self, key: str, why: str) -> None:
        self.q.pop(key, None)
        self.unknown[key] = (key, why)

    # ---- move output --------------------------------------------------------------------------
    def add(self, r: list, tol: float | None = None) -> None:
        """Append move record ``r``; ``tol`` is its path tolerance (default: the one now in force)."""
        self.moved_at = self.executed
        self.n_moves += 1
        if self.n_moves > MAX_MOVES:
            raise _Stop(r[R_LINE], f"more than {MAX_MOVES:,} moves; the program is not interpreted further")
        self.b.add(
            r[R_KIND], r[R_LINE], tuple(r[R_START]), tuple(r[R_END]), feed=r[R_FEED], unit=self.unit,
            offset=r[R_OFF], center=tuple(r[R_CEN]), plane=r[R_PLANE], turns=r[R_TURNS], correctable=r[R_CORR],
            flags=r[R_FLAGS], wstart=tuple(r[R_WS]), wend=tuple(r[R_WE]), wdec=tuple(r[R_WD]),
            wstyle=tuple(r[R_WST]), winc=tuple(r[R_WI]), cstart=tuple(r[R_CS]), cend=tuple(r[R_CE]),
            cdec=tuple(r[R_CD]), cstyle=tuple(r[R_CST]), cinc=tuple(r[R_CI]), insert_at=r[R_INS],
            blend_tol=self.tol if tol is None else tol,
        )

    def emit(self, r: list, hold: bool = False) -> None:
        """Append a move (after the helper moves of a pending APPR / RND / CHF)."""
        pre: list[list] = []
        if self.appr is not None:
            pre = self.resolve_appr(r)
        if self.corner is not None:
            pre = self.resolve_corner(r)
        if self.pending is not None:
            self.add(self.pending, self.pending_tol)
            self.pending = None
        for p in pre:
            self.add(p)
        if hold:
            self.pending = r
            self.pending_tol = self.tol
        else:
            self.add(r)
        self.last = r
        self.pos = list(r[R_END])

    def check_frame(self, line: int) -> None:
        if self.frame:
            what, (dline, desc) = next(iter(self.frame.items()))
            _ = what
            raise _Stop(line, f"{desc} at line {dline} is active: positions in a transformed frame are not modelled")

    def comp_flags(self, rcomp: str | None) -> int:
        if rcomp is not None and rcomp not in ("RL", "RR", "R0"):
            return FLAG_CUTTER_COMP  # paraxial R+ / R-
        if rcomp is not None:
            self.rcomp = rcomp
        return FLAG_CUTTER_COMP if self.rcomp in ("RL", "RR") else 0

    def set_feed(self, f: Any, line: int) -> bool:
        """Apply a feed word; True for FMAX (rapid, this block only)."""
        if f is None:
            return False
        if f == "MAX":
            return True
        if f == "AUTO":
            self.feed = self.tool_feed
            return False
        if type(f) is tuple:
            value = self.feed_value(f[1], line)
            if f[0] == "U" and math.isfinite(self.spindle):
                self.feed = value * self.spindle
            else:
                self.warn("fz", f"line {line}: feed per {'revolution' if f[0] == 'U' else 'tooth'} (F{f[0]}) "
                                "is not converted to mm/min; feed unknown")
                self.feed = _NAN
            return False
        value = self.feed_value(f, line)
        if value < 0:
            raise _Stop(line, f"negative feed rate F{value / self.unit:g}")
        self.feed = value
        return False

    def feed_value(self, f: Any, line: int) -> float:
        if type(f) is float:
            return f * self.unit
        try:
            return self.num(f, line) * self.unit
        except _Stop as stop:
            self.warn("feedq", f"line {line}: feed unknown ({stop.problem})")
            return _NAN

    def target(self, mo: _Motion, line: int, machine: bool = False) -> tuple[list[float], bool]:
        pos = self.pos
        off = self.off
        unit = self.unit
        end = [pos[0], pos[1], pos[2]]
        param = False
        for ax, inc, v, _s, _e, _d, _st in mo.coords:
            if type(v) is not float:
                v = self.num(v, line)
                param = True
            if inc:
                end[ax] = pos[ax] + v * unit
            elif machine:
                end[ax] = v * unit
            else:
                end[ax] = v * unit + off[ax]
        return end, param

    def m_pre(self, ms: list[int], line: int) -> bool:
        machine = False
        for m in ms:
            if m in (91, 92):
                machine = True
                self.warn("m91", f"line {line}: M91/M92 positions are machine coordinates; recorded as written "
                                 "(moves flagged FLAG_MACHINE)")
            elif m == 128:
                self.frame["tcpm"] = (line, "M128 (tool centre point management)")
            elif m == 129:
                self.frame.pop("tcpm", None)
            elif m == 140:
                raise _Stop(line, "M140 retracts along the tool axis to a machine-dependent position")
            elif m == 104:
                raise _Stop(line, "M104 re-activates a datum that is not known")
        return machine

    def m_post(self, ms: list[int], line: int, moved: bool) -> bool:
        """Cycle calls and program end after the block; True when the program ends."""
        called = False
        for m in ms:
            if m == 99:
                self.cycle_call(line)
                self.m89 = False
                called = True
            elif m == 89:
                self.m89 = True
        if self.m89 and moved and not called:
            self.cycle_call(line)
        return any(m in (2, 30) for m in ms)

    # ---- straight lines -----------------------------------------------------------------------
    def h_l(self, blk: _Block, i: int) -> int | None:
        mo: _Motion = blk.data
        line = blk.line
        machine = self.m_pre(mo.ms, line) if mo.ms else False
        rapid = self.set_feed(mo.feed, line)
        flags = self.comp_flags(mo.rcomp)
        if mo.rotary:
            self.warn("rot", f"line {line}: rotary axis words (A, B, C, U, V, W) are read but not modelled")
        moved = False
        if mo.coords:
            self.check_frame(line)
            end, param = self.target(mo, line, machine)
            if param:
                flags |= FLAG_PARAMETRIC
            if machine:
                flags |= FLAG_MACHINE
            ws, we, wd, wst, wi = _spans(mo)
            kind = MOVE_RAPID if rapid else MOVE_LINE
            if not rapid:
                self.check_feed(line)
            # a block with a rotary or parallel axis word is never corrected (as in G-code): what it does with
            # that axis is not modelled
            corr = not (rapid or param or machine or mo.rotary)
            off = tuple(self.off) if not machine else tuple(0.0 if ws[a] >= 0 else self.off[a] for a in range(3))
            self.emit([kind, line, self.pos, end, _NAN if rapid else self.feed, off, _NAN3, self.plane,
                       1, corr, flags, ws, we, wd, wst, wi, _NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3, mo.insert_at],
                      blk.hold)
            moved = True
        if mo.ms and self.m_post(mo.ms, line, moved):
            return -1
        if self.m89 and moved and not mo.ms:
            self.cycle_call(line)
        return None

    def h_fastl(self, blk: _Block, i: int) -> int | None:
        blk.data = _fast_motion(blk.data, blk.pos, True)
        blk.kind = K_L
        return self.h_l(blk, i)

    def h_run(self, blk: _Block, i: int) -> int | None:
        """Execute a run of plain L blocks with numpy (falls back to one block when a state needs care)."""
        run: _Run = blk.data
        n = len(run.lines)
        self.executed += n - 1
        if self.executed > MAX_BLOCKS:
            raise _Stop(run.lines[0], f"loop does not terminate (more than {MAX_BLOCKS:,} blocks executed)")
        if self.appr is not None or self.corner is not None or self.m89 or self.frame:
            for b in run.blocks():
                self.h_l(b, i)
            return None
        c = run.columns(self.text_bytes())
        if c is None:
            for b in run.blocks():
                self.h_l(b, i)
            return None
        unit = self.unit
        has, inc, vals = c["has"], c["inc"], c["vals"] * unit
        ends = np.empty((n, 3))
        for a in range(3):
            absolute = has[:, a] & ~inc[:, a]
            csum = np.cumsum(np.where(has[:, a] & inc[:, a], vals[:, a], 0.0))
            idx = np.maximum.accumulate(np.where(absolute, np.arange(n), -1))
            safe = np.maximum(idx, 0)
            target = vals[safe, a] + self.off[a]
            ends[:, a] = np.where(idx >= 0, target + (csum - csum[safe]), self.pos[a] + csum)
        rapid = c["rapid"]
        fval = c["fval"] * unit
        feed = _ffill(fval, ~np.isnan(fval), self.feed)
        rcomp = _ffill(c["rcomp"], c["rcomp"] > 0, _RCOMP_CODE[self.rcomp])
        sel = has.any(axis=1)
        m = int(sel.sum())
        if self.pending is not None:
            self.add(self.pending, self.pending_tol)
            self.pending = None
        self.feed = float(feed[-1])
        self.rcomp = _RCOMP_NAME[int(rcomp[-1])]
        if m == 0:
            return None
        self.n_moves += m
        self.moved_at = self.executed
        if self.n_moves > MAX_MOVES:
            raise _Stop(run.lines[0], f"more than {MAX_MOVES:,} moves; the program is not interpreted further")
        starts = np.vstack((np.array(self.pos)[None, :], ends[:-1]))[sel]
        ends_sel = ends[sel]
        kind = np.where(rapid, MOVE_RAPID, MOVE_LINE)[sel].astype(np.int8)
        is_line = kind == MOVE_LINE
        self.b.add_table(MoveTable(
            kind=kind, line=c["line"][sel], start_mm=starts, end_mm=ends_sel, center_mm=np.full((m, 3), np.nan),
            offset_mm=np.tile(np.array(self.off), (m, 1)), plane=np.full(m, self.plane, dtype=np.int8),
            turns=np.ones(m, dtype=np.int16), feed_mm_min=np.where(rapid, np.nan, feed)[sel],
            unit_mm=np.full(m, unit), command=np.where(is_line, self.b.n_commands + np.cumsum(is_line) - 1, -1)
            .astype(np.int32), flags=np.where(rcomp >= 2, FLAG_CUTTER_COMP, 0)[sel].astype(np.int16),
            word_start=c["ws"][sel], word_end=c["we"][sel], word_decimals=c["dec"][sel],
            word_style=c["style"][sel], word_incremental=c["inc"][sel] & has[sel],
            center_start=np.full((m, 3), -1, dtype=np.int64), center_end=np.full((m, 3), -1, dtype=np.int64),
            center_decimals=np.zeros((m, 3), dtype=np.int8), center_style=np.zeros((m, 3), dtype=np.int8),
            center_incremental=np.zeros((m, 3), dtype=bool), insert_at=c["ins"][sel],
            blend_tol_mm=np.full(m, self.tol),
        ))
        self.pos = [float(x) for x in ends_sel[-1]]
        self.last = _rec(int(kind[-1]), int(c["line"][sel][-1]), [float(x) for x in starts[-1]], list(self.pos),
                         self.feed, self.off, self.plane, 0)
        return None

    def h_m(self, blk: _Block, i: int) -> int | None:
        mo: _Motion = blk.data
        self.m_pre(mo.ms, blk.line)
        self.set_feed(mo.feed, blk.line)
        if self.m_post(mo.ms, blk.line, False):
            return -1
        return None

    # ---- polar, circles -----------------------------------------------------------------------
    def need_pole(self, line: int, what: str) -> tuple[list[float], int]:
        if self.pole is None:
            raise _Stop(line, f"{what} without a circle centre / pole CC")
        return self.pole

    def polar_start(self, pole: list[float], plane: int) -> tuple[float, float]:
        i0, i1, _i2 = PLANE_AXES[plane]
        ra = self.pos[i0] - self.off[i0] - pole[i0]
        rb = self.pos[i1] - self.off[i1] - pole[i1]
        return math.hypot(ra, rb), math.degrees(math.atan2(rb, ra))

    def centre(self, pole: list[float], plane: int) -> list[float]:
        i0, i1, i2 = PLANE_AXES[plane]
        c = [0.0, 0.0, 0.0]
        c[i0] = pole[i0] + self.off[i0]
        c[i1] = pole[i1] + self.off[i1]
        c[i2] = self.pos[i2]
        return c

    def direction(self, mo: _Motion, line: int, what: str) -> int:
        if mo.dr:
            self.dr = mo.dr
        if not self.dr:
            raise _Stop(line, f"{what} without a direction of rotation DR+ / DR-")
        return self.dr

    def take_cc_spans(self) -> tuple:
        spans = self.cc_spans
        self.cc_spans = None
        if spans is None:
            return (_NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3)
        cs, ce, cd, cst, ci, at = spans
        if any(ci) and at != self.pos:
            return (_NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3)
        return cs, ce, cd, cst, ci

    def h_cc(self, blk: _Block, i: int) -> int | None:
        mo: _Motion = blk.data
        line = blk.line
        prog = [self.pos[a] - self.off[a] for a in range(3)]
        axes = set()
        cs, ce, cd, cst, ci = _spans(mo)
        for ax, inc, v, _s, _e, _d, _st in mo.coords:
            v = self.num(v, line) * self.unit
            prog[ax] = prog[ax] + v if inc else v
            axes.add(ax)
        plane = _PAIR_PLANE.get(frozenset(axes), self.plane) if len(axes) == 2 else self.plane
        if len(axes) > 2:
            raise _Stop(line, "CC with three coordinates: the plane of the circle is ambiguous")
        self.pole = (prog, plane)
        self.cc_spans = (cs, ce, cd, cst, ci, list(self.pos))
        return None

    def arc_rec(self, kind: int, line: int, end: list[float], centre: list[float], plane: int, flags: int,
                mo: _Motion, turns: int = 1, cc: tuple | None = None, insert: bool = True) -> list:
        ws, we, wd, wst, wi = _spans(mo)
        cs, ce, cd, cst, ci = cc if cc is not None else (_NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3)
        return [kind, line, self.pos, end, self.feed, tuple(self.off), centre, plane, turns, False, flags,
                ws, we, wd, wst, wi, cs, ce, cd, cst, ci, mo.insert_at if insert else -1]

    def motion_prologue(self, blk: _Block) -> tuple[_Motion, int, bool, int]:
        mo: _Motion = blk.data
        line = blk.line
        machine = self.m_pre(mo.ms, line) if mo.ms else False
        if machine:
            raise _Stop(line, "M91/M92 on a circle or polar move is not modelled")
        rapid = self.set_feed(mo.feed, line)
        if not rapid:
            self.check_feed(line)
        flags = self.comp_flags(mo.rcomp)
        if mo.rotary:
            self.warn("rot", f"line {line}: rotary axis words (A, B, C, U, V, W) are read but not modelled")
        self.check_frame(line)
        return mo, line, rapid, flags

    def check_feed(self, line: int) -> None:
        """A feed move needs a positive feed (the G-code reader refuses the same)."""
        if self.feed == 0.0:
            raise _Stop(line, "feed move with zero feed rate (F0)")

    def epilogue(self, mo: _Motion, line: int) -> int | None:
        if mo.ms and self.m_post(mo.ms, line, True):
            return -1
        if self.m89 and not mo.ms:
            self.cycle_call(line)
        return None

    def h_c(self, blk: _Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        dr = self.direction(mo, line, "C")
        pole, plane = self.need_pole(line, "C")
        end, param = self.target(mo, line)
        if param:
            flags |= FLAG_PARAMETRIC
        kind = MOVE_ARC_CCW if dr > 0 else MOVE_ARC_CW
        centre = self.centre(pole, plane)
        self.check_radius(self.pos, end, centre, plane, line)
        r = self.arc_rec(kind, line, end, centre, plane, flags, mo, cc=self.take_cc_spans())
        if rapid:
            r[R_FEED] = _NAN
        self.emit(r, blk.hold)
        return self.epilogue(mo, line)

    def check_radius(self, start: list[float], end: list[float], centre: list[float], plane: int, line: int) -> None:
        """Refuse a C whose centre is its start, or whose end point is off the circle through its start by more
        than the G-code reader allows an arc (LinuxCNC's limits: 0.028 mm and 0.1 % of the radius); warn from
        ``ARC_TOLERANCE_MM`` on (the TNC may reject it)."""
        i0, i1, _i2 = PLANE_AXES[plane]
        r0 = math.hypot(start[i0] - centre[i0], start[i1] - centre[i1])
        r1 = math.hypot(end[i0] - centre[i0], end[i1] - centre[i1])
        if r0 < 1e-9:
            raise _Stop(line, "circle with zero radius (the centre CC is the start point)")
        off = abs(r1 - r0)
        if arc_off_circle(r0, r1):  # the mm limit, as before for MM and INCH programs alike
            raise _Stop(line, f"the end point of C is {off:.4f} mm off the circle (radius {r0:.4f} mm at the start,"
                              f" {r1:.4f} mm at the end)")
        if off > ARC_TOLERANCE_MM:
            self.warnings.append(f"line {line}: the end point of C is {off:.4f} mm off the circle "
                                 f"(radius {r0:.4f} mm at the start, {r1:.4f} mm at the end)")

    def h_cr(self, blk: _Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        dr = self.direction(mo, line, "CR")
        plane = self.plane
        i0, i1, i2 = PLANE_AXES[plane]
        radius = self.num(mo.radius, line) * self.unit
        end, param = self.target(mo, line)
        if param:
            flags |= FLAG_PARAMETRIC
        start = self.pos
        if abs(end[i2] - start[i2]) > _EPS:
            raise _Stop(line, "CR with a tool-axis move (helix) is not modelled")
        da, db = end[i0] - start[i0], end[i1] - start[i1]
        chord = math.hypot(da, db)
        if chord < 1e-9 or radius == 0:
            raise _Stop(line, "CR with identical start and end point or zero radius: the circle is not defined")
        h2 = radius * radius - chord * chord / 4
        if h2 < 0:
            if -h2 > (1e-6 + 1e-6 * abs(radius)) * abs(radius):
                raise _Stop(line, f"CR radius {abs(radius):g} mm is smaller than half the chord ({chord / 2:g} mm)")
            h2 = 0.0
        h = math.sqrt(h2)
        side = 1.0 if (dr > 0) == (radius > 0) else -1.0
        c = [0.0, 0.0, 0.0]
        c[i0] = start[i0] + da / 2 - side * h * db / chord
        c[i1] = start[i1] + db / 2 + side * h * da / chord
        c[i2] = start[i2]
        kind = MOVE_ARC_CCW if dr > 0 else MOVE_ARC_CW
        r = self.arc_rec(kind, line, end, c, plane, flags, mo)
        if rapid:
            r[R_FEED] = _NAN
        self.emit(r, blk.hold)
        return self.epilogue(mo, line)

    def end_tangent(self, r: list | None, line: int, what: str) -> tuple[float, float]:
        """Unit tangent of a move at its end, in the working plane."""
        if r is None:
            raise _Stop(line, f"{what} needs a preceding contour element")
        return self._tangent(r, R_END, line, what, "after", "preceding")

    def start_tangent(self, r: list, line: int, what: str) -> tuple[float, float]:
        """Unit tangent of a move at its start, in the working plane."""
        return self._tangent(r, R_START, line, what, "before", "following")

    def _tangent(self, r: list, at: int, line: int, what: str, rel: str, which: str) -> tuple[float, float]:
        i0, i1, _i2 = PLANE_AXES[self.plane]
        if r[R_KIND] >= MOVE_ARC_CW:
            if r[R_PLANE] != self.plane:
                raise _Stop(line, f"{what} {rel} an arc outside the working plane is not modelled")
            ra = r[at][i0] - r[R_CEN][i0]
            rb = r[at][i1] - r[R_CEN][i1]
            ta, tb = (-rb, ra) if r[R_KIND] == MOVE_ARC_CCW else (rb, -ra)
        else:
            ta = r[R_END][i0] - r[R_START][i0]
            tb = r[R_END][i1] - r[R_START][i1]
        n = math.hypot(ta, tb)
        if n < 1e-9:
            raise _Stop(line, f"{what}: the {which} element has no direction in the working plane")
        return ta / n, tb / n

    def h_ct(self, blk: _Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        plane = self.plane
        i0, i1, i2 = PLANE_AXES[plane]
        if self.corner is not None:
            raise _Stop(line, "CT after RND/CHF is not modelled")
        ta, tb = self.end_tangent(self.last, line, "CT")
        end, param = self.target(mo, line)
        if param:
            flags |= FLAG_PARAMETRIC
        start = self.pos
        if abs(end[i2] - start[i2]) > _EPS:
            raise _Stop(line, "CT with a tool-axis move (helix) is not modelled")
        da, db = end[i0] - start[i0], end[i1] - start[i1]
        denom = 2 * (-tb * da + ta * db)
        d2 = da * da + db * db
        if abs(denom) <= 1e-9 * math.sqrt(d2) or d2 < 1e-18:
            raise _Stop(line, "CT end point lies on the tangent: no tangential arc")
        s = d2 / denom
        c = [0.0, 0.0, 0.0]
        c[i0] = start[i0] - s * tb
        c[i1] = start[i1] + s * ta
        c[i2] = start[i2]
        kind = MOVE_ARC_CCW if s > 0 else MOVE_ARC_CW
        r = self.arc_rec(kind, line, end, c, plane, flags, mo)
        if rapid:
            r[R_FEED] = _NAN
        self.emit(r, blk.hold)
        return self.epilogue(mo, line)

    def polar_values(self, mo: _Motion, line: int, r0: float, a0: float) -> tuple[float | None, float | None, bool]:
        """(radius, angle or sweep, angle incremental) of the polar words; None when absent."""
        r = a = None
        inc_a = False
        if "PR" in mo.polar:
            v, inc = mo.polar["PR"]
            v = self.num(v, line) * self.unit
            r = r0 + v if inc else v
        if "PA" in mo.polar:
            v, inc_a = mo.polar["PA"]
            a = self.num(v, line)
        return r, a, inc_a

    def polar_param(self, mo: _Motion) -> bool:
        return any(type(v) is not float for v, _inc in mo.polar.values())

    def h_lp(self, blk: _Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        pole, plane = self.need_pole(line, "LP")
        i0, i1, i2 = PLANE_AXES[plane]
        if any(ax != i2 for ax, *_rest in mo.coords):
            raise _Stop(line, "LP with a coordinate in the plane of the pole")
        r0, a0 = self.polar_start(pole, plane)
        r, a, inc_a = self.polar_values(mo, line, r0, a0)
        r = r0 if r is None else r
        a = a0 if a is None else (a0 + a if inc_a else a)
        end, param = self.target(mo, line)
        end[i0] = pole[i0] + self.off[i0] + r * math.cos(math.radians(a))
        end[i1] = pole[i1] + self.off[i1] + r * math.sin(math.radians(a))
        flags |= FLAG_POLAR
        if param or self.polar_param(mo):
            flags |= FLAG_PARAMETRIC
        ws, we, wd, wst, wi = _spans(mo)
        kind = MOVE_RAPID if rapid else MOVE_LINE
        self.emit([kind, line, self.pos, end, _NAN if rapid else self.feed, tuple(self.off), _NAN3, self.plane, 1,
                   False, flags, ws, we, wd, wst, wi, _NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3, -1], blk.hold)
        return self.epilogue(mo, line)

    def h_cp(self, blk: _Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        dr = self.direction(mo, line, "CP")
        pole, plane = self.need_pole(line, "CP")
        i0, i1, i2 = PLANE_AXES[plane]
        if any(ax != i2 for ax, *_rest in mo.coords):
            raise _Stop(line, "CP with a coordinate in the plane of the pole")
        r0, a0 = self.polar_start(pole, plane)
        if r0 < 1e-9:
            raise _Stop(line, "CP starts at the pole: the circle is not defined")
        r, a, inc_a = self.polar_values(mo, line, r0, a0)
        if r is not None and abs(r - r0) > 1e-3:
            raise _Stop(line, f"CP radius {r:g} differs from the distance to the pole {r0:g}: not a circle")
        if a is None:
            raise _Stop(line, "CP without an angle PA / IPA")
        sweep = self.cp_sweep(a, inc_a, a0, dr, line)
        n = abs(sweep) / 360.0
        full = abs(n - round(n)) < 1e-9 and round(n) >= 1
        turns = round(n) if full else math.floor(n) + 1
        end, param = self.target(mo, line)
        if full:
            end[i0], end[i1] = self.pos[i0], self.pos[i1]
        else:
            ang = math.radians(a0 + sweep)
            end[i0] = pole[i0] + self.off[i0] + r0 * math.cos(ang)
            end[i1] = pole[i1] + self.off[i1] + r0 * math.sin(ang)
        flags |= FLAG_POLAR
        if param or self.polar_param(mo):
            flags |= FLAG_PARAMETRIC
        kind = MOVE_ARC_CCW if sweep > 0 else MOVE_ARC_CW
        rec = self.arc_rec(kind, line, end, self.centre(pole, plane), plane, flags, mo, turns=turns,
                           cc=self.take_cc_spans(), insert=False)
        if rapid:
            rec[R_FEED] = _NAN
        self.emit(rec, blk.hold)
        return self.epilogue(mo, line)

    def cp_sweep(self, a: float, inc: bool, a0: float, dr: int, line: int) -> float:
        if inc:
            if a == 0:
                raise _Stop(line, "CP with IPA+0: no circle")
            if (a > 0) != (dr > 0):
                raise _Stop(line, "CP: the sign of IPA contradicts DR")
            return a
        delta = (a - a0) % 360.0
        if dr > 0:
            return delta if delta > 1e-9 else 360.0
        back = (a0 - a) % 360.0
        return -(back if back > 1e-9 else 360.0)

    # ---- rounding, chamfer, approach, departure --------------------------------------------------
    def h_corner(self, blk: _Block, i: int) -> int | None:
        mo: _Motion = blk.data
        line = blk.line
        what = "RND" if blk.kind == K_RND else "CHF"
        if self.pending is None or self.corner is not None:
            raise _Stop(line, f"{what} must follow a contour element")
        value = self.num(mo.radius, line) * self.unit
        if value <= 0:
            raise _Stop(line, f"{what} with a non-positive size {value:g}")
        feed = self.feed if mo.feed is None else self.feed_value(mo.feed, line)
        self.corner = (what, value, feed, line)
        return None

    def resolve_corner(self, nxt: list) -> list[list]:
        what, value, feed, line = self.corner  # type: ignore[misc]
        self.corner = None
        prev = self.pending
        if prev is None:
            raise _Stop(line, f"{what} must follow a contour element")
        if prev[R_KIND] >= MOVE_ARC_CW or nxt[R_KIND] >= MOVE_ARC_CW:
            raise _Stop(line, f"{what} next to a circular arc is not modelled")
        i0, i1, i2 = PLANE_AXES[self.plane]
        a, p, b = prev[R_START], prev[R_END], nxt[R_END]
        if abs(a[i2] - p[i2]) > _EPS or abs(b[i2] - p[i2]) > _EPS:
            raise _Stop(line, f"{what} between lines that move the tool axis is not modelled")
        ua, ub = p[i0] - a[i0], p[i1] - a[i1]
        va, vb = b[i0] - p[i0], b[i1] - p[i1]
        lu, lv = math.hypot(ua, ub), math.hypot(va, vb)
        if lu < 1e-9 or lv < 1e-9:
            raise _Stop(line, f"{what} next to a line of zero length")
        ua, ub, va, vb = ua / lu, ub / lu, va / lv, vb / lv
        cross = ua * vb - ub * va
        if abs(cross) < 1e-9:
            raise _Stop(line, f"{what} between collinear lines")
        if what == "RND":
            d = value * math.tan(math.atan2(abs(cross), ua * va + ub * vb) / 2)
        else:
            d = value
        if d > lu + 1e-9 or d > lv + 1e-9:
            raise _Stop(line, f"{what} {value:g} does not fit between the lines")
        t1 = list(p)
        t2 = list(p)
        t1[i0], t1[i1] = p[i0] - d * ua, p[i1] - d * ub
        t2[i0], t2[i1] = p[i0] + d * va, p[i1] + d * vb
        prev[R_END] = t1
        prev[R_CORR] = False
        nxt[R_START] = t2
        flags = FLAG_DERIVED | (prev[R_FLAGS] & FLAG_CUTTER_COMP)
        r = _rec(MOVE_LINE, line, t1, t2, feed, list(prev[R_OFF]), self.plane, flags)
        if what == "RND":
            sign = 1.0 if cross > 0 else -1.0
            c = list(t1)
            c[i0], c[i1] = t1[i0] - sign * value * ub, t1[i1] + sign * value * ua
            r[R_KIND] = MOVE_ARC_CCW if cross > 0 else MOVE_ARC_CW
            r[R_CEN] = c
        return [r]

    def len_value(self, mo: _Motion, line: int, what: str) -> float:
        if "LEN" not in mo.extra:
            raise _Stop(line, f"{what} without LEN")
        v = self.num(mo.extra["LEN"], line) * self.unit
        if v <= 0:
            raise _Stop(line, f"{what} with LEN {v:g}: must be positive")
        return v

    def h_appr(self, blk: _Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        what = f"APPR {mo.sub}"
        if mo.sub not in ("LT", "LN"):
            raise _Stop(line, f"{what} is not modelled")
        _i0, _i1, i2 = PLANE_AXES[self.plane]
        if mo.polar or "CCA" in mo.extra or mo.radius is not None:
            raise _Stop(line, f"{what} with polar words, CCA or R is not valid here")
        if any(ax == i2 for ax, *_rest in mo.coords):
            raise _Stop(line, f"{what} with a tool-axis coordinate (3-D approach) is not modelled")
        if self.corner is not None or self.appr is not None:
            raise _Stop(line, f"{what} directly after RND/CHF/APPR")
        length = self.len_value(mo, line, what)
        if self.rcomp not in ("RL", "RR") and mo.sub == "LN":
            raise _Stop(line, f"{what} needs radius compensation RL or RR")
        end, param = self.target(mo, line)
        if param:
            flags |= FLAG_PARAMETRIC
        feed = _NAN if rapid else self.feed
        self.appr = (line, mo.sub, list(self.pos), end, length, self.rcomp, feed, flags)
        self.pos = end
        if mo.ms and self.m_post(mo.ms, line, False):
            return -1
        return None

    def resolve_appr(self, nxt: list) -> list[list]:
        line, sub, ps, pa, length, rcomp, feed, flags = self.appr  # type: ignore[misc]
        self.appr = None
        i0, i1, _i2 = PLANE_AXES[self.plane]
        ta, tb = self.start_tangent(nxt, line, f"APPR {sub}")
        ph = list(pa)
        if sub == "LT":
            ph[i0], ph[i1] = pa[i0] - length * ta, pa[i1] - length * tb
        else:
            na, nb = (tb, -ta) if rcomp == "RR" else (-tb, ta)
            ph[i0], ph[i1] = pa[i0] + length * na, pa[i1] + length * nb
        flags |= FLAG_DERIVED
        kind = MOVE_RAPID if feed != feed else MOVE_LINE
        return [_rec(kind, line, ps, ph, feed, self.off, self.plane, flags),
                _rec(MOVE_LINE, line, ph, list(pa), self.feed, self.off, self.plane, flags)]

    def h_dep(self, blk: _Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        what = f"DEP {mo.sub}"
        if mo.sub not in ("LT", "LN"):
            raise _Stop(line, f"{what} is not modelled")
        if mo.coords or mo.polar or "CCA" in mo.extra or mo.radius is not None:
            raise _Stop(line, f"{what} with coordinates, CCA or R is not modelled")
        if self.corner is not None or self.appr is not None:
            raise _Stop(line, f"{what} directly after RND/CHF/APPR")
        length = self.len_value(mo, line, what)
        i0, i1, _i2 = PLANE_AXES[self.plane]
        ta, tb = self.end_tangent(self.last, line, what)
        comp = self.rcomp
        end = list(self.pos)
        if mo.sub == "LT":
            end[i0], end[i1] = end[i0] + length * ta, end[i1] + length * tb
        else:
            if comp not in ("RL", "RR"):
                raise _Stop(line, f"{what} needs radius compensation RL or RR")
            na, nb = (tb, -ta) if comp == "RR" else (-tb, ta)
            end[i0], end[i1] = end[i0] + length * na, end[i1] + length * nb
        flags |= FLAG_DERIVED | (FLAG_CUTTER_COMP if comp in ("RL", "RR") else 0)
        kind = MOVE_RAPID if rapid else MOVE_LINE
        self.emit(_rec(kind, line, self.pos, end, _NAN if rapid else self.feed, self.off, self.plane, flags))
        self.rcomp = "R0"
        if mo.ms and self.m_post(mo.ms, line, True):
            return -1
        return None

    # ---- program flow ---------------------------------------------------------------------------
    def h_nothing(self, blk: _Block, i: int) -> int | None:
        return None

    def h_end(self, blk: _Block, i: int) -> int | None:
        return -1

    def h_assign(self, blk: _Block, i: int) -> int | None:
        key, f = blk.data
        self.assign(key, f, blk.line)
        return None

    def h_sysread(self, blk: _Block, i: int) -> int | None:
        self.set_unknown(blk.data, f"is read from the control by FN 18 SYSREAD at line {blk.line}")
        return None

    def h_qs(self, blk: _Block, i: int) -> int | None:
        self.warn("qs", f"line {blk.line}: string parameters (QS) are ignored")
        return None

    def h_fn_error(self, blk: _Block, i: int) -> int | None:
        raise _Stop(blk.line, f"FN 14 raises error {blk.data}: the control stops the program here")

    def h_fn_other(self, blk: _Block, i: int) -> int | None:
        num, _text = blk.data
        if num in (15, 16, 19, 20, 26, 27, 29, 37, 38):
            self.warn(f"fn{num}", f"line {blk.line}: FN {num} has no effect on the motion and is ignored")
            return None
        if num == 17:
            raise _Stop(blk.line, "FN 17 SYSWRITE changes control data that is not modelled")
        if num == 28:
            raise _Stop(blk.line, "FN 28 TABREAD reads Q parameters from a table; the values are not known")
        raise _Stop(blk.line, f"FN {num} is not modelled")

    def label_index(self, key: Any, line: int) -> int:
        if isinstance(key, tuple):
            if key[1].startswith("QS"):
                raise _Stop(line, f"jump to a label named by the string parameter {key[1]} is not modelled")
            v = self.num(_qget(key[1], False), line)
            if v != int(v):
                raise _Stop(line, f"label number {key[1]} = {v:g} is not a whole number")
            key = int(v)
        idx = self.labels.get(key)
        if idx is None:
            name = f'"{key}"' if isinstance(key, str) else str(key)
            raise _Stop(line, f"label {name} is not defined in this program")
        return idx

    def h_jump(self, blk: _Block, i: int) -> int | None:
        cmp, fa, fb, key = blk.data
        a = self.num(fa, blk.line)
        b = self.num(fb, blk.line)
        if (cmp == "EQU" and a == b) or (cmp == "NE" and a != b) or (cmp == "GT" and a > b) or (cmp == "LT" and a < b):
            return self.label_index(key, blk.line)
        return None

    def h_lbl(self, blk: _Block, i: int) -> int | None:
        if blk.data != 0 or not self.stack:
            return None
        frame = self.stack[-1]
        if frame[1] > 0:
            frame[1] -= 1
            return frame[2]
        self.stack.pop()
        return frame[0] + 1

    def h_call_lbl(self, blk: _Block, i: int) -> int | None:
        key, rep = blk.data
        line = blk.line
        st = self.stack
        for depth in range(len(st) - 1, -1, -1):
            if st[depth][0] == i:
                del st[depth + 1:]
                frame = st[depth]
                if frame[1] > 0:
                    frame[1] -= 1
                    return frame[2]
                st.pop()
                return None
        if not isinstance(rep, int):
            v = self.num(rep, line)
            if v != int(v) or v < 0:
                raise _Stop(line, f"REP count {v:g} is not a whole number >= 0")
            rep = int(v)
        if len(st) >= MAX_CALL_DEPTH:
            raise _Stop(line, f"label calls nested deeper than {MAX_CALL_DEPTH}")
        target = self.label_index(key, line)
        st.append([i, max(rep - 1, 0), target])
        return target

    def h_call_pgm(self, blk: _Block, i: int) -> int | None:
        raise _Stop(blk.line, f"CALL PGM {blk.data}: the called program is not read")

    # ---- cycles ----------------------------------------------------------------------------------
    def h_cycl_def(self, blk: _Block, i: int) -> int | None:
        num, sub, data = blk.data
        line = blk.line
        if sub is None or sub == 0:
            name = _cycle_name(data) if isinstance(data, str) else ""
            if num == 247:
                self.frame["datum"] = (line, "datum setting from the preset table (cycle 247)")
            elif num == 26:
                self.frame["scaling"] = (line, "axis-specific scaling (cycle 26)")
            elif num not in _DEF_ACTIVE:
                self.cycle = (num, name, line)
            return None
        if num == 7:
            self.datum_shift(data, line)
        elif num == 32 and sub == 1:
            # tolerance for the following moves; 32.1 without T resets it to the machine's
            self.tol = BLEND_PROFILE if data is None else max(self.num(data, line), 0.0) * self.unit
        elif num == 8:
            if data:
                self.frame["mirror"] = (line, "mirror image (cycle 8)")
            else:
                self.frame.pop("mirror", None)
        elif num == 10:
            for name, v in data:
                a = self.num(v, line)
                self.rot = self.rot + a if name.startswith("I") else a
            if abs(self.rot % 360.0) > 1e-12 and abs(self.rot % 360.0 - 360.0) > 1e-12:
                self.frame["rotation"] = (line, f"coordinate rotation by {self.rot:g} degrees (cycle 10)")
            else:
                self.frame.pop("rotation", None)
        elif num == 11:
            for _name, v in data:
                if abs(self.num(v, line) - 1.0) > 1e-12:
                    self.frame["scaling"] = (line, "scaling (cycle 11)")
                else:
                    self.frame.pop("scaling", None)
        elif num == 19 and sub == 1:
            angles = [self.num(v, line) for name, v in data if name in ("A", "B", "C")]
            if any(abs(a) > 1e-12 for a in angles):
                self.frame["tilt"] = (line, "tilted working plane (cycle 19)")
            else:
                self.frame.pop("tilt", None)
        return None

    def datum_shift(self, data: Any, line: int) -> None:
        if isinstance(data, tuple):
            self.frame["datum"] = (line, "datum shift from a datum table (cycle 7 #)")
            return
        for name, v in data:
            axis = name[-1]
            if axis not in _AXIS_INDEX:
                self.warn("rotshift", f"line {line}: datum shift of a rotary axis is not modelled")
                continue
            ax = _AXIS_INDEX[axis]
            value = self.num(v, line) * self.unit
            self.off[ax] = self.off[ax] + value if name[0] == "I" else value

    def h_cycl_call(self, blk: _Block, i: int) -> int | None:
        mo: _Motion = blk.data
        line = blk.line
        if mo.sub == "PAT":
            raise _Stop(line, "CYCL CALL PAT (point pattern) is not modelled")
        if mo.sub == "POS" and mo.coords:
            rapid = self.set_feed(mo.feed, line)
            self.check_frame(line)
            end, param = self.target(mo, line)
            flags = self.comp_flags(mo.rcomp) | (FLAG_PARAMETRIC if param else 0)
            kind = MOVE_RAPID if rapid else MOVE_LINE
            ws, we, wd, wst, wi = _spans(mo)
            self.emit([kind, line, self.pos, end, _NAN if rapid else self.feed, tuple(self.off), _NAN3, self.plane,
                       1, False, flags, ws, we, wd, wst, wi, _NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3, -1])
        self.m_pre(mo.ms, line)
        self.cycle_call(line)
        if any(m in (2, 30) for m in mo.ms):
            return -1
        return None

    def cycle_call(self, line: int) -> None:
        self.check_frame(line)
        if self.corner is not None or self.appr is not None:
            raise _Stop(line, "cycle call between RND/CHF/APPR and its contour element")
        if self.cycle is None:
            raise _Stop(line, "cycle call without a cycle definition")
        num, name, dline = self.cycle
        if num not in _RETURNING_CYCLES:
            label = f"cycle {num} {name}".strip()
            raise _Stop(line, f"{label} (defined at line {dline}) moves the tool; its motion is not modelled")
        self.cycle_calls.setdefault(dline, [num, name, []])[2].append(line)
        # the move that brought the tool to the cycle's position is the cycle's, not a contour's: never corrected
        self.b.uncommand_last()

    def cycle_warnings(self) -> None:
        for dline, (num, name, lines) in self.cycle_calls.items():
            where = ", ".join(str(x) for x in lines[:6]) + (", ..." if len(lines) > 6 else "")
            self.warnings.append(
                f"line {lines[0]}: cycle {num} {name} (defined at line {dline}) called {len(lines)} time(s) "
                f"(lines {where}): its internal motion is not modelled; the tool returns to its start position")

    # ---- tools, frames, others ---------------------------------------------------------------------
    def h_tool_call(self, blk: _Block, i: int) -> int | None:
        d = blk.data
        line = blk.line
        axis = d.get("axis")
        if axis is not None:
            if axis not in _AXIS_INDEX:
                raise _Stop(line, f"tool axis {axis} (parallel axis) is not modelled")
            self.plane = _TOOL_AXIS_PLANE[_AXIS_INDEX[axis]]
        if "F" in d:
            self.tool_feed = self.feed_value(d["F"], line)
        if "S" in d:
            try:
                self.spindle = self.num(d["S"], line)
            except _Stop:
                self.spindle = _NAN
        tool = d.get("tool")
        if tool is not None:
            try:
                self.tool = self.num(tool, line)
            except _Stop:
                self.tool = None
        self.tool_radius(d, line)
        return None

    def tool_radius(self, d: dict[str, Any], line: int) -> None:
        base = self.tools.get(self.tool) if self.tool is not None else None
        if base is None:
            self.set_unknown("Q108", f"is the radius of the tool in the tool table (TOOL CALL at line {line})")
            return
        delta = 0.0
        if "DR" in d:
            try:
                delta = self.num(d["DR"], line) * self.unit
            except _Stop:
                self.set_unknown("Q108", f"depends on an unknown DR in TOOL CALL at line {line}")
                return
        self.q["Q108"] = (base + delta) / self.unit

    def h_tool_def(self, blk: _Block, i: int) -> int | None:
        d = blk.data
        try:
            tool = self.num(d["tool"], blk.line) if d.get("tool") is not None else None
            if tool is not None and "R" in d:
                self.tools[tool] = self.num(d["R"], blk.line) * self.unit
        except _Stop:
            pass
        return None

    def h_plane(self, blk: _Block, i: int) -> int | None:
        tokens: list[str] = blk.data
        line = blk.line
        if tokens and tokens[0] == "RESET":
            self.frame.pop("tilt", None)
            return None
        kind = tokens[0] if tokens else ""
        angles = []
        for t in tokens[1:]:
            m = re.fullmatch(r"(SPA|SPB|SPC|PROPR|PROMIN|PROROT|EULPR|EULNU|EULROT|ROT|[ABC])([+-]?[\d.,]+)", t)
            if m:
                angles.append(float(m.group(2).replace(",", ".")))
        if kind in ("SPATIAL", "PROJECTED", "EULER", "RELATIV", "AXIAL") and angles and not any(angles):
            if kind != "RELATIV":
                self.frame.pop("tilt", None)
            return None
        self.frame["tilt"] = (line, f"tilted working plane (PLANE {kind})")
        return None

    def h_loose(self, blk: _Block, i: int) -> int | None:
        name, tokens = blk.data
        line = blk.line
        head = name.split()[0]
        if name in _LOOSE_STOP or head in _LOOSE_STOP:
            raise _Stop(line, _LOOSE_STOP.get(name) or _LOOSE_STOP[head])
        if head in ("DECLARE", "PATTERN", "CONTOUR"):
            return None
        if head == "SEL":
            self.warn(name, f"line {line}: {name} is ignored")
            return None
        if head == "FUNCTION":
            if "TCPM" in tokens:
                if "RESET" in tokens or "OFF" in tokens:
                    self.frame.pop("tcpm", None)
                else:
                    self.frame["tcpm"] = (line, "FUNCTION TCPM (tool centre point management)")
                return None
            if tokens and tokens[0] in ("DWELL", "FEED"):
                return None
            raise _Stop(line, f"FUNCTION {' '.join(tokens[:2])} is not modelled")
        if name == "TRANS DATUM":
            if tokens and tokens[0] == "RESET":
                self.off = [0.0, 0.0, 0.0]
                return None
            raise _Stop(line, "TRANS DATUM with values is not modelled")
        raise _Stop(line, f"{name} is not modelled")


# --------------------------------------------------------------------------------------------
# public API: reader
# --------------------------------------------------------------------------------------------
def _first_bad_line(data: bytes) -> int:
    """Line of the first NUL or stray control byte (for binary input)."""
    for k, b in enumerate(data[:65536]):
        if b == 0 or (b < 32 and b not in (9, 10, 12, 13, 26)):
            return data.count(b"\n", 0, k) + 1
    return 1


def read_heidenhain(path: Path, data: bytes) -> Program:
    """Read a Heidenhain Klartext program.

    Parameters
    ----------
    path : Path
        The file (used in messages and stored in the program).
    data : bytes
        The file content.

    Returns
    -------
    Program
        ``dialect="heidenhain"``; the text decoded as latin-1 (byte for byte);
        the moves in execution order with the correctable ``L`` commands;
        ``unsupported`` set when the interpretation stopped at a construct that
        is not modelled (the lexical layer is complete in any case).

    Raises
    ------
    ProgramError
        A syntax error, binary data or an empty file (one line: file, line,
        problem).
    """
    path = Path(path)
    if looks_binary(data):
        raise ProgramError(path, _first_bad_line(data), "binary data, not a Klartext program")
    text = decode_source(data)
    if not text.strip():
        raise ProgramError(path, 1, "empty program (no BEGIN PGM)")
    lex = _Lexer(path, text)
    lex.run()
    assert lex.begin is not None
    name, unit_word, _line = lex.begin
    unit = MM_PER_INCH if unit_word == "INCH" else 1.0
    interp = _Interp(lex, unit)
    interp.run()
    moves = _finish_table(interp, lex)
    warnings = list(lex.warnings)
    if lex.cycle_misspelled is not None:
        warnings.append(f"line {lex.cycle_misspelled}: 'CYCLE DEF' (misspelled by the post-processor) read as CYCL DEF")
    if lex.skipped_lines:
        warnings.append(f"line {lex.skipped_lines[0]}: blocks marked '/' ({len(lex.skipped_lines)}) are read as "
                        "executed (block skip off)")
    warnings.extend(interp.warnings)
    unmodelled = None
    if interp.cycle_calls:  # the first cycle called (its first call's line)
        dline, (num, cname, lines) = next(iter(interp.cycle_calls.items()))
        unmodelled = (lines[0], f"cycle {num} {cname} (defined at line {dline}) moves the tool at its {len(lines)}"
                                f" call(s); that motion is not modelled, so a run of the program is neither simulated"
                                " nor learned (the contour around it would be judged without it)")
    return Program(
        path=path, text=text, dialect="heidenhain", units="inch" if unit_word == "INCH" else "mm", moves=moves,
        name=name, warnings=warnings, unsupported=interp.unsupported, unmodelled=unmodelled,
    )


def _finish_table(interp: _Interp, lex: _Lexer) -> MoveTable:
    """Freeze the moves; drop the commands that are not executed exactly once or cannot be rewritten."""
    mt = interp.b.build()
    m = len(mt)
    if m == 0:
        return mt
    last_line = lex.last_line
    counts = np.zeros(last_line + 2, dtype=np.int64)
    for blk, c in zip(lex.blocks, interp.counts, strict=True):
        if blk.kind == K_RUN:
            counts[blk.data.lines] = c
        else:
            counts[blk.line] = c
    repeated = counts[mt.line] > 1
    mt.flags[repeated] |= FLAG_REPEATED
    cmd = (mt.command >= 0) & ~repeated
    if interp.unsupported is not None:
        first = _first_target_line(lex)
        if first is not None:
            cmd &= mt.line < first
    # the next move must absorb a changed start; a move after a helper move (APPR, RND, CHF) shapes it
    blocking = (mt.flags & (FLAG_DERIVED | FLAG_POLAR | FLAG_PARAMETRIC | FLAG_REPEATED)) != 0
    cmd[:-1] &= ~blocking[1:]
    cmd[1:] &= (mt.flags[:-1] & FLAG_DERIVED) == 0
    command = np.full(m, -1, dtype=np.int32)
    command[cmd] = np.arange(int(cmd.sum()), dtype=np.int32)
    mt.command = command
    return mt


def _first_target_line(lex: _Lexer) -> int | None:
    """Line of the first label a jump or call can reach (text after it may run again)."""
    best = None
    for key, idx in lex.labels.items():
        if lex.dynamic_targets or key in lex.targets:
            line = lex.blocks[idx].line
            best = line if best is None else min(best, line)
    return best


# --------------------------------------------------------------------------------------------
# public API: writer
# --------------------------------------------------------------------------------------------
_AXIS_LETTERS = "XYZ"


class _Writer:
    """Turns a move table into numbered Klartext blocks."""

    def __init__(self, scale: float, decimals: int) -> None:
        self.scale = scale
        self.decimals = decimals
        self.blocks: list[str] = []
        self.last: list[str | None] = [None, None, None]
        self.feed: str | None = None
        self.offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def num(self, value: float) -> str:
        s = f"{value / self.scale:+.{self.decimals}f}"
        if float(s) == 0.0:
            s = "+" + s[1:]
        return s

    def feed_word(self, feed: float) -> str:
        if not math.isfinite(feed):
            return ""
        f = feed / self.scale
        text = f"{f:.3f}".rstrip("0").rstrip(".")
        if text == self.feed:
            return ""
        self.feed = text
        return " F" + text

    def datum(self, off: tuple[float, float, float]) -> None:
        if off == self.offset:
            return
        self.offset = off
        self.blocks.append("CYCL DEF 7.0 DATUM SHIFT")
        for a in range(3):
            self.blocks.append(f"CYCL DEF 7.{a + 1} {_AXIS_LETTERS[a]}{self.num(off[a])}")
        self.last = [None, None, None]

    def axes(self, p: np.ndarray, force: tuple[int, ...] = (), named: list[int] | None = None) -> str:
        """Words of the axes whose written value changes (of ``named`` alone, when given: the axes the source
        named or the move changes, so an axis the source never positioned is not invented) and of ``force``."""
        words = []
        for a in range(3):
            txt = self.num(float(p[a]))
            write = txt != self.last[a] and (named is None or a in named)
            if write or a in force:
                words.append(f" {_AXIS_LETTERS[a]}{txt}")
                self.last[a] = txt
        return "".join(words)

    def machine_axes(self, p: np.ndarray, axes: list[int]) -> str:
        """Words of a machine-coordinate move (M91): only the axes it moves or names."""
        words = []
        for a in axes or [2]:
            words.append(f" {_AXIS_LETTERS[a]}{self.num(float(p[a]))}")
            self.last[a] = None
        return "".join(words)

    def straight(self, kind: int, p: np.ndarray, feed: float, machine: list[int] | None, plane: int,
                 named: list[int] | None = None) -> None:
        if machine is not None:
            words = self.machine_axes(p, machine)
        else:
            words = self.axes(p, named=named)
            if not words:
                words = self.axes(p, force=(PLANE_AXES.get(plane, (0, 1, 2))[0],), named=[])
        if kind == MOVE_RAPID:
            tail = " FMAX"
        else:
            tail = self.feed_word(feed)
        self.blocks.append("L" + words + tail + (" M91" if machine is not None else ""))

    def arc(self, kind: int, s: np.ndarray, p: np.ndarray, c: np.ndarray, plane: int, turns: int, feed: float) -> None:
        i0, i1, i2 = PLANE_AXES.get(plane, PLANE_AXES[PLANE_XY])
        first, second = sorted((i0, i1))
        self.blocks.append(f"CC {_AXIS_LETTERS[first]}{self.num(float(c[first]))} "
                           f"{_AXIS_LETTERS[second]}{self.num(float(c[second]))}")
        dr = " DR+" if kind == MOVE_ARC_CCW else " DR-"
        lin = self.num(float(p[i2]))
        helix = f" {_AXIS_LETTERS[i2]}{lin}" if lin != self.last[i2] else ""
        if turns > 1:
            sweep = _sweep_deg(kind, s, p, c, plane) + 360.0 * (turns - 1)
            sign = "+" if kind == MOVE_ARC_CCW else "-"
            self.blocks.append(f"CP IPA{sign}{sweep:.4f}{helix}{dr}{self.feed_word(feed)}")
            self.last[i0] = self.last[i1] = None
        else:
            self.blocks.append(f"C {_AXIS_LETTERS[first]}{self.num(float(p[first]))} "
                               f"{_AXIS_LETTERS[second]}{self.num(float(p[second]))}{helix}{dr}{self.feed_word(feed)}")
            self.last[first] = self.num(float(p[first]))
            self.last[second] = self.num(float(p[second]))
        self.last[i2] = lin


def _sweep_deg(kind: int, s: np.ndarray, p: np.ndarray, c: np.ndarray, plane: int) -> float:
    """Unsigned sweep of an arc in (0, 360] degrees."""
    i0, i1, _i2 = PLANE_AXES.get(plane, PLANE_AXES[PLANE_XY])
    a0 = math.atan2(s[i1] - c[i1], s[i0] - c[i0])
    a1 = math.atan2(p[i1] - c[i1], p[i0] - c[i0])
    sweep = math.degrees(a1 - a0 if kind == MOVE_ARC_CCW else a0 - a1) % 360.0
    return sweep if sweep > 1e-9 else 360.0


def _clean_name(name: str) -> str:
    cleaned = "".join(c if (c.isalnum() or c in "_-") and ord(c) < 256 else "_" for c in name.strip())
    return cleaned or "PGM"


def _comment_lines(comments: list[str] | None) -> list[str]:
    out: list[str] = []
    for text in comments or []:
        for part in str(text).splitlines() or [""]:
            part = part.encode("latin-1", errors="replace").decode("latin-1").rstrip(" \t~")
            out.append("; " + "".join(c if c >= " " else " " for c in part))
    return out


def write_klartext(moves: MoveTable, *, name: str, units: str = "mm", decimals: int = 3,
                   comments: list[str] | None = None, events: object = None) -> str:
    """Write a move table (of any dialect) as a Heidenhain Klartext program.

    Parameters
    ----------
    moves : MoveTable
        The motion, in execution order.
    name : str
        Program name for ``BEGIN PGM`` / ``END PGM`` (characters other than
        letters, digits, ``_`` and ``-`` become ``_``).
    units : {"mm", "inch"}
        Units of the written program.
    decimals : int
        Decimal places of coordinates (0..6).
    comments : list of str, optional
        Comment lines written after ``BEGIN PGM`` as ``; text``.
    events : Carried, optional
        The source's machining words by move (:func:`ilcnc.program.carry.carried_events`), written before and
        after their moves.

    Returns
    -------
    str
        The program, LF line ends, blocks numbered from 0. Rapids are
        ``L .. FMAX``, straight feeds ``L .. F..`` (only the axes that change,
        F when it changes), arcs ``CC`` + ``C .. DR+/DR-`` (a full circle is a
        ``C`` back to its start point, a helix carries the tool-axis word,
        multi-turn arcs are ``CP IPA..``). Coordinates are in the program
        frame (``end_mm - offset_mm``); an offset is written as a datum shift
        (cycle 7). ``M91`` marks machine-coordinate moves.

    Raises
    ------
    ValueError
        Unknown units or decimals out of range.
    """
    if units not in ("mm", "inch"):
        raise ValueError(f"units must be 'mm' or 'inch', not {units!r}")
    if not 0 <= int(decimals) <= 6:
        raise ValueError(f"decimals must be 0..6, not {decimals}")
    pgm = _clean_name(name)
    unit_word = "MM" if units == "mm" else "INCH"
    w = _Writer(MM_PER_INCH if units == "inch" else 1.0, int(decimals))
    blocks = w.blocks
    blocks.extend(_comment_lines(comments))
    from ilcnc.program.carry import Carried, klartext_blocks

    carried = events if isinstance(events, Carried) else Carried()
    named_all = named_axes(moves)
    for i in range(len(moves)):
        blocks.extend(klartext_blocks(carried.before.get(i, [])))
        kind = int(moves.kind[i])
        machine = bool(moves.flags[i] & FLAG_MACHINE)
        off = moves.offset_mm[i]
        if not machine:
            w.datum((float(off[0]), float(off[1]), float(off[2])))
        end = moves.end_mm[i] if machine else moves.end_mm[i] - off
        off = np.zeros(3) if machine else off
        plane = int(moves.plane[i])
        if kind in (MOVE_RAPID, MOVE_LINE):
            named = [a for a in range(3) if named_all[i, a]]  # an axis never positioned is not invented
            w.straight(kind, end, float(moves.feed_mm_min[i]), named if machine else None, plane,
                       named=None if machine else named)
        else:
            w.arc(kind, moves.start_mm[i] - off, end, moves.center_mm[i] - off, plane, int(moves.turns[i]),
                  float(moves.feed_mm_min[i]))
        blocks.extend(klartext_blocks(carried.after.get(i, [])))
    blocks.extend(klartext_blocks(carried.tail))
    if w.offset != (0.0, 0.0, 0.0):
        w.datum((0.0, 0.0, 0.0))
    lines = [f"0 BEGIN PGM {pgm} {unit_word}"]
    lines.extend(f"{k} {b}" for k, b in enumerate(blocks, start=1))
    lines.append(f"{len(blocks) + 1} END PGM {pgm} {unit_word}")
    return "\n".join(lines) + "\n"

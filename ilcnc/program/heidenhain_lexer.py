"""The Klartext lexer: block kinds, numbers and Q-parameter formulas, and every line cut into a block.

The first of the Heidenhain reader's two layers: values keep how they were written (decimals, sign) and
where they are in the text, so the rewriter changes a number without touching a byte around it; Q formulas
compile to functions of the parameters. The interpreter (:mod:`ilcnc.program.heidenhain`) runs the blocks.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ilcnc.errors import ProgramError
from ilcnc.program.heidenhain_expr import FUNCS, TERM, FormulaSyntaxError, parse_expr, qget, scan_value, skip_ws, token_at
from ilcnc.program.model import (
    STYLE_LITERAL,
    STYLE_PLUS,
)

__all__ = [
    "AXIS_INDEX",
    "K_APPR",
    "K_BEGIN",
    "K_C",
    "K_CALL_LBL",
    "K_CALL_PGM",
    "K_CC",
    "K_CHF",
    "K_CP",
    "K_CR",
    "K_CT",
    "K_CYCL_CALL",
    "K_CYCL_DEF",
    "K_DEP",
    "K_END",
    "K_FASTL",
    "K_FN_ARITH",
    "K_FN_ERROR",
    "K_FN_JUMP",
    "K_FN_OTHER",
    "K_FN_SYSREAD",
    "K_L",
    "K_LBL",
    "K_LOOSE",
    "K_LP",
    "K_M",
    "K_PLANE",
    "K_Q",
    "K_QS",
    "K_RND",
    "K_RUN",
    "K_STOP",
    "K_TOOL_CALL",
    "K_TOOL_DEF",
    "RCOMP_CODE",
    "RCOMP_NAME",
    "Block",
    "KlartextLexer",
    "Motion",
    "Run",
    "Stop",
    "block_number_lines",
    "cycle_name",
    "dwell_value",
    "fast_motion",
    "ffill"
]

AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}


# --------------------------------------------------------------------------------------------
# block kinds
# --------------------------------------------------------------------------------------------
(K_BEGIN, K_END, K_L, K_LP, K_C, K_CC, K_CR, K_CT, K_CP, K_RND, K_CHF, K_APPR, K_DEP, K_M, K_STOP,
 K_FN_ARITH, K_FN_JUMP, K_FN_ERROR, K_FN_SYSREAD, K_FN_OTHER, K_Q, K_QS, K_LBL, K_CALL_LBL, K_CALL_PGM,
 K_CYCL_DEF, K_CYCL_CALL, K_TOOL_CALL, K_TOOL_DEF, K_PLANE, K_LOOSE, K_FASTL, K_RUN) = range(33)
#: Shortest run of plain ``L`` blocks read with numpy instead of block by block.
MIN_RUN = 16


class Block:
    """One lexed block: its kind, first line, offset of its text and payload."""

    __slots__ = ("data", "hold", "kind", "line", "pos")

    def __init__(self, kind: int, line: int, pos: int, data: Any) -> None:
        self.kind = kind
        self.line = line
        self.pos = pos
        self.data = data
        self.hold = False


class Motion:
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


class Stop(Exception):
    """Interpretation stops here: a construct that is valid but not modelled."""

    def __init__(self, line: int, problem: str) -> None:
        super().__init__(problem)
        self.line = line
        self.problem = problem


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


def block_number_lines(text: str) -> np.ndarray:
    """File line (1-based) of each Klartext block number: ``out[n]`` is the line of block ``n`` (0: no such block,
    or a number given to more than one line). A TNC names the running block by this number, not by its line."""
    first: dict[int, int] = {}
    twice: set[int] = set()
    for i, line in enumerate(text.splitlines(), start=1):
        m = _PREFIX.match(line)
        if m is None or m.group(2) is None:
            continue
        n = int(m.group(2))
        if n in first:
            twice.add(n)
        else:
            first[n] = i
    out = np.zeros(max(first, default=-1) + 1, dtype=np.int64)
    for n, i in first.items():
        if n not in twice:
            out[n] = i
    return out


def _comment_free(s: str) -> str:
    """The block text without its ``;`` comments (which end at ``~``)."""
    return re.sub(r";[^~\n]*", "", s)


def dwell_value(text: str) -> Any:
    """The time of a dwell block (``CYCL DEF 9.1 DWELL 1.5``, ``V.ZEIT 1.5``, ``TIME5``, ``Q5``; ``FUNCTION DWELL
    TIME 1.5``): the first value after an optional name, a number or a Q closure (s); None when there is none."""
    body = _comment_free(text)
    m = re.match(r"[ \t]*(?:(?!Q[ \t]*\d)[A-Z][A-Z.]*[ \t]*)?", body)
    try:
        got = scan_value(body, m.end() if m is not None else 0)
    except FormulaSyntaxError:
        return None
    return None if got is None or isinstance(got[0], str) else got[0]


class KlartextLexer:
    """Split the text into blocks and parse each one."""

    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        self.text = text
        self.blocks: list[Block] = []
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
            last = Block(K_FASTL, ls.pop(), bs.pop(), ms.pop())
            last.hold = True
        blocks = self.blocks
        if len(ms) >= MIN_RUN:
            blocks.append(Block(K_RUN, ls[0], bs[0], Run(list(ms), list(ls), list(bs))))
        else:
            for m, ln, b in zip(ms, ls, bs, strict=True):
                blocks.append(Block(K_FASTL, ln, b, m))
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
                self.blocks.append(Block(K_FASTL, line, base, m))
                return
            m = _FAST_C.match(s)
            if m is not None and (m.group(1) == "C" or not any(m.groups()[10:])):
                self.close_run(False)
                kind = K_CC if m.group(1) == "CC" else K_C
                self.blocks.append(Block(kind, line, base, fast_motion(m, base, False)))
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
        except FormulaSyntaxError as exc:
            raise self.error(line, str(exc)) from None

    def dispatch(self, s: str, i: int, base: int, line: int, skip: bool) -> None:
        km = _KEYWORD.match(s, i)
        if km is None:
            raise FormulaSyntaxError(f"unknown block {token_at(s, i)!r}")
        kw = km.group()
        j = km.end()
        head = kw.split()[0] if kw[0] not in ";*" else kw
        if self.begin is None and not kw.startswith("BEGIN"):
            if kw in (";", "*"):
                raise FormulaSyntaxError("a comment before BEGIN PGM; the program must start with BEGIN PGM")
            raise FormulaSyntaxError(f"expected BEGIN PGM, found {token_at(s, i)!r}")
        if kw[0] in ";*":
            return
        alpha = kw[-1].isalpha()
        if alpha and j < len(s) and s[j] not in TERM and not (head in ("LBL", "CHF") or kw[0] == "M"):
            raise FormulaSyntaxError(f"unknown block {token_at(s, i)!r}")
        if skip:
            self.skipped_lines.append(line)
        self.close_run(kw in ("RND", "CHF"))
        rest_at = j
        blk = self.keyword(kw, s, i, rest_at, base, line)
        if blk is not None:
            self.blocks.append(blk)

    def keyword(self, kw: str, s: str, i: int, j: int, base: int, line: int) -> Block | None:
        first = kw.split()[0]
        if kw in _MOTION_KINDS:
            kind = _MOTION_KINDS[kw]
            return Block(kind, line, base, self.motion(kind, s, j, base))
        if kw == "M":
            return Block(K_M, line, base, self.motion(K_M, s, i, base))
        if kw == "STOP":
            return Block(K_STOP, line, base, self.motion(K_STOP, s, j, base))
        if kw == "RND":
            return Block(K_RND, line, base, self.rnd(s, j))
        if kw == "CHF":
            return Block(K_CHF, line, base, self.chf(s, j))
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
            return Block(K_TOOL_CALL, line, base, self.tool_call(s, j))
        if kw.startswith("TOOL") and kw.endswith("DEF"):
            return Block(K_TOOL_DEF, line, base, self.tool_def(s, j))
        if first == "BLK":
            self.blk_form(s, j)
            return None
        if kw == "PLANE":
            return Block(K_PLANE, line, base, _comment_free(s[j:]).split())
        if kw == "CALL PGM" or " ".join(kw.split()) == "CALL PGM":
            return Block(K_CALL_PGM, line, base, s[j:].strip())
        return Block(K_LOOSE, line, base, (" ".join(kw.split()), _comment_free(s[j:]).split()))

    # ---- program frame ---------------------------------------------------------------------
    def begin_pgm(self, s: str, i: int, base: int, line: int) -> Block:
        if self.begin is not None:
            raise FormulaSyntaxError(f"second BEGIN PGM (the first is at line {self.begin[2]})")
        m = _BEGIN_RE.match(s, i)
        if m is None:
            raise FormulaSyntaxError("malformed BEGIN PGM (expected 'BEGIN PGM name MM' or 'BEGIN PGM name INCH')")
        self.begin = (m.group(1), m.group(2), line)
        return Block(K_BEGIN, line, base, None)

    def end_pgm(self, s: str, i: int, base: int, line: int) -> Block:
        m = _END_RE.match(s, i)
        if m is None:
            raise FormulaSyntaxError("malformed END PGM (expected 'END PGM name MM')")
        assert self.begin is not None
        name, unit = m.group(1), m.group(2)
        if unit is not None and unit != self.begin[1]:
            raise FormulaSyntaxError(f"END PGM unit {unit} differs from BEGIN PGM unit {self.begin[1]}")
        if name != self.begin[0]:
            self.warnings.append(
                f"line {line}: END PGM names {name!r} but BEGIN PGM (line {self.begin[2]}) names {self.begin[0]!r}")
        self.end = (name, line)
        return Block(K_END, line, base, None)

    # ---- motion words ----------------------------------------------------------------------
    def motion(self, kind: int, s: str, i: int, base: int) -> Motion:
        mo = Motion()
        allowed = _ALLOWED[kind]
        n = len(s)
        mo.insert_at = base + i
        if kind in (K_APPR, K_DEP):
            i = self.appr_sub(mo, s, i)
            mo.insert_at = base + i
        seen: set[str] = set()
        i = skip_ws(s, i)
        while i < n:
            if s[i] == ";":
                break
            wm = _WORD.match(s, i)
            if wm is None:
                raise FormulaSyntaxError(f"unknown word {token_at(s, i)!r} in {_BLOCK_NAMES[kind]} block")
            i = self.word(kind, allowed, mo, seen, s, wm.group(), wm.end(), base)
            i = skip_ws(s, i)
        if kind == K_CR and mo.radius is None:
            raise FormulaSyntaxError("CR needs a radius R")
        return mo

    def appr_sub(self, mo: Motion, s: str, i: int) -> int:
        j = skip_ws(s, i)
        for sub in _APPR_SUBS:
            if s.startswith(sub, j) and (j + len(sub) >= len(s) or s[j + len(sub)] in TERM):
                mo.sub = sub
                return j + len(sub)
        raise FormulaSyntaxError(f"unknown approach/departure type {token_at(s, j)!r} (LT, LN, CT, LCT, PLT, PLN, PCT, PLCT)")

    def word(self, kind: int, allowed: frozenset[str], mo: Motion, seen: set[str], s: str, name: str, j: int,
             base: int) -> int:
        bname = _BLOCK_NAMES[kind]
        if name == "F":  # "F AUTO" / "F MAX" (a space between, as the TNC 640 also writes them)
            k = skip_ws(s, j)
            for tail, word in (("AUTO", "FAUTO"), ("MAX", "FMAX")):
                if k > j and s.startswith(tail, k) and (k + len(tail) >= len(s) or s[k + len(tail)] in TERM):
                    name, j = word, k + len(tail)
                    break
        cls = _word_class(name)
        if name == "R":
            return self.r_word(kind, allowed, mo, s, j, base)
        if cls not in allowed:
            raise FormulaSyntaxError(f"word {token_at(s, j - len(name))!r} is not allowed in a {bname} block")
        if cls == "dr" or name in ("FMAX", "FAUTO"):
            if j < len(s) and s[j] not in TERM:
                raise FormulaSyntaxError(f"unknown word {token_at(s, j - len(name))!r} in {bname} block")
            if cls == "dr":
                mo.dr = 1 if name[2] == "+" else -1
            elif name == "FMAX":
                mo.feed = "MAX"
            else:
                mo.feed = "AUTO"
            return j
        if name == "MB" and s.startswith("MAX", skip_ws(s, j)):
            k = skip_ws(s, j) + 3
            mo.extra["MB"] = "MAX"
            return k
        got = scan_value(s, j)
        if name in ("F", "M"):
            return self.f_or_m(mo, name, got, s, j)
        if name in ("FU", "FZ"):
            if got is None or isinstance(got[0], str):
                raise FormulaSyntaxError(f"missing number after {name!r}")
            mo.feed = (name[1], got[0])
            return got[5]
        key = name[1:] if name[0] == "I" and name not in ("I",) else name
        if got is None or isinstance(got[0], str):
            what = f"{name}{got[0]}" if got is not None else name
            raise FormulaSyntaxError(f"missing number after {what!r}")
        value, start, end, dec, style, nxt = got
        inc = name[0] == "I"
        if key in seen:
            raise FormulaSyntaxError(f"{key} given twice in one block")
        seen.add(key)
        if cls == "coord":
            if key in AXIS_INDEX:
                mo.coords.append((AXIS_INDEX[key], inc, value, base + start, base + end, dec, style))
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

    def f_or_m(self, mo: Motion, name: str, got: tuple | None, s: str, j: int) -> int:
        if got is None:
            return j
        value, start, _end, _dec, _style, nxt = got
        if isinstance(value, str):
            raise FormulaSyntaxError(f"missing number after {name}{value!r}")
        if name == "F":
            if mo.feed is not None and mo.ms and mo.ms[-1] in (103, 128):
                return nxt  # M103 F.. / M128 F..: a factor or a feed for the M function
            mo.feed = value
            return nxt
        if callable(value) or value != int(value) or value < 0:
            raise FormulaSyntaxError(f"malformed M function {token_at(s, start)!r}")
        mo.ms.append(int(value))
        return nxt

    def r_word(self, kind: int, allowed: frozenset[str], mo: Motion, s: str, j: int, base: int) -> int:
        n = len(s)
        bname = _BLOCK_NAMES[kind]
        if j < n and s[j] in "LR" and (j + 1 >= n or s[j + 1] in TERM):
            if "rcomp" not in allowed:
                raise FormulaSyntaxError(f"radius compensation R{s[j]} is not allowed in a {bname} block")
            mo.rcomp = "R" + s[j]
            return j + 1
        got = scan_value(s, j)
        if got is None:
            if "rcomp" not in allowed:
                raise FormulaSyntaxError(f"word 'R' is not allowed in a {bname} block")
            return j
        value, start, end, dec, _style, nxt = got
        if isinstance(value, str):
            if kind != K_L:
                raise FormulaSyntaxError(f"missing number after 'R{value}'")
            mo.rcomp = "R" + value
            return nxt
        if not callable(value) and value == 0 and dec == 0 and s[start:end].strip("+ \t") == "0" and "rcomp" in allowed:
            mo.rcomp = "R0"
            return nxt
        if "radius" not in allowed:
            raise FormulaSyntaxError(f"radius {token_at(s, j - 1)!r} is not allowed in a {bname} block")
        mo.radius = value
        return nxt

    def rnd(self, s: str, i: int) -> Motion:
        mo = Motion()
        j = skip_ws(s, i)
        if not s.startswith("R", j):
            raise FormulaSyntaxError("RND needs a radius R")
        got = scan_value(s, j + 1)
        if got is None or isinstance(got[0], str):
            raise FormulaSyntaxError("RND needs a radius R")
        mo.radius = got[0]
        self.tail_feed(mo, s, got[5], "RND")
        return mo

    def chf(self, s: str, i: int) -> Motion:
        mo = Motion()
        got = scan_value(s, i)
        if got is None or isinstance(got[0], str):
            raise FormulaSyntaxError("CHF needs a chamfer length")
        mo.radius = got[0]
        self.tail_feed(mo, s, got[5], "CHF")
        return mo

    def tail_feed(self, mo: Motion, s: str, i: int, what: str) -> None:
        i = skip_ws(s, i)
        n = len(s)
        while i < n and s[i] != ";":
            if s.startswith("F", i):
                got = scan_value(s, i + 1)
                if got is None or isinstance(got[0], str):
                    raise FormulaSyntaxError(f"missing number after 'F' in {what} block")
                mo.feed = got[0]
                i = skip_ws(s, got[5])
                continue
            wm = _M_WORDS.match(s, i)
            if wm is not None and (wm.end() >= n or s[wm.end()] in TERM):
                i = skip_ws(s, wm.end())
                continue
            raise FormulaSyntaxError(f"unexpected {token_at(s, i)!r} in {what} block")

    # ---- labels and calls --------------------------------------------------------------------
    def lbl(self, s: str, i: int, base: int, line: int) -> Block:
        m = _LBL_RE.match(s, i)
        if m is None:
            raise FormulaSyntaxError(f"malformed label {token_at(s, i)!r} (expected LBL number or LBL \"name\")")
        key = _label_key(m.group(1))
        if isinstance(key, tuple):
            raise FormulaSyntaxError("a label cannot be a Q parameter")
        if key != 0:
            if key in self.labels:
                raise FormulaSyntaxError(f"label {m.group(1)} defined twice (first at line {self.label_lines[key]})")
            self.labels[key] = len(self.blocks)
            self.label_lines[key] = line
        return Block(K_LBL, line, base, key)

    def call_lbl(self, s: str, i: int, base: int, line: int) -> Block:
        m = _CALL_LBL_RE.match(s, i)
        if m is None:
            raise FormulaSyntaxError(f"malformed label call {s[i:].strip()[:40]!r}")
        key = _label_key(m.group(1))
        self.note_target(key)
        if m.group(4) is not None:
            rep: Any = qget(m.group(4), False)
        elif m.group(2) is not None:
            rep = int(m.group(2))
            if m.group(3) is not None and int(m.group(3)) != rep:
                self.warnings.append(f"line {line}: REP {m.group(2)}/{m.group(3)}: {m.group(2)} repetitions used")
        else:
            rep = 0
        if key == 0:
            raise FormulaSyntaxError("CALL LBL 0 is not allowed (LBL 0 ends a subprogram)")
        return Block(K_CALL_LBL, line, base, (key, rep))

    def note_target(self, key: Any) -> None:
        if isinstance(key, tuple):
            self.dynamic_targets = True
        else:
            self.targets.add(key)

    # ---- FN and formulas ---------------------------------------------------------------------
    def fn(self, s: str, i: int, base: int, line: int) -> Block:
        m = _FN_RE.match(s, i)
        if m is None:
            raise FormulaSyntaxError(f"malformed FN block {token_at(s, i)!r}")
        num = int(m.group(1))
        j = m.end()
        if num in _FN_OPS or num in _FN_UNARY or num == 0:
            return Block(K_FN_ARITH, line, base, self.fn_arith(num, s, j))
        if num in _FN_CMP:
            return Block(K_FN_JUMP, line, base, self.fn_jump(num, s, j))
        if num == 14:
            em = _ERROR_RE.match(s, j)
            if em is None:
                raise FormulaSyntaxError("malformed FN 14 (expected 'FN 14: ERROR= number')")
            return Block(K_FN_ERROR, line, base, em.group(1))
        if num == 18:
            sm = _SYSREAD_RE.match(s, j)
            if sm is None:
                raise FormulaSyntaxError("malformed FN 18 (expected 'FN 18: SYSREAD Qn = ID.. NR..')")
            return Block(K_FN_SYSREAD, line, base, sm.group(1))
        if num > 45:
            raise FormulaSyntaxError(f"unknown function FN {num}")
        return Block(K_FN_OTHER, line, base, (num, s[j:].strip()))

    def fn_operand(self, s: str, j: int) -> tuple[Any, int]:
        got = scan_value(s, j)
        if got is None or isinstance(got[0], str):
            raise FormulaSyntaxError(f"missing operand at {token_at(s, skip_ws(s, j))!r}")
        return got[0], got[5]

    def fn_arith(self, num: int, s: str, j: int) -> tuple[str, Callable]:
        tm = _FN_TARGET.match(s, skip_ws(s, j))
        if tm is None:
            raise FormulaSyntaxError(f"malformed FN {num} (expected 'FN {num}: Qn = ...')")
        target = tm.group(1)
        j = tm.end()
        if num in _FN_UNARY:
            word = _FN_UNARY[num]
            k = skip_ws(s, j)
            if not s.startswith(word, k):
                raise FormulaSyntaxError(f"FN {num} expects {word}")
            a, j = self.fn_operand(s, k + len(word))
            fn = FUNCS[word]
            fa = _as_fn(a)
            f: Callable = lambda q: fn(fa(q))  # noqa: E731
        else:
            a, j = self.fn_operand(s, j)
            f = _as_fn(a)
            if num != 0:
                op = _FN_OPS[num]
                k = skip_ws(s, j)
                if not s.startswith(op, k):
                    raise FormulaSyntaxError(f"FN {num} expects the operator {op}")
                b, j = self.fn_operand(s, k + len(op))
                f = _fn_op(op, f, _as_fn(b))
        k = skip_ws(s, j)
        if k < len(s) and s[k] != ";":
            raise FormulaSyntaxError(f"unexpected {token_at(s, k)!r} after FN {num}")
        return target, f

    def fn_jump(self, num: int, s: str, j: int) -> tuple[str, Callable, Callable, Any]:
        bad = f"malformed FN {num} (expected 'FN {num}: IF a {_FN_CMP[num]} b GOTO LBL n')"
        g = _FN_GOTO_RE.search(s, j)
        if g is None:
            raise FormulaSyntaxError(bad)
        m = _FN_COND_RE.match(s[:g.start()], j)
        if m is None:
            raise FormulaSyntaxError(bad)
        if m.group(2) != _FN_CMP[num]:
            raise FormulaSyntaxError(f"FN {num} compares with {_FN_CMP[num]}, not {m.group(2)}")
        a = self.operand_text(m.group(1), s, m.start(1))
        b = self.operand_text(m.group(3).rstrip(), s, m.start(3))
        key = _label_key(g.group(1))
        self.note_target(key)
        return m.group(2), a, b, key

    def operand_text(self, txt: str, s: str, at: int) -> Callable:
        got = scan_value(txt, 0)
        if got is None or isinstance(got[0], str) or skip_ws(txt, got[5]) != len(txt):
            raise FormulaSyntaxError(f"malformed operand {txt!r}")
        return _as_fn(got[0])

    def q_formula(self, s: str, i: int, base: int, line: int) -> Block:
        if s.startswith("QS", i):
            return Block(K_QS, line, base, s[i:].split("=")[0].strip())
        m = _Q_RE.match(s, i)
        if m is None:
            raise FormulaSyntaxError(f"malformed Q parameter formula {token_at(s, i)!r} (expected 'Qn = formula')")
        f, _end = parse_expr(s, m.end(), len(s))
        return Block(K_Q, line, base, (m.group(1), f))

    # ---- cycles -----------------------------------------------------------------------------
    def cycl_def(self, s: str, i: int, base: int, line: int) -> Block:
        m = _CYCL_RE.match(s, i)
        if m is None:
            raise FormulaSyntaxError(f"malformed cycle definition {s[i:].strip()[:40]!r}")
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
        elif sub == 1 and num == 9:
            data = dwell_value(rest)
        elif sub is not None and sub >= 1 and num == 8:
            axes = _comment_free(rest).split()
            for a in axes:
                if a not in ("X", "Y", "Z", "U", "V", "W"):
                    raise FormulaSyntaxError(f"unknown mirror axis {a!r}")
            data = axes
        else:
            self.check_cycle_params(rest)
        return Block(K_CYCL_DEF, line, base, (num, sub, data))

    def cycle_words(self, num: int, rest: str) -> Any:
        body = _comment_free(rest).strip()
        if num == 7 and body.startswith("#"):
            return ("#", body)
        words: list[tuple[str, Any]] = []
        i = skip_ws(rest, 0)
        n = len(rest)
        names = {7: r"I?[XYZABCUVW]", 10: r"I?ROT", 11: r"SCL", 19: r"[ABC]|F|ABST"}[num]
        rx = re.compile(names)
        while i < n and rest[i] != ";":
            m = rx.match(rest, i)
            if m is None:
                raise FormulaSyntaxError(f"unexpected {token_at(rest, i)!r} in cycle {num}")
            got = scan_value(rest, m.end())
            if got is None or isinstance(got[0], str):
                raise FormulaSyntaxError(f"missing number after {m.group()!r} in cycle {num}")
            words.append((m.group(), got[0]))
            i = skip_ws(rest, got[5])
        return words

    def tolerance_word(self, rest: str) -> Any:
        """The ``T`` value of ``CYCL DEF 32.1`` (a number or a Q closure), None when the block has none."""
        body = _comment_free(rest)
        m = re.match(r"[ \t]*T(?=[ \t]*[-+0-9.,Q(]|[ \t]*$)", body)
        if m is None:
            return None
        got = scan_value(body, m.end())
        if got is None or isinstance(got[0], str):
            raise FormulaSyntaxError("missing number after T in cycle 32.1")
        return got[0]

    def check_cycle_params(self, rest: str) -> None:
        for m in re.finditer(r"\bQ\d+\s*=\s*([^\s;~]+)", _comment_free(rest)):
            txt = m.group(1)
            got = scan_value(txt, 0)
            if got is None or isinstance(got[0], str) or got[5] != len(txt):
                raise FormulaSyntaxError(f"malformed cycle parameter {m.group(0)!r}")

    def cycl_call(self, s: str, j: int, base: int, line: int) -> Block:
        k = skip_ws(s, j)
        mode = ""
        for word in ("POS", "PAT"):
            if s.startswith(word, k) and (k + 3 >= len(s) or s[k + 3] in TERM):
                mode = word
                k += 3
        mo = self.motion(K_CYCL_CALL, s, k, base)
        if mode != "POS" and mo.coords:
            raise FormulaSyntaxError("coordinates in CYCL CALL need POS")
        mo.sub = mode
        return Block(K_CYCL_CALL, line, base, mo)

    # ---- tools, blank ------------------------------------------------------------------------
    def tool_id(self, s: str, i: int) -> tuple[Any, int]:
        i = skip_ws(s, i)
        if i < len(s) and s[i] in "\"'":
            q = s.find(s[i], i + 1)
            if q < 0:
                raise FormulaSyntaxError("tool name without closing quote")
            return s[i + 1:q], q + 1
        m = _TOOL_ID.match(s, i)
        if m is not None and (m.end() >= len(s) or s[m.end()] in TERM):
            txt = m.group()
            return (qget(txt, False) if txt[0] == "Q" else float(txt)), m.end()
        return None, i

    def tool_call(self, s: str, j: int) -> dict[str, Any]:
        out: dict[str, Any] = {}
        tool, i = self.tool_id(s, j)
        out["tool"] = tool
        i = skip_ws(s, i)
        if i < len(s) and s[i] in "XYZUVW" and (i + 1 >= len(s) or s[i + 1] in TERM):
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
        i = skip_ws(s, i)
        n = len(s)
        while i < n and s[i] != ";":
            m = _TOOL_WORD.match(s, i)
            if m is None or m.group() not in allowed:
                raise FormulaSyntaxError(f"unexpected {token_at(s, i)!r} in {what}")
            got = scan_value(s, m.end())
            if got is None or isinstance(got[0], str):
                raise FormulaSyntaxError(f"missing number after {m.group()!r} in {what}")
            out[m.group()] = got[0]
            i = skip_ws(s, got[5])

    def blk_form(self, s: str, j: int) -> None:
        k = skip_ws(s, j)
        m = _BLK_SUB.match(s, k)
        if m is None:
            return  # BLK FORM CYLINDER / ROTATION / FILE: accepted as they are
        i = skip_ws(s, m.end())
        if m.group(1) == "1" and i < len(s) and s[i] in "XYZ" and (i + 1 >= len(s) or s[i + 1] in TERM):
            i += 1
        self.motion(K_CC, s, i, 0)  # checks the coordinate words


def fast_motion(m: re.Match[str], base: int, is_l: bool) -> Motion:
    """The words of a block matched by ``_FAST_L`` / ``_FAST_C``."""
    mo = Motion()
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


class Run:
    """A run of plain ``L`` blocks (``_FAST_L`` matches without M words), read as numpy columns."""

    __slots__ = ("_blocks", "_cols", "bases", "lines", "matches")

    def __init__(self, matches: list[re.Match[str]], lines: list[int], bases: list[int]) -> None:
        self.matches = matches
        self.lines = lines
        self.bases = bases
        self._blocks: list[Block] | None = None
        self._cols: dict[str, np.ndarray] | None = None

    def blocks(self) -> list[Block]:
        """The blocks one by one (for the block-by-block path)."""
        if self._blocks is None:
            self._blocks = [Block(K_L, ln, b, fast_motion(m, b, True))
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


RCOMP_CODE = {"R0": 1, "RL": 2, "RR": 3}
RCOMP_NAME = {1: "R0", 2: "RL", 3: "RR"}


def ffill(values: np.ndarray, present: np.ndarray, initial: float) -> np.ndarray:
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
    if axis in AXIS_INDEX:
        return "coord"
    return "rot"


def cycle_name(rest: str) -> str:
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



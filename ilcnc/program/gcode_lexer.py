"""The G-code lexer: every line cut into words, comments and parameter assignments with exact character spans.

The first of the reader's two layers (as in pygcode): :class:`Lexer` turns a line into a :class:`Block` of
:class:`Word` (letter, value, where its number is in the text and how it was written), evaluating
parameters and expressions as LinuxCNC does at that moment of the run. The spans let the rewriter change a
number without touching a byte around it. The interpreter (:mod:`ilcnc.program.gcode`) runs the blocks.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from ilcnc.errors import ProgramError
from ilcnc.program.expr import ExprError, Parameters, read_param_ref, read_value
from ilcnc.program.model import (
    STYLE_LITERAL,
    STYLE_NO_LEADING_ZERO,
    STYLE_PLUS,
    STYLE_TRAILING_DOT,
)

__all__ = ["MAX_NUMBER", "Block", "Lexer", "Word", "detect_dialect"]

# Letters LinuxCNC accepts as words (O is handled separately, E is not a word).
_VALID_LETTERS = frozenset("ABCDEFGHIJKLMNPQRSTUVWXYZ")  # E: the analog channel of M66/M67/M68 (LinuxCNC)
_LITERAL = re.compile(r"([+-]?)[ \t]*(\d*)(\.?)(\d*)")
_SIMPLE_LINE = re.compile(r"[ \t]*(?:[A-DF-NP-Za-df-np-z][ \t]*[+-]?[ \t]*(?:\d+(?:\.\d*)?|\.\d+)[ \t]*)*")
_SIMPLE_WORD = re.compile(r"([A-DF-NP-Za-df-np-z])[ \t]*([+-]?)[ \t]*(\d*)(\.?)(\d*)")
#: Largest magnitude of a number in a program (anything larger is a corrupt file, not a coordinate).
MAX_NUMBER = 1e12
_O_WORD = re.compile(r"[Oo]\s*(<[^>]*>|\d+|#\d+|\[)")
_O_KEYWORDS = (
    "sub", "endsub", "call", "return", "if", "elseif", "else", "endif", "while", "endwhile",
    "do", "repeat", "endrepeat", "break", "continue",
)


@dataclass(slots=True)
class Word:
    """One word of a block: letter, value and where its number is in the text."""

    letter: str
    value: float
    start: int  # offset of the number (after the letter and spaces)
    end: int
    decimals: int
    style: int


@dataclass(slots=True)
class Block:
    """One lexed line."""

    line: int
    words: list[Word] = field(default_factory=list)
    assignments: list[tuple[str | int, float]] = field(default_factory=list)
    comments: list[str] = field(default_factory=list)
    block_delete: bool = False
    percent: bool = False
    o_word: str | None = None  # the o-word text (control flow) if any
    system: str | None = None  # grbl '$' command
    polar: bool = False
    end_offset: int = -1  # offset just past the last word (insertion point)


class Lexer:
    """Cuts lines into blocks; evaluates parameters and expressions."""

    def __init__(self, path: Path, params: Parameters) -> None:
        self.path = path
        self.params = params
        self._permissive = Parameters(permissive=True)

    @property
    def lenient(self) -> bool:
        """After the interpreter stopped, lines are checked for syntax only."""
        return self.params is self._permissive

    @lenient.setter
    def lenient(self, on: bool) -> None:
        if on:
            self.params = self._permissive

    def error(self, line: int, problem: str) -> ProgramError:
        return ProgramError(self.path, line, problem)

    def lex(self, s: str, base: int, line: int) -> Block:
        """Lex one line ``s`` (no line ending) that starts at text offset ``base``."""
        blk = Block(line)
        if _SIMPLE_LINE.fullmatch(s) is not None:
            words = blk.words
            seen = 0
            for m in _SIMPLE_WORD.finditer(s):
                letter = m.group(1).upper()
                sign, ip, dot, fp = m.group(2), m.group(3), m.group(4), m.group(5)
                style = STYLE_LITERAL
                if sign == "+":
                    style |= STYLE_PLUS
                if not ip:
                    style |= STYLE_NO_LEADING_ZERO
                elif dot and not fp:
                    style |= STYLE_TRAILING_DOT
                txt = m.group(0)[1:].replace(" ", "").replace("\t", "")
                value = float(txt)
                if not abs(value) <= MAX_NUMBER:
                    raise self.error(line, f"number {txt[:20]}{'...' if len(txt) > 20 else ''} out of range")
                bit = 1 << (ord(letter) - 65)
                if seen & bit and letter not in "GM":
                    raise self.error(line, f"word {letter} appears twice in one block")
                seen |= bit
                words.append(Word(letter, value, base + m.start(2), base + m.end(), len(fp), style))
            if words:
                blk.end_offset = base + m.end()
            return blk
        return self._lex_general(s, base, line, blk)

    def _lex_general(self, s: str, base: int, line: int, blk: Block) -> Block:
        n = len(s)
        pos = 0
        seen: set[str] = set()
        pending_assign: list[tuple[str | int, float]] = []
        first = True
        while pos < n:
            ch = s[pos]
            if ch in " \t\r\x0c\x1a":
                pos += 1
                continue
            if ch == "(":
                end = s.find(")", pos + 1)
                if end < 0:
                    raise self.error(line, "comment '(' is not closed on this line")
                if "(" in s[pos + 1:end]:
                    raise self.error(line, "nested '(' inside a comment")
                blk.comments.append(s[pos + 1:end])
                pos = end + 1
                continue
            if ch == ";":
                blk.comments.append(s[pos + 1:])
                break
            if ch == "%":
                rest = s[pos + 1:].strip()
                # Mach3 posts number the closing line too ("N890 %"): a block number alone may precede it
                numbered = bool(blk.words) and all(w.letter == "N" for w in blk.words)
                if (blk.words and not numbered) or blk.assignments or (not first and not numbered) or (
                        rest and not rest.startswith(("(", ";"))):
                    raise self.error(line, "'%' must stand alone on its line (a block number may precede it)")
                if numbered:
                    blk.words.clear()
                blk.percent = True
                pos += 1
                first = False
                continue
            if ch == "/" and first:
                blk.block_delete = True
                pos += 1
                continue
            if ch == "$" and first:
                blk.system = s[pos:].strip()
                break
            first = False
            if ch == "#":
                key, pos = self._param_key(s, pos, line)
                p2 = pos
                while p2 < n and s[p2] in " \t":
                    p2 += 1
                if p2 >= n or s[p2] != "=":
                    raise self.error(line, "parameter reference without '=' (assignment expected)")
                value, pos = self._value(s, p2 + 1, line)
                pending_assign.append((key, value))
                continue
            if ch in "@^":
                blk.polar = True
                if ch in seen:
                    raise self.error(line, f"word {ch} appears twice in one block")
                seen.add(ch)
                vstart = pos + 1
                value, pos = self._value(s, vstart, line)
                blk.words.append(Word(ch, value, base + vstart, base + pos, 0, 0))
                blk.end_offset = base + pos
                continue
            if ch in "Oo":
                m = _O_WORD.match(s, pos)
                if m is None:
                    raise self.error(line, "O-word without a number or <name>")
                rest = s[m.end():].lstrip().lower()
                if blk.words:
                    raise self.error(line, "O-word must start the block")
                kw = next((k for k in _O_KEYWORDS if rest.startswith(k)), None)
                if kw is None:
                    if (m.group(1).isdigit() and not rest.strip(" \t")) or rest.startswith(("(", ";")):
                        # Fanuc program number "O0001" on its own line
                        blk.o_word = "program-number"
                        pos = m.end()
                        continue
                    raise self.error(line, f"O-word without a known keyword ({', '.join(_O_KEYWORDS)})")
                blk.o_word = kw
                break
            if ch.isalpha():
                letter = ch.upper()
                if letter not in _VALID_LETTERS:
                    raise self.error(line, f"unknown word '{ch}'")
                vpos = pos + 1
                while vpos < n and s[vpos] in " \t":
                    vpos += 1
                m = _LITERAL.match(s, vpos)
                literal = m is not None and (m.group(2) or m.group(4))
                if literal:
                    assert m is not None
                    sign, ip, dot, fp = m.group(1), m.group(2), m.group(3), m.group(4)
                    style = STYLE_LITERAL
                    if sign == "+":
                        style |= STYLE_PLUS
                    if not ip:
                        style |= STYLE_NO_LEADING_ZERO
                    elif dot and not fp:
                        style |= STYLE_TRAILING_DOT
                    value = float(f"{sign}{ip}{dot}{fp}" if ip else f"{sign}0{dot}{fp}")
                    if not abs(value) <= MAX_NUMBER:
                        raise self.error(line, f"number {(ip + dot + fp)[:20]}... out of range")
                    word = Word(letter, value, base + vpos, base + m.end(), len(fp), style)
                    pos = m.end()
                else:
                    if vpos >= n or not (s[vpos] in "#[+-" or s[vpos].isalpha()):
                        raise self.error(line, f"{letter} word without a number")
                    value, pos = self._value(s, vpos, line)
                    word = Word(letter, value, base + vpos, base + pos, 0, 0)
                if letter in seen and letter not in "GM":
                    raise self.error(line, f"word {letter} appears twice in one block")
                seen.add(letter)
                blk.words.append(word)
                blk.end_offset = base + pos
                continue
            raise self.error(line, f"unexpected character {ch!r}")
        blk.assignments = pending_assign
        if "E" in seen and not any(w.letter == "M" and w.value in (66.0, 67.0, 68.0) for w in blk.words):
            # E is the analog channel of M66/M67/M68 (G70 / G76, LinuxCNC's other users, are not modelled)
            raise self.error(line, "E word with no G70, G76, M66, M67 or M68 to use it")
        return blk

    def _param_key(self, s: str, pos: int, line: int) -> tuple[str | int, int]:
        try:
            return read_param_ref(s, pos, self.params)
        except ExprError as exc:
            raise self.error(line, str(exc)) from None
        except RecursionError:
            raise self.error(line, "expression nested too deeply") from None

    def _value(self, s: str, pos: int, line: int) -> tuple[float, int]:
        try:
            value, end = read_value(s, pos, self.params)
        except ExprError as exc:
            raise self.error(line, str(exc)) from None
        except RecursionError:
            raise self.error(line, "expression nested too deeply") from None
        if not math.isfinite(value) or abs(value) > MAX_NUMBER:
            raise self.error(line, f"value {value!r} out of range")
        return value, end


def detect_dialect(path: Path, text: str) -> str:
    """Guess the G-code dialect: ``linuxcnc``, ``fanuc`` or ``grbl``."""
    head = text[:20000]
    if re.search(r"^\s*\$[A-Za-z$#]", head, re.MULTILINE):
        return "grbl"
    if re.search(r"^\s*[Oo]\s*(<[^>]*>|\d+)\s*(sub|call|if|while|do|repeat)", head, re.MULTILINE) or "#<" in head:
        return "linuxcnc"
    suffix = path.suffix.lower()
    if suffix == ".ngc":
        return "linuxcnc"
    if suffix in (".gcode", ".gc", ".g"):
        return "grbl"
    return "fanuc"

"""What an ilcnc output changed in a program: the text diff of ``ilcnc diff ORIG OUT``.

An output of ``ilcnc learn`` or ``ilcnc export --corrections`` is the
original text with coordinate numbers rewritten (or a missing axis word
written out), the arc centre words that keep an arc's centre after its start
moved, feed words where ``learning.refine.feed`` changed a feed, and, when
refined, whole lines inserted before a move (marked ``(ilcnc refine)`` or
``; ilcnc refine``; Klartext block numbers after them shifted). Nothing else
may change: :func:`diff_programs` says so loudly (:attr:`ProgramDiff.breaches`)
when anything else did.

Lines are matched through the program model, not by text: the output's
inserted lines are set apart by their marker, and each remaining output line
is paired with the original line in the same place (when the counts differ,
by a sequence alignment of the lines with their coordinate words and block
numbers left out). The correction of a paired line is the change of the end
point of its block's last move as the interpreter (:mod:`ilcnc.program`)
reads both programs, in mm of the consistent frame: modal axes, incremental
words and units (inch programs) are resolved the way the control runs them.
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import InputError
from ilcnc.jsonout import json_float
from ilcnc.program import read_program
from ilcnc.program.comments import split_gcode_comments
from ilcnc.program.insert import MARKER
from ilcnc.program.model import Program
from ilcnc.shop.workflow import find_stamp, unstamp_text
from ilcnc.units import AXIS_LETTERS, AXIS_NAMES
from ilcnc.wording import plural

__all__ = ["WORD_KINDS", "ChangedLine", "DiffInserted", "ProgramDiff", "WordChange", "diff_files", "diff_programs",
           "format_diff"]

#: Kinds of word :class:`WordChange` names: a coordinate (X/Y/Z, Klartext ``IX``), an arc centre (I/J/K,
#: Klartext ``CC``), a feed (``F``).
WORD_KINDS = ("axis", "centre", "feed")

#: An end-point coordinate counts as moved when it changed by more than this, mm (float noise of reading
#: the same number twice is 0; a written number's last decimal is >= 1e-8 mm).
MOVED_TOL_MM = 1e-9

_GCODE_WORD = re.compile(r"([A-Za-z])\s*([-+]?\s*(?:\d+\.?\d*|\.\d+)|#<?\w+>?)")
_KL_NUMBER = re.compile(r"^(\s*)(\d+)(?=\s|$)")
_KL_AXIS = re.compile(r"^(I?)([XYZ])(.+)$", re.IGNORECASE)


@dataclass(frozen=True, slots=True)
class WordChange:
    """One word of a line that changed.

    Attributes
    ----------
    kind : str
        One of :data:`WORD_KINDS`.
    letter : str
        ``X``, ``Y``, ``Z`` (axis), ``I``, ``J``, ``K`` (G-code centre), ``X``/``Y``/``Z`` of a Klartext ``CC``
        (centre) or ``F``.
    old, new : str or None
        The word as written in the original and in the output; ``None`` where the line has no such word (a
        modal axis written out, a feed word added).
    """

    kind: str
    letter: str
    old: str | None
    new: str | None

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "letter": self.letter, "old": self.old, "new": self.new}

    def describe(self) -> str:
        """``X50 -> X50.007``, ``+X50.007`` (added) or ``-F1000`` (removed)."""
        if self.old is None:
            return f"+{self.new}"
        if self.new is None:
            return f"-{self.old}"
        return f"{self.old} -> {self.new}"


@dataclass(frozen=True, slots=True, kw_only=True)
class ChangedLine:
    """A line of the original whose text the output changed.

    Attributes
    ----------
    line : int
        1-based line in the original.
    out_line : int
        1-based line in the output.
    old, new : str
        The two lines' texts (without line ending; the output's without a provenance stamp).
    delta_mm : ndarray of shape (3,) or None
        Change of the end point of the block's last move (output minus original), mm; ``None`` when the
        line holds no move in either program (a Klartext ``CC`` block).
    words : tuple of WordChange
        The coordinate, centre and feed words that changed.
    other : tuple of str
        Anything else that changed on the line (a breach of the rewriting contract), one phrase each.
    """

    line: int
    out_line: int
    old: str
    new: str
    delta_mm: NDArray[np.float64] | None
    words: tuple[WordChange, ...]
    other: tuple[str, ...] = ()

    @property
    def delta_um(self) -> NDArray[np.float64] | None:
        """:attr:`delta_mm` in µm."""
        return None if self.delta_mm is None else self.delta_mm * 1e3

    def to_json(self) -> dict[str, Any]:
        d = self.delta_mm
        return {"line": self.line, "out_line": self.out_line, "old": self.old, "new": self.new,
                "delta_um": None if d is None else {a: json_float(float(v) * 1e3) for a, v in zip(AXIS_NAMES, d,
                                                                                                  strict=True)},
                "words": [w.to_json() for w in self.words], "other": list(self.other)}


@dataclass(frozen=True, slots=True, kw_only=True)
class DiffInserted:
    """A line the output has that the original has not.

    Attributes
    ----------
    out_line : int
        1-based line in the output.
    before_line : int or None
        The original line it precedes (``None`` at the end of the program).
    text : str
        Its text.
    end_mm : ndarray of shape (3,) or None
        End point of its move, mm (``None`` when it holds none).
    marked : bool
        It carries refinement's marker (``ilcnc refine``); an unmarked line is a breach.
    """

    out_line: int
    before_line: int | None
    text: str
    end_mm: NDArray[np.float64] | None
    marked: bool

    def to_json(self) -> dict[str, Any]:
        e = self.end_mm
        return {"out_line": self.out_line, "before_line": self.before_line, "text": self.text, "marked": self.marked,
                "end_mm": None if e is None else {a: json_float(float(v)) for a, v in zip(AXIS_NAMES, e, strict=True)}}


@dataclass(kw_only=True)
class ProgramDiff:
    """The diff of an output against its original.

    Attributes
    ----------
    original, output : Path
        The two programs.
    dialect : str
        Their dialect.
    changed : list of ChangedLine
        Lines whose text changed, in original order.
    inserted : list of DiffInserted
        Lines only the output has.
    removed : list of int
        Original lines (1-based) the output lacks (a breach).
    lines_original, lines_output : int
        Line counts.
    renumbered : int
        Klartext lines whose block number shifted by exactly the numbered lines inserted before them.
    stamp : bool
        The output carries ilcnc's provenance comment (``learn --stamp``), left out of the comparison.
    """

    original: Path
    output: Path
    dialect: str
    changed: list[ChangedLine] = field(default_factory=list)
    inserted: list[DiffInserted] = field(default_factory=list)
    removed: list[int] = field(default_factory=list)
    lines_original: int = 0
    lines_output: int = 0
    renumbered: int = 0
    stamp: bool = False

    @property
    def corrected(self) -> list[ChangedLine]:
        """Changed lines whose block's end point moved."""
        return [c for c in self.changed if c.delta_mm is not None and np.any(np.abs(c.delta_mm) > MOVED_TOL_MM)]

    def largest(self) -> ChangedLine | None:
        """The changed line with the longest end-point correction (None when no end point moved)."""
        best = None
        for c in self.corrected:
            if best is None or np.linalg.norm(c.delta_mm) > np.linalg.norm(best.delta_mm):  # type: ignore[arg-type]
                best = c
        return best

    def axis_lines(self) -> dict[str, int]:
        """Per axis (``x``, ``y``, ``z``), how many lines' end points moved along it."""
        out = dict.fromkeys(AXIS_NAMES, 0)
        for c in self.corrected:
            for a, name in enumerate(AXIS_NAMES):
                out[name] += int(abs(float(c.delta_mm[a])) > MOVED_TOL_MM)  # type: ignore[index]
        return out

    def word_counts(self) -> dict[str, int]:
        """How many words of each kind (:data:`WORD_KINDS`) changed, were written out or removed."""
        out = dict.fromkeys(WORD_KINDS, 0)
        for c in self.changed:
            for w in c.words:
                out[w.kind] += 1
        return out

    @property
    def breaches(self) -> list[str]:
        """Every change besides coordinate, centre and feed words and marked inserted lines, one line each
        (``line N: ...``); empty when the output keeps ilcnc's rewriting contract."""
        out = [f"line {c.line}: {o}" for c in self.changed for o in c.other]
        out += [f"output line {i.out_line}: inserted without the '{MARKER}' marker: {i.text.strip()}"
                for i in self.inserted if not i.marked]
        out += [f"line {ln}: removed" for ln in self.removed]
        return out

    def to_json(self) -> dict[str, Any]:
        big = self.largest()
        return {
            "original": str(self.original), "output": str(self.output), "dialect": self.dialect,
            "lines_original": self.lines_original, "lines_output": self.lines_output,
            "changed": [c.to_json() for c in self.changed], "inserted": [i.to_json() for i in self.inserted],
            "removed": list(self.removed),
            "summary": {
                "lines_changed": len(self.changed), "lines_corrected": len(self.corrected),
                "lines_inserted": len(self.inserted), "lines_removed": len(self.removed),
                "renumbered": self.renumbered, "stamp": self.stamp,
                "largest_correction_um": None if big is None else json_float(float(np.linalg.norm(big.delta_mm)) * 1e3),
                "largest_correction_line": None if big is None else big.line,
                "axis_lines": self.axis_lines(), "words": self.word_counts(),
                "only_coordinates": not self.breaches, "breaches": self.breaches,
            },
        }


# --------------------------------------------------------------------------- one line


@dataclass(slots=True)
class _Line:
    """A line taken apart: block number, coordinate/centre/feed words, everything else, comments."""

    number: int | None
    axes: dict[str, str]
    centres: dict[str, str]
    feed: str | None
    rest: list[str]
    comments: list[str]
    marked: bool

    def key(self) -> tuple[object, ...]:
        """What must be equal in a line pair: everything but coordinate, centre and feed words and the block
        number."""
        return tuple(self.rest), tuple(self.comments)


def _split_gcode(text: str) -> _Line:
    body, comments = split_gcode_comments(text, lenient=True)
    body = body or ""
    axes: dict[str, str] = {}
    centres: dict[str, str] = {}
    feed = None
    rest: list[str] = []
    pos = 0
    while pos < len(body):
        ch = body[pos]
        if ch.isspace():
            pos += 1
            continue
        m = _GCODE_WORD.match(body, pos)
        if ch == "[" or (ch.isalpha() and m is None and body[pos + 1:].lstrip().startswith("[")):
            # a bracketed expression (a rewritten parameter becomes "[expression+correction]")
            letter = ch if ch.isalpha() else ""
            j = body.index("[", pos)
            depth, k = 0, j
            while k < len(body):
                depth += {"[": 1, "]": -1}.get(body[k], 0)
                k += 1
                if depth == 0:
                    break
            word = body[pos:k]
            pos = k
        elif m is not None:
            letter, word = m.group(1), "".join(m.group(0).split())
            pos = m.end()
        else:
            rest.append(ch)
            pos += 1
            continue
        up = letter.upper()
        if up in AXIS_LETTERS:
            axes[up] = word
        elif up in "IJK" and up:
            centres[up] = word
        elif up == "F":
            feed = word
        else:
            rest.append(word.upper())
    return _Line(None, axes, centres, feed, rest, [c.strip() for c in comments],
                 any(MARKER in c for c in comments))


def _split_klartext(text: str, continuation: bool) -> _Line:
    code, sep, comment = text.partition(";")
    comments = [comment.strip()] if sep else []
    number = None
    if not continuation:
        m = _KL_NUMBER.match(code)
        if m is not None:
            number = int(m.group(2))
            code = code[m.end():]
    tokens = code.split()
    centre_block = bool(tokens) and tokens[0].upper() == "CC"
    axes: dict[str, str] = {}
    centres: dict[str, str] = {}
    feed = None
    rest: list[str] = []
    for t in tokens:
        m = _KL_AXIS.match(t)
        if m is not None:
            (centres if centre_block else axes)[m.group(2).upper()] = t
        elif t.upper().startswith("F") and (t[1:2].isdigit() or t.upper() in ("FMAX", "FAUTO")):
            feed = t
        else:
            rest.append(t)
    return _Line(number, axes, centres, feed, rest, comments, any(MARKER in c for c in comments))


def _split_lines(text: str) -> list[str]:
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
    return [ln[:-1] if ln.endswith("\r") else ln for ln in lines]


def _parse_lines(lines: list[str], klartext: bool) -> list[_Line]:
    if not klartext:
        return [_split_gcode(s) for s in lines]
    out = []
    continuation = False
    for s in lines:
        out.append(_split_klartext(s, continuation))
        continuation = re.sub(r";.*", "", s).rstrip(" \t").endswith("~")
    return out


def _word_changes(a: _Line, b: _Line, klartext: bool) -> list[WordChange]:
    out: list[WordChange] = []
    for kind, da, db in (("axis", a.axes, b.axes), ("centre", a.centres, b.centres)):
        for letter in sorted(set(da) | set(db)):
            wa, wb = da.get(letter), db.get(letter)
            if wa != wb:
                out.append(WordChange(kind, letter, wa, wb))
    if a.feed != b.feed:
        out.append(WordChange("feed", "F", a.feed, b.feed))
    return out


def _describe_other(a: _Line, b: _Line) -> list[str]:
    out = []
    if a.rest != b.rest:
        out.append(f"words other than coordinates changed: {' '.join(a.rest) or '(none)'} -> "
                   f"{' '.join(b.rest) or '(none)'}")
    if a.comments != b.comments:
        out.append("a comment changed")
    return out


# --------------------------------------------------------------------------- alignment


def _last_move_by_line(program: Program) -> dict[int, int]:
    """Source line -> index of the last move on it."""
    lines = program.moves.line
    out: dict[int, int] = {}
    for i, ln in enumerate(lines.tolist()):
        out[int(ln)] = i
    return out


#: Grid of the end points the fallback alignment compares, mm: far above a correction (learning.max_correction
#: bounds them to fractions of a mm), far below the distance between a program's points that differ.
_ALIGN_GRID_MM = 1.0


def _end_keys(program: Program, n_lines: int) -> list[tuple[float, ...]]:
    """Per line, the end point of its last move on :data:`_ALIGN_GRID_MM` (empty where the line has none)."""
    out: list[tuple[float, ...]] = [()] * n_lines
    for ln, i in _last_move_by_line(program).items():
        if 1 <= ln <= n_lines:
            out[ln - 1] = tuple(np.round(program.moves.end_mm[i] / _ALIGN_GRID_MM).tolist())
    return out


def _pairs(a: list[_Line], b: list[_Line], inserted: list[int], ends_a: list[tuple[float, ...]],
           ends_b: list[tuple[float, ...]]) -> tuple[list[tuple[int, int]], list[int], list[int]]:
    """(pairs of 0-based original and output lines, unpaired original lines, unpaired output lines)."""
    ins = set(inserted)
    rest_b = [j for j in range(len(b)) if j not in ins]
    if len(rest_b) == len(a) and all(x.key() == b[j].key() for x, j in zip(a, rest_b, strict=True)):
        return list(zip(range(len(a)), rest_b, strict=True)), [], []
    # the output is not the original plus marked lines: align the lines by what must not change and by
    # where their moves end (on a grid coarser than any correction)
    keys_a = [(x.key(), ends_a[i]) for i, x in enumerate(a)]
    keys_b = [(b[j].key(), ends_b[j]) for j in rest_b]
    sm = difflib.SequenceMatcher(None, keys_a, keys_b, autojunk=False)
    pairs: list[tuple[int, int]] = []
    lone_a: list[int] = []
    lone_b: list[int] = []
    for tag, i1, i2, j1, j2 in sm.get_opcodes():
        if tag == "equal" or (tag == "replace" and i2 - i1 == j2 - j1):
            pairs += [(i, rest_b[j]) for i, j in zip(range(i1, i2), range(j1, j2), strict=True)]
        else:
            lone_a += list(range(i1, i2))
            lone_b += [rest_b[j] for j in range(j1, j2)]
    return pairs, lone_a, lone_b


def diff_programs(original: Program, output: Program) -> ProgramDiff:
    """The diff of ``output`` (an ilcnc output of ``original``) against ``original``.

    Parameters
    ----------
    original, output : Program
        Both programs as read (same dialect).

    Returns
    -------
    ProgramDiff

    Raises
    ------
    InputError
        The two programs are of different dialects (a dialect conversion is no correction to diff).
    """
    kl_a, kl_b = original.dialect == "heidenhain", output.dialect == "heidenhain"
    if kl_a != kl_b:
        raise InputError(output.path, None, f"is {'Klartext' if kl_b else 'G-code'} and {original.path.name} is"
                         f" {'Klartext' if kl_a else 'G-code'}: ilcnc diff compares an output with its original in"
                         " one dialect (ilcnc export converts)")
    out_text = output.text
    stamp = find_stamp(out_text) is not None and find_stamp(original.text) is None
    if stamp:
        out_text = unstamp_text(out_text)
    la, lb = _split_lines(original.text), _split_lines(out_text)
    pa, pb = _parse_lines(la, kl_a), _parse_lines(lb, kl_a)
    marked = [j for j, x in enumerate(pb) if x.marked]
    # a marked line the original has as well is a line like any other
    # (when the original has marked lines too, the alignment tells its own from the output's new ones)
    inserted = marked if not any(x.marked for x in pa) else []
    pairs, lone_a, lone_b = _pairs(pa, pb, inserted, _end_keys(original, len(la)), _end_keys(output, len(lb)))
    ins_all = sorted(set(inserted) | set(lone_b))

    last_a, last_b = _last_move_by_line(original), _last_move_by_line(output)
    end_a, end_b = original.moves.end_mm, output.moves.end_mm
    diff = ProgramDiff(original=original.path, output=output.path, dialect=original.dialect, stamp=stamp,
                       lines_original=len(la), lines_output=len(lb), removed=[i + 1 for i in lone_a])
    # numbered lines inserted before each output line (Klartext renumbering)
    ins_set = set(ins_all)
    shift = np.cumsum([1 if (j in ins_set and pb[j].number is not None) else 0 for j in range(len(pb))])
    for i, j in pairs:
        a, b = pa[i], pb[j]
        if kl_a and a.number is not None and b.number is not None and a.number != b.number:
            before = int(shift[j - 1]) if j > 0 else 0
            if b.number - a.number == before:
                diff.renumbered += 1
                renumber_ok = True
            else:
                renumber_ok = False
        else:
            renumber_ok = True
        same_text = la[i] == lb[j]
        if same_text:
            continue
        words = _word_changes(a, b, kl_a)
        other = _describe_other(a, b)
        if not renumber_ok:
            other.append(f"block number {a.number} -> {b.number}")
        if (a.number is None) != (b.number is None):
            other.append("block number added or removed")
        if not words and not other:
            if a.number != b.number:
                continue  # renumbered only
            other.append("spacing changed")
        ia, ib = last_a.get(i + 1), last_b.get(j + 1)
        delta = None if ia is None or ib is None else end_b[ib] - end_a[ia]
        diff.changed.append(ChangedLine(line=i + 1, out_line=j + 1, old=la[i], new=lb[j], delta_mm=delta,
                                        words=tuple(words), other=tuple(other)))
    # the original line each inserted line precedes: the next paired output line's partner
    partner = {j: i for i, j in pairs}
    nxt: int | None = None
    before_of: dict[int, int | None] = {}
    for j in range(len(pb) - 1, -1, -1):
        if j in partner:
            nxt = partner[j] + 1
        else:
            before_of[j] = nxt
    for j in ins_all:
        ib = last_b.get(j + 1)
        diff.inserted.append(DiffInserted(out_line=j + 1, before_line=before_of.get(j), text=lb[j],
                                          end_mm=None if ib is None else end_b[ib].copy(), marked=pb[j].marked))
    return diff


def diff_files(original: str | Path, output: str | Path, *, default_units: str = "mm") -> ProgramDiff:
    """Read both programs and diff them (:func:`diff_programs`).

    Parameters
    ----------
    original, output : str or Path
        The original program and the ilcnc output of it.
    default_units : {"mm", "inch"}
        Units of a G-code program that sets neither G20 nor G21 (the output is read in the original's).

    Raises
    ------
    InputError
        A program that cannot be read, or programs of two dialects.
    """
    a = read_program(original, default_units=default_units)
    b = read_program(output, default_units=a.units)
    return diff_programs(a, b)


def _um(v: float) -> str:
    return f"{v * 1e3:+8.2f}"


def _fit(text: str, width: int) -> str:
    return text if len(text) <= width else text[: max(width - 1, 0)] + "…"


def format_diff(diff: ProgramDiff, width: int = 80) -> list[str]:
    """The diff as lines of at most ``width`` characters (``ilcnc diff``'s text output).

    One row per changed line: its line in the original and the output, the end point's correction in µm
    per axis, and the words that changed (wrapped under each other); the inserted lines with the original
    line they precede; a summary; and, when anything besides coordinate, centre and feed words and marked
    inserted lines changed, a line starting ``CONTRACT BREACH`` and each such change.
    """
    import textwrap

    out = [_fit(f"ilcnc diff: {diff.original.name} -> {diff.output.name}"
                f" ({'Klartext' if diff.dialect == 'heidenhain' else 'G-code'}; Δ = output - original)", width)]
    head = f"{'line':>6} {'out':>6} " + "".join(f"{'Δ' + a + ' µm':>8} " for a in AXIS_LETTERS) + " "
    indent = " " * len(head)
    if diff.changed:
        out.append(head + "changed words")
    for c in diff.changed:
        d = c.delta_mm
        nums = ("" if d is None else "".join(f"{_um(float(v))} " for v in d)).rstrip()
        row = f"{c.line:>6} {c.out_line:>6} " + (nums if d is not None else f"{'-':>8} {'-':>8} {'-':>8}")
        row = row.ljust(len(head))
        words = [w.describe() for w in c.words] + [f"[{o}]" for o in c.other]
        body = textwrap.wrap("  ".join(words) or "(spacing)", max(width - len(head), 20),
                             break_long_words=True, break_on_hyphens=False)
        out.append(row + body[0])
        out += [indent + b for b in body[1:]]
    if diff.inserted:
        out.append(f"inserted lines ({len(diff.inserted)}):")
    for i in diff.inserted:
        where = f"before line {i.before_line}" if i.before_line is not None else "at the end"
        out.append(_fit(f"{'':>6} {i.out_line:>6} {where}: {i.text.strip()}", width))
    for ln in diff.removed:
        out.append(f"{ln:>6} {'-':>6} removed")
    big = diff.largest()
    axes = diff.axis_lines()
    words = diff.word_counts()
    summary = (f"summary: {len(diff.changed)} of {plural(diff.lines_original, 'line')} changed"
               f" ({plural(len(diff.corrected), 'end point')} moved), {len(diff.inserted)} inserted,"
               f" {len(diff.removed)} removed")
    if diff.renumbered:
        summary += f", {diff.renumbered} renumbered"
    summary += "; largest correction " + ("none" if big is None else
                                          f"{float(np.linalg.norm(big.delta_mm)) * 1e3:.2f} µm"  # type: ignore
                                          f" (line {big.line})")
    summary += (f"; lines whose end point moved along X: {axes['x']}, Y: {axes['y']}, Z: {axes['z']};"
                f" words changed: {words['axis']} coordinate, {words['centre']} arc centre, {words['feed']} feed")
    if diff.stamp:
        summary += "; the output's provenance comment (learn --stamp) left out"
    out += textwrap.wrap(summary, width, subsequent_indent="  ")
    breaches = diff.breaches
    if breaches:
        out.append(_fit(f"CONTRACT BREACH: {plural(len(breaches), 'change')} besides coordinates, centres,"
                        " feeds, marked lines:", width))
        out += [_fit("  " + b, width) for b in breaches]
    else:
        out.append("only coordinate numbers changed" + (" (and marked lines inserted)" if diff.inserted else ""))
    return out

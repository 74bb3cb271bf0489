"""Split G-code arcs into shorter arcs on the same circle (levelling a helix onto a probed surface).

:func:`split_arcs` inserts, before an arc's line, G2/G3 lines that end at given fractions of its sweep, and
rewrites the arc's own I/J (relative to its new start) so that the re-read program runs exactly the original
circle, with the original helix's Z at each new end. Like :mod:`ilcnc.program.insert` it is careful: an arc is
split only when its line holds nothing but a block number, ``G2``/``G3``, X/Y/Z, I/J and F words and comments
(so nothing on it could act twice), it is a G17 arc of at most one turn with its centre relative to its start
(I/J, not R), in absolute distance mode and a feed per minute (not G93), not repeated, parametric, polar or
under cutter compensation, and it is the only move of its line. Every other arc is returned with a one-line
reason. Each inserted line carries the marker comment; the first carries the line's F word, so the pieces run
at the arc's feed.

Written numbers get enough decimals to lie within 0.05 µm of the circle (4 in mm, 6 in inch:
:func:`ilcnc.program.insert.required_decimals`), at least the source's.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from ilcnc.program.comments import split_gcode_comments
from ilcnc.program.insert import SkippedMove, required_decimals
from ilcnc.program.model import (
    FLAG_CUTTER_COMP,
    FLAG_DERIVED,
    FLAG_HOME,
    FLAG_MACHINE,
    FLAG_PARAMETRIC,
    FLAG_POLAR,
    FLAG_REPEATED,
    MOVE_ARC_CCW,
    MOVE_ARC_CW,
    PLANE_XY,
    Program,
)
from ilcnc.program.rewrite import format_number, spelling

__all__ = ["ArcSplitResult", "split_arcs"]

_UNSAFE = FLAG_MACHINE | FLAG_HOME | FLAG_REPEATED | FLAG_PARAMETRIC | FLAG_POLAR | FLAG_CUTTER_COMP | FLAG_DERIVED
_WORD = re.compile(r"([A-Za-z])[ \t]*([+-]?[ \t]*(?:\d+\.?\d*|\.\d+))[ \t]*")
_MOTION = re.compile(r"[Gg][ \t]*0*([23])(?![.\d])")


@dataclass(slots=True)
class ArcSplitResult:
    """What :func:`split_arcs` made: the new text, the number of inserted lines, the arcs left whole."""

    text: str
    n_inserted: int = 0
    skipped: list[SkippedMove] = field(default_factory=list)


def _line_words(body: str) -> dict[str, str] | str:
    """The words of a line without comments (letter -> number text), or why it holds something else."""
    code = split_gcode_comments(body)[0]
    if code is None:
        return "the line holds an unclosed comment"
    words: dict[str, str] = {}
    pos = 0
    code = code.strip()
    while pos < len(code):
        m = _WORD.match(code, pos)
        if m is None:
            return f"the line holds {code[pos:pos + 12]!r}, which is no plain word"
        letter = m.group(1).upper()
        if letter == "G":
            if not _MOTION.fullmatch(f"G{m.group(2).strip()}"):
                return f"the line holds G{m.group(2).strip()} besides the arc"
        elif letter not in "NXYZIJF":
            return f"the line holds a {letter} word besides the arc"
        elif letter in words:
            return f"the line holds two {letter} words"
        words[letter] = m.group(2)
        pos = m.end()
    return words


def split_arcs(program: Program, fractions: Mapping[int, list[float]], *, min_decimals: int, marker: str
               ) -> ArcSplitResult:
    """Split arcs of a G-code ``program`` at fractions of their sweep by inserting arc lines before them.

    Parameters
    ----------
    program : Program
        A G-code program as read (complete).
    fractions : mapping of int to list of float
        Move index -> fractions 0 < f < 1 of its sweep (angle), in any order.
    min_decimals : int
        Least number of decimals of a written number.
    marker : str
        The comment text of every inserted line.

    Returns
    -------
    ArcSplitResult
    """
    program.require_complete()
    mv = program.moves
    idx = sorted(int(i) for i in fractions)
    program.resolve_spans(np.array(idx, dtype=np.int64))
    result = ArcSplitResult(text=program.text)
    lines_count: dict[int, int] = {}
    for ln in mv.line.tolist():
        lines_count[ln] = lines_count.get(ln, 0) + 1
    plans: dict[int, tuple[list[str], list[tuple[int, int, str]]]] = {}
    for i in idx:
        line = int(mv.line[i])
        plan = _plan(program, i, sorted(set(fractions[i])), lines_count.get(line, 0), min_decimals, marker)
        if isinstance(plan, str):
            result.skipped.append(SkippedMove(i, line, plan))
        else:
            plans[line] = plan
            result.n_inserted += len(plan[0])
    if not plans:
        return result
    out: list[str] = []
    for ln, raw in enumerate(program.text.split("\n"), start=1):
        plan = plans.get(ln)
        if plan is None:
            out.append(raw)
            continue
        body, cr = (raw[:-1], "\r") if raw.endswith("\r") else (raw, "")
        start = program.line_start(ln)
        parts: list[str] = []
        last = 0
        for a, b, new in sorted(plan[1]):
            parts.append(body[last:a - start])
            parts.append(new)
            last = b - start
        parts.append(body[last:])
        out.extend(t + cr for t in plan[0])
        out.append("".join(parts) + cr)
    result.text = "\n".join(out)
    return result


def _plan(program: Program, i: int, fr: list[float], moves_on_line: int, min_decimals: int, marker: str
          ) -> tuple[list[str], list[tuple[int, int, str]]] | str:
    """The inserted lines and the rewrites of the arc's own I/J, or why the arc is left whole."""
    mv = program.moves
    if int(mv.kind[i]) not in (MOVE_ARC_CW, MOVE_ARC_CCW) or int(mv.plane[i]) != PLANE_XY:
        return "not an arc in the XY plane (G17)"
    if int(mv.flags[i]) & _UNSAFE:
        return "a repeated, parametric, polar, machine, home, derived or cutter-compensated move"
    if moves_on_line != 1 or int(mv.turns[i]) != 1:
        return "more than one move on the line, or a full-turn count (P)"
    if np.any(mv.word_incremental[i]) or not (mv.center_incremental[i, 0] and mv.center_incremental[i, 1]):
        return "incremental distance mode or absolute arc centres (G91 / G90.1)"
    if mv.center_start[i, 0] < 0 or mv.center_start[i, 1] < 0:
        return "the arc's centre is not given by I and J (R format)"
    if i == 0:
        return "the arc's start is not set by the program"
    if math.isfinite(float(mv.block_time_s[i])):
        return "inverse-time feed (G93): a piece would take the whole arc's time"
    _start, body, _eol = program.line_text(int(mv.line[i]))
    words = _line_words(body)
    if isinstance(words, str):
        return words
    if not all(0.0 < f < 1.0 for f in fr):
        raise ValueError(f"fractions of move {i} must lie in (0, 1), got {fr}")
    text = program.text
    unit = float(mv.unit_mm[i])
    off = mv.offset_mm[i]
    c = mv.center_mm[i]
    s, e = mv.start_mm[i], mv.end_mm[i]
    r = math.hypot(s[0] - c[0], s[1] - c[1])
    a0 = math.atan2(s[1] - c[1], s[0] - c[0])
    a1 = math.atan2(e[1] - c[1], e[0] - c[0])
    two_pi = 2.0 * math.pi
    if int(mv.kind[i]) == MOVE_ARC_CCW:
        sweep = (a1 - a0) % two_pi or two_pi
    else:
        sweep = -((a0 - a1) % two_pi or two_pi)
    src_dec = [spelling(text[int(mv.word_start[i, a]):int(mv.word_end[i, a])])[0] for a in range(3)
               if mv.word_start[i, a] >= 0]
    dec = max([min_decimals, required_decimals(unit), *src_dec])
    style = 0
    m = _MOTION.search(split_gcode_comments(body)[0] or "")
    # the motion word as the line spells it (G02 / G2), else the arc's own
    gword = m.group(0).replace(" ", "").replace("\t", "") if m else ("G2" if int(mv.kind[i]) == MOVE_ARC_CW else "G3")
    feed = f" F{words['F'].strip()}" if "F" in words else ""
    texts: list[str] = []
    prev = np.array(s[:2], dtype=np.float64)  # the written start of the next piece, mm
    for k, f in enumerate(fr):
        ang = a0 + f * sweep
        p = np.array([c[0] + r * math.cos(ang), c[1] + r * math.sin(ang)])
        z = s[2] + f * (e[2] - s[2])
        xs = format_number((p[0] - off[0]) / unit, dec, style)
        ys = format_number((p[1] - off[1]) / unit, dec, style)
        zs = format_number((z - off[2]) / unit, dec, style)
        i_s = format_number((c[0] - prev[0]) / unit, dec, style)
        j_s = format_number((c[1] - prev[1]) / unit, dec, style)
        t = f"{gword} X{xs} Y{ys} Z{zs} I{i_s} J{j_s}{feed if k == 0 else ''} ({marker})"
        texts.append(t)
        prev = np.array([float(xs) * unit + off[0], float(ys) * unit + off[1]])
    rewrites: list[tuple[int, int, str]] = []
    for a in (0, 1):  # I and J, relative to the arc's new start: the last inserted point
        cs, ce = int(mv.center_start[i, a]), int(mv.center_end[i, a])
        d0, st = spelling(text[cs:ce])
        rewrites.append((cs, ce, format_number((c[a] - prev[a]) / unit, max(d0, dec), st)))
    return texts, rewrites

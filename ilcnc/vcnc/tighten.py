"""A tighter corner tolerance on some lines of a program: the line ranges, the block that sets it in the program's
dialect and units (``G64 P`` in G-code, cycle 32 ``T`` in Klartext) and the one that gives the program its own path
control back after them, its planned cost, and the G-code text with those blocks written in and checked.

``ilcnc simulate --tighter-out`` (:mod:`ilcnc.shop.corners`) writes it where the corner report suggests it;
refinement (:mod:`ilcnc.learning.refine_tolerance`, ``learning.refine.tolerance``) writes it into the refined
program as a degree of freedom that learning has not: the planner's rounding within the tolerance the program
allows, which no corrected end point takes away.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from ilcnc.outcomes import PathMode
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import FLAG_DERIVED, MOVE_RAPID, Program
from ilcnc.program.path_control import PathSetting, path_settings
from ilcnc.units import MM_PER_INCH, length_word
from ilcnc.vcnc.rounding import CornerError, tolerance_cost

__all__ = ["ROUNDING_SHARE", "TIGHTER_MARKER", "TightenedProgram", "Tightening", "TighterRange", "own_path_control_lines",
           "tightened_text", "tightening_for", "tolerance_block", "tolerance_word_mm"]

_CYCLE_32 = re.compile(r"(?i)CYCL\s+DEF\s+32\b")
#: A corner whose planner rounding is at least this share of its maximum gets a tighter tolerance (suggested by
#: the corner report, chosen by refinement).
ROUNDING_SHARE = 0.5
#: The comment that marks every line :func:`tightened_text` inserts (``simulate --tighter-out``).
TIGHTER_MARKER = "ilcnc tighter"


def _klartext(program: Program) -> bool:
    return program.dialect == "heidenhain"


def own_path_control_lines(program: Program) -> set[int]:
    """The lines on which ``program`` sets its own path control (G-code ``G61``/``G64``, Klartext cycle 32)."""
    if _klartext(program):
        return {no for no, ln in enumerate(program.text.split("\n"), 1) if _CYCLE_32.search(ln)}
    return {s.line for s in path_settings(program)}


def tolerance_block(program: Program, tol_mm: float) -> str:
    """The block(s) that set a blend tolerance in the program's dialect and units."""
    w = length_word(tol_mm, program.units)
    return f"CYCL DEF 32.0 TOLERANCE / CYCL DEF 32.1 T{w}" if _klartext(program) else f"G64 P{w}"


def tolerance_word_mm(tol_mm: float, units: str) -> float:
    """``tol_mm`` as the number a program word can carry (:func:`ilcnc.units.length_word`'s decimals), rounded down
    so that the written tolerance still bounds the rounding to at most ``tol_mm`` (at least one step), mm."""
    scale = (1e5 / MM_PER_INCH) if units == "inch" else 1e4  # steps per mm
    return max(math.floor(tol_mm * scale * (1 + 1e-12)), 1) / scale


def _own_word(program: Program, profile: MachineProfile, move: int) -> str:
    """The block(s) that give ``move`` back the path control it runs in: the program's own, else the profile's."""
    own = float(program.moves.blend_tol_mm[move])
    mode = PathMode.of_tolerance(own)
    if _klartext(program):
        if mode is PathMode.UNSET:
            return "CYCL DEF 32.1 (the machine's tolerance again)"
        return f"CYCL DEF 32.1 T{length_word(max(own, 0.0), program.units)}"
    if mode is PathMode.UNSET:
        pc = profile.planner.path_control
        if pc != "tolerance":
            return pc.upper()
        return f"G64 P{length_word(profile.planner.corner_tolerance_mm, program.units)}"
    if mode is PathMode.BOUNDED:
        return f"G64 P{length_word(own, program.units)}"
    return str(mode)


def _setting_word(st: PathSetting) -> str:
    """A G-code program's own path-control block, from its words as written (P and Q in the program's units)."""
    if st.mode is PathMode.BOUNDED:
        return f"G64 P{st.p:g}" + (f" Q{st.q:g}" if st.q is not None else "")
    if st.mode is PathMode.UNBOUNDED:
        return "G64" + (f" Q{st.q:g}" if st.q is not None else "")
    return str(st.mode)


@dataclass(frozen=True, kw_only=True)
class TighterRange:
    """Lines that get a tighter tolerance: the block to put before them and the one that restores the mode after."""

    first_line: int
    last_line: int
    before: str
    after: str
    rounding_mm: float  #: the planner's largest rounding at its corners now
    rounding_after_mm: float  #: and with the tighter tolerance (planned)

    def to_json(self) -> dict[str, Any]:
        return {"first_line": self.first_line, "last_line": self.last_line, "before": self.before,
                "after": self.after, "rounding_mm": self.rounding_mm, "rounding_after_mm": self.rounding_after_mm}

    @property
    def lines(self) -> str:
        return str(self.first_line) if self.first_line == self.last_line else f"{self.first_line}-{self.last_line}"


@dataclass(frozen=True, kw_only=True)
class Tightening:
    """A tighter corner tolerance on some line ranges and what it costs (planned, no drive run)."""

    tolerance_mm: float
    word: str
    ranges: list[TighterRange]
    moves: int
    cycle_before_s: float
    cycle_after_s: float

    @property
    def extra_pct(self) -> float:
        return 100.0 * (self.cycle_after_s / self.cycle_before_s - 1.0) if self.cycle_before_s > 0 else 0.0

    def to_json(self) -> dict[str, Any]:
        return {"tolerance_mm": self.tolerance_mm, "word": self.word, "moves": self.moves,
                "cycle_time_s": self.cycle_before_s, "cycle_time_after_s": self.cycle_after_s,
                "cycle_time_change_pct": self.extra_pct, "ranges": [r.to_json() for r in self.ranges]}

    def text(self) -> str:
        lines = ", ".join(r.lines for r in self.ranges)
        now = max(r.rounding_mm for r in self.ranges) * 1e3
        after = max(r.rounding_after_mm for r in self.ranges) * 1e3
        return (f"{self.word} on line{'s' if len(self.ranges) > 1 or '-' in lines else ''} {lines} (the program's own"
                f" mode after each) bounds the planner's rounding there to {self.tolerance_mm * 1e3:.4g} µm (now up to"
                f" {now:.2f} µm, planned {after:.2f} µm): cycle time {self.cycle_before_s:.2f} →"
                f" {self.cycle_after_s:.2f} s ({self.extra_pct:+.2f} %)")


def _ranges(program: Program, chosen: list[CornerError]) -> list[tuple[int, int, list[CornerError]]]:
    """The line of the move that ends at each chosen corner, merged where they are adjacent lines."""
    line = program.moves.line
    per = sorted(((int(line[c.vertex - 1]), c) for c in chosen), key=lambda t: t[0])
    out: list[tuple[int, int, list[CornerError]]] = []
    for ln, c in per:
        if out and ln <= out[-1][1] + 1:
            out[-1] = (out[-1][0], max(out[-1][1], ln), out[-1][2] + [c])
        else:
            out.append((ln, ln, [c]))
    return out


def tightening_for(program: Program, profile: MachineProfile, chosen: list[CornerError], tolerance_mm: float, *,
                   cycle_time_s: float | None = None) -> Tightening | None:
    """The tighter tolerance ``tolerance_mm`` on the moves that end at the ``chosen`` corners of ``program``: its
    line ranges (adjacent lines merged), the block before each and the program's own mode after it, and its
    planned cost (:func:`ilcnc.vcnc.rounding.tolerance_cost`; ``cycle_time_s``: the program's planned cycle time
    when known). None when those moves already run within it or stop there.
    """
    ranges = _ranges(program, chosen)
    mv = program.moves
    sel = np.zeros(len(mv), dtype=np.bool_)
    for first, last, _cs in ranges:
        sel |= (mv.line >= first) & (mv.line <= last) & (mv.kind != MOVE_RAPID)
    cost = tolerance_cost(program, profile, sel, tolerance_mm, cycle_before_s=cycle_time_s)
    if cost.moves == 0:
        return None
    word = tolerance_block(program, tolerance_mm)
    settings = [] if _klartext(program) else path_settings(program)
    out: list[TighterRange] = []
    for first, last, cs in ranges:
        last_move = int(np.flatnonzero(sel & (mv.line <= last))[-1])
        after = np.nan_to_num(cost.rounding_after.max_mm[[c.vertex for c in cs]])
        # the program's own setting in force there, as written (its Q too: LinuxCNC merges short collinear G1s
        # within Q, which defaults to P, so a G64 P written without the program's Q0 would change that)
        gov = [st for st in settings if st.line <= first]
        q = f" Q{gov[-1].q:g}" if gov and gov[-1].q is not None else ""
        own = _setting_word(gov[-1]) if gov else _own_word(program, profile, last_move)
        out.append(TighterRange(first_line=first, last_line=last, before=word + q, after=own,
                                rounding_mm=max(c.rounding_mm for c in cs), rounding_after_mm=float(after.max())))
    return Tightening(tolerance_mm=tolerance_mm, word=word, ranges=out, moves=cost.moves,
                      cycle_before_s=cost.cycle_before_s, cycle_after_s=cost.cycle_after_s)


@dataclass(frozen=True, kw_only=True)
class TightenedProgram:
    """A G-code program with the tighter tolerance written in (:func:`tightened_text`)."""

    text: str
    ranges: list[TighterRange]  #: the ranges written
    skipped: list[str]  #: the ranges left out, each with its reason
    cycle_time_s: float  #: the written program's planned cycle time, s


def tightened_text(program: Program, profile: MachineProfile, tightening: Tightening, *,
                   marker: str = TIGHTER_MARKER) -> TightenedProgram:
    """``program``'s text with ``tightening``'s ``G64 P`` before each range and the program's own mode after it.

    A LinuxCNC G-code program (``G64 P`` is LinuxCNC's word; grbl and Fanuc set their corner tolerance
    elsewhere) or Klartext: cycle 32 (``CYCL DEF 32.0`` / ``32.1 T``) before the range and again after it with
    the program's own ``T`` (or none: the machine's), each in numbered blocks, the blocks after them renumbered
    (:func:`ilcnc.program.insert.insert_points`). A range in which the program sets its own path control
    (``G61``/``G64``, cycle 32 on one of its lines) is left out: the block after it would undo the program's.
    Each inserted line carries the comment ``(MARKER: ...)`` (Klartext ``; MARKER: ...``; ``marker``:
    ``ilcnc tighter``, or ``ilcnc refine`` in a refined program). The result is read again and checked: the
    same moves, bit for bit, and the tolerance written where it was meant to be.

    Raises
    ------
    InputError
        Neither a LinuxCNC G-code nor a Klartext program.
    CorrectionError
        The text read again is not the program with those tolerances (a defect of ilcnc).
    """
    from ilcnc.errors import CorrectionError, InputError
    from ilcnc.program.insert import insert_points, lines_inserted, reread, same_moves
    from ilcnc.vcnc.plan import planned_duration_s, profile_moves

    klartext = _klartext(program)
    if program.dialect not in ("linuxcnc", "heidenhain"):
        raise InputError(program.path, None, f"a {program.dialect} program: the tighter tolerance is written as"
                                             " LinuxCNC's G64 P or Klartext cycle 32; insert the blocks by hand")
    settings = own_path_control_lines(program)
    lines, held = program.moves.line, (program.moves.flags & FLAG_DERIVED) != 0
    before: dict[int, list[str]] = {}
    after: dict[int, list[str]] = {}
    done: list[TighterRange] = []
    skipped: list[str] = []
    for r in tightening.ranges:
        own = sorted(ln for ln in settings if r.first_line <= ln <= r.last_line)
        if own:
            skipped.append(f"lines {r.lines}: line {own[0]} sets the program's own path control")
            continue
        if klartext and held[(lines >= r.first_line - 1) & (lines <= r.last_line + 1)].any():
            # the control holds a move until the RND / CHF / APPR / DEP after it: cycle 32 between them would
            # apply to other moves than their lines say
            skipped.append(f"lines {r.lines}: next to a rounding, chamfer, approach or departure (RND / CHF / APPR / DEP)")
            continue
        # ASCII only ("um"): the program's other bytes are written back as they were read
        why = f"{marker}: corners rounded within {tightening.tolerance_mm * 1e3:.4g} um"
        again_own = f"{marker}: the program's own path control again"
        if klartext:  # cycle 32 in two numbered blocks; the restoring pair before the block after the range
            before.setdefault(r.first_line, []).extend(f"{{N}} {b} ; {why}" for b in r.before.split(" / "))
            before.setdefault(r.last_line + 1, []).extend(
                f"{{N}} {b} ; {again_own}" for b in ("CYCL DEF 32.0 TOLERANCE", r.after.split(" (")[0]))
        else:
            before[r.first_line] = [f"{r.before} ({why})"]
            after[r.last_line] = [f"{r.after} ({again_own})"]
        done.append(r)
    if klartext:
        res = insert_points(program, {}, min_decimals=0, marker=marker, blocks=before)
        text, origin, put = res.text, res.line_origin, res.line_inserted
    else:
        text = lines_inserted(program.text, before, after)
    again = reread(program, text)
    mv, nv = program.moves, again.moves
    if not same_moves(program, again):
        raise CorrectionError(program.path, None, "the program with the tighter tolerance re-reads to other moves")
    if klartext:  # each re-read move on the original line it came from, not on an inserted one
        ok_lines = bool(np.array_equal(origin[nv.line - 1], mv.line) and not put[nv.line - 1].any())
    else:  # each original line moves down by the lines inserted before it
        shift = np.zeros(program.text.count("\n") + 3, dtype=np.int64)
        for ln in before:
            shift[ln:] += 1
        for ln in after:
            shift[ln + 1:] += 1
        ok_lines = np.array_equal(nv.line, mv.line + shift[mv.line])
    inside = np.zeros(len(mv), dtype=np.bool_)
    for r in done:
        inside |= (mv.line >= r.first_line) & (mv.line <= r.last_line) & (mv.kind != MOVE_RAPID)
    eff = profile_moves(program, profile).blend_tol_mm
    want_in = np.where(np.isnan(eff) | (eff > tightening.tolerance_mm), tightening.tolerance_mm, mv.blend_tol_mm)
    ok_in = np.array_equal(nv.blend_tol_mm[inside], want_in[inside], equal_nan=True)
    kept = ~inside & ~np.isnan(mv.blend_tol_mm)
    restored = ~inside & np.isnan(mv.blend_tol_mm)
    ok_out = np.array_equal(nv.blend_tol_mm[kept], mv.blend_tol_mm[kept]) and bool(np.all(
        np.isnan(nv.blend_tol_mm[restored]) | (nv.blend_tol_mm[restored] == profile.planner.corner_tolerance_mm)
        | (profile.planner.path_control != "tolerance")))
    if not (ok_lines and ok_in and ok_out):
        raise CorrectionError(program.path, None, "the program with the tighter tolerance re-reads to other path"
                                                  " control than was meant")
    return TightenedProgram(text=text, ranges=done, skipped=skipped, cycle_time_s=planned_duration_s(again, profile))

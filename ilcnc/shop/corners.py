"""The worst corners of a run, said in the program's words: how much of each is the planner's rounding within the
tolerance the program allowed, how much the drives' lag, and what a tighter tolerance there would cost.

``ilcnc simulate`` and ``ilcnc learn`` print it after their figures (``--corners N``, ``--target-um``). The
numerics are :mod:`ilcnc.vcnc.rounding`; here they meet the program: its dialect (``G64 P`` in G-code, cycle 32
``T`` in Klartext), its units (an inch program's words in inches) and its line numbers.

The suggestion: where the planner's rounding is at least half of a corner's maximum, the program's own
tolerance is what is left, and learning cannot take it away (a corrected end point bent outwards is a sharper
corner, which the planner then takes slower: docs/learning.md, the cycle-time budget). A tighter tolerance on
the move that ends at that corner bounds the rounding; its cost is measured by planning the program with it
(:func:`ilcnc.vcnc.rounding.tolerance_cost`, no drive run).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ilcnc.outcomes import PathMode
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import MOVE_RAPID, Program
from ilcnc.units import MM_PER_INCH, length_word
from ilcnc.vcnc.rounding import (
    CornerError,
    VertexMax,
    corner_errors,
    planner_rounding,
    tolerance_cost,
    vertex_tolerances,
)

__all__ = [
    "DEFAULT_CORNERS",
    "ROUNDING_SHARE",
    "CornerReport",
    "Tightening",
    "TighterRange",
    "corner_report",
    "learned_corner_report",
    "setting_text",
]

#: How many corners the report lists by default.
DEFAULT_CORNERS = 5
#: A corner whose planner rounding is at least this share of its maximum gets a tighter tolerance suggested.
ROUNDING_SHARE = 0.5


def _klartext(program: Program) -> bool:
    return program.dialect == "heidenhain"


def _set_word(program: Program, tol_mm: float) -> str:
    """The block(s) that set a blend tolerance in the program's dialect and units."""
    w = length_word(tol_mm, program.units)
    return f"CYCL DEF 32.0 TOLERANCE / CYCL DEF 32.1 T{w}" if _klartext(program) else f"G64 P{w}"


def _word_mm(tol_mm: float, units: str) -> float:
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


def setting_text(program: Program, profile: MachineProfile, c: CornerError, *, short: bool = False) -> str:
    """What the corner's tolerance is and who set it, in the program's words (``short``: for a table column)."""
    if math.isnan(c.tolerance_mm):
        return "no blend" if short else "no blend (next to a rapid or at the path's end)"
    if c.tolerance_mm == 0.0:
        how = "cycle 32 T0" if _klartext(program) and c.set_by_program else str(c.mode)
        return how if short else f"an exact stop ({how})"
    word = f"cycle 32 T{length_word(c.tolerance_mm, program.units)}" if _klartext(program) else \
        _set_word(program, c.tolerance_mm)
    quarter = f"{c.tolerance_mm:g} mm, a quarter of the move"
    if not c.set_by_program:
        pc = profile.planner.path_control
        if pc == "tolerance":
            return f"{word} (profile)" if short else \
                f"{word} (the profile's planner.corner_tolerance_mm; the program sets none)"
        return f"{quarter} (profile)" if short else f"{quarter} (the profile's planner.path_control {pc})"
    if c.mode is PathMode.UNBOUNDED:
        return f"{quarter} ({'cycle 32' if _klartext(program) else 'G64'} without a tolerance)"
    if c.quarter:
        return f"{quarter} (the program's tolerance is larger)"
    return f"{word} (program)" if short else f"{word} (the program's)"


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


@dataclass(kw_only=True)
class CornerReport:
    """The worst corners of a run on the drawing ``program`` (the lines are the drawing's)."""

    program: str
    units: str
    dialect: str
    corners: list[CornerError]
    settings: list[str]
    short: list[str]
    tightening: Tightening | None = None
    notes: list[str] = field(default_factory=list)
    judged: str = ""  #: what run was judged, when it is not the program as given (learn's output)

    def summary(self) -> str:
        """One line on the worst corner."""
        if not self.corners:
            return "no cutting move: no corner to report"
        c, s = self.corners[0], self.settings[0]
        return (f"the cutting max {c.max_mm * 1e3:.2f} µm at line {c.line}: {c.rounding_mm * 1e3:.2f} µm is the"
                f" planner's rounding within {s}, {c.rest_mm * 1e3:.2f} µm the drives' lag and the rest")

    def rows(self) -> list[tuple[str, ...]]:
        """Table rows: lines, max, rounding, rest (µm), tolerance."""
        return [(f"{c.first_line}-{c.last_line}" if c.first_line != c.last_line else str(c.first_line),
                 str(c.line), f"{c.max_mm * 1e3:.2f}", f"{c.rounding_mm * 1e3:.2f}", f"{c.rest_mm * 1e3:.2f}", s)
                for c, s in zip(self.corners, self.short, strict=True)]

    def to_json(self) -> dict[str, Any]:
        return {
            "program": self.program,
            "judged": self.judged,
            "summary": self.summary(),
            "corners": [{"lines": [c.first_line, c.last_line], "line": c.line, "vertex": c.vertex,
                         "max_mm": c.max_mm, "rounding_mm": c.rounding_mm, "rest_mm": c.rest_mm,
                         "tolerance_mm": None if math.isnan(c.tolerance_mm) else c.tolerance_mm,
                         "path_mode": str(c.mode), "set_by": "program" if c.set_by_program else "profile",
                         "setting": s} for c, s in zip(self.corners, self.settings, strict=True)],
            "tighter": None if self.tightening is None else self.tightening.to_json(),
            "notes": self.notes,
        }


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


def corner_report(program: Program, profile: MachineProfile, vertices: VertexMax, *, top: int = DEFAULT_CORNERS,
                  target_um: float | None = None, cycle_time_s: float | None = None) -> CornerReport:
    """The report of a run whose cutting error near each end point of ``program`` (the drawing) is ``vertices``.

    Parameters
    ----------
    program : Program
        The drawing the run was judged against (its lines are the report's).
    profile : MachineProfile
        The run's profile.
    vertices : VertexMax
        The run's largest cutting error near each end point (:mod:`ilcnc.vcnc.rounding`).
    top : int
        Corners listed.
    target_um : float, optional
        The rounding a tighter tolerance should bound the corners to, µm (default: half their tolerance).
    cycle_time_s : float, optional
        The drawing's planned cycle time when known, s (planned here otherwise).
    """
    rounding = planner_rounding(program, profile)
    tols = vertex_tolerances(program, profile)
    floor = 0.5 * profile.machine.resolution_mm  # below half a resolution step a corner is no finding
    corners = [c for c in corner_errors(program, vertices, rounding, tols, top=top) if c.max_mm >= floor]
    rep = CornerReport(program=str(program.path), units=program.units, dialect=program.dialect, corners=corners,
                       settings=[setting_text(program, profile, c) for c in corners],
                       short=[setting_text(program, profile, c, short=True) for c in corners])
    blend = [c for c in corners if c.vertex > 0 and math.isfinite(c.tolerance_mm) and c.tolerance_mm > 0]
    mostly = [c for c in blend if c.rounding_share >= ROUNDING_SHARE]
    if not corners:
        return rep
    if not mostly:
        rep.notes.append(f"no listed corner's error is mostly ({ROUNDING_SHARE:.0%} or more) the planner's rounding:"
                         " a tighter tolerance would not lower it much")
        return rep
    target = _word_mm(target_um * 1e-3 if target_um is not None else 0.5 * min(c.tolerance_mm for c in mostly),
                      program.units)
    chosen = [c for c in mostly if c.rounding_mm > target]
    if not chosen:
        rep.notes.append(f"the planner's rounding at the listed corners is already within {target * 1e3:g} µm")
        return rep
    ranges = _ranges(program, chosen)
    mv = program.moves
    sel = np.zeros(len(mv), dtype=np.bool_)
    for first, last, _cs in ranges:
        sel |= (mv.line >= first) & (mv.line <= last) & (mv.kind != MOVE_RAPID)
    cost = tolerance_cost(program, profile, sel, target, cycle_before_s=cycle_time_s)
    if cost.moves == 0:
        rep.notes.append(f"the moves at these corners already run within {target * 1e3:g} µm or stop there")
        return rep
    word = _set_word(program, target)
    out: list[TighterRange] = []
    for first, last, cs in ranges:
        last_move = int(np.flatnonzero(sel & (mv.line <= last))[-1])
        after = np.nan_to_num(cost.rounding_after.max_mm[[c.vertex for c in cs]])
        out.append(TighterRange(first_line=first, last_line=last, before=word,
                                after=_own_word(program, profile, last_move),
                                rounding_mm=max(c.rounding_mm for c in cs), rounding_after_mm=float(after.max())))
    rep.tightening = Tightening(tolerance_mm=target, word=word, ranges=out, moves=cost.moves,
                                cycle_before_s=cost.cycle_before_s, cycle_after_s=cost.cycle_after_s)
    return rep


def learned_corner_report(state_dir: Path, output: Path, profile: MachineProfile, *, top: int = DEFAULT_CORNERS,
                          target_um: float | None = None) -> CornerReport:
    """The corner report of a virtual learning run's output, judged against the run's original (the drawing in
    its state): one more virtual run of the output (``learn`` prints it after its figures)."""
    from ilcnc.program import read_program
    from ilcnc.shop.state import LearnState
    from ilcnc.vcnc.run import simulate_figures

    state = LearnState.load(state_dir)
    units = profile.machine.units
    original = read_program(state.file(state.part["file"]), default_units=units, data=state.read_original_bytes())
    prog = read_program(output, default_units=units)
    vm = VertexMax.empty(len(original.moves))
    run = simulate_figures(prog, profile, against=original, vertices=vm)
    rep = corner_report(original, profile, vm, top=top, target_um=target_um)
    rep.judged = (f"{Path(output).name} on the virtual CNC, judged against the original's path (cutting max"
                  f" {run.stats.max_mm * 1e3:.2f} µm); the lines are the original's")
    return rep

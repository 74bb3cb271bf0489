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

from ilcnc._jit import PLAN_ONLY_WEIGHT, kernels_for
from ilcnc.outcomes import PathMode
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import MOVE_RAPID, Program
from ilcnc.shop.linuxcnc_prepare import PathSetting, path_settings
from ilcnc.units import MM_PER_INCH, length_word
from ilcnc.vcnc.plan_base import nominal_samples
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
    "TIGHTER_MARKER",
    "CornerReport",
    "TightenedProgram",
    "Tightening",
    "TighterRange",
    "corner_report",
    "learned_corner_report",
    "setting_text",
    "tightened_text",
    "write_tightened",
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


def _setting_word(st: PathSetting) -> str:
    """A G-code program's own path-control block, from its words as written (P and Q in the program's units)."""
    if st.mode is PathMode.BOUNDED:
        return f"G64 P{st.p:g}" + (f" Q{st.q:g}" if st.q is not None else "")
    if st.mode is PathMode.UNBOUNDED:
        return "G64" + (f" Q{st.q:g}" if st.q is not None else "")
    return str(st.mode)


def setting_text(program: Program, profile: MachineProfile, c: CornerError, *, short: bool = False) -> str:
    """What the corner's tolerance is and who set it, in the program's words (``short``: for a table column)."""
    if math.isnan(c.tolerance_mm):
        return "no blend" if short else "no blend (next to a rapid or at the path's end)"
    if c.tolerance_mm == 0.0:
        how = ("cycle 32 T0" if _klartext(program) else str(c.mode)) if c.set_by_program else \
            f"the profile's planner.path_control {profile.planner.path_control}"
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
    written: dict[str, Any] | None = None  #: what ``--tighter-out`` wrote

    def add_written(self, path: Path, done: TightenedProgram | None) -> None:
        """Say what :func:`write_tightened` wrote to ``path`` (``done`` None or without ranges: nothing)."""
        if done is None or not done.ranges:
            why = "; ".join(done.skipped) if done is not None else "no tighter tolerance to write"
            self.notes.append(f"{path}: not written ({why})")
            self.written = {"path": None, "skipped": done.skipped if done is not None else []}
            return
        lines = ", ".join(r.lines for r in done.ranges)
        self.notes.append(f"wrote {path}: {done.ranges[0].before} on lines {lines}, planned cycle time"
                          f" {done.cycle_time_s:.2f} s" + "".join(f"; left out {k}" for k in done.skipped))
        self.written = {"path": str(path), "ranges": [r.to_json() for r in done.ranges], "skipped": done.skipped,
                        "cycle_time_s": done.cycle_time_s}

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
            "tighter_out": self.written,
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
    # the drawing planned (no drive): as Python on a small program, like the run (ilcnc._jit.kernels_for)
    with kernels_for(nominal_samples(program.moves, profile), PLAN_ONLY_WEIGHT):
        return _corner_report(program, profile, vertices, top=top, target_um=target_um, cycle_time_s=cycle_time_s)


def _corner_report(program: Program, profile: MachineProfile, vertices: VertexMax, *, top: int,
                   target_um: float | None, cycle_time_s: float | None) -> CornerReport:
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
    rep.tightening = Tightening(tolerance_mm=target, word=word, ranges=out, moves=cost.moves,
                                cycle_before_s=cost.cycle_before_s, cycle_after_s=cost.cycle_after_s)
    if program.dialect in ("grbl", "fanuc"):
        rep.notes.append(f"G64 P is LinuxCNC's word: a {program.dialect} control sets its corner tolerance in its"
                         " settings, not per line (grbl: $11 junction deviation); the planned cost assumes a control that"
                         " rounds those corners within it")
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


#: The comment that marks every line :func:`tightened_text` inserts.
TIGHTER_MARKER = "ilcnc tighter"


@dataclass(frozen=True, kw_only=True)
class TightenedProgram:
    """A G-code program with the tighter tolerance written in (:func:`tightened_text`)."""

    text: str
    ranges: list[TighterRange]  #: the ranges written
    skipped: list[str]  #: the ranges left out, each with its reason
    cycle_time_s: float  #: the written program's planned cycle time, s


def tightened_text(program: Program, profile: MachineProfile, tightening: Tightening) -> TightenedProgram:
    """``program``'s text with ``tightening``'s ``G64 P`` before each range and the program's own mode after it.

    Only a LinuxCNC G-code program: ``G64 P`` is LinuxCNC's word (grbl and Fanuc set their corner tolerance
    elsewhere), and a Klartext block inserted would renumber the blocks after it. A range in which the program
    sets its own path control (``G61``/``G64`` on one of its lines) is left out: the block after it would undo
    the program's. Each inserted line carries the comment ``(ilcnc tighter ...)``. The result is read again and
    checked: the same moves, bit for bit, and the tolerance written where it was meant to be.

    Raises
    ------
    InputError
        Not a LinuxCNC G-code program.
    CorrectionError
        The text read again is not the program with those tolerances (a defect of ilcnc).
    """
    from ilcnc.errors import CorrectionError, InputError
    from ilcnc.program.insert import lines_inserted, reread, same_moves
    from ilcnc.vcnc.plan import planned_duration_s, profile_moves

    if program.dialect != "linuxcnc":
        raise InputError(program.path, None, f"a {program.dialect} program: the tighter tolerance is written as"
                                             " LinuxCNC's G64 P; insert the blocks by hand")
    settings = {s.line for s in path_settings(program)}
    before: dict[int, list[str]] = {}
    after: dict[int, list[str]] = {}
    done: list[TighterRange] = []
    skipped: list[str] = []
    for r in tightening.ranges:
        own = sorted(ln for ln in settings if r.first_line <= ln <= r.last_line)
        if own:
            skipped.append(f"lines {r.lines}: line {own[0]} sets the program's own path control")
            continue
        # ASCII only ("um"): the program's other bytes are written back as they were read
        before[r.first_line] = [f"{r.before} ({TIGHTER_MARKER}: corners rounded within"
                                f" {tightening.tolerance_mm * 1e3:.4g} um)"]
        after[r.last_line] = [f"{r.after} ({TIGHTER_MARKER}: the program's own path control again)"]
        done.append(r)
    text = lines_inserted(program.text, before, after)
    again = reread(program, text)
    mv, nv = program.moves, again.moves
    if not same_moves(program, again):
        raise CorrectionError(program.path, None, "the program with the tighter tolerance re-reads to other moves")
    # the re-read lines: each original line moves down by the lines inserted before it
    shift = np.zeros(program.text.count("\n") + 3, dtype=np.int64)
    for ln in before:
        shift[ln:] += 1
    for ln in after:
        shift[ln + 1:] += 1
    inside = np.zeros(len(mv), dtype=np.bool_)
    for r in done:
        inside |= (mv.line >= r.first_line) & (mv.line <= r.last_line) & (mv.kind != MOVE_RAPID)
    eff = profile_moves(program, profile).blend_tol_mm
    want_in = np.where(np.isnan(eff) | (eff > tightening.tolerance_mm), tightening.tolerance_mm, mv.blend_tol_mm)
    ok_lines = np.array_equal(nv.line, mv.line + shift[mv.line])
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



def write_tightened(program: Program, profile: MachineProfile, report: CornerReport | None, out: Path, *,
                    drawing: Program | None = None, protect: tuple[Path, ...] = ()) -> TightenedProgram | None:
    """``simulate --tighter-out``: write ``program`` with the report's tighter tolerance (:func:`tightened_text`).

    ``drawing`` is the program the report was judged against, when not ``program`` itself: its lines must be
    ``program``'s. Returns None, and writes nothing, when the report suggests no tighter tolerance (its notes
    say why).

    Raises
    ------
    UsageError
        No report (``--corners 0``), or a report on other lines than ``program``'s.
    """
    from ilcnc.errors import UsageError
    from ilcnc.fileio import write_atomic

    if report is None:
        raise UsageError("--tighter-out", "needs the corner report: give --corners 1 or more")
    if drawing is not None and not np.array_equal(drawing.moves.line, program.moves.line):
        raise UsageError("--tighter-out", f"writes {program.path.name} on the report's lines, which are"
                                          f" {drawing.path.name}'s: a refined output's lines are not the original's")
    if report.tightening is None:
        return None
    done = tightened_text(program, profile, report.tightening)
    if done.ranges:
        write_atomic(out, done.text.encode("latin-1"), protect=(program.path, *protect))
    return done

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
from ilcnc.program.model import Program
from ilcnc.units import length_word
from ilcnc.vcnc.plan_base import nominal_samples
from ilcnc.vcnc.rounding import (
    CornerError,
    VertexMax,
    corner_errors,
    planner_rounding,
    vertex_tolerances,
)
from ilcnc.vcnc.tighten import (
    ROUNDING_SHARE,
    TightenedProgram,
    Tightening,
    tightened_text,
    tightening_for,
    tolerance_block,
    tolerance_word_mm,
)

__all__ = ["DEFAULT_CORNERS", "CornerReport", "corner_report", "learned_corner_report", "setting_text",
           "write_tightened"]

#: How many corners the report lists by default.
DEFAULT_CORNERS = 5


def _klartext(program: Program) -> bool:
    return program.dialect == "heidenhain"


def setting_text(program: Program, profile: MachineProfile, c: CornerError, *, short: bool = False) -> str:
    """What the corner's tolerance is and who set it, in the program's words (``short``: for a table column)."""
    if math.isnan(c.tolerance_mm):
        return "no blend" if short else "no blend (next to a rapid or at the path's end)"
    if c.tolerance_mm == 0.0:
        how = ("cycle 32 T0" if _klartext(program) else str(c.mode)) if c.set_by_program else \
            f"the profile's planner.path_control {profile.planner.path_control}"
        return how if short else f"an exact stop ({how})"
    word = f"cycle 32 T{length_word(c.tolerance_mm, program.units)}" if _klartext(program) else \
        tolerance_block(program, c.tolerance_mm)
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
    target = tolerance_word_mm(target_um * 1e-3 if target_um is not None else 0.5 * min(c.tolerance_mm for c in mostly),
                      program.units)
    chosen = [c for c in mostly if c.rounding_mm > target]
    if not chosen:
        rep.notes.append(f"the planner's rounding at the listed corners is already within {target * 1e3:g} µm")
        return rep
    rep.tightening = tightening_for(program, profile, chosen, target, cycle_time_s=cycle_time_s)
    if rep.tightening is None:
        rep.notes.append(f"the moves at these corners already run within {target * 1e3:g} µm or stop there")
        return rep
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


# Names that moved with the tighter tolerance (learning.refine.tolerance needs them below the shop layer): the
# old import path keeps working for one release, with a DeprecationWarning naming the new one.
_MOVED_NAMES: dict[str, str] = {"TIGHTER_MARKER": "ilcnc.vcnc.tighten", "TighterRange": "ilcnc.vcnc.tighten"}


def __getattr__(name: str) -> object:
    where = _MOVED_NAMES.get(name)
    if where is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib
    import warnings

    warnings.warn(f"{__name__}.{name} moved to {where}.{name}; import it from there", DeprecationWarning,
                  stacklevel=2)
    return getattr(importlib.import_module(where), name)

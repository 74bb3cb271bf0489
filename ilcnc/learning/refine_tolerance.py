"""Refinement's third handle: a tighter corner tolerance where the first run's error is the planner's rounding.

Points and settles give learning end points and stops where it had none. At a corner between two feeds the
planner rounds the path within the tolerance the program allows (its ``G64 P``, else the profile's
``planner.corner_tolerance_mm``) before any drive has moved; learning removes the drives' lag there but not
that rounding (a corner bent outwards is a sharper corner, which the planner takes slower). When the cutting
maximum is to fall by half, every corner's rounding must fall below about half of the first run's maximum.

:func:`plan_tolerance` reads the first run (its contour error per sample, as :func:`ilcnc.learning.refine
.plan_refinement` does), splits the error near every end point into the planner's rounding and the rest
(:func:`ilcnc.vcnc.rounding.corner_errors`), and chooses the corners

* where two cutting feeds meet and the planner blends (not where it stops, nor next to a rapid: air moves
  are never touched);
* whose error after learning would still be above the **target**, half the first run's cutting maximum
  (:data:`TARGET_SHARE`: the issue's −50 %): its rounding plus the lag it has, at most as much lag as the
  target leaves room for beside the tighter tolerance, within :data:`MARGIN` of the target (learning takes
  the lag down; a corner whose rounding and that lag are well within the target needs no tighter tolerance);
* whose error is mostly (:data:`ilcnc.vcnc.tighten.ROUNDING_SHARE`, half or more) the planner's rounding:
  where it is mostly lag, learning takes it away;
* whose rounding is above the tighter tolerance, ``tolerance_share`` (0.6) of the target: the rest of the
  target is left for the lag learning leaves there (never below twice the machine's resolution: a tolerance
  the positions cannot resolve);
* and on whose line the program does not set its own path control (a block after it would undo the
  program's, as ``simulate --tighter-out`` leaves such a range out).

The largest errors first, as many as the planned cost allows within ``tolerance_budget_pct`` of the
original's planned cycle time (:func:`ilcnc.vcnc.rounding.tolerance_cost`, no drive run). They are written
into the refined program by :func:`ilcnc.vcnc.tighten.tightened_text` (the ``--tighter-out`` writer and its
check): ``G64 P`` before the move that ends at the corner (before its inserted points), the program's own
mode after it, both marked ``ilcnc refine``. The blocks are not moves: every iteration's rewrite carries
them as they are, and learning corrects the end points within the tighter tolerance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.contour.air import MOVE_CUT
from ilcnc.errors import InputError
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import FLAG_DERIVED, Program
from ilcnc.vcnc.rounding import CornerError, VertexMax, corner_errors, planner_rounding, vertex_tolerances
from ilcnc.vcnc.tighten import (
    ROUNDING_SHARE,
    TightenedProgram,
    Tightening,
    own_path_control_lines,
    tightened_text,
    tightening_for,
    tolerance_word_mm,
)
from ilcnc.wording import plural

__all__ = ["FLOOR_STEPS", "MARGIN", "TARGET_SHARE", "ToleranceRefinement", "plan_tolerance", "write_tolerance"]

#: The cutting maximum refinement aims at, as a share of the first run's (issue 18: −50 %).
TARGET_SHARE = 0.5
#: A corner is counted when its error after learning would come within this share of the target: learning does
#: not hold every corner at its first-run error (on locket_outside, corners at 8.5-8.7 µm next to corrected ones
#: ended at 8.6-8.9 µm, above the 8.73 µm target).
MARGIN = 0.9
#: The tighter tolerance is never below this many resolution steps.
FLOOR_STEPS = 2.0


@dataclass(slots=True)
class ToleranceRefinement:
    """The tighter tolerance of a refinement (``learning.refine.tolerance``, :func:`plan_tolerance`).

    Attributes
    ----------
    tolerance_mm : float
        The tighter tolerance, mm (NaN: none chosen).
    target_mm : float
        Half the first run's cutting maximum, mm: the corners above it are the candidates.
    corners : list of CornerError
        The chosen corners, largest first (the original's vertices and lines).
    tightening : Tightening or None
        Their line ranges on the original and the planned cost (None: nothing to tighten).
    written : TightenedProgram or None
        What was written into the refined program (its lines are the refined program's).
    passed : dict of str to int
        Corners above the target left alone, by reason.
    spent_s : float
        Planned cycle time the written tolerance adds to the refined program, s (counted inside
        ``learning.cycle_budget_pct``).
    remark : str
        Why no corner was looked at (a refinement from a machine log), or empty.
    """

    tolerance_mm: float = math.nan
    target_mm: float = math.nan
    corners: list[CornerError] = field(default_factory=list)
    tightening: Tightening | None = None
    written: TightenedProgram | None = None
    passed: dict[str, int] = field(default_factory=dict)
    spent_s: float = 0.0
    remark: str = ""

    @property
    def n_lines(self) -> int:
        """Lines the tolerance inserts (a block before each range, one after)."""
        return 2 * len(self.tightening.ranges) if self.tightening is not None else 0

    def _pass(self, reason: str, n: int = 1) -> None:
        if n > 0:
            self.passed[reason] = self.passed.get(reason, 0) + n

    def summary(self) -> dict[str, Any]:
        t = self.tightening
        w = self.written
        return {"corners": len(self.corners), "tolerance_mm": None if math.isnan(self.tolerance_mm) else self.tolerance_mm,
                "target_mm": None if math.isnan(self.target_mm) else self.target_mm,
                "lines": [c.first_line if c.first_line == c.last_line else [c.first_line, c.last_line]
                          for c in self.corners],
                "ranges": [r.to_json() for r in t.ranges] if t is not None else [],
                "inserted_lines": 2 * len(w.ranges) if w is not None else 0,
                "planned_cycle_change_pct": t.extra_pct if t is not None else 0.0, "spent_s": self.spent_s,
                "passed": dict(self.passed), "remark": self.remark}

    def notes(self) -> list[str]:
        """One line each: what was tightened where and what it costs, what was left alone and why."""
        out: list[str] = [f"refine: no tighter tolerance ({self.remark})"] if self.remark else []
        t = self.tightening
        if t is not None and self.corners:
            lines = ", ".join(r.lines for r in t.ranges[:8]) + (", ..." if len(t.ranges) > 8 else "")
            now = max(r.rounding_mm for r in t.ranges) * 1e3
            after = max(r.rounding_after_mm for r in t.ranges) * 1e3
            where = "lines" if len(t.ranges) > 1 or "-" in lines else "line"
            out.append(f"refined: {t.word} at {plural(len(self.corners), 'corner')} whose first-run error is mostly"
                       f" the planner's rounding ({where} {lines}; the program's own path control after each): rounding"
                       f" up to {now:.2f} -> {after:.2f} µm planned, cycle time {t.extra_pct:+.2f} % planned")
        for reason, n in sorted(self.passed.items()):
            out.append(f"refine: {plural(n, 'corner')} above half the first run's max left alone ({reason})")
        for why in self.written.skipped if self.written is not None else []:
            out.append(f"refine: no tighter tolerance on {why}")
        return out


def _vertex_max(n_moves: int, dist_mm: NDArray[np.float64], seg: NDArray[np.int64], u: NDArray[np.float64],
                classes: NDArray[np.int8]) -> VertexMax:
    """The first run's largest cutting error near each end point (samples on a cutting move)."""
    vm = VertexMax.empty(n_moves)
    sg = np.asarray(seg, dtype=np.int64)
    cutting = (sg >= 0) & np.isfinite(dist_mm) & (classes[np.maximum(sg, 0)] == MOVE_CUT)
    vm.add(np.asarray(dist_mm, dtype=np.float64), np.asarray(u, dtype=np.float64), sg, cutting)
    return vm


def plan_tolerance(program: Program, profile: MachineProfile, *, dist_mm: NDArray[np.float64],
                   seg: NDArray[np.int64], u: NDArray[np.float64], classes: NDArray[np.int8], cycle_time_s: float,
                   lines_used: int = 0) -> ToleranceRefinement:
    """Choose the corners of ``program`` that get a tighter tolerance, from its first run (module docstring).

    Parameters
    ----------
    program : Program
        The original program.
    profile : MachineProfile
        ``learning.refine`` settings (``tolerance_share``, ``tolerance_budget_pct``, ``max_lines``), the planner.
    dist_mm, seg, u : ndarray (N,)
        The first run's contour error per sample (mm), the move of its foot point (-1: none) and the path
        parameter (move + fraction).
    classes : ndarray (M,) int8
        Class of every move (:func:`ilcnc.contour.air.move_classes`): only cutting corners are chosen.
    cycle_time_s : float
        The original's planned cycle time, s (the budget is a share of it).
    lines_used : int
        Lines the points and settles insert (with these, at most ``learning.refine.max_lines``).

    Raises
    ------
    InputError
        The points, settles and these blocks together exceed ``learning.refine.max_lines``.
    """
    cfg = profile.learning.refine
    out = ToleranceRefinement()
    m = len(program.moves)
    if m < 2:
        return out
    vm = _vertex_max(m, dist_mm, seg, u, classes)
    first_max = vm.overall_mm
    if not math.isfinite(first_max):
        return out
    out.target_mm = TARGET_SHARE * first_max
    rounding = planner_rounding(program, profile)
    tols = vertex_tolerances(program, profile)
    floor = FLOOR_STEPS * profile.machine.resolution_mm
    out.tolerance_mm = tolerance_word_mm(max(cfg.tolerance_share * out.target_mm, floor), program.units)
    # after learning a corner keeps its rounding and at most the lag the target leaves room for
    room = max(out.target_mm - out.tolerance_mm, 0.0)
    above = [c for c in corner_errors(program, vm, rounding, tols, top=m + 1)
             if c.rounding_mm + min(max(c.rest_mm, 0.0), room) > MARGIN * out.target_mm]
    blend = [c for c in above if c.vertex > 0 and math.isfinite(c.tolerance_mm) and c.tolerance_mm > 0]
    out._pass("no blend there: the path stops or meets a rapid", len(above) - len(blend))
    mostly = [c for c in blend if c.rounding_share >= ROUNDING_SHARE]
    out._pass("mostly the drives' lag, which learning takes", len(blend) - len(mostly))
    if not mostly:
        return out
    if program.dialect not in ("linuxcnc", "heidenhain"):
        out._pass(f"a {program.dialect} program: {program.dialect} sets its corner tolerance in the control's"
                  " settings, not per line (the tighter tolerance is LinuxCNC's G64 P or Klartext cycle 32)", len(mostly))
        return out
    chosen = [c for c in mostly if c.rounding_mm > out.tolerance_mm]
    out._pass(f"rounding already within {out.tolerance_mm * 1e3:g} µm", len(mostly) - len(chosen))
    own = own_path_control_lines(program)
    line = program.moves.line
    free = [c for c in chosen if int(line[c.vertex - 1]) not in own]
    out._pass("the program sets its own path control on that line", len(chosen) - len(free))
    if program.dialect == "heidenhain":  # the control holds a move until the RND / CHF / APPR / DEP after it
        held = {int(x) for x in line[(program.moves.flags & FLAG_DERIVED) != 0].tolist()}
        near = [c for c in free if not held & {int(line[c.vertex - 1]) + d for d in (-1, 0, 1)}]
        out._pass("next to a rounding, chamfer, approach or departure (RND / CHF / APPR / DEP)", len(free) - len(near))
        free = near
    if not free:
        return out
    budget_s = cfg.tolerance_budget_pct / 100.0 * cycle_time_s

    def tight(k: int) -> Tightening | None:
        return tightening_for(program, profile, free[:k], out.tolerance_mm, cycle_time_s=cycle_time_s)

    best = tight(len(free))
    k = len(free)
    if best is not None and best.cycle_after_s - best.cycle_before_s > budget_s:
        # the largest errors first: the longest prefix within the budget (its cost grows with the prefix)
        lo, hi, best = 0, len(free), None
        while hi - lo > 1:
            mid = (lo + hi) // 2
            t = tight(mid)
            if t is None or t.cycle_after_s - t.cycle_before_s <= budget_s:
                lo, best = mid, t
            else:
                hi = mid
        k = lo
        out._pass("beyond learning.refine.tolerance_budget_pct", len(free) - k)
    if best is None or k == 0:
        return out
    out.corners, out.tightening = free[:k], best
    if lines_used + out.n_lines > cfg.max_lines:
        raise InputError(program.path, None, f"refinement would insert {lines_used + out.n_lines} lines, more than"
                         f" learning.refine.max_lines = {cfg.max_lines}: raise it, or refine less"
                         " (learning.refine.tolerance_budget_pct, corner_angle_deg, points_per_side)")
    return out


def write_tolerance(refined: Program, line_origin: NDArray[np.int32], line_inserted: NDArray[np.bool_],
                    profile: MachineProfile, plan: ToleranceRefinement) -> str:
    """The refined program's text with ``plan``'s tighter tolerance written in (:func:`tightened_text`, marked
    ``ilcnc refine``; read back and checked there). ``line_origin`` / ``line_inserted`` map each line of
    ``refined`` to the original's (:class:`ilcnc.program.insert.InsertResult`): the block goes before the
    first line of the range's first move (before its inserted points), the restoring one after its last."""
    from ilcnc.program.insert import MARKER

    t = plan.tightening
    if t is None:
        return refined.text
    ranges = []
    for r in t.ranges:
        first = int(np.flatnonzero(line_origin == r.first_line)[0]) + 1
        last = int(np.flatnonzero((line_origin == r.last_line) & ~line_inserted)[0]) + 1
        ranges.append(replace(r, first_line=first, last_line=last))
    done = tightened_text(refined, profile, replace(t, ranges=ranges), marker=MARKER)
    plan.written = done
    return done.text

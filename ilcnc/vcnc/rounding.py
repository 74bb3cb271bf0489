"""How much of the error at each corner is the planner's own rounding, and what a tighter tolerance costs.

The filter planner (:mod:`ilcnc.vcnc.plan`) takes each corner at the speed that rounds it by its corner
tolerance: the program's ``G64 P`` or cycle 32 ``T``, else the profile's ``planner.corner_tolerance_mm``
(:func:`ilcnc.vcnc.plan_corners.junction_tolerances`). The reference it commands is then off the drawing by
up to that tolerance before any drive has moved. The cutting-move error at a corner is split here into

* **planner rounding**: the largest distance of the planned reference of the drawing (the program as drawn,
  planned alone, no drive) from the drawing, over the cutting samples near that corner;
* **the rest**: the actual path's largest distance there minus that rounding. This is what the drives'
  lag (and any error source the profile adds) leaves. Learning can reduce it. The rounding is what the
  program allowed: only a tighter tolerance takes it away.

"Near a corner" is the path parameter of a sample's nearest point on the drawing rounded to the nearest end
point: vertex ``e`` is the end of move ``e − 1`` and the start of move ``e`` (0 the start of the path, M its
end). The largest error along a move is counted at the end point nearer to it. The two maxima of a vertex
need not be at the same instant: the drive's error at a corner peaks after the reference's.

:func:`tolerance_cost` plans (no drive) the program with a tighter tolerance on chosen moves and gives the
cycle time and the rounding it would have: what ``G64 P`` / cycle 32 there would cost.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.contour.air import air_above_mm, cutting_samples, profile_move_classes
from ilcnc.outcomes import PathMode
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import MOVE_RAPID, Program
from ilcnc.vcnc.plan import (
    DEFAULT_CHUNK_SAMPLES,
    plan_chunks,
    planned_duration_s,
    profile_moves,
    vertex_tolerances_mm,
)

__all__ = ["CornerError", "ToleranceCost", "VertexMax", "VertexTolerances", "corner_errors", "planner_rounding",
           "tolerance_cost", "vertex_tolerances"]


@dataclass(slots=True)
class VertexMax:
    """The largest cutting-move distance from the drawing near each end point of its moves, added chunk by chunk.

    Attributes
    ----------
    max_mm : ndarray (M + 1,)
        Largest distance of a cutting sample whose nearest point on the drawing is nearest to vertex ``e``, mm
        (NaN: no such sample).
    move : ndarray (M + 1,) int64
        The move of the drawing that sample's nearest point is on (-1: none).
    """

    max_mm: NDArray[np.float64]
    move: NDArray[np.int64]

    @classmethod
    def empty(cls, n_moves: int) -> VertexMax:
        """No sample yet, for a drawing of ``n_moves`` moves."""
        return cls(np.full(n_moves + 1, np.nan), np.full(n_moves + 1, -1, dtype=np.int64))

    @property
    def overall_mm(self) -> float:
        """The largest distance of all, mm (NaN when no sample was cut)."""
        return float(np.nanmax(self.max_mm)) if np.isfinite(self.max_mm).any() else math.nan

    def add(self, dist_mm: NDArray[np.float64], u: NDArray[np.float64], seg: NDArray[np.integer],
            cutting: NDArray[np.bool_]) -> None:
        """Add a stretch of samples.

        Parameters
        ----------
        dist_mm : ndarray (N,)
            Each sample's distance from the drawing, mm (:class:`ilcnc.contour.search.ContourError`).
        u : ndarray (N,)
            Path parameter of its nearest point (move + fraction).
        seg : ndarray (N,)
            Move of its nearest point (-1: none).
        cutting : ndarray (N,) bool
            Samples counted with the cutting moves (:func:`ilcnc.contour.air.cutting_samples`).
        """
        ok = cutting & np.isfinite(dist_mm) & (np.asarray(seg) >= 0)
        if not ok.any():
            return
        n_vertex = self.max_mm.shape[0]
        v = np.clip(np.floor(u[ok] + 0.5), 0, n_vertex - 1).astype(np.int64)
        d = dist_mm[ok]
        best = np.full(n_vertex, -np.inf)
        np.maximum.at(best, v, d)
        better = best > np.nan_to_num(self.max_mm, nan=-np.inf)
        if not better.any():
            return
        # the move of the largest sample of each improved vertex (one of them where several are equal)
        hit = better[v] & (d == best[v])
        self.move[v[hit]] = np.asarray(seg)[ok][hit]
        self.max_mm[better] = best[better]


def planner_rounding(program: Program, profile: MachineProfile, *,
                     chunk_samples: int = DEFAULT_CHUNK_SAMPLES) -> VertexMax:
    """The planner's rounding of ``program``: its planned reference's distance from its own path, per vertex.

    The reference is planned chunk by chunk (bounded memory); no drive runs. Samples count as the run's
    figures count them (cutting moves, not above the stock top: :func:`ilcnc.contour.air.cutting_samples`).
    """
    from ilcnc.contour.path import PathGeometry
    from ilcnc.contour.search import contour_error

    path = PathGeometry.from_moves(program.moves, include_rapids=True)
    _rule, classes = profile_move_classes(program, profile)
    above = air_above_mm(program, _rule, classes, resolution_mm=profile.machine.resolution_mm)
    out = VertexMax.empty(len(program.moves))
    for ch in plan_chunks(program, profile, chunk_samples=chunk_samples):
        err = contour_error(path, ch.pos_mm, ch.move, reference_mm=ch.pos_mm,
                            reference_slack_mm=profile.planner.corner_tolerance_mm)
        out.add(err.dist_mm, err.u, err.seg, cutting_samples(ch.move, classes, err.foot_mm[:, 2], above))
    return out


@dataclass(frozen=True, slots=True, kw_only=True)
class VertexTolerances:
    """The corner tolerance that governs each vertex (:func:`vertex_tolerances`).

    Attributes
    ----------
    tolerance_mm : ndarray (M + 1,)
        Largest rounding the planner allows at vertex ``e``, mm (0: it stops there; NaN: no junction of two
        feed moves).
    mode : ndarray (M + 1,) object
        :class:`ilcnc.outcomes.PathMode` of the move before the vertex (it decides blend or stop).
    set_by_program : ndarray (M + 1,) bool
        The program set that move's path control (else the profile's tolerance or path control applies).
    quarter : ndarray (M + 1,) bool
        The tolerance is LinuxCNC's bound, a quarter of the shorter move, not the one written.
    """

    tolerance_mm: NDArray[np.float64]
    mode: NDArray[Any]
    set_by_program: NDArray[np.bool_]
    quarter: NDArray[np.bool_]


def vertex_tolerances(program: Program, profile: MachineProfile) -> VertexTolerances:
    """The tolerance the planner rounds each vertex of ``program`` within, and where it comes from
    (:func:`ilcnc.vcnc.plan.vertex_tolerances_mm`: the planner's own rule, on its collinear chains)."""
    own = program.moves.blend_tol_mm
    mv = profile_moves(program, profile)
    m = len(mv)
    tol, free = vertex_tolerances_mm(program, profile)
    mode = np.full(m + 1, PathMode.UNSET, dtype=object)
    by_program = np.zeros(m + 1, dtype=np.bool_)
    if m >= 2:
        feed = mv.kind != MOVE_RAPID
        tol[1:m] = np.where(feed[:-1] & feed[1:], tol[1:m], np.nan)
        mode[1:m] = [PathMode.of_tolerance(float(t)) for t in mv.blend_tol_mm[:-1]]
        by_program[1:m] = ~np.isnan(own[:-1])
    # LinuxCNC's quarter-move bound took the tolerance down where it is below the one without it
    quarter = np.isfinite(tol) & (tol > 0) & (tol < free * (1 - 1e-12))
    return VertexTolerances(tolerance_mm=tol, mode=mode, set_by_program=by_program, quarter=quarter)


@dataclass(frozen=True, slots=True, kw_only=True)
class CornerError:
    """The cutting-move error near one vertex of the drawing, split into the planner's rounding and the rest.

    Attributes
    ----------
    vertex : int
        End point ``e``: the end of move ``e − 1`` and the start of move ``e``.
    line : int
        Source line of the move the largest error is on (the line ``simulate`` names as the worst).
    first_line, last_line : int
        Source lines of the two moves that meet at the vertex.
    max_mm : float
        Largest distance of the actual path from the drawing there, mm.
    rounding_mm : float
        Largest distance of the planned reference (of the drawing, before any drive) from the drawing there, mm.
    rest_mm : float
        ``max_mm − rounding_mm``: what the drives' lag and the other error sources add, mm (negative where the
        actual path cuts closer to the drawing than the reference).
    tolerance_mm : float
        The corner tolerance the planner rounds the vertex within, mm (NaN: not a junction of two feed moves).
    mode : PathMode
        The path control of the move before the vertex.
    set_by_program : bool
        The program set it (else the profile's ``planner.corner_tolerance_mm`` / ``planner.path_control``).
    quarter : bool
        The tolerance is a quarter of the shorter move (LinuxCNC's bound on a programmed tolerance).
    """

    vertex: int
    line: int
    first_line: int
    last_line: int
    max_mm: float
    rounding_mm: float
    rest_mm: float
    tolerance_mm: float
    mode: PathMode
    set_by_program: bool
    quarter: bool

    @property
    def rounding_share(self) -> float:
        """The rounding's part of the maximum (0 to 1; 0 when the maximum is 0)."""
        return min(max(self.rounding_mm / self.max_mm, 0.0), 1.0) if self.max_mm > 0 else 0.0


def corner_errors(program: Program, actual: VertexMax, rounding: VertexMax, tolerances: VertexTolerances, *,
                  top: int = 5) -> list[CornerError]:
    """The ``top`` vertices with the largest actual error, each split into rounding and rest.

    ``program`` is the drawing that ``actual``, ``rounding`` and ``tolerances`` were measured on (the same
    moves). Vertices without an actual cutting sample are left out.
    """
    a = actual.max_mm
    order = np.flatnonzero(np.isfinite(a))
    order = order[np.argsort(-a[order], kind="stable")][:max(top, 0)]
    line = program.moves.line
    m = len(line)
    out: list[CornerError] = []
    for e in order.tolist():
        mx = float(a[e])
        rd = float(rounding.max_mm[e]) if np.isfinite(rounding.max_mm[e]) else 0.0
        mv = int(actual.move[e])
        first = int(line[max(e - 1, 0)])
        last = int(line[min(e, m - 1)])
        out.append(CornerError(vertex=int(e), line=int(line[mv]) if mv >= 0 else first, first_line=min(first, last),
                               last_line=max(first, last), max_mm=mx, rounding_mm=rd, rest_mm=mx - rd,
                               tolerance_mm=float(tolerances.tolerance_mm[e]), mode=tolerances.mode[e],
                               set_by_program=bool(tolerances.set_by_program[e]), quarter=bool(tolerances.quarter[e])))
    return out


@dataclass(frozen=True, slots=True, kw_only=True)
class ToleranceCost:
    """What a tighter corner tolerance on some moves does to the plan (:func:`tolerance_cost`).

    Attributes
    ----------
    tolerance_mm : float
        The tolerance given to the moves, mm.
    moves : int
        How many moves got it.
    cycle_before_s, cycle_after_s : float
        Planned cycle time without and with it, s.
    rounding_after : VertexMax
        The planner's rounding with it, per vertex.
    """

    tolerance_mm: float
    moves: int
    cycle_before_s: float
    cycle_after_s: float
    rounding_after: VertexMax

    @property
    def extra_s(self) -> float:
        return self.cycle_after_s - self.cycle_before_s

    @property
    def extra_pct(self) -> float:
        return 100.0 * self.extra_s / self.cycle_before_s if self.cycle_before_s > 0 else 0.0


def tolerance_cost(program: Program, profile: MachineProfile, moves: NDArray[np.bool_], tolerance_mm: float, *,
                   cycle_before_s: float | None = None) -> ToleranceCost:
    """Plan ``program`` with the corner tolerance ``tolerance_mm`` on ``moves`` (M,) bool, as a ``G64 P`` /
    cycle 32 ``T`` the program sets there would: the cycle time and the rounding it gives (plan only, no drive).

    The program's own setting elsewhere is kept. A programmed tolerance is also bounded by a quarter of the
    shorter move, as the planner bounds every programmed one.
    """
    if not (math.isfinite(tolerance_mm) and tolerance_mm > 0):
        raise ValueError(f"tolerance {tolerance_mm} mm: a corner tolerance is a positive length")
    sel = np.asarray(moves, dtype=np.bool_)
    if sel.shape != (len(program.moves),):
        raise ValueError(f"moves has shape {sel.shape}, the program has {len(program.moves)} moves")
    before = planned_duration_s(program, profile) if cycle_before_s is None else cycle_before_s
    blend = program.moves.blend_tol_mm.copy()
    # only tighter: a move already within the tolerance (or stopping at its corners, by the program or the
    # profile's planner.path_control) keeps its mode
    eff = profile_moves(program, profile).blend_tol_mm
    tighten = sel & (np.isnan(eff) | (eff > tolerance_mm))
    blend[tighten] = tolerance_mm
    tight = dataclasses.replace(program, moves=dataclasses.replace(program.moves, blend_tol_mm=blend))
    after = planned_duration_s(tight, profile)
    return ToleranceCost(tolerance_mm=float(tolerance_mm), moves=int(tighten.sum()), cycle_before_s=float(before),
                         cycle_after_s=float(after), rounding_after=planner_rounding(tight, profile))

"""Refinement: extra end points on the original path where the error is and no end point can shape it.

Learning moves end points. On dense CAM output (moves of a few tenths of a
millimetre) every stretch of the path has some; between long moves it has
none where the error is: a corner between two long moves is cut short over
the length the machine lags (about feed / Kv, plus the planner's blend), and
the first feed move after a rapid starts while the axes still lag the
rapid. Moving the corner's own end point tilts both long moves over their
whole length (``docs/learning.md``, "Why path"), so the error stays.

:func:`plan_refinement` reads the first run (virtual, or the machine's log
of the original program) and places points on the straight feeds next to
each such spot:

* **where**: a corner between two straight feeds that turns by more than
  ``learning.refine.corner_angle_deg``, and the start of a straight feed that
  follows a rapid, where the first run's contour error exceeds
  ``learning.refine.min_error_mm`` (default twice the resolution: below it
  the error is at the physical floor);
* **how far**: over the *disturbed stretch* on each side, the distance from
  the corner out to where the first run's error has fallen below a fifth of
  its peak there (or below the threshold). On a machine with position gain
  Kv this stretch is about the lag length v / Kv plus the blend length;
  measuring it instead of computing it covers every drive model, the
  planner's blends and the real machine alike. At most half of a move
  belongs to one corner;
* **how many**: at distances halving from the end of the stretch towards the
  corner (d, d/2, d/4, ...), at most ``points_per_side``, never closer than
  ``min_spacing_periods`` servo periods of motion at the move's feed to
  another end point (a controller runs one block per period at most; closer
  points only cost look-ahead). Inside the planner's slow zone at the corner
  too: the planner gives a straight line split into moves the zones of the
  line (:mod:`ilcnc.vcnc.plan_zones`), so the refined program, uncorrected,
  plans as the original (same reference, same cycle time) and cuts what it
  cuts;
* **settle** (``learning.refine.settle``): before the first feed after a
  rapid whose first-run error is above the threshold, a dwell as long as the
  slowest drive model takes to settle from that error to the threshold
  (:func:`ilcnc.vcnc.settle.settle_time_s`). The error there is the rapid's
  lag, not the feed's: no end point on the feed can take back a lag that
  closes along the rapid's direction while the feed runs, a stop can. The
  largest first, within ``settle_budget_pct`` of the cycle time;
* **cap**: more than ``max_lines`` points and settles in a program is refused.

The points are inserted by :func:`ilcnc.program.insert.insert_points`, which
keeps every original line and checks that the refined program runs the same
path (within 0.05 µm per axis: the written decimals).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.contour.air import MOVE_CUT
from ilcnc.errors import InputError
from ilcnc.learning.move_limits import ZERO_LENGTH_MM
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import MOVE_ARC_CW, MOVE_LINE, MOVE_RAPID, Program

__all__ = ["RefinePlan", "RefineSite", "plan_refinement", "refine_threshold_mm"]

#: Fraction of a spot's peak error below which its disturbed stretch ends.
STRETCH_FRACTION = 0.2
#: Largest share of a move that one of its corners may refine.
MAX_MOVE_SHARE = 0.5


@dataclass(frozen=True, slots=True)
class RefineSite:
    """One refined spot: a corner, the start of a feed after a rapid, or a straight feed's junction with an arc.

    Attributes
    ----------
    kind : str
        ``corner``, ``rapid`` or ``arc`` (a straight feed next to an arc).
    line : int
        Source line of the move that ends at the spot (the rapid, for ``rapid``).
    peak_mm : float
        Largest contour error of the first run within the spot's stretch, mm.
    stretch_mm : tuple of float
        Disturbed stretch before and after the spot, mm.
    points : int
        Points placed.
    settle_s : float
        Dwell written before the feed (``rapid`` only; 0: none), s.
    """

    kind: str
    line: int
    peak_mm: float
    stretch_mm: tuple[float, float]
    points: int
    settle_s: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "line": self.line, "peak_mm": self.peak_mm,
                "stretch_mm": list(self.stretch_mm), "points": self.points, "settle_s": self.settle_s}


@dataclass(slots=True)
class RefinePlan:
    """Where to insert points: per move the fractions of its length, and what was refined why.

    Attributes
    ----------
    points : dict of int to list of float
        Move index -> fractions 0 < f < 1 along it.
    sites : list of RefineSite
        The refined spots.
    threshold_mm : float
        The least error of a refined spot, mm.
    passed : dict of str to int
        Spots seen but left alone, by reason (``below threshold``, ``short moves``, ...).
    settles : dict of int to float
        Move index of a feed after a rapid -> dwell before it, s (``learning.refine.settle``).
    """

    points: dict[int, list[float]] = field(default_factory=dict)
    settles: dict[int, float] = field(default_factory=dict)
    sites: list[RefineSite] = field(default_factory=list)
    threshold_mm: float = 0.0
    passed: dict[str, int] = field(default_factory=dict)

    @property
    def n_points(self) -> int:
        return sum(len(v) for v in self.points.values())

    def summary(self) -> dict[str, Any]:
        kinds = {k: sum(1 for s in self.sites if s.kind == k) for k in ("corner", "rapid", "arc")}
        return {"points": self.n_points, "moves_split": len(self.points), "corners": kinds["corner"],
                "rapids": kinds["rapid"], "arcs": kinds["arc"], "threshold_mm": self.threshold_mm,
                "settles": len(self.settles), "settle_s": float(sum(self.settles.values())),
                "passed": dict(self.passed)}


def refine_threshold_mm(profile: MachineProfile) -> float:
    """``learning.refine.min_error_mm``, or twice the machine's resolution."""
    v = profile.learning.refine.min_error_mm
    return float(v) if v is not None else 2.0 * profile.machine.resolution_mm


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def _side_profile(dist: NDArray[np.float64], seg: NDArray[np.int64], frac: NDArray[np.float64], length: NDArray[np.float64],
                  move: int, from_end: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Distance from the spot (mm) and contour error (mm) of the first run's samples with their foot on ``move``."""
    sel = seg == move
    d = dist[sel]
    f = frac[sel]
    s = (1.0 - f) * length[move] if from_end else f * length[move]
    return s, d


def _stretch(s: NDArray[np.float64], d: NDArray[np.float64], limit: float, floor: float) -> tuple[float, float]:
    """(peak error, distance where it falls below the stretch threshold for good) within ``limit`` of the spot."""
    near = s <= limit
    if not near.any():
        return 0.0, 0.0
    s, d = s[near], d[near]
    peak = float(np.max(d))
    thr = max(STRETCH_FRACTION * peak, floor)
    above = s[d > thr]
    return peak, float(above.max()) if above.size else 0.0


def _distances(stretch: float, n_max: int, spacing: float, nearest: float, room: float) -> list[float]:
    """d, d/2, d/4, ... from the spot, at most ``n_max``, none nearer than ``nearest`` to the spot nor closer than
    ``spacing`` to each other, none beyond ``room``."""
    out: list[float] = []
    d = min(max(stretch, nearest), room)
    while len(out) < n_max and d >= nearest:
        if not out or out[-1] - d >= spacing:
            out.append(d)
        d *= 0.5
    if not out and nearest <= room:
        out.append(nearest)
    return out


def _settles(plan: RefinePlan, profile: MachineProfile, rapid_feeds: list[tuple[int, int]],
             cycle_time_s: float | None) -> None:
    """Give the feeds after rapids their settle (:mod:`ilcnc.vcnc.settle`): from the lag the first run shows
    there (the site's peak) down to the refine threshold, the largest lags first within the budget; a rapid
    site left with neither points nor a settle is dropped and counted."""
    if not rapid_feeds:
        return
    from ilcnc.vcnc.settle import settle_time_s

    peaks = np.array([plan.sites[k].peak_mm for k, _ in rapid_feeds])
    need = settle_time_s(profile, peaks, plan.threshold_mm)
    budget = (profile.learning.refine.settle_budget_pct / 100.0 * cycle_time_s
              if cycle_time_s is not None and cycle_time_s > 0 else 0.0)
    spent = 0.0
    for r in np.argsort(-peaks, kind="stable").tolist():
        k, j = rapid_feeds[r]
        t = float(need[r])
        if t <= 0.0:
            continue
        if spent + t > budget + 1e-12:
            plan.passed["settle beyond settle_budget_pct"] = plan.passed.get("settle beyond settle_budget_pct", 0) + 1
            continue
        spent += t
        plan.settles[j] = t
        plan.sites[k] = replace(plan.sites[k], settle_s=t)
    empty = [k for k, _ in rapid_feeds if plan.sites[k].points == 0 and plan.sites[k].settle_s == 0.0]
    if empty:
        plan.passed["moves too short"] = plan.passed.get("moves too short", 0) + len(empty)
        drop = set(empty)
        plan.sites[:] = [s for k, s in enumerate(plan.sites) if k not in drop]


def plan_refinement(program: Program, profile: MachineProfile, *, dist_mm: NDArray[np.float64],
                    seg: NDArray[np.int64], u: NDArray[np.float64], classes: NDArray[np.int8],
                    cycle_time_s: float | None = None) -> RefinePlan:
    """Place the refinement points of ``program`` from its first run.

    Parameters
    ----------
    program : Program
        The original program.
    profile : MachineProfile
        ``learning.refine`` settings, servo period.
    dist_mm, seg, u : ndarray (N,)
        The first run's contour error per sample (mm), the move of its foot point (-1: none) and the
        continuous path parameter (move + fraction), as :class:`ilcnc.contour.search.ContourError` has them; samples
        off the cut (NaN distance) are ignored.
    classes : ndarray (M,) int8
        Class of every move (:func:`ilcnc.contour.air.move_classes`): only cutting moves are refined.
    cycle_time_s : float, optional
        The original's planned cycle time, s: the settles may add ``learning.refine.settle_budget_pct`` of it
        (absent: no settles).

    Returns
    -------
    RefinePlan

    Raises
    ------
    InputError
        The refinement needs more than ``learning.refine.max_lines`` points.
    """
    cfg = profile.learning.refine
    period = profile.machine.servo_period_s
    mv = program.moves
    m = len(mv)
    plan = RefinePlan(threshold_mm=refine_threshold_mm(profile))
    if m < 2:
        return plan
    ok = np.isfinite(dist_mm) & (seg >= 0)
    dist, sg = dist_mm[ok], seg[ok].astype(np.int64)
    frac = np.clip(u[ok] - sg, 0.0, 1.0)
    d_vec = mv.end_mm - mv.start_mm
    length = np.linalg.norm(d_vec, axis=1)
    tangent = _unit(d_vec)
    straight = (mv.kind == MOVE_LINE) & (mv.command >= 0) & (classes == MOVE_CUT)
    arc = (mv.kind >= MOVE_ARC_CW) & (classes == MOVE_CUT)
    feed_mm_s = np.nan_to_num(mv.feed_mm_min, nan=0.0) / 60.0
    cos_limit = math.cos(math.radians(cfg.corner_angle_deg))
    # samples by move, once: the foot's move sorted, so each move's samples are a slice
    order = np.argsort(sg, kind="stable")
    sg_sorted = sg[order]
    bounds = np.searchsorted(sg_sorted, np.arange(m + 1))
    claimed: dict[int, list[float]] = {}

    def side(move: int, from_end: bool, limit: float) -> tuple[float, float]:
        idx = order[bounds[move]:bounds[move + 1]]
        s, d = _side_profile(dist[idx], sg[idx], frac[idx], length, move, from_end)
        return _stretch(s, d, limit, plan.threshold_mm)

    def arc_peak(move: int) -> float:
        idx = order[bounds[move]:bounds[move + 1]]
        return float(np.max(dist[idx])) if idx.size else 0.0

    def place(move: int, dists: list[float], from_end: bool) -> int:
        fr = [1.0 - x / length[move] if from_end else x / length[move] for x in dists]
        fr = [f for f in fr if 0.0 < f < 1.0]
        claimed.setdefault(move, []).extend(fr)
        return len(fr)

    def spacing(move: int) -> float:
        return max(cfg.min_spacing_periods * feed_mm_s[move] * period, 1e-3)

    # a point the program repeats (a zero-length straight block) is one point: the corner is between the moves
    # either side of it (jsdc writes one at corners and before retracts; without this they were never refined)
    repeat = (mv.kind == MOVE_LINE) & (length <= ZERO_LENGTH_MM)
    rapid_feeds: list[tuple[int, int]] = []  # (site index, feed move) of the rapid sites
    for i in range(m - 1):
        if repeat[i]:
            continue
        j = i + 1
        while j < m - 1 and repeat[j]:
            j += 1
        if not np.allclose(mv.end_mm[i], mv.start_mm[j], atol=1e-6) or length[j] <= 0:
            continue
        if mv.kind[i] == MOVE_RAPID and (straight[j] or arc[j]):
            kind = "rapid"  # on an arc: no points, a settle only
        elif straight[i] and straight[j] and length[i] > 0:
            if float(tangent[i] @ tangent[j]) > cos_limit:
                continue
            kind = "corner"
        elif cfg.arcs == "on" and ((straight[i] and arc[j]) or (arc[i] and straight[j])):
            kind = "arc"  # a straight feed next to an arc: its end points are the arc's only handles
        else:
            continue
        room_j = MAX_MOVE_SHARE * length[j]
        if kind == "arc":
            # the arc's own error (no end point on it can move) and the straight side's stretch from the junction
            line, from_end = (i, True) if straight[i] else (j, False)
            peak_a = arc_peak(j if straight[i] else i)
            peak_l, st_l = side(line, from_end, MAX_MOVE_SHARE * length[line])
            peak = max(peak_a, peak_l)
            if peak < plan.threshold_mm:
                plan.passed["below threshold"] = plan.passed.get("below threshold", 0) + 1
                continue
            # the arc bends the path within the lag: the straight side's stretch starts at the junction
            st_l = max(st_l, spacing(line))
            near, room = spacing(line), MAX_MOVE_SHARE * length[line]
            n = place(line, _distances(st_l, cfg.points_per_side, spacing(line), near, room), from_end)
            if n == 0:
                plan.passed["moves too short"] = plan.passed.get("moves too short", 0) + 1
                continue
            plan.sites.append(RefineSite(kind, int(mv.line[i]), peak, (st_l, 0.0) if from_end else (0.0, st_l), n))
            continue
        peak_j, st_j = side(j, False, room_j)
        peak_i, st_i = (side(i, True, MAX_MOVE_SHARE * length[i]) if kind == "corner" else (0.0, 0.0))
        peak = max(peak_i, peak_j)
        if peak < plan.threshold_mm:
            plan.passed["below threshold"] = plan.passed.get("below threshold", 0) + 1
            continue
        if kind == "corner" and cfg.feed == "on":
            # the feed learning slows a corner by its pieces: both sides need a piece as long as the stretch the
            # corner disturbs (the error shows on one side, the lag that makes it runs over both)
            st_i = st_j = max(st_i, st_j)
        n = 0
        if kind == "corner":
            near_i, room_i = spacing(i), MAX_MOVE_SHARE * length[i]
            n += place(i, _distances(st_i, cfg.points_per_side, spacing(i), near_i, room_i), True)
        if straight[j]:
            near_j = spacing(j)
            n += place(j, _distances(st_j, cfg.points_per_side, spacing(j), near_j, room_j), False)
        if kind == "rapid" and cfg.settle == "on":
            rapid_feeds.append((len(plan.sites), j))  # a settle may still come (_settles); decided below
        elif n == 0:
            plan.passed["moves too short"] = plan.passed.get("moves too short", 0) + 1
            continue
        plan.sites.append(RefineSite(kind, int(mv.line[i]), peak, (st_i, st_j), n))
    _settles(plan, profile, rapid_feeds, cycle_time_s)
    # one move may be claimed by the corners at both of its ends: keep its fractions sorted, apart
    for move, fr in claimed.items():
        fr = sorted(set(fr))
        gap = spacing(move) / length[move]
        kept: list[float] = []
        for f in fr:
            if f < gap or f > 1.0 - gap:
                continue
            if kept and f - kept[-1] < gap:
                continue
            kept.append(f)
        if kept:
            plan.points[move] = kept
    if plan.n_points + len(plan.settles) > cfg.max_lines:
        raise InputError(program.path, None, f"refinement would insert {plan.n_points + len(plan.settles)} lines,"
                         " more than"
                         f" learning.refine.max_lines = {cfg.max_lines}: raise it, or refine less"
                         " (learning.refine.corner_angle_deg, points_per_side, min_error_mm)")
    return plan

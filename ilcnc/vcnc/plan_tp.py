"""Segment planner after LinuxCNC 2.9's trajectory planner (``planner.profile: linuxcnc``).

ilcnc's own planner (:mod:`ilcnc.vcnc.plan`) smooths an ideal interpolator with moving-average filters. A real
controller plans differently, and where the learning loop runs on a virtual copy of one, the copy should
move as the controller does. This module plans a program the way LinuxCNC 2.9 (``src/emc/tp``: ``tp.c``,
``blendmath.c``, ``tc.c``) does, as far as it shapes the commanded path on a 3-axis mill:

* **Segments.** Every move is a segment with a requested speed (its feed; rapids the axes' limit) capped so
  that no axis exceeds its velocity, and a tangential acceleration limit ``min_i a_i/|u_i|``. A segment may
  not run faster than its length per :data:`MIN_SEGMENT_CYCLES` servo periods (LinuxCNC's
  ``TP_MIN_SEGMENT_CYCLES``), so very short moves are slow.
* **Corners** (``G64``, the move before the corner decides): a corner whose *kink* acceleration, the jump
  of the acceleration vector when the direction changes at full speed in one period, stays below
  :data:`KINK_RATIO` of the axis limits is passed as tangent. Otherwise a circular **blend arc** replaces
  the corner: it may use half of each move (:data:`BLEND_DIST_FRACTION`) and deviate from the vertex by the
  corner tolerance, the smaller of the two moves' ``G64 P`` (``G64`` without P: a quarter of the move,
  :data:`TOLERANCE_RATIO`) and a quarter of either move; its speed is ``sqrt(a_n·R)`` with
  ``a_n = ACC_RATIO_NORMAL·a`` and it accelerates along itself at ``ACC_RATIO_TANGENTIAL·a``; its radius is
  the larger of what its speed needs and what a parabolic blend of the same time would sweep. A line left
  shorter than :data:`GAP_CYCLES` periods of the arc's speed is run as part of the arc. Where no arc fits,
  the corner is passed as tangent at the kink speed. Reversals (within 2°) stop.
* **Stops.** ``G61.1`` stops at every corner; ``G61`` at every corner that is not a straight continuation;
  the machine stops between rapids and feed moves (no in-position wait: the next move starts when the
  commanded one ends). Arcs (``G2``/``G3``) are followed exactly at ``sqrt(a_n·R)`` at most; a corner next to
  an arc is tangent when its kink is small, else a stop (LinuxCNC also blends lines into arcs; not modelled).
* **Dwells** (``MoveTable.dwell_s``, ``G4 P``): LinuxCNC's task waits until the motion queue is empty
  before it dwells, so the move before a dwell ends at a stop (never blended) and the commanded position
  holds for ``round(dwell_s / period)`` servo periods before the next move starts (a dwell after the last
  move: as many periods after the final stop). Those samples belong to the move before the dwell (-1 before
  the first move), as LinuxCNC's log reads them: with the queue empty, ``motion.program-line`` is 0 and
  the halsampler reader carries the last line forward (:mod:`ilcnc.axislog.halsampler`).
* **Look-ahead.** The final speed of every segment is the highest from which the next
  :data:`LOOKAHEAD_SEGMENTS` segments (LinuxCNC's ``ARC_BLEND_OPTIMIZATION_DEPTH``) can still be run to a
  stop, capped by both segments' speeds and the kink speed.
* **Execution** per servo period: the trapezoidal velocity update LinuxCNC runs each cycle (the largest
  speed from which the end of the segment is reached at its final speed with the segment's acceleration,
  bounded by the requested speed and by ±acceleration over the period); a segment that ends inside a
  period hands the rest of the period to the next one.

Not modelled: LinuxCNC's "ramp" mode for segments shorter than a 100 Hz period, parabolic blending (a
failed arc here becomes a tangent corner at the kink speed), line–arc blend arcs, feed override, spindle
synchronisation. The numbers are measured against LinuxCNC's own motion in docs/papers.md ("Real
controller": on plain-``G64`` CAM programs the per-command error it predicts correlates 0.96–1.00 with the
measured one). The code is written from that description of the method; LinuxCNC's source is GPL-2.

The per-period loop cannot be vectorised (each period depends on the last), so it is compiled (numba),
as are the two sequential passes over the segments (each corner trims the segment the previous corner
made).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ilcnc._jit import njit
from ilcnc.program.geometry import arc_sweep_rad, move_lengths_mm
from ilcnc.program.model import MOVE_ARC_CW, MOVE_RAPID, PLANE_AXES, MoveTable
from ilcnc.vcnc.plan_base import PlanLimits, dwell_samples, move_directions, nominal_speed_mm_s

__all__ = ["ACC_RATIO_NORMAL", "ACC_RATIO_TANGENTIAL", "BLEND_DIST_FRACTION", "GAP_CYCLES", "KINK_RATIO",
           "LOOKAHEAD_SEGMENTS", "MIN_SEGMENT_CYCLES", "TOLERANCE_RATIO", "plan_linuxcnc"]

#: Share of the axis acceleration a blend arc uses along itself (the rest is for its normal acceleration).
ACC_RATIO_TANGENTIAL = 0.5
#: Share of the axis acceleration a blend arc's radius is sized for: sqrt(1 − 0.5²).
ACC_RATIO_NORMAL = math.sqrt(1.0 - ACC_RATIO_TANGENTIAL**2)
#: A segment takes at least this many servo periods (its speed is at most length / (1.02·period)).
MIN_SEGMENT_CYCLES = 1.02
#: A corner whose one-period acceleration jump stays below this share of the axis limits is tangent.
KINK_RATIO = 0.1
#: Segments the final-speed look-ahead spans.
LOOKAHEAD_SEGMENTS = 50
#: A line left shorter than this many periods at the blend arc's speed is run as part of the arc.
GAP_CYCLES = 4
#: Share of a move a blend arc may use.
BLEND_DIST_FRACTION = 0.5
#: ``G64`` without P: the corner tolerance is this share of the move (and never more than it).
TOLERANCE_RATIO = 0.25
#: A corner turning back by more than 180° − 2° stops.
_REVERSAL_COS = -math.cos(math.radians(2.0))
_MIN_ARC_ANGLE = 1e-3
_MIN_ARC_LENGTH_MM = 1e-6
_ANGLE_EPS = 1e-6

# segment kinds
_LINE = 0
_BLEND = 1
_ARC = 2


@njit(cache=True, nogil=True)
def _inscribed(n0: float, n1: float, n2: float, bound: NDArray[np.float64]) -> float:  # pragma: no cover - compiled
    """Diameter of the circle inscribed in the cross-section, through the centre and normal to ``n``, of the
    box of half-sizes ``bound`` (an axis without limit: 0): the largest vector in that plane all axes allow."""
    nv = (n0, n1, n2)
    d = 0.0
    ext = np.zeros(3)
    for j in range(3):
        sq = 0.0
        for i in range(3):
            c = (1.0 if i == j else 0.0) - nv[i] * nv[j]
            sq += c * c
        sc = max(math.sqrt(sq), 1e-12)
        ext[j] = bound[j] / sc if bound[j] > 0 else 0.0
        d = max(d, ext[j])
    for j in range(3):
        if bound[j] > 0:
            d = min(d, ext[j])
    return d


@njit(cache=True, nogil=True)
def _segments(start, end, length, kind, tol, rapid, vreq, t_in, t_out, arc_c, arc_ax, arc_r0, arc_r1, vlim, alim,
              period, kink_ratio, gap_cycles, still):  # pragma: no cover - compiled
    """Segments of a move table: lines, blend arcs at corners, program arcs, with speeds, accelerations and the
    end condition of each (module docstring). Moves of zero length are skipped. ``still`` (M,): samples the
    position holds before each move (its dwell); the move before it stops, and its first segment gets them."""
    m = start.shape[0]
    cap = 2 * m + 2
    skind = np.zeros(cap, np.int8)
    p0 = np.zeros((cap, 3))
    p1 = np.zeros((cap, 3))
    ctr = np.zeros((cap, 3))
    e1 = np.zeros((cap, 3))
    e2 = np.zeros((cap, 3))
    rad = np.zeros(cap)
    straight = np.zeros(cap)
    target = np.zeros(cap)
    maxvel = np.zeros(cap)
    acc = np.zeros(cap)
    tangent = np.zeros(cap, np.bool_)
    kink = np.full(cap, -1.0)
    owner = np.zeros(cap, np.int64)
    hold = np.zeros(cap, np.int64)
    n = 0
    last = -1          # segment of the previous move (its end is still open)
    last_move = -1
    for i in range(m):
        L = length[i]
        if L <= 1e-9:
            continue
        u = t_in[i]
        s = n
        n += 1
        owner[s] = i
        hold[s] = still[i]
        p0[s] = start[i]
        p1[s] = end[i]
        target[s] = L
        if kind[i] >= 2:
            skind[s] = _ARC
            a1, a2 = arc_ax[i, 0], arc_ax[i, 1]
            a_pl = min(alim[a1], alim[a2])
            v_pl = min(vlim[a1], vlim[a2])
            r = max(min(arc_r0[i], arc_r1[i]), 1e-9)
            maxvel[s] = min(vreq[i], v_pl, math.sqrt(ACC_RATIO_NORMAL * a_pl * r))
            acc[s] = ACC_RATIO_TANGENTIAL * a_pl
            ctr[s] = arc_c[i]
        else:
            skind[s] = _LINE
            am = 1e300
            for j in range(3):
                if abs(u[j]) > 1e-12:
                    am = min(am, alim[j] / abs(u[j]))
            maxvel[s] = vreq[i]                     # already capped by the axes' velocity limits
            acc[s] = am
        if last >= 0 and last_move == i - 1:
            q = last
            tq = tol[last_move]
            uq = t_out[last_move]
            dot = min(1.0, max(-1.0, uq[0] * u[0] + uq[1] * u[1] + uq[2] * u[2]))
            if tq < 0.0 or rapid[last_move] != rapid[i] or still[i] > 0:
                tangent[q] = False                  # exact stop; a rapid and a feed move do not blend; a dwell
            elif tq == 0.0:
                tangent[q] = dot > 1.0 - 1e-12      # exact path: only a straight continuation
            elif dot < _REVERSAL_COS:
                tangent[q] = False
            else:
                vmx = min(maxvel[q], maxvel[s])
                a_inst = vmx / period + acc[s]
                scale = 0.0
                for j in range(3):
                    if alim[j] > 0:
                        scale = max(scale, abs(a_inst * (u[j] - uq[j])) / alim[j])
                if skind[q] == _ARC or skind[s] == _ARC:
                    scale /= ACC_RATIO_TANGENTIAL
                tangent[q] = True
                if scale < kink_ratio:
                    kink[q] = vmx
                elif skind[q] == _ARC or skind[s] == _ARC:
                    tangent[q] = False              # no line-arc blend arc: stop
                else:
                    kink[q] = vmx * kink_ratio / scale
                    # a blend arc in the plane of the two lines
                    theta = math.acos(-dot) / 2.0
                    phi = math.pi - 2.0 * theta
                    nom_q = length[last_move]
                    t1 = tq if math.isfinite(tq) else 0.0
                    t2 = tol[i] if (math.isfinite(tol[i]) and tol[i] > 0.0) else 0.0
                    if t1 == 0.0:
                        t1 = nom_q * TOLERANCE_RATIO
                    if t2 == 0.0:
                        t2 = L * TOLERANCE_RATIO
                    tol_b = min(min(t1, t2), min(nom_q, L) * TOLERANCE_RATIO)
                    l1 = min(target[q], nom_q * BLEND_DIST_FRACTION)
                    l2 = L * BLEND_DIST_FRACTION
                    bx = uq[1] * u[2] - uq[2] * u[1]
                    by = uq[2] * u[0] - uq[0] * u[2]
                    bz = uq[0] * u[1] - uq[1] * u[0]
                    bn = math.sqrt(bx * bx + by * by + bz * bz)
                    ok = theta > _MIN_ARC_ANGLE and phi > _MIN_ARC_ANGLE and (math.pi / 2 - theta) > _ANGLE_EPS and bn > 0
                    if ok:
                        a_max = _inscribed(bx / bn, by / bn, bz / bn, alim)
                        a_n = a_max * ACC_RATIO_NORMAL
                        v_req = max(vreq[last_move], vreq[i])
                        v_planar = _inscribed(bx / bn, by / bn, bz / bn, vlim)
                        phe = min(phi, math.pi * 0.49)
                        v1 = min(maxvel[q], maxvel[s] / math.cos(phe))
                        v2 = min(maxvel[s], maxvel[q] / math.cos(phe))
                        base = math.sqrt((u[0] * v2 - uq[0] * v1) ** 2 + (u[1] * v2 - uq[1] * v1) ** 2
                                         + (u[2] * v2 - uq[2] * v1) ** 2)
                        v_alt = v1 * v2 * math.sin(phi) / base if base > 0 else 0.0
                        v_goal = min(v_req, max(v_alt, v_planar))
                        d_tol = math.cos(theta) * tol_b / (1.0 - math.sin(theta))
                        d_geom = min(min(l1, l2), d_tol)
                        r_geom = math.tan(theta) * d_geom
                        v_plan = min(math.sqrt(a_n * r_geom), v_goal)
                        a_par = 0.5 * a_max
                        t_bl = min(math.sqrt(2.0 * a_par * d_geom), v_plan) / a_par
                        r_bl = min(t_bl * v_plan / phi, r_geom)
                        r = max(v_plan * v_plan / a_n, r_bl)
                        d_plan = r / math.tan(theta)
                        ok = (r > 1e-12 and r * phi >= _MIN_ARC_LENGTH_MM and d_plan <= l1 * (1 + 1e-12)
                              and d_plan <= l2 * (1 + 1e-12))
                    if ok:
                        vertex = p1[q].copy()
                        p1[q] = vertex - uq * d_plan
                        target[q] -= d_plan
                        # the blend arc takes slot s; the line moves to the next slot
                        t = n
                        n += 1
                        skind[t] = _LINE
                        p0[t] = vertex + u * d_plan
                        p1[t] = end[i]
                        target[t] = L - d_plan
                        maxvel[t] = maxvel[s]
                        acc[t] = acc[s]
                        owner[t] = i
                        nx, ny, nz = u[0] - uq[0], u[1] - uq[1], u[2] - uq[2]
                        nl = math.sqrt(nx * nx + ny * ny + nz * nz)
                        cdist = r / math.sin(theta)
                        skind[s] = _BLEND
                        ctr[s, 0] = vertex[0] + nx / nl * cdist
                        ctr[s, 1] = vertex[1] + ny / nl * cdist
                        ctr[s, 2] = vertex[2] + nz / nl * cdist
                        rad[s] = r
                        e1[s] = (p1[q] - ctr[s]) / r
                        e2[s] = uq
                        p0[s] = p1[q]
                        straight[s] = 0.0
                        target[s] = r * phi
                        maxvel[s] = min(v_plan, v_req)
                        acc[s] = a_max * ACC_RATIO_TANGENTIAL
                        owner[s] = i
                        tangent[s] = True
                        kink[s] = -1.0
                        kink[q] = -1.0
                        # the rest of the line before is run as part of the arc when it is very short
                        if skind[q] == _LINE and target[q] < gap_cycles * period * max(v_plan, 1e-9):
                            straight[s] = target[q]
                            target[s] += target[q]
                            p0[s] = p0[q]
                            target[q] = 0.0
                        s = t
                    # else: tangent at the kink speed
        last = s
        last_move = i
    return (skind[:n], p0[:n], p1[:n], ctr[:n], e1[:n], e2[:n], rad[:n], straight[:n], target[:n], maxvel[:n],
            acc[:n], tangent[:n], kink[:n], owner[:n], hold[:n])


@njit(cache=True, nogil=True)
def _final_speeds(target, maxvel, acc, tangent, kink, depth):  # pragma: no cover - compiled
    """Final speed of every segment: the highest from which the next ``depth`` segments can still stop."""
    n = target.shape[0]
    vf = np.zeros(n)
    for s in range(n):
        if not tangent[s] or s == n - 1:
            continue
        v = 0.0
        for k in range(min(n - 1, s + depth), s, -1):
            if not tangent[k - 1]:
                v = 0.0
                continue
            lim = min(maxvel[k], maxvel[k - 1])
            if kink[k - 1] >= 0.0:
                lim = min(lim, kink[k - 1])
            v = min(math.sqrt(v * v + 2.0 * acc[k] * target[k]), lim)
        vf[s] = v
    return vf


@njit(cache=True, nogil=True)
def _point(s, prog, skind, p0, p1, ctr, e1, e2, rad, straight, target, arc_move, arc_ax, arc_th0, arc_sgn, arc_sw,
           arc_r0, arc_r1, arc_dz, out):  # pragma: no cover - compiled
    """Position ``prog`` mm along segment ``s``."""
    if skind[s] == _LINE:
        f = prog / target[s] if target[s] > 0 else 1.0
        for j in range(3):
            out[j] = p0[s, j] + (p1[s, j] - p0[s, j]) * f
    elif skind[s] == _BLEND:
        if prog < straight[s]:
            for j in range(3):
                out[j] = p0[s, j] + e2[s, j] * prog
        else:
            th = (prog - straight[s]) / rad[s]
            c, sn = math.cos(th), math.sin(th)
            for j in range(3):
                out[j] = ctr[s, j] + rad[s] * (c * e1[s, j] + sn * e2[s, j])
    else:
        i = arc_move[s]
        f = min(max(prog / target[s], 0.0), 1.0) if target[s] > 0 else 1.0
        th = arc_th0[i] + arc_sgn[i] * arc_sw[i] * f
        r = arc_r0[i] + (arc_r1[i] - arc_r0[i]) * f
        a1, a2, lin = arc_ax[i, 0], arc_ax[i, 1], arc_ax[i, 2]
        out[a1] = ctr[s, a1] + r * math.cos(th)
        out[a2] = ctr[s, a2] + r * math.sin(th)
        out[lin] = p0[s, lin] + arc_dz[i] * f
        if f >= 1.0:
            for j in range(3):
                out[j] = p1[s, j]


@njit(cache=True, nogil=True)
def _room(pos, mv, k):  # pragma: no cover - compiled
    """``pos`` (R, 3) and ``mv`` (R,) with room for row ``k``: doubled (rows before ``k`` copied) when full."""
    if k < pos.shape[0]:
        return pos, mv
    pos2 = np.empty((2 * pos.shape[0], 3))
    pos2[:k] = pos[:k]
    mv2 = np.empty(2 * pos.shape[0], np.int64)
    mv2[:k] = mv[:k]
    return pos2, mv2


@njit(cache=True, nogil=True)
def _run(skind, p0, p1, ctr, e1, e2, rad, straight, target, maxvel, acc, tangent, vf, owner, period, first,
         arc_ax, arc_th0, arc_sgn, arc_sw, arc_r0, arc_r1, arc_dz, hold):  # pragma: no cover - compiled
    """Positions and segment owners at every servo period (sample 0: at rest at ``first``). ``hold[s]``: samples
    the position stands still before segment ``s`` starts (a dwell; the previous segment ends at a stop), on
    the move of the sample before."""
    n = target.shape[0]
    pos = np.empty((4096, 3))
    mv = np.empty(4096, np.int64)
    pos[0] = first
    mv[0] = -1
    k = 1
    s = 0
    prog = 0.0
    v = 0.0
    pt = np.empty(3)
    wait = hold[0] if n > 0 else 0
    while s < n:
        if wait > 0:
            pos, mv = _room(pos, mv, k)
            pos[k] = pos[k - 1]
            mv[k] = mv[k - 1]
            k += 1
            wait -= 1
            continue
        tau = period
        while tau > 0.0 and s < n:
            a = acc[s]
            fv = vf[s] if tangent[s] else 0.0
            half = a * tau * 0.5
            disc = fv * fv + a * (2.0 * (target[s] - prog) - v * tau) + half * half
            nv = -half + math.sqrt(disc) if disc > half * half else -half
            nv = min(nv, maxvel[s])
            ac = max(-a, min(a, (nv - v) / tau))
            v2 = max(v + ac * tau, 0.0)
            disp = (v + v2) * 0.5 * tau
            if prog + disp < target[s] - 1e-12:
                prog += disp
                v = v2
                tau = 0.0
            else:
                # the segment ends inside this period: the rest of the period runs on the next one
                rest = target[s] - prog
                if abs(ac) > 1e-12:
                    t1 = (-v + math.sqrt(max(v * v + 2.0 * ac * rest, 0.0))) / ac
                else:
                    t1 = rest / max(v, 1e-12)
                t1 = min(max(t1, 0.0), tau)
                v = max(v + ac * t1, 0.0)
                stop = not tangent[s]
                tau = 0.0 if (stop or tau - t1 < 1e-9 * period) else tau - t1
                s += 1
                prog = 0.0
                if stop:
                    v = 0.0
                    if s < n:
                        wait = hold[s]
        pos, mv = _room(pos, mv, k)
        if s < n:
            _point(s, prog, skind, p0, p1, ctr, e1, e2, rad, straight, target, owner, arc_ax, arc_th0, arc_sgn, arc_sw,
                   arc_r0, arc_r1, arc_dz, pt)
            pos[k] = pt
            mv[k] = owner[s] if wait == 0 else owner[s - 1]  # a dwell starts here: the move before's
        else:
            pos[k] = p1[n - 1]
            mv[k] = owner[n - 1]
        k += 1
    return pos[:k], mv[:k]


def _arc_geometry(moves: MoveTable) -> tuple[NDArray[np.float64], ...]:
    """Per move: arc centre (at the start's linear coordinate), plane axes, start angle, direction, sweep,
    start and end radius, linear travel (zeros for straight moves)."""
    m = len(moves)
    c = np.zeros((m, 3))
    ax = np.zeros((m, 3), dtype=np.int64)
    th0, sgn, r0, r1, dz = (np.zeros(m) for _ in range(5))
    sweep = arc_sweep_rad(moves)
    is_arc = moves.kind >= MOVE_ARC_CW
    for plane, (a1, a2, lin) in PLANE_AXES.items():
        sel = np.flatnonzero(is_arc & (moves.plane == plane))
        if sel.size == 0:
            continue
        s, e, cc = moves.start_mm[sel], moves.end_mm[sel], moves.center_mm[sel]
        ax[sel] = (a1, a2, lin)
        c[sel, a1], c[sel, a2], c[sel, lin] = cc[:, a1], cc[:, a2], s[:, lin]
        th0[sel] = np.arctan2(s[:, a2] - cc[:, a2], s[:, a1] - cc[:, a1])
        sgn[sel] = np.where(moves.kind[sel] == MOVE_ARC_CW, -1.0, 1.0)
        r0[sel] = np.hypot(s[:, a1] - cc[:, a1], s[:, a2] - cc[:, a2])
        r1[sel] = np.hypot(e[:, a1] - cc[:, a1], e[:, a2] - cc[:, a2])
        dz[sel] = e[:, lin] - s[:, lin]
    return c, ax, th0, sgn, sweep, r0, r1, dz


def plan_linuxcnc(moves: MoveTable, limits: PlanLimits, period_s: float, *, corner_tolerance_mm: float = 0.0,
                  lookahead_segments: int = LOOKAHEAD_SEGMENTS, trailing_dwell_s: float = 0.0
                  ) -> tuple[NDArray[np.float64], NDArray[np.int32], NDArray[np.float64]]:
    """Plan a move table as LinuxCNC 2.9's trajectory planner does (module docstring).

    Parameters
    ----------
    moves : MoveTable
        The program's moves, with the path control of every move (``blend_tol_mm``: < 0 exact stop, 0 exact
        path, > 0 ``G64 P``, inf ``G64`` without P; NaN takes ``corner_tolerance_mm``).
    limits : PlanLimits
        Per-axis feed and rapid velocity limits and acceleration limits (the jerk limit is not used).
    period_s : float
        Servo period, s.
    corner_tolerance_mm : float
        Corner tolerance of moves whose program sets no path control, mm.
    lookahead_segments : int
        Segments the final-speed look-ahead spans (LinuxCNC's ``[TRAJ] ARC_BLEND_OPTIMIZATION_DEPTH``).
    trailing_dwell_s : float
        Dwell after the last move, s (``Program.trailing_dwell_s``): the reference stands still that long at
        the end. The dwells before moves are ``moves.dwell_s`` (module docstring, "Dwells").

    Returns
    -------
    pos_mm : ndarray (N, 3)
        Commanded position at every servo period, mm (sample 0: at rest at the first move's start).
    move : ndarray (N,) int32
        Move each sample is on (-1 for sample 0; a blend arc belongs to the move after the corner).
    move_speed_mm_s : ndarray (M,)
        Speed each move may reach (feed and axis limits), mm/s.
    """
    length = move_lengths_mm(moves)
    m = len(moves)
    still = dwell_samples(moves.dwell_s, period_s)
    tail = dwell_samples(trailing_dwell_s, period_s)
    if m == 0 or not (length > 1e-9).any():
        start = moves.start_mm[0] if m else np.zeros(3)
        rows = 1 + (int(still.sum()) + tail if m else 0)  # only dwells: the reference stands still for them
        return (np.repeat(np.asarray(start, dtype=np.float64).reshape(1, 3), rows, axis=0), np.full(rows, -1, np.int32),
                np.zeros(m))

    t_in, t_out = move_directions(moves)
    rapid = moves.kind == MOVE_RAPID
    lim_v = np.where(np.isfinite(limits.velocity_mm_s), limits.velocity_mm_s, 1e12)
    lim_a = np.where(np.isfinite(limits.acceleration_mm_s2), limits.acceleration_mm_s2, 1e12)
    # every move's speed: its feed (a rapid: the rapid limits), capped so that no axis exceeds its limit
    speed = nominal_speed_mm_s(moves, length, limits)
    tol = np.asarray(moves.blend_tol_mm, dtype=np.float64)
    tol = np.where(np.isnan(tol), corner_tolerance_mm, np.where(tol < 0, -1.0, tol))
    c, ax, th0, sgn, sweep, r0, r1, dz = _arc_geometry(moves)
    segs = _segments(np.ascontiguousarray(moves.start_mm, dtype=np.float64),
                     np.ascontiguousarray(moves.end_mm, dtype=np.float64), length, moves.kind.astype(np.int64), tol,
                     rapid, speed, np.ascontiguousarray(t_in), np.ascontiguousarray(t_out), c, ax, r0, r1,
                     lim_v.astype(np.float64), lim_a.astype(np.float64), float(period_s),
                     KINK_RATIO, GAP_CYCLES, _still_before_moves(still, length > 1e-9))
    live = segs[8] > 0.0
    skind, p0, p1, ctr, e1, e2, rad, straight, target, maxvel, acc, tangent, kink, owner = (x[live] for x in segs[:14])
    hold = segs[14]
    if hold.any():
        # a segment left empty (a line run as part of the blend arc after it) hands its dwell to the next one
        run = np.cumsum(hold)[live]
        tail += int(hold.sum() - (run[-1] if run.size else 0))
        hold = np.diff(run, prepend=0)
    else:
        hold = hold[live]
    maxvel = np.minimum(maxvel, target / (MIN_SEGMENT_CYCLES * period_s))
    vf = _final_speeds(target, maxvel, acc, tangent, kink, int(lookahead_segments))
    first = np.ascontiguousarray(moves.start_mm[int(np.flatnonzero(length > 1e-9)[0])], dtype=np.float64)
    pos, mv = _run(skind, p0, p1, ctr, e1, e2, rad, straight, target, maxvel, acc, tangent, vf, owner,
                   float(period_s), first, ax, th0, sgn, sweep, r0, r1, dz, np.ascontiguousarray(hold, dtype=np.int64))
    tail += int(still[int(np.flatnonzero(length > 1e-9)[-1]) + 1:].sum())
    if tail:  # the dwells after the last move that moves: the position holds at its end
        pos = np.concatenate((pos, np.repeat(pos[-1:], tail, axis=0)))
        mv = np.concatenate((mv, np.full(tail, mv[-1], dtype=mv.dtype)))
    return pos, mv.astype(np.int32), speed


def _still_before_moves(still: NDArray[np.int64], moving: NDArray[np.bool_]) -> NDArray[np.int64]:
    """Per move, the dwell samples before it when it moves: its own and those of the moves of zero length since the
    last move that moved (which the segments skip); 0 for a move that does not move."""
    if not still.any():
        return still
    c = np.cumsum(still)
    at = np.flatnonzero(moving)
    out = np.zeros_like(still)
    out[at] = np.diff(c[at], prepend=0)
    return out

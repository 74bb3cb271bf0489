"""What keeps an arc valid when the straight feed before it is corrected: its start stays on its circle.

The rewriter keeps an arc's centre and end point when its start moves (the end point of the G01 command before
it), so a start moved off the circle makes the arc a spiral and a start moved past the end turns a short arc
into a nearly full circle. :func:`arc_start_constraint` finds those commands and their arcs,
:func:`keep_arcs_valid` restricts their corrections (:mod:`ilcnc.learning.learner` reports each change as a
clip with the cause ``"arc start"``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ilcnc.program.model import MOVE_ARC_CW, MOVE_RAPID, Program

__all__ = ["arc_start_constraint", "keep_arcs_valid"]


def arc_start_constraint(program: Program) -> tuple[NDArray[np.int64], dict[str, NDArray[np.float64]]]:
    """Commands whose end point starts an arc, with what keeps that arc valid.

    The rewriter keeps an arc's centre and end point when its start moves, so
    a start moved off the circle makes the arc a spiral (most controls refuse
    a start and end radius that differ by more than a few µm) and a start
    moved past the end along a short arc turns it into a nearly full circle.

    Returns
    -------
    k : ndarray (J,)
        Commands followed directly by an arc.
    geometry : dict
        ``center``, ``start`` (J, 3) mm, ``axes`` (J, 3) plane axes (first,
        second, linear), ``direction`` (J,) +1 counter-clockwise, -1 clockwise,
        ``length_mm`` (J,) arc length in the plane.
    """
    from ilcnc.program.model import MOVE_ARC_CCW, PLANE_AXES

    mv = program.moves
    cm = program.command_moves
    nxt = cm + 1
    ok = nxt < len(mv)
    nk = np.where(ok, mv.kind[np.minimum(nxt, len(mv) - 1)], MOVE_RAPID) if len(mv) else np.zeros(0, np.int8)
    sel = np.flatnonzero(ok & ((nk == MOVE_ARC_CW) | (nk == MOVE_ARC_CCW)))
    arc = nxt[sel]
    axes = np.array([PLANE_AXES[int(p)] for p in mv.plane[arc]], dtype=np.int64).reshape(-1, 3)
    start = mv.start_mm[arc]
    center = mv.center_mm[arc]
    end = mv.end_mm[arc]
    rows = np.arange(arc.size)
    r0 = np.hypot(start[rows, axes[:, 0]] - center[rows, axes[:, 0]], start[rows, axes[:, 1]] - center[rows, axes[:, 1]])
    a0 = np.arctan2(start[rows, axes[:, 1]] - center[rows, axes[:, 1]], start[rows, axes[:, 0]] - center[rows, axes[:, 0]])
    a1 = np.arctan2(end[rows, axes[:, 1]] - center[rows, axes[:, 1]], end[rows, axes[:, 0]] - center[rows, axes[:, 0]])
    direction = np.where(mv.kind[arc] == MOVE_ARC_CCW, 1.0, -1.0)
    sweep = np.mod(direction * (a1 - a0), 2 * np.pi)
    sweep = np.where(sweep < 1e-12, 2 * np.pi, sweep) + 2 * np.pi * np.maximum(mv.turns[arc].astype(np.float64) - 1, 0)
    r1 = np.hypot(end[rows, axes[:, 0]] - center[rows, axes[:, 0]], end[rows, axes[:, 1]] - center[rows, axes[:, 1]])
    return sel, {"center": center, "start": start, "axes": axes, "direction": direction,
                 "length_mm": r0 * sweep, "radius_mm": r0, "end_radius_mm": r1,
                 "radial_mm": np.zeros(arc.size)}


def keep_arcs_valid(u: NDArray[np.float64], sel: NDArray[np.int64], geo: dict[str, NDArray[np.float64]],
                    *, share: float = 0.1) -> NDArray[np.float64]:
    """Restrict the corrections of arc-starting commands to what keeps their arc one the control runs.

    The in-plane part of the correction along the arc's tangent is kept, at
    most ``share`` of the arc's length, and the point is moved along the
    circle (same centre). The radial part is kept within ``geo["radial_mm"]``
    of the end's radius (0: none, the arc stays a true arc; more: the arc
    becomes a spiral whose start and end radii differ by at most that much,
    which controls run as a spiral, see
    :func:`~ilcnc.program.model.arc_off_circle`); the out-of-plane part is
    dropped.
    """
    if sel.size == 0:
        return u
    out = u.copy()
    ax = geo["axes"]
    rows = np.arange(sel.size)
    c1, c2 = geo["center"][rows, ax[:, 0]], geo["center"][rows, ax[:, 1]]
    p1, p2 = geo["start"][rows, ax[:, 0]], geo["start"][rows, ax[:, 1]]
    r = geo["radius_mm"]
    ang = np.arctan2(p2 - c2, p1 - c1)
    # unit tangent in the direction of travel
    t1, t2 = -np.sin(ang) * geo["direction"], np.cos(ang) * geo["direction"]
    uu = u[sel]
    along = uu[rows, ax[:, 0]] * t1 + uu[rows, ax[:, 1]] * t2
    lim = share * geo["length_mm"]
    along = np.clip(along, -lim, lim)
    with np.errstate(invalid="ignore", divide="ignore"):
        dang = np.where(r > 0, along / r, 0.0) * geo["direction"]
    radial = uu[rows, ax[:, 0]] * np.cos(ang) + uu[rows, ax[:, 1]] * np.sin(ang)
    lim_r = geo["radial_mm"]
    r1 = geo["end_radius_mm"]
    rn = np.clip(r + radial, r1 - lim_r, r1 + lim_r)
    rn = np.where(lim_r > 0, rn, r)
    n1, n2 = c1 + rn * np.cos(ang + dang), c2 + rn * np.sin(ang + dang)
    new = np.zeros_like(uu)
    new[rows, ax[:, 0]] = n1 - p1
    new[rows, ax[:, 1]] = n2 - p2
    out[sel] = new
    return out

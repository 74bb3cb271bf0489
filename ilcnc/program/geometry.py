"""Vectorised geometry of a move table: lengths, extents, feed-only times."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ilcnc.program.model import MOVE_ARC_CW, MOVE_RAPID, PLANE_AXES, MoveTable, program_frame_mm


def arc_length_mm(start: list[float], end: list[float], center: list[float], a1: int, a2: int, lin: int, cw: bool,
                  turns: int) -> float:
    """Length of one arc or helix, mm: from ``start`` to ``end`` (mm) about ``center`` in the plane of axes ``a1``,
    ``a2`` (``lin`` the helix axis), clockwise if ``cw``, with ``turns`` full turns (1: less than one)."""
    r = math.hypot(start[a1] - center[a1], start[a2] - center[a2])
    t0 = math.atan2(start[a2] - center[a2], start[a1] - center[a1])
    t1 = math.atan2(end[a2] - center[a2], end[a1] - center[a1])
    sweep = (t0 - t1) if cw else (t1 - t0)
    sweep %= 2 * math.pi
    if sweep < 1e-12:
        sweep = 2 * math.pi
    sweep += 2 * math.pi * (turns - 1)
    return math.hypot(r * sweep, end[lin] - start[lin])


def arc_sweep_rad(moves: MoveTable) -> NDArray[np.float64]:
    """Signed-free sweep angle of every arc (rad, > 0; 0 for straight moves)."""
    n = len(moves)
    sweep = np.zeros(n)
    is_arc = moves.kind >= MOVE_ARC_CW
    if not is_arc.any():
        return sweep
    for plane, (a1, a2, _lin) in PLANE_AXES.items():
        sel = is_arc & (moves.plane == plane)
        if not sel.any():
            continue
        s, e, c = moves.start_mm[sel], moves.end_mm[sel], moves.center_mm[sel]
        t0 = np.arctan2(s[:, a2] - c[:, a2], s[:, a1] - c[:, a1])
        t1 = np.arctan2(e[:, a2] - c[:, a2], e[:, a1] - c[:, a1])
        cw = moves.kind[sel] == MOVE_ARC_CW
        sw = np.where(cw, t0 - t1, t1 - t0) % (2 * np.pi)
        sw = np.where(sw < 1e-12, 2 * np.pi, sw)
        sweep[sel] = sw + 2 * np.pi * (moves.turns[sel] - 1)
    return sweep


def move_lengths_mm(moves: MoveTable) -> NDArray[np.float64]:
    """Path length of every move, mm (arcs and helices exactly)."""
    d = moves.end_mm - moves.start_mm
    length = np.sqrt(np.einsum("ij,ij->i", d, d))
    is_arc = moves.kind >= MOVE_ARC_CW
    if is_arc.any():
        sweep = arc_sweep_rad(moves)
        for plane, (a1, a2, lin) in PLANE_AXES.items():
            sel = is_arc & (moves.plane == plane)
            if not sel.any():
                continue
            s, c = moves.start_mm[sel], moves.center_mm[sel]
            r = np.hypot(s[:, a1] - c[:, a1], s[:, a2] - c[:, a2])
            length[sel] = np.hypot(r * sweep[sel], d[sel, lin])
    return length


def extents_mm(moves: MoveTable, *, program_frame: bool = True) -> NDArray[np.float64]:
    """Axis-aligned extents of all end points (and arc quadrant points), shape (2, 3): min, max."""
    if len(moves) == 0:
        return np.zeros((2, 3))
    def frame(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return program_frame_mm(moves, p) if program_frame else p

    start, end, centre = frame(moves.start_mm), frame(moves.end_mm), frame(moves.center_mm)
    pts = [end, start]
    is_arc = moves.kind >= MOVE_ARC_CW
    if is_arc.any():
        sweep = arc_sweep_rad(moves)
        for plane, (a1, a2, _lin) in PLANE_AXES.items():
            sel = np.flatnonzero(is_arc & (moves.plane == plane))
            if sel.size == 0:
                continue
            # quadrant points of the frame asked for (a turned arc's extremes are those of its own frame)
            s, c = start[sel], centre[sel]
            r = np.hypot(s[:, a1] - c[:, a1], s[:, a2] - c[:, a2])
            t0 = np.arctan2(s[:, a2] - c[:, a2], s[:, a1] - c[:, a1])
            cw = moves.kind[sel] == MOVE_ARC_CW
            for q in range(4):
                ang = q * np.pi / 2
                rel = np.where(cw, t0 - ang, ang - t0) % (2 * np.pi)
                hit = rel <= sweep[sel]
                if not hit.any():
                    continue
                p = s[hit].copy()
                p[:, a1] = c[hit, a1] + r[hit] * np.cos(ang)
                p[:, a2] = c[hit, a2] + r[hit] * np.sin(ang)
                pts.append(p)
    allp = np.concatenate(pts)
    return np.stack([allp.min(axis=0), allp.max(axis=0)])


def feed_time_s(moves: MoveTable, rapid_mm_min: float) -> float:
    """Cycle time at programmed feed, no acceleration (the naive estimate), s; with the dwells before the moves
    (``moves.dwell_s``; a program's dwell after its last move is its ``trailing_dwell_s``)."""
    length = move_lengths_mm(moves)
    feed = np.where(moves.kind == MOVE_RAPID, rapid_mm_min, moves.feed_mm_min)
    feed = np.where(np.isfinite(feed) & (feed > 0), feed, rapid_mm_min)
    return float(np.sum(length / feed) * 60.0 + np.sum(moves.dwell_s))

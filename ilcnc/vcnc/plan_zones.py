"""The ideal interpolator's pieces: every move of a planning group split into zones run at constant speed.

:mod:`ilcnc.vcnc.plan` samples an ideal interpolator that runs each move, or the zones of a move near its
corners, at its own constant speed, and smooths that signal with moving-average filters. This module cuts the
moves into those zones: a slow zone of ``v_corner * span`` (the filters' span, s) before and after a junction
the planner must pass slower than the moves, the move's own speed between, a stand-still of one span at an
exact stop and of its programmed time on a zero-length inverse-time block; a straight line split into
collinear moves gets the zones of the one line it is. All lengths are mm, speeds mm/s, times s.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["Pieces", "slow_zones", "zone_pieces"]

#: Per piece: length (mm), speed (mm/s), index of its move in the group, arc length where it starts within its
#: move (mm), duration (s); and per move its length (mm) (:func:`zone_pieces`).
Pieces = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64], NDArray[np.float64],
               NDArray[np.float64], NDArray[np.float64]]


def slow_zones(v: NDArray[np.float64], vj: NDArray[np.float64], span_s: float
           ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Speed entering and leaving every move (its own, or a slower junction's; a stop is no speed limit here:
    it is a dwell) and the lengths of its slow zones at start and end, mm (``v_corner * span``)."""
    vj_slow = np.where(vj <= 0.0, np.inf, vj)
    v_in = np.minimum(v, np.concatenate(([np.inf], vj_slow)))
    v_out = np.minimum(v, np.concatenate((vj_slow, [np.inf])))
    return v_in, v_out, np.where(v_in < v, v_in * span_s, 0.0), np.where(v_out < v, v_out * span_s, 0.0)


def _chain_zones(move_len: NDArray[np.float64], v: NDArray[np.float64], vj: NDArray[np.float64], span_s: float,
                 chain: NDArray[np.int64], lens: NDArray[np.float64], spds: NDArray[np.float64]) -> None:
    """The slow zones of collinear chains (a straight line split into moves), laid over their moves in place.

    A chain's corner zones are those of the line it is: its first move's entry speed, its last move's exit
    speed, its whole length (the same short-line rule as one move). A move of the chain takes the parts of
    the zones that lie on it; its own speed elsewhere. So a point inserted anywhere on a line, even inside a
    corner's slow zone, leaves the plan as it was (refinement, :mod:`ilcnc.learning.refine`). A join the planner
    stops at (an exact stop) or slows at is not a chain join here. Moves alone in their chain keep what
    :func:`zone_pieces` gave them (bit for bit).
    """
    n = move_len.shape[0]
    # a join limits nothing unless the planner stops or slows there (a written point is collinear to 0.05 µm)
    brk = np.concatenate(([True], (chain[1:] != chain[:-1]) | (vj <= 0.0) | (vj < np.minimum(v[:-1], v[1:]))))
    zc = np.cumsum(brk) - 1
    first = np.flatnonzero(brk)
    last = np.concatenate((first[1:] - 1, [n - 1]))
    multi = (last > first)[zc]
    if not multi.any():
        return
    lc = np.bincount(zc, weights=move_len)
    vj_slow = np.where(vj <= 0.0, np.inf, vj)
    v_in_c = np.minimum(v[first], np.concatenate(([np.inf], vj_slow))[first])
    v_out_c = np.minimum(v[last], np.concatenate((vj_slow, [np.inf]))[last])
    zin_c = np.where(v_in_c < v[first], v_in_c * span_s, 0.0)
    zout_c = np.where(v_out_c < v[last], v_out_c * span_s, 0.0)
    short_c = zin_c + zout_c >= lc
    end_slow = v_out_c <= v_in_c
    zs = np.minimum(np.where(end_slow, zout_c, zin_c), lc)
    zin_c = np.where(short_c, np.where(end_slow, lc - zs, zs), zin_c)
    zout_c = np.where(short_c, np.where(end_slow, zs, lc - zs), zout_c)
    cs = np.cumsum(move_len)
    o = (cs - move_len) - (cs - move_len)[first][zc]
    m = np.flatnonzero(multi)
    ln = move_len[m]
    z_in = np.clip(zin_c[zc[m]] - o[m], 0.0, ln)
    z_out = np.clip(o[m] + ln - (lc[zc[m]] - zout_c[zc[m]]), 0.0, ln)
    z_out = np.minimum(z_out, ln - z_in)
    lens[m, 0], lens[m, 1], lens[m, 2] = z_in, ln - z_in - z_out, z_out
    spds[m, 0] = np.minimum(v_in_c[zc[m]], v[m])
    spds[m, 1] = v[m]
    spds[m, 2] = np.minimum(v_out_c[zc[m]], v[m])


def zone_pieces(move_len: NDArray[np.float64], v: NDArray[np.float64], vj: NDArray[np.float64], span_s: float,
                hold_s: NDArray[np.float64] | None = None, chain: NDArray[np.int64] | None = None) -> Pieces:
    """Split moves into zones with their speeds: slow zones before and after each junction.

    A zone long enough for the filters to finish the speed change before the
    corner (``v_corner * span``) runs at the corner speed; the rest of the move
    at its own speed. A move too short for both zones keeps the slower
    junction's zone (its full length, or the move) and runs the rest at the
    faster junction's speed. A junction whose speed is 0 (an exact stop, tolerance 0) is a
    dwell of one filter span at the vertex: the filters then stop the axes
    there and the path passes through the vertex exactly. A move with a stand-still
    ``hold_s > 0`` (a zero-length inverse-time block) is one piece of speed 0 lasting that long.

    Returns
    -------
    (length, speed, owner, offset, duration, move_length)
        Per piece: length (mm), speed (mm/s), index of its move within the
        group, arc length where it starts within its move, duration (s); and
        per move its length.
    """
    n = move_len.shape[0]
    stop_after = np.concatenate((vj <= 0.0, [False]))
    v_in, v_out, zin, zout = slow_zones(v, vj, span_s)
    slow = (v_in < v) | (v_out < v)
    short = (zin + zout >= move_len) | ((span_s == 0.0) & slow)
    lens = np.stack([zin, move_len - zin - zout, zout, np.zeros(n)], axis=1)
    spds = np.stack([v_in, v, v_out, np.zeros(n)], axis=1)
    # a move too short for both zones: the slower junction's zone keeps its length (the filters finish the
    # speed change before that corner, as on a long move), the rest runs at the faster junction's speed. Not
    # the whole move at the slower speed: that makes the plan jump with the geometry (a point moved by 1 µm
    # that breaks a collinear chain made a 0.07 mm move before a reversal crawl for 0.3 s)
    end_slow = v_out <= v_in
    z_slow = np.minimum(np.where(end_slow, zout, zin), move_len)
    rest = move_len - z_slow
    lens[short] = 0.0
    spds[short] = 0.0
    i_s = np.flatnonzero(short & end_slow)
    lens[i_s, 0], spds[i_s, 0] = rest[i_s], v_in[i_s]
    lens[i_s, 2], spds[i_s, 2] = z_slow[i_s], v_out[i_s]
    i_s = np.flatnonzero(short & ~end_slow)
    lens[i_s, 0], spds[i_s, 0] = z_slow[i_s], v_in[i_s]
    lens[i_s, 2], spds[i_s, 2] = rest[i_s], v_out[i_s]
    if chain is not None and n > 1:
        _chain_zones(move_len, v, vj, span_s, chain, lens, spds)
    with np.errstate(divide="ignore", invalid="ignore"):
        durs = np.where(lens > 0, lens / spds, 0.0)
    durs[:, 3] = np.where(stop_after, span_s, 0.0)
    if hold_s is not None and np.any(hold_s > 0.0):
        still = hold_s > 0.0
        spds[still, 1] = 0.0
        durs[still, 1] = hold_s[still]
        move_len = np.where(still, 1.0, move_len)  # any length: the position is the fraction 0 of a point
    offs = np.concatenate([np.zeros((n, 1)), np.cumsum(lens, axis=1)[:, :3]], axis=1)
    owner = np.repeat(np.arange(n), 4).reshape(n, 4)
    keep = durs > 0
    return lens[keep], spds[keep], owner[keep], offs[keep], durs[keep], move_len

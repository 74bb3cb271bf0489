"""The planner's compiled kernels: a group of moves sampled, filtered and checked in blocks (numba).

:func:`ilcnc.vcnc.plan.plan_moves` plans each group of blended moves with these kernels when numba is
installed: they sample the ideal motion of the group at the servo period (lines, arcs and helices from
:func:`arc_table`), run the moving-average filters that shape its jerk, and check the axes' limits, block
by block, so the reference is never held twice in memory. They repeat, operation for operation, the numpy
path of :mod:`ilcnc.vcnc.plan` (which the tests compare them with).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ilcnc._jit import njit, set_component
from ilcnc.program.model import (
    MOVE_ARC_CW,
    PLANE_AXES,
    MoveTable,
)

__all__ = ["BLOCK_SAMPLES", "arc_table", "group_kernel", "group_range", "group_state"]

#: Samples the compiled planner streams through its stages at once (a buffer of 24 kB, in cache).
BLOCK_SAMPLES = 1024


def arc_table(moves: MoveTable, idx: NDArray[np.int64], sweep_all: NDArray[np.float64]):
    """Per group move: is an arc, its plane axes, centre, radius, start angle and signed sweep
    (computed as :func:`_position_on_moves` does per sample).

    The radius is (k, 2): the start's radius and the end's minus it. An arc whose end misses the circle
    through its start (within the control's tolerance, :func:`~ilcnc.program.model.arc_off_circle`) is a
    spiral whose radius changes in proportion to the angle, as LinuxCNC runs it, and so ends at its end point.
    """
    k = idx.shape[0]
    garc = np.zeros(k, dtype=np.bool_)
    ga1 = np.zeros(k, dtype=np.int64)
    ga2 = np.ones(k, dtype=np.int64)
    gc1, gc2, gt0, gssw = (np.zeros(k) for _ in range(4))
    gr = np.zeros((k, 2))
    is_arc = moves.kind[idx] >= MOVE_ARC_CW
    if is_arc.any():
        for plane, (a1, a2, _lin) in PLANE_AXES.items():
            sel = np.flatnonzero(is_arc & (moves.plane[idx] == plane))
            if sel.size == 0:
                continue
            m_sel = idx[sel]
            c = moves.center_mm[m_sel]
            st = moves.start_mm[m_sel]
            garc[sel] = True
            ga1[sel], ga2[sel] = a1, a2
            gc1[sel], gc2[sel] = c[:, a1], c[:, a2]
            en = moves.end_mm[m_sel]
            gr[sel, 0] = np.hypot(st[:, a1] - c[:, a1], st[:, a2] - c[:, a2])
            gr[sel, 1] = np.hypot(en[:, a1] - c[:, a1], en[:, a2] - c[:, a2]) - gr[sel, 0]
            gt0[sel] = np.arctan2(st[:, a2] - c[:, a2], st[:, a1] - c[:, a1])
            gssw[sel] = np.where(moves.kind[m_sel] == MOVE_ARC_CW, -1.0, 1.0) * sweep_all[m_sel]
    return garc, ga1, ga2, gc1, gc2, gr, gt0, gssw


@njit(cache=True, nogil=True)
def _ideal_block(k0, k1, i, period, total, last, t_end, dur, pspd, owner, offs, mlen, gs, ge, garc, ga1, ga2, gc1, gc2,
                 gr, gt0, gssw, prev, blk, counts):  # pragma: no cover - compiled
    """Samples ``k0:k1`` of the ideal interpolator (:func:`_sample_ideal`) as increments into ``blk``.

    ``i`` is the piece of the previous sample, ``prev`` its position (updated); returns the piece of the last.
    Sample ``last`` (the interpolator's last) is at ``total``.
    """
    npc = t_end.shape[0]
    px, py, pz = prev[0], prev[1], prev[2]
    for k in range(k0, k1):
        t = (k + 1) * period
        if t > total or k == last:
            t = total
        tt = t - 1e-12
        while i < npc - 1 and t_end[i] < tt:  # searchsorted(t_end, t - 1e-12) on increasing t
            i += 1
        o = owner[i]
        frac = (offs[i] + (t - (t_end[i] - dur[i])) * pspd[i]) / mlen[o]
        if frac < 0.0:
            frac = 0.0
        elif frac > 1.0:
            frac = 1.0
        x0 = gs[o, 0] + (ge[o, 0] - gs[o, 0]) * frac
        x1 = gs[o, 1] + (ge[o, 1] - gs[o, 1]) * frac
        x2 = gs[o, 2] + (ge[o, 2] - gs[o, 2]) * frac
        if garc[o]:
            ang = gt0[o] + gssw[o] * frac
            rad = gr[o, 0] + gr[o, 1] * frac
            x0, x1, x2 = set_component(x0, x1, x2, ga1[o], gc1[o] + rad * math.cos(ang))
            x0, x1, x2 = set_component(x0, x1, x2, ga2[o], gc2[o] + rad * math.sin(ang))
        counts[o] += 1
        j = k - k0
        blk[j, 0] = x0 - px
        blk[j, 1] = x1 - py
        blk[j, 2] = x2 - pz
        px, py, pz = x0, x1, x2
    prev[0], prev[1], prev[2] = px, py, pz
    return i


@njit(cache=True, nogil=True)
def _average_block(k0, nb, blk, ln, live_end, ring, csum, slot):  # pragma: no cover - compiled
    """One moving average of length ``ln`` (:func:`_smooth_increments`) over the ``nb`` rows of ``blk``, in place.

    The running sum minus the sum ``ln`` samples back (``ring`` holds the last ``ln`` sums, ``csum`` the sum,
    ``slot[0]`` the ring position), then / ``ln`` in a separate loop, which the compiler vectorises; the
    three running sums are the only dependency chains. Input rows at ``k >= live_end`` are numpy's zero padding.
    """
    c0, c1, c2 = csum[0], csum[1], csum[2]
    sl = slot[0]
    for j in range(nb):
        k = k0 + j
        if k < live_end:
            c0 = c0 + blk[j, 0]
            c1 = c1 + blk[j, 1]
            c2 = c2 + blk[j, 2]
        else:
            c0 = c0 + 0.0
            c1 = c1 + 0.0
            c2 = c2 + 0.0
        o0, o1, o2 = ring[sl, 0], ring[sl, 1], ring[sl, 2]
        ring[sl, 0] = c0
        ring[sl, 1] = c1
        ring[sl, 2] = c2
        if k >= ln:
            blk[j, 0] = c0 - o0
            blk[j, 1] = c1 - o1
            blk[j, 2] = c2 - o2
        else:
            blk[j, 0] = c0
            blk[j, 1] = c1
            blk[j, 2] = c2
        sl += 1
        if sl == ln:
            sl = 0
    flat = blk.reshape(blk.shape[0] * 3)
    fl = float(ln)
    for j in range(3 * nb):
        flat[j] = flat[j] / fl
    csum[0], csum[1], csum[2] = c0, c1, c2
    slot[0] = sl


@njit(cache=True, nogil=True)
def _sum_block(nb, blk, acc, start):  # pragma: no cover - compiled
    """``start + cumsum`` of the increments in ``blk``, in place; ``acc`` carries the running sums."""
    s0, s1, s2 = acc[0], acc[1], acc[2]
    st0, st1, st2 = start[0], start[1], start[2]
    for j in range(nb):
        s0 += blk[j, 0]
        s1 += blk[j, 1]
        s2 += blk[j, 2]
        blk[j, 0] = st0 + s0
        blk[j, 1] = st1 + s1
        blk[j, 2] = st2 + s2
    acc[0], acc[1], acc[2] = s0, s1, s2


@njit(cache=True, nogil=True)
def _check_block(k0, nb, blk, hist, pre, thr_a, thr_j, p2, p3, bad, nbad):  # pragma: no cover - compiled
    """:func:`_violations` on the positions in ``blk``: appends the samples over a limit to ``bad``.

    ``hist`` carries the previous position, first and second differences (9 values); ``pre`` the
    thresholds ``thr · Ts^k · (1 − 1e-12)``: ``|d2 / Ts^2| > thr`` can only hold where ``|d2|`` is above
    it (a margin far above the rounding of either side), so the exact test, numpy's division, is only
    done there. Returns ``(bad, nbad)`` (``bad`` grows by doubling).
    """
    l0, l1, l2, a0, a1, a2, b0, b1, b2 = hist[0], hist[1], hist[2], hist[3], hist[4], hist[5], hist[6], hist[7], hist[8]
    pa0, pa1, pa2, pj0, pj1, pj2 = pre[0], pre[1], pre[2], pre[3], pre[4], pre[5]
    for j in range(nb):
        q0, q1, q2 = blk[j, 0], blk[j, 1], blk[j, 2]
        e0, e1, e2 = q0 - l0, q1 - l1, q2 - l2
        g0, g1, g2 = e0 - a0, e1 - a1, e2 - a2
        h0, h1, h2 = g0 - b0, g1 - b1, g2 - b2
        l0, l1, l2 = q0, q1, q2
        a0, a1, a2 = e0, e1, e2
        b0, b1, b2 = g0, g1, g2
        if not (abs(g0) <= pa0 and abs(g1) <= pa1 and abs(g2) <= pa2 and abs(h0) <= pj0 and abs(h1) <= pj1
                and abs(h2) <= pj2):  # near a limit (or NaN): the exact test, as numpy does it
            k = k0 + j  # the sample of the output (0 = the start) the differences are centred on
            flag = False
            if k >= 1:
                flag = abs(g0 / p2) > thr_a[0] or abs(g1 / p2) > thr_a[1] or abs(g2 / p2) > thr_a[2]
            if k >= 2:
                flag = flag or abs(h0 / p3) > thr_j[0] or abs(h1 / p3) > thr_j[1] or abs(h2 / p3) > thr_j[2]
            if flag:
                if nbad == bad.shape[0]:
                    grown = np.empty(2 * nbad, dtype=np.int64)
                    grown[:nbad] = bad
                    bad = grown
                bad[nbad] = k
                nbad += 1
    hist[0], hist[1], hist[2], hist[3], hist[4], hist[5], hist[6], hist[7], hist[8] = l0, l1, l2, a0, a1, a2, b0, b1, b2
    return bad, nbad


@njit(cache=True, nogil=True)
def group_kernel(t_end, dur, pspd, owner, offs, mlen, n, period, total, gs, ge, garc, ga1, ga2, gc1, gc2, gr, gt0, gssw,
                  start, lens, out, counts, check, thr_a, thr_j, p2, p3):  # pragma: no cover - compiled
    """One pass of a group: ideal interpolator -> moving averages -> running sum -> limit check.

    Hand-written loops because the numpy path makes ~15 passes over (N, 3) arrays, each a fresh
    allocation of up to 1.4 GB for a 16-hour program (and fresh memory costs more to fault in than the
    arithmetic). Here blocks of ``BLOCK_SAMPLES`` samples go through the stages (one small compiled function
    each) in a buffer that stays in cache, and only ``out`` is written. The arithmetic is that of
    :func:`_sample_ideal`, :func:`_smooth_increments`, ``np.cumsum`` and :func:`_violations`, operation
    for operation, so the numbers are the same. The three axes run side by side in scalars: their
    running sums are independent dependency chains the CPU overlaps.

    Writes ``out`` (rows 1.. of the group's output; an empty ``out``: nothing is written, the pass
    only checks and counts), counts the ideal samples on each group move in ``counts`` and returns the
    indices of the samples (0 = the start) where a limit is exceeded.
    """
    st = group_state(start, lens)
    ntot = n
    for f in range(lens.shape[0]):
        ntot += lens[f] - 1
    bad = np.empty(16, dtype=np.int64)
    bad, nbad = group_range(0, ntot, st, t_end, dur, pspd, owner, offs, mlen, n, period, total, gs, ge, garc, ga1,
                             ga2, gc1, gc2, gr, gt0, gssw, start, lens, out, out.shape[0] > 0, counts, check, thr_a,
                             thr_j, p2, p3, bad, 0)
    return bad[:nbad]


@njit(cache=True, nogil=True)
def group_state(start, lens):  # pragma: no cover - compiled
    """The state a group's pass carries from one range of samples to the next (:func:`group_range`):
    filter rings, running sums, ring slots, the previous ideal position, the output's running sums, the
    limit check's history and the interpolator's piece (as floats in ``misc``)."""
    nf = lens.shape[0]
    lmax = 1
    for f in range(nf):
        lmax = max(lmax, lens[f])
    ring = np.zeros((nf, lmax, 3))
    csum = np.zeros((nf, 3))
    slot = np.zeros((nf, 1), dtype=np.int64)
    prev = start.copy()  # previous ideal position
    acc = np.zeros(3)  # running sums of the filtered increments
    hist = np.zeros(9)  # previous output position, first and second differences
    hist[:3] = start
    piece = np.zeros(1, dtype=np.int64)
    return ring, csum, slot, prev, acc, hist, piece


@njit(cache=True, nogil=True)
def group_range(k_begin, k_end, st, t_end, dur, pspd, owner, offs, mlen, n, period, total, gs, ge, garc, ga1, ga2,
                 gc1, gc2, gr, gt0, gssw, start, lens, out, store, counts, check, thr_a, thr_j, p2, p3, bad,
                 nbad):  # pragma: no cover - compiled
    """Output samples ``k_begin:k_end`` of a group's pass (``k_begin`` a multiple of ``BLOCK_SAMPLES``), carrying
    the pass's state ``st`` (:func:`group_state`) on: ranges run one after another give the numbers of
    one run over the whole group. With ``store`` the rows go to ``out[0:k_end - k_begin]``."""
    ring, csum, slot, prev, acc, hist, piece = st
    nf = lens.shape[0]
    nin = np.empty(nf + 1, dtype=np.int64)  # input length of each filter
    nin[0] = n
    for f in range(nf):
        nin[f + 1] = nin[f] + lens[f] - 1
    blk = np.empty((BLOCK_SAMPLES, 3))
    pre = np.empty(6)
    for a in range(3):
        pre[a] = thr_a[a] * p2 * (1.0 - 1e-12)
        pre[3 + a] = thr_j[a] * p3 * (1.0 - 1e-12)
    i = piece[0]
    for k0 in range(k_begin, k_end, BLOCK_SAMPLES):
        nb = min(BLOCK_SAMPLES, k_end - k0)
        k1 = min(k0 + nb, n)
        if k1 > k0:
            i = _ideal_block(k0, k1, i, period, total, n - 1, t_end, dur, pspd, owner, offs, mlen, gs, ge, garc, ga1,
                             ga2, gc1, gc2, gr, gt0, gssw, prev, blk, counts)
        blk[max(k1 - k0, 0):nb] = 0.0  # after the interpolator's last sample: no increment
        for f in range(nf):
            _average_block(k0, nb, blk, lens[f], nin[f], ring[f], csum[f], slot[f])
        _sum_block(nb, blk, acc, start)
        if store:
            out[k0 - k_begin:k0 - k_begin + nb] = blk[:nb]
        if check:
            bad, nbad = _check_block(k0, nb, blk, hist, pre, thr_a, thr_j, p2, p3, bad, nbad)
    piece[0] = i
    return bad, nbad




"""The speed through each junction of a group: the filters' rounding of the polyline around it.

:mod:`ilcnc.vcnc.plan` smooths the ideal interpolator's motion with moving-average filters (module docstring
there). At constant speed ``v`` the filtered point at the time the ideal motion passes junction ``i`` differs
from the junction by

    D_i(v) = v · Σ_j Δu_j · g(|s_j − s_i| / v),        g(δ) = E[(τ − δ)⁺],

summed over the junctions ``j`` within the filters' span (``Δu_j`` the direction change at ``j``, ``s_j`` its
place on the path, mm; ``τ`` the filters' centred kernel as a distribution of time, s). Its acceleration
there, per axis, is

    A_i(v) = v · Σ_j Δu_j · ρ(|s_j − s_i| / v),

``ρ`` the kernel's density (1/s). One junction alone gives the familiar rules: ``D = v·|Δu|·E[τ⁺]``
(``T1/8 + T2²/(24·T1)`` for two filters with ``T1 ≥ T2``) and ``A = v·|Δu|/max(T)``; a polyline dense
along a curve of radius R gives the arc's shrinking ``v²·Var(τ)/(2R)`` and its centripetal ``v²/R``. A chain
of small kinks that alternate, such as the corrections learning writes at points inserted on a line, gives
what the filters make of it: their sum, not the worst kink taken alone. So one rule covers corners, dense
curves and corrected chains.

Each junction's speed is the largest ``v`` (bisection) at which ``|D_i| ≤`` its tolerance and every
``|A_i|`` within the axis's acceleration limit. The speeds of the moves around a junction are taken as
``v`` (the rule is exact at constant speed), so every corner within a slower one's span (``v·`` the
kernel's reach) is passed at that slower speed too (a point on a line, which takes no speed of its own, stays
one: the line plans as it did without it): else a corner whose neighbours' kinks lower its own sum
(a corrected point next to it) is summed at one speed and run through at a faster one (compass, one learning
step: 11.17 µm of rounding for a 10 µm tolerance). The planner's check of the sampled reference against the
axes' limits catches what a change of speed nearby adds. Arcs add no junction: their own curvature is limited
per move (:func:`ilcnc.vcnc.plan._corner_limits`). A junction next to a stand-still block (a zero-length
``G93`` block) is taken alone.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ilcnc._jit import njit

__all__ = ["BLEND_LENGTH_FRACTION", "RoundingTables", "junction_speeds", "junction_tolerances", "rounding_tables"]

#: Largest corner tolerance a program can set (G64, G64 P), as a fraction of the shorter adjoining move:
#: LinuxCNC's own bound (``tcFindBlendTolerance``, tolerance_ratio 0.25).
BLEND_LENGTH_FRACTION = 0.25

#: Bisection steps for a junction's speed: 2⁻⁴⁰ of the moves' own speed.
_BISECTION_STEPS = 40

RoundingTables = tuple[NDArray[np.float64], NDArray[np.float64], float]


def rounding_tables(lengths: tuple[int, ...], period_s: float) -> RoundingTables:
    """``g(δ)`` and ``ρ(δ)`` of the filters of ``lengths`` samples, on a grid of half a period.

    The kernel of discrete moving averages is a set of weights at multiples of the period (of half of it
    when its length is even), so ``g`` is piecewise linear with its breaks on that grid: linear
    interpolation in the table is exact. ``ρ`` is the kernel's weights per second, interpolated linearly.

    Returns
    -------
    g_s : ndarray (m,)
        ``E[(τ − δ)⁺]`` at ``δ = k · step``, s.
    rho_per_s : ndarray (m,)
        The kernel's density at ``δ = k · step``, 1/s.
    step_s : float
        The grid step, s (half the period).
    """
    h = np.ones(1)
    for n in lengths:
        h = np.convolve(h, np.full(n, 1.0 / n))
    tau = (np.arange(h.size) - 0.5 * (h.size - 1)) * period_s
    step = 0.5 * period_s
    delta = np.arange(0, h.size + 2) * step
    g = np.maximum(tau[None, :] - delta[:, None], 0.0) @ h
    rho = np.interp(delta, tau, h / period_s, left=0.0, right=0.0)
    last = int(np.flatnonzero((g > 0) | (rho > 0))[-1]) + 2 if np.any((g > 0) | (rho > 0)) else 1
    return g[:last].copy(), rho[:last].copy(), step


@njit(cache=True, nogil=True)
def _lookup(tab, x):  # pragma: no cover - compiled
    """Linear interpolation in a table on the grid 0, 1, 2, ... (0 beyond it)."""
    k = math.floor(x)
    if k >= tab.shape[0] - 1:
        return 0.0
    f = x - k
    return tab[k] * (1.0 - f) + tab[k + 1] * f


@njit(cache=True, nogil=True)
def _span(i, w, s_mm, tol, alone):  # pragma: no cover - compiled
    """First and last junction of the run around junction ``i`` within ``w`` mm of it along the path; the run
    stops at a junction without a rounding tolerance (an exact stop or path) and at one taken alone."""
    n = s_mm.shape[0]
    lo = i
    hi = i
    while lo > 0 and tol[lo - 1] > 0.0 and not alone[lo - 1] and s_mm[i] - s_mm[lo - 1] < w:
        lo -= 1
    while hi < n - 1 and tol[hi + 1] > 0.0 and not alone[hi + 1] and s_mm[hi + 1] - s_mm[i] < w:
        hi += 1
    return lo, hi


@njit(cache=True, nogil=True)
def _fits(i, v, s_mm, du, tol, acc, alone, g_s, rho, step_s, reach_s, dev, acc_v):  # pragma: no cover - compiled
    """Whether junction ``i`` passed at ``v`` keeps its rounding within ``tol[i]`` and its acceleration within
    ``acc``; ``dev`` and ``acc_v`` are scratch (n_axes,)."""
    na = du.shape[1]
    dev[:] = 0.0
    acc_v[:] = 0.0
    scale = 1.0 / (v * step_s)
    lo, hi = (i, i) if alone[i] else _span(i, v * reach_s, s_mm, tol, alone)
    for j in range(lo, hi + 1):
        x = abs(s_mm[j] - s_mm[i]) * scale
        gj = _lookup(g_s, x)
        rj = _lookup(rho, x)
        if gj == 0.0 and rj == 0.0:
            continue
        for a in range(na):
            dev[a] += du[j, a] * gj
            acc_v[a] += du[j, a] * rj
    d2 = 0.0
    for a in range(na):
        d2 += dev[a] * dev[a]
    if v * math.sqrt(d2) > tol[i]:
        return False
    for a in range(na):
        if v * abs(acc_v[a]) > acc[a]:
            return False
    return True


@njit(cache=True, nogil=True)
def _junction_speeds(s_mm, du, tol, v_cap, acc, alone, g_s, rho, step_s, reach_s):  # pragma: no cover - compiled
    n, na = du.shape
    out = np.full(n, np.inf)
    dev = np.zeros(na)
    acc_v = np.zeros(na)
    for i in range(n):
        hi = v_cap[i]
        if not (tol[i] > 0.0) or not (hi > 0.0) or not math.isfinite(hi):
            continue
        if _fits(i, hi, s_mm, du, tol, acc, alone, g_s, rho, step_s, reach_s, dev, acc_v):
            continue
        lo = 0.0
        for _ in range(_BISECTION_STEPS):
            mid = 0.5 * (lo + hi)
            if mid <= 0.0:
                break
            if _fits(i, mid, s_mm, du, tol, acc, alone, g_s, rho, step_s, reach_s, dev, acc_v):
                lo = mid
            else:
                hi = mid
        out[i] = lo
    # the rule is exact at constant speed: a junction within the span of a slower one is passed at that speed
    # (else the slower one's rounding, summed at its own speed, meets a faster motion around it)
    lim = out.copy()
    for j in range(n):
        vj = lim[j]
        if not math.isfinite(vj) or alone[j]:
            continue
        lo, hi = _span(j, vj * reach_s, s_mm, tol, alone)
        for k in range(lo, hi + 1):
            if out[k] > vj and math.isfinite(v_cap[k]):
                out[k] = vj
    return out


def junction_speeds(s_mm: NDArray[np.float64], du: NDArray[np.float64], tol_mm: NDArray[np.float64],
                    v_cap_mm_s: NDArray[np.float64], acceleration_mm_s2: NDArray[np.float64],
                    alone: NDArray[np.bool_], tables: RoundingTables) -> NDArray[np.float64]:
    """Largest speed through each junction of a group (module docstring).

    Parameters
    ----------
    s_mm : ndarray (m,)
        Place of each junction along the group's path, mm, increasing.
    du : ndarray (m, n_axes)
        Direction change at each junction (unit tangent after minus before).
    tol_mm : ndarray (m,)
        Largest rounding at each junction, mm; 0 where the axes stop (an exact stop or path, handled by the
        caller): such a junction gets ``inf`` and bounds the sums of its neighbours (the motion on its other
        side is not at the neighbours' speed).
    v_cap_mm_s : ndarray (m,)
        The speed of the moves at each junction, mm/s: a junction that keeps its limits at this speed
        gets ``inf`` (no limit of its own).
    acceleration_mm_s2 : ndarray (n_axes,)
        Each axis's acceleration limit, mm/s² (inf: none).
    alone : ndarray (m,) bool
        Junctions taken alone (next to a stand-still block): neither summed with others nor in their sums.
    tables : RoundingTables
        :func:`rounding_tables` of the group's filters.

    Returns
    -------
    ndarray (m,)
        Speed, mm/s (``inf`` where the junction keeps its limits at ``v_cap_mm_s``).
    """
    g_s, rho, step_s = tables
    reach_s = g_s.shape[0] * step_s
    return _junction_speeds(np.ascontiguousarray(s_mm, dtype=np.float64), np.ascontiguousarray(du, dtype=np.float64),
                            np.ascontiguousarray(tol_mm, dtype=np.float64),
                            np.ascontiguousarray(v_cap_mm_s, dtype=np.float64),
                            np.ascontiguousarray(acceleration_mm_s2, dtype=np.float64),
                            np.ascontiguousarray(alone, dtype=np.bool_), g_s, rho, step_s, reach_s)


def junction_tolerances(blend_tol: NDArray[np.float64], default_tol_mm: float, length: NDArray[np.float64],
                        before_len: NDArray[np.float64] | None = None, after_len: NDArray[np.float64] | None = None,
                        ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Corner tolerance of each junction of a group from the path control of its moves (the module docstring of
    :mod:`ilcnc.vcnc.plan`, "Path control").

    Parameters
    ----------
    blend_tol : ndarray (n,)
        ``MoveTable.blend_tol_mm`` of the group's moves, mm (NaN: no program setting).
    default_tol_mm : float
        The profile's corner tolerance, mm, for moves without a program setting.
    length : ndarray (n,)
        Their lengths, mm (inf for a move that bounds no tolerance).
    before_len, after_len : ndarray (n - 1,), optional
        Lengths of the collinear chains before and after each junction (:func:`ilcnc.vcnc.plan._chain_lengths`), mm;
        default the moves' own.

    Returns
    -------
    tol_j : ndarray (n - 1,)
        Largest deviation at the corner between move i and move i + 1, mm (0: stop unless tangent).
    stop : ndarray (n - 1,) bool
        Junctions where the axes stop even when the moves are tangent (``G61.1``).
    """
    tol = np.where(np.isnan(blend_tol), default_tol_mm, blend_tol)
    t_a, t_b = tol[:-1], tol[1:]
    # the move before the corner decides blend or stop; when both blend, the smaller tolerance
    # (an exact-mode move after the corner sets none), as LinuxCNC's tcFindBlendTolerance
    tol_j = np.where(t_a > 0.0, np.where(t_b > 0.0, np.minimum(t_a, t_b), t_a), 0.0)
    # a tolerance the program sets (G64, G64 P) is also bounded as LinuxCNC bounds it: a quarter of the
    # shorter adjoining move (the profile's tolerance is used as it is)
    programmed = ~np.isnan(blend_tol[:-1])
    if programmed.any():
        a = length[:-1] if before_len is None else before_len
        b = length[1:] if after_len is None else after_len
        quarter = BLEND_LENGTH_FRACTION * np.minimum(a, b)
        tol_j = np.where(programmed & (tol_j > 0.0), np.minimum(tol_j, quarter), tol_j)
    return tol_j, t_a < 0.0

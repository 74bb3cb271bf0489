"""A probed surface along the path: heights by bilinear interpolation, and how far a straight move or an arc
whose end points follow the surface departs from it between them.

The senders interpolate between probe points, bCNC and OpenCNCPilot bilinearly (Candle bicubically, the cncjs
extension on the plane of the three nearest probes); ilcnc interpolates bilinearly for every map
(docs/probemaps.md). Outside the probed rectangle the height is the one at the nearest point of its edge
(clamped): the surface beyond the last probe is unknown, and holding the edge value moves the tool by no
more than the probes showed. The callers count the points outside.

Along a straight move inside one grid cell the bilinear height is a quadratic in the path parameter; its
largest distance from the straight line between the end heights is at the middle of the move
(``|h(mid) - (h0 + h1) / 2|``). A move across cells is cut at the cell edges and the pieces' quadratics are
searched exactly (:func:`line_split_fractions`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ilcnc.axislog.heightmap import HeightMap

__all__ = ["arc_height_error_mm", "line_split_fractions", "surface_height_mm"]


def surface_height_mm(hmap: HeightMap, x_mm: NDArray[np.float64], y_mm: NDArray[np.float64]
                      ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Bilinear height of the map at points, clamped to the probed rectangle.

    Parameters
    ----------
    hmap : HeightMap
    x_mm, y_mm : ndarray
        Points, mm (the map's work coordinates), any equal shapes.

    Returns
    -------
    z_mm : ndarray
        Height at each point, mm.
    outside : ndarray of bool
        The point lies outside the probed rectangle (its height is the nearest edge point's).
    """
    x = np.asarray(x_mm, dtype=np.float64)
    y = np.asarray(y_mm, dtype=np.float64)
    xs, ys, z = hmap.x_mm, hmap.y_mm, hmap.z_mm
    tol = 1e-9
    outside = (x < xs[0] - tol) | (x > xs[-1] + tol) | (y < ys[0] - tol) | (y > ys[-1] + tol)
    xc = np.clip(x, xs[0], xs[-1])
    yc = np.clip(y, ys[0], ys[-1])
    i = np.clip(np.searchsorted(xs, xc, side="right") - 1, 0, xs.size - 2)
    j = np.clip(np.searchsorted(ys, yc, side="right") - 1, 0, ys.size - 2)
    a = (xc - xs[i]) / (xs[i + 1] - xs[i])
    b = (yc - ys[j]) / (ys[j + 1] - ys[j])
    h = ((1 - a) * (1 - b) * z[j, i] + a * (1 - b) * z[j, i + 1] + (1 - a) * b * z[j + 1, i]
         + a * b * z[j + 1, i + 1])
    return h, outside


def _h(hmap: HeightMap, p0: NDArray[np.float64], d: NDArray[np.float64], t: NDArray[np.float64]) -> NDArray[np.float64]:
    return surface_height_mm(hmap, p0[0] + d[0] * t, p0[1] + d[1] * t)[0]


def _cell_breaks(hmap: HeightMap, p0: NDArray[np.float64], d: NDArray[np.float64]) -> NDArray[np.float64]:
    """Path parameters 0 < t < 1 where the move crosses a grid line (clamping makes the edges grid lines too)."""
    ts = [0.0, 1.0]
    for axis, grid in ((0, hmap.x_mm), (1, hmap.y_mm)):
        if abs(d[axis]) > 1e-15:
            t = (grid - p0[axis]) / d[axis]
            ts.extend(t[(t > 1e-12) & (t < 1 - 1e-12)].tolist())
    return np.unique(np.array(ts))


def _pieces_error(h0: NDArray[np.float64], hm: NDArray[np.float64], h1: NDArray[np.float64],
                  c0: NDArray[np.float64], c1: NDArray[np.float64]) -> float:
    """Largest |q| over pieces where q = h - chord is quadratic on each: q's values at a piece's ends and middle
    (``h0 - c0``, ``hm - (c0 + c1) / 2``, ``h1 - c1``) fix it; the extremum is at an end or at the vertex."""
    q0, qm, q1 = h0 - c0, hm - 0.5 * (c0 + c1), h1 - c1
    # q(s) = q0 + b s + a s^2 on s in [0, 1]
    a = 2.0 * (q0 + q1 - 2.0 * qm)
    b = q1 - q0 - a
    best = np.maximum(np.abs(q0), np.abs(q1))
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(np.abs(a) > 1e-300, -b / (2.0 * a), -1.0)
    inside = (s > 0.0) & (s < 1.0)
    best = np.where(inside, np.maximum(best, np.abs(q0 + b * s + a * s * s)), best)
    return float(best.max()) if best.size else 0.0


def line_split_fractions(hmap: HeightMap, start_xy_mm: NDArray[np.float64], end_xy_mm: NDArray[np.float64],
                         tol_mm: float) -> tuple[list[float], float]:
    """Where to split a straight move so that straight pieces follow the surface within ``tol_mm``.

    The pieces' end points follow the surface exactly; between them the tool moves straight, the surface
    bilinearly. Splits are placed at grid-cell edges (where the surface's slope along the move changes),
    greedily: each piece as long as its largest height departure stays within ``tol_mm``, as the senders
    split (bCNC at every cell edge) but only where needed. A piece inside one cell that still departs more
    (a strongly warped cell) is halved until it does not.

    Parameters
    ----------
    hmap : HeightMap
    start_xy_mm, end_xy_mm : ndarray (2,)
        The move's ends in the map's coordinates, mm.
    tol_mm : float
        Largest height departure of a piece from the surface, mm.

    Returns
    -------
    fractions : list of float
        Split points 0 < f < 1 along the move (empty: the move follows within the tolerance as it is).
    error_mm : float
        The largest departure of the unsplit move, mm.
    """
    p0 = np.asarray(start_xy_mm, dtype=np.float64)
    d = np.asarray(end_xy_mm, dtype=np.float64) - p0
    breaks = _cell_breaks(hmap, p0, d)
    mids = 0.5 * (breaks[:-1] + breaks[1:])
    hb = _h(hmap, p0, d, breaks)
    hm = _h(hmap, p0, d, mids)

    def err(a: int, b: int) -> float:
        """Departure of the straight piece from break a to break b (every cell piece between, at once)."""
        ta, tb = breaks[a], breaks[b]
        slope = (hb[b] - hb[a]) / (tb - ta)
        c0 = hb[a] + slope * (breaks[a:b] - ta)
        c1 = hb[a] + slope * (breaks[a + 1:b + 1] - ta)
        return _pieces_error(hb[a:b], hm[a:b], hb[a + 1:b + 1], c0, c1)

    n = breaks.size - 1
    whole = err(0, n)
    if whole <= tol_mm:
        return [], whole
    out: list[float] = []
    a = 0
    while a < n:
        # the farthest break b with err(a, b) within the tolerance: galloping, then bisection (a piece's departure
        # grows with its length; O(log n) evaluations instead of one per break)
        good, step = a + 1, 1
        while good + step <= n and err(a, good + step) <= tol_mm:
            good += step
            step *= 2
        lo, hi = good, min(good + step, n + 1)
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if err(a, mid) <= tol_mm:
                lo = mid
            else:
                hi = mid
        b = lo
        if b == a + 1 and err(a, b) > tol_mm:
            # one cell: the piece's departure is its quadratic's, |a| (t1-t0)^2 / 4 over the cell piece; halving
            # a piece quarters it
            ratio = err(a, b) / tol_mm
            parts = 2 ** max(1, math.ceil(math.log(ratio, 4)))
            ta, tb = breaks[a], breaks[b]
            out.extend((ta + (tb - ta) * np.arange(1, parts) / parts).tolist())
        if b < n:
            out.append(float(breaks[b]))
        a = b
    return sorted(out), whole


def arc_height_error_mm(hmap: HeightMap, center_xy_mm: NDArray[np.float64], radius_mm: float, angle0_rad: float,
                        sweep_rad: float, h0_mm: float, h1_mm: float) -> float:
    """Largest departure of a helix (Z linear in the angle, from ``h0_mm`` to ``h1_mm``) from the surface
    along its arc, mm. Sampled at steps of at most a sixteenth of the map's finer grid step (and 32 samples):
    between samples a bilinear surface bends by (step/16)^2 of its twist, far below the tolerances used."""
    step = min(float(np.min(np.diff(hmap.x_mm))), float(np.min(np.diff(hmap.y_mm)))) / 16.0
    n = max(32, math.ceil(abs(sweep_rad) * radius_mm / max(step, 1e-9)))
    n = min(n, 20_000)
    s = np.linspace(0.0, 1.0, n + 1)
    ang = angle0_rad + sweep_rad * s
    h, _ = surface_height_mm(hmap, center_xy_mm[0] + radius_mm * np.cos(ang), center_xy_mm[1] + radius_mm * np.sin(ang))
    return float(np.max(np.abs(h - (h0_mm + (h1_mm - h0_mm) * s))))

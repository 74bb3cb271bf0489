"""Contour error of actual samples against the programmed path.

The programmed path is the move table of a part program: straight moves,
arcs and helices (:class:`PathGeometry`). Three measures of the error of an
actual (measured or simulated) position ``q`` are provided:

* :func:`contour_error` -- the *exact* contour error (seed 000's "actual
  contour error", ACE): the shortest distance from ``q`` to the path, with the
  foot point on the path, the error vector ``foot - q``, where on the path the
  foot is (segment and continuous path parameter ``u``) and a signed in-plane
  error. The search is windowed around a per-sample segment *hint* (the segment
  the reference / interpolator is on at that instant) and looks ``window``
  segments *before and after* the hint -- seed 000's eq. (11) looks backwards
  only, which fails as soon as learning makes an axis lead its reference.
  Given the reference positions, the search also covers a path *length*
  around the hint that grows with the distance between reference and actual
  (the *reach*), so a machine lagging many short segments behind its
  reference is not trapped at a corner (issue 5; :func:`contour_error`,
  *Notes*).
  Distances are exact point-to-segment and point-to-arc distances, never the
  distance to the nearest vertex or reference sample (which over-estimates the
  error by up to half a segment / sample spacing).
* :func:`tangent_error` -- seed 000's Frenet-frame estimate: the component of
  the tracking error ``r - q`` normal to the reference tangent at ``r``.
* :func:`per_command_error` -- the error vector ``E(k)`` at the instant the
  machine passes the end point of G01 command ``k`` (the learning index of
  seed 004), found from where the foot parameter ``u`` crosses the end of the
  command's move.

:func:`summary` gives max / mean / RMS and the worst sample.

Path parameter
--------------
Segments are the moves of the table, one to one, so segment ``i`` *is* move
``i``. The path parameter of a point on segment ``i`` is ``u = i + f`` with
``f`` in ``[0, 1]`` the fraction along the segment by arc length (lines:
exact; arcs and helices: fraction of the swept angle, which is the fraction of
arc length for a constant radius; for an arc whose start and end radii differ
-- a spiral, as programs with rounded I/J produce -- it is the angle fraction).
The end of move ``m`` is ``u = m + 1``, which is also the start of move
``m + 1``, so ``u`` is continuous along a continuous path. Moves that are not
part of the path (rapids, unless ``include_rapids``) stay in the table as
*inactive* segments: they are never a foot, so the path has a gap there.

Arcs, helices, spirals
----------------------
An arc in plane G17/G18/G19 is described in its plane's axes ``(a1, a2)`` =
(X, Y), (Z, X), (Y, Z) and the linear axis ``n`` = Z, Y, X; ``MOVE_ARC_CW`` /
``MOVE_ARC_CCW`` turn clockwise / counter-clockwise seen from ``+n``. The
radius is interpolated linearly in the swept angle from the start radius to
the end radius (equal for a true circle) and the linear axis linearly in the
swept angle (a helix). For a planar circular arc the nearest point is exact:
the radial foot when the sample's angle is inside the sweep, else the nearer
end point. For a helix (or spiral) the radial foot is refined by two Newton
steps on the squared distance, and the end points are candidates too; the
returned distance is always the distance to a real point of the helix, so it
can only over-estimate the true distance. Starting from the radial foot the
over-estimate is at most ``|e_n| sin^2(alpha)`` (``e_n`` the error along the
helix axis, ``alpha`` the lead angle, ``tan(alpha) = pitch / (2 pi R)``): at
most 0.3 % of ``e_n`` for a 3 degree ramp. Newton converges quadratically from
there, so after two steps the remaining over-estimate is far below a
nanometre for any practical helix (the tests compare with a dense sampling).

Signed error
------------
``signed_mm`` is the component of ``q - foot`` along the *left* normal of the
path direction at the foot, in the plane of the foot's move (G17: the XY
plane; arcs: the arc's plane; straight moves use the plane active at that
move, which is XY unless the program selected G18/G19): positive when the
actual point lies to the left of the path. On a counter-clockwise circle a
point inside the circle is positive. A straight move perpendicular to its
plane (a plunge) has no left side: its signed error is 0.

Performance
-----------
The search runs in compiled kernels (numba, the ``_k_*`` functions): one loop
over the samples of a chunk (``chunk`` samples, default 65 536), the chunks
spread over a thread pool (the kernels release the GIL). Per sample the
straight candidates of the window are a few dozen flops on one row of a
segment table (with a reach, the range of a sample comes from two short
scans of the cumulative path length outwards from the window); an arc
candidate is first bounded by its radii and linear range and only evaluated
when it could be nearer than the nearest line (on stellabee1 that leaves
~1 in 10); arc work (trigonometry, the Newton steps of
helices and spirals) runs in separate loops, because a call in the hot loop
slows numba's code down several times. The kernels repeat the arithmetic of
the numpy path (:func:`_search`, :func:`_final`, the walk of :func:`_chunk`)
operation for operation, so the results are the same bit for bit; the numpy
path is the reference they are tested against and runs when numba is
missing. The candidates of a window are compared with one integer minimum per
candidate: the squared distance's IEEE bits with the candidate number in the
lowest bits (the exact distance of the winner is computed afterwards), so the
order they are taken in does not change the result.

Measured on the 2-core development machine, one thread: 12-15 million
samples per CPU-second on straight segments (compass.ngc; numpy path 3.5-6),
8-13 million on stellabee1 (9 % of its samples on spirals; numpy path 3);
both threads: the 57.7 M samples of stellabee1 in 3-7 s, up to half of it
mapping the 5 GB of fresh memory the result occupies.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ilcnc._jit import HAVE_NUMBA, compiled_for, njit, python_kernels, set_component
from ilcnc.contour.path import TWO_PI, PathGeometry, WorkBuffers

if HAVE_NUMBA:  # pragma: no cover - exercised by the environment, not by a test
    from ilcnc._jit import intrinsic  # numba's, made when the first kernel runs (start-up: issue 24)
    from ilcnc._jit import numba_types as types

    def _bits_of_python(x: float) -> int:
        """:func:`_bits_of` as Python (:func:`ilcnc._jit.kernels_for`)."""
        return int(np.float64(x).view(np.int64))

    def _float_of_python(x: int) -> float:
        """:func:`_float_of` as Python."""
        return float(np.int64(x).view(np.float64))

    @intrinsic(_bits_of_python)
    def _bits_of(typingctx, x):
        """The IEEE bits of a float64 as an int64 (``x.view(np.int64)`` of a scalar)."""
        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(types.int64))

        return types.int64(types.float64), codegen

    @intrinsic(_float_of_python)
    def _float_of(typingctx, x):
        """The float64 whose IEEE bits are the int64 ``x``."""
        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(types.float64))

        return types.float64(types.int64), codegen


__all__ = ["DEFAULT_CHUNK", "DEFAULT_WINDOW", "REACH_FACTOR", "ContourError", "contour_error", "guess_hints"]

#: Segments searched before and after the hint segment (the window is 2w + 1 segments).
DEFAULT_WINDOW = 3
#: Samples per chunk: bounds the memory of a search and keeps it in cache.
DEFAULT_CHUNK = 1 << 16
#: Walks (re-centred windows) allowed when the nearest point is at a window edge.
DEFAULT_MAX_WALK = 32
#: Path length searched on each side of the hint segment, in units of ``|r - q| + reference_slack_mm`` (see
#: :func:`contour_error`): 4 finds the nearest point across any stretch of path that turns by up to 120 degrees.
REACH_FACTOR = 4.0

# (first, second, linear) axis of each plane, as RS-274 orders them
_FAR_D2 = 1e299
_SIGN_CLEAR = np.int64(0x7FFFFFFFFFFFFFFF)
#: An arc is left out of a window's search when all its points are farther than the best candidate by more
#: than this (mm): far above the rounding of the distances, far below anything measured.
_PRUNE_MM = 1e-6
#: Take the compiled path (numba); False: the numpy path (the reference the kernels are checked against).
_USE_KERNEL = HAVE_NUMBA


# ---------------------------------------------------------------------------------------------
# Exact contour error
# ---------------------------------------------------------------------------------------------


@dataclass(slots=True, eq=False)
class ContourError:
    """Exact contour error of N samples (see :func:`contour_error`).

    Attributes
    ----------
    dist_mm : float64 (N,)
        Shortest distance from the sample to the path, mm (NaN: no active segment in the window).
    foot_mm : float64 (N, 3)
        Nearest point on the path.
    vector_mm : float64 (N, 3)
        Error vector ``foot - sample`` (seed 000's ``e_c = r_c - q``).
    seg : int64 (N,)
        Segment (= move) of the foot, -1 when none.
    u : float64 (N,)
        Path parameter of the foot, ``seg + fraction``.
    signed_mm : float64 (N,)
        In-plane error, positive when the sample is left of the path direction.
    hint : int64 (N,)
        The segment hint the search started from.
    path : PathGeometry
        The path measured against.
    walked : int
        How many times a sample's window was moved on (see ``max_walk``).
    """

    dist_mm: NDArray[np.float64]
    foot_mm: NDArray[np.float64]
    vector_mm: NDArray[np.float64]
    seg: NDArray[np.int64]
    u: NDArray[np.float64]
    signed_mm: NDArray[np.float64]
    hint: NDArray[np.int64]
    path: PathGeometry = field(repr=False)
    walked: int = 0

    def __len__(self) -> int:
        return int(self.dist_mm.shape[0])


def contour_error(
    path: PathGeometry,
    actual_mm: ArrayLike,
    hint_seg: ArrayLike,
    *,
    reference_mm: ArrayLike | None = None,
    reference_slack_mm: float | ArrayLike = 0.0,
    reach_factor: float = REACH_FACTOR,
    window: int = DEFAULT_WINDOW,
    max_walk: int = DEFAULT_MAX_WALK,
    chunk: int = DEFAULT_CHUNK,
    workers: int | None = None,
) -> ContourError:
    """Exact contour error of actual samples: nearest point on the path, searched around a hint.

    Parameters
    ----------
    path : PathGeometry
        The programmed path.
    actual_mm : (N, 3) or (N, 2) array
        Actual positions, mm (2 columns: Z = 0).
    hint_seg : (N,) int array or int
        Per sample, the segment (move index) the reference is on at that instant.
    reference_mm : (N, 3) or (N, 2) array, optional
        The reference position ``r`` of each sample, mm: a point of its hint segment (or within
        ``reference_slack_mm`` of it). When given, the search of sample ``q`` covers, besides the
        ``window`` segments, every segment with a point within the path length
        ``L = reach_factor * (|r - q| + reference_slack_mm)`` of the hint segment (see *Reach*). A
        sample whose ``r`` is NaN gets the ``window`` segments only. Default: the ``window`` only.
    reference_slack_mm : float or (M,) array
        How far, at most, the reference may be from its hint segment, mm: one value, or one per
        segment of ``path`` (taken at each sample's hint). The planner's corner rounding (its corner
        tolerance), plus, when the reference runs another program than ``path`` (a corrected one),
        how far that program's move is from the segment (for a straight move: the larger of the
        distances between their start points and between their end points).
    reach_factor : float
        ``L`` in units of ``|r - q| + reference_slack_mm``; the default 4 is exact across any stretch
        of path that turns by up to 120 degrees (see *Reach*).
    window : int
        Segments searched before *and* after the hint (2 w + 1 candidates) at least.
    max_walk : int
        When the nearest point lies on the first or last segment of the searched range
        (the true nearest may lie further out, e.g. a lag of more than
        ``window`` short segments), a window of ``window`` segments each side is moved on by
        ``window`` segments in that direction and searched again while that finds a
        strictly nearer point, at most this many times. 0 disables it. The
        walk follows the path, so it finds the nearest point of the stretch of
        path it has covered, not a far-away pass of the tool. It stops at a
        local minimum of the distance (e.g. behind a corner where the distance
        grows before it falls again): the reach does not.
    chunk : int
        Samples processed at once (memory ~ 250 bytes x chunk).
    workers : int, optional
        Threads; default: the number of CPUs.

    Returns
    -------
    ContourError
        Samples whose window holds no active segment get NaN and ``seg = -1``.

    Notes
    -----
    *Reach.* A window counted in segments covers little path where the segments are short: on a
    path of 1-ms blocks a machine lagging 90 blocks behind its reference is out of reach of 3 of
    them, and the walk stops at the first local minimum of the distance. The reach counts path
    length instead. Let ``r`` lie on the hint segment (the reference, which *is* a point of the
    path) and ``f`` be the nearest point of the path to ``q``. Then ``|f - q| <= |r - q| = d`` and
    so ``|f - r| <= 2 d``: the nearest point is within ``2 d`` of the reference *in space*. Along
    the path it can be farther, without bound where the path folds back. If the stretch of path
    between ``r`` and ``f`` turns by ``theta < 180`` degrees in all (the sum of its corner angles
    and arc sweeps; in 3-D the length of its tangent's curve on the unit sphere), its tangents lie
    within ``theta / 2`` of one direction ``t``, so its length ``s`` satisfies
    ``s cos(theta / 2) <= (f - r) . t <= 2 d``: ``s <= 2 d / cos(theta / 2)``. A reach
    ``L = c d`` is thus exact whenever ``cos(theta / 2) >= 2 / c``: ``c = 2`` only on a straight
    path, ``c = 2 sqrt(2)`` up to one right-angled corner, ``c = 4`` (the default) up to 120
    degrees of turning. A reference off its segment by up to ``delta`` (``reference_slack_mm``)
    adds ``delta`` to ``d`` (the point of the segment next to ``r`` is within ``d + delta`` of
    ``q``). Beyond that bound (a reversal between the reference and the foot) the reach still
    searches ``L`` of path, and the walk goes on from its ends as before. The arc-length range is
    measured from the whole hint segment (``r`` may be anywhere on it): the segments ``i`` with
    ``S[i + 1] >= S[h] - L`` and ``S[i] <= S[h + 1] + L`` (:attr:`PathGeometry.cum_length_mm`
    ``S``; ``np.searchsorted`` on it in the numpy path, a scan outwards from the window in the
    kernels, the same integers). The candidates of a range of ``n`` segments are told apart by
    ``log2(n)`` low bits of the squared distance; a range of a million segments leaves 32 bits of
    its mantissa to choose by, far below any distance measured.
    """
    p = np.asarray(actual_mm, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise ValueError("actual_mm must be (N, 2) or (N, 3)")
    if p.shape[1] == 2:
        p = np.column_stack([p, np.zeros(p.shape[0])])
    n = p.shape[0]
    m = len(path)
    h = np.asarray(hint_seg)
    if h.dtype.kind not in "iu" or h.dtype.itemsize > 8 or h.dtype == np.uint64:
        h = h.astype(np.int64)
    hint = np.empty(n, np.int64)  # clipped straight into the int64 field (no int64 copy of an int32 hint first)
    np.clip(np.broadcast_to(h, (n,)), 0, m - 1, out=hint)
    w = int(window)
    if w < 0:
        raise ValueError("window must be >= 0")
    r = None
    if reference_mm is not None:
        r = np.asarray(reference_mm, dtype=np.float64)
        if r.ndim != 2 or r.shape[0] != n or r.shape[1] not in (2, 3):
            raise ValueError("reference_mm must be (N, 2) or (N, 3) like actual_mm")
        if r.shape[1] == 2:
            r = np.column_stack([r, np.zeros(n)])
        r = np.ascontiguousarray(r)
    slack = np.asarray(reference_slack_mm, dtype=np.float64)
    if slack.shape not in ((), (m,)):
        raise ValueError(f"reference_slack_mm must be a number or one per segment ({m},), not {slack.shape}")
    # a fresh writeable copy either way: a per-segment slack through broadcast_to alone stays a read-only view,
    # which numba compiles as a type of its own (a second _k_chunk: 7.5 s of a cold learn, issue 24)
    reach = (float(reach_factor), np.array(np.broadcast_to(slack, (m,)), dtype=np.float64))
    out = ContourError(
        dist_mm=np.empty(n), foot_mm=np.empty((n, 3), order="F"), vector_mm=np.empty((n, 3), order="F"),
        seg=np.empty(n, np.int64), u=np.empty(n), signed_mm=np.empty(n), hint=hint, path=path,
    )
    chunk = max(int(chunk), 1024)
    starts = list(range(0, n, chunk))
    from ilcnc._threads import thread_limit  # the one place that decides ilcnc's thread counts

    nw = workers if workers is not None else thread_limit()
    nw = max(1, min(int(nw), len(starts)))
    walked = [0] * nw
    # in a small job's Python block (ilcnc._jit.kernels_for) the numpy path, unless its windows are wide: it costs
    # a pass per candidate segment, a sample with a window of s segments costs s / (2w + 1) samples' work
    use_kernel = _USE_KERNEL and compiled_for(_extra_window_work(path, p, hint, r, reach, w) if python_kernels() else 0)
    if use_kernel:
        tabs = path._kernel_tables()
        bits = max(1, (2 * w).bit_length())
        pc = np.ascontiguousarray(p)
        hc = hint
        rc = r if r is not None else np.zeros((1, 3))

    def work(k: int) -> None:
        if use_kernel:
            iw, lo, wd2 = np.empty((8, chunk), np.int64), np.empty(chunk, np.bool_), np.empty(chunk)
            for a in starts[k::nw]:
                walked[k] += _k_chunk(*tabs, path.cum_length_mm, pc, hc, rc, r is not None, reach[0], reach[1], a,
                                      min(a + chunk, n), w, bits, int(max_walk), out.dist_mm, out.foot_mm,
                                      out.vector_mm, out.seg, out.u, out.signed_mm, iw, lo, wd2)
            return
        ws = WorkBuffers()
        for a in starts[k::nw]:
            sl = slice(a, min(a + chunk, n))
            walked[k] += _chunk(path, p[sl], hint[sl], None if r is None else r[sl], reach, w, max_walk, out, sl, ws)

    if nw == 1:
        work(0)
    else:
        with ThreadPoolExecutor(max_workers=nw) as ex:
            list(ex.map(work, range(nw)))
    out.walked = int(sum(walked))
    return out


def _extra_window_work(path: PathGeometry, p, h, r, reach: tuple[float, NDArray[np.float64]], w: int) -> int:
    """The numpy search's work beyond one window of ``2w + 1`` segments per sample, in samples (a path of many
    segments shorter than the reach: seed000_corner.ngc, 8,000 one-sample moves, has windows of ~740)."""
    if r is None or p.shape[0] == 0:
        return 0
    lo, hi, _bits = _ranges(path, p[:, 0], p[:, 1], p[:, 2], h, r, reach, w)
    return max(0, int(np.sum(hi - lo + 1)) // (2 * w + 1) - p.shape[0])


def _ranges(path: PathGeometry, px, py, pz, h, r, reach: tuple[float, NDArray[np.float64]], w: int):
    """First and last segment searched for each point and the low bits its candidate numbers take.

    The window ``h - w .. h + w`` (clipped to the path), widened by the reach when the reference
    ``r`` (n, 3) is given (:func:`contour_error`, *Reach*); ``reach``: the factor and the slack of each segment.
    """
    m = len(path)
    lo = np.maximum(h - w, 0)
    hi = np.minimum(h + w, m - 1)
    bits_w = max(1, (2 * w).bit_length())
    if r is None:
        return lo, hi, np.full(h.shape[0], bits_w, np.int64)
    dx, dy, dz = r[:, 0] - px, r[:, 1] - py, r[:, 2] - pz
    reach_mm = reach[0] * (np.sqrt(dx * dx + dy * dy + dz * dz) + reach[1][h])
    ok = reach_mm >= 0.0  # NaN: the window only
    cum = path.cum_length_mm
    lo_r = np.searchsorted(cum[1:], cum[h] - reach_mm, side="left")  # first segment ending at or after s(h) - L
    hi_r = np.searchsorted(cum[:-1], cum[h + 1] + reach_mm, side="right") - 1  # last starting at or before s(h+1) + L
    lo = np.where(ok, np.minimum(lo, lo_r), lo)
    hi = np.where(ok, np.maximum(hi, hi_r), hi)
    bits = np.maximum(np.frexp((hi - lo).astype(np.float64))[1].astype(np.int64), bits_w)  # frexp: the bit length
    return lo, hi, bits


def _search(path: PathGeometry, p, px, py, pz, lo, hi, bits, w: int, ws: WorkBuffers):
    """Nearest of the segments ``lo .. hi`` (per point, within the path) for each point.

    Candidate ``j`` is segment ``lo + j``; ``bits`` (per point) low bits of the key hold it. Returns
    the segment index and its squared distance (``>= _FAR_D2``: none active), both in buffers of
    ``ws``.
    """
    n = lo.shape[0]
    low = (np.int64(1) << bits) - 1
    keep = _SIGN_CLEAR & ~low
    best = ws.f("best", n, np.int64)
    best.fill(np.iinfo(np.int64).max)
    idx = ws.f("idx", n, np.int64)
    span = ws.f("span", n, np.int64)
    np.subtract(hi, lo, out=span)
    nmax = int(span.max()) if n else 0
    # every point takes the candidates 0 .. 2w (those past its range repeat its last one, a key that never
    # wins: same distance, same number); the points of longer ranges take their further ones by themselves
    common = min(nmax, max(2 * w, int(span.min()) if n else 0))
    jj = ws.f("jj", n, np.int64)
    for j in range(common + 1):
        np.minimum(span, j, out=jj)
        np.add(lo, jj, out=idx)
        d2 = path._eval(p, px, py, pz, idx, ws)[0]
        # one integer minimum keeps distance and candidate: the squared distance's bits (sign
        # cleared, so a rounding to -0 or -1e-18 counts as 0) with the candidate in the low bits;
        # non-negative doubles order like their bit patterns, and ties go to the earlier segment
        key = d2.view(np.int64)
        key &= keep
        key |= jj
        np.minimum(best, key, out=best)
    for j in range(common + 1, nmax + 1):
        sel = np.flatnonzero(span >= j)
        d2 = path._eval(p[sel], px[sel], py[sel], pz[sel], lo[sel] + j, ws)[0]
        key = d2.view(np.int64)
        key &= keep[sel]
        key |= np.int64(j)
        best[sel] = np.minimum(best[sel], key)
    seg = ws.f("seg", n, np.int64)
    np.bitwise_and(best, low, out=seg)
    seg += lo
    best &= keep
    return seg, best.view(np.float64)


def _final(path: PathGeometry, p, px, py, pz, seg, ws: WorkBuffers):
    """Exact foot of each point on its segment.

    Returns the fraction, the error-vector columns, the squared distance and the signed
    error (buffers of ``ws``).
    """
    n = seg.shape[0]
    g, wx, wy, wz = ws.f("g", n), ws.f("wx", n), ws.f("wy", n), ws.f("wz", n)
    dx, dy, dz = ws.f("dx", n), ws.f("dy", n), ws.f("dz", n)
    t, vx, vy, vz = ws.f("ft", n), ws.f("vx", n), ws.f("vy", n), ws.f("vz", n)
    d2, signed = ws.f("d2", n), ws.f("signed", n)
    np.take(path._ax, seg, mode="clip", out=g)
    np.subtract(px, g, out=wx)
    np.take(path._ay, seg, mode="clip", out=g)
    np.subtract(py, g, out=wy)
    np.take(path._az, seg, mode="clip", out=g)
    np.subtract(pz, g, out=wz)
    np.take(path._dx, seg, mode="clip", out=dx)
    np.take(path._dy, seg, mode="clip", out=dy)
    np.take(path._dz, seg, mode="clip", out=dz)
    np.multiply(wx, dx, out=t)
    np.multiply(wy, dy, out=g)
    t += g
    np.multiply(wz, dz, out=g)
    t += g
    np.take(path._il2, seg, mode="clip", out=g)
    t *= g
    np.clip(t, 0.0, 1.0, out=t)
    # error vector foot - p = a + t d - p = t d - w
    np.multiply(t, dx, out=vx)
    vx -= wx
    np.multiply(t, dy, out=vy)
    vy -= wy
    np.multiply(t, dz, out=vz)
    vz -= wz
    if path._line_plane:
        # every straight segment in one plane with normal n: signed = -(n . (d x v)) / |d in plane|
        i, j = path._line_plane
        cols_d, cols_v = (dx, dy, dz), (vx, vy, vz)
        np.multiply(cols_d[j], cols_v[i], out=signed)
        np.multiply(cols_d[i], cols_v[j], out=g)
        signed -= g
        np.take(path._inv_inplane, seg, mode="clip", out=g)
        signed *= g
    else:
        np.take(path._lx, seg, mode="clip", out=signed)
        signed *= vx
        np.take(path._ly, seg, mode="clip", out=g)
        g *= vy
        signed += g
        np.take(path._lz, seg, mode="clip", out=g)
        g *= vz
        signed += g
        np.negative(signed, out=signed)
    if path.has_arcs:
        j = np.take(path._arc_of, seg, mode="clip")
        sel = np.flatnonzero(j >= 0)
        if sel.size:
            ps = p[sel]
            _d2, fa, foot, left = path._arc_d2(ps, j[sel], full=True)
            va = foot - ps
            t[sel] = fa
            vx[sel], vy[sel], vz[sel] = va[:, 0], va[:, 1], va[:, 2]
            signed[sel] = -np.einsum("ij,ij->i", va, left)
    np.multiply(vx, vx, out=d2)
    np.multiply(vy, vy, out=g)
    d2 += g
    np.multiply(vz, vz, out=g)
    d2 += g
    return t, vx, vy, vz, d2, signed


def _chunk(path: PathGeometry, p, h, r, reach: tuple[float, NDArray[np.float64]], w: int, max_walk: int,
           out: ContourError, sl: slice, ws: WorkBuffers) -> int:
    n = p.shape[0]
    pt = ws.f("pt", 3 * n).reshape(3, n)
    pt[...] = p.T
    px, py, pz = pt[0], pt[1], pt[2]
    m = len(path)
    lo, hi, bits = _ranges(path, px, py, pz, h, r, reach, w)
    seg, d2k = _search(path, p, px, py, pz, lo, hi, bits, w, ws)
    none = ~(d2k < _FAR_D2)  # no active segment in the window, or a NaN sample
    frac, vx, vy, vz, d2, signed = _final(path, p, px, py, pz, seg, ws)
    walked = 0
    if max_walk > 0 and w < m:
        wlo, whi = lo, hi  # the window each sample searched last (a walk's: c - w .. c + w, not clipped)
        shift = max(w, 1)
        bits_w = max(1, (2 * w).bit_length())
        wk = WorkBuffers()
        for _ in range(max_walk):
            # samples whose nearest segment is the first or last of their window (and the window
            # does not end at the end of the path): the true nearest may lie further out
            at_lo = (seg == wlo) & (wlo > 0)
            at_hi = (seg == whi) & (whi < m - 1)
            ei = np.flatnonzero((at_lo | at_hi) & ~none)
            if ei.size == 0:
                break
            at_lo = at_lo[ei]
            walked += int(ei.size)
            # move the window on so that the current best sits at its other end; a window that
            # finds nothing strictly better leaves the best inside it, which ends that sample's walk
            c = np.clip(np.where(at_lo, seg[ei] - shift, seg[ei] + shift), 0, m - 1)
            wlo, whi = wlo.copy(), whi.copy()
            wlo[ei] = c - w
            whi[ei] = c + w
            pe, pxe, pye, pze = p[ei], px[ei], py[ei], pz[ei]
            s2, _dk = _search(path, pe, pxe, pye, pze, np.maximum(c - w, 0), np.minimum(c + w, m - 1),
                              np.full(ei.size, bits_w, np.int64), w, wk)
            f2, vx2, vy2, vz2, dd, sg2 = _final(path, pe, pxe, pye, pze, s2, wk)
            bi = np.flatnonzero(dd < d2[ei])
            if bi.size == 0:
                break
            e2 = ei[bi]
            seg[e2], frac[e2], d2[e2], signed[e2] = s2[bi], f2[bi], dd[bi], sg2[bi]
            vx[e2], vy[e2], vz[e2] = vx2[bi], vy2[bi], vz2[bi]
    if none.any():
        for a in (d2, frac, vx, vy, vz, signed):
            a[none] = np.nan
    np.sqrt(d2, out=out.dist_mm[sl])
    np.add(seg, frac, out=out.u[sl])
    out.vector_mm[sl, 0] = vx
    out.vector_mm[sl, 1] = vy
    out.vector_mm[sl, 2] = vz
    np.add(px, vx, out=out.foot_mm[sl, 0])
    np.add(py, vy, out=out.foot_mm[sl, 1])
    np.add(pz, vz, out=out.foot_mm[sl, 2])
    out.seg[sl] = seg
    if none.any():
        out.seg[sl][none] = -1
    out.signed_mm[sl] = signed
    return walked


# ---------------------------------------------------------------------------------------------
# The compiled path: the same arithmetic, one sample at a time
# ---------------------------------------------------------------------------------------------
#
# The kernels below are hand-written loops over samples (numba): they repeat, operation for operation,
# the numpy kernels above (:meth:`PathGeometry._line_d2`, ``_arc_d2_fast``, ``_arc_d2``, :func:`_search`,
# :func:`_final`, the walk of :func:`_chunk`), so they give the same numbers. Per sample the numpy path
# makes ~40 passes over chunk-sized buffers for each of the 2w + 1 candidates, and gathers the arcs
# among them with index arrays (which is why arcs cost ~4x a line there); here each candidate is a
# few dozen flops on one row of the segment table.


@njit(cache=True, nogil=True, inline="always")
def _k_npmin(a, b):  # pragma: no cover - compiled
    """``np.minimum`` of two floats (NaN wins)."""
    if a != a or b != b:
        return a + b
    return a if a <= b else b


@njit(cache=True, nogil=True, inline="always")
def _k_mod2pi(x):  # pragma: no cover - compiled
    """``np.mod(x, 2 pi)``."""
    # fmod's exact remainder, without its loop where it is one subtraction (exact by Sterbenz's lemma)
    if -TWO_PI < x < TWO_PI:
        r = x
    elif TWO_PI <= x < 2.0 * TWO_PI:
        r = x - TWO_PI
    elif -2.0 * TWO_PI < x <= -TWO_PI:
        r = x + TWO_PI
    else:
        r = np.fmod(x, TWO_PI)
    if r != 0.0:
        if r < 0.0:
            r += TWO_PI
    else:
        r = 0.0
    return r


@njit(cache=True, nogil=True, inline="always")
def _k_pick(x0, x1, x2, axis):  # pragma: no cover - compiled
    """Component ``axis`` of ``(x0, x1, x2)`` (a tuple indexed at run time is much slower in numba)."""
    if axis == 0:
        return x0
    if axis == 1:
        return x1
    return x2


@njit(cache=True, nogil=True, inline="always")
def _k_clip01(x):  # pragma: no cover - compiled
    if x < 0.0:
        return 0.0
    if x > 1.0:
        return 1.0
    return x


@njit(cache=True, nogil=True, inline="always")
def _k_line_d2(segt, i, px, py, pz):  # pragma: no cover - compiled
    """:meth:`PathGeometry._line_d2` of one point and segment ``i``."""
    wx = px - segt[i, 0]
    wy = py - segt[i, 1]
    wz = pz - segt[i, 2]
    s = wx * segt[i, 3]
    s += segt[i, 4] * wy
    s += segt[i, 5] * wz
    t = _k_clip01(segt[i, 7] * s)
    q = wx * wx + wy * wy
    q += wz * wz
    g = segt[i, 6] * t
    s2 = (s * 2.0 - g) * t
    return q - s2


@njit(cache=True, nogil=True)
def _k_arc_d2(arct, arci, multi_path, ja, p0, p1, p2):  # pragma: no cover - compiled
    """:meth:`PathGeometry._arc_d2` of one point and arc row ``ja``: (d2, f, s, cos, sin) with ``s`` the angle of
    the radial candidate from the start and the cosine and sine of its angle; :func:`_k_arc_foot` gives the rest."""
    q1 = _k_pick(p0, p1, p2, arci[ja, 0]) - arct[ja, 0]
    q2 = _k_pick(p0, p1, p2, arci[ja, 1]) - arct[ja, 1]
    h = _k_pick(p0, p1, p2, arci[ja, 2])
    th0, sg, sw = arct[ja, 16], arct[ja, 2], arct[ja, 21]
    r0, dr = arct[ja, 9], arct[ja, 18]
    lin0, dlin = arct[ja, 10], arct[ja, 19]
    sp = _k_mod2pi(sg * (math.atan2(q2, q1) - th0))
    if multi_path and sw > TWO_PI + 1e-9:
        # several turns: take the turn whose linear-axis position is nearest the sample
        if dlin != 0.0:
            s_ax = (h - lin0) * sw / dlin
        else:
            s_ax = sp
        nt = np.rint((s_ax - sp) / TWO_PI)
        hi = max(math.floor((sw - sp) / TWO_PI), 0.0)
        if nt < 0.0:
            nt = 0.0
        elif nt > hi:
            nt = hi
        sp = sp + TWO_PI * nt
    s = _k_npmin(sp, sw)
    if arct[ja, 20] > 0.0:
        # helix / spiral: two Newton steps on |P(s) - q|^2 from the radial foot
        rp = dr / sw
        kp = dlin / sw
        for _ in range(2):
            th = th0 + sg * s
            c = math.cos(th)
            sn = math.sin(th)
            r = r0 + rp * s
            g1 = r * c - q1
            g2 = r * sn - q2
            g3 = lin0 + kp * s - h
            d1 = rp * c - sg * r * sn
            d2 = rp * sn + sg * r * c
            d3 = kp
            dd1 = -2.0 * sg * rp * sn - r * c
            dd2 = 2.0 * sg * rp * c - r * sn
            num = g1 * d1 + g2 * d2 + g3 * d3
            den = d1 * d1 + d2 * d2 + d3 * d3 + g1 * dd1 + g2 * dd2
            step = num / den if den > 0.0 else 0.0
            s = s - step
            if s < 0.0:
                s = 0.0
            elif s > sw:
                s = sw
    # candidates: the (refined) radial foot, the start and the end point
    f = s / sw
    th = th0 + sg * s
    r = r0 + dr * f
    cth = math.cos(th)
    sth = math.sin(th)
    e1 = r * cth - q1
    e2 = r * sth - q2
    e3 = lin0 + dlin * f - h
    d2 = e1 * e1 + e2 * e2 + e3 * e3
    srad = s
    g1 = arct[ja, 11] - q1
    g2 = arct[ja, 12] - q2
    g3 = lin0 - h
    de = g1 * g1 + g2 * g2 + g3 * g3
    if de < d2:
        d2 = de
        f = 0.0
    g1 = arct[ja, 13] - q1
    g2 = arct[ja, 14] - q2
    g3 = arct[ja, 15] - h
    de = g1 * g1 + g2 * g2 + g3 * g3
    if de < d2:
        d2 = de
        f = 1.0
    return d2, f, srad, cth, sth


@njit(cache=True, nogil=True)
def _k_arc_foot(arct, arci, ja, f, srad, cth, sth):  # pragma: no cover - compiled
    """Foot (x, y, z) at fraction ``f`` of arc row ``ja`` and the unit left normal (x, y, z), as ``_arc_d2(full=True)``.

    ``srad``, ``cth``, ``sth``: the radial candidate of :func:`_k_arc_d2`, whose cosine and sine are reused
    when ``f`` is its fraction (the same angle, bit for bit); the end points' are in the table.
    """
    ia1, ia2, il = arci[ja, 0], arci[ja, 1], arci[ja, 2]
    sg = arct[ja, 2]
    sw = arct[ja, 21]
    r = arct[ja, 9] + arct[ja, 18] * f
    fs = f * sw
    if f == 0.0:
        c, sn = arct[ja, 26], arct[ja, 27]
    elif f == 1.0:
        c, sn = arct[ja, 28], arct[ja, 29]
    elif fs == srad:
        c, sn = cth, sth
    else:
        th = arct[ja, 16] + sg * fs
        c = math.cos(th)
        sn = math.sin(th)
    x0, x1, x2 = set_component(0.0, 0.0, 0.0, ia1, arct[ja, 0] + r * c)
    x0, x1, x2 = set_component(x0, x1, x2, ia2, arct[ja, 1] + r * sn)
    x0, x1, x2 = set_component(x0, x1, x2, il, arct[ja, 10] + arct[ja, 19] * f)
    # left of the direction of travel = -sig * radial unit (CCW: towards the centre)
    l0, l1, l2 = set_component(0.0, 0.0, 0.0, ia1, -sg * c)
    l0, l1, l2 = set_component(l0, l1, l2, ia2, -sg * sn)
    return x0, x1, x2, l0, l1, l2


@njit(cache=True, nogil=True)
def _k_arc_d2_fast(arct, arci, multi_path, ja, p0, p1, p2):  # pragma: no cover - compiled
    """:meth:`PathGeometry._arc_d2_fast` of one point and arc row ``ja``."""
    q1 = _k_pick(p0, p1, p2, arci[ja, 0]) - arct[ja, 0]
    q2 = _k_pick(p0, p1, p2, arci[ja, 1]) - arct[ja, 1]
    h = _k_pick(p0, p1, p2, arci[ja, 2])
    sg = arct[ja, 2]
    cs = (arct[ja, 3] * q2 - arct[ja, 4] * q1) * sg
    ce = (q1 * arct[ja, 6] - q2 * arct[ja, 5]) * sg
    pos_s = cs >= 0.0
    pos_e = ce >= 0.0
    inside = (pos_s and pos_e) if arct[ja, 7] > 0.0 else (pos_s or pos_e)
    inside = inside or arct[ja, 8] > 0.0
    rho = math.hypot(q1, q2)
    r = arct[ja, 9]
    lin = arct[ja, 10]
    if arct[ja, 20] > 0.0:
        f = math.atan2(q2, q1)
        f -= arct[ja, 16]
        f *= sg
        f = _k_mod2pi(f)
        f *= arct[ja, 17]
        f = _k_npmin(f, 1.0)
        r = arct[ja, 18] * f + r
        lin = arct[ja, 19] * f + lin
    rho -= r
    rho *= rho
    d2 = h - lin
    d2 *= d2
    d2 += rho
    g = q1 - arct[ja, 11]
    d2s = g * g
    g = q2 - arct[ja, 12]
    d2s += g * g
    g = h - arct[ja, 10]
    d2s += g * g
    g = q1 - arct[ja, 13]
    d2e = g * g
    g = q2 - arct[ja, 14]
    d2e += g * g
    g = h - arct[ja, 15]
    d2e += g * g
    d2s = _k_npmin(d2s, d2e)
    d2 = _k_npmin(d2, d2s)
    if not inside:
        d2 = d2s
    if multi_path and arct[ja, 21] > TWO_PI + 1e-9:
        d2 = _k_arc_d2(arct, arci, multi_path, ja, p0, p1, p2)[0]
    return d2


_KEY_MAX = np.int64(0x7FFFFFFFFFFFFFFF)


@njit(cache=True, nogil=True, inline="always")
def _k_arc_pruned(arct, arci, ja, px, py, pz, best, keep):  # pragma: no cover - compiled
    """Arc row ``ja`` cannot beat the key ``best``: all its points are farther than the best distance by more
    than :data:`_PRUNE_MM` (its radii and linear range bound it; rounding is ~1e-13 mm)."""
    if best == _KEY_MAX:
        return False
    q1 = _k_pick(px, py, pz, arci[ja, 0]) - arct[ja, 0]
    q2 = _k_pick(px, py, pz, arci[ja, 1]) - arct[ja, 1]
    h3 = _k_pick(px, py, pz, arci[ja, 2])
    rho = math.sqrt(q1 * q1 + q2 * q2)
    gr = max(max(rho - arct[ja, 23], arct[ja, 22] - rho), 0.0)
    gl = max(max(h3 - arct[ja, 25], arct[ja, 24] - h3), 0.0)
    return math.sqrt(gr * gr + gl * gl) > math.sqrt(_float_of(best & keep)) + _PRUNE_MM


@njit(cache=True, nogil=True, inline="always")
def _k_search_lines(segt, arc_of, arct, arci, flags, px, py, pz, lo, hi, keep):  # pragma: no cover - compiled
    """The straight candidates of :func:`_search` (segments ``lo .. hi``) for one point: (best key, an arc
    candidate is left to do).

    The key is the squared distance's bits (sign cleared) with the candidate number ``i - lo`` in the low bits,
    so the minimum does not depend on the order the candidates are taken in (ties go to the lower number): the
    arcs can come afterwards (:func:`_k_search_arcs`), with the nearest line as the bound that prunes them. No
    call to a compiled function here: one in the loop makes numba's code several times slower.
    """
    best = _KEY_MAX
    arcs = False
    for i in range(lo, hi + 1):
        if flags[0] and arc_of[i] >= 0:
            arcs = True
            continue
        key = (_bits_of(_k_line_d2(segt, i, px, py, pz)) & keep) | np.int64(i - lo)
        if key < best:
            best = key
    if arcs:  # pruned by the lines already?
        arcs = False
        for i in range(lo, hi + 1):
            ja = arc_of[i]
            if ja >= 0 and not _k_arc_pruned(arct, arci, ja, px, py, pz, best, keep):
                arcs = True
                break
    return best, arcs


@njit(cache=True, nogil=True)
def _k_search_arcs(arct, arci, arc_of, flags, px, py, pz, lo, hi, keep, best):  # pragma: no cover - compiled
    """The arc candidates of :func:`_search` (segments ``lo .. hi``) for one point, after the lines: the best key."""
    for i in range(lo, hi + 1):
        ja = arc_of[i]
        if ja < 0 or _k_arc_pruned(arct, arci, ja, px, py, pz, best, keep):
            continue
        key = (_bits_of(_k_arc_d2_fast(arct, arci, flags[3] != 0, ja, px, py, pz)) & keep) | np.int64(i - lo)
        if key < best:
            best = key
    return best


@njit(cache=True, nogil=True, inline="always")
def _k_keep(bits):  # pragma: no cover - compiled
    """The bits of a key that hold the squared distance, when ``bits`` low bits hold the candidate."""
    return _KEY_MAX & ~((np.int64(1) << bits) - 1)


@njit(cache=True, nogil=True, inline="always")
def _k_bits(bits_w, lo, hi, w):  # pragma: no cover - compiled
    """Low bits of the keys of the range ``lo .. hi``: those of the window, more for a longer range (as
    :func:`_ranges`)."""
    span = hi - lo
    if span <= 2 * w:
        return bits_w
    b = 0
    while span > 0:
        b += 1
        span >>= 1
    return max(b, bits_w)


@njit(cache=True, nogil=True, inline="always")
def _k_decode(best, lo, bits):  # pragma: no cover - compiled
    """Segment and squared distance (``>= _FAR_D2``: none) of a best key, as :func:`_search` returns them."""
    low = (np.int64(1) << bits) - 1
    return (best & low) + lo, _float_of(best & ~low & _KEY_MAX)


@njit(cache=True, nogil=True)
def _k_search(segt, arc_of, arct, arci, flags, m, px, py, pz, h, w, bits):  # pragma: no cover - compiled
    """:func:`_search` of one point in the window ``h - w .. h + w``: (segment, key of its squared distance as
    float)."""
    keep = _k_keep(bits)
    lo = max(h - w, 0)
    hi = min(h + w, m - 1)
    best, arcs = _k_search_lines(segt, arc_of, arct, arci, flags, px, py, pz, lo, hi, keep)
    if arcs:
        best = _k_search_arcs(arct, arci, arc_of, flags, px, py, pz, lo, hi, keep, best)
    return _k_decode(best, lo, bits)


@njit(cache=True, nogil=True, inline="always")
def _k_final_line(segt, side, flags, px, py, pz, sg):  # pragma: no cover - compiled
    """:func:`_final` of one point on straight segment ``sg``: (fraction, vx, vy, vz, d2, signed)."""
    wx = px - segt[sg, 0]
    wy = py - segt[sg, 1]
    wz = pz - segt[sg, 2]
    dx, dy, dz = segt[sg, 3], segt[sg, 4], segt[sg, 5]
    t = wx * dx
    t += wy * dy
    t += wz * dz
    t = _k_clip01(t * segt[sg, 7])
    vx = t * dx - wx
    vy = t * dy - wy
    vz = t * dz - wz
    if flags[1] >= 0:
        # d[j] v[i] - d[i] v[j] of the plane's axes (i, j) = (0, 1), (2, 0) or (1, 2)
        if flags[1] == 0:
            signed = dy * vx - dx * vy
        elif flags[1] == 2:
            signed = dx * vz - dz * vx
        else:
            signed = dz * vy - dy * vz
        signed *= side[sg, 3]
    else:
        signed = side[sg, 0] * vx
        signed += side[sg, 1] * vy
        signed += side[sg, 2] * vz
        signed = -signed
    d2 = vx * vx
    d2 += vy * vy
    d2 += vz * vz
    return t, vx, vy, vz, d2, signed


@njit(cache=True, nogil=True)
def _k_final_arc(arct, arci, flags, ja, px, py, pz):  # pragma: no cover - compiled
    """:func:`_final` of one point on arc row ``ja``: (fraction, vx, vy, vz, d2, signed)."""
    _d2, t, srad, cth, sth = _k_arc_d2(arct, arci, flags[3] != 0, ja, px, py, pz)
    fx, fy, fz, lx, ly, lz = _k_arc_foot(arct, arci, ja, t, srad, cth, sth)
    vx = fx - px
    vy = fy - py
    vz = fz - pz
    signed = -(vx * lx + vy * ly + vz * lz)
    d2 = vx * vx
    d2 += vy * vy
    d2 += vz * vz
    return t, vx, vy, vz, d2, signed


@njit(cache=True, nogil=True)
def _k_final(segt, side, arc_of, arct, arci, flags, px, py, pz, sg):  # pragma: no cover - compiled
    """:func:`_final` of one point on segment ``sg``: (fraction, vx, vy, vz, d2, signed)."""
    ja = arc_of[sg] if flags[0] else -1
    if ja >= 0:
        return _k_final_arc(arct, arci, flags, ja, px, py, pz)
    return _k_final_line(segt, side, flags, px, py, pz, sg)


@njit(cache=True, nogil=True, inline="always")
def _k_store(k, p, sg, t, vx, vy, vz, d2, sv, dist, foot, vec, segout, u, signed):  # pragma: no cover - compiled
    """Write the result of sample ``k``: foot on segment ``sg`` at fraction ``t``, error vector, ``d2``, signed."""
    segout[k] = sg
    u[k] = sg + t
    dist[k] = math.sqrt(d2)
    vec[k, 0] = vx
    vec[k, 1] = vy
    vec[k, 2] = vz
    foot[k, 0] = p[k, 0] + vx
    foot[k, 1] = p[k, 1] + vy
    foot[k, 2] = p[k, 2] + vz
    signed[k] = sv


@njit(cache=True, nogil=True)
def _k_chunk(segt, side, arc_of, arct, arci, flags, cum, p, hint, ref, use_ref, reach_factor, slack, a0, a1, w, bits,
             max_walk, dist, foot, vec, segout, u, signed, iw, lo, wd2):  # pragma: no cover - compiled
    """:func:`_chunk` of samples ``a0:a1``: writes the outputs and returns the number of walks.

    ``cum``: :attr:`PathGeometry.cum_length_mm`; ``ref`` (N, 3): the reference, read when ``use_ref`` (the
    reach, :func:`_ranges`, with the slack of each segment ``slack`` (M,)). ``bits`` as in :func:`_search` for
    the window of ``w``. Work space, at least ``a1 - a0`` long: ``iw`` (8 rows, int64: walking samples, first
    and last segment of their windows, best keys, samples with arcs to search, samples whose foot is on an arc,
    first and last segment searched per sample), ``lo`` (bool), ``wd2`` (float64). The straight segments are
    done in loops without calls, the arcs afterwards in loops of their own (see :func:`_k_search_lines`).
    """
    m = segt.shape[0]
    nan = np.nan
    walkers, wlo, whi, bestk, pend, arcq, slo, shi = iw[0], iw[1], iw[2], iw[3], iw[4], iw[5], iw[6], iw[7]
    # 1. the range of every sample and its straight candidates
    npend = 0
    for k in range(a0, a1):
        h = hint[k]
        px, py, pz = p[k, 0], p[k, 1], p[k, 2]
        first = max(h - w, 0)
        last = min(h + w, m - 1)
        if use_ref:
            dx = ref[k, 0] - px
            dy = ref[k, 1] - py
            dz = ref[k, 2] - pz
            reach = reach_factor * (math.sqrt(dx * dx + dy * dy + dz * dz) + slack[h])
            if reach >= 0.0:  # NaN: the window only
                x = cum[h] - reach
                while first > 0 and cum[first] >= x:
                    first -= 1
                x = cum[h + 1] + reach
                while last < m - 1 and cum[last + 1] <= x:
                    last += 1
        slo[k - a0] = first
        shi[k - a0] = last
        keep = _k_keep(_k_bits(bits, first, last, w))
        best, arcs = _k_search_lines(segt, arc_of, arct, arci, flags, px, py, pz, first, last, keep)
        bestk[k - a0] = best
        if arcs:
            pend[npend] = k
            npend += 1
    # 2. the arcs not pruned by the nearest line
    for q in range(npend):
        k = pend[q]
        first, last = slo[k - a0], shi[k - a0]
        keep = _k_keep(_k_bits(bits, first, last, w))
        bestk[k - a0] = _k_search_arcs(arct, arci, arc_of, flags, p[k, 0], p[k, 1], p[k, 2], first, last, keep,
                                       bestk[k - a0])
    # 3. the exact foot of every sample on a straight segment (arcs: step 4)
    nwalk = 0
    narc = 0
    walking = max_walk > 0 and w < m
    for k in range(a0, a1):
        first, last = slo[k - a0], shi[k - a0]
        sg, d2k = _k_decode(bestk[k - a0], first, _k_bits(bits, first, last, w))
        if not d2k < _FAR_D2:  # no active segment in the window, or a NaN sample
            segout[k] = -1
            dist[k] = nan
            u[k] = nan
            signed[k] = nan
            for c in range(3):
                vec[k, c] = nan
                foot[k, c] = nan
            continue
        if flags[0] and arc_of[sg] >= 0:
            segout[k] = sg
            arcq[narc] = k
            narc += 1
            continue
        t, vx, vy, vz, d2, sv = _k_final_line(segt, side, flags, p[k, 0], p[k, 1], p[k, 2], sg)
        _k_store(k, p, sg, t, vx, vy, vz, d2, sv, dist, foot, vec, segout, u, signed)
        if walking and ((sg == first and first > 0) or (sg == last and last < m - 1)):
            walkers[nwalk] = k
            wlo[nwalk] = first
            whi[nwalk] = last
            wd2[nwalk] = d2
            nwalk += 1
    # 4. feet on arcs
    for q in range(narc):
        k = arcq[q]
        sg = segout[k]
        t, vx, vy, vz, d2, sv = _k_final_arc(arct, arci, flags, arc_of[sg], p[k, 0], p[k, 1], p[k, 2])
        _k_store(k, p, sg, t, vx, vy, vz, d2, sv, dist, foot, vec, segout, u, signed)
        first, last = slo[k - a0], shi[k - a0]
        if walking and ((sg == first and first > 0) or (sg == last and last < m - 1)):
            walkers[nwalk] = k
            wlo[nwalk] = first
            whi[nwalk] = last
            wd2[nwalk] = d2
            nwalk += 1
    # 5. the walk, as the numpy path does it chunk-wide: every round moves the windows of all samples still at
    #    a window edge, and the rounds stop when no sample got nearer (a sample that does not get nearer
    #    swings back and forth with the others until then: it is counted each time, as there); the order of
    #    the walking samples does not matter
    walked = 0
    shift = max(w, 1)
    for _ in range(max_walk if w < m else 0):
        if nwalk == 0:
            break
        nk = 0
        for q in range(nwalk):
            k = walkers[q]
            sc = segout[k]
            at_lo = sc == wlo[q] and wlo[q] > 0
            at_hi = sc == whi[q] and whi[q] < m - 1
            if at_lo or at_hi:
                walkers[nk] = k
                wlo[nk] = wlo[q]
                whi[nk] = whi[q]
                wd2[nk] = wd2[q]
                lo[nk] = at_lo
                nk += 1
        nwalk = nk
        if nwalk == 0:
            break
        walked += nwalk
        better = 0
        for q in range(nwalk):
            k = walkers[q]
            c = segout[k] - shift if lo[q] else segout[k] + shift
            c = min(max(c, 0), m - 1)
            wlo[q] = c - w
            whi[q] = c + w
            px, py, pz = p[k, 0], p[k, 1], p[k, 2]
            s2, _dk = _k_search(segt, arc_of, arct, arci, flags, m, px, py, pz, c, w, bits)
            t, vx, vy, vz, d2, sv = _k_final(segt, side, arc_of, arct, arci, flags, px, py, pz, s2)
            if d2 < wd2[q]:
                better += 1
                wd2[q] = d2
                _k_store(k, p, s2, t, vx, vy, vz, d2, sv, dist, foot, vec, segout, u, signed)
        if better == 0:
            break
        # samples whose best is (still or again) at an edge of their window walk on
        nk = 0
        for q in range(nwalk):
            k = walkers[q]
            if segout[k] == wlo[q] or segout[k] == whi[q]:
                walkers[nk] = k
                wlo[nk] = wlo[q]
                whi[nk] = whi[q]
                wd2[nk] = wd2[q]
                nk += 1
        nwalk = nk
    return walked


def guess_hints(path: PathGeometry, points_mm: ArrayLike, *, spacing_mm: float | None = None) -> NDArray[np.int64]:
    """Segment hints for samples without a reference (e.g. a measured log): nearest densely sampled path point.

    Only a *hint* for :func:`contour_error` (which then computes the exact
    distance); the path is sampled every ``spacing_mm`` (default: 1/4 of the
    median active segment length) and a KD-tree gives the nearest sample.
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points_mm, dtype=np.float64)
    if p.shape[1] == 2:
        p = np.column_stack([p, np.zeros(p.shape[0])])
    act = np.flatnonzero(path.active)
    if act.size == 0:
        raise ValueError("the path has no active segment")
    lens = path.length_mm[act]
    if spacing_mm is None:
        pos = lens[lens > 0]
        spacing_mm = float(np.median(pos)) / 4.0 if pos.size else 1.0
    nper = np.clip(np.ceil(lens / spacing_mm).astype(np.int64), 1, 10_000) + 1
    seg = np.repeat(act, nper)
    start = np.repeat(np.cumsum(nper) - nper, nper)
    frac = (np.arange(seg.size) - start) / np.repeat(nper - 1, nper)
    pts = path.point_at(seg, frac)
    _d, i = cKDTree(pts).query(p)
    return seg[i]



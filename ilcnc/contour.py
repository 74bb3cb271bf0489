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
Everything is numpy on whole arrays, processed in chunks (``chunk`` samples,
default 65 536) spread over a thread pool (numpy releases the GIL inside its
loops); each thread works in reusable buffers, because re-allocating numpy
temporaries of this size costs more than the arithmetic. The candidates of a
window are compared with one integer minimum per candidate: the squared
distance's IEEE bits with the candidate number in the lowest bits (the
exact distance of the winner is computed afterwards). Measured on the 2-core
development machine (5 million samples, ``window=2``, line segments, one
thread): 6.3-6.9 million samples per CPU-second, which was 3.4-4.5 million
per second of wall time while other jobs kept both cores busy (load average
3-4); a second thread adds throughput only when a core is free. Arc-heavy programs (every third
segment an arc) run at about 1.6 million samples per CPU-second.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ilcnc.program.model import MOVE_ARC_CCW, MOVE_ARC_CW, MOVE_LINE, MOVE_RAPID, PLANE_AXES, PLANE_XY, MoveTable

__all__ = [
    "DEFAULT_CHUNK",
    "DEFAULT_WINDOW",
    "CommandError",
    "ContourError",
    "PathGeometry",
    "contour_error",
    "guess_hints",
    "per_command_error",
    "sample_command",
    "summary",
    "tangent_error",
]

#: Segments searched before and after the hint segment (the window is 2w + 1 segments).
DEFAULT_WINDOW = 3
#: Samples per chunk: bounds the memory of a search and keeps it in cache.
DEFAULT_CHUNK = 1 << 16
#: Walks (re-centred windows) allowed when the nearest point is at a window edge.
DEFAULT_MAX_WALK = 32

# (first, second, linear) axis of each plane, as RS-274 orders them
# Coordinate of an inactive segment's start: far away, yet its squared distance (~3e300) stays finite
_FAR = 1e150
_FAR_D2 = 1e299
_TWO_PI = 2.0 * math.pi
_SIGN_CLEAR = np.int64(0x7FFFFFFFFFFFFFFF)


class _Work:
    """Reusable work buffers of one thread (numpy temporaries of a few hundred kB each would
    otherwise be freed and re-mapped by malloc on every call, which costs more than the arithmetic)."""

    def __init__(self) -> None:
        self._buf: dict[str, np.ndarray] = {}

    def f(self, name: str, n: int, dtype: type = np.float64) -> np.ndarray:
        b = self._buf.get(name)
        if b is None or b.shape[0] < n or b.dtype != dtype:
            b = np.empty(max(n, 1024), dtype)
            self._buf[name] = b
        return b[:n]


# ---------------------------------------------------------------------------------------------
# The path
# ---------------------------------------------------------------------------------------------


class PathGeometry:
    """The programmed path as numpy arrays of segments (one segment per move).

    Build it with :meth:`from_moves` (a program's :class:`MoveTable`) or
    :meth:`from_polyline` (a chain of straight segments).

    Attributes
    ----------
    start_mm, end_mm : float64 (M, 3)
        Start and end point of each segment, mm.
    kind : int8 (M,)
        Move kind (``MOVE_RAPID``, ``MOVE_LINE``, ``MOVE_ARC_CW``, ``MOVE_ARC_CCW``).
    active : bool (M,)
        Segment belongs to the path (inactive ones are never a foot point).
    plane : int8 (M,)
        17, 18 or 19.
    line : int32 (M,)
        Source line of the move (0 when unknown).
    command : int32 (M,)
        G01 command index k of the move, -1 when the move is not a command.
    length_mm : float64 (M,)
        Path length of each segment (arcs and helices exactly).
    sweep_rad : float64 (M,)
        Swept angle of arcs (0 for straight segments).
    """

    def __init__(
        self,
        start_mm: ArrayLike,
        end_mm: ArrayLike,
        kind: ArrayLike,
        *,
        center_mm: ArrayLike | None = None,
        plane: ArrayLike | None = None,
        turns: ArrayLike | None = None,
        active: ArrayLike | None = None,
        line: ArrayLike | None = None,
        command: ArrayLike | None = None,
    ) -> None:
        s = np.array(start_mm, dtype=np.float64).reshape(-1, 3)
        e = np.array(end_mm, dtype=np.float64).reshape(-1, 3)
        m = s.shape[0]
        if e.shape[0] != m:
            raise ValueError("start_mm and end_mm must have the same length")
        if m == 0:
            raise ValueError("a path needs at least one segment")
        self.start_mm = s
        self.end_mm = e
        self.kind = np.asarray(kind, dtype=np.int8).reshape(m)
        self.plane = np.full(m, PLANE_XY, np.int8) if plane is None else np.asarray(plane, np.int8).reshape(m)
        self.active = np.ones(m, bool) if active is None else np.asarray(active, bool).reshape(m).copy()
        self.line = np.zeros(m, np.int32) if line is None else np.asarray(line, np.int32).reshape(m)
        self.command = np.full(m, -1, np.int32) if command is None else np.asarray(command, np.int32).reshape(m)
        center = np.full((m, 3), np.nan) if center_mm is None else np.array(center_mm, np.float64).reshape(m, 3)
        turns_a = np.ones(m, np.int16) if turns is None else np.asarray(turns, np.int16).reshape(m)
        self.center_mm = center
        self._build(turns_a)

    # -- construction ---------------------------------------------------------------------------

    @classmethod
    def from_moves(cls, moves: MoveTable, *, include_rapids: bool = False) -> PathGeometry:
        """The path of a move table: feed moves (lines, arcs, helices), rapids only if asked.

        Segment ``i`` is move ``i``; excluded rapids are inactive segments (a gap).
        """
        active = moves.kind != MOVE_RAPID if not include_rapids else np.ones(len(moves), bool)
        return cls(
            moves.start_mm, moves.end_mm, moves.kind, center_mm=moves.center_mm, plane=moves.plane,
            turns=moves.turns, active=active, line=moves.line, command=moves.command,
        )

    @classmethod
    def from_polyline(cls, vertices: ArrayLike, *, commands: bool = True) -> PathGeometry:
        """A chain of straight segments through ``vertices`` (V, 2 or 3); segment k is command k if ``commands``."""
        v = np.asarray(vertices, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] not in (2, 3) or v.shape[0] < 2:
            raise ValueError("vertices must be (V >= 2, 2 or 3)")
        if v.shape[1] == 2:
            v = np.column_stack([v, np.zeros(v.shape[0])])
        m = v.shape[0] - 1
        cmd = np.arange(m, dtype=np.int32) if commands else None
        return cls(v[:-1], v[1:], np.full(m, MOVE_LINE, np.int8), command=cmd)

    def _build(self, turns: NDArray[np.int16]) -> None:
        m = len(self)
        s, e, kind = self.start_mm, self.end_mm, self.kind
        is_arc = (kind == MOVE_ARC_CW) | (kind == MOVE_ARC_CCW)
        self.is_arc = is_arc
        self.has_arcs = bool(is_arc.any())
        d = e - s
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        # straight-segment data (arcs get their chord, overridden by the arc evaluation)
        l2 = np.einsum("ij,ij->i", d, d)
        with np.errstate(divide="ignore"):
            il2 = np.where(l2 > 0.0, 1.0 / np.where(l2 > 0.0, l2, 1.0), 0.0)
        a = s.copy()
        inactive = ~self.active
        a[inactive] = _FAR
        d_l = d.copy()
        d_l[inactive] = 0.0
        l2 = np.where(inactive, 0.0, l2)
        il2 = np.where(inactive, 0.0, il2)
        self._ax, self._ay, self._az = (np.ascontiguousarray(a[:, i]) for i in range(3))
        self._dx, self._dy, self._dz = (np.ascontiguousarray(d_l[:, i]) for i in range(3))
        self._l2 = np.ascontiguousarray(l2)
        self._il2 = np.ascontiguousarray(il2)
        # left normal (in the move's plane) of straight segments, unit, 0 if none
        left = np.zeros((m, 3))
        for pl, (a1, a2, _n) in PLANE_AXES.items():
            sel = self.plane == pl
            if not sel.any():
                continue
            t1, t2 = d[sel, a1], d[sel, a2]
            nn = np.hypot(t1, t2)
            ok = nn > 0
            inv = np.where(ok, 1.0 / np.where(ok, nn, 1.0), 0.0)
            lv = np.zeros((int(sel.sum()), 3))
            lv[:, a1] = -t2 * inv
            lv[:, a2] = t1 * inv
            left[sel] = lv
        self._left = left
        self._lx, self._ly, self._lz = (np.ascontiguousarray(left[:, i]) for i in range(3))
        # fast signed error when all straight segments share a plane: its in-plane axes and 1/|d in plane|
        line_planes = np.unique(self.plane[~is_arc])
        self._line_plane: tuple[int, int] | None = None
        if line_planes.size == 1:
            a1, a2, _n = PLANE_AXES[int(line_planes[0])]
            self._line_plane = (a1, a2)
            nn = np.hypot(d[:, a1], d[:, a2])
            self._inv_inplane = np.where(nn > 0, 1.0 / np.where(nn > 0, nn, 1.0), 0.0)

        # arc table (only arcs), indexed through _arc_of (-1 for straight segments)
        sweep = np.zeros(m)
        self._arc_of = np.full(m, -1, np.int64)
        ai = np.flatnonzero(is_arc)
        if ai.size:
            plane = self.plane[ai]
            bad = ~np.isin(plane, (17, 18, 19))
            if bad.any():
                raise ValueError(f"arc segment {int(ai[bad][0])} has plane {int(plane[bad][0])} (expected 17, 18 or 19)")
            c = self.center_mm[ai]
            axes = np.array([PLANE_AXES[int(p)] for p in (17, 18, 19)])
            ax3 = axes[plane - 17]  # (A, 3): a1, a2, lin
            rows = np.arange(ai.size)
            sa, ea = s[ai], e[ai]
            ia1, ia2, il = ax3[:, 0], ax3[:, 1], ax3[:, 2]
            c1, c2 = c[rows, ia1], c[rows, ia2]  # the centre's linear-axis coordinate is not used
            bad = ~(np.isfinite(c1) & np.isfinite(c2))
            if bad.any():
                raise ValueError(f"arc segment {int(ai[bad][0])} has no centre in its plane")
            s1, s2 = sa[rows, ia1] - c1, sa[rows, ia2] - c2
            e1, e2 = ea[rows, ia1] - c1, ea[rows, ia2] - c2
            r0 = np.hypot(s1, s2)
            r1 = np.hypot(e1, e2)
            th0 = np.arctan2(s2, s1)
            th1 = np.arctan2(e2, e1)
            sig = np.where(kind[ai] == MOVE_ARC_CCW, 1.0, -1.0)
            sw = np.where(sig < 0, th0 - th1, th1 - th0) % _TWO_PI
            sw = np.where(sw < 1e-12, _TWO_PI, sw) + _TWO_PI * (np.maximum(turns[ai], 1) - 1)
            sweep[ai] = sw
            self._arc_of[ai] = rows
            self._a_ia1, self._a_ia2, self._a_il = ia1.astype(np.int64), ia2.astype(np.int64), il.astype(np.int64)
            self._a_c1, self._a_c2 = c1, c2
            self._a_r0, self._a_dr = r0, r1 - r0
            self._a_th0, self._a_sig, self._a_sw = th0, sig, sw
            self._a_lin0 = sa[rows, il]
            self._a_dlin = ea[rows, il] - sa[rows, il]
            self._a_curved = (np.abs(self._a_dr) > 0.0) | (np.abs(self._a_dlin) > 0.0)
            self._a_multi = bool((sw > _TWO_PI + 1e-9).any())
            # for the fast candidate test: start / end in plane coordinates relative to the centre,
            # their unit directions, the end's linear coordinate, sweep class
            self._a_s1, self._a_s2, self._a_e1, self._a_e2 = s1, s2, e1, e2
            r0s = np.where(r0 > 0, r0, 1.0)
            r1s = np.where(r1 > 0, r1, 1.0)
            self._a_us1, self._a_us2 = np.where(r0 > 0, s1 / r0s, 1.0), np.where(r0 > 0, s2 / r0s, 0.0)
            self._a_ue1, self._a_ue2 = np.where(r1 > 0, e1 / r1s, 1.0), np.where(r1 > 0, e2 / r1s, 0.0)
            self._a_lin1 = ea[rows, il]
            self._a_small = sw <= math.pi
            self._a_round = sw >= _TWO_PI * (1.0 - 1e-12)
            self._a_multi_of = sw > _TWO_PI + 1e-9
            self._a_all_curved = bool(self._a_curved.all())
            self._a_tab = np.array([
                c1, c2, sig, self._a_us1, self._a_us2, self._a_ue1, self._a_ue2, self._a_small, self._a_round,
                r0, self._a_lin0, s1, s2, e1, e2, self._a_lin1, th0, 1.0 / sw, r1 - r0, self._a_dlin,
                self._a_curved,
            ], dtype=np.float64)
            planes = np.unique(plane)
            self._arc_plane: tuple[int, int, int] | None = PLANE_AXES[int(planes[0])] if planes.size == 1 else None
            # length: helix exactly, spiral by its mean radius
            length[ai] = np.hypot(0.5 * (r0 + r1) * sw, self._a_dlin)
            # for straight-line data of arcs keep the chord (harmless, always overridden)
        self.sweep_rad = sweep
        self.length_mm = length

    # -- basic properties -----------------------------------------------------------------------

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    @property
    def n_segments(self) -> int:
        """Number of segments M (= moves)."""
        return len(self)

    @property
    def feed(self) -> NDArray[np.bool_]:
        """Segment is an active feed move (not a rapid)."""
        return self.active & (self.kind != MOVE_RAPID)

    @property
    def move_of_command(self) -> NDArray[np.int64]:
        """Segment (move) index ``m_k`` of every G01 command k, shape (K,)."""
        return np.flatnonzero(self.command >= 0)

    @property
    def n_commands(self) -> int:
        """Number of G01 commands K."""
        return int(np.count_nonzero(self.command >= 0))

    # -- points and tangents --------------------------------------------------------------------

    def point_at(self, seg: ArrayLike, frac: ArrayLike) -> NDArray[np.float64]:
        """Point of segment ``seg`` at fraction ``frac`` (by arc length / swept angle), (N, 3) mm."""
        seg = np.asarray(seg, dtype=np.int64)
        frac = np.asarray(frac, dtype=np.float64)
        seg, frac = np.broadcast_arrays(seg, frac)
        seg, frac = seg.ravel(), frac.ravel()
        out = self.start_mm[seg] + frac[:, None] * (self.end_mm[seg] - self.start_mm[seg])
        if self.has_arcs:
            j = self._arc_of[seg]
            sel = np.flatnonzero(j >= 0)
            if sel.size:
                ja = j[sel]
                s = frac[sel] * self._a_sw[ja]
                th = self._a_th0[ja] + self._a_sig[ja] * s
                r = self._a_r0[ja] + self._a_dr[ja] * frac[sel]
                out[sel, self._a_ia1[ja]] = self._a_c1[ja] + r * np.cos(th)
                out[sel, self._a_ia2[ja]] = self._a_c2[ja] + r * np.sin(th)
                out[sel, self._a_il[ja]] = self._a_lin0[ja] + self._a_dlin[ja] * frac[sel]
        return out

    def point_at_u(self, u: ArrayLike) -> NDArray[np.float64]:
        """Point at path parameter ``u`` (``u = M`` is the end of the last segment), (N, 3) mm."""
        seg, frac = self.split_u(u)
        return self.point_at(seg, frac)

    def split_u(self, u: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Segment index and fraction of path parameters (``u = i + 1`` is the end of segment i)."""
        u = np.asarray(u, dtype=np.float64).ravel()
        seg = np.clip(np.ceil(u) - 1, 0, len(self) - 1).astype(np.int64)
        return seg, np.clip(u - seg, 0.0, 1.0)

    def tangent_at(self, seg: ArrayLike, frac: ArrayLike) -> NDArray[np.float64]:
        """Unit tangent (direction of travel) at ``(seg, frac)``, (N, 3); 0 for zero-length segments."""
        seg = np.asarray(seg, dtype=np.int64)
        frac = np.asarray(frac, dtype=np.float64)
        seg, frac = np.broadcast_arrays(seg, frac)
        seg, frac = seg.ravel(), frac.ravel()
        t = self.end_mm[seg] - self.start_mm[seg]
        if self.has_arcs:
            j = self._arc_of[seg]
            sel = np.flatnonzero(j >= 0)
            if sel.size:
                ja = j[sel]
                sw = self._a_sw[ja]
                th = self._a_th0[ja] + self._a_sig[ja] * frac[sel] * sw
                r = self._a_r0[ja] + self._a_dr[ja] * frac[sel]
                dr = self._a_dr[ja] / sw
                sg = self._a_sig[ja]
                t[sel, self._a_ia1[ja]] = dr * np.cos(th) - sg * r * np.sin(th)
                t[sel, self._a_ia2[ja]] = dr * np.sin(th) + sg * r * np.cos(th)
                t[sel, self._a_il[ja]] = self._a_dlin[ja] / sw
        n = np.sqrt(np.einsum("ij,ij->i", t, t))
        return t / np.where(n > 0, n, 1.0)[:, None]

    def left_normal_at(self, seg: ArrayLike, frac: ArrayLike) -> NDArray[np.float64]:
        """Unit left normal of the path direction in the segment's plane, (N, 3); 0 if undefined."""
        seg = np.asarray(seg, dtype=np.int64)
        frac = np.asarray(frac, dtype=np.float64)
        seg, frac = np.broadcast_arrays(seg, frac)
        seg, frac = seg.ravel(), frac.ravel()
        out = self._left[seg]
        if self.has_arcs:
            j = self._arc_of[seg]
            sel = np.flatnonzero(j >= 0)
            if sel.size:
                ja = j[sel]
                th = self._a_th0[ja] + self._a_sig[ja] * frac[sel] * self._a_sw[ja]
                sg = self._a_sig[ja]
                lv = np.zeros((sel.size, 3))
                rows = np.arange(sel.size)
                # left of the direction of travel = -sig * radial unit (CCW: towards the centre)
                lv[rows, self._a_ia1[ja]] = -sg * np.cos(th)
                lv[rows, self._a_ia2[ja]] = -sg * np.sin(th)
                out[sel] = lv
        return out

    # -- distance kernels -----------------------------------------------------------------------

    def _line_d2(self, px, py, pz, idx, ws: _Work):
        """Squared distance to the straight segments ``idx`` and the fraction of the foot.

        Works in the buffers of ``ws`` (no allocation); returns views of them.
        """
        n = idx.shape[0]
        g, wx, wy, wz, s, t = ws.f("g", n), ws.f("wx", n), ws.f("wy", n), ws.f("wz", n), ws.f("s", n), ws.f("t", n)
        np.take(self._ax, idx, mode="clip", out=g)
        np.subtract(px, g, out=wx)
        np.take(self._ay, idx, mode="clip", out=g)
        np.subtract(py, g, out=wy)
        np.take(self._az, idx, mode="clip", out=g)
        np.subtract(pz, g, out=wz)
        np.take(self._dx, idx, mode="clip", out=g)
        np.multiply(wx, g, out=s)
        np.take(self._dy, idx, mode="clip", out=g)
        g *= wy
        s += g
        np.take(self._dz, idx, mode="clip", out=g)
        g *= wz
        s += g
        np.take(self._il2, idx, mode="clip", out=t)
        t *= s
        np.clip(t, 0.0, 1.0, out=t)
        wx *= wx
        wy *= wy
        wz *= wz
        wx += wy
        wx += wz
        # |w - t d|^2 = |w|^2 - t (2 s - t |d|^2)
        np.take(self._l2, idx, mode="clip", out=g)
        g *= t
        s *= 2.0
        s -= g
        s *= t
        wx -= s
        return wx, t

    def _arc_d2(self, p: NDArray[np.float64], ja: NDArray[np.int64], *, full: bool = False):
        """Nearest point of arcs ``ja`` (arc-table rows) to points ``p`` (n, 3), precisely.

        Returns the squared distance and the fraction of the foot; with ``full`` also the foot
        (n, 3) and the unit left normal in the arc's plane (n, 3).
        """
        n = ja.size
        rows = np.arange(n)
        q1 = p[rows, self._a_ia1[ja]] - self._a_c1[ja]
        q2 = p[rows, self._a_ia2[ja]] - self._a_c2[ja]
        h = p[rows, self._a_il[ja]]
        th0, sg, sw = self._a_th0[ja], self._a_sig[ja], self._a_sw[ja]
        r0, dr = self._a_r0[ja], self._a_dr[ja]
        lin0, dlin = self._a_lin0[ja], self._a_dlin[ja]
        sp = np.mod(sg * (np.arctan2(q2, q1) - th0), _TWO_PI)  # angle from the start, in the direction of travel
        if self._a_multi:
            # several turns: take the turn whose linear-axis position is nearest the sample
            multi = sw > _TWO_PI + 1e-9
            if multi.any():
                with np.errstate(divide="ignore", invalid="ignore"):
                    s_ax = np.where(dlin != 0.0, (h - lin0) * sw / np.where(dlin != 0.0, dlin, 1.0), sp)
                nt = np.round((s_ax - sp) / _TWO_PI)
                nt = np.clip(nt, 0.0, np.maximum(np.floor((sw - sp) / _TWO_PI), 0.0))
                sp = np.where(multi, sp + _TWO_PI * nt, sp)
        s = np.minimum(sp, sw)
        curved = self._a_curved[ja]
        if curved.any():
            # helix / spiral: two Newton steps on |P(s) - q|^2 from the radial foot
            ci = np.flatnonzero(curved)
            sc = s[ci]
            q1c, q2c, hc = q1[ci], q2[ci], h[ci]
            th0c, sgc, swc = th0[ci], sg[ci], sw[ci]
            rp = dr[ci] / swc
            kp = dlin[ci] / swc
            r0c, lin0c = r0[ci], lin0[ci]
            for _ in range(2):
                th = th0c + sgc * sc
                c, sn = np.cos(th), np.sin(th)
                r = r0c + rp * sc
                g1, g2, g3 = r * c - q1c, r * sn - q2c, lin0c + kp * sc - hc
                d1, d2, d3 = rp * c - sgc * r * sn, rp * sn + sgc * r * c, kp
                dd1 = -2.0 * sgc * rp * sn - r * c
                dd2 = 2.0 * sgc * rp * c - r * sn
                num = g1 * d1 + g2 * d2 + g3 * d3
                den = d1 * d1 + d2 * d2 + d3 * d3 + g1 * dd1 + g2 * dd2
                step = np.where(den > 0.0, num / np.where(den > 0.0, den, 1.0), 0.0)
                sc = np.clip(sc - step, 0.0, swc)
            s[ci] = sc
        # candidates: the (refined) radial foot, the start and the end point
        f = s / sw
        th = th0 + sg * s
        r = r0 + dr * f
        e1 = r * np.cos(th) - q1
        e2 = r * np.sin(th) - q2
        e3 = lin0 + dlin * f - h
        d2 = e1 * e1 + e2 * e2 + e3 * e3
        for fe, c1e, c2e, le in ((0.0, self._a_s1, self._a_s2, self._a_lin0), (1.0, self._a_e1, self._a_e2, self._a_lin1)):
            g1 = c1e[ja] - q1
            g2 = c2e[ja] - q2
            g3 = le[ja] - h
            de = g1 * g1 + g2 * g2 + g3 * g3
            better = de < d2
            d2 = np.where(better, de, d2)
            f = np.where(better, fe, f)
        if not full:
            return d2, f
        # foot point and left normal of the chosen parameter, in world axes
        th = th0 + sg * (f * sw)
        r = r0 + dr * f
        c, sn = np.cos(th), np.sin(th)
        foot = np.empty((n, 3))
        left = np.zeros((n, 3))
        i1, i2, il = self._a_ia1[ja], self._a_ia2[ja], self._a_il[ja]
        foot[rows, i1] = self._a_c1[ja] + r * c
        foot[rows, i2] = self._a_c2[ja] + r * sn
        foot[rows, il] = lin0 + dlin * f
        # left of the direction of travel = -sig * radial unit (CCW: towards the centre)
        left[rows, i1] = -sg * c
        left[rows, i2] = -sg * sn
        return d2, f, foot, left

    def _arc_d2_fast(self, p, px, py, pz, sel, ja):
        """Squared distance from points ``sel`` to arcs ``ja`` for choosing the nearest candidate.

        Circles exactly, without trigonometry: the sample's direction is inside the sweep when it
        is on the travel side of the start direction and on the far side of the end direction
        (sweeps up to pi: both; longer sweeps: either); inside, the distance is the radial one,
        outside, that to the nearer end point. Helices and spirals use the radial foot at the
        sample's angle (not refined; the winner is refined by :meth:`_arc_d2`), multi-turn arcs
        the precise kernel.
        """
        tab = np.take(self._a_tab, ja, axis=1)
        (c1, c2, sg, us1, us2, ue1, ue2, small, rnd, r0, lin0, s1, s2, e1, e2, lin1, th0, isw, dr, dlin,
         curved) = tab
        if self._arc_plane is not None:
            a1, a2, al = self._arc_plane
            cols = (px, py, pz)
            q1 = cols[a1][sel]
            q2 = cols[a2][sel]
            h = cols[al][sel]
        else:
            rows = np.arange(ja.size)
            ps = p[sel]
            q1 = ps[rows, self._a_ia1[ja]]
            q2 = ps[rows, self._a_ia2[ja]]
            h = ps[rows, self._a_il[ja]]
        q1 -= c1
        q2 -= c2
        cs = us1 * q2
        cs -= us2 * q1
        cs *= sg
        ce = q1 * ue2
        ce -= q2 * ue1
        ce *= sg
        pos_s = cs >= 0.0
        pos_e = ce >= 0.0
        inside = np.where(small > 0.0, pos_s & pos_e, pos_s | pos_e)
        inside |= rnd > 0.0
        rho = np.hypot(q1, q2)
        if self._a_all_curved or (curved > 0.0).any():
            ci = None if self._a_all_curved else np.flatnonzero(curved > 0.0)
            sub = (lambda x: x) if ci is None else (lambda x: x[ci])
            f = np.arctan2(sub(q2), sub(q1))
            f -= sub(th0)
            f *= sub(sg)
            np.mod(f, _TWO_PI, out=f)
            f *= sub(isw)
            np.minimum(f, 1.0, out=f)
            if ci is None:
                r = dr * f
                r += r0
                lin = dlin * f
                lin += lin0
            else:
                r, lin = r0.copy(), lin0.copy()
                r[ci] += dr[ci] * f
                lin[ci] += dlin[ci] * f
        else:
            r, lin = r0, lin0
        rho -= r
        rho *= rho
        d2 = h - lin
        d2 *= d2
        d2 += rho
        g = q1 - s1
        d2s = g * g
        g = q2 - s2
        d2s += g * g
        g = h - lin0
        d2s += g * g
        g = q1 - e1
        d2e = g * g
        g = q2 - e2
        d2e += g * g
        g = h - lin1
        d2e += g * g
        np.minimum(d2s, d2e, out=d2s)
        np.minimum(d2, d2s, out=d2)
        d2 = np.where(inside, d2, d2s)
        if self._a_multi:
            mi = np.flatnonzero(self._a_multi_of[ja])
            if mi.size:
                d2[mi] = self._arc_d2(p[sel[mi]], ja[mi])[0]
        return d2

    def _eval(self, p, px, py, pz, idx, ws: _Work):
        """Squared distance (for choosing) from points to segments ``idx`` (lines and arcs)."""
        d2, t = self._line_d2(px, py, pz, idx, ws)
        if self.has_arcs:
            j = np.take(self._arc_of, idx, mode="clip")
            sel = np.flatnonzero(j >= 0)
            if sel.size:
                d2[sel] = self._arc_d2_fast(p, px, py, pz, sel, j[sel])
        return d2, t


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
    window : int
        Segments searched before *and* after the hint (2 w + 1 candidates).
    max_walk : int
        When the nearest point lies on the first or last segment of the window
        (the true nearest may lie further out, e.g. a lag of more than
        ``window`` short segments), the window is moved on by ``window``
        segments in that direction and searched again while that finds a
        strictly nearer point, at most this many times. 0 disables it. The
        walk follows the path, so it finds the nearest point of the stretch of
        path it has covered, not a far-away pass of the tool.
    chunk : int
        Samples processed at once (memory ~ 200 bytes x chunk).
    workers : int, optional
        Threads; default: the number of CPUs.

    Returns
    -------
    ContourError
        Samples whose window holds no active segment get NaN and ``seg = -1``.
    """
    p = np.asarray(actual_mm, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise ValueError("actual_mm must be (N, 2) or (N, 3)")
    if p.shape[1] == 2:
        p = np.column_stack([p, np.zeros(p.shape[0])])
    n = p.shape[0]
    m = len(path)
    hint = np.broadcast_to(np.asarray(hint_seg, dtype=np.int64), (n,))
    hint = np.clip(hint, 0, m - 1)
    w = int(window)
    if w < 0:
        raise ValueError("window must be >= 0")
    out = ContourError(
        dist_mm=np.empty(n), foot_mm=np.empty((n, 3), order="F"), vector_mm=np.empty((n, 3), order="F"),
        seg=np.empty(n, np.int64), u=np.empty(n), signed_mm=np.empty(n), hint=hint, path=path,
    )
    chunk = max(int(chunk), 1024)
    starts = list(range(0, n, chunk))
    nw = workers if workers is not None else (os.cpu_count() or 1)
    nw = max(1, min(int(nw), len(starts)))
    walked = [0] * nw

    def work(k: int) -> None:
        ws = _Work()
        for a in starts[k::nw]:
            sl = slice(a, min(a + chunk, n))
            walked[k] += _chunk(path, p[sl], hint[sl], w, max_walk, out, sl, ws)

    if nw == 1:
        work(0)
    else:
        with ThreadPoolExecutor(max_workers=nw) as ex:
            list(ex.map(work, range(nw)))
    out.walked = int(sum(walked))
    return out


def _search(path: PathGeometry, p, px, py, pz, h, w: int, ws: _Work):
    """Nearest of the segments ``h - w .. h + w`` (clipped to the path) for each point.

    Returns the segment index and its squared distance (``>= _FAR_D2``: none active), both
    in buffers of ``ws``.
    """
    m = len(path)
    n = h.shape[0]
    bits = max(1, (2 * w).bit_length())
    low = np.int64((1 << bits) - 1)
    keep = np.int64(_SIGN_CLEAR & ~low)
    best = ws.f("best", n, np.int64)
    best.fill(np.iinfo(np.int64).max)
    idx = ws.f("idx", n, np.int64)
    for j in range(-w, w + 1):
        np.add(h, j, out=idx)  # out-of-range indices are clipped by the kernels' take(mode="clip")
        d2 = path._eval(p, px, py, pz, idx, ws)[0]
        # one integer minimum keeps distance and candidate: the squared distance's bits (sign
        # cleared, so a rounding to -0 or -1e-18 counts as 0) with the candidate in the low bits;
        # non-negative doubles order like their bit patterns, and ties go to the earlier segment
        key = d2.view(np.int64)
        key &= keep
        key |= np.int64(j + w)
        np.minimum(best, key, out=best)
    seg = ws.f("seg", n, np.int64)
    np.bitwise_and(best, low, out=seg)
    seg += h
    seg -= w
    np.clip(seg, 0, m - 1, out=seg)
    best &= keep
    return seg, best.view(np.float64)


def _final(path: PathGeometry, p, px, py, pz, seg, ws: _Work):
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


def _chunk(path: PathGeometry, p, h, w: int, max_walk: int, out: ContourError, sl: slice, ws: _Work) -> int:
    n = p.shape[0]
    pt = ws.f("pt", 3 * n).reshape(3, n)
    pt[...] = p.T
    px, py, pz = pt[0], pt[1], pt[2]
    m = len(path)
    seg, d2k = _search(path, p, px, py, pz, h, w, ws)
    none = ~(d2k < _FAR_D2)  # no active segment in the window, or a NaN sample
    frac, vx, vy, vz, d2, signed = _final(path, p, px, py, pz, seg, ws)
    walked = 0
    if max_walk > 0 and w < m:
        cur = h
        shift = max(w, 1)
        wk = _Work()
        for _ in range(max_walk):
            # samples whose nearest segment is the first or last of their window (and the window
            # does not end at the end of the path): the true nearest may lie further out
            rel = ws.f("rel", n, np.int64)
            np.subtract(seg, cur, out=rel)
            np.abs(rel, out=rel)
            ci = np.flatnonzero(rel == w)
            if ci.size == 0:
                break
            sc, cc = seg[ci], cur[ci]
            at_lo = (sc == cc - w) & (cc - w > 0)
            at_hi = (sc == cc + w) & (cc + w < m - 1)
            keep = (at_lo | at_hi) & ~none[ci]
            ei = ci[keep]
            if ei.size == 0:
                break
            at_lo = at_lo[keep]
            walked += int(ei.size)
            # move the window on so that the current best sits at its other end; a window that
            # finds nothing strictly better leaves the best inside it, which ends that sample's walk
            cur = cur.copy()
            cur[ei] = np.clip(np.where(at_lo, seg[ei] - shift, seg[ei] + shift), 0, m - 1)
            pe, pxe, pye, pze = p[ei], px[ei], py[ei], pz[ei]
            s2, _dk = _search(path, pe, pxe, pye, pze, cur[ei], w, wk)
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


# ---------------------------------------------------------------------------------------------
# Frenet / tangent estimate (seed 000)
# ---------------------------------------------------------------------------------------------


def tangent_error(
    ref_mm: ArrayLike, actual_mm: ArrayLike, *, tangent: ArrayLike | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Seed 000's contour error estimate: the part of ``r - q`` normal to the reference tangent at ``r``.

    ``e = (r - q) - ((r - q) . T) T`` with ``T`` the unit tangent of the
    reference at the reference sample (the ``[0, e_n, e_b]`` components of
    seed 000's eq. (6) expressed in world axes; their split between N and B
    does not change the vector). ``T`` is the central difference of the
    reference samples unless given; where the reference stands still the
    nearest defined tangent is used.

    Returns
    -------
    vector_mm : (N, 3)
        Estimated error vector, pointing from the actual towards the tangent line.
    norm_mm : (N,)
        Its length.
    """
    r = np.asarray(ref_mm, dtype=np.float64)
    q = np.asarray(actual_mm, dtype=np.float64)
    if r.shape != q.shape or r.ndim != 2:
        raise ValueError("ref_mm and actual_mm must both be (N, 2) or (N, 3)")
    e = r - q
    n = r.shape[0]
    if tangent is None:
        t = np.gradient(r, axis=0) if n > 1 else np.zeros_like(r)
    else:
        t = np.array(tangent, dtype=np.float64).reshape(r.shape)
    norm = np.sqrt(np.einsum("ij,ij->i", t, t))
    ok = norm > 1e-12 * max(1.0, float(np.nanmax(np.abs(r))) if n else 1.0)
    if not ok.all() and ok.any():
        i = np.arange(n)
        prev = np.maximum.accumulate(np.where(ok, i, -1))
        nxt = np.minimum.accumulate(np.where(ok, i, n)[::-1])[::-1]
        use = np.where(prev >= 0, prev, nxt)
        use = np.where((nxt < n) & (prev >= 0) & (nxt - i < i - prev), nxt, use)
        t = t[use]
        norm = norm[use]
        ok = ok[use]
    tu = np.where(ok[:, None], t / np.where(ok, norm, 1.0)[:, None], 0.0)
    vec = e - np.einsum("ij,ij->i", e, tu)[:, None] * tu
    return vec, np.sqrt(np.einsum("ij,ij->i", vec, vec))


# ---------------------------------------------------------------------------------------------
# Per-command error E(k)
# ---------------------------------------------------------------------------------------------


@dataclass(slots=True, eq=False)
class CommandError:
    """Error at the instant the machine passes each G01 command's end point.

    Attributes
    ----------
    e_mm : float64 (K, 3)
        ``E(k) = end point of command k - actual position`` at the crossing, mm (NaN if not reached).
    sample : float64 (K,)
        Fractional sample index of the crossing (NaN if not reached).
    time_s : float64 (K,) or None
        Time of the crossing, when sample times were given.
    reached : bool (K,)
        The foot parameter reached the end of the command's move.
    move : int64 (K,)
        Move index ``m_k`` of each command.
    line : int32 (K,)
        Source line of each command.
    """

    e_mm: NDArray[np.float64]
    sample: NDArray[np.float64]
    time_s: NDArray[np.float64] | None
    reached: NDArray[np.bool_]
    move: NDArray[np.int64]
    line: NDArray[np.int32]

    @property
    def norm_mm(self) -> NDArray[np.float64]:
        """``|E(k)|``, mm."""
        return np.sqrt(np.einsum("ij,ij->i", self.e_mm, self.e_mm))


def per_command_error(
    path: PathGeometry,
    err: ContourError,
    actual_mm: ArrayLike,
    *,
    t_s: ArrayLike | None = None,
) -> CommandError:
    """``E(k)``: the error vector when the machine passes the end point of G01 command k.

    For command k on move ``m_k`` the crossing is the first sample pair
    ``i - 1, i`` with ``u[i - 1] < m_k + 1 <= u[i]``, on the running maximum of
    the foot parameter (the furthest the machine has got along the path, so
    noise that moves the foot back and forth does not make extra crossings).
    The actual position is interpolated linearly between the two samples at
    the fraction where ``u`` reaches ``m_k + 1``, and ``E(k)`` is the command's
    end point minus that position. When the actual path cuts the corner, the
    foot jumps from before the vertex to after it between two samples; that is
    a crossing like any other (the foot of the crossing is the vertex).
    Commands whose end is never reached (the log stops earlier, or the first
    sample is already past them) are NaN with ``reached = False``.
    """
    q = np.asarray(actual_mm, dtype=np.float64)
    if q.shape[1] == 2:
        q = np.column_stack([q, np.zeros(q.shape[0])])
    mk = path.move_of_command
    kk = mk.size
    target = mk.astype(np.float64) + 1.0
    u = np.where(np.isfinite(err.u), err.u, -np.inf)
    n = u.shape[0]
    e = np.full((kk, 3), np.nan)
    sample = np.full(kk, np.nan)
    reached = np.zeros(kk, bool)
    if n and kk:
        umax = np.maximum.accumulate(u)
        i = np.searchsorted(umax, target, side="left")
        tol = 1e-12 * np.maximum(1.0, np.abs(target))
        first_ok = (i == 0) & (n > 0) & (np.abs(u[0] - target) <= tol)
        ok = ((i > 0) & (i < n)) | first_ok
        ii = np.clip(i, 1, max(n - 1, 1))
        ua, ub = u[np.clip(ii - 1, 0, n - 1)], u[np.minimum(ii, n - 1)]
        with np.errstate(invalid="ignore", divide="ignore"):
            alpha = np.where(np.isfinite(ua) & (ub > ua), (target - ua) / (ub - ua), 1.0)
        alpha = np.clip(alpha, 0.0, 1.0)
        alpha = np.where(first_ok, 0.0, alpha)
        ia = np.where(first_ok, 0, np.clip(ii - 1, 0, n - 1))
        ib = np.where(first_ok, 0, np.minimum(ii, n - 1))
        pos = q[ia] + alpha[:, None] * (q[ib] - q[ia])
        end = path.end_mm[mk]
        e[ok] = (end - pos)[ok]
        sample[ok] = (ia + alpha)[ok]
        reached = ok
    time = None
    if t_s is not None:
        ts = np.asarray(t_s, dtype=np.float64)
        time = np.full(kk, np.nan)
        if reached.any():
            time[reached] = np.interp(sample[reached], np.arange(ts.size), ts)
    return CommandError(e_mm=e, sample=sample, time_s=time, reached=reached, move=mk, line=path.line[mk])


def sample_command(err: ContourError) -> NDArray[np.int64]:
    """Command index k of each sample: that of the move its foot is on (-1: not a G01 command, or no foot)."""
    k = err.path.command[np.clip(err.seg, 0, len(err.path) - 1)].astype(np.int64)
    k[err.seg < 0] = -1
    return k


# ---------------------------------------------------------------------------------------------
# Summary
# ---------------------------------------------------------------------------------------------


def summary(err: ContourError, mask: ArrayLike | None = None) -> dict:
    """Max / mean / RMS of the contour error over feed moves, and the worst sample.

    By default the samples counted are those with a foot on a feed move whose
    hint (the reference) is also on a feed move -- samples taken while the
    reference is in a rapid are left out. ``mask`` (N,) bool restricts further.

    Returns
    -------
    dict
        ``max``, ``mean``, ``rms`` (mm), ``n`` (samples counted), ``worst_index``
        (sample), ``worst_move``, ``worst_command`` (k of the foot's move, -1 if
        that move is not a G01 command), ``worst_line``. With no sample counted
        the statistics are NaN and the indices -1.
    """
    path = err.path
    d = err.dist_mm
    ok = np.isfinite(d) & (err.seg >= 0)
    feed = path.kind != MOVE_RAPID
    ok &= feed[np.clip(err.seg, 0, len(path) - 1)] & feed[err.hint]
    if mask is not None:
        ok &= np.asarray(mask, bool)
    sel = d[ok]
    if sel.size == 0:
        nan = float("nan")
        return {"max": nan, "mean": nan, "rms": nan, "n": 0, "worst_index": -1, "worst_move": -1,
                "worst_command": -1, "worst_line": -1}
    idx = np.flatnonzero(ok)
    w = int(idx[int(np.argmax(sel))])
    mv = int(err.seg[w])
    return {
        "max": float(sel.max()),
        "mean": float(sel.mean()),
        "rms": float(np.sqrt(np.mean(sel * sel))),
        "n": int(sel.size),
        "worst_index": w,
        "worst_move": mv,
        "worst_command": int(path.command[mv]),
        "worst_line": int(path.line[mv]),
    }

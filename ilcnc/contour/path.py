"""The programmed path as geometry: straight moves, arcs and helices, with the distances the search needs.

:class:`PathGeometry` is built from a program's move table (or a polyline) once per run and holds, per
segment, what the contour search (:mod:`ilcnc.contour.search`) evaluates for every sample: start, end,
direction and length of lines; centre, radius, sweep and lead of arcs and helices; the point and tangent at a
path parameter; and the exact squared distance from points to a segment.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ilcnc.program.model import MOVE_ARC_CCW, MOVE_ARC_CW, MOVE_LINE, MOVE_RAPID, PLANE_AXES, PLANE_XY, MoveTable

__all__ = ["FAR_MM", "TWO_PI", "PathGeometry", "WorkBuffers"]

#: Coordinate of an inactive segment's start, mm: far away, yet its squared distance (~3e300) stays finite.
FAR_MM = 1e150
TWO_PI = 2.0 * math.pi


class WorkBuffers:
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
    cum_length_mm : float64 (M + 1,)
        Path length from the start of the path to the start of each segment, mm (the last entry: the whole
        length). Inactive segments (rapids) count too: the tool travels them.
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
        a[inactive] = FAR_MM
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
            sw = np.where(sig < 0, th0 - th1, th1 - th0) % TWO_PI
            sw = np.where(sw < 1e-12, TWO_PI, sw) + TWO_PI * (np.maximum(turns[ai], 1) - 1)
            sweep[ai] = sw
            self._arc_of[ai] = rows
            self._a_ia1, self._a_ia2, self._a_il = ia1.astype(np.int64), ia2.astype(np.int64), il.astype(np.int64)
            self._a_c1, self._a_c2 = c1, c2
            self._a_r0, self._a_dr = r0, r1 - r0
            self._a_th0, self._a_sig, self._a_sw = th0, sig, sw
            self._a_lin0 = sa[rows, il]
            self._a_dlin = ea[rows, il] - sa[rows, il]
            self._a_curved = (np.abs(self._a_dr) > 0.0) | (np.abs(self._a_dlin) > 0.0)
            self._a_multi = bool((sw > TWO_PI + 1e-9).any())
            # for the fast candidate test: start / end in plane coordinates relative to the centre,
            # their unit directions, the end's linear coordinate, sweep class
            self._a_s1, self._a_s2, self._a_e1, self._a_e2 = s1, s2, e1, e2
            r0s = np.where(r0 > 0, r0, 1.0)
            r1s = np.where(r1 > 0, r1, 1.0)
            self._a_us1, self._a_us2 = np.where(r0 > 0, s1 / r0s, 1.0), np.where(r0 > 0, s2 / r0s, 0.0)
            self._a_ue1, self._a_ue2 = np.where(r1 > 0, e1 / r1s, 1.0), np.where(r1 > 0, e2 / r1s, 0.0)
            self._a_lin1 = ea[rows, il]
            self._a_small = sw <= math.pi
            self._a_round = sw >= TWO_PI * (1.0 - 1e-12)
            self._a_multi_of = sw > TWO_PI + 1e-9
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
        self.cum_length_mm = np.concatenate(([0.0], np.cumsum(length)))

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

    # -- tables of the compiled kernel -------------------------------------------------------------

    def _kernel_tables(self) -> tuple:
        """The path as the compiled kernel reads it (built once): one row per segment and per arc.

        ``seg`` (M, 8): start (``FAR_MM`` if inactive), direction, ``|d|^2``, ``1/|d|^2``; ``side`` (M, 4):
        left normal, ``1/|d in plane|``; ``arc`` (A, 30): :attr:`_a_tab` by row, the sweep, the range of
        the radius and of the linear axis (min, max), cos and sin of the angle at the start and the end;
        ``arc_axes`` (A, 3): in-plane and linear axes; ``flags``: has arcs, axes of the common plane of
        the straight segments (-1: none), several turns somewhere.
        """
        tab = getattr(self, "_ktab", None)
        if tab is not None:
            return tab
        seg = np.ascontiguousarray(np.column_stack([self._ax, self._ay, self._az, self._dx, self._dy, self._dz,
                                                    self._l2, self._il2]))
        inv = self._inv_inplane if self._line_plane else np.zeros(len(self))
        side = np.ascontiguousarray(np.column_stack([self._lx, self._ly, self._lz, inv]))
        if self.has_arcs:
            r1, lin1 = self._a_r0 + self._a_dr, self._a_lin0 + self._a_dlin
            th_s = self._a_th0 + self._a_sig * (0.0 * self._a_sw)  # the angles _arc_d2(full=True) takes at f = 0, 1
            th_e = self._a_th0 + self._a_sig * (1.0 * self._a_sw)
            arc = np.ascontiguousarray(np.vstack([
                self._a_tab, self._a_sw, np.minimum(self._a_r0, r1), np.maximum(self._a_r0, r1),
                np.minimum(self._a_lin0, lin1), np.maximum(self._a_lin0, lin1),
                np.cos(th_s), np.sin(th_s), np.cos(th_e), np.sin(th_e),
            ]).T)
            arc_axes = np.ascontiguousarray(np.column_stack([self._a_ia1, self._a_ia2, self._a_il]))
            multi = self._a_multi
        else:
            arc = np.zeros((1, 30))
            arc_axes = np.zeros((1, 3), np.int64)
            multi = False
        lp = self._line_plane or (-1, -1)
        flags = np.array([int(self.has_arcs), lp[0], lp[1], int(multi)], dtype=np.int64)
        tab = (seg, side, np.ascontiguousarray(self._arc_of), arc, arc_axes, flags)
        self._ktab = tab
        return tab

    # -- distance kernels -----------------------------------------------------------------------

    def _line_d2(self, px, py, pz, idx, ws: WorkBuffers):
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
        sp = np.mod(sg * (np.arctan2(q2, q1) - th0), TWO_PI)  # angle from the start, in the direction of travel
        if self._a_multi:
            # several turns: take the turn whose linear-axis position is nearest the sample
            multi = sw > TWO_PI + 1e-9
            if multi.any():
                with np.errstate(divide="ignore", invalid="ignore"):
                    s_ax = np.where(dlin != 0.0, (h - lin0) * sw / np.where(dlin != 0.0, dlin, 1.0), sp)
                nt = np.round((s_ax - sp) / TWO_PI)
                nt = np.clip(nt, 0.0, np.maximum(np.floor((sw - sp) / TWO_PI), 0.0))
                sp = np.where(multi, sp + TWO_PI * nt, sp)
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
            np.mod(f, TWO_PI, out=f)
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

    def _eval(self, p, px, py, pz, idx, ws: WorkBuffers):
        """Squared distance (for choosing) from points to segments ``idx`` (lines and arcs)."""
        d2, t = self._line_d2(px, py, pz, idx, ws)
        if self.has_arcs:
            j = np.take(self._arc_of, idx, mode="clip")
            sel = np.flatnonzero(j >= 0)
            if sel.size:
                d2[sel] = self._arc_d2_fast(p, px, py, pz, sel, j[sel])
        return d2, t



"""Contour error: exact windowed nearest point, tangent estimate, per-command error E(k)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from ilcnc.contour.estimates import per_command_error, summary, tangent_error
from ilcnc.contour.path import PathGeometry
from ilcnc.contour.search import contour_error, guess_hints
from ilcnc.program import read_program
from ilcnc.program.model import MOVE_ARC_CCW, MOVE_ARC_CW, MOVE_LINE, MOVE_RAPID, MoveTableBuilder

from .conftest import SAMPLES

CONTOUR = SAMPLES / "contour"


def _table(moves):
    """MoveTable from (kind, start, end, center, plane, correctable) tuples."""
    b = MoveTableBuilder()
    for i, (kind, start, end, center, plane, corr) in enumerate(moves):
        b.add(kind, i + 1, tuple(start), tuple(end), feed=600.0 if kind != MOVE_RAPID else float("nan"),
              center=tuple(center) if center is not None else (float("nan"),) * 3, plane=plane, correctable=corr)
    return b.build()


def _circle_path(r=10.0, kind=MOVE_ARC_CCW, center=(0.0, 0.0, 0.0), plane=17):
    c = np.array(center, float)
    axes = {17: (0, 1), 18: (2, 0), 19: (1, 2)}[plane]
    start = c.copy()
    start[axes[0]] += r
    return PathGeometry.from_moves(_table([(kind, start, start, c, plane, False)]))


def _exhaustive(path, pts):
    """Nearest over ALL segments with the library's kernels (a window that covers the whole path)."""
    m = len(path)
    return contour_error(path, pts, m // 2, window=m // 2 + 1, max_walk=0)


def _lines_bruteforce(path, pts, chunk=64):
    """Independent point-to-segment distance over every active straight segment."""
    act = np.flatnonzero(path.active & ~path.is_arc)
    a = path.start_mm[act]
    d = path.end_mm[act] - a
    l2 = np.einsum("ij,ij->i", d, d)
    out = np.empty(len(pts))
    seg = np.empty(len(pts), np.int64)
    for i in range(0, len(pts), chunk):
        p = pts[i:i + chunk, None, :]
        w = p - a[None]
        t = np.clip(np.einsum("nmk,mk->nm", w, d) / np.where(l2 > 0, l2, 1.0), 0.0, 1.0)
        e = w - t[..., None] * d[None]
        dist = np.sqrt(np.einsum("nmk,nmk->nm", e, e))
        j = np.argmin(dist, axis=1)
        out[i:i + chunk] = dist[np.arange(len(j)), j]
        seg[i:i + chunk] = act[j]
    return out, seg


def _points_near(path, n, rng, max_off=0.05):
    act = np.flatnonzero(path.active & (path.length_mm > 0))
    seg = rng.choice(act, n)
    frac = rng.random(n)
    v = rng.normal(size=(n, 3))
    v *= (rng.random(n) * max_off / np.linalg.norm(v, axis=1))[:, None]
    return path.point_at(seg, frac) + v


# ---------------------------------------------------------------------------------------------
# analytic cases
# ---------------------------------------------------------------------------------------------


def test_point_offset_from_line_is_d():
    rng = np.random.default_rng(1)
    a, b = np.array([1.0, -2.0, 3.0]), np.array([41.0, 13.0, -7.0])
    path = PathGeometry.from_polyline([a - (b - a), a, b, b + (b - a)])
    u = (b - a) / np.linalg.norm(b - a)
    n = 1000
    normal = rng.normal(size=(n, 3))
    normal -= np.outer(normal @ u, u)
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    d = rng.uniform(1e-6, 0.5, n)
    along = rng.random(n)
    pts = a + along[:, None] * (b - a) + d[:, None] * normal
    err = contour_error(path, pts, 1, window=1)
    np.testing.assert_allclose(err.dist_mm, d, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(err.seg, 1)
    np.testing.assert_allclose(err.u, 1 + along, atol=1e-12)
    np.testing.assert_allclose(err.vector_mm, -d[:, None] * normal, atol=1e-12)
    np.testing.assert_allclose(err.foot_mm + 0, pts + err.vector_mm, atol=1e-12)


@pytest.mark.parametrize("plane", [17, 18, 19])
@pytest.mark.parametrize("kind", [MOVE_ARC_CW, MOVE_ARC_CCW])
def test_point_inside_and_outside_circle(plane, kind):
    rng = np.random.default_rng(2)
    r = 12.5
    c = np.array([3.0, -4.0, 2.0])
    path = _circle_path(r, kind, c, plane)
    a1, a2 = {17: (0, 1), 18: (2, 0), 19: (1, 2)}[plane]
    n = 2000
    rho = rng.uniform(0.2, 2 * r, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    pts = np.tile(c, (n, 1))
    pts[:, a1] += rho * np.cos(phi)
    pts[:, a2] += rho * np.sin(phi)
    err = contour_error(path, pts, 0, window=0)
    np.testing.assert_allclose(err.dist_mm, np.abs(r - rho), rtol=1e-10, atol=1e-11)
    # the foot is on the circle, in the sample's direction
    rel = err.foot_mm - c
    np.testing.assert_allclose(np.hypot(rel[:, a1], rel[:, a2]), r, rtol=1e-12)
    np.testing.assert_allclose(np.arctan2(rel[:, a2], rel[:, a1]), phi, atol=1e-9)


def test_arc_outside_its_sweep_goes_to_the_nearer_end():
    # quarter circle CCW from (10, 0) to (0, 10), centre 0
    path = PathGeometry.from_moves(_table([(MOVE_ARC_CCW, (10, 0, 0), (0, 10, 0), (0, 0, 0), 17, False)]))
    pts = np.array([[12.0, -3.0, 0.0], [-3.0, 12.0, 0.0], [-5.0, -5.1, 0.0], [5.0, 5.0, 0.0]])
    err = contour_error(path, pts, 0, window=0)
    expect = [math.hypot(2, 3), math.hypot(3, 2), math.hypot(15, 5.1), 10 - math.hypot(5, 5)]
    np.testing.assert_allclose(err.dist_mm, expect, rtol=1e-12)
    np.testing.assert_allclose(err.u, [0.0, 1.0, 0.0, 0.5], atol=1e-12)


@pytest.mark.parametrize(("plane", "axes"), [(17, (0, 1, 2)), (18, (2, 0, 1)), (19, (1, 2, 0))])
def test_arc_orientation_per_plane(plane, axes):
    """CCW seen from +normal: from +a1 through +a2 (G17 X->Y, G18 Z->X, G19 Y->Z); CW through -a2."""
    a1, a2, _n = axes
    start, end = np.zeros(3), np.zeros(3)
    start[a1], end[a1] = 5.0, -5.0
    for kind, sign in ((MOVE_ARC_CCW, 1.0), (MOVE_ARC_CW, -1.0)):
        path = PathGeometry.from_moves(_table([(kind, start, end, (0, 0, 0), plane, False)]))
        mid = path.point_at([0], [0.5])[0]
        expect = np.zeros(3)
        expect[a2] = 5.0 * sign
        np.testing.assert_allclose(mid, expect, atol=1e-12)
        # a point just inside the half circle is left of travel for CCW, right for CW
        q = 0.9 * expect
        err = contour_error(path, q[None], 0, window=0)
        assert err.signed_mm[0] == pytest.approx(0.5 * sign, abs=1e-12)


def test_signed_error_on_ccw_circle_and_lines():
    rng = np.random.default_rng(3)
    r = 20.0
    phi = rng.uniform(-np.pi, np.pi, 500)
    inside = np.column_stack([(r - 0.1) * np.cos(phi), (r - 0.1) * np.sin(phi), np.zeros(500)])
    outside = inside * (r + 0.1) / (r - 0.1)
    ccw = _circle_path(r, MOVE_ARC_CCW)
    cw = _circle_path(r, MOVE_ARC_CW)
    np.testing.assert_allclose(contour_error(ccw, inside, 0).signed_mm, 0.1, atol=1e-10)  # inside = left
    np.testing.assert_allclose(contour_error(ccw, outside, 0).signed_mm, -0.1, atol=1e-10)
    np.testing.assert_allclose(contour_error(cw, inside, 0).signed_mm, -0.1, atol=1e-10)
    np.testing.assert_allclose(contour_error(cw, outside, 0).signed_mm, 0.1, atol=1e-10)
    # straight moves: left of the direction of travel in XY is positive, Z offsets do not count
    line = PathGeometry.from_polyline([[0, 0, 0], [10, 0, 0], [10, 10, 0]])
    err = contour_error(line, [[5, 0.2, 0.3], [5, -0.2, 0], [9.7, 5, -1], [10.4, 5, 0]], [0, 0, 1, 1], window=0)
    np.testing.assert_allclose(err.signed_mm, [0.2, -0.2, 0.3, -0.4], atol=1e-12)


def test_helix_matches_dense_search():
    """Helix (G17 CCW, 1.5 turns... one turn with Z ramp) against a dense polyline of the same helix."""
    r, rise = 4.0, -1.5  # 1.5 mm down in one turn: lead angle 3.4 degrees
    c = np.array([10.0, 5.0, 0.0])
    start = c + np.array([r, 0.0, 0.0])
    end = start + np.array([0.0, 0.0, rise])
    path = PathGeometry.from_moves(_table([(MOVE_ARC_CCW, start, end, c, 17, False)]))
    rng = np.random.default_rng(4)
    n = 400
    f = rng.random(n)
    th = 2 * np.pi * f
    base = np.column_stack([c[0] + r * np.cos(th), c[1] + r * np.sin(th), rise * f])
    pts = base + rng.normal(size=(n, 3)) * 0.05
    err = contour_error(path, pts, 0, window=0)
    # independent: minimise |helix(s) - p| over s with a bounded scalar search around a dense start
    dense = np.linspace(0, 1, 2001)
    hp = np.column_stack([c[0] + r * np.cos(2 * np.pi * dense), c[1] + r * np.sin(2 * np.pi * dense), rise * dense])
    ref = np.empty(n)
    for i, p in enumerate(pts):
        k = int(np.argmin(np.linalg.norm(hp - p, axis=1)))
        lo, hi = dense[max(k - 1, 0)], dense[min(k + 1, 2000)]

        def dist(s, p=p):
            return math.dist(p, (c[0] + r * math.cos(2 * math.pi * s), c[1] + r * math.sin(2 * math.pi * s), rise * s))

        res = minimize_scalar(dist, bounds=(lo, hi), method="bounded", options={"xatol": 1e-13})
        ref[i] = min(res.fun, dist(lo), dist(hi))
    diff = err.dist_mm - ref
    print(f"helix: max |ours - bounded search| = {np.abs(diff).max():.2e} mm")
    assert np.abs(diff).max() < 1e-9
    np.testing.assert_allclose(np.linalg.norm(err.foot_mm - pts, axis=1), err.dist_mm, rtol=1e-12)


def test_multi_turn_helix_in_g18():
    """Three CW turns in G18 (plane Z-X, linear axis Y) falling 3 mm: each sample finds its own turn."""
    c, r = np.array([1.0, 2.0, 3.0]), 2.0
    start = c + np.array([0.0, 0.0, r])
    end = start + np.array([0.0, -3.0, 0.0])
    b = MoveTableBuilder()
    b.add(MOVE_ARC_CW, 1, tuple(start), tuple(end), center=tuple(c), plane=18, turns=3)
    path = PathGeometry.from_moves(b.build())
    assert path.length_mm[0] == pytest.approx(math.hypot(3 * 2 * math.pi * r, 3.0))
    np.testing.assert_allclose(path.point_at([0], [1 / 12])[0] - c, [-r, -0.25, 0.0], atol=1e-12)  # CW from +Z to -X
    rng = np.random.default_rng(10)
    f = rng.random(300)
    pts = path.point_at(np.zeros(300, np.int64), f) + rng.normal(size=(300, 3)) * 0.03
    err = contour_error(path, pts, 0, window=0)
    grid = np.linspace(0, 1, 4001)
    dense = path.point_at(np.zeros(grid.size, np.int64), grid)
    ref = np.empty(len(pts))
    for i, p in enumerate(pts):
        k = int(np.argmin(np.linalg.norm(dense - p, axis=1)))
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, 4000)]
        res = minimize_scalar(lambda x, p=p: float(np.linalg.norm(path.point_at([0], [x])[0] - p)), bounds=(lo, hi),
                              method="bounded", options={"xatol": 1e-14})
        ref[i] = min(res.fun, np.linalg.norm(dense[max(k - 1, 0)] - p), np.linalg.norm(dense[min(k + 1, 4000)] - p))
    assert np.abs(err.dist_mm - ref).max() < 1e-9
    assert np.abs(err.u - f).max() < 0.01  # the right turn (one turn = 1/3)


# ---------------------------------------------------------------------------------------------
# windowed search vs brute force on real CAM programs
# ---------------------------------------------------------------------------------------------


def test_windowed_equals_bruteforce_compass():
    prog = read_program(CONTOUR / "compass.ngc")
    path = PathGeometry.from_moves(prog.moves)
    assert not path.has_arcs
    rng = np.random.default_rng(5)
    pts = _points_near(path, 3000, rng)
    ref, ref_seg = _lines_bruteforce(path, pts)
    for w in (1, 2, 3):
        hint = np.clip(ref_seg + rng.integers(-w, w + 1, len(pts)), 0, len(path) - 1)
        err = contour_error(path, pts, hint, window=w)
        np.testing.assert_allclose(err.dist_mm, ref, rtol=1e-9, atol=1e-12)
    # the exhaustive search with the library kernel agrees with the independent one
    np.testing.assert_allclose(_exhaustive(path, pts).dist_mm, ref, rtol=1e-9, atol=1e-12)


def _arc_reference(moves, m, p):
    """Independent distance from p to move m (an arc or helix, radius and Z linear in the angle)."""
    a1, a2, al = {17: (0, 1, 2), 18: (2, 0, 1), 19: (1, 2, 0)}[int(moves.plane[m])]
    s, e, c = moves.start_mm[m], moves.end_mm[m], moves.center_mm[m]
    t0 = math.atan2(s[a2] - c[a2], s[a1] - c[a1])
    t1 = math.atan2(e[a2] - c[a2], e[a1] - c[a1])
    r0 = math.hypot(s[a2] - c[a2], s[a1] - c[a1])
    r1 = math.hypot(e[a2] - c[a2], e[a1] - c[a1])
    sgn = 1.0 if moves.kind[m] == MOVE_ARC_CCW else -1.0
    sweep = ((t1 - t0) * sgn) % (2 * math.pi) or 2 * math.pi

    def point(f):
        th = t0 + sgn * sweep * f
        r = r0 + (r1 - r0) * f
        q = np.empty(3)
        q[a1], q[a2], q[al] = c[a1] + r * math.cos(th), c[a2] + r * math.sin(th), s[al] + (e[al] - s[al]) * f
        return q

    grid = np.linspace(0, 1, 721)
    dd = [np.linalg.norm(point(f) - p) for f in grid]
    k = int(np.argmin(dd))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, 720)]
    res = minimize_scalar(lambda f: float(np.linalg.norm(point(f) - p)), bounds=(lo, hi), method="bounded",
                          options={"xatol": 1e-14})
    return min(res.fun, dd[max(k - 1, 0)], dd[min(k + 1, 720)])


def test_windowed_equals_bruteforce_arc_heavy():
    prog = read_program(CONTOUR / "Gates_combined_R12.nc")
    path = PathGeometry.from_moves(prog.moves)
    assert path.is_arc.sum() > 5000
    rng = np.random.default_rng(6)
    pts = _points_near(path, 1500, rng)
    full = _exhaustive(path, pts)
    # straight segments: the independent brute force agrees where it wins
    line_d, _s = _lines_bruteforce(path, pts)
    assert np.all(full.dist_mm <= line_d + 1e-12)
    on_line = ~path.is_arc[full.seg]
    np.testing.assert_allclose(full.dist_mm[on_line], line_d[on_line], rtol=1e-9, atol=1e-12)
    # arcs (spirals: CAM-rounded I/J give start and end radii up to 0.14 um apart, 46 helices):
    # an independent bounded scalar search on the winning arc
    arc_i = np.flatnonzero(~on_line)
    assert arc_i.size > 300
    ref = np.array([_arc_reference(prog.moves, int(full.seg[i]), pts[i]) for i in arc_i])
    print(f"Gates: {arc_i.size} of {len(pts)} nearest on an arc, max |kernel - bounded search| = "
          f"{np.abs(full.dist_mm[arc_i] - ref).max():.1e} mm")
    assert np.abs(full.dist_mm[arc_i] - ref).max() < 1e-9
    # windowed search from hints around the true nearest segment = the exhaustive one
    for w in (1, 2, 3):
        hint = np.clip(full.seg + rng.integers(-w, w + 1, len(pts)), 0, len(path) - 1)
        err = contour_error(path, pts, hint, window=w)
        np.testing.assert_allclose(err.dist_mm, full.dist_mm, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(err.vector_mm, axis=1), err.dist_mm, rtol=1e-12, atol=1e-15)


def test_walk_follows_lag_beyond_the_window():
    """The reference leads (or trails) the actual by 0.5 mm of path, up to 11 segments of a real program.

    Seed 000's eq. (11) searches backwards only; here the hint is ahead of the true nearest
    segment (servo lag) or behind it (the axis leads, as it may after learning), and the window
    of 2 walks on until the nearest point is inside it.
    """
    prog = read_program(CONTOUR / "compass.ngc")
    path = PathGeometry.from_moves(prog.moves)
    rng = np.random.default_rng(7)
    pts = _points_near(path, 3000, rng, max_off=0.01)
    ref, ref_seg = _lines_bruteforce(path, pts)
    foot = contour_error(path, pts, ref_seg, window=0)
    length = np.where(path.active, path.length_mm, 0.0)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    s_foot = cum[foot.seg] + (foot.u - foot.seg) * length[foot.seg]
    for lag in (0.5, -0.5):
        hint = np.clip(np.searchsorted(cum, s_foot + lag, side="right") - 1, 0, len(path) - 1)
        err = contour_error(path, pts, hint, window=2)
        stuck = contour_error(path, pts, hint, window=2, max_walk=0)
        ok = np.isclose(err.dist_mm, ref, rtol=1e-9, atol=1e-12)
        ok0 = np.isclose(stuck.dist_mm, ref, rtol=1e-9, atol=1e-12)
        print(f"lag {lag:+.1f} mm (hint up to {np.abs(hint - ref_seg).max()} segments off), window 2: "
              f"{ok.mean():.1%} exact with the walk ({err.walked} walks), {ok0.mean():.1%} without")
        assert ok.mean() > 0.99
        assert ok0.mean() < 0.7
        assert np.all(stuck.dist_mm >= ref - 1e-12) and np.all(err.dist_mm >= ref - 1e-12)


def test_nearest_vertex_overestimates_on_fine_chamfers():
    """Nearest vertex (seed 000's eq. (13) without its interpolation) vs exact, on a finely chamfered path."""
    rng = np.random.default_rng(8)
    # a 20 mm square whose corners are chamfered by 0.1 mm chords of a 2 mm radius, sides split every 0.5 mm
    r, side = 2.0, 20.0
    verts = []
    for k, (cx, cy) in enumerate([(side - r, r), (side - r, side - r), (r, side - r), (r, r)]):
        a0 = -np.pi / 2 + k * np.pi / 2
        nseg = int(np.ceil(r * np.pi / 2 / 0.1))
        th = a0 + np.linspace(0, np.pi / 2, nseg + 1)
        arc = np.column_stack([cx + r * np.cos(th), cy + r * np.sin(th)])
        nxt = [(side - r, side - r), (r, side - r), (r, r), (side - r, r)][k]
        end = arc[-1]
        a1 = a0 + np.pi / 2
        toward = np.array([nxt[0] + r * np.cos(a1), nxt[1] + r * np.sin(a1)])
        nline = int(np.ceil(np.linalg.norm(toward - end) / 0.5))
        line = end + np.linspace(0, 1, nline + 1)[1:-1, None] * (toward - end)
        verts.extend([*arc, *line])
    verts.append(verts[0])
    path = PathGeometry.from_polyline(np.array(verts))
    pts = _points_near(path, 5000, rng, max_off=0.005)  # contour errors up to 5 um
    ref, ref_seg = _lines_bruteforce(path, pts)
    err = contour_error(path, pts, ref_seg, window=1)
    np.testing.assert_allclose(err.dist_mm, ref, rtol=1e-9, atol=1e-12)
    v = np.concatenate([path.start_mm, path.end_mm[-1:]])
    nv = np.array([np.linalg.norm(v - p, axis=1).min() for p in pts])
    over = nv - err.dist_mm
    print(
        f"nearest vertex vs exact: exact mean {err.dist_mm.mean() * 1e3:.2f} um, max {err.dist_mm.max() * 1e3:.2f} um; "
        f"nearest vertex mean {nv.mean() * 1e3:.1f} um, max {nv.max() * 1e3:.1f} um; "
        f"over-estimate mean {over.mean() * 1e3:.1f} um, max {over.max() * 1e3:.1f} um"
    )
    chamfer = path.length_mm[err.seg] < 0.2
    print(f"  on the 0.1 mm chamfer chords alone ({chamfer.sum()} samples): "
          f"exact mean {err.dist_mm[chamfer].mean() * 1e3:.2f} um, "
          f"over-estimate mean {over[chamfer].mean() * 1e3:.1f} um, max {over[chamfer].max() * 1e3:.1f} um")
    assert np.all(over >= -1e-12)
    assert over.mean() > 20 * err.dist_mm.mean()
    assert over[chamfer].max() > 0.03
    assert over.max() > 0.2  # up to half a 0.5 mm segment


# ---------------------------------------------------------------------------------------------
# per-command error E(k)
# ---------------------------------------------------------------------------------------------


def _rounded_corner_samples(rho, n_line=400, n_arc=801, n_up=400):
    """Actual path: (0,0) -> (10-rho, 0), quarter arc of radius rho, -> (10, 10)."""
    x = np.linspace(0, 10 - rho, n_line, endpoint=False)
    th = np.linspace(-np.pi / 2, 0, n_arc, endpoint=False)
    arc = np.column_stack([10 - rho + rho * np.cos(th), rho + rho * np.sin(th)])
    y = np.linspace(rho, 10, n_up)
    pts = np.concatenate([np.column_stack([x, np.zeros_like(x)]), arc, np.column_stack([np.full_like(y, 10), y])])
    return np.column_stack([pts, np.zeros(len(pts))])


def test_per_command_error_on_a_rounded_corner():
    rho = 0.5
    path = PathGeometry.from_moves(_table([
        (MOVE_LINE, (0, 0, 0), (10, 0, 0), None, 17, True),
        (MOVE_LINE, (10, 0, 0), (10, 10, 0), None, 17, True),
    ]))
    q = _rounded_corner_samples(rho)
    hint = np.where(np.arange(len(q)) < 400 + 400, 0, 1)  # the reference turns half-way round the arc
    err = contour_error(path, q, hint, window=1)
    ce = per_command_error(path, err, q, t_s=np.arange(len(q)) * 1e-3)
    assert ce.reached.all()
    # the foot jumps over the vertex where the arc crosses the bisector: E = vertex - arc midpoint
    expect = rho * (1 - 1 / math.sqrt(2)) * np.array([1.0, -1.0, 0.0])
    print(f"E(0) = {ce.e_mm[0]} (expected {expect}), |E| = {ce.norm_mm[0] * 1e3:.3f} um "
          f"(rho (sqrt 2 - 1) = {rho * (math.sqrt(2) - 1) * 1e3:.3f} um)")
    np.testing.assert_allclose(ce.e_mm[0], expect, atol=1e-6)
    assert ce.sample[0] == pytest.approx(400 + 400, abs=1.0)  # the arc's middle sample
    assert ce.time_s[0] == pytest.approx(ce.sample[0] * 1e-3)
    np.testing.assert_allclose(ce.e_mm[1], 0.0, atol=1e-12)  # the last sample sits on (10, 10)
    np.testing.assert_array_equal(ce.line, [1, 2])
    np.testing.assert_array_equal(ce.move, [0, 1])


def test_per_command_error_unreached_and_overshoot():
    path = PathGeometry.from_moves(_table([
        (MOVE_RAPID, (0, 0, 5), (0, 0, 0), None, 17, False),
        (MOVE_LINE, (0, 0, 0), (10, 0, 0), None, 17, True),
        (MOVE_LINE, (10, 0, 0), (10, 10, 0), None, 17, True),
        (MOVE_LINE, (10, 10, 0), (0, 10, 0), None, 17, True),
    ]))
    # overshoot: the actual runs 0.3 mm past the corner at (10, 0), then comes back up the side
    x = np.linspace(0, 10.3, 104)
    y = np.linspace(0.0, 6.0, 60)
    q = np.concatenate([np.column_stack([x, np.zeros_like(x)]), np.column_stack([np.full_like(y, 10.0), y])])
    q = np.column_stack([q, np.zeros(len(q))])
    hint = np.where(np.arange(len(q)) < 104, 1, 2)
    err = contour_error(path, q, hint, window=1)
    ce = per_command_error(path, err, q)
    np.testing.assert_array_equal(ce.reached, [True, False, False])
    # first instant the foot reaches the vertex: the first sample at x >= 10
    i = int(np.flatnonzero(x >= 10)[0])
    np.testing.assert_allclose(ce.e_mm[0], [10 - x[i], 0, 0], atol=1e-12)
    assert ce.sample[0] == pytest.approx(i)
    assert np.isnan(ce.e_mm[1:]).all() and np.isnan(ce.sample[1:]).all()


# ---------------------------------------------------------------------------------------------
# tangent (Frenet) estimate vs exact, summary, misc
# ---------------------------------------------------------------------------------------------


def test_tangent_estimate_overestimates_on_a_circle_with_lag():
    """Seed 000: the Frenet estimate is the normal part of r - q at r; on a curve with lag it is too big."""
    r, delta, lag = 5.0, 0.02, np.deg2rad(3.0)  # 20 um inside, 3 degrees (0.26 mm) behind
    th = np.linspace(0, 2 * np.pi, 3601)
    ref = np.column_stack([r * np.cos(th), r * np.sin(th), np.zeros_like(th)])
    act = np.column_stack([(r - delta) * np.cos(th - lag), (r - delta) * np.sin(th - lag), np.zeros_like(th)])
    path = _circle_path(r)
    exact = contour_error(path, act, 0, window=0)
    vec, est = tangent_error(ref, act)
    np.testing.assert_allclose(exact.dist_mm, delta, rtol=1e-9)
    np.testing.assert_allclose(est[1:-1], r - (r - delta) * np.cos(lag), rtol=1e-5)  # central differences
    print(f"circle r={r} mm, 20 um inside, 3 deg lag: exact {exact.dist_mm.mean() * 1e3:.3f} um, "
          f"tangent estimate {est.mean() * 1e3:.3f} um")
    assert np.all(exact.dist_mm < est)
    # the estimate is the tracking error minus its tangential part
    e = ref - act
    np.testing.assert_allclose(np.einsum("ij,ij->i", vec, e - vec), 0.0, atol=1e-12)
    # with an exact tangent and no lag both agree
    _vec0, est0 = tangent_error(ref, np.column_stack([ref[:, :2] * (r - delta) / r, ref[:, 2]]))
    np.testing.assert_allclose(est0[1:-1], delta, rtol=1e-9)  # (one-sided differences at the two ends)


def test_tangent_estimate_with_standstill():
    ref = np.array([[0, 0, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0], [2, 0, 0]], float)
    act = ref + np.array([0.0, 0.1, 0.0])
    _v, n = tangent_error(ref, act)
    np.testing.assert_allclose(n, 0.1)


def test_summary_and_rapids():
    path = PathGeometry.from_moves(_table([
        (MOVE_RAPID, (0, 0, 5), (0, 0, 0), None, 17, False),
        (MOVE_LINE, (0, 0, 0), (10, 0, 0), None, 17, True),
        (MOVE_ARC_CCW, (10, 0, 0), (10, 10, 0), (10, 5, 0), 17, False),
        (MOVE_LINE, (10, 10, 0), (0, 10, 0), None, 17, True),
    ]))
    q = np.array([[0.0, 0.0, 4.0], [5.0, 0.01, 0.0], [15.2, 5.0, 0.0], [5.0, 10.03, 0.0]])
    hint = np.array([0, 1, 2, 3])
    err = contour_error(path, q, hint, window=1)
    # the sample in the rapid finds the feed move's start (rapids are not part of the path)
    assert err.seg[0] == 1 and err.dist_mm[0] == pytest.approx(4.0)
    np.testing.assert_allclose(err.dist_mm[1:], [0.01, 0.2, 0.03], atol=1e-12)
    s = summary(err)
    assert s["n"] == 3  # the sample whose reference is in the rapid is left out
    assert s["max"] == pytest.approx(0.2)
    assert s["worst_index"] == 2 and s["worst_move"] == 2 and s["worst_command"] == -1 and s["worst_line"] == 3
    assert s["rms"] == pytest.approx(math.sqrt((0.01**2 + 0.2**2 + 0.03**2) / 3))
    s2 = summary(err, mask=np.array([True, True, False, True]))
    assert s2["worst_command"] == 1 and s2["worst_line"] == 4 and s2["max"] == pytest.approx(0.03)
    with_rapids = contour_error(PathGeometry.from_moves(path_moves := _table([
        (MOVE_RAPID, (0, 0, 5), (0, 0, 0), None, 17, False),
        (MOVE_LINE, (0, 0, 0), (10, 0, 0), None, 17, True),
    ]), include_rapids=True), q[:1], 0, window=0)
    assert len(path_moves) == 2
    assert with_rapids.dist_mm[0] == pytest.approx(0.0) and with_rapids.seg[0] == 0


def test_no_active_segment_in_window_is_nan():
    path = PathGeometry.from_moves(_table([
        (MOVE_LINE, (0, 0, 0), (1, 0, 0), None, 17, True),
        (MOVE_RAPID, (1, 0, 0), (1, 0, 5), None, 17, False),
        (MOVE_RAPID, (1, 0, 5), (9, 0, 5), None, 17, False),
        (MOVE_RAPID, (9, 0, 5), (9, 0, 0), None, 17, False),
        (MOVE_LINE, (9, 0, 0), (10, 0, 0), None, 17, True),
    ]))
    err = contour_error(path, [[5.0, 0.0, 5.0]], 2, window=0)
    assert np.isnan(err.dist_mm[0]) and err.seg[0] == -1 and np.isnan(err.u[0])
    assert summary(err)["n"] == 0


def test_chunks_threads_and_guessed_hints_agree():
    prog = read_program(CONTOUR / "Gates_combined_R12.nc")
    path = PathGeometry.from_moves(prog.moves)
    rng = np.random.default_rng(9)
    pts = _points_near(path, 6000, rng, max_off=0.02)
    hint = guess_hints(path, pts)
    a = contour_error(path, pts, hint, window=2, workers=1)
    b = contour_error(path, pts, hint, window=2, chunk=1024, workers=2)
    for name in ("dist_mm", "foot_mm", "vector_mm", "u", "signed_mm"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(a.seg, b.seg)
    full = _exhaustive(path, pts)
    ok = np.isclose(a.dist_mm, full.dist_mm, rtol=1e-9, atol=1e-12)
    print(f"KD-tree hints: {ok.mean():.2%} of samples exact")
    assert ok.mean() > 0.99


def test_path_parameter_and_points():
    path = PathGeometry.from_moves(_table([
        (MOVE_LINE, (0, 0, 0), (10, 0, 0), None, 17, True),
        (MOVE_ARC_CW, (10, 0, 0), (10, -10, -2), (10, -5, 0), 17, False),
    ]))
    assert path.n_commands == 1 and list(path.move_of_command) == [0]
    np.testing.assert_allclose(path.length_mm, [10.0, math.hypot(5 * math.pi, 2)])
    np.testing.assert_allclose(path.point_at_u([0.5, 1.0, 1.5, 2.0]),
                               [[5, 0, 0], [10, 0, 0], [15, -5, -1], [10, -10, -2]], atol=1e-12)
    t = path.tangent_at([0, 1], [0.5, 0.5])
    np.testing.assert_allclose(t[0], [1, 0, 0])
    np.testing.assert_allclose(t[1], np.array([0, -5 * math.pi, -2]) / math.hypot(5 * math.pi, 2), atol=1e-12)


# ---------------------------------------------------------------------------------------------
# the compiled search against the numpy path
# ---------------------------------------------------------------------------------------------


def _both_paths(monkeypatch, path, pts, hint, **kw):
    import ilcnc.contour.search as contour_mod

    monkeypatch.setattr(contour_mod, "_USE_KERNEL", False)
    ref = contour_error(path, pts, hint, **kw)
    monkeypatch.setattr(contour_mod, "_USE_KERNEL", True)
    return ref, contour_error(path, pts, hint, **kw)


#: Flops in the longest chain from coordinates to one output (differences, a dot or cross product,
#: a division, a square root), each of which the compiler may reassociate or contract into an FMA.
_CHAIN_FLOPS = 16


def _assert_same_error(a, b, path, pts) -> None:
    """The compiled kernel and the numpy path compute the same formulas, not the same instructions.

    LLVM may contract ``a*b + c`` into one fused multiply-add and numpy rounds each step (numba
    0.68 / llvmlite 0.50 differ from numpy by one rounding in 2 of 2,000 ``signed_mm``). Each output
    in mm is a chain of at most ``_CHAIN_FLOPS`` operations on coordinates of magnitude at most R (the
    largest coordinate of the path and the points), each rounding by at most eps·R/2, so the two agree
    within ``_CHAIN_FLOPS · eps · R``; the path parameter ``u = seg + t`` with ``t`` a distance over the
    segment's length agrees within that over the length (plus one rounding of ``u``). The discrete
    choices (segment, hint, walk) must be equal, except where two feet lie at equal distance within
    that tolerance (a tie either answer is right for).
    """
    eps = np.finfo(float).eps
    r = max(float(np.max(np.abs(path.start_mm))), float(np.max(np.abs(path.end_mm))), float(np.nanmax(np.abs(pts))))
    tol_mm = _CHAIN_FLOPS * eps * r
    for name in ("dist_mm", "foot_mm", "vector_mm", "u", "signed_mm", "seg", "hint"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and x.flags.f_contiguous == y.flags.f_contiguous, name
    np.testing.assert_array_equal(np.isnan(a.dist_mm), np.isnan(b.dist_mm))
    tie = (a.seg != b.seg) & (np.abs(a.dist_mm - b.dist_mm) <= tol_mm)
    same = ~tie
    np.testing.assert_array_equal(a.seg[same], b.seg[same], err_msg="seg")
    np.testing.assert_array_equal(a.hint[same], b.hint[same], err_msg="hint")
    for name in ("dist_mm", "foot_mm", "vector_mm", "signed_mm"):
        x, y = getattr(a, name)[same], getattr(b, name)[same]
        np.testing.assert_allclose(x, y, rtol=0.0, atol=tol_mm, equal_nan=True, err_msg=name)
    ok = same & (a.seg >= 0)
    length = np.maximum(path.length_mm[a.seg[ok]], np.finfo(float).tiny)
    u_tol = tol_mm / length + eps * np.abs(a.u[ok])
    assert np.all(np.abs(a.u[ok] - b.u[ok]) <= u_tol), "u"
    np.testing.assert_allclose(a.dist_mm[tie], b.dist_mm[tie], rtol=0.0, atol=tol_mm, err_msg="tied dist_mm")
    assert a.walked == b.walked


@pytest.mark.parametrize("lag", [0.0, 0.4, -0.4])
def test_compiled_search_equals_numpy_path_on_arcs_and_walks(monkeypatch, lag):
    # spirals, helices and lines of a CAM program; hints off by up to 0.4 mm of path so that the walk runs
    prog = read_program(CONTOUR / "Gates_combined_R12.nc")
    path = PathGeometry.from_moves(prog.moves)
    rng = np.random.default_rng(11)
    pts = _points_near(path, 20000, rng, max_off=0.05)
    full = _exhaustive(path, pts[:2000])
    length = np.where(path.active, path.length_mm, 0.0)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    s = cum[full.seg] + (full.u - full.seg) * length[full.seg]
    hint = np.clip(np.searchsorted(cum, s + lag, side="right") - 1, 0, len(path) - 1)
    pts = pts[:2000]
    pts[7] = np.nan  # a NaN sample: no foot
    for w in (0, 2, 3):
        a, b = _both_paths(monkeypatch, path, pts, hint, window=w, chunk=1024)
        _assert_same_error(a, b, path, pts)
    assert (b.walked > 0) == (lag != 0.0) and np.isnan(b.dist_mm[7]) and b.seg[7] == -1


def test_compiled_search_equals_numpy_path_on_helices_and_planes(monkeypatch):
    b = MoveTableBuilder()
    b.add(MOVE_ARC_CW, 1, (3.0, 2.0, 3.0), (3.0, -1.0, 3.0), center=(1.0, 2.0, 3.0), plane=18, turns=3)  # multi-turn
    b.add(MOVE_LINE, 2, (3.0, -1.0, 3.0), (5.0, -1.0, 4.0))
    b.add(MOVE_ARC_CCW, 3, (5.0, -1.0, 4.0), (5.0, 1.0, 4.5), center=(5.0, 0.0, 4.0), plane=19)  # helix in G19
    b.add(MOVE_RAPID, 4, (5.0, 1.0, 4.5), (9.0, 1.0, 9.0))
    b.add(MOVE_LINE, 5, (9.0, 1.0, 9.0), (9.0, 4.0, 9.0))
    path = PathGeometry.from_moves(b.build())
    rng = np.random.default_rng(12)
    seg = rng.integers(0, len(path), 5000)
    pts = path.point_at(seg, rng.random(5000)) + rng.normal(size=(5000, 3)) * 0.3
    for w in (0, 1, 3):
        a, c = _both_paths(monkeypatch, path, pts, seg, window=w)
        _assert_same_error(a, c, path, pts)


# ---------------------------------------------------------------------------------------------
# the reach: a window of path length (issue 5)
# ---------------------------------------------------------------------------------------------


def _lagging_corner(step=0.005, leg=2.0, lag_periods=60.0):
    """A corner of short segments (one per period) and a machine lagging ~60 segments behind it.

    The reference runs X0 Y0 -> X2 -> Y2 one ``step`` per period and stops; the actual is its first-order lag
    (time constant ``lag_periods``), which cuts the corner. Returns the path, the reference, the actual, the
    hint (the reference's segment) and the exact distance to the two legs (computed independently).
    """
    s = np.arange(1, round(leg / step) + 1) * step
    v = np.vstack([[0.0, 0.0], np.column_stack([s, 0.0 * s]), np.column_stack([np.full_like(s, leg), s])])
    path = PathGeometry.from_polyline(v)
    k = np.minimum(np.arange(int(3 * len(s))), len(v) - 1)
    ref = np.column_stack([v[k], np.zeros(k.size)])
    hint = np.minimum(k, len(path) - 1)  # the reference is the start of segment k (the end of the last one)
    act = np.empty_like(ref)
    act[0] = ref[0]
    for i in range(1, k.size):
        act[i] = act[i - 1] + (ref[i] - act[i - 1]) / lag_periods
    exact = np.full(k.size, np.inf)
    for a, b in (((0.0, 0.0), (leg, 0.0)), ((leg, 0.0), (leg, leg))):
        a, b = np.array(a), np.array(b)
        d = b - a
        t = np.clip((act[:, :2] - a) @ d / (d @ d), 0.0, 1.0)
        exact = np.minimum(exact, np.linalg.norm(act[:, :2] - (a + t[:, None] * d), axis=1))
    return path, ref, act, hint, exact


@pytest.mark.parametrize("kernel", [True, False])
def test_reach_finds_the_corner_the_segment_window_is_trapped_at(monkeypatch, kernel):
    """Issue 5: the machine lags ~60 short segments; the window of 3 segments and its walk stop at a local
    minimum on the second leg (like seed 000's corner: 0.192 mm instead of 0.109 mm); the reach does not."""
    import ilcnc.contour.search as contour_mod

    monkeypatch.setattr(contour_mod, "_USE_KERNEL", kernel)
    path, ref, act, hint, exact = _lagging_corner()
    trapped = contour_error(path, act, hint)
    assert trapped.dist_mm.max() > 2.0 * exact.max()  # 0.229 mm against 0.109 mm
    assert np.count_nonzero(np.abs(trapped.dist_mm - exact) > 1e-9) > 10
    err = contour_error(path, act, hint, reference_mm=ref)
    np.testing.assert_allclose(err.dist_mm, exact, rtol=0.0, atol=1e-12)
    assert err.walked == 0  # the reach covers the lag: nothing is left to walk
    # 2 columns are X, Y as for the actual; a reach of 2 |r - q| is short around the right angle, 2 sqrt(2) is not
    # (the bound of contour_error's notes)
    np.testing.assert_array_equal(contour_error(path, act[:, :2], hint, reference_mm=ref[:, :2]).dist_mm, err.dist_mm)
    long_enough = contour_error(path, act, hint, reference_mm=ref, reach_factor=2.0 * math.sqrt(2.0), max_walk=0)
    np.testing.assert_allclose(long_enough.dist_mm, exact, rtol=0.0, atol=1e-12)


def test_reach_range_is_the_path_length_around_the_hint(monkeypatch):
    """The searched range: the window, widened to every segment within L = factor (|r - q| + slack) of path."""
    import ilcnc.contour.search as contour_mod

    # 10 segments of 1 mm, then 10 of 0.1 mm; the sample sits on segment 12 (s = 10.25), 0.05 mm off the path
    v = np.concatenate([np.arange(0.0, 10.0), 10.0 + 0.1 * np.arange(0, 11)])
    path = PathGeometry.from_polyline(np.column_stack([v, np.zeros_like(v)]))
    np.testing.assert_allclose(path.cum_length_mm, np.concatenate([[0.0], np.cumsum(path.length_mm)]))
    q = np.array([[10.25, 0.05, 0.0]])
    for kernel in (True, False):
        monkeypatch.setattr(contour_mod, "_USE_KERNEL", kernel)
        # hint 19 (s = 10.9 .. 11.0): the window 16 .. 19 misses segment 12, the walk is off
        far = contour_error(path, q, 19, window=1, max_walk=0)
        assert far.seg[0] == 18
        # |r - q| = 0.05: L = 4 (0.05 + 0.08) = 0.52 mm reaches back to s = 10.38 from s(19) = 10.9: segment 13
        short = contour_error(path, q, 19, window=1, max_walk=0, reference_mm=[[10.3, 0.05, 0.0]],
                              reference_slack_mm=0.08)
        assert short.seg[0] == 13
        # L = 4 (0.05 + 0.125) = 0.7 mm reaches s = 10.2: segment 12, the foot
        near = contour_error(path, q, 19, window=1, max_walk=0, reference_mm=[[10.3, 0.05, 0.0]],
                             reference_slack_mm=0.125)
        assert near.seg[0] == 12 and near.dist_mm[0] == pytest.approx(0.05, abs=1e-12)
        # the slack per segment, taken at the hint
        slack = np.zeros(len(path))
        slack[19] = 0.125
        per_seg = contour_error(path, q, 19, window=1, max_walk=0, reference_mm=[[10.3, 0.05, 0.0]],
                                reference_slack_mm=slack)
        assert per_seg.seg[0] == 12
        slack[19], slack[18] = 0.0, 0.125
        assert contour_error(path, q, 19, window=1, max_walk=0, reference_mm=[[10.3, 0.05, 0.0]],
                             reference_slack_mm=slack).seg[0] == 16  # L = 0.2 mm: back to 16 (s = 10.6 .. 10.7)
        # a NaN reference: the window only
        nan = contour_error(path, q, 19, window=1, max_walk=0, reference_mm=[[np.nan, 0.0, 0.0]])
        assert nan.seg[0] == far.seg[0] and nan.dist_mm[0] == far.dist_mm[0]
    with pytest.raises(ValueError, match="reference_mm"):
        contour_error(path, q, 19, reference_mm=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="reference_slack_mm"):
        contour_error(path, q, 19, reference_mm=q, reference_slack_mm=np.zeros(3))


@pytest.mark.parametrize("lag", [0.4, -0.4, 3.0])
def test_compiled_search_equals_numpy_path_with_the_reach(monkeypatch, lag):
    # spirals, helices and lines; the reference lag mm of path ahead of (or behind) each sample's foot, so that the
    # ranges vary from the window to ~100 segments and some still end at the foot's side and walk
    prog = read_program(CONTOUR / "Gates_combined_R12.nc")
    path = PathGeometry.from_moves(prog.moves)
    rng = np.random.default_rng(13)
    pts = _points_near(path, 2000, rng, max_off=0.05)
    full = _exhaustive(path, pts)
    length = np.where(path.active, path.length_mm, 0.0)
    cum = np.concatenate([[0.0], np.cumsum(length)])
    s = cum[full.seg] + (full.u - full.seg) * length[full.seg]
    hint = np.clip(np.searchsorted(cum, s + lag, side="right") - 1, 0, len(path) - 1)
    ref = path.point_at(hint, np.clip((s + lag - cum[hint]) / np.where(length[hint] > 0, length[hint], 1.0), 0, 1))
    # the reference on the path: without a walk the reach finds the nearest point of the whole path (the
    # exhaustive search) but where the path reverses between foot and reference (beyond the 120 degrees of its
    # bound: 1 sample in 2000 at lag 0.4); the window of 3 segments misses more (its range is a part of the reach's)
    reach = contour_error(path, pts, hint, reference_mm=ref, max_walk=0)
    window = contour_error(path, pts, hint, max_walk=0)
    assert np.all(reach.dist_mm >= full.dist_mm - 1e-12) and np.all(reach.dist_mm <= window.dist_mm + 1e-12)
    exact_reach = np.count_nonzero(np.isclose(reach.dist_mm, full.dist_mm, rtol=1e-9, atol=1e-12))
    exact_window = np.count_nonzero(np.isclose(window.dist_mm, full.dist_mm, rtol=1e-9, atol=1e-12))
    assert exact_reach >= 1996 and exact_window < exact_reach
    ref[rng.random(len(ref)) < 0.5] += 0.5 * (rng.random((1, 3)) - 0.5)  # half the references off, some ranges short
    pts[7] = np.nan  # a NaN sample: no foot
    ref[8] = np.nan  # a NaN reference: the window only
    for w in (0, 2, 3):
        for factor, slack in ((4.0, 0.0), (1.0, 0.01), (2.0, rng.random(len(path)) * 0.2)):
            a, b = _both_paths(monkeypatch, path, pts, hint, window=w, chunk=1024, reference_mm=ref,
                               reach_factor=factor, reference_slack_mm=slack)
            _assert_same_error(a, b, path, pts)
    assert np.isnan(b.dist_mm[7]) and b.seg[7] == -1

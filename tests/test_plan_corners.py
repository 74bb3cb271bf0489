"""The speed through a junction from the filters' rounding of the polyline around it (ilcnc.vcnc.plan_corners)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ilcnc.program.gcode import read_gcode
from ilcnc.vcnc import plan_corners
from ilcnc.vcnc.plan import PlanLimits, plan_moves
from ilcnc.vcnc.plan_corners import junction_speeds, rounding_tables

PERIOD = 0.001


def _limits(v: float = 50.0, a: float = 1000.0, j: float = 20000.0) -> PlanLimits:
    return PlanLimits(np.full(3, v), np.full(3, v), np.full(3, a), np.full(3, j))


def _prog(text: str):
    return read_gcode(Path("t.ngc"), text.encode())


def _kernel(lengths: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    h = np.ones(1)
    for n in lengths:
        h = np.convolve(h, np.full(n, 1.0 / n))
    return h, (np.arange(h.size) - 0.5 * (h.size - 1)) * PERIOD


@pytest.mark.parametrize("lengths", [(17, 59), (59, 17), (100, 10), (40, 40), (3, 56, 10)])
def test_tables_are_the_kernels_moments(lengths: tuple[int, ...]) -> None:
    g, rho, step = rounding_tables(lengths, PERIOD)
    h, tau = _kernel(lengths)
    for k in (0, 3, 17, g.size // 2):
        d = k * step
        assert g[k] == pytest.approx(float(np.sum(h * np.maximum(tau - d, 0.0))), rel=1e-12, abs=1e-18)
    # one junction alone: E[tau+] is T_long/8 + T_short^2/(24 T_long) for two filters (whichever comes first:
    # the rule before this module took the first filter as the long one, 41 % too slow at (17, 59)), up to the
    # discrete kernel's own difference from the continuous one (a sample in ~60: 1e-3 relative)
    if len(lengths) == 2:
        t_long, t_short = max(lengths) * PERIOD, min(lengths) * PERIOD
        assert g[0] == pytest.approx(t_long / 8 + t_short**2 / (24 * t_long), rel=2e-3)
    # the density's peak is 1 / the longest filter (the acceleration of a velocity step)
    assert rho[0] == pytest.approx(1.0 / (max(lengths) * PERIOD), rel=1e-12)
    # the support ends where the kernel ends
    assert (g.size - 2) * step <= 0.5 * (sum(lengths) - len(lengths) + 1) * PERIOD + step


def test_a_corner_alone_gets_the_closed_form_speed() -> None:
    tables = rounding_tables((20, 60), PERIOD)
    du = np.array([[-1.0, 1.0, 0.0]])  # 90 degrees
    tol = 0.01
    v = junction_speeds(np.zeros(1), du, np.array([tol]), np.array([200.0]), np.full(3, np.inf), np.zeros(1, bool),
                        tables)
    assert v[0] == pytest.approx(tol / (np.sqrt(2.0) * tables[0][0]), rel=1e-9)  # bisection to 2^-40 of 200 mm/s
    # and the acceleration: v |du_axis| / T_long within the axis's limit
    v = junction_speeds(np.zeros(1), du, np.array([10.0]), np.array([200.0]), np.full(3, 1000.0), np.zeros(1, bool),
                        tables)
    assert v[0] == pytest.approx(1000.0 * 0.06, rel=1e-9)


def test_corner_rounding_reaches_the_tolerance_when_the_jerk_filter_is_the_longer() -> None:
    # a = 1000 mm/s^2, j = 5000 mm/s^3 at 50 mm/s: T1 = 50 ms (acceleration), T2 = 200 ms (jerk)
    prog = _prog("G21 G90\nG0 X0 Y0 Z0\nG1 X80 F3000\nY80\nM2\n")
    for tol in (0.005, 0.05):
        ref = plan_moves(prog.moves, _limits(j=5000.0), period_s=PERIOD, corner_tolerance_mm=tol)
        p = ref.pos_mm[:, :2]
        dev = float(np.min(np.hypot(p[:, 0] - 80.0, p[:, 1])))
        # within the tolerance, and the speed lowered no more than it needs (the rule before: 0.69 of it). The
        # corner falls between two ticks: the sampled motion cuts it by at most v*P*|du|/4 there, which the
        # kernel's peak weight 1/n_long passes on: 2/n_long^2 of the rounding v*|du|*n_long*P/8 (measured 4.8e-5)
        assert 0.97 * tol <= dev <= tol * (1 + 2 / 200**2)


def _zigzag_line(n: int, step_mm: float, amp_mm: float) -> str:
    # 20 mm straight before and after: the axes start and stop on a straight line (the filters are designed to
    # reach the jerk limit exactly there, so the planner's check would take any kink in the ramp as a breach)
    lines = ["G21 G90 G64", "G0 X0 Y0 Z0", "F3000", "G1 X20"]
    for i in range(1, n + 1):
        y = 0.0 if i == n else (amp_mm if i % 2 else -amp_mm)
        lines.append(f"G1 X{20 + i * step_mm:.4f} Y{y:.4f}")
    return "\n".join([*lines, f"G1 X{40 + n * step_mm:.4f}", "M2", ""])


def test_alternating_kinks_on_a_line_do_not_slow_it() -> None:
    # what learning writes at points inserted on a line: corrections of +-1 um between points 0.1 mm apart.
    # Each kink alone (2 % turn) would be a corner of 1.1 um rounding at 50 mm/s and slow the line to the
    # tolerance's speed; the filters average 60 of them to nothing
    line = plan_moves(_prog(_zigzag_line(400, 0.1, 0.0)).moves, _limits(), period_s=PERIOD, corner_tolerance_mm=0.001)
    kinks = plan_moves(_prog(_zigzag_line(400, 0.1, 0.001)).moves, _limits(), period_s=PERIOD,
                       corner_tolerance_mm=0.001)
    assert kinks.duration_s <= line.duration_s * 1.005
    # the same kinks taken one by one (each junction alone) would cap the speed far below the feed
    tables = rounding_tables((50, 50), PERIOD)
    m = 400
    du = np.zeros((m, 3))
    du[:, 1] = np.where(np.arange(m) % 2, 0.04, -0.04)
    s = np.arange(m) * 0.1
    args = (s, du, np.full(m, 0.001), np.full(m, 50.0), np.full(3, np.inf))
    alone = junction_speeds(*args, np.ones(m, bool), tables)
    together = junction_speeds(*args, np.zeros(m, bool), tables)
    assert np.all(alone < 50.0)
    # inside the chain, farther from its ends than the filters reach (50 mm/s x 50 ms = 2.5 mm: 25 kinks) twice
    # over: the ends see half a kink's rounding, which the line's lead-in and lead-out take in the program above,
    # and each slow junction passes its speed on to the junctions within its own span (measured: finite at the
    # first and last 47)
    assert np.all(np.isinf(together[50:-50]))
    assert np.all(np.diff(together[:47]) >= 0.0)  # the speed rises from the ends inwards


def test_a_dense_polygon_rounds_as_its_arc() -> None:
    # a circle of R = 2 mm in 0.01 mm chords: the filters shrink it by v^2 Var(tau) / (2 R)
    r_mm, n = 2.0, 1257
    ang = np.linspace(0.0, 2 * np.pi, n + 1)
    pts = np.stack([r_mm * np.cos(ang), r_mm * np.sin(ang), np.zeros(n + 1)], axis=1)
    u = np.diff(pts, axis=0)
    u /= np.linalg.norm(u, axis=1)[:, None]
    du = u[1:] - u[:-1]
    s = np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))[:-1]
    lengths = (30, 20)
    tables = rounding_tables(lengths, PERIOD)
    var = sum((k * PERIOD) ** 2 for k in lengths) / 12.0
    tol = 0.002
    v = junction_speeds(s, du, np.full(n - 1, tol), np.full(n - 1, 500.0), np.full(3, np.inf),
                        np.zeros(n - 1, bool), tables)
    mid = v[n // 2]
    # the discrete kernel's variance differs from the continuous one's by (1/12)(1/n^2) terms: ~0.3 %
    assert mid == pytest.approx(np.sqrt(2 * tol * r_mm / var), rel=0.01)


def test_compiled_kernel_equals_its_python() -> None:
    rng = np.random.default_rng(7)
    m = 200
    s = np.cumsum(rng.uniform(0.01, 0.5, m))
    du = rng.normal(0.0, 0.05, (m, 3))
    tol = np.where(rng.uniform(size=m) < 0.1, 0.0, rng.uniform(0.001, 0.02, m))
    cap = rng.uniform(5.0, 80.0, m)
    acc = np.array([1000.0, 800.0, np.inf])
    alone = rng.uniform(size=m) < 0.05
    g, rho, step = rounding_tables((40, 25), PERIOD)
    reach = g.size * step
    got = plan_corners._junction_speeds(s, du, tol, cap, acc, alone, g, rho, step, reach)
    want = plan_corners._junction_speeds.py_func(s, du, tol, cap, acc, alone, g, rho, step, reach)
    # the same operations in the same order: equal but for the compiler's fused multiply-adds (ulps of the
    # sums, which move a bisection step by at most its last bit)
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_a_corrected_corner_stays_within_the_tolerance_of_its_own_path() -> None:
    """compass refined on the example mill, one learning step (no guard, no cycle budget): the corrections bend
    the points inserted next to its corners by ~1 µm. The planner rounds the corrected program within the
    corner tolerance of that program's own path (measured 9.38 µm for 10 µm; before a junction within the span
    of a slower one took that speed, the kinks lowered the corner's own sum and the motion around it ran faster
    than the sum assumed: 11.17 µm at line 328)."""
    import dataclasses

    from ilcnc.contour.path import PathGeometry
    from ilcnc.contour.search import contour_error
    from ilcnc.learning.learner import learn_virtual, refine_for_learning
    from ilcnc.profile.load import load_profile
    from ilcnc.vcnc.plan import plan_program

    repo = Path(__file__).resolve().parents[1]
    profile = load_profile(repo / "configs" / "example-mill.yaml")
    profile = dataclasses.replace(profile, learning=dataclasses.replace(profile.learning, cycle_budget_pct=100.0))
    prog = refine_for_learning(read_gcode(repo / "samples" / "compass.ngc",
                                          (repo / "samples" / "compass.ngc").read_bytes()), profile).program
    res = learn_virtual(prog, profile, iterations=1, error="lifted", stop_on_stall=False, guard=False)
    corrected = read_gcode(prog.path, res.iterations[1].text.encode("latin-1"))
    assert np.count_nonzero(res.iterations[1].corrections_mm) > 100
    ref = plan_program(corrected, profile)
    ce = contour_error(PathGeometry.from_moves(corrected.moves), ref.pos_mm, np.maximum(ref.move, 0),
                       reference_mm=ref.pos_mm)
    dist = np.asarray(ce.dist_mm)[ref.command >= 0]
    tol = profile.planner.corner_tolerance_mm
    # the sampled motion may cut a corner between two ticks by a hair more (test above: 2/n_long^2 of it)
    assert np.nanmax(dist) <= tol * 1.001

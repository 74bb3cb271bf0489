"""Feed planner: limits on real programs, the 7-phase profile against ruckig, corner tolerance, arcs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.program.gcode import read_gcode
from ilcnc.vcnc.plan import PlanLimits, check_limits, plan_moves, plan_program

from .conftest import REPO, SAMPLES

PROFILE = load_profile(REPO / "configs" / "example-mill.yaml")


def _limits(v: float = 50.0, a: float = 1000.0, j: float = 20000.0) -> PlanLimits:
    return PlanLimits(np.full(3, v), np.full(3, v), np.full(3, a), np.full(3, j))


def _prog(text: str):
    return read_gcode(Path("t.ngc"), text.encode())


@pytest.mark.parametrize("name", ["contour/compass.ngc", "contour/locket_outside.ngc", "contour/Gates_combined_R12.nc",
                                  "contour/vcarve.ngc", "gcode/tiny_cat_outline.ngc"])
def test_never_exceeds_axis_limits_on_real_programs(name: str) -> None:
    prog = read_program(SAMPLES / name)
    ref = plan_program(prog, PROFILE)
    lim = PlanLimits.from_profile(PROFILE)
    peak = check_limits(ref, lim)
    assert np.all(peak["velocity"] <= lim.velocity_mm_s * (1 + 1e-5))
    assert np.all(peak["acceleration"] <= lim.acceleration_mm_s2 * (1 + 1e-5))
    assert np.all(peak["jerk"] <= lim.jerk_mm_s3 * (1 + 1e-5))
    # it ends where the program ends, and visits every move in order
    assert np.allclose(ref.pos_mm[-1], prog.moves.end_mm[-1])
    seen = ref.move[ref.move >= 0]
    assert np.all(np.diff(seen) >= 0)
    # accounting for acceleration makes it slower than the feed-only estimate, never faster
    from ilcnc.program.geometry import feed_time_s
    rapid = min(ax.rapid_mm_min for ax in PROFILE.axes.values())
    assert ref.duration_s >= 0.99 * feed_time_s(prog.moves, rapid)


def test_single_move_matches_ruckig() -> None:
    ruckig = pytest.importorskip("ruckig", reason="ruckig (test reference) not installed")
    v, a, j = 50.0, 1000.0, 20000.0
    prog = _prog("G21 G90\nG0 X0 Y0 Z0\nG1 X100 F3000\nM2\n")
    ref = plan_moves(prog.moves[1:] if False else prog.moves, _limits(v, a, j), period_s=0.001,
                     corner_tolerance_mm=0.01)
    # the feed move alone (the rapid to the origin has zero length)
    inp = ruckig.InputParameter(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [100.0], [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [v], [a], [j]
    traj = ruckig.Trajectory(1)
    assert ruckig.Ruckig(1).calculate(inp, traj) == ruckig.Result.Working
    x = ref.pos_mm[:, 0]
    moving = np.flatnonzero(np.abs(np.diff(x)) > 1e-12)
    t0 = moving[0]
    t_ours = (moving[-1] + 1 - t0) * 0.001
    assert t_ours == pytest.approx(traj.duration, abs=0.002)
    # same position profile, sample by sample
    times = np.arange(0, int(traj.duration / 0.001)) * 0.001
    theirs = np.array([traj.at_time(t)[0][0] for t in times])
    ours = x[t0:t0 + times.size]
    assert np.max(np.abs(ours - theirs)) < 0.06  # mm: one servo tick of phase at 50 mm/s


def _corner_deviation(p: np.ndarray, x: float = 50.0) -> float:
    """Largest distance of the points from the corner X0 Y0 -> X``x`` -> Y.. (mm)."""
    # distance to the two legs of the corner (x axis, then the line x = ``x``)
    d1 = np.where(p[:, 0] <= x, np.abs(p[:, 1]), np.hypot(p[:, 0] - x, p[:, 1]))
    d2 = np.where(p[:, 1] >= 0, np.abs(p[:, 0] - x), np.hypot(p[:, 0] - x, p[:, 1]))
    return float(np.minimum(d1, d2).max())


def test_corner_never_cut_by_more_than_the_tolerance() -> None:
    prog = _prog("G21 G90\nG0 X0 Y0 Z0\nG1 X50 F3000\nY50\nM2\n")
    for tol in (0.005, 0.05, 0.5):
        ref = plan_moves(prog.moves, _limits(), period_s=0.001, corner_tolerance_mm=tol)
        dev = _corner_deviation(ref.pos_mm)
        assert dev <= tol * (1 + 1e-6)
        assert dev >= 0.5 * tol  # and the speed was not lowered more than needed


def test_arc_is_interpolated_as_arc_within_tolerance() -> None:
    prog = _prog("G21 G90 G17\nG0 X25 Y0 Z0\nG2 X25 Y0 I-25 J0 F3000\nM2\n")
    ref = plan_moves(prog.moves, _limits(), period_s=0.001, corner_tolerance_mm=0.01)
    r = np.hypot(ref.pos_mm[:, 0], ref.pos_mm[:, 1])
    moving = ref.move == 1
    assert np.max(np.abs(r[moving] - 25.0)) <= 0.01 + 1e-6
    # clockwise: the angle decreases
    ang = np.unwrap(np.arctan2(ref.pos_mm[moving, 1], ref.pos_mm[moving, 0]))
    assert ang[-1] - ang[0] == pytest.approx(-2 * np.pi, abs=1e-3)


def test_an_arc_whose_end_misses_the_circle_is_a_spiral_to_its_end() -> None:
    """End radius 25.02 mm, start radius 25 mm (LinuxCNC accepts up to 0.028 mm and runs a spiral whose radius
    changes in proportion to the angle): the reference reaches the end point without a jump and its radius
    moves from 25 to 25.02 mm with the angle."""
    prog = _prog("G21 G90 G17\nG0 X25 Y0 Z0\nG3 X0 Y25.02 I-25 J0 F600\nG1 X-10\nM2\n")
    ref = plan_moves(prog.moves, _limits(), period_s=0.001, mode="constant_feed")
    on_arc = ref.move == 1
    p = ref.pos_mm[on_arc]
    r = np.hypot(p[:, 0], p[:, 1])
    ang = np.arctan2(p[:, 1], p[:, 0])
    # constant feed: the ideal interpolator itself, sampled on the spiral
    assert np.max(np.abs(r - (25.0 + 0.02 * ang / (np.pi / 2)))) <= 1e-9
    feed = np.flatnonzero(ref.move >= 1)
    step = np.linalg.norm(ref.pos_mm[feed] - ref.pos_mm[feed - 1], axis=1)
    # 600 mm/min, no jump at the arc's end: the interpolator advances the angle by the start circle's length, so
    # on the spiral a step is at most r1 / r0 = 25.02 / 25 as long (plus the radial rate, 1e-7 of it)
    assert step.max() <= 10.0 * 0.001 * (25.02 / 25.0) * (1 + 1e-6)
    assert np.linalg.norm(p[-1] - [0.0, 25.02, 0.0]) <= step.max()  # the last sample on the arc, one step short


def test_constant_feed_is_the_ideal_interpolator() -> None:
    prog = _prog("G21 G90\nG0 X0 Y0 Z0\nG1 X10 F150\nY10\nM2\n")
    ref = plan_moves(prog.moves, _limits(), period_s=0.001, mode="constant_feed")
    v = np.linalg.norm(np.diff(ref.pos_mm, axis=0), axis=1) / 0.001
    moving = v > 0
    # 150 mm/min all the way, no slow-down at the corner (only the tick that straddles the vertex is a chord)
    assert np.count_nonzero(np.abs(v[moving] - 2.5) > 1e-9) <= 1
    assert v[moving].min() > 2.5 / np.sqrt(2) - 1e-9
    assert ref.duration_s == pytest.approx(20.0 / 2.5, abs=0.002)


def test_cubic_profile_has_continuous_jerk() -> None:
    prog = _prog("G21 G90\nG0 X0 Y0 Z0\nG1 X100 F3000\nM2\n")
    seven = plan_moves(prog.moves, _limits(), period_s=0.001, mode="seven_phase")
    cubic = plan_moves(prog.moves, _limits(), period_s=0.001, mode="cubic", jerk_time_constant_s=0.01)
    j7 = np.diff(seven.pos_mm[:, 0], n=3) / 1e-9
    jc = np.diff(cubic.pos_mm[:, 0], n=3) / 1e-9
    # the 7-phase profile jumps between 0 and +-J; the cubic one ramps (steps of J * Ts / Tj, twice that where
    # two ramps meet)
    assert np.max(np.abs(np.diff(j7))) > 0.9 * 20000
    assert np.max(np.abs(np.diff(jc))) < 0.25 * 20000
    assert cubic.duration_s == pytest.approx(seven.duration_s + 0.01, abs=0.003)


# -- the compiled planner against the numpy path -------------------------------------------


def _numpy_plan(moves, limits: PlanLimits, **kw):
    from ilcnc.vcnc import plan
    args = dict(period_s=0.001, mode="seven_phase", corner_tolerance_mm=0.01, jerk_time_constant_s=0.01,
                in_position_s=plan.IN_POSITION_S, max_passes=12)
    args.update(kw)
    return plan._plan(moves, limits, args["period_s"], args["mode"], args["corner_tolerance_mm"],
                      args["jerk_time_constant_s"], args["in_position_s"], args["max_passes"], kernel=False)


def _assert_same_reference(a, b) -> None:
    """The compiled planner and its numpy twin: the same arithmetic, not the same instructions.

    The positions are running sums (the moving averages and the sum back to positions) over a group; the
    compiler may contract a multiply-add or keep a partial sum in a register where numpy rounds, one rounding
    per term at most, each at most eps times the largest coordinate, and a running sum carries those along:
    so the two agree within ``eps * max|x| * n`` for ``n`` samples (a bound; measured: bit for bit with numba
    0.68). The discrete columns (move, command, line) and the speeds are decided on equal numbers: equal.
    """
    assert a.pos_mm.shape == b.pos_mm.shape and a.pos_mm.dtype == b.pos_mm.dtype == np.float64
    n = a.pos_mm.shape[0]
    tol = np.finfo(float).eps * max(float(np.max(np.abs(a.pos_mm), initial=1.0)), 1.0) * max(n, 1)
    np.testing.assert_allclose(a.pos_mm, b.pos_mm, rtol=0.0, atol=tol)
    for name in ("move", "command", "line"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.int32
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.move_speed_mm_s, b.move_speed_mm_s)


@pytest.mark.parametrize("text", [
    "G21 G90\nG0 X0 Y0 Z0\nG1 X5 F3000\nX4\nX5\nX4.5\nY1\nM2\n",  # reversals: limits hit, groups planned again
    "G21 G90\nG0 X0 Y0 Z0\nG1 X5 F3000\nY0.2\nX0\nY0.4\nX5\nY0.6\nX0\nG0 Z5\nX20\nG1 Z0 F600\nX25\nM2\n",
    "G21 G90 G17\nG0 X25 Y0 Z0\nG2 X25 Y0 Z-2 I-25 J0 P2 F3000\nG18 G3 X35 Z-2 I5 K0\nG19 G2 Y5 Z3 J2.5 K2.5\nM2\n",
    # path control per move, and an inverse-time stand-still
    "G21 G90\nG0 X0 Y0 Z0\nG61\nG1 X5 F3000\nY1\nG61.1 X6\nX7\nG64\nY0\nX0.5\nG64 P0.002 Y0.3\nX3\nG2 X5 Y0.3 R1\n"
    "G93 G1 X5 F3000\nX5.5 F6000\nY3 F60000\nM2\n",
    # a spiral: the end misses the circle through the start by 20 µm
    "G21 G90 G17\nG0 X25 Y0 Z0\nG1 X25.01 F3000\nG3 X0 Y25.02 I-25.01 J0\nG1 X-10\nM2\n",
])
@pytest.mark.parametrize("mode", ["seven_phase", "cubic", "constant_feed"])
@pytest.mark.parametrize("tol", [0.0, 0.01, 0.5])
def test_compiled_planner_equals_numpy_path(text: str, mode: str, tol: float) -> None:
    moves = _prog(text).moves
    kw = dict(period_s=0.001, mode=mode, corner_tolerance_mm=tol, jerk_time_constant_s=0.01)
    _assert_same_reference(plan_moves(moves, _limits(), **kw), _numpy_plan(moves, _limits(), **kw))


@pytest.mark.parametrize("name", ["contour/Gates_combined_R12.nc", "gcode/arcspiral.ngc", "gcode/cds.ngc"])
def test_compiled_planner_equals_numpy_path_on_real_programs(name: str) -> None:
    prog = read_program(SAMPLES / name)
    lim = PlanLimits.from_profile(PROFILE)
    kw = dict(period_s=PROFILE.machine.servo_period_s, corner_tolerance_mm=PROFILE.planner.corner_tolerance_mm)
    _assert_same_reference(plan_program(prog, PROFILE), _numpy_plan(prog.moves, lim, **kw))


def test_position_array_grows_when_replanning_outgrows_its_estimate(monkeypatch: pytest.MonkeyPatch) -> None:
    # the array is sized from the speeds before re-planning; without slack a slower re-plan must grow it
    from ilcnc.vcnc import plan
    moves = _prog("G21 G90\nG0 X0 Y0 Z0\nG1 X5 F3000\nX4\nX5\nX4.5\nY1\nG0 Z5\nG1 Z0 F300\nM2\n").moves
    ref = plan_moves(moves, _limits(), period_s=0.001)
    reserve = plan._reserve
    grown = []

    def spy(buf, size):
        grown.append(size > buf.shape[0])
        return reserve(buf, size)

    monkeypatch.setattr(plan, "_SLACK_ROWS", 0)
    monkeypatch.setattr(plan, "_reserve", spy)
    _assert_same_reference(plan_moves(moves, _limits(), period_s=0.001), ref)
    assert any(grown)


# -- the program's path control (G61, G61.1, G64 [P]) -----------------------------------------


def _speed_mm_s(ref) -> np.ndarray:
    """Path speed at every sample (backward difference; 0 at the first), mm/s."""
    return np.concatenate(([0.0], np.linalg.norm(np.diff(ref.pos_mm, axis=0), axis=1) / ref.period_s))


def _at_vertex(ref, vertex: tuple[float, float]) -> tuple[float, float]:
    """Closest approach of the reference to ``vertex`` (mm) and the lowest speed there (within 0.1 mm of it, mm/s)."""
    d = np.hypot(ref.pos_mm[:, 0] - vertex[0], ref.pos_mm[:, 1] - vertex[1])
    return float(d.min()), float(_speed_mm_s(ref)[d < d.min() + 0.1].min())


def test_g61_stops_at_every_corner_whatever_the_profile_tolerance() -> None:
    square = "G1 X20 F3000\nY20\nX0\nY0\nM2\n"
    exact = plan_moves(_prog("G21 G90\nG0 X0 Y0 Z0\nG61\n" + square).moves, _limits(), period_s=0.001,
                       corner_tolerance_mm=0.5)
    for vertex in ((20, 0), (20, 20), (0, 20)):
        dist, v_min = _at_vertex(exact, vertex)
        assert dist < 1e-9 and v_min < 1e-6  # on the vertex, at rest
    blended = plan_moves(_prog("G21 G90\nG0 X0 Y0 Z0\nG64 P0.5\n" + square).moves, _limits(), period_s=0.001,
                         corner_tolerance_mm=0.0)  # the program's P beats the profile's exact stop
    for vertex in ((20, 0), (20, 20), (0, 20)):
        dist, v_min = _at_vertex(blended, vertex)
        assert 0.25 < dist < 0.6 and v_min > 20.0
    assert exact.duration_s > blended.duration_s + 0.1


def test_g61_passes_tangent_joins_and_g61_1_stops_there_too() -> None:
    text = "G21 G90\nG0 X0 Y0 Z0\n{mode}\nG1 X10 F3000\nX20\nM2\n"
    path = plan_moves(_prog(text.format(mode="G61")).moves, _limits(), period_s=0.001)
    stop = plan_moves(_prog(text.format(mode="G61.1")).moves, _limits(), period_s=0.001)
    assert _at_vertex(path, (10, 0))[1] > 49.0
    dist, v_min = _at_vertex(stop, (10, 0))
    assert dist < 1e-9 and v_min < 1e-6
    assert stop.duration_s > path.duration_s + 0.05


def test_g64_p_bounds_the_corner_deviation() -> None:
    text = "G21 G90\nG0 X0 Y0 Z0\nG64 P{p}\nG1 X50 F3000\nY50\nM2\n"
    refs = {}
    for p in (0.001, 0.05):
        # the program's tolerance, not the profile's, whichever is larger
        refs[p] = ref = plan_moves(_prog(text.format(p=p)).moves, _limits(), period_s=0.001, corner_tolerance_mm=0.3)
        dev = _corner_deviation(ref.pos_mm)
        assert 0.5 * p <= dev <= p * (1 + 1e-6)
    assert refs[0.001].duration_s > refs[0.05].duration_s + 0.01


def test_g64_without_p_blends_at_least_as_much_as_any_p() -> None:
    text = "G21 G90\nG0 X0 Y0 Z0\n{mode}\nG1 X50 F3000\nY50\nM2\n"
    free = plan_moves(_prog(text.format(mode="G64")).moves, _limits(), period_s=0.001, corner_tolerance_mm=0.001)
    dev_free = _corner_deviation(free.pos_mm)
    for p in (0.001, 0.05, 0.5, 5.0):
        ref = plan_moves(_prog(text.format(mode=f"G64 P{p}")).moves, _limits(), period_s=0.001)
        assert dev_free >= _corner_deviation(ref.pos_mm) * (1 - 1e-9)
        assert free.duration_s <= ref.duration_s
    assert dev_free > 0.4  # the corner at full speed: only the axes' acceleration bounds the blend
    assert _at_vertex(free, (50, 0))[1] > 30.0  # 50 mm/s along the legs, 50/sqrt(2) at the bisector
    # G64 P0 is G64 without P (LinuxCNC: tolerance 0 = no tolerance)
    p0 = plan_moves(_prog(text.format(mode="G64 P0")).moves, _limits(), period_s=0.001, corner_tolerance_mm=0.001)
    np.testing.assert_array_equal(p0.pos_mm, free.pos_mm)


def test_programmed_blends_are_bounded_by_a_quarter_of_the_shorter_move(monkeypatch: pytest.MonkeyPatch) -> None:
    # LinuxCNC's own bound (tcFindBlendTolerance): 0.5 mm legs blend by at most 0.125 mm, with or without P
    from ilcnc.vcnc import plan_corners
    text = "G21 G90\nG0 X0 Y0 Z0\n{mode}\nG1 X0.5 F3000\nY0.5\nM2\n"
    free = plan_moves(_prog(text.format(mode="G64")).moves, _limits(), period_s=0.001)
    assert 0.5 * 0.125 < _corner_deviation(free.pos_mm, x=0.5) <= 0.125 * (1 + 1e-6)
    for mode in ("G64 P0.125", "G64 P3"):
        _assert_same_reference(plan_moves(_prog(text.format(mode=mode)).moves, _limits(), period_s=0.001), free)
    # the bound is what keeps it there: without it the corner is cut by more
    monkeypatch.setattr(plan_corners, "BLEND_LENGTH_FRACTION", np.inf)  # the junction rule's (plan_corners)
    unbounded = plan_moves(_prog(text.format(mode="G64")).moves, _limits(), period_s=0.001)
    assert _corner_deviation(unbounded.pos_mm, x=0.5) > 0.125


def test_g64_p_of_an_inch_program_is_in_inch() -> None:
    x = 50 / 25.4  # 50 mm legs, written in inch
    text = f"G20 G90\nG0 X0 Y0 Z0\nG64 P0.002\nG1 X{x} F120\nY{x}\nM2\n"
    ref = plan_moves(_prog(text).moves, _limits(), period_s=0.001, corner_tolerance_mm=0.5)
    dev = _corner_deviation(ref.pos_mm)
    assert 0.5 * 0.0508 <= dev <= 0.0508 * (1 + 1e-6)


def test_the_move_before_a_corner_decides_and_the_smaller_tolerance_wins() -> None:
    # the corner at the end of a move follows that move's mode (LinuxCNC: the previous segment's term_cond) ...
    ref = plan_moves(_prog("G21 G90\nG0 X0 Y0 Z0\nG64 P0.05\nG1 X50 F3000\nG61\nY50\nX0\nM2\n").moves, _limits(),
                     period_s=0.001)
    first = ref.pos_mm[:, 1] < 25.0
    assert 0.025 <= _corner_deviation(ref.pos_mm[first]) <= 0.05 * (1 + 1e-6)  # blended
    assert _at_vertex(ref, (50, 0))[1] > 1.0
    dist, v_min = _at_vertex(ref, (50, 50))
    assert dist < 1e-9 and v_min < 1e-6  # stopped on the vertex
    # ... and where both moves blend, by the smaller of their tolerances
    ref = plan_moves(_prog("G21 G90\nG0 X0 Y0 Z0\nG64 P0.5\nG1 X50 F3000\nG64 P0.01\nY50\nM2\n").moves, _limits(),
                     period_s=0.001)
    assert 0.005 <= _corner_deviation(ref.pos_mm) <= 0.01 * (1 + 1e-6)


# -- inverse time (G93) -----------------------------------------------------------------------


def _inverse_time_line(n: int) -> str:
    """``n`` G01 blocks of one 1-ms period each along X, 2.5 µm apart (seed 000's time-indexed reference)."""
    xs = np.arange(1, n + 1) * 0.0025
    return "G21 G90 G94\nG00 X0 Y0\nG93\n" + "".join(f"G01 X{x:.4f} Y0 F60000\n" for x in xs) + "M30\n"


@pytest.mark.parametrize("kernel", [True, False])
def test_inverse_time_blocks_give_one_sample_each_and_no_repeated_last_sample(kernel: bool) -> None:
    from ilcnc.vcnc import plan
    n = 20000  # the durations sum to 20 s plus float noise: one tick more (a repeated last sample) before the fix
    moves = _prog(_inverse_time_line(n)).moves
    lim = PlanLimits(np.full(3, 1e6), np.full(3, 1e6), np.full(3, 1e9), np.full(3, 1e12))
    ref = plan._plan(moves, lim, 0.001, "constant_feed", 0.01, 0.01, 0.0, 12, kernel=kernel)
    assert ref.n_samples == n + 1  # the start, then block k ends at sample k + 1
    np.testing.assert_allclose(ref.pos_mm[1:, 0], moves.end_mm[1:, 0], rtol=0, atol=1e-9)
    assert np.all(np.diff(ref.pos_mm[:, 0]) > 0.0025 - 1e-9)
    assert ref.pos_mm[-1, 0] == moves.end_mm[-1, 0]


def test_zero_length_inverse_time_block_stands_still_for_its_time() -> None:
    text = "G21 G90\nG0 X0 Y0 Z0\nG93\nG1 X10 F60\n{still}G1 X20 F60\nM2\n"
    with_still = _prog(text.format(still="G1 X10 F120\n"))  # 0.5 s at X10
    without = _prog(text.format(still=""))
    lim = _limits()
    ideal = plan_moves(with_still.moves, lim, period_s=0.001, mode="constant_feed", in_position_s=0.0)
    at10 = np.abs(ideal.pos_mm[:, 0] - 10.0) < 1e-9
    assert np.count_nonzero(at10) == 501  # arrives at 1 s, leaves after 1.5 s
    assert ideal.duration_s == pytest.approx(2.5, abs=1e-9)
    assert np.all(ideal.move[at10][1:] == 2)  # the stand-still is the zero-length block's
    for mode in ("seven_phase", "cubic"):
        a = plan_moves(with_still.moves, lim, period_s=0.001, mode=mode)
        b = plan_moves(without.moves, lim, period_s=0.001, mode=mode)
        assert a.duration_s == pytest.approx(b.duration_s + 0.5, abs=0.05)
        assert np.count_nonzero(np.abs(a.pos_mm[:, 0] - 10.0) < 1e-9) >= 400
        _assert_same_reference(a, _numpy_plan(with_still.moves, lim, mode=mode))


def test_profile_path_control_is_the_mode_of_moves_the_program_sets_none_for(tmp_path: Path) -> None:
    """planner.path_control g64 plans a program without path-control codes as if it began with G64 (LinuxCNC's
    start-up mode), g61 as if with G61; tolerance (the default) keeps corner_tolerance_mm."""
    import re

    from ilcnc.profile.load import load_profile, profile_from_dict
    from ilcnc.program import read_program
    from ilcnc.vcnc.plan import plan_program
    from tests.conftest import REPO

    square = (REPO / "samples" / "own" / "square.ngc").read_text()
    bare = re.sub(r"G64 P[0-9.]+( Q0)?", "", square)
    assert "G64" not in bare and "G61" not in bare

    def plan(text: str, control: str, name: str):
        d = load_profile(REPO / "configs" / "linuxcnc-sim.yaml").to_dict()
        d["planner"]["path_control"] = control
        p = tmp_path / f"{name}.ngc"
        p.write_text(text)
        return plan_program(read_program(p), profile_from_dict(d))

    as_g64 = plan(bare, "g64", "a")
    assert np.array_equal(as_g64.pos_mm, plan("G64\n" + bare, "tolerance", "b").pos_mm)
    as_g61 = plan(bare, "g61", "c")
    assert np.array_equal(as_g61.pos_mm, plan("G61\n" + bare, "tolerance", "d").pos_mm)
    default = plan(bare, "tolerance", "e")
    assert default.n_samples > as_g64.n_samples  # blending without a bound saves time
    assert not np.array_equal(as_g61.pos_mm[: default.n_samples], default.pos_mm[: as_g61.n_samples])
    # the profile's default never overrides the program's own codes
    assert np.array_equal(plan(square, "g61", "f").pos_mm, plan(square, "tolerance", "g").pos_mm)

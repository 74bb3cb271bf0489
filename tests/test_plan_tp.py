"""LinuxCNC 2.9's planner (ilcnc/vcnc/plan_tp.py, ``planner.profile: linuxcnc``).

The comparison with LinuxCNC's own commanded motion is in tests/integration/test_planner_vs_linuxcnc.py and
docs/papers.md; here the rules the module implements are checked on small programs whose figures can be
worked out by hand, and on real CAM programs for the invariants (limits, end point, path).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ilcnc.contour.path import PathGeometry
from ilcnc.contour.search import contour_error, guess_hints
from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.vcnc.plan import plan_chunks, plan_program, planned_duration_s
from ilcnc.vcnc.plan_tp import ACC_RATIO_NORMAL, MIN_SEGMENT_CYCLES
from tests.conftest import REPO, SAMPLES

PROFILE = load_profile(REPO / "configs" / "linuxcnc-sim.yaml")  # 100 mm/s, 1000 mm/s² per axis, 1 kHz
A = 1000.0


def _plan(tmp_path: Path, text: str, name: str = "p.ngc"):
    p = tmp_path / name
    p.write_text(text)
    prog = read_program(p)
    return prog, plan_program(prog, PROFILE)


def _speed(pos: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(pos, axis=0), axis=1) / 1e-3


def square(mode: str) -> str:
    return f"G21 G90 G17 {mode}\nG0 X0 Y0 Z0\nG1 X50 Y0 F3000\nX50 Y50\nX0 Y50\nX0 Y0\nM2\n"


def test_g64_p_corner_is_a_blend_arc_at_the_speed_its_radius_allows(tmp_path: Path) -> None:
    prog, ref = _plan(tmp_path, square("G64 P0.01 Q0"))
    # 90° corner, tolerance 0.01 mm: the arc may reach d = cos45°·0.01/(1 − sin45°) = 24.1 µm along each
    # line, radius tan45°·d = 24.1 µm, speed sqrt(0.866·1000·0.0241) = 4.57 mm/s (LinuxCNC: 4.5-4.7 mm/s)
    d = math.cos(math.pi / 4) * 0.01 / (1 - math.sin(math.pi / 4))
    v_arc = math.sqrt(ACC_RATIO_NORMAL * A * d)
    v = _speed(ref.pos_mm)
    corner = int(np.argmax(ref.pos_mm[:, 1] > 1e-9))
    assert v[corner - 5:corner + 5].min() == pytest.approx(v_arc, rel=0.03)
    # full deceleration up to the corner (trapezoid, no jerk limit): 1000 mm/s² within the sampling
    acc = np.diff(v) / 1e-3
    assert acc.min() == pytest.approx(-A, rel=0.02) and acc.max() == pytest.approx(A, rel=0.02)
    # the commanded path stays within the tolerance of the programmed corner
    geo = PathGeometry.from_moves(prog.moves)
    feed = ref.move >= 0
    pts = ref.pos_mm[feed]
    err = contour_error(geo, pts, guess_hints(geo, pts), window=3).dist_mm
    assert float(np.max(err)) <= 0.01 + 1e-6
    assert np.allclose(ref.pos_mm[-1], [0, 0, 0])


def test_plain_g64_blends_within_a_quarter_of_the_move(tmp_path: Path) -> None:
    _prog, ref = _plan(tmp_path, square("G64"))
    # tolerance: a quarter of the 50 mm move = 12.5 mm, and the arc may use half of each move (25 mm), so the
    # feed decides: at 50 mm/s the arc needs R = 50²/866 = 2.89 mm, and a parabolic blend of the same time
    # (50 mm/s at half the acceleration: 0.1 s, 5 mm of path) over the 90° turn sweeps R = 5/(π/2) = 3.18 mm,
    # the larger one; the arc passes the vertex at R·(1/sin 45° − 1) = 1.32 mm
    dist = np.min(np.linalg.norm(ref.pos_mm[:, :2] - [50.0, 0.0], axis=1))
    r = max(50.0**2 / (ACC_RATIO_NORMAL * A), 50.0 / (0.5 * A) * 50.0 / (math.pi / 2))
    assert dist == pytest.approx(r / math.sin(math.pi / 4) - r, rel=0.01)
    assert _speed(ref.pos_mm).max() <= 50.0 + 1e-6


def test_g61_stops_at_every_corner_and_g61_1_at_every_move(tmp_path: Path) -> None:
    _prog, ref = _plan(tmp_path, square("G61"))
    for x, y in ((50, 0), (50, 50), (0, 50)):
        at = np.flatnonzero(np.linalg.norm(ref.pos_mm[:, :2] - [x, y], axis=1) < 1e-9)
        assert at.size >= 1  # the corner itself is a sample: the commanded motion stops there
    collinear = "G21 G90 G17 {}\nG0 X0 Y0\nG1 X10 F3000\nX20\nX30\nM2\n"
    _p, through = _plan(tmp_path, collinear.format("G61"), "a.ngc")
    _p, stops = _plan(tmp_path, collinear.format("G61.1"), "b.ngc")
    # G61 keeps the feed (50 mm/s) through a straight continuation, G61.1 stops at X10 and X20
    for ref, v_at_10 in ((through, 50.0), (stops, 0.0)):
        v = _speed(ref.pos_mm)
        i = int(np.argmin(np.abs(ref.pos_mm[1:, 0] - 10.0)))
        assert v[max(i - 1, 0):i + 1].min() == pytest.approx(v_at_10, abs=1.0)
    assert stops.n_samples > through.n_samples + 50


def test_a_rapid_and_a_feed_move_do_not_blend(tmp_path: Path) -> None:
    _prog, ref = _plan(tmp_path, "G21 G90 G64\nG0 X0 Y0 Z5\nG0 X20 Y0\nG1 Z0 F600\nG1 X40\nM2\n")
    # the feed move starts where the rapid ended: the corner (20, 0, 5) is a sample
    assert np.min(np.linalg.norm(ref.pos_mm - [20.0, 0.0, 5.0], axis=1)) < 1e-9
    # the rapid runs at the rapid limit (100 mm/s), the plunge at F600
    v = _speed(ref.pos_mm)
    assert v.max() == pytest.approx(100.0, rel=1e-6)


def test_short_moves_take_at_least_one_servo_period(tmp_path: Path) -> None:
    # 200 collinear-ish moves of 0.01 mm at F3000: at most 0.01 mm per 1.02 periods = 9.8 mm/s
    pts = "\n".join(f"X{0.01 * (i + 1):.3f} Y{0.00001 * ((i + 1) % 2):.5f}" for i in range(200))
    _prog, ref = _plan(tmp_path, f"G21 G90 G64\nG0 X0 Y0\nG1 F3000\n{pts}\nM2\n")
    assert _speed(ref.pos_mm).max() <= 0.01 / (MIN_SEGMENT_CYCLES * 1e-3) * 1.001


def test_arcs_are_followed_exactly_at_their_normal_acceleration(tmp_path: Path) -> None:
    _prog, ref = _plan(tmp_path, "G21 G90 G17 G64\nG0 X0 Y0\nG1 X10 F6000\nG3 X10 Y4 I0 J2\nG1 X0\nM2\n")
    on_arc = ref.move == 2
    c = np.array([10.0, 2.0])
    r = np.linalg.norm(ref.pos_mm[on_arc, :2] - c, axis=1)
    assert np.allclose(r, 2.0, atol=1e-9)
    v = _speed(ref.pos_mm)[on_arc[1:]]
    assert v.max() <= math.sqrt(ACC_RATIO_NORMAL * A * 2.0) * 1.001
    assert np.allclose(ref.pos_mm[-1], [0, 4, 0])


@pytest.mark.parametrize("name", ["gcode/jsdc.gcode", "contour/compass.ngc", "gcode/tiny_cat_outline.ngc",
                                  "gcode/Cereal.ngc"])
def test_real_programs_keep_the_axis_limits_and_end_where_they_end(name: str) -> None:
    prog = read_program(SAMPLES / name)
    ref = plan_program(prog, PROFILE)
    v = np.diff(ref.pos_mm, axis=0) / 1e-3
    assert np.abs(v).max() <= 100.0 * (1 + 1e-6)
    # per-axis acceleration: LinuxCNC's blends share the limit between the tangent and the normal direction;
    # a period-wide acceleration within 5 % of the limit (the split cycles at segment ends add a little)
    a = np.diff(v, axis=0) / 1e-3
    assert np.abs(a).max() <= A * 1.05
    assert np.allclose(ref.pos_mm[-1], prog.moves.end_mm[-1], atol=1e-9)
    # the chunked plan is the same samples, and the duration the same
    chunks = list(plan_chunks(prog, PROFILE, chunk_samples=8192))
    assert np.array_equal(np.concatenate([c.pos_mm for c in chunks]), ref.pos_mm)
    assert planned_duration_s(prog, PROFILE) == ref.duration_s

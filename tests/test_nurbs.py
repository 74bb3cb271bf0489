"""G5.2/G5.3 NURBS blocks (issue 21): the curve, its chords, and what is refused, as LinuxCNC 2.9 reads them.

The curve is checked against a plain-Python Cox-de Boor evaluation written here (basis functions by their
recursion, not de Boor's algorithm the module uses); the points LinuxCNC's own interpreter puts on the curve are
compared with ilcnc's chords in tests/test_linuxcnc_interp.py (tests/data/nurbs.ngc).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from ilcnc.program import read_program
from ilcnc.program.gcode import SPLINE_CHORD_MM
from ilcnc.program.model import FLAG_DERIVED, FLAG_POSITION_READ
from ilcnc.program.nurbs import clamped_knots, nurbs_points

DATA = Path(__file__).with_name("data")
RS274 = shutil.which("rs274")


def _basis(i: int, k: int, u: float, knots: list[float]) -> float:
    """Cox-de Boor: the B-spline basis function N_{i,k} (order k) at u, with 0/0 = 0; the last knot belongs to
    the last non-empty span (the curve's end)."""
    if k == 1:
        lo, hi = knots[i], knots[i + 1]
        if lo < hi and (lo <= u < hi or (u == knots[-1] and hi == knots[-1])):
            return 1.0
        return 0.0
    out = 0.0
    if knots[i + k - 1] > knots[i]:
        out += (u - knots[i]) / (knots[i + k - 1] - knots[i]) * _basis(i, k - 1, u, knots)
    if knots[i + k] > knots[i + 1]:
        out += (knots[i + k] - u) / (knots[i + k] - knots[i + 1]) * _basis(i + 1, k - 1, u, knots)
    return out


def _curve(ctrl: list[tuple[float, float]], weights: list[float], order: int, u: float) -> tuple[float, float]:
    """The NURBS point sum(N_i w_i P_i) / sum(N_i w_i) with LinuxCNC's knots: order zeros, 1 .. n - k + 1, order
    times n - k + 2 (as its reference says the knots are computed, uniform and clamped)."""
    n = len(ctrl) - 1
    knots = [0.0] * order + [float(j) for j in range(1, n - order + 2)] + [float(n - order + 2)] * order
    nw = [_basis(i, order, u, knots) * weights[i] for i in range(n + 1)]
    s = sum(nw)
    return (sum(a * p[0] for a, p in zip(nw, ctrl, strict=True)) / s,
            sum(a * p[1] for a, p in zip(nw, ctrl, strict=True)) / s)


# the three blocks of tests/data/nurbs.ngc: (G5.3 line, control points in the program frame, weights, order)
BLOCKS = [
    (12, [(10, 10), (10, 20), (30, 20), (30, 0), (10, 0)], [1, 1, 1, 1, 2], 3),
    (21, [(40, 0), (50, 10), (45, 25), (60, 30), (70, 15), (65, 5)], [2, 1, 0.5, 3, 1, 1], 4),
    (31, [(0, 0), (0, 8), (8, 8), (8, 0)], [1, 1, 1.5, 1], 3),
]


def test_knots_are_clamped_and_uniform() -> None:
    assert clamped_knots(5, 3).tolist() == [0, 0, 0, 1, 2, 3, 3, 3]
    assert clamped_knots(4, 4).tolist() == [0, 0, 0, 0, 1, 1, 1, 1]  # one span: a rational Bézier curve
    with pytest.raises(ValueError, match="at least 3 control points"):
        clamped_knots(2, 3)


@pytest.mark.parametrize(("ctrl", "weights", "order"), [(c, w, k) for _, c, w, k in BLOCKS])
def test_points_agree_with_cox_de_boor(ctrl: list, weights: list, order: int) -> None:
    umax = len(ctrl) - order + 1
    u = np.linspace(0.0, umax, 97)
    mine = nurbs_points(np.array(ctrl, float), np.array(weights, float), order, u)
    theirs = np.array([_curve(ctrl, weights, order, float(v)) for v in u])
    # two evaluations of the same rational polynomials in doubles: a few ulps of the 70 mm coordinates
    assert np.abs(mine - theirs).max() <= 1e-12
    assert np.array_equal(mine[[0, -1]], np.array(ctrl, float)[[0, -1]])  # clamped: it starts and ends on them


def _distance_to_polyline(pts: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Each point's distance to the nearest of the segments a[i]-b[i], mm."""
    out = np.empty(len(pts))
    d = b - a
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-30)
    for s in range(0, len(pts), 500):
        p = pts[s:s + 500, None, :]
        t = np.clip(np.einsum("pij,ij->pi", p - a, d) / dd, 0.0, 1.0)
        out[s:s + 500] = np.hypot(*(a + t[..., None] * d - p).transpose(2, 0, 1)).min(axis=1)
    return out


def test_nurbs_blocks_are_followed_through_chords_within_0_1_um() -> None:
    """Every chord the reader makes of a NURBS block ends on the curve and stays within SPLINE_CHORD_MM of it
    (the curve sampled densely with the Cox-de Boor evaluation above); the chords are derived moves on the G5.3
    line (never commands), the G1 before each block is frozen (its end is the first control point), the G1 after
    is a command again."""
    prog = read_program(DATA / "nurbs.ngc")
    assert prog.unsupported is None
    mv = prog.moves
    from ilcnc.program.model import program_frame_mm

    for line, ctrl, weights, order in BLOCKS:
        sel = np.flatnonzero(mv.line == line)
        assert sel.size > 100 and np.all(mv.flags[sel] & FLAG_DERIVED) and np.all(mv.command[sel] < 0)
        before, after = sel[0] - 1, sel[-1] + 1
        assert mv.flags[before] & FLAG_POSITION_READ and mv.command[after] >= 0
        a = program_frame_mm(mv, mv.start_mm[sel], sel)[:, :2]
        b = program_frame_mm(mv, mv.end_mm[sel], sel)[:, :2]
        # the frame change of the third block (turned by 30 degrees, shifted) costs a few ulps of 100 mm
        assert np.abs(a[0] - ctrl[0]).max() <= 1e-12 and np.abs(b[-1] - ctrl[-1]).max() <= 1e-12
        umax = len(ctrl) - order + 1
        u = np.linspace(0.0, umax, 4000 * umax + 1)
        dense = np.array([_curve(ctrl, weights, order, float(v)) for v in u])
        # the curve within 0.1 µm of the chords (plus the frame change's ulps)
        far = _distance_to_polyline(dense, a, b).max()
        assert far <= SPLINE_CHORD_MM + 1e-12, f"G5.3 line {line}: the curve is {far * 1e3:.4f} µm from the chords"
        # every chord end on the curve: its distance to the dense polyline is at most that polyline's own
        # distance from the curve, h**2/8 max|C''| (h = 1/4000, C'' from the samples' second differences, x2)
        h = umax / (len(u) - 1)
        second = np.hypot(*(dense[2:] - 2 * dense[1:-1] + dense[:-2]).T).max() / h**2
        tol = 2 * h * h / 8 * second + 1e-12
        on = _distance_to_polyline(b, dense[:-1], dense[1:]).max()
        assert on <= tol, f"G5.3 line {line}: a chord end is {on * 1e3:.5f} µm off the curve (tolerance {tol * 1e3:.5f})"
        # and not many more chords than needed: a chord's sagitta is h²/8 |C''|, so |C''| bounds the count
        assert sel.size <= np.ceil(umax * np.sqrt(1.5 * second * (1 + 1e-6) / (8 * SPLINE_CHORD_MM))) + umax


def test_a_corrected_program_keeps_its_nurbs_blocks_as_written() -> None:
    """The control points are not commands (one is off the path: moving it bends the curve over several knot
    spans, not at a point), and the G1 ending on a block's first control point is never corrected."""
    from ilcnc.learning.learner import axes_free_to_move, correctable_commands
    from ilcnc.program.rewrite import apply_corrections

    prog = read_program(DATA / "nurbs.ngc")
    assert prog.command_line.tolist() == [5, 6, 13, 22, 27, 32]
    free = axes_free_to_move(prog) & correctable_commands(prog)[:, None]
    lines = prog.command_line.tolist()
    # 6, 13 and 27 end where a G5.2 block starts; 22 ends where the G92 at line 26 takes its offset from; 32 is
    # followed by a G0 that writes no X or Y (axes_free_to_move: the rapid would need a new word)
    assert [ln for ln, f in zip(lines, free.any(axis=1).tolist(), strict=True) if not f] == [6, 13, 22, 27, 32]
    corr = np.zeros((prog.n_commands, 3))
    corr[:, :2] = 0.004  # every free command 4 µm off in X and Y
    corr[~free] = 0.0
    out, _edits = apply_corrections(prog, corr)
    src, new = prog.text.splitlines(), out.splitlines()
    changed = [i + 1 for i, (x, y) in enumerate(zip(src, new, strict=True)) if x != y]
    assert changed and not [ln for ln in changed if 6 <= ln <= 31]
    again = read_program(DATA / "nurbs.ngc", data=out.encode())
    # the curves are read as before, the third too: its work frame (the G92 at line 26) is set from line 22, which
    # stays as written
    for line, *_ in BLOCKS:
        assert np.array_equal(again.moves.end_mm[again.moves.line == line], prog.moves.end_mm[prog.moves.line == line])


def _prog(tmp_path: Path, body: str) -> Path:
    p = tmp_path / "nurbs.ngc"
    p.write_text(f"G21 G90 G17 F100\nG1 X1 Y1\n{body}\nM2\n")
    return p


def _rs274_refusal_line(path: Path, tmp_path: Path) -> int | None:
    """The source line rs274 refuses (None if it runs the program), from an N-prefixed copy."""
    copy = tmp_path / "n.ngc"
    copy.write_text("".join(f"N{i} {s}\n" for i, s in enumerate(path.read_text().splitlines(), 1)))
    proc = subprocess.run([RS274, "-g", str(copy)], capture_output=True, text=True, cwd=tmp_path,
                          env={"HOME": str(tmp_path), "PATH": "/usr/bin:/bin"}, stdin=subprocess.DEVNULL, timeout=60)
    if proc.returncode == 0:
        return None
    last = [r for r in proc.stderr.splitlines() if r.strip()][-1]
    return int(last.strip().split()[0][1:])


# (body after 'G1 X1 Y1' on line 2, the line ilcnc stops at, its message, the line rs274 refuses or None)
REFUSALS = [
    ("G5.3", 3, "G5.3 without G5.2", 3),
    ("F0\nG5.2 X0 Y1 P1\nX1 Y2 P1\nX2 Y0 P1\nG5.3", 4, "zero feed rate", 4),
    ("G5.2 X0 Y1 P1\nX1\nX2 Y0 P1\nG5.3", 4, "both X and Y", 4),
    ("G5.2 X0 L3\nX1 Y2 P1\nX2 Y0 P1\nG5.3", 3, "both X and Y", 3),
    ("G5.2 X0 Y1 P1\nX1 Y2\nX2 Y0 P1\nG5.3", 4, "positive weight P", 4),
    ("G5.2 X0 Y1 P1\nX1 Y2 P0\nX2 Y0 P1\nG5.3", 4, "must be positive", 4),
    ("G5.2 X0 Y1 P1\nX1 Y2 P-1\nX2 Y0 P1\nG5.3", 4, "must be positive", 4),
    ("G5.2 X0 Y1 P1 L4\nX1 Y2 P1\nG5.3", 5, "at least 4 control points", 5),
    ("G5.2 X0 Y1 P1 L2.5\nX1 Y2 P1\nX2 Y0 P1\nG5.3", 3, "must be an integer", 3),
    # a G1 inside: LinuxCNC moves it, drops the control points and refuses the next P word
    ("G5.2 X0 Y1 P1\nG1 X1 Y2\nX2 Y0 P1\nG5.3", 4, "G or M code", 5),
    # LinuxCNC runs these; ilcnc stops with the line rather than guess
    ("G18\nG5.2 X0 Y1 P1\nX1 Y2 P1\nX2 Y0 P1\nG5.3", 4, "XY plane", None),
    ("G91\nG5.2 X0 Y1 P1\nX1 Y2 P1\nX2 Y0 P1\nG5.3", 4, "incremental", None),
    ("G5.2 X0 Y1\nX1 Y2 P1\nX2 Y0 P1\nG5.3", 3, "undefined weight", None),
    ("G5.2 X0 Y1 P1 L2\nX1 Y2 P1\nX2 Y0 P1\nG5.3", 3, "orders below 3", None),
    ("G5.2 X0 Y1 P1\nX1 Y2 P1 Z3\nX2 Y0 P1\nG5.3", 4, "Z words inside", None),
    ("G5.2 X0 Y1 P1\nX1 Y2 P1 L4\nX2 Y0 P1\nG5.3", 4, "L words inside", None),
    ("G5.2 X0 Y1 P1\nX1 Y2 P1\nX2 Y0 P1\nG5.3 X4 Y4", 6, "G5.3 with words", None),
    ("G5.2 X0 Y1 P1\nX1 Y2 P1\nX2 Y0 P1", 6, "program's end", None),  # M2 inside: LinuxCNC drops the curve
]


@pytest.mark.parametrize(("body", "line", "problem", "lcnc_line"), REFUSALS)
def test_what_linuxcnc_refuses_is_refused_with_its_line(tmp_path: Path, body: str, line: int, problem: str,
                                                          lcnc_line: int | None) -> None:
    path = _prog(tmp_path, body)
    prog = read_program(path)
    assert prog.unsupported is not None and prog.unsupported[0] == line and problem in prog.unsupported[1], (
        prog.unsupported)
    assert prog.moves.line.max() <= 2  # nothing of the block was moved
    if RS274 is None:
        print("rs274 is not on PATH: LinuxCNC's refusals not checked")
        return
    assert _rs274_refusal_line(path, tmp_path) == lcnc_line


def test_a_file_ending_inside_a_block_is_refused_at_its_g5_2(tmp_path: Path) -> None:
    p = tmp_path / "open.ngc"
    p.write_text("G21 F100\nG1 X1 Y1\nG5.2 X0 Y1 P1\nX1 Y2 P1\nX2 Y0 P1\n")
    prog = read_program(p)
    assert prog.unsupported == (3, "the G5.2 NURBS block is not closed by G5.3 before the program ends")


def test_no_motion_mode_after_g5_3(tmp_path: Path) -> None:
    """After G5.3 axis words need a motion code again (rs274: 'Cannot use axis values without a g code that uses
    them')."""
    prog = read_program(_prog(tmp_path, "G5.2 X0 Y1 P1\nX1 Y2 P1\nX2 Y0 P1\nG5.3\nX5 Y5"))
    assert prog.unsupported is not None and prog.unsupported[0] == 7 and "motion mode" in prog.unsupported[1]


def test_linuxcnc_samples_the_same_curve(tmp_path: Path) -> None:
    """The knots, the default order and the first weight as LinuxCNC has them: its ``gcode`` module (AXIS's
    preview) emits straight feeds on the G5.3 line ending at the curve's points u = umax i / (15 (n + 1)) while
    they are short of umax (summed step by step: 15 (n + 1) - 1 of them, or one more when the sum rounds below
    umax), then at the last control point; ilcnc's curve at those parameters is the same to
    the last bits (the frame change of the third block, turned by 30 degrees and shifted, costs a few ulps of
    100 mm; the module's inches times 25.4 a few more)."""
    import json

    from ilcnc.program.model import program_frame_mm

    python = Path("/usr/bin/python3")
    probe = subprocess.run([str(python), "-c", "import gcode"], capture_output=True) if python.exists() else None
    if probe is None or probe.returncode != 0:
        pytest.skip(f"{python} cannot import LinuxCNC's gcode module: LinuxCNC's own curve points not compared")
    out = tmp_path / "moves.json"
    subprocess.run([str(python), str(Path(__file__).with_name("lcnc_gcode_dump.py")), str(DATA / "nurbs.ngc"),
                    str(tmp_path / "params.var"), str(out), "G21"], cwd=tmp_path, env={"HOME": str(tmp_path)},
                   capture_output=True, check=True, timeout=120, stdin=subprocess.DEVNULL)
    moves = json.loads(out.read_text())["moves"]
    for line, ctrl, weights, order in BLOCKS:
        theirs = np.array([m[2:4] for m in moves if m[0] == 1 and m[1] == line]) * 25.4  # inches to mm
        count = len(ctrl)
        assert len(theirs) in (15 * count, 15 * count + 1)
        u = (count - order + 1) * np.arange(1, len(theirs)) / (15 * count)
        mine = nurbs_points(np.array(ctrl, float), np.array(weights, float), order, u)
        assert np.abs(mine - theirs[:-1]).max() <= 1e-11, f"G5.3 line {line}"
        assert np.abs(theirs[-1] - ctrl[-1]).max() <= 1e-12
        prog = read_program(DATA / "nurbs.ngc")
        sel = np.flatnonzero(prog.moves.line == line)
        assert np.abs(program_frame_mm(prog.moves, prog.moves.end_mm[sel[-1:]], sel[-1:])[0, :2] - ctrl[-1]).max() <= 1e-12

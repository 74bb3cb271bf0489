"""G-code reader on real CAM output and on constructed cases."""

from __future__ import annotations

import math
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from ilcnc.errors import ProgramError, UnsupportedError
from ilcnc.program import read_program
from ilcnc.program.gcode import read_gcode
from ilcnc.program.model import (
    FLAG_MACHINE,
    FLAG_PARAMETRIC,
    FLAG_REPEATED,
    MOVE_ARC_CCW,
    MOVE_ARC_CW,
    MOVE_LINE,
    MOVE_RAPID,
    SPAN_LAZY,
    STYLE_LITERAL,
    program_frame_mm,
    rotate_xy,
)
from ilcnc.program.rewrite import apply_corrections

from .conftest import OWN, SAMPLES, SHARED_SAMPLES, sample_files, shared_sample_reason

GCODE_SAMPLES = [p for p in sample_files("gcode", "contour", "interp", "large")]


def _read(text: str, name: str = "t.ngc"):
    return read_gcode(Path(name), text.encode("latin-1"))


@pytest.mark.parametrize("path", GCODE_SAMPLES, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_sample_reads_and_spans_hold_the_numbers(path: Path) -> None:
    prog = read_program(path)
    assert prog.text.encode("latin-1") == path.read_bytes()
    prog.resolve_spans()
    mv = prog.moves
    assert not np.any(mv.word_start == -2) and not np.any(mv.insert_at == -2)
    # every command with a coordinate word has its span
    idx_all = prog.command_moves
    assert np.all(np.any(mv.word_start[idx_all] >= 0, axis=1))
    idx = prog.command_moves
    # every command's coordinate spans hold exactly the number that gives its end point, in the program frame
    # (a rotated work system, G10 L2 R, turns the words: rotate_xy undoes the turn)
    end_p = program_frame_mm(mv, mv.end_mm)
    step_p = rotate_xy(mv.end_mm - mv.start_mm, -mv.rotation_deg)
    centre_p = rotate_xy(mv.center_mm - mv.start_mm, -mv.rotation_deg)
    for a in range(3):
        ws, we = mv.word_start[idx, a], mv.word_end[idx, a]
        has = ws >= 0
        for i, s, e in zip(idx[has][:2000], ws[has][:2000], we[has][:2000], strict=True):
            if not mv.word_style[i, a] & STYLE_LITERAL:
                # a parameter or an expression (corrected as [expression+c]): the move says so
                # (or a function call, sqrt[2])
                assert mv.flags[i] & FLAG_PARAMETRIC and (prog.text[s:e][:1] in "#[-+" or prog.text[s:e][:1].isalpha())
                continue
            val = float(prog.text[s:e].replace(" ", ""))
            unit = mv.unit_mm[i]
            if mv.word_incremental[i, a]:
                assert val * unit == pytest.approx(step_p[i, a], abs=1e-9)
            else:
                assert val * unit == pytest.approx(end_p[i, a], abs=1e-9)
    # arc centre words (I/J/K relative to the start) hold the centre
    arcs = np.flatnonzero((mv.kind >= MOVE_ARC_CW) & np.any(mv.center_start >= 0, axis=1))
    for i in arcs[:2000]:
        for a in range(3):
            s, e = mv.center_start[i, a], mv.center_end[i, a]
            if s < 0 or not mv.center_incremental[i, a] or not mv.center_style[i, a] & STYLE_LITERAL:
                continue
            val = float(prog.text[s:e].replace(" ", ""))
            assert val * mv.unit_mm[i] == pytest.approx(centre_p[i, a], abs=1e-9)
    # consecutive moves chain
    if len(mv) > 1:
        assert np.allclose(mv.start_mm[1:], mv.end_mm[:-1])


def test_cam_sample_counts() -> None:
    prog = read_program(SAMPLES / "contour" / "locket_outside.ngc")
    text = prog.text.splitlines()
    # independent count: lines with a G1 (or modal continuation) holding X/Y/Z
    assert prog.n_commands == 10206
    assert prog.units == "mm"
    assert all(text[line - 1].strip() for line in prog.command_line[:100])


def test_inch_program_is_converted_to_mm() -> None:
    prog = read_program(SAMPLES / "gcode" / "circle-inch.gcode")
    assert prog.units == "inch"
    assert np.all(prog.moves.unit_mm == 25.4)


def test_modal_bare_lines_and_feed_only_blocks() -> None:
    prog = _read("G21 G90\nG0 X0 Y0\nG01 F100\nX10\nY5 F200\nG1 F300\nZ-1\nM2\n")
    assert prog.n_commands == 3
    assert prog.command_line.tolist() == [4, 5, 7]
    assert prog.command_feed_mm_min.tolist() == [100.0, 200.0, 300.0]
    assert prog.command_end_mm.tolist() == [[10, 0, 0], [10, 5, 0], [10, 5, -1]]


def test_comments_block_delete_percent_and_words_with_spaces() -> None:
    prog = _read("%\n(header) ; both\nN10 G21 G90 ;x\n/G0 X1 Y1\nG00 Z 5.0000\nG1 X 2 F 100.0000(Penetrate)\nN20X3Y+4\n%\n")
    assert prog.command_end_mm.tolist() == [[2, 1, 5], [3, 4, 5]]


def test_incremental_and_arc_centres() -> None:
    prog = _read("G21 G90 G17\nG0 X0 Y0\nG91 G1 X10 F100\nY10\nG90 G2 X20 Y0 I0 J-10\nG3 X0 Y0 R10\nM2\n")
    mv = prog.moves
    assert mv.kind.tolist() == [MOVE_RAPID, MOVE_LINE, MOVE_LINE, MOVE_ARC_CW, MOVE_ARC_CCW]
    assert mv.end_mm[2].tolist() == [10, 10, 0]
    assert mv.center_mm[3, :2].tolist() == [10, 0]
    assert mv.center_mm[4, :2].tolist() == pytest.approx([10, 0])
    assert mv.word_incremental[1].tolist() == [True, False, False]


def test_g18_arc_r_and_helix() -> None:
    prog = _read("G21 G18\nG0 X0 Y0 Z0\nG2 X10 Z0 R5 Y3 F100\nM2\n")
    c = prog.moves.center_mm[1]
    assert c[0] == pytest.approx(5.0) and c[2] == pytest.approx(0.0)


def test_offsets_g92_g53_g54() -> None:
    prog = _read("G21 G90\nG0 X7.6\nG92 X0\nG1 X5 F100\nG53 G1 X5\nG10 L2 P2 X100\nG55 G1 X1\nM2\n")
    mv = prog.moves
    assert mv.end_mm[1, 0] == pytest.approx(12.6)
    assert (mv.end_mm[1] - mv.offset_mm[1])[0] == pytest.approx(5.0)
    assert mv.flags[2] & FLAG_MACHINE
    assert mv.end_mm[2, 0] == pytest.approx(5.0)
    assert mv.command[2] == -1  # G53 moves are never corrected
    assert mv.end_mm[3, 0] == pytest.approx(101.0 + 7.6)


def test_parameters_and_expressions() -> None:
    prog = _read("G21\n#1=2\n#<d>=[#1*3]\nG1 X[#<d>+1] Y#1 F[60*2]\nG1 X[sin[30]*2] Y[atan[1]/[1]]\nM2\n")
    mv = prog.moves
    assert mv.end_mm[0, :2].tolist() == pytest.approx([7.0, 2.0])
    assert mv.end_mm[1, :2].tolist() == pytest.approx([1.0, 45.0])
    # parameter-valued words run once: commands, corrected as [expression+c] (issue 21 item 2)
    assert mv.command[:2].tolist() == [0, 1] and np.all(mv.flags[:2] & FLAG_PARAMETRIC)


@pytest.mark.parametrize(
    ("text", "line", "needle"),
    [
        ("G21\nG1 X1 E5 F100\n", 2, "E word with no G70, G76, M66, M67 or M68"),  # as rs274 says
        ("G21\nG1 X1 F100\nG1 X(2\n", 3, "X word without a number"),
        ("G21\nG1 X1 F100 (open\n", 2, "not closed"),
        ("G21\nG1 X F100\n", 2, ""),
        ("G21\nG1 X1 X2 F100\n", 2, "twice"),
        ("G21\nG1 X[1+ F100\n", 2, ""),
        ("G21\nG12345 X1\n", 2, "unknown G code"),
    ],
)
def test_syntax_errors_name_the_line(text: str, line: int, needle: str) -> None:
    with pytest.raises(ProgramError) as info:
        _read(text)
    assert info.value.line == line
    assert needle in str(info.value)
    assert "\n" not in str(info.value)


def test_unsupported_constructs_are_reported_never_misread() -> None:
    prog = read_program(SAMPLES / "gcode" / "mmount.ngc")
    with pytest.raises(UnsupportedError) as info:
        prog.require_complete()
    assert info.value.line == 314
    assert "G33.1 rigid tapping is not modelled" in str(info.value)
    assert len(prog.moves) == 562  # subroutines, loops and drilling cycles before line 314 were run


def test_subroutines_and_loops_run_and_repeated_lines_are_never_corrected() -> None:
    text = (
        "G21 G90\nG0 X0 Y0\nF100\n"
        "o10 sub\n  G1 X[#1] Y[#2]\n  G1 X[#1+1]\no10 endsub\n"
        "#<n> = 0\n"
        "o20 while [#<n> LT 3]\n  o10 call [#<n>] [2]\n  #<n> = [#<n> + 1]\no20 endwhile\n"
        "o30 if [#<n> EQ 3]\n  G1 X9 Y9\no30 else\n  G1 X-9 Y-9\no30 endif\n"
        "o40 repeat [2]\n  G91 G1 X1\n  G90\no40 endrepeat\n"
        "M2\n"
    )
    prog = _read(text)
    prog.require_complete()
    mv = prog.moves
    assert len(mv) == 1 + 6 + 1 + 2
    assert mv.end_mm[1:7, 0].tolist() == [0, 1, 1, 2, 2, 3]
    assert mv.end_mm[7, :2].tolist() == [9, 9]
    assert mv.end_mm[9, 0] == 11
    assert prog.n_commands == 1  # only "G1 X9 Y9" ran exactly once
    assert prog.command_line.tolist() == [14]
    assert np.all(mv.flags[1:7] & FLAG_REPEATED)


def test_refused_blocks_match_linuxcnc_messages() -> None:
    # LinuxCNC refuses both of these programs too (checked with rs274)
    p = read_program(SAMPLES / "contour" / "SheepTile-v2.nc")
    assert p.unsupported is not None and p.unsupported[0] == 14 and "zero feed" in p.unsupported[1]
    p = read_program(SAMPLES / "gcode" / "Circle_Diamond_Square_Calibration.gcode")
    assert p.unsupported is not None and p.unsupported[0] == 624


def test_binary_and_empty_files() -> None:
    with pytest.raises(ProgramError, match="binary"):
        read_gcode(Path("b.nc"), bytes(range(256)) * 10)
    with pytest.raises(ProgramError, match="empty"):
        read_gcode(Path("e.nc"), b"  \n\n")


def test_own_samples_read() -> None:
    for p in sorted(OWN.glob("*.n*")):
        prog = read_program(p)
        prog.require_complete()
        assert prog.n_commands > 0


@pytest.mark.parametrize("path", [*GCODE_SAMPLES, *sorted(OWN.glob("*.n*"))], ids=lambda p: f"{p.parent.name}/{p.name}")
def test_compiled_scanner_classifies_exactly_like_the_regular_expression(path: Path) -> None:
    from ilcnc.program import gcode, scan
    from ilcnc.program.model import decode_source

    if not scan.AVAILABLE:
        pytest.fail("numba (a runtime dependency) is not installed")
    data = path.read_bytes()
    text = decode_source(data)
    starts = np.concatenate(([0], np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == 10) + 1))
    a, slow_a = gcode._classify(text, data, starts.shape[0], starts, path, force="regex")
    b, slow_b = gcode._classify(text, data, starts.shape[0], starts, path, force="scanner")
    assert np.array_equal(slow_a, slow_b)
    assert np.array_equal(a, b, equal_nan=True)


def test_compiled_scanner_on_edge_cases() -> None:
    from ilcnc.program import gcode

    text = ("G1 X1.5 F100\nN10 G00 x-.5 y+2. Z3\nG10 X1\nG1.0 X1\nX1 X2\nG2 X1 Y2 I0.5 J-0.25\nF 200\n"
            "X 1 Y2\nX- 1\n\nX12345678901234567\nX0.000000000000000000000001\n  \t\r\nG01F-1\n")
    data = text.encode()
    starts = np.concatenate(([0], np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == 10) + 1))
    a, slow_a = gcode._classify(text, data, starts.shape[0], starts, Path("t.ngc"), force="regex")
    b, slow_b = gcode._classify(text, data, starts.shape[0], starts, Path("t.ngc"), force="scanner")
    assert slow_a.tolist() == [False, False, True, True, True, False, False, False, True, False, False, False, False,
                               True, False]
    # the scanner leaves numbers with more than 15 significant digits or 22 decimals to the general lexer
    agree = ~(slow_a ^ slow_b)
    assert not agree[10] and slow_b[10] and not agree[11] and slow_b[11]
    keep = np.ones(len(slow_a), bool)
    keep[[10, 11]] = False
    assert np.array_equal(slow_a[keep], slow_b[keep])
    assert np.array_equal(a[keep & ~slow_b], b[keep & ~slow_b], equal_nan=True)


# -- path control (G61, G61.1, G64) and inverse time (G93) ------------------------------------------


def test_path_control_modes_set_the_blend_tolerance_of_the_following_moves() -> None:
    prog = _read("G21 G90\nG0 X0 Y0\nG1 X1 F100\nG61\nX2\nG61.1 X3\nG64\nX4\nG64 P0.05 Q0.01\nX5\nG64 P0 X6\n"
                 "G64 P-1\nX7\nG20 G64 P0.002\nX0.5\nG64 P0.001 G21\nX9\nM2\n")
    tol = prog.moves.blend_tol_mm
    assert np.isnan(tol[:2]).all()  # no program setting: the profile's tolerance applies
    assert tol[2:].tolist() == [0.0, -1.0, np.inf, 0.05, np.inf, np.inf, 0.002 * 25.4, 0.001]
    assert prog.n_commands == 9  # Q (LinuxCNC's naive-CAM merging) is read and ignored: nothing is merged


def test_path_control_refused_with_cutter_compensation_as_linuxcnc_does() -> None:
    prog = _read("G21 G90\nG0 X0 Y0\nG41 D1 G1 X1 F100\nG64 P0.01\nX2\nM2\n")
    assert prog.unsupported is not None and prog.unsupported[0] == 4
    assert "cutter radius compensation" in prog.unsupported[1]
    assert _read("G21 G90\nG0 X0 Y0\nG41 D1 G1 X1 F100\nG40 G64 P0.01\nX2\nM2\n").unsupported is None
    assert "path control" in _read("G21\nG61 G64\nM2\n").unsupported[1]


def test_inverse_time_blocks_carry_their_programmed_time() -> None:
    prog = _read("G21 G90\nG0 X0 Y0\nG1 X1 F100\nG93 G1 X2 F30\nG1 X2 F120\nG2 X3 Y1 I0.5 J0.5 F60\nG0 X0\n"
                 "G94 G1 X1 F100\nM2\n")
    bt = prog.moves.block_time_s
    assert np.isnan(bt[[0, 1, 5, 6]]).all()  # rapids and G94 feed moves
    assert bt[2:5].tolist() == [2.0, 0.5, 1.0]  # 60 / F s, the zero-length block too
    assert prog.moves.feed_mm_min[3] == 0.0


def _read_general_only(text: str, monkeypatch: pytest.MonkeyPatch):
    """Read with every line through the general lexer and interpreter (no vectorised plain-block runs)."""
    from ilcnc.program import gcode

    def all_slow(text, data, n, line_start, path, *, force=None):
        return np.full((n, 9), np.nan), np.ones(n, dtype=bool)

    with monkeypatch.context() as mp:
        mp.setattr(gcode, "_classify", all_slow)
        return _read(text)


def test_fast_path_equals_general_path_with_path_control_and_inverse_time(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(9)
    modes = ["G61", "G61.1", "G64", "G64 P0.02 Q0.01", "G20 G64 P0.001", "G21", "G93", "G94"]
    lines = ["G21 G90", "G0 X0 Y0 Z1", "G1 Z0 F500"]
    inverse = False
    for k in range(300):
        if k % 17 == 0:
            mode = modes[(k // 17) % len(modes)]
            inverse = {"G93": True, "G94": False}.get(mode, inverse)
            lines.append(mode)
        x, y = rng.uniform(-20, 20, 2)
        feed = inverse or k % 5 == 0 or k % 17 == 1  # G93 needs F in every feed block
        lines.append(f"G1 X{x:.3f} Y{y:.3f}" + (f" F{rng.uniform(50, 900):.1f}" if feed else ""))
    lines.append("M2")
    text = "\n".join(lines) + "\n"
    fast = _read(text)
    slow = _read_general_only(text, monkeypatch)
    assert fast.unsupported is None and slow.unsupported is None
    a, b = fast.moves, slow.moves
    assert len(a) == len(b) > 290
    assert np.count_nonzero(a.insert_at == SPAN_LAZY) > 100 and not np.any(b.insert_at == SPAN_LAZY)  # both paths ran
    assert np.isfinite(a.block_time_s).any() and (a.blend_tol_mm == 0.0254).any() and np.isinf(a.blend_tol_mm).any()
    for name in ("kind", "line", "command", "flags", "plane", "unit_mm", "start_mm", "end_mm", "feed_mm_min",
                 "blend_tol_mm", "block_time_s"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_axis_words_in_any_order_are_plain_blocks(monkeypatch: pytest.MonkeyPatch) -> None:
    """A rewrite inserts a missing axis word after a block's others (``X1 Z2`` -> ``X1 Z2 Y3``, stellabee1: 1,233
    such blocks after one learning iteration); the reader reads those on its fast path too, with the numbers the
    general lexer reads. A repeated axis word, or one after I/J/K/R/F, is left to the lexer (an error there)."""
    from ilcnc.program import gcode

    text = ("G20 G90\nG0 X0 Y0 Z0.1\nG1 Z-0.1 F20\nX1 Z-0.2 Y0.5\n Y0.25 Z-0.3 X2\ny1x3\nG3 Z-0.3 X2 Y0.25 R1\n"
            "G1 Y.5X2.5Z-.25\nX3 Y1 X4\nX3 I1 Y1\nZ1 Z2\nM2\n")
    data = text.encode()
    starts = np.concatenate(([0], np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == 10) + 1))
    a, slow_a = gcode._classify(text, data, starts.shape[0], starts, Path("t.ngc"), force="regex")
    b, slow_b = gcode._classify(text, data, starts.shape[0], starts, Path("t.ngc"), force="scanner")
    assert slow_a.tolist() == [True, False, False, False, False, False, False, False, True, True, True, True, False]
    assert np.array_equal(slow_a, slow_b)
    assert np.array_equal(a, b, equal_nan=True)
    assert a[3, 1:4].tolist() == [1.0, 0.5, -0.2] and a[5, 1:3].tolist() == [3.0, 1.0]
    plain = "\n".join(text.splitlines()[:8]) + "\nM2\n"
    fast = _read(plain)
    slow = _read_general_only(plain, monkeypatch)
    assert np.count_nonzero(fast.moves.insert_at == SPAN_LAZY) == 7  # the fast path read all seven moves
    fast.resolve_spans()
    for name in ("kind", "line", "command", "start_mm", "end_mm", "center_mm", "feed_mm_min", "word_start", "word_end",
                 "insert_at"):
        np.testing.assert_array_equal(getattr(fast.moves, name), getattr(slow.moves, name), err_msg=name)


def test_a_block_number_before_the_closing_percent(tmp_path):
    """Issue 21: Mach3 posts end with `N890 %`; it was refused ("'%' must stand alone on its line"). A block
    number alone may precede the closing percent; the motion is LinuxCNC's (rs274, where installed)."""
    import re as _re
    import shutil
    import subprocess

    src = tmp_path / "mach3.nc"
    src.write_text("%\nN10 G21 G90\nN20 G0 X0 Y0 Z5\nN30 G1 Z-1 F100\nN40 X10\nN50 Y4\nN60 M30\nN70 %\n")
    p = read_program(src)
    assert p.unsupported is None and p.n_commands == 3
    assert p.command_end_mm.tolist() == [[0.0, 0.0, -1.0], [10.0, 0.0, -1.0], [10.0, 4.0, -1.0]]
    # anything else before the percent is still refused
    bad = tmp_path / "bad.nc"
    bad.write_text("%\nG21 G90\nG1 X1 F100\nG1 X2 %\n")
    with pytest.raises(ProgramError, match="'%' must stand alone"):
        read_program(bad)
    if shutil.which("rs274"):
        out = subprocess.run(["rs274", "-g", str(src)], capture_output=True, text=True, timeout=60).stdout
        feeds = [[float(v) for v in m.group(1).split(",")[:3]] for m in _re.finditer(r"STRAIGHT_FEED\(([^)]*)\)", out)]
        assert feeds == p.command_end_mm.tolist()


def test_g92_3_restores_the_saved_offsets(tmp_path):
    """Issue 21: G92.3 was refused. G92 and G52 keep their offsets in #5211..#5213 (#5210 = 1), G92.1 clears both,
    G92.2 clears the offsets only, G92.3 restores them from the parameters; compared with rs274 where installed."""
    import re as _re
    import shutil
    import subprocess

    src = tmp_path / "g923.ngc"
    src.write_text("G21 G90\nG0 X10 Y10 Z5\nG92 X0 Y0\nG1 Z-1 F100\nG1 X5\nG92.2\nG1 X20\nG92.3\nG1 X7 Y3\nG92.1\nG1 X1\n"
                   "G92.3\nG1 X2\nG52 X1\nG92.2\nG92.3\nG1 X3\nM2\n")
    p = read_program(src)
    assert p.unsupported is None
    prog_xy = (p.command_end_mm - p.moves.offset_mm[p.command_moves])[:, :2]
    assert prog_xy.tolist() == [[0, 0], [5, 0], [20, 10], [7, 3], [1, 13], [2, 13], [3, 13]]
    assert p.moves.end_mm[-1].tolist() == [4.0, 13.0, -1.0]  # G52 X1 restored by G92.3: 3 + 1
    if shutil.which("rs274"):
        out = subprocess.run(["rs274", "-g", str(src)], capture_output=True, text=True, timeout=60).stdout
        feeds = [[float(v) for v in m.group(1).split(",")[:2]] for m in _re.finditer(r"STRAIGHT_FEED\(([^)]*)\)", out)]
        assert feeds == prog_xy.tolist()


def test_e_words_of_analog_io_are_read(tmp_path):
    """Issue 21: `M68 E2 Q[#2]` (LinuxCNC's m6demo.ngc) was refused as "unknown word 'E'". E is the analog channel
    of M66/M67/M68; elsewhere it is refused as rs274 refuses it."""
    src = tmp_path / "e.ngc"
    src.write_text("G21\n#2=5\nM68 E2 Q[#2]\nG1 X1 F100\nM66 E0 L0\nG1 Y1\nM2\n")
    p = read_program(src)
    assert p.unsupported is None and p.command_end_mm.tolist() == [[1, 0, 0], [1, 1, 0]]
    with pytest.raises(ProgramError, match="E word with no"):
        _read("G21\nG1 X1 E5 F100\nM2\n")


# -- Fanuc subprograms (M98 / M99), issue 21 ------------------------------------

M98_PROGRAM = """G21 G90 G17
G0 X0 Y0 Z1
G1 Z-1 F300
M98 P100 L3
G1 X50 Y0 F600
M98 P200
G0 Z5
M30

O100 (step right)
G91 G1 X10 F600
G90
M99

O200 (two sides)
G1 Y10
G1 X40
M99
"""


def _m98(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "m98.ngc"
    p.write_text(text)
    return p


def test_fanuc_subprograms_run_as_linuxcnc_runs_them(tmp_path: Path) -> None:
    """O100 runs three times (its incremental line is not a command: one line, three positions), O200 once
    (its lines are commands like the main program's). The end points are those rs274 prints for this program
    (LinuxCNC 2.9; checked in the next test where it is installed)."""
    prog = read_program(_m98(tmp_path, M98_PROGRAM))
    assert prog.unsupported is None
    mv = prog.moves
    assert mv.line.tolist() == [2, 3, 11, 11, 11, 5, 16, 17, 7]
    assert mv.end_mm[:, 0].tolist() == [0, 0, 10, 20, 30, 50, 50, 40, 40]
    assert mv.end_mm[:, 1].tolist() == [0, 0, 0, 0, 0, 0, 10, 10, 10]
    assert prog.command_line.tolist() == [3, 5, 16, 17]


@pytest.mark.linuxcnc
@pytest.mark.skipif(shutil.which("rs274") is None, reason="LinuxCNC's interpreter rs274 is not installed (Debian:"
                    " apt-get install linuxcnc-uspace): cannot compare M98/M99 with LinuxCNC")
def test_fanuc_subprograms_agree_with_rs274(tmp_path: Path) -> None:
    path = _m98(tmp_path, M98_PROGRAM)
    res = subprocess.run(["rs274", "-g", str(path)], capture_output=True, text=True, timeout=60)
    theirs = [[float(v) for v in m.split(",")[:3]]
              for m in re.findall(r"STRAIGHT_(?:FEED|TRAVERSE)\(([^)]*)\)", res.stdout)]
    assert np.array_equal(read_program(path).moves.end_mm, np.array(theirs))  # rs274 prints 4 decimals: exact here


def test_fanuc_program_number_heads_a_program(tmp_path: Path) -> None:
    """As rs274 runs it: an O number met in the flow does nothing (O1000 heads the program)."""
    text = "O1000 (PART)\nG21 G90\nG0 X0 Y0 Z1\nM98 P7\nG1 X5 F100\nM30\nO7\nG1 Y3 F100\nM99\n"
    prog = read_program(_m98(tmp_path, text))
    assert prog.unsupported is None
    assert prog.moves.line.tolist() == [3, 8, 5] and prog.command_line.tolist() == [8, 5]


def test_fanuc_subprogram_without_motion_shared_sample() -> None:
    """LinuxCNC's own nested M98 example (parameters shared with the caller, L repeats): read, no motion."""
    src = SHARED_SAMPLES / "interp" / "lcnc_m98m99-nested-subs.ngc"
    if not src.exists():
        pytest.skip(shared_sample_reason("interp", src.name))
    prog = read_program(src)
    assert prog.unsupported is None and len(prog.moves) == 0


@pytest.mark.parametrize(("text", "line", "problem"), [
    ("G21\nG1 X1 F100\nM99\n", 3, "M99 in the main program"),
    ("G21\nM98 P7\nM30\n", 2, "subprogram O7 is not in this file"),
    ("G21\nM98 P7 G1 X1 F100\nM30\nO7\nM99\n", 2, "M98 with other words on its line"),
    # rs274: "EOF in file seeking o-word: o<7> from line: 4"
    ("G21\nO7\nG1 Y3 F100\nM98 P7\nG1 X5\nM30\n", 4, "O7 stands before the call"),
])
def test_fanuc_subprograms_the_reader_does_not_model_are_named(tmp_path: Path, text: str, line: int,
                                                               problem: str) -> None:
    prog = read_program(_m98(tmp_path, text))
    assert prog.unsupported is not None and prog.unsupported[0] == line and problem in prog.unsupported[1]


@pytest.mark.parametrize(("text", "line", "problem"), [
    ("G21\nM30\nO7\nM99\nO7\nM99\n", 5, "O7 is defined twice"),
    ("G21\nM98\nM30\nO7\nM99\n", 2, "M98 needs P"),
    # rs274: "File ended with no percent sign or program end"
    ("O1000\nG21 G90\nG0 X0 Y0 Z1\nM98 P7\nG1 X5 F100\nM30\nO7\nG1 Y3 F100\n", 7, "ends inside subprogram O7"),
])
def test_bad_fanuc_subprograms_are_refused_with_their_line(tmp_path: Path, text: str, line: int, problem: str) -> None:
    with pytest.raises(ProgramError, match=problem) as exc:
        read_program(_m98(tmp_path, text))
    assert exc.value.line == line


# -- G5.1 quadratic splines, issue 21 ---------------------------------------------

SPLINE_PROGRAM = """G21 G90 G17
G0 X0 Y0 Z-1
G1 X2 Y0 F600
G5.1 X12 Y0 I5 J5
G1 X20 Y3
G91 G5.1 X10 Y0 I5 J-5
G90 G1 X30 Y10
M30
"""


def test_quadratic_spline_is_followed_through_chords_on_the_curve(tmp_path: Path) -> None:
    """G5.1 X Y I J: the Bézier curve from the start through the control point start + (I, J) to (X, Y); the
    reader generates chords whose vertices lie on the curve and whose middles are within SPLINE_CHORD_MM of it
    (|B''| dt² / 8 with B'' = 2 (p0 - 2 p1 + p2)); they are not commands, the moves around them are."""
    from ilcnc.program.gcode import SPLINE_CHORD_MM
    from ilcnc.program.model import FLAG_DERIVED

    prog = read_program(_m98(tmp_path, SPLINE_PROGRAM))
    assert prog.unsupported is None
    mv = prog.moves
    assert prog.command_line.tolist() == [3, 5, 7]
    for line, p0, ctrl, p2 in ((4, (2, 0), (7, 5), (12, 0)), (6, (20, 3), (25, -2), (30, 3))):
        sel = np.flatnonzero(mv.line == line)
        assert np.all(mv.flags[sel] & FLAG_DERIVED) and np.all(mv.command[sel] < 0) and np.all(mv.end_mm[sel, 2] == -1)
        p0, ctrl, p2 = (np.array(v, float) for v in (p0, ctrl, p2))
        assert np.array_equal(mv.end_mm[sel[-1], :2], p2) and np.array_equal(mv.start_mm[sel[0], :2], p0)
        n = sel.size
        assert n == int(np.ceil(np.sqrt(np.hypot(*(p0 - 2 * ctrl + p2)) / (4 * SPLINE_CHORD_MM))))
        t = np.arange(1, n + 1) / n
        curve = (1 - t)[:, None] ** 2 * p0 + (2 * t * (1 - t))[:, None] * ctrl + (t * t)[:, None] * p2
        assert np.abs(mv.end_mm[sel, :2] - curve).max() <= 1e-12 * 30  # the same arithmetic, a few ulps of 30 mm
        tm = (np.arange(n) + 0.5) / n
        mid = (1 - tm)[:, None] ** 2 * p0 + (2 * tm * (1 - tm))[:, None] * ctrl + (tm * tm)[:, None] * p2
        chord_mid = 0.5 * (mv.start_mm[sel, :2] + mv.end_mm[sel, :2])
        assert np.hypot(*(chord_mid - mid).T).max() <= SPLINE_CHORD_MM * (1 + 1e-9)


def test_a_corrected_program_keeps_its_splines_as_written(tmp_path: Path) -> None:
    from ilcnc.learning.learner import axes_free_to_move
    from ilcnc.program.rewrite import apply_corrections

    src = _m98(tmp_path, SPLINE_PROGRAM)
    prog = read_program(src)
    free = axes_free_to_move(prog)
    # the end point before a spline is its start (and with it the control point): the learning leaves it alone
    assert free.tolist() == [[False, False, False], [False, False, False], [True, True, True]]
    corr = np.zeros((prog.n_commands, 3))
    corr[:, :2] = 0.004  # every free command 4 µm off in X and Y
    corr[~free] = 0.0
    out, _edits = apply_corrections(prog, corr)
    lines_in, lines_out = SPLINE_PROGRAM.splitlines(), out.splitlines()
    assert [i + 1 for i, (a, b) in enumerate(zip(lines_in, lines_out, strict=True)) if a != b] == [7]
    again = read_program(_m98(tmp_path, out))
    assert np.allclose(again.command_end_mm, prog.command_end_mm + corr, atol=1e-9)


@pytest.mark.parametrize(("body", "problem"), [
    ("G5.1 X10 Y0 I5 F600", "must specify both I and J"),
    ("G5.1 X10 Y0 Z1 I5 J5 F600", "XY plane only"),
    ("G18\nG5.1 X10 Z0 I5 K5 F600", "only allowed in the XY plane"),
    ("G5.1 X10 Y0 I5 J5 F600\nX20 Y0", "without I and J"),
    ("G41 D1 G5.1 X10 Y0 I5 J5 F600", "cutter radius compensation"),
])
def test_quadratic_splines_linuxcnc_refuses_are_refused(tmp_path: Path, body: str, problem: str) -> None:
    """Each refused by rs274 too (the last but one: rs274 makes no move, refused here rather than guessed)."""
    prog = read_program(_m98(tmp_path, f"G21 G90 G17\nG0 X0 Y0 Z0\n{body}\nG1 X0 Y0\nM30\n"))
    assert prog.unsupported is not None and problem in prog.unsupported[1]


def test_rotated_work_system_moves_and_refusals() -> None:
    """G10 L2 R turns the work system's XY about its origin (LinuxCNC: machine = R (program + G92) + G5x; the
    comparison with rs274 on tests/data/rotated_frames.ngc is in test_linuxcnc_interp). The reader records the
    rotation per move, and refuses, naming the line, what it cannot follow."""
    prog = _read("G21 G90\nG10 L2 P1 X10 Y0 R90\nG54 G1 X5 Y0 F100\nG91 X0 Y2\nG2 X-2 Y-2 I0 J-2\nM2\n")
    assert prog.unsupported is None
    mv = prog.moves
    # (5, 0) turned by 90 degrees is (0, 5), plus the work offset (10, 0); G91 Y2 goes -X on the machine
    assert mv.end_mm[0] == pytest.approx([10.0, 5.0, 0.0], abs=1e-12)
    assert mv.end_mm[1] == pytest.approx([8.0, 5.0, 0.0], abs=1e-12)
    # the arc keeps its direction; its centre (program start + I J = (5, 0)) is turned too
    assert mv.kind[2] == MOVE_ARC_CW
    assert mv.center_mm[2, :2] == pytest.approx([10.0, 5.0], abs=1e-12)
    assert mv.end_mm[2] == pytest.approx([10.0, 3.0, 0.0], abs=1e-12)
    assert mv.rotation_deg.tolist() == [90.0, 90.0, 90.0]
    assert program_frame_mm(mv, mv.end_mm)[2] == pytest.approx([3.0, 0.0, 0.0], abs=1e-12)
    # LinuxCNC refuses R with L20 ("R not allowed in G10 L20")
    bad = _read("G21\nG10 L20 P1 X0 R10\nG1 X1 F100\nM2\n")
    assert bad.unsupported == (2, "R not allowed in G10 L20")
    # LinuxCNC tilts an XZ arc's plane with the rotation: the move table cannot hold it
    xz = _read("G21 G18\nG10 L2 P1 R30\nG1 X1 F100\nG2 X3 Z0 I1 K0\nM2\n")
    assert xz.unsupported is not None and xz.unsupported[0] == 4 and "G18" in xz.unsupported[1]
    # a new rotation of the active system under a G92 offset: LinuxCNC's interpreter loses its position
    g92 = _read("G21\nG1 X1 F100\nG92 X0\nG10 L2 P1 R30\nG1 X1\nM2\n")
    assert g92.unsupported is not None and g92.unsupported[0] == 4 and "G92" in g92.unsupported[1]


@pytest.mark.parametrize("path", [SAMPLES / "interp" / "lcnc_g10-l2-while-active.ngc",
                                  Path(__file__).with_name("data") / "rotated_frames.ngc"], ids=lambda p: p.name)
def test_corrections_in_rotated_work_systems_land_on_the_machine(path: Path) -> None:
    """Corrections are machine-frame vectors; in a work system turned by G10 L2 R the writer turns them back into
    the program's numbers (absolute and G91 words, I/J of the arcs after them), adding the axis word a turned
    correction needs. Re-read, every command ends at its original end plus its correction."""
    prog = read_program(path)
    assert prog.unsupported is None
    turned = prog.moves.rotation_deg[prog.command_moves] != 0.0
    assert turned.any()
    n = prog.n_commands
    rng = np.random.default_rng(21)
    # 2-5 µm in X and Y (arc starts stay on their circles, within LinuxCNC's 0.028 mm), some X only
    corr = np.zeros((n, 3))
    corr[:, :2] = rng.uniform(2e-3, 5e-3, (n, 2)) * rng.choice([-1.0, 1.0], (n, 2))
    corr[::3, 1] = 0.0
    # polar words (@ ^) take no correction in any frame (both computed words sit on one span: "overlapping
    # rewrites", also without rotation): their line is left as it is
    polar_line = [i + 1 for i, t in enumerate(prog.text.split("\n")) if "@" in t]
    corr[np.isin(prog.command_line, polar_line)] = 0.0
    text, edits = apply_corrections(prog, corr, min_decimals=6)
    assert edits
    again = read_gcode(path, text.encode("latin-1"))
    assert again.unsupported is None and again.n_commands == n
    # each written number is rounded to 6 decimals of the program unit (half a unit of the 6th decimal); a turned
    # frame mixes the X and Y numbers into each machine axis (|cos| + |sin| <= sqrt 2)
    tol = 0.5e-6 * float(prog.moves.unit_mm.max()) * math.sqrt(2.0) + 1e-12
    assert np.abs(again.command_end_mm - (prog.command_end_mm + corr)).max() <= tol
    # every other move ends where it did
    other = again.moves.command < 0
    assert np.all(np.abs(again.moves.end_mm[other] - prog.moves.end_mm[prog.moves.command < 0]) <= tol)
    # a turned X-only correction on a line that names X only (a G91 'X-5' in rotated_frames.ngc, an absolute 'y' in
    # the LinuxCNC sample) gets the other axis word added
    added = [e for e in edits if e.start == e.end]
    assert any(turned[k] and corr[k, 1] == 0.0 for k in range(n))
    assert added, "no axis word was added for a correction that the rotation turned onto the other axis"


def test_a_loop_over_very_long_lines_is_refused_not_lexed_for_minutes() -> None:
    # the fuzzer's case: spiral.ngc's 800-times repeat with a line made 7 MB long; each run of a line lexes it
    # again, so the reader stops at MAX_REPEATED_BYTES of repeated lines with its line, as for an endless loop
    from ilcnc.program.gcode_flow import MAX_REPEATED_BYTES

    long = "(" + "x" * 200_000 + ")"
    text = f"G21 G90\nG0 X0 Y0 Z1\no100 repeat [800]\nG91 G1 X0.01 F100 {long}\no100 endrepeat\nG90\nM2\n"
    assert 800 * len(long) > MAX_REPEATED_BYTES
    prog = read_gcode(Path("loop.ngc"), text.encode())
    with pytest.raises(UnsupportedError) as err:
        prog.require_complete()
    assert err.value.line == 4 and "64 MB of lines again" in err.value.format()
    # the same loop over short lines reads whole
    short = read_gcode(Path("loop.ngc"), text.replace(long, "(short)").encode())
    short.require_complete()
    assert len(short.moves) >= 800

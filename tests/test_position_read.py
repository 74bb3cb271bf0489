"""Commands whose end point a later block reads before the next move (G92, G10 L20, G28.1, a canned cycle, G5.1,
#5420.., polar words) are never corrected: a correction would move everything that block sets up."""

from __future__ import annotations

import numpy as np
import pytest

from ilcnc.learning.learner import correctable_commands, frozen_reasons, learn_virtual, program_with_corrections
from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.program.model import FLAG_POLAR, FLAG_POSITION_READ
from tests.conftest import REPO, SAMPLES

PROFILE = REPO / "configs" / "example-mill.yaml"

# a fast square whose corners the virtual CNC rounds (large corrections), then a block that reads the position the
# G1 before it ends at, then a second square whose place depends on what that block read
SQUARE = "G1 X20 Y0\nG1 X20 Y20\nG1 X0 Y20\nG1 X0 Y0\nG1 X20 Y0\nG1 X20 Y20\n"
HEAD = "G21 G90 G17 G64\nF4000\nG0 X0 Y0 Z1\nG1 Z-1\n"


def _read(tmp_path, text: str, name: str = "p.ngc"):
    p = tmp_path / name
    p.write_text(text)
    return read_program(p)


def _learned_text(program) -> str:
    """The program iteration 1 of a virtual learning wrote (kept or not: what a correction does to it)."""
    res = learn_virtual(program, load_profile(PROFILE), iterations=1, guard=False, stop_on_stall=False)
    return res.iterations[-1].text


@pytest.mark.parametrize("reader", ["G92 X0 Y0", "G10 L20 P1 X0 Y0", "G28.1"])
def test_a_block_reading_the_position_freezes_the_g1_before_it_and_the_output_keeps_every_later_move(
        tmp_path, reader: str) -> None:
    after = "G28 G91 Z0\nG90\n" if reader == "G28.1" else ""
    text = HEAD + SQUARE + reader + "\n" + after + SQUARE + "G0 Z5\nM2\n"
    prog = _read(tmp_path, text)
    line = text.splitlines().index(reader) + 1
    frozen_k = int(np.flatnonzero(prog.command_line == line - 1)[0])
    assert prog.moves.flags[prog.command_moves[frozen_k]] & FLAG_POSITION_READ
    assert not correctable_commands(prog)[frozen_k]
    assert frozen_reasons(prog) == {next(iter(frozen_reasons(prog))): 1}
    assert any(f"line {line}:" in w and f"line {line - 1} ending there is never corrected" in w for w in prog.warnings)
    out = _read(tmp_path, _learned_text(prog), "out.ngc")
    mv0, mv1 = prog.moves, out.moves
    assert len(mv1) == len(mv0)
    moved = np.any(mv1.end_mm != mv0.end_mm, axis=1)
    assert moved.any(), "the learning corrected nothing: the test would prove nothing"
    # the frozen command and every move after the reading block end exactly where the source's do (the source's
    # own numbers are written back untouched, so equality is exact), and read the same work offsets
    later = np.flatnonzero(mv0.line >= line - 1)
    later = later[mv0.line[later] > line] if reader == "G28.1" else later
    np.testing.assert_array_equal(mv1.end_mm[later][~moved[later]], mv0.end_mm[later][~moved[later]])
    np.testing.assert_array_equal(mv1.offset_mm[mv0.line > line], mv0.offset_mm[mv0.line > line])
    # moves after it that did move are the second square's own corrected commands, each by a learned correction
    k_later = mv1.command[later][moved[later]]
    assert np.all(k_later >= 0)
    assert not np.any(mv1.line[later][moved[later]] == line - 1)


def test_without_the_freeze_a_g92_after_a_corrected_g1_shifts_every_later_move(tmp_path) -> None:
    """Why the rule exists: a correction on the G1 before a G92 moves the whole second square. The writer refuses
    it (one line, the line named); the same change made by hand in the text shows what it would do."""
    from ilcnc.errors import CorrectionError

    text = HEAD + SQUARE + "G92 X0 Y0\n" + SQUARE + "M2\n"
    prog = _read(tmp_path, text)
    k = int(np.flatnonzero(prog.moves.flags[prog.command_moves] & FLAG_POSITION_READ)[0])
    corr = np.zeros((prog.n_commands, 3))
    corr[k] = (0.01, -0.02, 0.0)
    with pytest.raises(CorrectionError) as err:
        program_with_corrections(prog, corr, load_profile(PROFILE))
    line = int(prog.command_line[k])
    assert err.value.line == line and "next block reads its end point" in err.value.format()
    lines = text.split("\n")
    end = prog.moves.end_mm[prog.command_moves[k]]
    lines[line - 1] = f"G1 X{end[0] + 0.01:.4f} Y{end[1] - 0.02:.4f}"
    mv0, mv1 = prog.moves, _read(tmp_path, "\n".join(lines), "out.ngc").moves
    after = mv0.line > 11
    np.testing.assert_allclose(mv1.end_mm[after] - mv0.end_mm[after], np.tile([0.01, -0.02, 0.0], (after.sum(), 1)),
                               atol=1e-12)  # the whole square, shifted by the correction (float sums of mm)


def test_a_g1_before_a_drilling_cycle_is_frozen_and_learning_writes_the_program(tmp_path) -> None:
    """Before: "no place to insert a X word" (the cycle's moves carry no words); the hole without X/Y is drilled at
    the current position, so a correction of the G1 would move the hole."""
    text = HEAD + SQUARE + "G81 Z-3 R1\nG81 X5 Y5 Z-3 R1\nG80\nG0 Z5\nM2\n"
    prog = _read(tmp_path, text)
    line = 11
    k = int(np.flatnonzero(prog.command_line == line - 1)[0])
    assert not correctable_commands(prog)[k]
    out = _read(tmp_path, _learned_text(prog), "out.ngc")
    holes = prog.moves.line >= line
    np.testing.assert_array_equal(out.moves.end_mm[holes], prog.moves.end_mm[holes])
    assert np.any(out.moves.end_mm != prog.moves.end_mm)


def test_a_g1_before_a_g51_spline_is_frozen(tmp_path) -> None:
    text = HEAD + SQUARE + "G5.1 X30 Y10 I5 J-5\nG1 X0 Y0\nG0 Z5\nM2\n"
    prog = _read(tmp_path, text)
    k = int(np.flatnonzero(prog.command_line == 10)[0])
    assert not correctable_commands(prog)[k]
    out = _read(tmp_path, _learned_text(prog), "out.ngc")
    spline = prog.moves.line == 11
    np.testing.assert_array_equal(out.moves.end_mm[spline], prog.moves.end_mm[spline])


def test_current_position_parameters_freeze_the_g1_they_read(tmp_path) -> None:
    text = HEAD + SQUARE + "#1 = #5420\nG1 X[#1 + 5]\nM2\n"
    prog = _read(tmp_path, text)
    k = int(np.flatnonzero(prog.command_line == 10)[0])
    assert prog.moves.flags[prog.command_moves[k]] & FLAG_POSITION_READ
    assert correctable_commands(prog)[k - 1]


def test_polar_lines_are_frozen_and_never_fail_the_learning(tmp_path) -> None:
    """Before: "overlapping rewrites in one block" (X and Y were both the @ word's span)."""
    text = HEAD + SQUARE + "G1 @10 ^45\nG1 @20\nG91 G1 ^10\nG90 G1 X0 Y0\nG0 Z5\nM2\n"
    prog = _read(tmp_path, text)
    polar = prog.moves.line >= 11
    polar &= prog.moves.line <= 13
    assert np.all(prog.moves.flags[polar] & FLAG_POLAR)
    ks = prog.moves.command[polar]
    assert not correctable_commands(prog)[ks].any()
    # G1 @20 keeps the angle of the position before it, G91 ^10 both: the G1 @10 ^45 they read is frozen anyway;
    # G1 @10 ^45 (both words, G90) reads nothing, so the G1 at line 10 keeps its correction
    assert correctable_commands(prog)[int(np.flatnonzero(prog.command_line == 10)[0])]
    out = _read(tmp_path, _learned_text(prog), "out.ngc")
    np.testing.assert_array_equal(out.moves.end_mm[polar], prog.moves.end_mm[polar])


@pytest.mark.parametrize(("name", "why", "reader", "before"), [
    ("spiral.ngc", "a polar move measured from the current position", "o100 repeat", "g1 z"),
    ("systems.ngc", "G5.1 starts its spline at the current position", "G5.1", "G01"),
])
def test_shipped_linuxcnc_samples_name_the_commands_a_later_block_reads(name: str, why: str, reader: str,
                                                                         before: str) -> None:
    """LinuxCNC's nc_files: spiral.ngc's loop of G91 polar moves starts from the plunge before it (800 polar moves,
    each measured from the end of the one before); systems.ngc's glyphs start G5.1 splines at the end of a G01."""
    path = SAMPLES / "gcode" / name
    if not path.is_file():
        pytest.skip(f"{path} is not in this checkout")
    prog = read_program(path)
    prog.require_complete()
    lines = [s.strip() for s in path.read_text(encoding="latin-1").splitlines()]
    # the source's own count: a reading block whose nearest non-empty line before it is a G1
    want = []
    for i, s in enumerate(lines):
        if s.startswith(reader):
            j = i - 1
            while not lines[j]:
                j -= 1
            if lines[j].startswith(before):
                want.append(j + 1)
    assert want
    notes = [w for w in prog.warnings if why in w]
    assert [int(w.split("the G1 at line ")[1].split()[0]) for w in notes] == want
    frozen = prog.moves.flags[prog.command_moves] & FLAG_POSITION_READ != 0
    assert sorted(set(prog.command_line[frozen].tolist())) == want
    assert not correctable_commands(prog)[frozen].any()


def test_klartext_cc_without_coordinates_freezes_the_l_before_it(tmp_path) -> None:
    """A bare CC takes the last programmed position as the pole (a circle around it would move with a correction);
    CYCL DEF 7 takes numbers, not the position, and freezes nothing."""
    text = ("0 BEGIN PGM P MM\n1 TOOL CALL 1 Z S1000\n2 L X+0 Y+0 Z+1 R0 FMAX\n3 L Z-1 F1000\n4 L X+20 Y+0\n"
            "5 CYCL DEF 7.0 DATUM SHIFT\n6 CYCL DEF 7.1 X+0\n7 L X+20 Y+20\n8 CC\n9 L X+30 Y+20\n"
            "10 C X+10 Y+20 DR+\n11 L Z+5 FMAX\n12 END PGM P MM\n")
    prog = _read(tmp_path, text, "p.h")
    prog.require_complete()
    frozen = prog.moves.flags[prog.command_moves] & FLAG_POSITION_READ != 0
    # file lines are block numbers + 1 (BEGIN PGM is block 0)
    assert prog.command_line[frozen].tolist() == [8]
    assert correctable_commands(prog)[prog.command_line == 5].all()
    assert any(w.startswith("line 9: CC without both pole coordinates") for w in prog.warnings)


def test_export_refuses_a_correction_of_a_command_whose_end_point_the_next_block_reads(tmp_path) -> None:
    # the learner never corrects such a command; a corrections CSV given to export must not either: G92 would take
    # the corrected position and every later move would shift by the correction
    from ilcnc.errors import CorrectionError
    from ilcnc.program.rewrite import apply_corrections

    prog = _read(tmp_path, "G21 G90\nG0 X0 Y0 Z0\nG1 X1 Y1 F100\nG92 X0 Y0\nG1 X5 Y5\nM2\n")
    corr = np.zeros((prog.n_commands, 3))
    k = int(np.flatnonzero(prog.command_line == 3)[0])
    corr[k] = (0.01, 0.0, 0.0)
    with pytest.raises(CorrectionError) as err:
        apply_corrections(prog, corr)
    assert err.value.line == 3 and "next block reads its end point" in err.value.format()
    other = np.zeros_like(corr)
    other[int(np.flatnonzero(prog.command_line == 5)[0])] = (0.01, 0.0, 0.0)
    text, _edits = apply_corrections(prog, other)  # the command after the G92 takes one
    assert "X5.01" in text


def test_a_measured_step_reports_its_frozen_commands_as_the_virtual_learning_does(tmp_path) -> None:
    # a log of the program (the virtual CNC stands in for the machine), then one measured step: the G1 the G92 reads
    # is counted with its reason in the JSON, as learn's virtual run counts it (before: frozen_commands 0)
    import json
    import subprocess
    import sys

    src = tmp_path / "part.ngc"
    src.write_text(HEAD + SQUARE + "G92 X0 Y0\n" + SQUARE + "M2\n")
    run = [sys.executable, "-m", "ilcnc"]
    log = tmp_path / "run0.csv"
    r = subprocess.run([*run, "simulate", str(src), "--profile", str(PROFILE), "--log-out", str(log)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    r = subprocess.run([*run, "learn", str(src), "--profile", str(PROFILE), "--log", str(log), "--state",
                        str(tmp_path / "st"), "--out", str(tmp_path / "p1.ngc"), "--json"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    measured = json.loads(r.stdout)
    virtual = learn_virtual(read_program(src), load_profile(PROFILE), iterations=1)
    assert measured["frozen_commands"] == virtual.frozen >= 1
    assert measured["frozen_reasons"] == dict(virtual.frozen_reasons)

"""Conversion moves the tool where the source does and carries its machining (issue 20, items 1-4):
machine-coordinate moves, datum shifts, axes the source never positioned, tool calls, spindle, coolant, dwells,
stops and comments; what has no equivalent in the target is refused with the line."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.program import read_program
from ilcnc.program.carry import carried_events
from ilcnc.program.model import FLAG_MACHINE

from .conftest import OWN, REPO, SAMPLES, TEST_ONLY, shared_param

runner = CliRunner()


def _export(src, out) -> tuple[int, str]:
    res = runner.invoke(app, ["export", str(src), "--out", str(out)])
    return res.exit_code, res.output


def _same_motion(a, b, tol_mm: float) -> None:
    """Both interpretations move alike: every move's kind, machine flag and end point (the readers' consistent
    frame: program coordinates plus the active offsets; machine coordinates for machine moves)."""
    ma, mb = a.moves, b.moves
    assert len(ma) == len(mb)
    if len(ma) == 0:
        return
    assert np.array_equal(ma.kind, mb.kind)
    assert np.array_equal(ma.flags & FLAG_MACHINE, mb.flags & FLAG_MACHINE)
    assert np.abs(ma.end_mm - mb.end_mm).max() <= tol_mm
    work = (ma.flags & FLAG_MACHINE) == 0  # a machine move's position does not depend on the work offset
    if work.any():
        assert np.abs(ma.offset_mm[work] - mb.offset_mm[work]).max() <= tol_mm
    # the same feed on every feed move (written with at least one decimal in program units per minute)
    fed = ma.kind != 0
    assert np.allclose(mb.feed_mm_min[fed], ma.feed_mm_min[fed], rtol=1e-6, atol=0.051 * 25.4), "feeds differ"


def test_m91_retract_becomes_g53_not_a_work_rapid(tmp_path):
    src = tmp_path / "m91.h"
    src.write_text("0 BEGIN PGM T MM\n1 L X+0 Y+0 Z+50 R0 FMAX\n2 L Z+5 F500\n3 L X+10 F500\n"
                   "4 L Z-10 R0 FMAX M91\n5 END PGM T MM\n")
    rc, _ = _export(src, tmp_path / "m91.ngc")
    assert rc == 0
    lines = (tmp_path / "m91.ngc").read_text().splitlines()
    assert "G53 G0 Z-10.000" in lines
    assert not any(ln.startswith("G0") and "Z-10" in ln for ln in lines)  # never a work-coordinate rapid there
    _same_motion(read_program(src), read_program(tmp_path / "m91.ngc"), 5e-4)


@pytest.mark.parametrize("name", ["apt_teste-metrologia_12.h"])  # apt_top-light-cover_11: its pecking cycles
def test_klartext_machine_moves_convert_and_read_back_alike(tmp_path, name):  # are refused (below)
    src = SAMPLES / "heidenhain" / name
    out = tmp_path / "out.ngc"
    rc, msg = _export(src, out)
    assert rc == 0, msg
    a, b = read_program(src), read_program(out)
    assert np.count_nonzero(a.moves.flags & FLAG_MACHINE) > 0
    assert "G53 G0" in out.read_text()
    _same_motion(a, b, 5e-4)
    # and back to Klartext: M91 again, the same motion
    back = tmp_path / "back.h"
    rc, msg = _export(out, back)
    assert rc == 0, msg
    assert "M91" in back.read_text()
    _same_motion(a, read_program(back), 5e-4)


def test_datum_shift_becomes_g52(tmp_path):
    src = tmp_path / "ds.h"
    src.write_text("0 BEGIN PGM D MM\n1 L X+0 Y+0 Z+5 R0 FMAX\n2 CYCL DEF 7.0 DATUM SHIFT\n3 CYCL DEF 7.1 X+100\n"
                   "4 L X+0 Y+0 FMAX\n5 L Z-1 F200\n6 L X+10 F500\n7 END PGM D MM\n")
    out = tmp_path / "ds.ngc"
    rc, msg = _export(src, out)
    assert rc == 0, msg
    text = out.read_text()
    assert "G52 X100.000 Y0.000 Z0.000" in text and "G52 X0 Y0 Z0" in text
    a, b = read_program(src), read_program(out)
    _same_motion(a, b, 5e-4)
    assert b.moves.end_mm[-1].tolist() == [110.0, 0.0, -1.0]


def test_gcode_to_klartext_writes_only_the_axes_the_source_moves(tmp_path):
    src = tmp_path / "g53.ngc"
    src.write_text("G21 G90\nG0 Z5\nG53 G0 Z0\nG0 X10 Y10\nG1 Z-1 F100\nG1 X20\nM2\n")
    out = tmp_path / "g53.h"
    rc, msg = _export(src, out)
    assert rc == 0, msg
    blocks = [ln.split(" ", 1)[1] for ln in out.read_text().splitlines()[1:-1]]
    # no invented X0 Y0 before the first move, no drop to work Z0 after the machine-coordinate move
    assert blocks == ["L Z+5.000 FMAX", "L Z+0.000 FMAX M91", "L X+10.000 Y+10.000 FMAX", "L Z-1.000 F100",
                      "L X+20.000"]


def test_klartext_to_gcode_writes_only_the_axes_the_source_moves(tmp_path):
    src = tmp_path / "z.h"
    src.write_text("0 BEGIN PGM Z MM\n1 L Z+50 R0 FMAX\n2 L Z+10 FMAX M91\n3 L X+5 Y+5 FMAX\n4 L Z-1 F300\n"
                   "5 L X+20 F800\n6 END PGM Z MM\n")
    out = tmp_path / "z.ngc"
    rc, msg = _export(src, out)
    assert rc == 0, msg
    lines = out.read_text().splitlines()[2:-1]
    assert lines == ["G0 Z50.000", "G53 G0 Z10.000", "G0 X5.000 Y5.000", "G1 Z-1.000 F300.0", "G1 X20.000 F800.0"]


def test_m92_and_g28_are_refused_and_nothing_is_written(tmp_path):
    src = tmp_path / "m92.h"
    src.write_text("0 BEGIN PGM T MM\n1 L X+0 Y+0 Z+50 R0 FMAX\n2 L Z+5 F500\n3 L Z-10 R0 FMAX M92\n4 END PGM T MM\n")
    rc, msg = _export(src, tmp_path / "m92.ngc")
    assert rc == 1 and "m92.h:4" in msg and "M92" in msg
    assert not (tmp_path / "m92.ngc").exists()
    src = tmp_path / "g28.ngc"
    src.write_text("G21 G90\nG0 Z5\nG28\nG0 X1\nM2\n")
    rc, msg = _export(src, tmp_path / "g28.h")
    assert rc == 1 and "g28.ngc:3" in msg and "G28" in msg
    assert sorted(p.name for p in tmp_path.iterdir()) == ["g28.ngc", "m92.h"]  # nothing left behind


# -- item 4: the machining is carried, or the conversion is refused with the line ------------------------------

def _blocks_before_first_move(path) -> list[str]:
    out = []
    for ln in path.read_text().splitlines()[1:]:
        body = ln.split(" ", 1)[1] if path.suffix == ".h" else ln
        if body.startswith(("L ", "G0 ", "G1 ", "C ", "CC ")):
            break
        out.append(body)
    return out


def test_compass_to_klartext_keeps_its_spindle(tmp_path):
    """The README's own example: `M3 S4000` was dropped, rc 0."""
    out = tmp_path / "compass.h"
    rc, msg = _export(REPO / "samples" / "compass.ngc", out)
    assert rc == 0, msg
    assert _blocks_before_first_move(out) == ["TOOL CALL Z S4000", "M3"]


def test_kb219_to_klartext_keeps_spindle_coolant_and_dwells(tmp_path):
    out = tmp_path / "kb.h"
    rc, msg = _export(SAMPLES / "gcode" / "KB-219 test.gcode", out)
    assert rc == 0, msg
    head = _blocks_before_first_move(out)
    # in the source's order: G4 P0.5, M3, S20000, M8, G4 P7 (and grbl's $H kept in sight as a comment)
    want = ["CYCL DEF 9.1 DWELL 0.5", "M3", "TOOL CALL Z S20000", "M8", "CYCL DEF 9.1 DWELL 7"]
    got = [b for b in head if b in want]
    assert got == want
    assert any("$H" in b for b in head)


def test_klartext_tool_call_to_gcode_applies_the_length_like_the_tnc(tmp_path):
    out = tmp_path / "square.ngc"
    rc, msg = _export(OWN / "square.h", out)
    assert rc == 0, msg
    head = _blocks_before_first_move(out)[2:]  # after the header comment and the modes line
    assert head == ["T1 M6 S12000", "G43 H1", "M3"]  # M3 on the first rapid acts at its start: before it
    if shutil.which("rs274"):  # LinuxCNC's interpreter runs it: tool change, length offset, spindle
        res = subprocess.run(["rs274", "-g", str(out)], capture_output=True, text=True, timeout=60)
        canon = res.stdout
        assert "CHANGE_TOOL(1)" in canon and "USE_TOOL_LENGTH_OFFSET" in canon and "START_SPINDLE_CLOCKWISE" in canon
        assert "error" not in (res.stdout + res.stderr).lower()


def test_a_stamp_survives_conversion(tmp_path):
    from ilcnc.shop.workflow import find_stamp, stamp_text

    src = tmp_path / "stamped.ngc"
    text = (REPO / "samples" / "compass.ngc").read_text()
    src.write_text(stamp_text(text, "linuxcnc", name="compass.ngc", sha256="ab" * 32, iteration=3))
    out = tmp_path / "stamped.h"
    rc, msg = _export(src, out)
    assert rc == 0, msg
    st = find_stamp(out.read_text())
    assert st is not None and st["iteration"] == 3 and st["sha"] == "ab" * 8


@pytest.mark.parametrize(("path", "line", "what"), [
    (SAMPLES / "heidenhain" / "apt_top-light-cover_11.h", 23, "CYCL DEF 1.0"),
    (SAMPLES / "gcode" / "comp.ngc", 13, "G41/G42"),
    (SAMPLES / "interp" / "daisy.ngc", 25, "axis word A"),
    (SAMPLES / "gcode" / "botomata_bottom.nc", 8, "G55"),
])
def test_what_cannot_be_carried_is_refused_with_its_line(tmp_path, path, line, what):
    out = tmp_path / ("x.ngc" if path.suffix == ".h" else "x.h")
    rc, msg = _export(path, out)
    assert rc == 1
    assert f"{path.name}:{line}:" in msg.replace("\n", "") and what in msg.replace("\n", " ")
    assert not out.exists()


def _machining(program) -> list[tuple[str, object]]:
    """The machining words of a program in run order (a tool call's speed as a speed after it), program ends and
    the converter's header comment left out."""
    c = carried_events(program)
    seq = []
    for i in range(len(program.moves)):
        seq += c.before.get(i, []) + c.after.get(i, [])
    seq += c.tail
    out: list[tuple[str, object]] = []
    for e in seq:
        if e.kind == "m" and e.value in (2.0, 30.0):
            continue
        if e.kind == "comment":
            if str(e.value).startswith("converted by ilcnc from"):
                continue
            # G-code comments cannot hold parentheses: the writer makes them brackets; control characters become
            # spaces; a Klartext line's trailing '~' would continue it
            text = str(e.value).replace("(", "[").replace(")", "]")
            # (and the writers' rule for what a comment holds: printable ASCII and latin-1 letters)
            text = "".join(c if " " <= c <= "~" or ord(c) > 160 else " " for c in text).rstrip(" ~")
            out.append(("comment", " ".join(text.split())))
            continue
        out.append((e.kind, e.value))
        if e.kind == "tool" and e.rpm is not None:
            out.append(("spindle", e.rpm))
    return out


_CONVERTIBLE = sorted(p for p in [*(REPO / "samples").glob("*.*"), *OWN.glob("*.*"), *SAMPLES.rglob("*.*")]
                      if p.suffix.lower() in (".h", ".ngc", ".nc", ".gcode", ".tap") and "large" not in p.parts)
_TEST_ONLY = [shared_param(folder, name) for folder, names in TEST_ONLY.items() for name in names]


@pytest.mark.parametrize("path", [*_CONVERTIBLE, *_TEST_ONLY], ids=lambda p: p.name)
def test_every_sample_converts_alike_or_is_refused(tmp_path, path):
    """Both directions on every sample the reader runs: the output reads back with the same motion (kind,
    machine flag, end point within the written decimals) and the same machining words in the same order, and
    converts back alike; or the conversion is refused with a line and writes nothing."""
    a = read_program(path)
    out = tmp_path / ("out.ngc" if a.dialect == "heidenhain" else "out.h")
    rc, msg = _export(path, out)
    if a.unsupported is not None:  # what the reader does not run is not converted either
        assert rc == 1 and f"{path.name}:{a.unsupported[0]}:" in msg.replace("\n", ""), msg
        assert not out.exists()
        return
    if rc != 0:
        assert rc == 1 and re.search(rf"{re.escape(path.name)}:\d+:", msg.replace("\n", "")), msg
        assert not out.exists()
        return
    b = read_program(out)
    assert b.unsupported is None
    _same_motion(a, b, 6e-4 * (25.4 if a.units == "inch" else 1.0))
    assert _machining(b) == _machining(a)
    back = tmp_path / ("back.h" if a.dialect == "heidenhain" else "back.ngc")
    rc, msg = _export(out, back)
    assert rc == 0, msg
    c = read_program(back)
    _same_motion(a, c, 6e-4 * (25.4 if a.units == "inch" else 1.0))
    assert _machining(c) == _machining(a)


# -- item 6: the source's precision is kept, and no arc becomes a full circle -----------------------------------

def test_a_tiny_arc_stays_tiny_and_the_source_precision_is_kept(tmp_path):
    src = tmp_path / "tiny.ngc"
    src.write_text("G21 G90 G17\nG0 X0 Y0 Z1\nG1 Z-1 F500\nG1 X10 Y0 F1000\nG3 X10.0003 Y0.0001 I0.0001 J0.5\n"
                   "G1 X20 Y0\nG0 Z5\nM2\n")
    out = tmp_path / "tiny.h"
    rc, msg = _export(src, out)
    assert rc == 0, msg
    a, b = read_program(src), read_program(out)
    _same_motion(a, b, 1e-9)
    assert "C X+10.0003 Y+0.0001 DR+" in out.read_text()
    # the 0.3 µm arc is not a full 1 mm circle: the path is as long as the source's
    length = lambda p: float(np.sum(np.linalg.norm(p.moves.end_mm - p.moves.start_mm, axis=1)))  # noqa: E731
    assert length(b) == pytest.approx(length(a), abs=1e-6)


@pytest.mark.parametrize(("path", "decimals"), [(REPO / "samples" / "compass.ngc", 6),
                                                (SAMPLES / "contour" / "Gates_combined_R12.nc", 4)])
def test_conversion_writes_the_decimals_the_source_wrote(tmp_path, path, decimals):
    out = tmp_path / "out.h"
    rc, msg = _export(path, out)
    assert rc == 0, msg
    words = re.findall(r" [XYZ][+-]\d+\.(\d+)", out.read_text())
    assert words and {len(w) for w in words} == {decimals}
    a, b = read_program(path), read_program(out)
    _same_motion(a, b, 0.5 * 10.0 ** -decimals + 1e-9)


@pytest.mark.parametrize(("text", "suffix", "line"), [
    ("0 BEGIN PGM R MM\n1 L X+0 Y+0 Z+5 R0 FMAX\n2 L X+10 A+5 F500\n3 END PGM R MM\n", ".h", 3),
    ("0 BEGIN PGM R MM\n1 L X+0 Y+0 Z+5 R0 FMAX\n2 L X+20 W+5 F500\n3 END PGM R MM\n", ".h", 3),
    ("G21 G90\nG0 X0 Y0 Z5\nG1 X10 A45 F500\nM2\n", ".ngc", 3),
])
def test_rotary_and_parallel_axes_are_refused_not_dropped(tmp_path, text, suffix, line):
    """Issue 20 item 5: `L X+10 A+5 F500` became `G1 X10.000`; `G1 X10 A45` became `L X+10.000`."""
    src = tmp_path / ("r" + suffix)
    src.write_text(text)
    out = tmp_path / ("r.ngc" if suffix == ".h" else "r.h")
    rc, msg = _export(src, out)
    assert rc == 1 and f"{src.name}:{line}:" in msg.replace("\n", "") and "axis" in msg
    assert not out.exists()

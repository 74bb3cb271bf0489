"""Conversion moves the tool where the source does (issue 20, items 1-3): machine-coordinate moves, datum shifts
and axes the source never positioned; what has no equivalent in the target is refused with the line."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.program import read_program
from ilcnc.program.model import FLAG_MACHINE

from .conftest import SAMPLES

runner = CliRunner()


def _export(src, out) -> tuple[int, str]:
    res = runner.invoke(app, ["export", str(src), "--out", str(out)])
    return res.exit_code, res.output


def _same_motion(a, b, tol_mm: float) -> None:
    """Both interpretations move alike: every move's kind, machine flag and end point (the readers' consistent
    frame: program coordinates plus the active offsets; machine coordinates for machine moves)."""
    ma, mb = a.moves, b.moves
    assert len(ma) == len(mb)
    assert np.array_equal(ma.kind, mb.kind)
    assert np.array_equal(ma.flags & FLAG_MACHINE, mb.flags & FLAG_MACHINE)
    assert np.abs(ma.end_mm - mb.end_mm).max() <= tol_mm
    work = (ma.flags & FLAG_MACHINE) == 0  # a machine move's position does not depend on the work offset
    assert np.abs(ma.offset_mm[work] - mb.offset_mm[work]).max() <= tol_mm


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


@pytest.mark.parametrize("name", ["apt_top-light-cover_11.h", "apt_teste-metrologia_12.h"])
def test_klartext_machine_moves_convert_and_read_back_alike(tmp_path, name):
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

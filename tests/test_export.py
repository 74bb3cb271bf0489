"""export: byte-identical copies, corrections that move exactly their end points."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ilcnc.errors import CorrectionError
from ilcnc.program import read_program
from ilcnc.shop.corrections import write_corrections
from ilcnc.shop.export import export_program

from .conftest import OWN, REPO, SAMPLES, sample_files

ROUND_TRIP = sample_files("gcode", "contour", "interp")


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ilcnc", *args], capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("path", ROUND_TRIP, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_round_trip_is_byte_identical(path: Path, tmp_path: Path) -> None:
    out = tmp_path / ("copy" + path.suffix)
    export_program(path, out)
    assert out.read_bytes() == path.read_bytes()


def test_round_trip_through_the_command_line(tmp_path: Path) -> None:
    src = SAMPLES / "gcode" / "KB-219 test.gcode"
    out = tmp_path / "out.gcode"
    r = _cli("export", str(src), "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert out.read_bytes() == src.read_bytes()


_COORD = re.compile(r"(?i)([XYZIJK])\s*[-+]?\d*\.?\d*")


def _strip_coords(line: str) -> str:
    return _COORD.sub(lambda m: m.group(1).upper(), line)


def _check_corrected(src: Path, tmp_path: Path, pick: np.ndarray, rng: np.random.Generator) -> None:
    prog = read_program(src)
    n = prog.n_commands
    # a command that starts an arc may only move along the arc's circle (the learner keeps it there; a random
    # correction would move it off, and export refuses that: test_a_correction_may_not_move_an_arc_start_off)
    nxt = np.minimum(prog.command_moves + 1, len(prog.moves) - 1)
    starts_arc = (prog.moves.kind[nxt] >= 2) & (prog.command_moves + 1 < len(prog.moves))
    pick = pick[~starts_arc[pick]]
    corr = np.zeros((n, 3))
    corr[pick] = rng.uniform(-0.05, 0.05, size=(len(pick), 3))
    corr = np.round(corr, 3)
    csv = tmp_path / "corr.csv"
    csv.write_text(write_corrections(corr))
    out = tmp_path / ("out" + src.suffix)
    export_program(src, out, corrections_path=csv, min_decimals=3)
    new = read_program(out)
    assert new.n_commands == n
    # corrected commands moved by their correction, every other end point stayed
    expect = prog.moves.end_mm.copy()
    expect[prog.command_moves] += corr
    tol = 0.5e-3 * prog.moves.unit_mm[:, None] + 1e-9
    assert np.all(np.abs(new.moves.end_mm - expect) <= tol)
    # only coordinate words changed: line count, and every line equal once numbers are removed
    a = prog.text.split("\n")
    b = new.text.split("\n")
    assert len(a) == len(b)
    changed = [i + 1 for i, (x, y) in enumerate(zip(a, b, strict=True)) if x != y]
    assert changed, "nothing was rewritten"
    for ln in changed:
        x, y = a[ln - 1], b[ln - 1]
        assert _strip_coords(x).replace(" ", "") == _strip_coords(y).replace(" ", "") or \
            set(_strip_coords(y).replace(" ", "")) >= set(_strip_coords(x).replace(" ", "")), (x, y)
    cmd_lines = set(prog.command_line[pick].tolist())
    # a changed line is a corrected command or the block right after one (absorbing the change)
    after = {int(prog.moves.line[min(i + 1, len(prog.moves) - 1)]) for i in prog.command_moves[pick]}
    assert set(changed) <= cmd_lines | after


def test_corrections_absolute_program(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    src = SAMPLES / "contour" / "compass.ngc"
    n = read_program(src).n_commands
    _check_corrected(src, tmp_path, rng.choice(n, size=200, replace=False), rng)


def test_corrections_inch_program(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    src = SAMPLES / "contour" / "vcarve.ngc"
    n = read_program(src).n_commands
    _check_corrected(src, tmp_path, rng.choice(n, size=100, replace=False), rng)


def test_corrections_incremental_program(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    src = OWN / "square-incremental.nc"
    _check_corrected(src, tmp_path, np.array([1, 2, 3]), rng)
    out = tmp_path / ("out" + src.suffix)
    text = out.read_text()
    # the G91 block after the corrected one absorbs the change; the final close is where it was
    assert read_program(out).moves.end_mm[-2].tolist() == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
    assert "G91" in text


def test_correction_of_modal_axis_inserts_the_word(tmp_path: Path) -> None:
    src = OWN / "square.ngc"
    corr = np.zeros((read_program(src).n_commands, 3))
    corr[1] = [0.012, 0.0, 0.0]  # G1 X50 -> X50.012 ; the next block "G1 Y50" must keep X50
    csv = tmp_path / "c.csv"
    csv.write_text(write_corrections(corr))
    out = tmp_path / "o.ngc"
    export_program(src, out, corrections_path=csv)
    lines = out.read_text().splitlines()
    assert lines[4] == "G1 X50.012 F3000"
    assert lines[5] == "G1 Y50 X50.000"
    assert read_program(out).moves.end_mm[3].tolist() == [50.0, 50.0, 0.0]


def test_corrections_with_unknown_k_fail_and_leave_nothing(tmp_path: Path) -> None:
    csv = tmp_path / "c.csv"
    csv.write_text("k,dx,dy,dz\n0,0.01,0,0\n99999,0.01,0,0\n")
    out = tmp_path / "o.ngc"
    r = _cli("export", str(OWN / "square.ngc"), "--out", str(out), "--corrections", str(csv))
    assert r.returncode == 1
    assert r.stderr.count("\n") == 1
    assert "c.csv:3:" in r.stderr and "k=99999" in r.stderr
    assert not out.exists()
    assert list(tmp_path.iterdir()) == [csv]


def test_export_refuses_to_overwrite_input(tmp_path: Path) -> None:
    src = tmp_path / "a.ngc"
    src.write_bytes((OWN / "square.ngc").read_bytes())
    r = _cli("export", str(src), "--out", str(src))
    assert r.returncode == 1
    assert "input" in r.stderr
    assert src.read_bytes() == (OWN / "square.ngc").read_bytes()


def test_corrections_on_unsupported_program_are_refused(tmp_path: Path) -> None:
    csv = tmp_path / "c.csv"
    csv.write_text("k,dx,dy,dz\n0,0.01,0,0\n")
    src = tmp_path / "cubic.ngc"  # (G5.1 and G5.2 NURBS blocks are modelled since; the G5 cubic spline is not)
    src.write_text("G21 G90 G17\nG0 X0 Y0 Z0\nG1 X1 F600\nG5 X5 Y5 I1 J0 P-1 Q0\nM30\n")
    r = _cli("export", str(src), "--out", str(tmp_path / "o.ngc"), "--corrections", str(csv))
    assert r.returncode == 1
    assert "cubic.ngc:4:" in r.stderr and "G5 cubic spline is not modelled" in r.stderr
    assert not (tmp_path / "o.ngc").exists()
    # systems.ngc is read since G5.1 splines are: its command 0 (line 14) ends where the spline on line 15 starts,
    # so the writer refuses its correction on its own line (before: when the spline's start could not follow)
    r = _cli("export", str(SAMPLES / "gcode" / "systems.ngc"), "--out", str(tmp_path / "o.ngc"), "--corrections", str(csv))
    assert r.returncode == 1 and "systems.ngc:14:" in r.stderr and "next block reads its end point" in r.stderr
    assert not (tmp_path / "o.ngc").exists()


def test_rewritten_numbers_keep_the_source_spelling(tmp_path: Path) -> None:
    src = tmp_path / "s.nc"
    src.write_text("G21 G90\nG0 X0 Y0\nG1 X10.1234 Y+5. F100\nX-.5000 Y2\nM2\n")
    corr = np.zeros((2, 3))
    corr[0] = [0.001, 0.002, 0.0]
    corr[1] = [0.0001, 0.0, 0.0]
    csv = tmp_path / "c.csv"
    csv.write_text(write_corrections(corr))
    out = tmp_path / "o.nc"
    export_program(src, out, corrections_path=csv, min_decimals=3)
    assert out.read_text().splitlines()[2:4] == ["G1 X10.1244 Y+5.002 F100", "X-.4999 Y2"]


def test_inspect_reports_planned_cycle_time_with_a_profile(tmp_path: Path) -> None:
    import json

    src = SAMPLES / "contour" / "compass.ngc"
    plain = json.loads(_cli("inspect", str(src), "--json").stdout)
    planned = json.loads(_cli("inspect", str(src), "--json", "--profile", str(REPO / "configs" / "example-mill.yaml")).stdout)
    assert plain["g01_commands"] == planned["g01_commands"] == 2994
    assert planned["cycle_time_kind"].startswith("planned")
    # acceleration and corner slow-downs make the real cycle longer than length / feed
    assert planned["cycle_time_s"] > planned["feed_only_time_s"]
    moves = tmp_path / "m.csv"
    r = _cli("inspect", str(src), "--moves", str(moves))
    assert r.returncode == 0
    rows = moves.read_text().splitlines()
    assert rows[0] == "k,line,x,y,z,f" and len(rows) == 2995


def test_inspect_warns_where_path_control_rounds_corners_beyond_the_profile() -> None:
    """Issue 23 item 6: square.ngc says G64 P0.05 (example-mill's tolerance: 0.01 mm); jsdc.gcode says nothing, so
    on linuxcnc-sim (planner.path_control g64, LinuxCNC's start-up mode) its corners are blended without a bound;
    on example-mill (path_control tolerance) nothing is said."""
    import json

    def warns(prog: Path, profile: str) -> list[str]:
        r = _cli("inspect", str(prog), "--json", "--profile", str(REPO / "configs" / profile))
        assert r.returncode == 0, r.stderr
        return json.loads(r.stdout)["warnings"]

    w = warns(OWN / "square.ngc", "example-mill.yaml")
    assert len(w) == 1 and "blend within up to 0.05 mm (first on line 4)" in w[0] and "0.01 mm" in w[0]
    w = warns(SAMPLES / "gcode" / "jsdc.gcode", "linuxcnc-sim.yaml")
    assert len(w) == 1 and w[0].startswith("2381 feed moves run without a path control setting") and "G64 P0.01" in w[0]
    assert warns(SAMPLES / "gcode" / "jsdc.gcode", "example-mill.yaml") == []


@pytest.mark.parametrize("src", [SAMPLES / "heidenhain" / "apt_interface-glue_11.h", OWN / "square-incremental.h",
                                 SAMPLES / "heidenhain" / "apt_top-light-cover_11.h"],
                         ids=lambda p: p.name)
def test_corrections_in_klartext(src: Path, tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    n = read_program(src).n_commands
    pick = rng.choice(n, size=min(n, 150), replace=False)
    _check_corrected(src, tmp_path, np.sort(pick), rng)


@pytest.mark.parametrize("src", [SAMPLES / "contour" / "compass.ngc", SAMPLES / "contour" / "Gates_combined_R12.nc",
                                 SAMPLES / "contour" / "vcarve.ngc", OWN / "circle.ngc"], ids=lambda p: p.name)
def test_gcode_to_klartext_and_back_keeps_every_g01(src: Path, tmp_path: Path) -> None:
    prog = read_program(src)
    h = tmp_path / "part.h"
    export_program(src, h, min_decimals=4)
    klartext = read_program(h)
    klartext.require_complete()
    back = tmp_path / "part.ngc"
    export_program(h, back, min_decimals=4)
    again = read_program(back)
    tol = 0.5e-4 * (25.4 if prog.units == "inch" else 1.0) + 1e-9
    for other in (klartext, again):
        assert other.n_commands == prog.n_commands
        a = prog.command_end_mm - prog.moves.offset_mm[prog.command_moves]
        b = other.command_end_mm - other.moves.offset_mm[other.command_moves]
        assert np.max(np.abs(a - b)) <= tol
    text = h.read_text()
    assert text.upper().startswith("0 BEGIN PGM PART") and text.upper().rstrip().endswith("END PGM PART " + prog.units.upper())


def test_a_correction_may_not_move_an_arc_start_off_its_circle(tmp_path: Path) -> None:
    """A corrections file that moves the start of an arc 0.05 mm off its circle would give the control an arc it
    refuses (and the readers refuse it too): refused with the arc's line, nothing written."""
    src = OWN / "circle.ngc"
    prog = read_program(src)
    nxt = prog.command_moves + 1
    k = int(np.flatnonzero((nxt < len(prog.moves)) & (prog.moves.kind[np.minimum(nxt, len(prog.moves) - 1)] >= 2))[0])
    corr = np.zeros((prog.n_commands, 3))
    corr[k] = [0.05, 0.05, 0.0]
    csv = tmp_path / "corr.csv"
    csv.write_text(write_corrections(corr))
    out = tmp_path / "out.ngc"
    with pytest.raises(CorrectionError, match="off its circle"):
        export_program(src, out, corrections_path=csv)
    assert not out.exists()


def test_a_copy_of_a_program_the_interpreter_stops_in_says_so(tmp_path: Path) -> None:
    """Issue 21 item 3: export copies what it cannot interpret, byte for byte, and says so on stderr."""
    src = tmp_path / "m98.ngc"  # (M98 subprograms, G5.1 and G5.2 are modelled since; the G5 cubic spline is not)
    src.write_bytes(b"G21 G90\r\nG0 X0 Y0 Z5\r\nG5 X2 Y2 I1 J0 P1 Q0\r\nM98 P100\r\nG1 X1 F100\r\nM30\r\nO100\r\n"
                    b"G1 Y1\r\nM99\r\n")
    out = tmp_path / "copy.ngc"
    res = _cli("export", str(src), "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert out.read_bytes() == src.read_bytes()
    assert "m98.ngc:3:" in res.stderr and "copied byte for byte" in res.stderr
    # a correction still needs the interpretation: refused with the line
    csv = tmp_path / "c.csv"
    csv.write_text("k,dx,dy,dz\n0,0.01,0,0\n")
    res = _cli("export", str(src), "--out", str(tmp_path / "c.ngc"), "--corrections", str(csv))
    assert res.returncode == 1 and "m98.ngc:3:" in res.stderr


def test_parametric_coordinates_are_corrected_exactly_in_3d_chips(tmp_path: Path) -> None:
    """Issue 21 item 2 on LinuxCNC's own 3D_Chips.ngc (4,681 straight feeds written as X[#<xscale>*53.]): every one
    is a command, a correction c becomes [expression+c], and LinuxCNC's interpreter runs the result to the
    programmed point plus c (rs274 prints 4 decimals)."""
    import re as _re
    import shutil

    src = Path("/usr/share/linuxcnc/ncfiles/3D_Chips.ngc")
    if not src.exists() or not shutil.which("rs274"):
        pytest.skip("LinuxCNC's 3D_Chips.ngc and rs274 come with linuxcnc-uspace (not installed here)")
    prog = read_program(src)
    assert prog.n_commands == 4681 and prog.unsupported is None
    corr = np.round(np.random.default_rng(1).uniform(-0.01, 0.01, (prog.n_commands, 3)), 3)
    csv = tmp_path / "corr.csv"
    csv.write_text(write_corrections(corr))
    out = tmp_path / "chips.ngc"
    export_program(src, out, corrections_path=csv, min_decimals=4)
    assert "]+0." in out.read_text() or "]-0." in out.read_text()
    again = read_program(out)
    assert np.abs(again.command_end_mm - (prog.command_end_mm + corr)).max() < 1e-9
    res = subprocess.run(["rs274", "-g", str(out)], capture_output=True, text=True, timeout=300)
    feeds = np.array([[float(v) for v in m.group(1).split(",")[:3]]
                      for m in _re.finditer(r"STRAIGHT_FEED\(([^)]*)\)", res.stdout)])
    assert feeds.shape == (4681, 3)
    assert np.abs(feeds - again.command_end_mm / again.moves.unit_mm[again.command_moves, None]).max() <= 0.5e-4 + 1e-9

"""Probe height maps of the senders (bCNC, Candle, OpenCNCPilot, cncjs autolevel) and levelling a program on them.

The maps are written as each sender writes its file (bench/probemaps.py, the shipped ones in
samples/own/probemaps/); the programs are shipped third-party samples with arcs: circle-inch.gcode (cncjs,
G20, four G2 quarter arcs) and Gates_combined_R12.nc (CamBam, 10,156 G1 and 5,748 G2/G3).
"""

from __future__ import annotations

import importlib.util
import math
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.axislog.heightmap import detect_height_map, read_height_map
from ilcnc.cli import app
from ilcnc.contour.surface import line_split_fractions, surface_height_mm
from ilcnc.errors import InputError
from ilcnc.program import read_program
from ilcnc.program.model import MOVE_ARC_CW, MOVE_LINE
from ilcnc.shop.levelling import LEVEL_MARKER, _eligible, level_program
from tests.conftest import cli_output

REPO = Path(__file__).resolve().parent.parent
MAPS = REPO / "samples" / "own" / "probemaps"
GATES = REPO / "samples" / "third_party" / "contour" / "Gates_combined_R12.nc"
CIRCLE = REPO / "samples" / "circle-inch.gcode"
runner = CliRunner()


def _bench():
    spec = importlib.util.spec_from_file_location("probemaps", REPO / "bench" / "probemaps.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


BENCH = _bench()
FORMATS = {"bcnc": "bcnc", "candle": "candle", "opencncpilot": "opencncpilot", "cncjs": "xyz"}
#: circle-inch.gcode spans X/Y -12.7..12.7 mm: a 7 x 5 grid over -15..15 / -14..14 mm covers it
CIRCLE_GRID = (-15.0, 15.0, 7, -14.0, 14.0, 5)


def test_shipped_maps_are_the_script_output() -> None:
    files = BENCH.files()
    assert sorted(p.name for p in MAPS.iterdir()) == sorted(files)
    for name, data in files.items():
        assert (MAPS / name).read_bytes() == data, f"{name}: rerun python bench/probemaps.py"


@pytest.mark.parametrize("surface", ["tilt", "warp"])
@pytest.mark.parametrize("writer", list(FORMATS))
def test_each_format_reads_its_grid(surface: str, writer: str) -> None:
    suffix = BENCH.WRITERS[writer][0]
    m = read_height_map(MAPS / f"gates_{surface}_{writer}{suffix}")
    assert m.fmt == FORMATS[writer] == detect_height_map(m.path)
    assert m.shape == (13, 16)
    np.testing.assert_allclose(m.x_mm, np.linspace(-5, 145, 16), atol=1e-12)
    np.testing.assert_allclose(m.y_mm, np.linspace(-5, 115, 13), atol=1e-12)
    f = BENCH.SURFACES[surface]
    truth = np.array([[f(x, y) for x in m.x_mm] for y in m.y_mm])
    # each sender's zero: Candle's origin (X0 Y0), the extension's first probe (xmin, ymin); the others as probed
    zero = {"bcnc": 0.0, "opencncpilot": 0.0, "candle": f(0.0, 0.0), "cncjs": f(-5.0, -5.0)}[writer]
    # the files hold 6 decimals (bCNC's %g: 6 significant digits, below 1 mm that is >= 6 decimals)
    np.testing.assert_allclose(m.z_mm, truth - zero, atol=5.000001e-7)
    assert m.reference_xy_mm == {"bcnc": None, "opencncpilot": None, "candle": (0.0, 0.0), "cncjs": (-5.0, -5.0)}[writer]


def test_points_csv_is_no_height_map() -> None:
    assert detect_height_map(REPO / "samples" / "own" / "seed002_circle_probe.csv") is None


def _strip(line: str, centre: bool = False) -> str:
    """A line without its Z word (and I/J words: ``centre``) and the levelling marker: what must stay byte for
    byte."""
    line = re.sub(r" \(ilcnc: levelled with \S+ sha256:[0-9a-f]{16}\)", "", line)
    letters = "ZIJ" if centre else "Z"
    return re.sub(rf"\s*[{letters}][-+]?(\d+\.?\d*|\.\d+)", "", line, flags=re.IGNORECASE)


def _check_levelled(src: Path, out: Path, map_path: Path, z_tol_mm: float) -> tuple:
    """Z at every levelled end point is the program's Z plus the map's height (minus its zero), and every other
    word of every original line is unchanged; returns (original, output) programs."""
    orig = read_program(src)
    lev = read_program(out)
    hmap = read_height_map(map_path)
    lines_in = src.read_text(encoding="latin-1").splitlines()
    lines_out = out.read_text(encoding="latin-1").splitlines()
    kept = [(ln, k > 0 and LEVEL_MARKER in lines_out[k - 1]) for k, ln in enumerate(lines_out)
            if LEVEL_MARKER not in ln]
    assert len(kept) == len(lines_in)
    for a, (b, split) in zip(lines_in, kept, strict=True):
        # a split arc's own I/J are relative to its new start (its centre is checked below)
        assert _strip(a, centre=split) == _strip(b, centre=split), (a, b)
    # map the output's moves to the original's: inserted moves are on marked lines
    marked = np.array([LEVEL_MARKER in lev.line_text(int(ln))[1] for ln in lev.moves.line])
    own = np.flatnonzero(~marked)
    assert own.size == len(orig.moves)
    np.testing.assert_array_equal(lev.moves.kind[own], orig.moves.kind)
    ok = _eligible(orig)
    pc = orig.moves.end_mm - orig.moves.offset_mm
    h, _ = surface_height_mm(hmap, pc[:, 0], pc[:, 1])
    ref = 0.0
    if hmap.reference_xy_mm is not None:
        ref = float(surface_height_mm(hmap, np.array([hmap.reference_xy_mm[0]]), np.array([hmap.reference_xy_mm[1]]))[0][0])
    want = orig.moves.end_mm[:, 2] + np.where(ok, h - ref, 0.0)
    got = lev.moves.end_mm[own, 2]
    assert np.max(np.abs(got - want)) <= z_tol_mm
    np.testing.assert_array_equal(lev.moves.end_mm[own, :2], orig.moves.end_mm[:, :2])
    np.testing.assert_array_equal(lev.moves.offset_mm[own], orig.moves.offset_mm)
    # arcs keep their centres (a split arc's I/J are written to the numbers' rounding: 0.05 µm per axis)
    np.testing.assert_allclose(lev.moves.center_mm[own], orig.moves.center_mm, atol=1e-4, equal_nan=True)
    # an inserted point lies on its original straight feed or arc, at the surface height there
    for i in np.flatnonzero(marked).tolist():
        k = int(np.searchsorted(own, i))  # the original move it splits
        s0, e0 = orig.moves.start_mm[k], orig.moves.end_mm[k]
        pt = lev.moves.end_mm[i]
        if int(orig.moves.kind[k]) == MOVE_LINE:
            d = e0[:2] - s0[:2]
            f = float(np.dot(pt[:2] - s0[:2], d) / np.dot(d, d))
            off_path = np.hypot(*(s0[:2] + f * d - pt[:2]))
        else:
            assert int(orig.moves.kind[k]) >= MOVE_ARC_CW and int(lev.moves.kind[i]) == int(orig.moves.kind[k])
            c = orig.moves.center_mm[k, :2]
            a0, a1, ap = (math.atan2(*(q[1::-1] - c[::-1])) for q in (s0[:2], e0[:2], pt[:2]))
            ccw = int(orig.moves.kind[k]) != MOVE_ARC_CW
            sweep = ((a1 - a0) if ccw else (a0 - a1)) % (2 * math.pi) or 2 * math.pi
            f = (((ap - a0) if ccw else (a0 - ap)) % (2 * math.pi)) / sweep
            off_path = abs(np.hypot(*(pt[:2] - c)) - np.hypot(*(s0[:2] - c)))
        assert 0.0 < f < 1.0
        assert off_path < 1e-4  # inserted points are written within 0.05 µm per axis
        q = pt - lev.moves.offset_mm[i]
        hz = float(surface_height_mm(hmap, np.array([q[0]]), np.array([q[1]]))[0][0])
        # the path's Z there plus the surface height; the fraction f carries the XY rounding (<= 0.05 µm) into Z
        # times the move's Z slope, and the written Z its 0.5 µm
        assert abs(pt[2] - (s0[2] + f * (e0[2] - s0[2]) + hz - ref)) <= z_tol_mm + 1e-6
    return orig, lev


@pytest.mark.parametrize("writer", list(FORMATS))
def test_level_circle_inch_in_each_format(writer: str, tmp_path: Path) -> None:
    suffix, write = BENCH.WRITERS[writer]
    mp = tmp_path / f"warp{suffix}"
    mp.write_bytes(write(BENCH.warp, CIRCLE_GRID))
    out = tmp_path / "levelled.gcode"
    res = level_program(CIRCLE, mp, out)
    assert res.map_format == FORMATS[writer]
    # 5 inch decimals: a written number is within 0.5e-5 inch = 0.127 µm of its value
    _check_levelled(CIRCLE, out, mp, z_tol_mm=0.5e-5 * 25.4 + 1e-9)
    text = out.read_text()
    assert text.splitlines()[0].startswith("G17 G20 G90 G94 G54 (ilcnc: levelled with warp")
    # arcs stay arcs: the four G02 lines keep their I/J words and get a Z; where the surface bends along them
    # more than 1 µm they are split into arcs on the same circle, each within it
    arcs = [ln for ln in text.splitlines() if re.match(r"^(G0?2 )?X.* I", ln)]
    assert len(arcs) == 4 + res.points_inserted and all("Z" in ln for ln in arcs)
    assert res.arcs == len(arcs) and res.ends_outside == 0
    assert res.arcs_over_tolerance == 0 and res.arc_error_max_mm <= res.tolerance_mm


def test_level_gates_keeps_arcs_comments_and_splits_only_where_needed(tmp_path: Path) -> None:
    mp = MAPS / "gates_warp_opencncpilot.hmap"
    out = tmp_path / "gates.nc"
    res = level_program(GATES, mp, out)
    # 3 mm decimals: 0.5 µm
    orig, lev = _check_levelled(GATES, out, mp, z_tol_mm=0.5e-3 + 1e-9)
    n_arcs = int(np.count_nonzero(orig.moves.kind >= MOVE_ARC_CW))
    assert int(np.count_nonzero(lev.moves.kind >= MOVE_ARC_CW)) == n_arcs == 5748
    assert res.points_inserted == len(lev.moves) - len(orig.moves) > 0
    assert res.lines_split <= res.points_inserted < 0.01 * orig.n_commands  # only where the surface bends
    assert not res.split_refused
    assert res.line_error_max_mm <= res.tolerance_mm
    assert res.arcs_over_tolerance == 0 and res.arc_error_max_mm <= res.tolerance_mm
    # every levelled straight feed follows the surface within the tolerance between its ends (+ the 0.5 µm of
    # the written Z numbers at each end)
    hmap = read_height_map(mp)
    ok = _eligible(lev)
    worst = 0.0
    for i in np.flatnonzero(ok[1:] & ok[:-1] & (lev.moves.kind[1:] == MOVE_LINE)).tolist():
        i += 1
        s = lev.moves.start_mm[i, :2] - lev.moves.offset_mm[i, :2]
        e = lev.moves.end_mm[i, :2] - lev.moves.offset_mm[i, :2]
        if math.hypot(*(e - s)) > 1e-6:
            worst = max(worst, line_split_fractions(hmap, s, e, math.inf)[1])
    assert worst <= res.tolerance_mm
    text = out.read_text()
    assert text.count("(ilcnc level)") == res.points_inserted
    for word in ("M3 S1000", "M5", "M30", "( Holes )", "( Outside )", "( T0 M6 )"):
        assert word in text


def test_second_application_is_refused(tmp_path: Path) -> None:
    mp = MAPS / "gates_tilt_cncjs_probe.txt"
    mp2 = tmp_path / "circle.probe"
    mp2.write_bytes(BENCH.bcnc(BENCH.tilt, CIRCLE_GRID))
    out = tmp_path / "once.gcode"
    res = runner.invoke(app, ["learn", str(CIRCLE), "--points", str(mp2), "--out", str(out), "--json"])
    assert res.exit_code == 0, res.output
    assert '"mode": "height-map"' in cli_output(res)
    again = runner.invoke(app, ["learn", str(out), "--points", str(mp2), "--out", str(tmp_path / "twice.gcode")])
    assert again.exit_code == 1
    err = cli_output(again).strip()
    assert err.count("\n") == 0
    assert err.startswith(f"error: {out}:1: is levelled already with this map")
    other = runner.invoke(app, ["learn", str(out), "--points", str(mp), "--out", str(tmp_path / "twice.gcode")])
    assert other.exit_code == 1 and "is levelled already with map circle.probe" in cli_output(other)
    assert not (tmp_path / "twice.gcode").exists()


@pytest.mark.parametrize(("name", "content", "line", "problem"), [
    ("ragged.map", "candle map v3\r\n0;0;10;10\r\n0;0\r\n3;2;-1;3;10\r\n0;12;8\r\n0;0.1;0.2\r\n0;0.1\r\n", 7,
     "Candle map row 2: 2 values for 3 grid points in X (ragged grid)"),
    ("nan.probe", "0 10 2\n0 10 2\n-1 3 10\n\n\n0 0 0\n10 0 nan\n\n0 10 0\n10 10 0\n", 7, "z is not a finite number"),
    ("short.probe", "0 10 2\n0 10 2\n-1 3 10\n\n\n0 0 0\n10 0 0\n\n0 10 0\n", 9, "3 points for a 2 x 2 grid"),
    ("text.hmap", '<?xml version="1.0"?>\n<heightmap MinX="0" MinY="0" MaxX="10" MaxY="10" SizeX="2" SizeY="2">\n'
     '<point X="0" Y="0">0</point>\n<point X="1" Y="0">abc</point>\n</heightmap>\n', 4, "'abc' is not a number"),
    ("huge.probe", "0 10 1000000000\n0 10 1000000000\n-1 3 10\n\n\n0 0 0\n", 6, "1 points for a 1000000000 x"),
    ("huge.hmap", '<heightmap MinX="0" MinY="0" MaxX="10" MaxY="10" SizeX="100000" SizeY="100000">\n'
     '<point X="0" Y="0">0</point>\n</heightmap>\n', None, "9999999999 of 10000000000 grid points not probed"),
    ("holes_probe.txt", "0 0 0 0 0 0 0 0 0\n10 0 0.1 0 0 0 0 0 0\n0 10 0.2 0 0 0 0 0 0\n", None, "no full grid"),
])
def test_malformed_map_gives_one_line(name: str, content: str, line: int | None, problem: str, tmp_path: Path) -> None:
    p = tmp_path / name
    p.write_text(content)
    with pytest.raises(InputError) as exc:
        read_height_map(p)
    msg = exc.value.format()
    assert msg.startswith(f"{p}:{line}: " if line is not None else f"{p}: ")
    assert problem in msg and "\n" not in msg
    res = runner.invoke(app, ["learn", str(CIRCLE), "--points", str(p), "--out", str(tmp_path / "o.gcode")])
    assert res.exit_code == 1
    assert cli_output(res).strip() == f"error: {msg}"


def test_height_map_refuses_learning_options(tmp_path: Path) -> None:
    res = runner.invoke(app, ["learn", str(CIRCLE), "--points", str(MAPS / "gates_tilt_candle.map"), "--out",
                              str(tmp_path / "o.gcode"), "--state", str(tmp_path / "st")])
    assert res.exit_code == 2 and "--state does not go with a probe height map" in cli_output(res)
    res = runner.invoke(app, ["learn", str(CIRCLE), "--out", str(tmp_path / "o.gcode")])
    assert res.exit_code == 2 and "--profile is required" in cli_output(res)


def test_arcs_on_a_tilted_plane_are_split_into_arcs(tmp_path: Path) -> None:
    """A tilted plane is a cosine along a circle: a helix over a quarter circle of 12.7 mm departs from it by
    r * slope * (about 0.4) ~ 13 µm; each halving of the sweep divides that by about 4, so 4 pieces (3 inserted
    arcs per quarter circle) bring it below 1 µm."""
    mp = tmp_path / "tilt.probe"
    mp.write_bytes(BENCH.bcnc(BENCH.tilt, CIRCLE_GRID))
    out = tmp_path / "levelled.gcode"
    res = level_program(CIRCLE, mp, out)
    assert res.arcs_split == 4 and res.points_inserted == 12 and res.arcs == 16
    assert res.arcs_over_tolerance == 0 and res.arc_error_max_mm <= res.tolerance_mm
    _check_levelled(CIRCLE, out, mp, z_tol_mm=0.5e-5 * 25.4 + 1e-9)
    if shutil.which("rs274") is None:
        print("rs274 (LinuxCNC's interpreter) is not installed: LinuxCNC's acceptance of the split arcs not checked")
        return
    run = subprocess.run(["rs274", "-g", str(out)], capture_output=True, text=True, timeout=60)
    assert "error" not in (run.stderr + run.stdout).lower().replace("no percent sign or program end", "")
    assert run.stdout.count("ARC_FEED(") == 16


def test_a_program_with_splines_is_refused_in_one_line(tmp_path: Path) -> None:
    """systems.ngc (LinuxCNC) draws its letters with G5.1 splines, on which LinuxCNC takes no Z word."""
    prog = REPO / "samples" / "third_party" / "gcode" / "systems.ngc"
    mp = tmp_path / "tilt.probe"
    mp.write_bytes(BENCH.bcnc(BENCH.tilt, (-1.0, 3.0, 5, -1.0, 1.0, 3)))
    out = tmp_path / "o.ngc"
    res = runner.invoke(app, ["learn", str(prog), "--points", str(mp), "--out", str(out)])
    assert res.exit_code == 1
    assert cli_output(res).strip() == (f"error: {prog}:15: a spline (G5, G5.1, G5.2) or another move the reader derives:"
                                       " its Z cannot follow the map (LinuxCNC takes no Z word on a spline); have the"
                                       " CAM write it as arcs or lines")
    assert not out.exists()


def test_work_offsets_stay_and_a_change_is_told(tmp_path: Path) -> None:
    """circle-inch.gcode with its G54 and, before the second circle, a G92 shift of 0.1 inch in X: every offset
    and every word but Z stays; the map is read in each move's own work coordinates, and the result says so."""
    text = CIRCLE.read_text(encoding="latin-1")
    prog = tmp_path / "circle-g92.gcode"
    prog.write_text(text.replace("G01 Z0.1 F5.", "G01 Z0.1 F5.\nG92 X-0.4\nG01 X-0.5\nG01 Z0.\n"
                                 "G02 X0. Y0.5 I0.5 J0. F2.5\nG01 Z0.1 F5.\nG92.1", 1), encoding="latin-1")
    mp = tmp_path / "warp.probe"
    mp.write_bytes(BENCH.bcnc(BENCH.warp, CIRCLE_GRID))
    out = tmp_path / "levelled.gcode"
    res = level_program(prog, mp, out)
    _check_levelled(prog, out, mp, z_tol_mm=0.5e-5 * 25.4 + 1e-9)
    assert any(n.startswith("the work offset changes at line 12 ") for n in res.notes), res.notes
    assert "G92 X-0.4\n" in out.read_text() and "G92.1" in out.read_text()

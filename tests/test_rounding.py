"""The worst corners split into the planner's rounding and the rest (ilcnc.vcnc.rounding, ilcnc.shop.corners)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.outcomes import PathMode
from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.shop.corners import corner_report, setting_text
from ilcnc.units import length_word
from ilcnc.vcnc.plan import planned_duration_s
from ilcnc.vcnc.rounding import VertexMax, corner_errors, planner_rounding, vertex_tolerances
from ilcnc.vcnc.run import simulate_figures
from ilcnc.vcnc.simulate import simulate_program

from .conftest import OWN, REPO, cli_output, shared_sample

PROFILE = REPO / "configs" / "example-mill.yaml"
runner = CliRunner()


@pytest.fixture(scope="module")
def prof():
    return load_profile(PROFILE)


def _run(path: Path, prof):
    prog = read_program(path, default_units="mm")
    vm = VertexMax.empty(len(prog.moves))
    run = simulate_figures(prog, prof, vertices=vm)
    return prog, run, vm


def test_square_corners_are_rounded_within_its_own_g64_p_and_the_parts_add_up(prof) -> None:
    prog, run, vm = _run(OWN / "square.ngc", prof)  # G64 P0.05 Q0, a 50 mm square at F3000
    # the corners' maxima are the run's cutting samples grouped by the end point nearest them: the largest is
    # the run's cutting max, the same sample
    assert np.nanmax(vm.max_mm) == run.stats.max_mm
    rep = corner_report(prog, prof, vm)
    assert rep.corners[0].max_mm == run.stats.max_mm
    # four corners (plunge to X, three turns); the fifth end point meets the retract G0: no blend, and its
    # error is below half a resolution step, so it is not listed
    assert [(c.first_line, c.last_line) for c in rep.corners] == [(7, 8), (6, 7), (5, 6), (4, 5)]
    for c in rep.corners:
        assert c.tolerance_mm == 0.05 and c.set_by_program and c.mode is PathMode.BOUNDED and not c.quarter
        # a lone corner: the planner rounds it by at most the tolerance (at this feed the acceleration bounds
        # it first: 34-35 µm)
        assert 0.0 < c.rounding_mm <= c.tolerance_mm
        assert c.rounding_mm + c.rest_mm == pytest.approx(c.max_mm, abs=1e-15)  # one subtraction
        assert c.rest_mm > 0  # the drives lag behind the reference at every corner
    assert rep.summary().startswith("the cutting max 44.03 µm at line 8: 34.99 µm is the planner's rounding within"
                                    " G64 P0.05 (the program's)")
    assert rep.short[0] == "G64 P0.05 (program)"


def test_the_suggested_tolerance_costs_what_the_program_with_it_plans(prof, tmp_path: Path) -> None:
    prog, run, vm = _run(OWN / "square.ngc", prof)
    rep = corner_report(prog, prof, vm, cycle_time_s=run.cycle_time_s)
    t = rep.tightening
    assert t is not None and t.word == "G64 P0.025"  # half the program's 0.05 mm
    (r,) = t.ranges  # lines 4-7 end the four corners: one range
    # the program's own words after the range, its Q0 too, and on the tighter block
    assert (r.first_line, r.last_line, r.before, r.after) == (4, 7, "G64 P0.025 Q0", "G64 P0.05 Q0")
    assert 0.0 < r.rounding_after_mm <= 0.025 < r.rounding_mm
    # the program with those two lines written in plans to the cost the report gives, to the servo period
    lines = (OWN / "square.ngc").read_text().splitlines()
    edited = [*lines[:3], "G64 P0.025 Q0 (ilcnc: tighter corner tolerance)", *lines[3:7], "G64 P0.05 Q0", *lines[7:]]
    path = tmp_path / "square-tight.ngc"
    path.write_text("\n".join(edited) + "\n")
    assert planned_duration_s(read_program(path), prof) == t.cycle_after_s
    assert t.cycle_before_s == run.cycle_time_s < t.cycle_after_s


def test_the_planner_rounds_within_the_tolerance_and_reaches_it_where_the_tolerance_binds(prof) -> None:
    for name in ("jsdc.gcode", "compass.ngc"):
        prog = read_program(REPO / "samples" / name, default_units="mm")
        rd = planner_rounding(prog, prof)
        tol = vertex_tolerances(prog, prof)
        ok = np.isfinite(tol.tolerance_mm) & (tol.tolerance_mm > 0) & np.isfinite(rd.max_mm)
        assert ok.sum() > 2000
        assert not tol.set_by_program[ok].any() and np.all(tol.tolerance_mm[ok] == 0.01)  # the profile's
        assert np.all(rd.max_mm[ok] <= tol.tolerance_mm[ok])
        if name == "jsdc.gcode":
            # jsdc's corners run at the speed whose rounding is the tolerance (the planner's bisection); the
            # sampled reference comes within 0.1 µm of it (measured 9.99 µm of 10)
            assert rd.overall_mm == pytest.approx(0.01, abs=1e-4)


def test_whole_and_streamed_runs_find_the_same_corners(prof) -> None:
    prog = read_program(REPO / "samples" / "jsdc.gcode", default_units="mm")
    whole, streamed = VertexMax.empty(len(prog.moves)), VertexMax.empty(len(prog.moves))
    simulate_program(prog, prof, vertices=whole)
    simulate_figures(prog, prof, vertices=streamed)
    np.testing.assert_array_equal(whole.max_mm, streamed.max_mm)
    np.testing.assert_array_equal(whole.move, streamed.move)


def test_klartext_corners_are_said_as_cycle_32(prof) -> None:
    prog, _run_figures, vm = _run(OWN / "square.h", prof)  # no cycle 32: the profile's 10 µm
    rep = corner_report(prog, prof, vm)
    assert rep.short[0] == "cycle 32 T0.01 (profile)"
    assert rep.tightening is not None
    assert rep.tightening.word == "CYCL DEF 32.0 TOLERANCE / CYCL DEF 32.1 T0.005"
    assert rep.tightening.ranges[0].after == "CYCL DEF 32.1 (the machine's tolerance again)"


def test_a_programmed_cycle_32_governs_its_corners(prof) -> None:
    path = shared_sample("heidenhain", "lk_Krivka.h")  # CYCL DEF 32.1 T0,01 before its curve
    prog = read_program(path, default_units="mm")
    tol = vertex_tolerances(prog, prof)
    feed = np.isfinite(tol.tolerance_mm) & (tol.tolerance_mm > 0)
    assert tol.set_by_program[feed].all()
    # 0.01 mm, except where LinuxCNC's bound (a quarter of the shorter move) is below it
    assert np.all(np.where(tol.quarter[feed], tol.tolerance_mm[feed] < 0.01, tol.tolerance_mm[feed] == 0.01))
    e = int(np.flatnonzero(feed & ~tol.quarter)[0])
    fake = VertexMax.empty(len(prog.moves))
    fake.max_mm[e], fake.move[e] = 0.012, e
    (c,) = corner_errors(prog, fake, fake, tol, top=5)
    assert setting_text(prog, prof, c) == "cycle 32 T0.01 (the program's)"


def test_an_inch_program_gets_its_words_in_inches(prof) -> None:
    assert length_word(0.01, "inch") == "0.00039" and length_word(0.0125, "mm") == "0.0125"
    prog, _run_figures, vm = _run(REPO / "samples" / "circle-inch.gcode", prof)
    rep = corner_report(prog, prof, vm, target_um=3.0)
    assert rep.short[0] == "G64 P0.00039 (profile)"
    t = rep.tightening
    assert t is not None
    # 3 µm is 0.000118 in: the word is rounded down to its 5 decimals, so it still bounds the rounding
    assert t.word == "G64 P0.00011" and t.tolerance_mm == pytest.approx(0.00011 * 25.4, rel=1e-12)
    assert all(r.rounding_after_mm <= t.tolerance_mm for r in t.ranges)


def _cli(*args: str):
    return runner.invoke(app, [str(a) for a in args], env={"COLUMNS": "80"})


def test_simulate_reports_the_corners_in_text_and_json() -> None:
    jsdc = REPO / "samples" / "jsdc.gcode"
    # simulate lists no corners unless asked (it plans the drawing twice more)
    res = _cli("simulate", jsdc, "--profile", PROFILE, "--json")
    assert res.exit_code == 0, cli_output(res)
    assert "corners" not in json.loads(res.stdout)
    res = _cli("simulate", jsdc, "--profile", PROFILE, "--corners", "5", "--json")
    assert res.exit_code == 0, cli_output(res)
    data = json.loads(res.stdout)
    cs = data["corners"]
    assert cs["corners"][0]["max_mm"] == data["contour_error_mm"]["max"]
    assert cs["corners"][0]["set_by"] == "profile" and cs["corners"][0]["tolerance_mm"] == 0.01
    assert cs["tighter"]["word"] == "G64 P0.005"
    assert cs["tighter"]["cycle_time_after_s"] > cs["tighter"]["cycle_time_s"] == data["cycle_time_s"]
    res = _cli("simulate", jsdc, "--profile", PROFILE, "--corners", "2")
    out = cli_output(res)
    assert "worst cutting corners" in out and "the cutting max 15.91 µm at line 315" in out
    assert "tighter: G64 P0.005 on lines" in out
    res = _cli("simulate", jsdc, "--profile", PROFILE, "--corners", "0", "--json")
    assert "corners" not in json.loads(res.stdout)
    res = _cli("simulate", jsdc, "--profile", PROFILE, "--target-um", "0")
    assert res.exit_code == 2 and "--target-um" in cli_output(res)


def test_learn_reports_the_corners_of_its_output(tmp_path: Path) -> None:
    out = tmp_path / "sq.ngc"
    res = _cli("learn", OWN / "square.ngc", "--profile", PROFILE, "--out", out, "--iterations", "1", "--json")
    assert res.exit_code == 0, cli_output(res)
    data = json.loads(res.stdout)
    cs = data["corners"]
    assert "judged against the original's path" in cs["judged"]
    kept = [it for it in data["iterations"] if it["kept"]]
    best = min(kept[::-1], key=lambda it: it["contour_error_mm"]["rms"])  # the lowest RMS, the later of equals
    # one more run of the output against the original: the output is the best kept iteration, the same figures
    assert cs["corners"][0]["max_mm"] == pytest.approx(best["contour_error_mm"]["max"], rel=1e-12)
    assert cs["corners"][0]["setting"] == "G64 P0.05 (the program's)"


def test_tighter_out_writes_the_g64_p_lines_and_the_program_keeps_its_moves(tmp_path: Path) -> None:
    src = REPO / "samples" / "compass.ngc"  # no G61/G64: the profile's 10 µm governs every corner
    out = tmp_path / "compass-tight.ngc"
    res = _cli("simulate", src, "--profile", PROFILE, "--tighter-out", out, "--json")
    assert res.exit_code == 0, cli_output(res)
    data = json.loads(res.stdout)["corners"]
    written = data["tighter_out"]
    assert written["path"] == str(out) and not written["skipped"]
    old, new = src.read_bytes().split(b"\n"), out.read_bytes().split(b"\n")
    added = [ln for ln in new if b"ilcnc tighter" in ln]
    # two lines per corner range, everything else byte for byte in order
    assert len(added) == 2 * len(data["tighter"]["ranges"]) and len(new) == len(old) + len(added)
    assert [ln for ln in new if b"ilcnc tighter" not in ln] == old
    first = data["tighter"]["ranges"][0]["first_line"]
    assert new[first - 1].startswith(b"G64 P0.005 (ilcnc tighter") and new[first].startswith(old[first - 1])
    assert new[first + 1].startswith(b"G64 P0.01 (ilcnc tighter")  # the profile's tolerance, as a word
    prof = load_profile(PROFILE)
    a, b = read_program(src), read_program(out)
    np.testing.assert_array_equal(a.moves.end_mm, b.moves.end_mm)
    # the written program plans to the time the output reports; its moves after each range are now held to the
    # G64 P0.01 written there (LinuxCNC's quarter-move bound applies to a programmed tolerance), so it is at least
    # the suggestion's planned time
    assert planned_duration_s(b, prof) == written["cycle_time_s"] >= data["tighter"]["cycle_time_after_s"]
    # the corners the suggestion named are now rounded within 5 µm
    vm = VertexMax.empty(len(b.moves))
    simulate_figures(b, prof, vertices=vm)
    rd = planner_rounding(b, prof)
    lines = {r["first_line"] for r in data["tighter"]["ranges"]}
    moved = [i + 1 for i, ln in enumerate(a.moves.line.tolist()) if ln in lines]  # the vertex each move ends at
    assert np.all(rd.max_mm[moved] <= 0.005)


def test_tighter_out_refuses_what_it_cannot_write(tmp_path: Path) -> None:
    jsdc = REPO / "samples" / "jsdc.gcode"  # a grbl program: no G64 P to write
    res = _cli("simulate", jsdc, "--profile", PROFILE, "--tighter-out", tmp_path / "j.gcode")
    assert res.exit_code == 1 and "grbl program" in cli_output(res)
    assert not (tmp_path / "j.gcode").exists()
    res = _cli("simulate", OWN / "square.ngc", "--profile", PROFILE, "--corners", "0", "--tighter-out",
               tmp_path / "s.ngc")
    assert res.exit_code == 2 and "--corners" in cli_output(res)


@pytest.mark.linuxcnc
@pytest.mark.skipif(shutil.which("rs274") is None, reason="LinuxCNC's interpreter rs274 is not installed (Debian:"
                    " apt-get install linuxcnc-uspace): cannot check that LinuxCNC reads the tighter G64 P")
def test_linuxcnc_reads_the_tighter_tolerance_and_the_programs_own_after_it(tmp_path: Path) -> None:
    out = tmp_path / "square-tight.ngc"
    res = _cli("simulate", OWN / "square.ngc", "--profile", PROFILE, "--tighter-out", out)
    assert res.exit_code == 0, cli_output(res)
    run = subprocess.run(["rs274", "-g", str(out)], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and "error" not in (run.stderr + run.stdout).lower(), run.stderr[-2000:]
    modes = re.findall(r"SET_MOTION_CONTROL_MODE\(CANON_CONTINUOUS, ([0-9.]+)\)", run.stdout)
    naive = re.findall(r"SET_NAIVECAM_TOLERANCE\(([0-9.]+)\)", run.stdout)
    # the program's G64 P0.05 Q0, the tighter P0.025 (with the program's Q0) before line 4, its own after line 7
    assert modes == ["0.050000", "0.025000", "0.050000"] and naive == ["0.0000"] * 3
    feeds = re.findall(r"STRAIGHT_FEED\(([-0-9.]+), ([-0-9.]+), ([-0-9.]+)", run.stdout)
    orig = subprocess.run(["rs274", "-g", str(OWN / "square.ngc")], capture_output=True, text=True, timeout=60)
    assert feeds == re.findall(r"STRAIGHT_FEED\(([-0-9.]+), ([-0-9.]+), ([-0-9.]+)", orig.stdout)  # the same moves

"""Settles (learning.refine.settle): a dwell before the first feed after a rapid where the axes still lag the rapid."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.learning.learner import refine_for_learning
from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.program.insert import MARKER, insert_points
from ilcnc.program.model import MOVE_RAPID
from ilcnc.vcnc.settle import settle_time_s

from .conftest import OWN, REPO, with_refine

LCNC = REPO / "configs" / "linuxcnc-sim.yaml"
MILL = REPO / "configs" / "example-mill.yaml"
COMPASS = REPO / "samples" / "compass.ngc"
runner = CliRunner()


def _run(*args: object) -> tuple[int, str]:
    res = runner.invoke(app, [str(a) for a in args])
    return res.exit_code, res.stdout


def test_the_settle_is_the_tail_of_the_drive_models_step() -> None:
    # linuxcnc-sim's drives: first order, tau 27.851 ms, dead time 4.997 ms: a lag settles from e0 to e in
    # delay + tau ln(e0/e); the sampled model holds the dead time to whole periods and the result is rounded up to
    # one: within two periods of the closed form
    prof = load_profile(LCNC)
    d = prof.axes["x"].drive
    lags = np.array([0.0001, 0.0002, 0.01, 0.16, 0.5])
    got = settle_time_s(prof, lags, 0.0002)
    want = [0.0 if e <= 0.0002 else d.delay_s + d.time_constant_s * math.log(e / 0.0002) for e in lags]
    assert got[:2].tolist() == [0.0, 0.0]
    assert np.all(np.abs(got[2:] - want[2:]) <= 2 * prof.machine.servo_period_s), (got, want)
    assert np.all(np.diff(got) >= 0)
    assert np.allclose(got / prof.machine.servo_period_s, np.round(got / prof.machine.servo_period_s))


def test_compass_gets_a_settle_before_each_feed_after_a_rapid() -> None:
    """On LinuxCNC's planner (no in-position wait) compass's four plunges start while the axes still lag the
    rapid by 127-160 µm (the first run, virtual); each gets a dwell, written before the plunge's line and its
    inserted points, and the refined program still runs the original path with the dwells planned."""
    prof = load_profile(LCNC)
    prog = read_program(COMPASS)
    ref = refine_for_learning(prog, prof)
    mv = prog.moves
    after_rapid = [j for j in range(1, len(mv)) if mv.kind[j - 1] == MOVE_RAPID and mv.kind[j] != MOVE_RAPID]
    assert sorted(ref.plan.settles) == after_rapid and len(after_rapid) == 4
    peaks = {s.line: s.peak_mm for s in ref.plan.sites if s.kind == "rapid"}
    for j, secs in ref.plan.settles.items():
        assert secs == pytest.approx(float(settle_time_s(prof, peaks[int(mv.line[j - 1])], ref.plan.threshold_mm)[0]))
        assert 0.15 < secs < 0.25  # 127-160 µm down to 0.2 µm: about 7 time constants
    assert ref.inserted.settled == {j: pytest.approx(math.ceil(round(t * 1000, 6)) / 1000) for j, t in
                                    ref.plan.settles.items()}
    new = ref.program.text.splitlines()
    old = prog.text.splitlines()
    for j in after_rapid:
        feed = old[int(mv.line[j]) - 1]
        at = new.index(feed)
        k = at - 1
        while MARKER in new[k] and not new[k].startswith("G4"):
            k -= 1  # the plunge's own inserted points come after the settle
        assert new[k] == f"G4 P{ref.inserted.settled[j]:.3f} ({MARKER})", new[k - 1:at + 1]
    # every original line, in order; only marked lines added
    it = iter(new)
    assert all(any(line == x for x in it) for line in old)
    assert len(new) - len(old) == ref.inserted.n_inserted + len(after_rapid)
    assert all(MARKER in x for x in set(new) - set(old))
    # the refined program stands still before each plunge for its settle, the moves otherwise as planned
    nv = ref.program.moves
    assert np.count_nonzero(nv.dwell_s) == 4
    assert sorted(nv.dwell_s[nv.dwell_s > 0].tolist()) == sorted(ref.inserted.settled.values())
    t0, t1 = ref.cycle_time_s
    total = sum(ref.inserted.settled.values())
    assert t1 - t0 == pytest.approx(total, abs=0.005 * t0), (t0, t1, total)
    assert ref.to_json()["settles"] == 4


def test_settles_stay_within_their_budget_and_can_be_switched_off() -> None:
    prof = load_profile(LCNC)
    prog = read_program(COMPASS)
    full = refine_for_learning(prog, prof)
    t0 = full.cycle_time_s[0]
    # a budget for the two largest lags only (each ~0.2 s of a 574 s program)
    two = sorted(full.plan.settles.values(), reverse=True)[:2]
    pct = 100.0 * (sum(two) + 0.001) / t0
    part = refine_for_learning(prog, with_refine(prof, settle_budget_pct=pct))
    assert len(part.plan.settles) == 2 and part.plan.passed["settle beyond settle_budget_pct"] == 2
    biggest = sorted((s.peak_mm, s.settle_s) for s in full.plan.sites if s.kind == "rapid")[-2:]
    assert sorted(s.settle_s for s in part.plan.sites if s.settle_s > 0) == sorted(t for _, t in biggest)
    off = refine_for_learning(prog, with_refine(prof, settle="off"))
    assert not off.plan.settles and not off.inserted.settled and "G4" not in off.program.text
    assert off.program.text == insert_points(prog, off.plan.points, min_decimals=prof.min_decimals("mm")).text
    # the example mill checks in-position after every rapid: no lag is left, no settle is planned
    mill = refine_for_learning(prog, load_profile(MILL))
    assert not mill.plan.settles and "G4" not in mill.program.text


def test_a_klartext_settle_is_cycle_9_and_renumbers_the_blocks() -> None:
    prog = read_program(OWN / "square.h")
    j = 2  # L Z+0.000 F1000, after the FMAX moves
    assert prog.moves.kind[j - 1] == MOVE_RAPID and prog.moves.kind[j] != MOVE_RAPID
    res = insert_points(prog, {}, min_decimals=3, settles={j: 0.1234})
    lines = res.text.splitlines()
    assert lines[7:10] == ["7 CYCL DEF 9.0 DWELL TIME ; ilcnc refine", "8 CYCL DEF 9.1 DWELL 0.124 ; ilcnc refine",
                           "9 L Z+0.000 F1000"]
    assert res.renumbered and res.settled == {j: 0.124} and lines[-1].startswith("16 END PGM")
    again = read_program(prog.path, data=res.text.encode("latin-1"))
    assert again.moves.dwell_s[j] == pytest.approx(0.124) and np.count_nonzero(again.moves.dwell_s) == 1
    assert np.array_equal(again.moves.end_mm, prog.moves.end_mm)


def test_a_settle_in_text_that_runs_twice_is_left_alone(tmp_path: Path) -> None:
    src = tmp_path / "sub.ngc"
    src.write_text("G21 G90\no100 sub\nG0 X0 Y0\nG1 X10 F600\no100 endsub\no100 call\no100 call\nM2\n")
    prog = read_program(src)
    res = insert_points(prog, {}, min_decimals=3, settles={1: 0.2})
    assert not res.settled and res.text == prog.text
    assert [s.reason for s in res.skipped] == ["settle: text executed more than once (loop, subprogram, label call)"]


def test_the_measured_workflow_settles_from_the_log_and_the_plunges_stop_lagging(tmp_path: Path) -> None:
    """compass on linuxcnc-sim (the virtual CNC standing in for LinuxCNC): refined from the log of the original,
    the output settles before each plunge; its run no longer starts the plunges while the axes lag the rapid."""
    state = tmp_path / "state"
    code, msg = _run("simulate", COMPASS, "--profile", LCNC, "--log-out", tmp_path / "run0.csv", "--json")
    assert code == 0, msg
    code, msg = _run("learn", COMPASS, "--profile", LCNC, "--log", tmp_path / "run0.csv", "--state", state,
                     "--out", tmp_path / "p1.ngc", "--refine", "--json")
    assert code == 0, msg
    first = json.loads(msg)
    assert first["refined"]["settles"] == 4
    assert any("settle" in n for n in first["notes"]), first["notes"]
    text = (tmp_path / "p1.ngc").read_text()
    assert sum(x.startswith("G4 P") and MARKER in x for x in text.splitlines()) == 4
    code, msg = _run("simulate", tmp_path / "p1.ngc", "--profile", LCNC, "--against", COMPASS, "--json")
    assert code == 0, msg
    after = json.loads(msg)
    before = first["iterations"][0]["contour_error_mm"]
    # the first iteration's figures are the log's own (the settle windows are left out of the update, not of them)
    code, msg = _run("simulate", COMPASS, "--profile", LCNC, "--json")
    assert code == 0, msg
    orig = json.loads(msg)
    assert before["max"] == pytest.approx(orig["contour_error_mm"]["max"], rel=1e-3)
    # measured: the cutting max was the lag at a plunge (162.9 µm, after the rapid on line 453); settled and one
    # step learned, the max is 58.1 µm at a corner LinuxCNC's G64 without P rounds (line 761), no plunge
    assert after["contour_error_mm"]["max"] < 0.5 * before["max"], (before, after["contour_error_mm"])
    lines = text.splitlines()
    worst = after["worst"]["line"]
    assert not any(x.startswith("G4") for x in lines[max(worst - 8, 0):worst]), lines[worst - 8:worst]
    assert after["cycle_time_s"] < orig["cycle_time_s"] * 1.005  # 574.51 -> 576.23 s: settles 0.76 s, the step 1 s

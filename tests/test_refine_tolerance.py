"""Refinement's tighter tolerance (learning.refine.tolerance): G64 P where the first run's error is the planner's rounding."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.errors import ProfileError
from ilcnc.learning.learner import refine_for_learning
from ilcnc.learning.refine_tolerance import MARGIN
from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.program.insert import MARKER, inserted_moves, same_moves
from ilcnc.shop.state import LearnState
from ilcnc.vcnc.plan import planned_duration_s
from ilcnc.vcnc.rounding import planner_rounding

from .conftest import OWN, REPO, with_refine

MILL = REPO / "configs" / "example-mill.yaml"
COMPASS = REPO / "samples" / "compass.ngc"
JSDC = REPO / "samples" / "jsdc.gcode"
runner = CliRunner()


def _run(*args: object) -> tuple[int, str]:
    res = runner.invoke(app, [str(a) for a in args])
    return res.exit_code, res.output


def _tol_lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if MARKER in ln and "G64" in ln]


@pytest.fixture(scope="module")
def compass_refined():
    prof = with_refine(load_profile(MILL), tolerance="on")
    prog = read_program(COMPASS)
    return prog, prof, refine_for_learning(prog, prof)


def test_the_chosen_corners_are_rounded_within_the_tighter_tolerance_and_the_budget(compass_refined) -> None:
    """compass on the example mill: its first run's cutting max is 13.32 µm, mostly the planner's rounding within
    the profile's 10 µm at its corners. The corners above half of it (6.66 µm) whose error is mostly rounding get
    G64 P at learning.refine.tolerance_share (0.5) of that target, 3.3 µm (the word rounded down to 0.1 µm); planned,
    they are rounded within it, and
    the refined program costs what was planned, within learning.refine.tolerance_budget_pct."""
    _prog, prof, ref = compass_refined
    tol = ref.tolerance
    assert tol is not None and tol.written is not None and len(tol.corners) > 0
    first_max = 2.0 * tol.target_mm
    share = prof.learning.refine.tolerance_share
    assert tol.tolerance_mm == pytest.approx(np.floor(share * 0.5 * first_max * 1e4) / 1e4, abs=1e-12)  # word grid
    assert tol.tolerance_mm >= 2 * prof.machine.resolution_mm
    room = tol.target_mm - tol.tolerance_mm  # the lag the target leaves room for beside the tighter tolerance
    for c in tol.corners:
        assert c.rounding_mm + min(c.rest_mm, room) > MARGIN * tol.target_mm
        assert c.rounding_mm >= 0.5 * c.max_mm and c.rounding_mm > tol.tolerance_mm
    lines = _tol_lines(ref.program.text)
    assert len(lines) == 2 * len(tol.written.ranges) == tol.summary()["inserted_lines"]
    word = f"G64 P{tol.tolerance_mm:g} ({MARKER}"
    assert sum(ln.startswith(word) for ln in lines) == len(tol.written.ranges)
    # the refined program without the marked G64 lines is the one with the points alone: the same moves bit for bit
    pointed = read_program(COMPASS, data="\n".join(ln for ln in ref.program.text.split("\n")
                                                  if ln not in set(lines)).encode("latin-1"))
    assert same_moves(pointed, ref.program)
    # the tolerance where intended: the tightened moves have it, every other keeps its own (compass sets none:
    # after each range the profile's tolerance comes back as G64 P, as simulate --tighter-out writes it)
    a, b = pointed.moves.blend_tol_mm, ref.program.moves.blend_tol_mm
    tight = b == tol.tolerance_mm
    assert np.all(np.isnan(a)) and tight.sum() >= len(tol.corners)
    assert np.all(np.isnan(b[~tight]) | (b[~tight] == prof.planner.corner_tolerance_mm))
    # the chosen corners (vertex e of the original: the end of move e - 1, the move the points precede) planned
    # within the tighter tolerance; the planner never rounds beyond its tolerance (tests/test_rounding.py), the
    # 1e-9 mm is the float noise of a distance of numbers near 100 mm
    own = np.flatnonzero(~inserted_moves(ref.program))
    at = np.array([own[c.vertex - 1] + 1 for c in tol.corners])
    r0, r1 = planner_rounding(pointed, prof).max_mm, planner_rounding(ref.program, prof).max_mm
    assert np.all(r1[at] <= tol.tolerance_mm + 1e-9) and np.all(r0[at] > tol.tolerance_mm)
    # elsewhere the plan rounds no more than before, within half a resolution step (the restored G64 P is a
    # programmed tolerance, which LinuxCNC also bounds by a quarter of the move: measured 0.40 µm at most)
    ok = np.isfinite(r0)
    assert np.array_equal(ok, np.isfinite(r1))
    assert np.all(r1[ok] <= r0[ok] + 0.5 * prof.machine.resolution_mm)
    # the cycle time: what the plan said (the quarter-move bound costs < 0.01 %), within the budget
    t_points, t_refined = planned_duration_s(pointed, prof), planned_duration_s(ref.program, prof)
    assert t_points == pytest.approx(ref.cycle_time_s[0], rel=1e-12)  # points alone plan as the original
    assert t_refined == pytest.approx(ref.cycle_time_s[1], rel=1e-12)
    assert tol.spent_s == pytest.approx(t_refined - t_points, rel=1e-9)
    assert 0 < tol.spent_s <= prof.learning.refine.tolerance_budget_pct / 100 * ref.cycle_time_s[0]
    assert abs(tol.spent_s / ref.cycle_time_s[0] * 100 - tol.tightening.extra_pct) < 0.01
    js = ref.to_json()["tolerance"]
    assert js["corners"] == len(tol.corners) and js["tolerance_mm"] == tol.tolerance_mm
    assert any("G64 P" in n and "corner" in n for n in ref.notes())


def test_off_by_default_and_refine_is_unchanged(compass_refined) -> None:
    """Without the option the refined program is the one with points and settles alone, byte for byte."""
    prog, prof, ref = compass_refined
    assert load_profile(MILL).learning.refine.tolerance == "off"
    plain = refine_for_learning(prog, with_refine(prof, tolerance="off"))
    assert plain.tolerance is None and "tolerance" not in plain.to_json()
    lines = set(_tol_lines(ref.program.text))
    assert plain.program.text == "\n".join(ln for ln in ref.program.text.split("\n") if ln not in lines)


def test_a_corner_whose_line_sets_the_programs_own_path_control_is_left_alone(compass_refined, tmp_path: Path) -> None:
    """As simulate --tighter-out leaves such a range out: a G64 P written after it would undo the program's."""
    prog, prof, ref = compass_refined
    worst = ref.tolerance.corners[0]
    line = int(prog.moves.line[worst.vertex - 1])
    text = prog.text.split("\n")
    text[line - 1] = text[line - 1].rstrip("\r") + " G64 P0.01"  # the program's own, on the corner's move
    src = tmp_path / "compass-own.ngc"
    src.write_bytes("\n".join(text).encode("latin-1"))
    own = read_program(src)
    ref2 = refine_for_learning(own, prof)
    tol = ref2.tolerance
    assert tol.passed.get("the program sets its own path control on that line", 0) >= 1
    assert all(int(own.moves.line[c.vertex - 1]) != line for c in tol.corners)
    assert any("sets its own path control" in n for n in ref2.notes())


def test_the_path_control_lines_survive_every_iteration_and_export(tmp_path: Path) -> None:
    prof = tmp_path / "mill.yaml"
    data = yaml.safe_load(MILL.read_text())
    data["learning"].setdefault("refine", {})["tolerance"] = "on"
    prof.write_text(yaml.safe_dump(data))
    out = tmp_path / "compass.ilc.ngc"
    code, msg = _run("learn", COMPASS, "--profile", prof, "--out", out, "--refine", "--iterations", "2", "--json")
    assert code == 0, msg
    js = json.loads(msg)["refined"]["tolerance"]
    assert js["corners"] > 0 and js["inserted_lines"] > 0
    st = LearnState.load(tmp_path / "compass.ilc.ngc.state")
    refined = st.file(st.part["refined"]["file"]).read_text(encoding="latin-1")
    want = _tol_lines(refined)
    assert len(want) == js["inserted_lines"]
    for e in st.iterations:  # every iteration carries them, unchanged and in place
        text = st.file(e.program).read_text(encoding="latin-1")
        assert _tol_lines(text) == want
        assert [i for i, ln in enumerate(text.splitlines()) if ln in want] == \
            [i for i, ln in enumerate(refined.splitlines()) if ln in want]
        code, msg = _run("export", COMPASS, "--out", tmp_path / f"e{e.iteration}.ngc", "--state", st.directory,
                         "--iteration", e.iteration)
        assert code == 0, msg
        assert (tmp_path / f"e{e.iteration}.ngc").read_bytes() == st.file(e.program).read_bytes()
    assert _tol_lines(out.read_text(encoding="latin-1")) == want
    # judged against the original drawing like any refined output
    code, msg = _run("simulate", out, "--profile", prof, "--against", COMPASS, "--json")
    assert code == 0, msg


def test_klartext_gets_cycle_32_in_numbered_blocks() -> None:
    """square.h: cycle 32 with T before the range, cycle 32 without T (the machine's tolerance) after it, each in
    two blocks marked like the points; every block after them renumbered, consecutive; re-read, the tightened
    moves run within T and the others as before (the writer checks it; asserted here again on the text)."""
    prof = with_refine(load_profile(MILL), tolerance="on")
    prog = read_program(OWN / "square.h")
    ref = refine_for_learning(prog, prof)
    tol = ref.tolerance
    assert tol.written is not None and len(tol.written.ranges) == 1 and len(tol.corners) >= 1
    lines = ref.program.text.splitlines()
    t = f"{tol.tolerance_mm:g}"
    cyc = [ln for ln in lines if "CYCL DEF 32" in ln]
    assert [ln.split(" ", 1)[1].split(" ;")[0] for ln in cyc] == [
        "CYCL DEF 32.0 TOLERANCE", f"CYCL DEF 32.1 T{t}", "CYCL DEF 32.0 TOLERANCE", "CYCL DEF 32.1"]
    assert all(ln.endswith(("corners rounded within 2.3 um", "the program's own path control again")) and
               f"; {MARKER}: " in ln for ln in cyc)
    assert [int(ln.split(" ", 1)[0]) for ln in lines] == list(range(len(lines)))  # block numbers 0, 1, 2, ...
    mv = ref.program.moves
    inside = (mv.line > lines.index(cyc[1]) + 1) & (mv.line < lines.index(cyc[2]) + 1)
    assert inside.sum() >= 2 and np.all(mv.blend_tol_mm[inside] == tol.tolerance_mm)
    assert np.all(np.isnan(mv.blend_tol_mm[~inside]))  # the program sets none: the machine's, before and after


def test_klartext_corners_next_to_rnd_or_chf_are_left_alone() -> None:
    """contour.h: the control holds the move before RND / CHF until that block; cycle 32 between them would
    apply to other moves than their lines say, so those corners are left alone and counted."""
    prof = with_refine(load_profile(MILL), tolerance="on")
    ref = refine_for_learning(read_program(OWN / "contour.h"), prof)
    assert ref.tolerance.passed.get("next to a rounding, chamfer, approach or departure (RND / CHF / APPR / DEP)", 0) >= 1


def test_grbl_is_left_alone_with_its_reason() -> None:
    """jsdc is a grbl program: grbl sets its corner tolerance in its settings ($11), not per line."""
    prof = with_refine(load_profile(MILL), tolerance="on")
    ref = refine_for_learning(read_program(JSDC), prof)
    assert ref.tolerance is not None and ref.tolerance.written is None and not _tol_lines(ref.program.text)
    assert any("a grbl program" in k for k in ref.tolerance.passed)


@pytest.mark.parametrize(("key", "value", "words"), [
    ("tolerance_share", 1.5, "must be > 0 and <= 1, got 1.5"),
    ("tolerance_share", 0, "must be > 0 and <= 1, got 0"),
    ("tolerance_budget_pct", 11, "must be >= 0 and <= 10, got 11"),
    ("tolerance", "maybe", "maybe"),
])
def test_an_option_out_of_range_is_one_line_naming_it(tmp_path: Path, key: str, value: object, words: str) -> None:
    data = yaml.safe_load(MILL.read_text())
    data["learning"].setdefault("refine", {})[key] = value
    p = tmp_path / "mill.yaml"
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(ProfileError) as info:
        load_profile(p)
    msg = str(info.value)
    assert "\n" not in msg and f"learning.refine.{key}" in msg and words in msg and str(p) in msg


def test_moved_names_keep_their_old_import_path() -> None:
    """The writer moved from ilcnc.shop.corners to ilcnc.vcnc.tighten and path_settings to ilcnc.program.path_control:
    the old paths still give the same objects (the two that are no longer imported there, with a warning)."""
    import ilcnc.program.path_control as pc
    import ilcnc.shop.corners as corners
    import ilcnc.shop.linuxcnc_prepare as prepare
    import ilcnc.vcnc.tighten as tighten

    assert prepare.path_settings is pc.path_settings and prepare.PathSetting is pc.PathSetting
    assert corners.tightened_text is tighten.tightened_text and corners.Tightening is tighten.Tightening
    for name in ("TIGHTER_MARKER", "TighterRange"):
        with pytest.warns(DeprecationWarning, match=f"moved to ilcnc.vcnc.tighten.{name}"):
            assert getattr(corners, name) is getattr(tighten, name)
    with pytest.raises(AttributeError):
        _ = corners.no_such_name

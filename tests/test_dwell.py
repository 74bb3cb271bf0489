"""Dwells on the virtual CNC: G-code ``G4 P`` and the drilling cycles' bottom dwell, Klartext cycle 9 and
``FUNCTION DWELL``, read into ``MoveTable.dwell_s`` / ``Program.trailing_dwell_s`` and planned as a stand-still by
both planners (ilcnc's filter planner on configs/example-mill.yaml, LinuxCNC 2.9's on configs/linuxcnc-sim.yaml).

Sample counts are integers, so the figures here are exact: a dwell of P seconds at a 1 ms servo period is
round(P / 0.001) samples, and every comparison is between two plans whose other samples are the same.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from ilcnc.errors import UnsupportedError
from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.program.gcode import read_gcode
from ilcnc.program.heidenhain import read_heidenhain
from ilcnc.vcnc import plan
from ilcnc.vcnc.plan import PlanLimits, plan_chunks, plan_program, planned_duration_s, planned_move_times_s

from .conftest import REPO, SAMPLES

PROFILES = {name: load_profile(REPO / "configs" / name) for name in ("example-mill.yaml", "linuxcnc-sim.yaml")}


def _hold(profile) -> int:
    """In-position samples the profile's planner stands still before a dwell: the filter planner's in-position
    wait (example-mill: 0.1 s = 100 samples); none on LinuxCNC's (its task starts the dwell when motion is done)."""
    if profile.planner.profile == "linuxcnc":
        return 0
    return max(3, int(np.ceil(profile.planner.in_position_s / profile.machine.servo_period_s)))


def _gcode(p_after_rapid: float | None, p_between_feeds: float | None, tail: str = "") -> object:
    """A rapid, a plunge and three feeds; ``G4 P`` after the rapid and between the first two feeds."""
    lines = ["G21 G90 G17 G64", "G0 X0 Y0 Z5", "G0 X10 Y0 Z5"]
    if p_after_rapid is not None:
        lines.append(f"G4 P{p_after_rapid}")
    lines += ["G1 Z0 F600", "G1 X40 F1200"]
    if p_between_feeds is not None:
        lines.append(f"G4 P{p_between_feeds}")
    lines += ["G1 X40 Y30", "G1 X0 Y30", tail, "M2", ""]
    return read_gcode(Path("dwell.ngc"), "\n".join(lines).encode())


def _still_at(ref, point_mm) -> tuple[int, np.ndarray]:
    """Samples at ``point_mm`` (within 1 nm) that repeat the sample before them bit for bit: the stand-still."""
    pos = ref.pos_mm
    near = np.all(np.abs(pos - np.asarray(point_mm)) <= 1e-6, axis=1)
    same = np.concatenate(([False], np.all(pos[1:] == pos[:-1], axis=1)))
    idx = np.flatnonzero(near & same)
    return idx.size, idx


def test_g4_is_read_into_the_move_after_it() -> None:
    prog = _gcode(0.5, 0.25)
    mv = prog.moves
    assert mv.dwell_s.tolist() == [0.0, 0.0, 0.5, 0.0, 0.25, 0.0]
    assert mv.line[mv.dwell_s > 0].tolist() == [5, 8]  # the G1 after each G4
    assert prog.trailing_dwell_s == 0.0
    # two G4 in a row add up; after the last move they are the program's trailing dwell
    two = _gcode(None, None, tail="G4 P0.5\nG4 P1.25")
    assert two.moves.dwell_s.sum() == 0.0 and two.trailing_dwell_s == 1.75


@pytest.mark.parametrize("profile", list(PROFILES))
def test_the_reference_stands_still_for_the_dwell(profile: str) -> None:
    prof = PROFILES[profile]
    ref = plan_program(_gcode(0.5, 0.5), prof)
    hold = _hold(prof)
    for point, before in (([10.0, 0.0, 5.0], 1), ([40.0, 0.0, 0.0], 3)):
        n, idx = _still_at(ref, point)
        # 500 samples of dwell at 1 kHz after the stop and the in-position wait, in one run
        assert n == 500 + hold, point
        assert np.all(np.diff(idx) == 1)
        # they belong to the move that ends there (as LinuxCNC's log reads them: program-line 0, carried forward)
        assert set(ref.move[idx].tolist()) == {before}
        assert ref.move[idx[-1] + 1] == before + 1
    # three times the dwell: 1000 samples more at each, nothing else changes
    longer = plan_program(_gcode(1.5, 1.5), prof)
    assert longer.n_samples - ref.n_samples == 2000
    assert _still_at(longer, [40.0, 0.0, 0.0])[0] == 1500 + hold


@pytest.mark.parametrize("profile", list(PROFILES))
def test_a_dwell_where_the_planner_stops_anyway_adds_just_its_time(profile: str) -> None:
    prof = PROFILES[profile]
    # both planners stop between a rapid and a feed move (example-mill also waits in position there)
    bare = plan_program(_gcode(None, None), prof)
    dwelt = plan_program(_gcode(0.5, None), prof)
    assert dwelt.n_samples - bare.n_samples == 500
    assert planned_duration_s(_gcode(0.5, None), prof) == dwelt.duration_s
    # the time is counted on the rapid before the dwell; on LinuxCNC's planner the sample where the rapid stops,
    # which is the next move's without a dwell (its first period is already its), is the rapid's too
    t0, _ = planned_move_times_s(_gcode(None, None), prof)
    t1, _ = planned_move_times_s(_gcode(0.5, None), prof)
    step = 1 if prof.planner.profile == "linuxcnc" else 0
    assert np.rint((t1 - t0) / prof.machine.servo_period_s).astype(int).tolist() == [0, 500 + step, -step, 0, 0, 0]


@pytest.mark.parametrize("profile", list(PROFILES))
def test_a_dwell_between_feeds_stops_the_blend(profile: str) -> None:
    prof = PROFILES[profile]
    blended = plan_program(_gcode(None, None), prof)
    dwelt = plan_program(_gcode(None, 0.5), prof)
    # without the dwell the corner at (40, 0, 0) is blended: the reference passes it, never stands there
    assert _still_at(blended, [40.0, 0.0, 0.0])[0] == 0
    # with it the axes stop, wait in position, then dwell: longer than the dwell alone
    assert dwelt.n_samples - blended.n_samples > 500 + _hold(prof)


@pytest.mark.parametrize("profile", list(PROFILES))
def test_a_trailing_dwell_ends_the_reference_standing_still(profile: str) -> None:
    prof = PROFILES[profile]
    bare = plan_program(_gcode(None, None), prof)
    tail = plan_program(_gcode(None, None, tail="G4 P0.75"), prof)
    assert tail.n_samples - bare.n_samples == 750 + _hold(prof)
    assert np.array_equal(tail.pos_mm[:bare.n_samples], bare.pos_mm)
    assert np.all(tail.pos_mm[bare.n_samples:] == bare.pos_mm[-1])
    assert np.all(tail.move[bare.n_samples:] == bare.move[-1])


@pytest.mark.parametrize("profile", list(PROFILES))
def test_chunks_with_dwells_are_the_whole_plan(profile: str) -> None:
    """plan_chunks (the streamed run) and plan_program give the same samples with dwells: a leading one, one after a
    rapid, one between feeds, a trailing one; chunks of 1024 samples cut through groups and stand-stills."""
    prof = PROFILES[profile]
    text = _gcode(0.5, 0.25, tail="G4 P0.3").text.replace("G0 X0 Y0 Z5", "G4 P0.2\nG0 X0 Y0 Z5")
    prog = read_gcode(Path("dwell.ngc"), text.encode())
    assert prog.moves.dwell_s[0] == 0.2 and prog.trailing_dwell_s == 0.3
    ref = plan_program(prog, prof)
    chunks = list(plan_chunks(prog, prof, chunk_samples=1024))
    assert len(chunks) >= 5
    for col in ("pos_mm", "move", "command", "line"):
        assert np.array_equal(np.concatenate([getattr(c, col) for c in chunks]), getattr(ref, col)), col
    assert planned_duration_s(prog, prof) == ref.duration_s
    # the leading dwell: 200 samples at the start before any move (-1), no in-position wait (at rest already)
    assert np.all(ref.move[:201] == -1) and ref.move[201] == 0
    assert np.all(ref.pos_mm[:201] == prog.moves.start_mm[0])


def test_compiled_planner_equals_numpy_path_with_dwells() -> None:
    prof = PROFILES["example-mill.yaml"]
    prog = _gcode(0.5, 0.25, tail="G4 P0.3")
    pl = prof.planner
    args = (prog.moves, PlanLimits.from_profile(prof), prof.machine.servo_period_s, pl.profile, pl.corner_tolerance_mm,
            pl.jerk_time_constant_s, pl.in_position_s, 12)
    a = plan._plan(*args, kernel=False, trailing_dwell_s=0.3)
    b = plan._plan(*args, kernel=True, trailing_dwell_s=0.3)
    assert np.array_equal(a.pos_mm, b.pos_mm) and np.array_equal(a.move, b.move)
    assert np.array_equal(a.pos_mm, plan_program(prog, prof).pos_mm)


@pytest.mark.parametrize("code", ["G82", "G86", "G89"])
def test_drilling_cycles_dwell_at_the_bottom_of_each_hole(code: str) -> None:
    prog = read_gcode(Path("drill.ngc"), f"G21 G90 G17 G99\nG0 X0 Y0 Z10\n{code} X5 Y5 Z-3 R2 P0.4 F300\nX15\n"
                                          "G80\nM2\n".encode())
    mv = prog.moves
    bottom = np.flatnonzero(np.isclose(mv.end_mm[:, 2], -3.0))
    assert bottom.size == 2  # two holes
    # the move that leaves the bottom carries the dwell, nothing else does
    assert np.flatnonzero(mv.dwell_s).tolist() == (bottom + 1).tolist()
    assert np.all(mv.dwell_s[bottom + 1] == 0.4)
    for prof in PROFILES.values():
        ref = plan_program(prog, prof)
        assert _still_at(ref, mv.end_mm[bottom[0]])[0] == 400 + _hold(prof)


def test_fanuc_dwell_words() -> None:
    """Fanuc: ``G04 X`` is seconds (X is then no axis word), ``G04 P`` without a decimal point milliseconds, as
    ilcnc.program.carry reads them; LinuxCNC and grbl: ``P`` seconds."""
    fanuc = read_gcode(Path("f.nc"), b"G21 G90\nG0 X0 Y0\nG04 X1.5\nG1 X10 F100\nG04 P250\nG1 X20\nM30\n",
                       dialect="fanuc")
    assert fanuc.moves.dwell_s.tolist() == [0.0, 1.5, 0.25]
    assert fanuc.moves.end_mm[:, 0].tolist() == [0.0, 10.0, 20.0]  # the X of G04 moved nothing
    lcnc = read_gcode(Path("l.ngc"), b"G21 G90\nG0 X0 Y0\nG4 P250\nG1 X10 F100\nM2\n")
    assert lcnc.moves.dwell_s.tolist() == [0.0, 250.0]


def test_g4_p_from_a_parameter_is_evaluated() -> None:
    prog = read_gcode(Path("p.ngc"), b"G21 G90\n#1=0.125\nG0 X0 Y0\nG4 P[#1*2]\nG1 X10 F100\nM2\n")
    assert prog.moves.dwell_s.tolist() == [0.0, 0.25]


@pytest.mark.parametrize(("block", "problem"), [("G4 P-0.5", "G4 dwell with a negative time P-0.5"),
                                                ("G4", "G4 dwell without a P word"),
                                                ("#2=-1\nG4 P#2", "G4 dwell with a negative time P-1"),
                                                ("G82 X1 Y1 Z-1 R1 F100", "G82 without a P word")])
def test_a_bad_dwell_is_one_line_naming_file_and_line(tmp_path: Path, block: str, problem: str) -> None:
    src = tmp_path / "bad.ngc"
    src.write_text(f"G21 G90\nG0 X0 Y0 Z5\n{block}\nG1 X10 F100\nM2\n")
    prog = read_program(src)
    with pytest.raises(UnsupportedError) as exc:
        prog.require_complete()
    msg = exc.value.format()
    line = 3 + block.count("\n")
    assert "\n" not in msg and msg.startswith(f"{src}:{line}: ") and problem in msg


KLARTEXT = """0 BEGIN PGM DWELL MM
1 BLK FORM 0.1 Z X+0 Y+0 Z-20
2 BLK FORM 0.2 X+100 Y+100 Z+0
3 TOOL CALL 1 Z S3000
4 L X+0 Y+0 Z+5 R0 FMAX
5 L X+10 FMAX
6 CYCL DEF 9.0 DWELL TIME
7 CYCL DEF 9.1 DWELL {p}
8 L Z+0 F600
9 L X+40 F1200
10 FUNCTION DWELL TIME 0.25
11 L Y+30
12 L X+0
13 CYCL DEF 9.0 DWELL TIME
14 CYCL DEF 9.1 DWELL 0.1
15 END PGM DWELL MM
"""


def _klartext(p: float) -> object:
    return read_heidenhain(Path("dwell.h"), KLARTEXT.format(p=p).encode())


def test_klartext_cycle_9_and_function_dwell() -> None:
    prog = _klartext(0.5)
    prog.require_modelled()
    mv = prog.moves
    assert np.flatnonzero(mv.dwell_s).tolist() == [2, 4]
    assert mv.line[[2, 4]].tolist() == [9, 12]  # file lines: block 0 is line 1
    assert mv.dwell_s[[2, 4]].tolist() == [0.5, 0.25]
    assert prog.trailing_dwell_s == 0.1
    for prof in PROFILES.values():
        ref = plan_program(prog, prof)
        assert _still_at(ref, [10.0, 0.0, 5.0])[0] == 500 + _hold(prof)
        assert plan_program(_klartext(1.5), prof).n_samples - ref.n_samples == 1000


def test_klartext_negative_dwell_stops_with_its_line() -> None:
    prog = read_heidenhain(Path("neg.h"), KLARTEXT.format(p="-1").encode())
    with pytest.raises(UnsupportedError) as exc:
        prog.require_complete()
    assert exc.value.format() == "neg.h:8: cycle 9 DWELL TIME with a negative dwell time -1"


_G4_LINE = re.compile(rb"(?im)^[ \t]*G0?4[ \t]*P([0-9.]+)[ \t]*\r?$")


@pytest.mark.parametrize(("name", "extra_holds"), [
    # grbl job (also ../shared/samples/gcode): G4 P0.5 and P7 before its first move, two G4 P7 after its last
    ("gcode/KB-219 test.gcode", 1),
    # LinuxCNC's daisy.ngc (also ../shared/samples/interp): G4P2 between a rapid and a feed, and between the last feed and a rapid
    ("interp/daisy.ngc", 0),
])
@pytest.mark.parametrize("profile", list(PROFILES))
def test_a_real_programs_planned_time_includes_its_dwells(name: str, extra_holds: int, profile: str) -> None:
    """The planned duration of a real program with G4 lines, against a copy with them removed: longer by the sum of
    their P exactly where each dwell sits where the planner stops anyway, plus (filter planner) the in-position wait
    before a dwell after the last move (KB-219), where the plan without it just ends."""
    prof = PROFILES[profile]
    path = SAMPLES / name
    data = path.read_bytes()
    dwells = [float(p) for p in _G4_LINE.findall(data)]
    assert dwells, "the sample has its G4 lines"
    with_g4 = read_gcode(path, data)
    without = read_gcode(path, _G4_LINE.sub(b"", data))
    assert len(with_g4.moves) == len(without.moves)
    period = prof.machine.servo_period_s
    got = round((planned_duration_s(with_g4, prof) - planned_duration_s(without, prof)) / period)
    assert got == round(sum(dwells) / period) + extra_holds * _hold(prof)


def test_linuxcnc_planner_as_python_agrees_with_compiled_with_dwells(monkeypatch: pytest.MonkeyPatch) -> None:
    """plan_tp's kernels run as Python for small jobs (ilcnc._jit): with dwells the two give the same samples.

    Tolerance: numba may contract ``a*b + c`` into one FMA or take another libm path, so a position may differ by
    a few ulps of the largest coordinate (40 mm here): 16 eps * 40 mm, as tests/test_startup.py allows."""
    from ilcnc.vcnc import plan_tp

    prog = read_gcode(Path("dwell.ngc"), _gcode(0.5, 0.25, tail="G4 P0.3").text.replace(
        "G0 X0 Y0 Z5", "G4 P0.2\nG0 X0 Y0 Z5").encode())
    prof = PROFILES["linuxcnc-sim.yaml"]
    compiled = plan_program(prog, prof)
    for name in ("_segments", "_final_speeds", "_run"):
        monkeypatch.setattr(plan_tp, name, getattr(plan_tp, name).py_func)
    python = plan_program(prog, prof)
    assert np.array_equal(python.move, compiled.move)
    assert np.max(np.abs(python.pos_mm - compiled.pos_mm)) <= 16 * np.finfo(float).eps * 40.0


def test_a_dwell_too_long_for_a_virtual_run_is_refused_before_planning() -> None:
    """A run is bounded (plan_base.MAX_RUN_SAMPLES, 1e9 periods): a dwell counts, so ``G4 P2e6`` (2e9 periods at
    1 ms) is refused with the line of the move it precedes, or of the last move when it comes after it, instead of
    allocating the samples."""
    from ilcnc.errors import InputError

    prof = PROFILES["example-mill.yaml"]
    for text, line in (("G21 G90\nG0 X0 Y0\nG4 P2000000\nG1 X10 F100\nM2\n", 4),
                       ("G21 G90\nG0 X0 Y0\nG1 X10 F100\nG4 P2000000\nM2\n", 3)):
        with pytest.raises(InputError) as exc:
            plan_program(read_gcode(Path("long.ngc"), text.encode()), prof)
        assert exc.value.format().startswith(f"long.ngc:{line}: the program's motion takes at least 556 h")
        assert "dwell" in exc.value.format()

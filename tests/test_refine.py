"""Refinement (learn --refine): points on the original path, the same plan, the output contract, refusals."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.contour.path import PathGeometry
from ilcnc.contour.search import contour_error
from ilcnc.learning.learner import refine_for_learning
from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.program.insert import MARKER, inserted_moves, split_move_of
from ilcnc.shop.state import LearnState
from ilcnc.vcnc.plan import plan_program

from .conftest import OWN, REPO, SAMPLES

MILL = REPO / "configs" / "example-mill.yaml"
PROGRAMS = [OWN / "square.ngc", REPO / "samples" / "jsdc.gcode", REPO / "samples" / "compass.ngc",
            SAMPLES / "contour" / "locket_outside.ngc", SAMPLES / "contour" / "Gates_combined_R12.nc"]
runner = CliRunner()
_COORD = re.compile(r"([XYZxyz])\s*[-+]?(\d+\.?\d*|\.\d+)")


def _run(*args: object) -> tuple[int, str]:
    res = runner.invoke(app, [str(a) for a in args])
    return res.exit_code, res.output


def _planned_path_deviation_mm(original, refined, profile) -> tuple[float, float, float]:
    """Largest distance of the refined program's planned reference from the original's (as a polyline), mm,
    and both cycle times, s."""
    a, b = plan_program(original, profile), plan_program(refined, profile)
    path = PathGeometry.from_polyline(a.pos_mm, commands=False)
    nxt = split_move_of(inserted_moves(refined))  # an inserted piece: the move it splits
    first_sample = np.searchsorted(a.move, np.arange(len(original.moves)))
    hint = np.clip(first_sample[nxt[np.maximum(b.move, 0)]], 0, a.n_samples - 2)
    err = contour_error(path, b.pos_mm, hint, window=3000)
    return float(np.nanmax(err.dist_mm)), a.duration_s, b.duration_s


@pytest.mark.parametrize("src", PROGRAMS, ids=lambda p: p.name)
def test_the_refined_program_plans_the_original_path(src: Path) -> None:
    # the proof: uncorrected, the refined program's planned path lies within 0.1 µm of the
    # original's and its cycle time within 0.5 % (measured: 0.05 µm at most, the same cycle time)
    prof = load_profile(MILL)
    prog = read_program(src)
    ref = refine_for_learning(prog, prof)
    assert ref.inserted.n_inserted > 0 and ref.plan.sites
    dev, t0, t1 = _planned_path_deviation_mm(prog, ref.program, prof)
    assert dev < 1e-4, dev
    assert abs(t1 / t0 - 1.0) < 0.005 and ref.cycle_time_s == pytest.approx((t0, t1))
    # every inserted point on a cutting straight feed, next to a refined spot
    skipped = {m.move for m in ref.inserted.skipped}
    assert ref.inserted.n_inserted == sum(len(f) for m, f in ref.plan.points.items() if m not in skipped)
    lines = ref.program.text.splitlines()
    assert all(lines[x.new_line - 1].rstrip().endswith((f"({MARKER})", f"; {MARKER}")) for x in ref.inserted.inserted)


def test_refined_output_keeps_every_line_and_is_judged_against_the_original(tmp_path: Path) -> None:
    src = REPO / "samples" / "jsdc.gcode"
    out = tmp_path / "jsdc.ilc.gcode"
    code, msg = _run("learn", src, "--profile", MILL, "--out", out, "--refine", "--iterations", "3", "--json")
    assert code == 0, msg
    data = json.loads(msg)
    refined = data["refined"]
    assert refined["inserted_lines"] > 0 and refined["corners"] > 0
    assert any(n.startswith("refined: ") for n in data["notes"])
    # every original line is still there, in order; only coordinate numbers changed on them
    orig = src.read_text(encoding="latin-1").splitlines()
    new = out.read_text(encoding="latin-1").splitlines()
    kept = [ln for ln in new if MARKER not in ln]
    assert len(kept) == len(orig) and len(new) - len(kept) == refined["inserted_lines"]
    for a, b in zip(orig, kept, strict=True):  # (an axis word may be added where a correction needs it)
        assert _COORD.sub("", a).split() == _COORD.sub("", b).split(), (a, b)
    # the refined program of the state is the learning index; iteration 0 is it, uncorrected
    st = LearnState.load(tmp_path / "jsdc.ilc.gcode.state")
    assert st.part["refined"]["file"] and st.part["refined"]["commands"] == read_program(
        st.file(st.part["refined"]["file"])).n_commands
    assert st.file(st.iterations[0].program).read_bytes() == st.file(st.part["refined"]["file"]).read_bytes()
    # export --state reproduces every iteration's program byte for byte, and by default the run's output
    for e in st.iterations:
        code, msg = _run("export", src, "--out", tmp_path / f"e{e.iteration}.gcode", "--state", st.directory,
                         "--iteration", e.iteration)
        assert code == 0, msg
        assert (tmp_path / f"e{e.iteration}.gcode").read_bytes() == st.file(e.program).read_bytes()
    code, msg = _run("export", src, "--out", tmp_path / "e.gcode", "--state", st.directory)
    assert code == 0 and (tmp_path / "e.gcode").read_bytes() == out.read_bytes()
    code, msg = _run("export", REPO / "samples" / "compass.ngc", "--out", tmp_path / "x.gcode", "--state", st.directory)
    assert code == 1 and "is not the original nor an output" in msg
    # judged by simulate against the original drawing: the same part, the figures learn reported
    code, msg = _run("simulate", out, "--profile", MILL, "--against", src, "--json")
    assert code == 0, msg
    judged = json.loads(msg)["contour_error_mm"]
    best = min((it for it in data["iterations"] if it["kept"]), key=lambda it: it["contour_error_mm"]["rms"])
    # learn judges against the refined program's path, which is the original's within 0.05 µm
    assert judged["max"] == pytest.approx(best["contour_error_mm"]["max"], abs=2e-4)
    assert judged["max"] < data["iterations"][0]["contour_error_mm"]["max"]
    # a program with other moves is still refused
    code, msg = _run("simulate", out, "--profile", MILL, "--against", REPO / "samples" / "compass.ngc")
    assert code == 1 and "not the same part" in msg
    # continued: the refined commands go on learning
    code, msg = _run("learn", src, "--profile", MILL, "--out", tmp_path / "more.gcode", "--iterations", "1",
                     "--state", tmp_path / "jsdc.ilc.gcode.state", "--json")
    assert code == 0, msg
    assert sum(1 for ln in (tmp_path / "more.gcode").read_text(encoding="latin-1").splitlines() if MARKER in ln) \
        == refined["inserted_lines"]


def test_without_refine_nothing_is_inserted(tmp_path: Path) -> None:
    src = OWN / "square.ngc"
    out = tmp_path / "sq.ngc"
    code, msg = _run("learn", src, "--profile", MILL, "--out", out, "--iterations", "2", "--json")
    assert code == 0, msg
    assert json.loads(msg)["refined"] is None
    assert len(out.read_text().splitlines()) == len(src.read_text().splitlines()) and MARKER not in out.read_text()
    # --refine on a state without refinement: refused, the state untouched
    before = (tmp_path / "sq.ngc.state" / "state.json").read_bytes()
    code, msg = _run("learn", src, "--profile", MILL, "--out", tmp_path / "x.ngc", "--state", tmp_path / "sq.ngc.state",
                     "--refine")
    assert code == 1 and "without refinement" in msg
    assert (tmp_path / "sq.ngc.state" / "state.json").read_bytes() == before


def _profile_with(tmp_path: Path, **refine: object) -> Path:
    d = yaml.safe_load(MILL.read_text())
    d["learning"]["refine"] = refine
    p = tmp_path / "p.yaml"
    p.write_text(yaml.safe_dump(d))
    return p


def test_bad_refine_settings_and_the_cap_are_refused_leaving_nothing(tmp_path: Path) -> None:
    bad = _profile_with(tmp_path, corner_angle_deg=0)
    code, msg = _run("learn", OWN / "square.ngc", "--profile", bad, "--out", tmp_path / "a.ngc", "--refine")
    errors = [ln for ln in msg.splitlines() if ln.strip()]
    assert code == 1 and len(errors) == 1 and "learning.refine.corner_angle_deg" in errors[0] and "p.yaml:" in errors[0]
    capped = _profile_with(tmp_path, max_lines=3)
    code, msg = _run("learn", OWN / "square.ngc", "--profile", capped, "--out", tmp_path / "b.ngc", "--refine")
    assert code == 1 and "learning.refine.max_lines = 3" in msg and msg.strip().startswith("error: ")
    assert not (tmp_path / "b.ngc").exists() and not (tmp_path / "b.ngc.state").exists()
    # probed points hold no error along the path to refine from: said, nothing made
    pts = tmp_path / "p.csv"
    pts.write_text("k,dx,dy,dz\n1,0.001,0,0\n")
    code, msg = _run("learn", OWN / "square.ngc", "--profile", MILL, "--out", tmp_path / "d.ngc", "--points", pts,
                     "--state", tmp_path / "d.state", "--refine")
    assert code == 1 and "--refine needs the error along the path" in msg and not (tmp_path / "d.state").exists()
    on = _profile_with(tmp_path, enabled="on")
    code, msg = _run("learn", OWN / "square.ngc", "--profile", on, "--out", tmp_path / "c.ngc", "--iterations", "1",
                     "--json", "--report", tmp_path / "rep")
    assert code == 0 and json.loads(msg)["refined"]["inserted_lines"] > 0
    assert (tmp_path / "rep" / "refined-corner.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_measured_workflow_refines_from_the_log_of_the_original(tmp_path: Path) -> None:
    """No extra machine run: the log of the original program holds the error at the inserted points."""
    src = REPO / "samples" / "jsdc.gcode"
    state = tmp_path / "state"

    def run_on_machine(prog: Path, log: Path) -> None:  # the virtual CNC stands in for the machine
        code, msg = _run("simulate", prog, "--profile", MILL, "--log-out", log, "--json")
        assert code == 0, msg

    run_on_machine(src, tmp_path / "run0.csv")
    code, msg = _run("learn", src, "--profile", MILL, "--log", tmp_path / "run0.csv", "--state", state,
                     "--out", tmp_path / "p1.gcode", "--refine", "--json")
    assert code == 0, msg
    first = json.loads(msg)
    assert first["refined"]["inserted_lines"] > 0 and first["notes"][0].startswith("refined from the log")
    # the same points as a virtual first run would place: the log is that run
    virtual = refine_for_learning(read_program(src), load_profile(MILL))
    assert first["refined"]["inserted_lines"] == virtual.inserted.n_inserted
    st = LearnState.load(state)
    assert st.file(st.iterations[0].program).read_bytes() == virtual.program.data
    rms = [first["iterations"][0]["contour_error_mm"]["rms"]]
    for i in (1, 2):
        run_on_machine(tmp_path / f"p{i}.gcode", tmp_path / f"run{i}.csv")
        code, msg = _run("learn", src, "--profile", MILL, "--log", tmp_path / f"run{i}.csv", "--state", state,
                         "--out", tmp_path / f"p{i + 1}.gcode", "--json")
        assert code == 0, msg
        it = json.loads(msg)["iterations"][i]
        assert it["kept"]
        rms.append(it["contour_error_mm"]["rms"])
    assert rms[2] < 0.5 * rms[0], rms  # measured: 6.23 -> 2.96 -> 1.49 µm
    assert sum(MARKER in ln for ln in (tmp_path / "p3.gcode").read_text().splitlines()) == virtual.inserted.n_inserted
    # a log of the unrefined program after the refined one ran: one line, exit 1, the state untouched
    before = {p.name: p.read_bytes() for p in state.iterdir()}
    rows = (tmp_path / "run0.csv").read_text().splitlines()
    rows[5] = rows[5][:-1] + ("1" if rows[5][-1] != "1" else "2")  # another recording of the original program
    (tmp_path / "again.csv").write_text("\n".join(rows) + "\n")
    code, msg = _run("learn", src, "--profile", MILL, "--log", tmp_path / "again.csv", "--state", state,
                     "--out", tmp_path / "x.gcode")
    errors = [ln for ln in msg.splitlines() if ln.strip()]
    # refused by the first check that sees it: its line numbers (most run lines that hold no move of the refined
    # program) or, where the inserted lines shift enough of them onto moves, its positions (22 % of its feed
    # samples more than 2 mm from the moves their lines name in the refined program); either way one line
    # naming the log and saying it is not of this program
    assert code == 1 and len(errors) == 1 and "again.csv" in errors[0]
    assert any(s in errors[0] for s in ("log of another program", "not a log of this program",
                                        "not a run of this program")), errors[0]
    assert {p.name: p.read_bytes() for p in state.iterdir()} == before and not (tmp_path / "x.gcode").exists()


def test_refine_arcs_on_places_points_next_to_arcs(tmp_path):
    """learning.refine.arcs: on refines the straight feeds next to Gates' 0.5 mm fillets (off by default: none);
    the refined program runs the same path (insert_points checks it on the program read back)."""
    import dataclasses

    profile = load_profile(MILL)
    src = SAMPLES / "contour" / "Gates_combined_R12.nc"
    head = [*src.read_bytes().split(b"\n")[:60], b"G0 Z3.0", b"M2", b""]
    prog = read_program(tmp_path / "gates-head.nc", data=b"\n".join(head))
    off = refine_for_learning(prog, profile)
    on_profile = dataclasses.replace(profile, learning=dataclasses.replace(
        profile.learning, refine=dataclasses.replace(profile.learning.refine, arcs="on")))
    on = refine_for_learning(prog, on_profile)
    assert off.plan.summary()["arcs"] == 0
    assert on.plan.summary()["arcs"] > 0 and on.inserted.n_inserted > off.inserted.n_inserted
    assert on.program.n_commands == prog.n_commands + on.inserted.n_inserted


def test_refining_from_a_log_with_blends_round_sharp_corners(tmp_path: Path) -> None:
    """jsdc on LinuxCNC's planner (G64 without P: corners blended as far as the axes allow): where a blend takes
    the commanded position round a corner sharper than 90°, its projection on the move falls back while the
    control still names the move; reading the log on the refined program must not send its lines back (it did:
    "the log goes back from line 2430 to line 2429 ... holds more than one run")."""
    lsim = REPO / "configs" / "linuxcnc-sim.yaml"
    src = REPO / "samples" / "jsdc.gcode"
    code, msg = _run("simulate", src, "--profile", lsim, "--log-out", tmp_path / "run0.csv", "--json")
    assert code == 0, msg
    code, msg = _run("learn", src, "--profile", lsim, "--log", tmp_path / "run0.csv", "--state", tmp_path / "st",
                     "--out", tmp_path / "o.gcode", "--refine", "--json")
    assert code == 0, msg
    d = json.loads(msg)
    assert d["refined"]["inserted_lines"] > 0 and d["status"] == "stepped"

"""``ilcnc learn`` as a shop runs it: virtual learning with its state, the measured loop, and every refusal."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.axislog.log import read_axis_log, write_axis_log
from ilcnc.cli import app
from ilcnc.shop.state import LearnState
from ilcnc.shop.workflow import LearnRequest, find_stamp, learn_part, stamp_text, unstamp_text
from tests.conftest import REPO, SAMPLES

CONFIGS = REPO / "configs"
SEED004 = CONFIGS / "seed004-ward-sopdt.yaml"
JSDC = SAMPLES / "gcode" / "jsdc.gcode"
COMPASS = SAMPLES / "contour" / "compass.ngc"

runner = CliRunner()


def _run(*args: str) -> tuple[int, str]:
    res = runner.invoke(app, [str(a) for a in args])
    return res.exit_code, res.output


def _json(*args: str) -> dict:
    code, out = _run(*args, "--json")
    assert code == 0, out
    return json.loads(out)


def _simulate_log(prog: Path, out: Path, against: Path | None = None) -> Path:
    args = ["simulate", prog, "--profile", SEED004, "--log-out", out, "--json"]
    if against is not None:
        args += ["--against", against]
    code, msg = _run(*args)
    assert code == 0, msg
    return out


def _error_line(out: str) -> str:
    lines = [x for x in out.splitlines() if x.startswith("error:")]
    assert len(lines) == 1, out
    return lines[0]


def test_virtual_learn_writes_output_state_and_json(tmp_path) -> None:
    out = tmp_path / "jsdc.ilc.gcode"
    rep = tmp_path / "report"
    data = _json("learn", JSDC, "--profile", SEED004, "--out", out, "--iterations", "2", "--report", rep)
    assert data["status"] in ("max_iterations", "stopped", "converged")
    assert [it["iteration"] for it in data["iterations"]] == [0, 1, 2]
    assert set(data["iterations"][0]) >= {"iteration", "contour_error_mm", "clipped", "kept"}
    assert set(data["iterations"][0]["contour_error_mm"]) == {"max", "mean", "rms"}
    assert data["output"] == str(out) and out.is_file()
    st = LearnState.load(tmp_path / "jsdc.ilc.gcode.state")
    assert [e.iteration for e in st.iterations] == [0, 1, 2]
    assert all(st.file(e.program).is_file() and e.errors for e in st.iterations)
    assert st.part["sha256"] and st.file(st.part["file"]).read_bytes() == JSDC.read_bytes()
    # the output is the best iteration's program, byte for byte
    best = min((e for e in st.iterations if e.kept), key=lambda e: e.stats["rms"])
    assert out.read_bytes() == st.file(best.program).read_bytes()
    for name in ("summary.csv", "commands.csv", "error-vs-iteration.png", "path-iter002.png"):
        assert (rep / name).is_file()
    # the same command again does not silently continue or overwrite the run
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--out", out)
    assert code == 1 and "already holds a learning run" in _error_line(msg)
    # told to continue, it goes on from the best iteration: measured again as a new iteration after the last
    # (issue 25 item 8: no record is written twice)
    data2 = _json("learn", JSDC, "--profile", SEED004, "--out", tmp_path / "more.gcode", "--iterations", "1",
                  "--state", tmp_path / "jsdc.ilc.gcode.state")
    assert data2["iterations"][0]["iteration"] == 3
    st2 = LearnState.load(tmp_path / "jsdc.ilc.gcode.state")
    rerun = next(e for e in st2.iterations if e.iteration == 3)
    assert rerun.measured_from is not None and rerun.measured_from["rerun_of"] == best.iteration
    assert st2.file(rerun.program).read_bytes() == st.file(best.program).read_bytes()
    assert [e.stats for e in st2.iterations[:3]] == [e.stats for e in st.iterations]


def test_force_replaces_an_earlier_run_but_never_an_input(tmp_path) -> None:
    out = tmp_path / "jsdc.ilc.gcode"
    state_dir = tmp_path / "jsdc.ilc.gcode.state"
    first = _json("learn", JSDC, "--profile", SEED004, "--out", out, "--iterations", "2")
    old_iterations = sorted(p.name for p in state_dir.iterdir())
    # typed again with --force: a new run from iteration 0, the earlier state replaced, nothing left beside it
    second = _json("learn", JSDC, "--profile", SEED004, "--out", out, "--iterations", "1", "--force")
    assert [it["iteration"] for it in second["iterations"]] == [0, 1]
    assert second["iterations"][0]["contour_error_mm"] == first["iterations"][0]["contour_error_mm"]
    st = LearnState.load(state_dir)
    assert [e.iteration for e in st.iterations] == [0, 1]
    assert any(n.startswith("iter-002") for n in old_iterations)
    assert not any(p.name.startswith("iter-002") for p in state_dir.iterdir())  # nothing of the earlier run is left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["jsdc.ilc.gcode", "jsdc.ilc.gcode.state"]
    # an output of that run is refused as a new start even with --force (it would be corrected twice)
    before = out.read_bytes()
    code, msg = _run("learn", out, "--profile", SEED004, "--out", tmp_path / "again.gcode", "--state", state_dir, "--force")
    assert code == 1 and "correct it twice" in _error_line(msg)
    assert out.read_bytes() == before and LearnState.load(state_dir).iterations[-1].iteration == 1
    # a program inside the state folder is an input: --force refuses to replace it
    inside = state_dir / st.part["file"]
    code, msg = _run("learn", inside, "--profile", SEED004, "--out", tmp_path / "x.gcode", "--state", state_dir, "--force")
    assert code == 1 and "inside the state" in _error_line(msg)
    assert LearnState.exists(state_dir) and inside.read_bytes() == JSDC.read_bytes()
    # a measured step continues its state: --force has no meaning there
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--out", tmp_path / "m.gcode", "--log", tmp_path / "none.csv",
                     "--state", state_dir, "--force")
    assert code == 1 and "--force" in _error_line(msg)


def test_measured_loop_three_steps_and_refusals(tmp_path) -> None:
    st = tmp_path / "st"
    run0 = _simulate_log(JSDC, tmp_path / "run0.csv")
    # a log needs a state directory: a usage error (issue 25 item 17: exit 2, the option named)
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--log", run0, "--out", tmp_path / "x.gcode")
    assert code == 2 and "--state" in _error_line(msg)
    rms = []
    prog = JSDC
    log = run0
    for i in range(1, 4):
        out = tmp_path / f"jsdc.ilc{i}.gcode"
        data = _json("learn", JSDC, "--profile", SEED004, "--log", log, "--state", st, "--out", out)
        assert data["status"] == "stepped" and data["output"] == str(out)
        rms.append(data["iterations"][i - 1]["contour_error_mm"]["rms"])
        prog = out
        log = _simulate_log(prog, tmp_path / f"run{i}.csv", against=JSDC)
    assert rms[1] < 0.7 * rms[0] and rms[2] < rms[1]
    # the output of a run, given with its state, continues it (here: with the log of that output)
    data = _json("learn", prog, "--profile", SEED004, "--log", log, "--state", st, "--out", tmp_path / "next.gcode")
    assert data["status"] == "stepped"
    # the same log twice is refused
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--log", log, "--state", st, "--out", tmp_path / "again.gcode")
    assert code == 1 and "already used for iteration" in _error_line(msg)
    # a state directory of another part is refused
    code, msg = _run("learn", COMPASS, "--profile", SEED004, "--log", log, "--state", st, "--out", tmp_path / "c.ngc")
    assert code == 1 and "belongs to jsdc.gcode" in _error_line(msg)


def test_log_of_another_program_is_refused(tmp_path) -> None:
    other = _simulate_log(SAMPLES / "gcode" / "tiny_cat_outline.ngc", tmp_path / "cat.csv")
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--log", other, "--state", tmp_path / "st",
                     "--out", tmp_path / "o.gcode")
    line = _error_line(msg)
    assert code == 1 and "cat.csv" in line and ("another program" in line or "not a run of this program" in line)
    assert not (tmp_path / "o.gcode").exists()


def _edit_log(src: Path, dst: Path, edit) -> Path:
    log = read_axis_log(src)
    edit(log)
    write_axis_log(dst, log)
    return dst


def test_bad_logs_are_refused_with_the_line(tmp_path) -> None:
    run0 = _simulate_log(JSDC, tmp_path / "run0.csv")
    lines = run0.read_text().splitlines()
    nan = tmp_path / "nan.csv"
    lines_nan = list(lines)
    cells = lines_nan[500].split(",")
    cells[6] = "nan"
    lines_nan[500] = ",".join(cells)
    nan.write_text("\n".join(lines_nan) + "\n")
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--log", nan, "--state", tmp_path / "s1",
                     "--out", tmp_path / "a.gcode")
    assert code == 1 and "nan.csv:501:" in _error_line(msg) and "finite" in msg
    gap = tmp_path / "gap.csv"
    gap.write_text("\n".join(lines[:1000] + lines[1200:]) + "\n")
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--log", gap, "--state", tmp_path / "s2",
                     "--out", tmp_path / "b.gcode")
    assert code == 1 and "gap.csv:1001:" in _error_line(msg) and "gap" in msg
    # a log in mm where inch was said
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--log", run0, "--log-units", "inch", "--state", tmp_path / "s3",
                     "--out", tmp_path / "c.gcode")
    assert code == 1 and "in mm, not inch" in _error_line(msg)
    # a log in inch where mm was said (the default)
    inch = _edit_log(run0, tmp_path / "inch.csv", lambda lg: (lg.act_mm.__itruediv__(25.4), lg.ref_mm.__itruediv__(25.4)))
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--log", inch, "--state", tmp_path / "s4",
                     "--out", tmp_path / "d.gcode")
    assert code == 1 and "in inch, not mm" in _error_line(msg)
    # a log of only half of the run
    half = tmp_path / "half.csv"
    half.write_text("\n".join(lines[: len(lines) // 3]) + "\n")
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--log", half, "--state", tmp_path / "s5",
                     "--out", tmp_path / "e.gcode")
    assert code == 1 and "half.csv" in _error_line(msg)
    # nothing was learned from any of them: no state with a measurement was left behind
    for d in ("s1", "s2", "s3", "s4", "s5"):
        assert not (tmp_path / d / "state.json").exists()


def test_points_step(tmp_path) -> None:
    from ilcnc.program import read_program
    from ilcnc.shop.measure import interpolate_along_path

    prog = read_program(JSDC)
    pts = tmp_path / "probe.csv"
    # a regular probing pattern (every 7th command) with a hole: commands 700..1399 are not measured
    k = np.arange(0, prog.n_commands, 7)
    k = k[(k < 700) | (k >= 1400)]
    rows = ["k,dx,dy,dz"] + [f"{int(i)},0.004,-0.002,0" for i in k]
    pts.write_text("\n".join(rows) + "\n")
    data = _json("learn", JSDC, "--profile", SEED004, "--points", pts, "--state", tmp_path / "st",
                 "--out", tmp_path / "p1.gcode")
    assert data["status"] == "stepped" and data["mode"] == "points"
    assert any("interpolated along the path" in n for n in data["notes"])
    assert any("far from any measured point" in n for n in data["notes"])
    st = LearnState.load(tmp_path / "st")
    u = st.read_corrections(st.iterations[1])
    assert np.allclose(u[k[5]], [-0.002, 0.001, 0.0], atol=1e-4)  # Γ = 0.5 against measured − nominal
    # which commands the interpolation bridges: the same cut, between two measured commands, within the reach
    e = np.full((prog.n_commands, 3), np.nan)
    e[k] = [-0.004, 0.002, 0.0]
    _e, filled, reach = interpolate_along_path(e, prog)
    assert reach == pytest.approx(3 * 7 * np.median(np.linalg.norm(np.diff(prog.command_end_mm, axis=0), axis=1)), rel=1.0)
    assert filled.sum() > 0.5 * (prog.n_commands - k.size)
    hole = np.arange(750, 1350)
    assert not filled[hole].any()  # far from any measured point: left alone
    assert np.all(u[hole] == 0.0) and not np.all(u[filled] == 0.0)
    assert np.allclose(u[filled][np.any(u[filled] != 0.0, axis=1)], [-0.002, 0.001, 0.0], atol=1e-4)
    bad = tmp_path / "bad.csv"
    bad.write_text("k,dx,dy,dz\n999999,0.001,0,0\n")
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--points", bad, "--state", tmp_path / "st2",
                     "--out", tmp_path / "q.gcode")
    assert code == 1 and "bad.csv:2:" in _error_line(msg) and "does not exist" in msg


def test_stamp_and_correcting_twice(tmp_path) -> None:
    out = tmp_path / "jsdc.ilc.gcode"
    _json("learn", JSDC, "--profile", SEED004, "--out", out, "--iterations", "1", "--stamp")
    text = out.read_text(encoding="latin-1")
    st = find_stamp(text)
    assert st is not None and st["name"] == "jsdc.gcode" and st["line"] == 1
    assert len(text.splitlines()) == len(JSDC.read_text(encoding="latin-1").splitlines())  # no line moved
    # a stamped output is refused as the start of a new learning run
    code, msg = _run("learn", out, "--profile", SEED004, "--out", tmp_path / "twice.gcode")
    line = _error_line(msg)
    assert code == 1 and "jsdc.ilc.gcode:1:" in line and "correct twice" in line
    # the stamped output with the state of its own run continues that run
    data = _json("learn", out, "--profile", SEED004, "--out", tmp_path / "cont.gcode", "--iterations", "1",
                 "--state", tmp_path / "jsdc.ilc.gcode.state")
    # from its best iteration (1), measured again as iteration 2 (issue 25 item 8: no record is written twice)
    assert data["iterations"][0]["iteration"] == 2
    assert unstamp_text(text).encode("latin-1") == (tmp_path / "jsdc.ilc.gcode.state" / "iter-001.gcode").read_bytes()
    assert (tmp_path / "jsdc.ilc.gcode.state" / "iter-002.gcode").read_bytes() == \
        (tmp_path / "jsdc.ilc.gcode.state" / "iter-001.gcode").read_bytes()
    # an output recognised by its hash alone (no stamp), given with another part's state
    _json("learn", COMPASS, "--profile", SEED004, "--out", tmp_path / "compass.ilc.ngc", "--iterations", "1")
    code, msg = _run("learn", out, "--profile", SEED004, "--out", tmp_path / "x.gcode", "--state",
                     tmp_path / "compass.ilc.ngc.state")
    assert code == 1 and "belongs to compass.ngc" in _error_line(msg)
    # Klartext stamps go after the BEGIN PGM line's text
    assert "; ilcnc: learned from a.h" in stamp_text("0 BEGIN PGM A MM\n1 END PGM A MM\n", "heidenhain", name="a.h",
                                                     sha256="0" * 64, iteration=2).splitlines()[0]


def test_an_unstamped_output_is_not_corrected_twice_by_default(tmp_path) -> None:
    """Issue 20 item 11: `ilcnc learn jsdc.ilc.gcode ...` (an output without a stamp, its state beside it) was
    corrected again. It is refused, naming the run; --relearn starts anew on purpose."""
    out = tmp_path / "jsdc.ilc.gcode"
    _json("learn", JSDC, "--profile", SEED004, "--out", out, "--iterations", "1")
    assert find_stamp(out.read_text(encoding="latin-1")) is None
    code, msg = _run("learn", out, "--profile", SEED004, "--out", tmp_path / "twice.gcode", "--iterations", "1")
    line = _error_line(msg)
    assert code == 1 and "correct it twice" in line and "jsdc.ilc.gcode.state" in line and "iteration 1" in line
    assert not (tmp_path / "twice.gcode").exists() and not (tmp_path / "twice.gcode.state").exists()
    data = _json("learn", out, "--profile", SEED004, "--out", tmp_path / "twice.gcode", "--iterations", "1",
                 "--relearn")
    assert data["status"] in ("max_iterations", "stopped", "converged", "diverged")
    # a state beside a program that holds it as its original (iteration 0) does not refuse it
    orig = tmp_path / "part.gcode"
    orig.write_bytes(JSDC.read_bytes())
    _json("learn", orig, "--profile", SEED004, "--out", tmp_path / "p1.gcode", "--iterations", "1",
          "--state", tmp_path / "part.gcode.state")
    _json("learn", orig, "--profile", SEED004, "--out", tmp_path / "p2.gcode", "--iterations", "1")


def test_state_survives_a_crash_while_writing(tmp_path, monkeypatch) -> None:
    out = tmp_path / "o.gcode"
    _json("learn", JSDC, "--profile", SEED004, "--out", out, "--iterations", "1")
    sdir = tmp_path / "o.gcode.state"
    before = (sdir / "state.json").read_bytes()
    import ilcnc.fileio as fio

    real_replace = os.replace

    class Killed(BaseException):
        pass

    def crash(src, dst):
        if str(dst).endswith("state.json"):
            raise Killed("killed while writing the state")
        return real_replace(src, dst)

    monkeypatch.setattr(fio.os, "replace", crash)
    req = LearnRequest(JSDC, SEED004, tmp_path / "o2.gcode", iterations=1, state=sdir)
    with pytest.raises(Killed):
        learn_part(req)
    monkeypatch.setattr(fio.os, "replace", real_replace)
    assert (sdir / "state.json").read_bytes() == before
    LearnState.load(sdir)  # the previous state still loads
    assert not any(p.name.endswith(".tmp") for p in sdir.iterdir())


def test_state_survives_sigkill(tmp_path) -> None:
    """Kill a real learning process at random moments: the state on disk always loads."""
    sdir = tmp_path / "o.gcode.state"
    env = dict(os.environ)
    for delay in (2.0, 3.5):
        if sdir.exists():
            for p in sdir.iterdir():
                p.unlink()
            sdir.rmdir()
        proc = subprocess.Popen([sys.executable, "-m", "ilcnc", "learn", str(JSDC), "--profile", str(SEED004),
                                 "--out", str(tmp_path / "o.gcode"), "--iterations", "8", "--json"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
        deadline = time.monotonic() + 60
        while not (sdir / "state.json").exists() and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.05)
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        st = LearnState.load(sdir)
        assert st.iterations and st.iterations[0].iteration == 0


def test_interpolation_along_the_path_is_linear_in_path_length_and_stops_at_cuts(tmp_path) -> None:
    from ilcnc.program import read_program
    from ilcnc.shop.measure import interpolate_along_path

    p = tmp_path / "two_cuts.ngc"
    # cut 1: k = 0..4 along X with uneven steps; a rapid; cut 2: k = 5..7
    p.write_text("G21 G90 G17\nG0 X0 Y0 Z0\nG1 X1 F600\nG1 X2\nG1 X5\nG1 X6\nG1 X10\n"
                 "G0 X20\nG1 X21\nG1 X22\nG1 X23\nM2\n")
    prog = read_program(p)
    assert prog.n_commands == 8
    e = np.full((8, 3), np.nan)
    e[0] = [0.0, 0.010, 0.0]
    e[4] = [0.0, 0.019, 0.0]
    e[5] = [0.0, 0.001, 0.0]
    out, filled, reach = interpolate_along_path(e, prog, reach_mm=20.0)
    assert reach == 20.0
    assert filled.tolist() == [False, True, True, True, False, False, False, False]
    assert np.allclose(out[1:4, 1], [0.011, 0.014, 0.015])  # linear in path length (X 2, 5, 6 of 1..10)
    assert np.isnan(out[6:]).all()  # after the last measured command of cut 2: left alone
    _out, filled2, _r = interpolate_along_path(e, prog, reach_mm=5.0)  # the 9 mm gap is beyond the reach
    assert not filled2.any()


def test_a_refused_first_log_leaves_no_state_and_a_retry_works(tmp_path) -> None:
    run0 = _simulate_log(JSDC, tmp_path / "run0.csv")
    half = tmp_path / "half.csv"
    lines = run0.read_text().splitlines()
    half.write_text("\n".join(lines[: len(lines) // 3]) + "\n")
    st = tmp_path / "st"
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--log", half, "--state", st, "--out", tmp_path / "a.gcode")
    assert code == 1 and "half.csv" in _error_line(msg)
    assert not st.exists()  # nothing half-made
    # the same directory, the whole log, with a report: a step is made and the report written
    rep = tmp_path / "rep"
    data = _json("learn", JSDC, "--profile", SEED004, "--log", run0, "--state", st, "--out", tmp_path / "a.gcode",
                 "--report", rep)
    assert data["status"] == "stepped" and (st / "state.json").exists()
    assert (rep / "summary.csv").exists() or any(rep.iterdir())
    # an existing non-empty directory that is not a state is never emptied
    other = tmp_path / "other"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    code, msg = _run("learn", JSDC, "--profile", SEED004, "--log", run0, "--state", other, "--out", tmp_path / "b.gcode")
    assert code == 1 and "not empty" in _error_line(msg) and (other / "keep.txt").read_text() == "mine"


def test_a_log_of_a_cutter_compensated_program_is_refused(tmp_path) -> None:
    prog = tmp_path / "comp.ngc"
    prog.write_text("G21 G90 G17\nG0 X0 Y0 Z1\nG1 Z0 F300\nG41 D1 G1 X10 F600\nG1 Y10\nG1 X0\nG40 G1 Y0\nM2\n")
    log = _simulate_log(prog, tmp_path / "comp.csv")
    code, msg = _run("learn", prog, "--profile", SEED004, "--log", log, "--state", tmp_path / "st",
                     "--out", tmp_path / "o.ngc")
    line = _error_line(msg)
    assert code == 1 and "comp.ngc:4:" in line and "cutter radius compensation" in line
    assert not (tmp_path / "st").exists()


def test_stamp_goes_inside_the_first_comment_when_it_holds_a_semicolon(tmp_path) -> None:
    text = "(star; sharp corners)\nG21 G90\nG1 X1 F100\nM2\n"
    stamped = stamp_text(text, "linuxcnc", name="star.ngc", sha256="0" * 64, iteration=2)
    first = stamped.splitlines()[0]
    assert first.startswith("(star; sharp corners) (ilcnc: learned from star.ngc") and first.endswith(")")
    assert unstamp_text(stamped) == text
    semi = "G21 G90 ; metric\nM2\n"
    assert stamp_text(semi, "linuxcnc", name="a.ngc", sha256="0" * 64, iteration=1).startswith(
        "G21 G90 ; metric ilcnc: learned from a.ngc")


def test_log_period_option_reads_a_halsampler_log_at_its_own_rate(tmp_path) -> None:
    code, out = _run("learn", "--help")
    assert code == 0 and "--log-period" in out


def test_virtual_learning_refuses_cutter_compensation_and_unmodelled_cycles(tmp_path) -> None:
    """Issue 20 items 8 and 10: a compensated contour (the machine runs the tool-centre path) and a program whose
    cycles move the tool unmodelled are refused with the line, and nothing is left behind."""
    prog = tmp_path / "comp.ngc"
    prog.write_text("G21 G90 G17\nG0 X0 Y0 Z1\nG1 Z0 F300\nG41 D1 G1 X10 F600\nG1 Y10\nG1 X0\nG40 G1 Y0\nM2\n")
    code, msg = _run("learn", prog, "--profile", SEED004, "--out", tmp_path / "o.ngc", "--iterations", "1")
    line = _error_line(msg)
    assert code == 1 and "comp.ngc:4:" in line and "cutter radius compensation" in line
    pocket = tmp_path / "pocket.h"
    pocket.write_text("0 BEGIN PGM P MM\n1 TOOL CALL 3 Z S5000\n2 CYCL DEF 5.0 CIRCULAR POCKET\n"
                      "3 CYCL DEF 5.1 SET UP-2\n4 CYCL DEF 5.2 DEPTH -5.9\n5 CYCL DEF 5.3 PECKG -1.5 F50\n"
                      "6 CYCL DEF 5.4 RADIUS1.65\n7 CYCL DEF 5.5 F50 DR-\n8 L X+32 Y+0 Z+2 R0 F5000 M13\n"
                      "9 CYCL CALL M\n10 L X+0 Y+0 F800\n11 L X+10 F800\n12 L Z+100 R0 F5000 M2\n13 END PGM P MM\n")
    for args in (("learn", pocket, "--profile", SEED004, "--out", tmp_path / "p.h", "--iterations", "1"),
                 ("simulate", pocket, "--profile", SEED004)):
        code, msg = _run(*args)
        line = _error_line(msg)
        assert code == 1 and "pocket.h:10:" in line and "cycle 5 CIRCULAR POCKET" in line and "not modelled" in line
    code, msg = _run("inspect", pocket)  # read in full: it can still be inspected
    assert code == 0, msg
    assert sorted(p.name for p in tmp_path.iterdir()) == ["comp.ngc", "pocket.h"]

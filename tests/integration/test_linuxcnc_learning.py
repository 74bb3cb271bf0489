"""The shop workflow with a real controller in the loop: LinuxCNC runs, ilcnc learns from its logs.

run the program on LinuxCNC → ``ilcnc learn --log`` → compensated program →
run it on LinuxCNC → next log → ... for four learning iterations, on a real
CAM sample (jscut engraving ``samples/jsdc.gcode``, 2,381 G01 commands; the
file lacks the program end LinuxCNC insists on, so the test runs a copy with
``M2`` appended — the copy is the drawing). Time-scaled ×8: ~7 s per run.
"""

from __future__ import annotations

import re
import shutil

import pytest

from ilcnc.cli import app
from ilcnc.learning.guard import best_stats, grew
from ilcnc.profile.load import load_profile
from ilcnc.shop.state import LearnState
from tests.integration._lcnc import PROFILE, REPO, cli_json, needs_linuxcnc, runner

pytestmark = needs_linuxcnc()
_COORD = re.compile(r"\s?[XYZ][-+]?[0-9]*\.?[0-9]*")


@pytest.fixture(scope="module")
def loop(tmp_path_factory) -> dict:
    d = tmp_path_factory.mktemp("lcnc-learn")
    part = d / "jsdc.ngc"
    part.write_bytes((REPO / "samples" / "jsdc.gcode").read_bytes() + b"M2\n")
    state = d / "state"
    logs, outs, learned = [], [part], []
    log = d / "run0.csv"
    cli_json("linuxcnc", "run", part, "--log", log, "--time-scale", 8)
    logs.append(log)
    for i in range(1, 5):
        out = d / f"jsdc.ilc{i}.ngc"
        learned.append(cli_json("learn", part, "--profile", PROFILE, "--log", log, "--state", state, "--out", out))
        if i == 1:  # a copy of the state while it waits for its next log (the run may stop later: the guard)
            shutil.copytree(state, d / "state-open")
        log = d / f"run{i}.csv"
        # LinuxCNC must accept every compensated program (a refusal raises and fails the test)
        cli_json("linuxcnc", "run", out, "--log", log, "--time-scale", 8)
        outs.append(out)
        logs.append(log)
    last = cli_json("learn", part, "--profile", PROFILE, "--log", log, "--state", state, "--out", d / "jsdc.ilc5.ngc")
    return {"dir": d, "part": part, "state": state, "logs": logs, "outs": outs, "learned": learned, "last": last,
            "open_state": d / "state-open"}


def test_four_iterations_on_linuxcnc_reduce_the_contour_error(loop) -> None:
    its = loop["last"]["iterations"]
    measured = [it for it in its[:5] if it["contour_error_mm"]]
    assert len(measured) == 5
    # the guard judges the cutting moves (ilcnc.contour.air): an iteration is kept exactly when neither their max nor
    # their RMS grew past the best kept before it. jsdc's cutting max sits where LinuxCNC blends a slot's last
    # cut into its G1 retract (~340 µm at Z -0.6, the tool rising early): no end point shapes it and it moves a
    # few % from run to run, so an iteration may be refused there (measured 2026-12-01: 355.4 -> 343.3 ->
    # 336.9 -> 345.8 (refused) µm max; RMS 34.10 -> 28.26 -> 27.05 -> 26.53 µm). Before the cutting moves
    # were judged apart, that max hid under the air moves' (448 µm, a G1 at Z1) and every iteration was kept.
    res = load_profile(PROFILE).machine.resolution_mm
    for i, it in enumerate(measured[1:], start=1):
        best = best_stats([x["contour_error_mm"] for x in measured[:i] if x["kept"]])
        assert it["kept"] == (not grew(it["contour_error_mm"], best, resolution_mm=res)), (i, its)
    kept = [it["contour_error_mm"]["rms"] for it in measured if it["kept"]]
    assert len(kept) >= 3 and kept[1] < kept[0], its
    # measured 2026-11-23 (all feed moves, 3 model-assisted steps per measured one): 41.61 -> 31.36 µm (-24.6 %);
    # 2026-12-01, cutting moves: 34.10 -> 26.53 µm (-22 %)
    assert min(kept) < 0.9 * measured[0]["contour_error_mm"]["rms"], its
    st = LearnState.load(loop["state"])
    assert [e.iteration for e in st.iterations][:5] == [0, 1, 2, 3, 4]
    assert all(e.measured_from["kind"] == "log" for e in st.iterations[:5])


def test_fidelity_of_the_virtual_cnc_on_the_blended_cam_program(loop) -> None:
    # `simulate --compare` on LinuxCNC's run of the original. jsdc runs in plain G64 (blended), which
    # configs/linuxcnc-sim.yaml plans as LinuxCNC does (planner.profile linuxcnc, ilcnc/vcnc/plan_tp.py). Measured
    # 2026-11-23: correlation 0.986, difference 14 % of the error, sample RMS 41.6 µm measured / 40.1 µm
    # predicted (with ilcnc's filter planner: 0.865, 42 %, 38.5 µm): issue 9's targets (0.9, 20 %) are met.
    f = cli_json("simulate", loop["part"], "--profile", PROFILE, "--compare", loop["logs"][0])["fidelity"]
    assert f["commands"] == 2381
    assert f["correlation"] >= 0.9
    assert f["relative_difference"] <= 0.2
    assert f["trusted"] is True
    assert f["contour_predicted_mm"]["rms"] == pytest.approx(f["contour_measured_mm"]["rms"], rel=0.1)


def test_compensated_programs_differ_only_in_g01_coordinates(loop) -> None:
    src = loop["part"].read_text(encoding="latin-1").splitlines()
    for out in loop["outs"][1:]:
        new = out.read_text(encoding="latin-1").splitlines()
        assert len(new) == len(src)
        diff = [(a, b) for a, b in zip(src, new, strict=True) if a != b]
        assert diff
        for a, b in diff:
            assert a.lstrip().upper().startswith("G1") and _COORD.sub("", a) == _COORD.sub("", b), (a, b)


def test_a_log_cut_off_mid_run_is_refused_and_the_state_kept(loop, tmp_path) -> None:
    # the state as it waited for the log of iteration 1 (copied then: the loop's own state may have stopped since)
    state = tmp_path / "state"
    shutil.copytree(loop["open_state"], state)
    before = (state / "state.json").read_bytes()
    full = loop["logs"][1].read_text().splitlines()
    cut = tmp_path / "cut.csv"
    cut.write_text("\n".join(full[: len(full) // 3]) + "\n")
    res = runner.invoke(app, ["learn", str(loop["part"]), "--profile", str(PROFILE), "--log", str(cut), "--state",
                              str(state), "--out", str(tmp_path / "x.ngc")])
    assert res.exit_code == 1 and res.output.startswith("error: ") and len(res.output.strip().splitlines()) == 1
    assert "cut.csv" in res.output
    assert (state / "state.json").read_bytes() == before
    LearnState.load(state)

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

import numpy as np
import pytest

from ilcnc.cli import app
from ilcnc.learning.guard import best_stats, grew
from ilcnc.profile.load import load_profile
from ilcnc.shop.state import LearnState
from tests.conftest import cli_output
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
    cli_json("linuxcnc", "run", part, "--log-out", log, "--time-scale", 8)
    logs.append(log)
    for i in range(1, 5):
        out = d / f"jsdc.ilc{i}.ngc"
        learned.append(cli_json("learn", part, "--profile", PROFILE, "--log", log, "--state", state, "--out", out))
        if i == 1:  # a copy of the state while it waits for its next log (the run may stop later: the guard)
            shutil.copytree(state, d / "state-open")
        log = d / f"run{i}.csv"
        # LinuxCNC must accept every compensated program (a refusal raises and fails the test)
        cli_json("linuxcnc", "run", out, "--log-out", log, "--time-scale", 8)
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


def _step_on_open_state(loop, tmp_path, log):  # type: ignore[no-untyped-def]
    """``learn --log LOG`` on a copy of the state as it waited for the log of iteration 1 (copied then: the loop's
    own state may have stopped since). Returns the copy, its state.json before, and the CLI result."""
    state = tmp_path / "state"
    shutil.copytree(loop["open_state"], state)
    before = (state / "state.json").read_bytes()
    res = runner.invoke(app, ["learn", str(loop["part"]), "--profile", str(PROFILE), "--log", str(log), "--state",
                              str(state), "--out", str(tmp_path / "x.ngc")])
    return state, before, res


def test_a_log_cut_off_mid_run_is_refused_and_the_state_kept(loop, tmp_path) -> None:
    full = loop["logs"][1].read_text().splitlines()
    cut = tmp_path / "cut.csv"
    cut.write_text("\n".join(full[: len(full) // 3]) + "\n")
    state, before, res = _step_on_open_state(loop, tmp_path, cut)
    assert res.exit_code == 1 and cli_output(res).startswith("error: ") and len(cli_output(res).strip().splitlines()) == 1
    assert "cut.csv" in res.output
    assert (state / "state.json").read_bytes() == before
    LearnState.load(state)


def _distance_to_nearby_moves(act: np.ndarray, moves, move: np.ndarray, window: int) -> np.ndarray:
    """Exact distance from each sample to the straight moves within ``window`` moves of its block (mm).

    Written apart from :mod:`ilcnc.contour` (no path object, no search, no reach): the projection of the point on
    each segment, clipped to it, and the least distance over the window. jsdc has no arcs.
    """
    a, b = moves.start_mm, moves.end_mm
    best = np.full(act.shape[0], np.inf)
    for off in range(-window, window + 1):
        j = np.clip(move + off, 0, len(moves) - 1)
        d = b[j] - a[j]
        n2 = np.einsum("ij,ij->i", d, d)
        u = np.clip(np.einsum("ij,ij->i", act - a[j], d) / np.where(n2 > 0, n2, 1.0), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(a[j] + u[:, None] * d - act, axis=1))
    return best


@pytest.fixture(scope="module")
def compass_head(tmp_path_factory) -> dict:
    """The first 60 lines of compass.ngc (a plunge after a rapid, then a dense contour) run on LinuxCNC."""
    d = tmp_path_factory.mktemp("lcnc-compass")
    part = d / "compass-head.ngc"
    head = (REPO / "samples" / "compass.ngc").read_text(encoding="latin-1").splitlines()[:60]
    part.write_text("\n".join(head) + "\nG0 Z5\nM2\n", encoding="latin-1")
    log = d / "run0.csv"
    cli_json("linuxcnc", "run", part, "--log-out", log, "--time-scale", 8)
    return {"part": part, "outs": [part], "logs": [log]}


@pytest.mark.parametrize(("case", "run"), [("jsdc", 0), ("jsdc", 1), ("compass", 0)],
                         ids=["jsdc-original", "jsdc-iteration-1", "compass-plunge"])
def test_measured_error_is_the_distance_to_the_path(loop, compass_head, case, run) -> None:
    # issue 25 item 0: a lagging tool has not reached the corner yet (here: the plunge after compass's first rapid,
    # the tool still 80 µm above Z -4.85); a contour search without the log's commanded positions stopped on the
    # wrong side of it (compass: 80.5 µm where the path is 32.5 µm away). Each measured sample's distance must be
    # the point-to-path distance computed independently.
    from ilcnc.axislog.detect import read_log
    from ilcnc.program import read_program
    from ilcnc.shop.measure import measure_log, sample_moves
    from ilcnc.vcnc.command_error import error_kind

    case_runs = loop if case == "jsdc" else compass_head
    profile = load_profile(PROFILE)
    original = read_program(case_runs["part"])
    ran = read_program(case_runs["outs"][run])
    assert not np.isfinite(original.moves.center_mm).any()  # straight moves only: the independent distance's premise
    log_path = case_runs["logs"][run]
    log = read_log(log_path, fmt="auto", period_s=profile.machine.servo_period_s, units="mm", columns=None)
    m = measure_log(log, ran, original, profile, error_kind(profile), source=log_path)
    assert m.contour_mm is not None and m.feed_mask is not None
    # the window: LinuxCNC lags up to ~0.5 mm behind its command, these moves are >= ~0.01 mm: 40 moves either
    # side hold every point the tool can be nearest to (measured: widening it to 300 changes no distance)
    indep = _distance_to_nearby_moves(np.asarray(log.act_mm), original.moves, sample_moves(log, ran), 40)
    sel = m.feed_mask & np.isfinite(m.contour_mm)
    assert sel.sum() > 0.9 * m.feed_mask.sum()
    # two formulas for the same projection on coordinates below 100 mm: rounding ~1e-14 mm; 1e-9 mm bounds it
    np.testing.assert_allclose(m.contour_mm[sel], indep[sel], rtol=0, atol=1e-9)
    # the cutting moves' figures are taken from these distances (the air moves' apart)
    assert m.stats["max"] <= indep[sel].max() + 1e-9


def test_the_log_of_the_program_before_is_refused_on_linuxcnc(loop, tmp_path) -> None:
    # issue 25 item 2 on LinuxCNC: the state waits for the log of iteration 1; the original's log, one sample short
    # (other bytes, other samples: neither hash knows it), fits the original's path, not iteration 1's
    rows = loop["logs"][0].read_text().splitlines()
    old = tmp_path / "old.csv"
    old.write_text("\n".join(rows[:-1]) + "\n")
    state, before, res = _step_on_open_state(loop, tmp_path, old)
    assert res.exit_code == 1 and len(cli_output(res).strip().splitlines()) == 1, cli_output(res)
    assert "fit the program of iteration 0 (iter-000.ngc) better than iter-001.ngc" in res.output, res.output
    assert (state / "state.json").read_bytes() == before and not (tmp_path / "x.ngc").exists()

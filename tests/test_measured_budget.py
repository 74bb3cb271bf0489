"""learning.cycle_budget_pct on measured steps (``learn --log``): the proposal planned on the profile's planner
model, held like virtual learning holds it, the guard and the stop as for virtual learning.

The logs are runs of the programs on the profile's virtual CNC (``simulate --log-out``), as in
tests/test_learn_workflow.py: for ``configs/linuxcnc-sim.yaml`` that is LinuxCNC 2.9's planner
(``planner.profile: linuxcnc``, :mod:`ilcnc.vcnc.plan_tp`) with the drives fitted to the LinuxCNC simulation.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.axislog.detect import read_log
from ilcnc.cli import app
from ilcnc.learning.cycle_hold import CLIP_CYCLE, motion_time_s
from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.shop.state import LearnState
from ilcnc.vcnc.plan import planned_duration_s

from .conftest import OWN, REPO, cli_output

SQUARE = OWN / "square.ngc"  # 50 mm square at F3000, G64 P0.05
LCNC = REPO / "configs" / "linuxcnc-sim.yaml"
MILL = REPO / "configs" / "example-mill.yaml"

runner = CliRunner()


def _profile(base: Path, tmp: Path, pct: float) -> Path:
    """``base`` with ``learning.cycle_budget_pct: pct``."""
    text = base.read_text(encoding="utf-8")
    assert "\nlearning:\n" in text
    out = tmp / f"{base.stem}-budget-{pct:g}.yaml"
    out.write_text(text.replace("\nlearning:\n", f"\nlearning:\n  cycle_budget_pct: {pct:g}\n", 1), encoding="utf-8")
    return out


def _cli(*args: object) -> tuple[int, str]:
    res = runner.invoke(app, [str(a) for a in args])
    return res.exit_code, cli_output(res)


def _json(*args: object) -> dict:
    code, out = _cli(*args, "--json")
    assert code == 0, out
    return json.loads(out)


def _log(prog: Path, profile: Path, out: Path, against: Path | None = None) -> Path:
    _json("simulate", prog, "--profile", profile, "--log-out", out, *(["--against", against] if against else []))
    return out


def _step(profile: Path, log: Path, state: Path, out: Path, *extra: str) -> dict:
    return _json("learn", SQUARE, "--profile", profile, "--log", log, "--state", state, "--out", out, *extra)


@pytest.fixture(scope="module")
def refined_square(tmp_path_factory):
    """square.ngc refined from its log on linuxcnc-sim, one measured step under budgets of 100 %, 5 % (the
    default) and 0.5 %. The unbounded proposal plans +1.07 % (measured 4.787 -> 4.838 s)."""
    tmp = tmp_path_factory.mktemp("refined_square")
    log = _log(SQUARE, LCNC, tmp / "run0.csv")
    runs = {}
    for pct in (100.0, 5.0, 0.5):
        prof = _profile(LCNC, tmp, pct)
        st, out = tmp / f"st{pct:g}", tmp / f"square{pct:g}.ngc"
        runs[pct] = (_step(prof, log, st, out, "--refine"), LearnState.load(st), out)
    return tmp, log, runs


def test_a_measured_step_within_the_budget_is_not_held(refined_square):
    """Within the budget nothing changes: the output is byte for byte the one no budget limits, no clip is
    'cycle time', and the step reports the planned cycle time of the run next to its log's motion time."""
    _tmp, log, runs = refined_square
    free, within = runs[100.0], runs[5.0]
    assert within[2].read_bytes() == free[2].read_bytes()
    assert CLIP_CYCLE not in {c["cause"] for c in within[0]["clipped"]}
    state = within[1]
    profile = load_profile(LCNC)
    c0 = planned_duration_s(read_program(state.file(state.iterations[0].program)), profile)
    c1 = planned_duration_s(read_program(within[2]), profile)
    assert c0 < c1 <= 1.05 * c0 and c1 > 1.005 * c0  # over the small budget below, within the default
    it0 = within[0]["iterations"][0]
    assert it0["cycle_time_s"] == c0
    # the virtual CNC's log runs the original program (its motion 4.780 s); the refined program plans 4.787 s
    run0 = read_log(log)
    motion = motion_time_s(run0.t_s, run0.ref_mm)
    assert it0["log_motion_s"] == motion and motion == pytest.approx(c0, abs=0.01)
    note = next(n for n in within[0]["notes"] if n.startswith("cycle time: iteration 0 plans"))
    assert "on the profile's planner (linuxcnc)" in note and "learning.cycle_budget_pct 5 % allows" in note
    assert f"its log's motion took {motion:.3f} s" in note


def test_a_measured_proposal_over_a_small_budget_is_held(refined_square):
    """Under 0.5 % the corrections that slow LinuxCNC's planner are held back (measured: 64 coordinates, +1.07 %
    -> +0.40 %), each a 'cycle time' clip; only those coordinates differ from the unbounded proposal, and each
    lies between the previous correction (0) and the proposal."""
    runs = refined_square[2]
    st_free = runs[100.0][1]
    held, st_held, out = runs[0.5]
    profile = load_profile(LCNC)
    c0 = planned_duration_s(read_program(st_held.file(st_held.iterations[0].program)), profile)
    c1 = planned_duration_s(read_program(out), profile)
    assert c1 <= 1.005 * c0
    causes = Counter(c["cause"] for c in held["clipped"])
    assert causes[CLIP_CYCLE] > 0
    assert held["iterations"][1]["clipped"] == len(held["clipped"])
    u_free = st_free.read_corrections(st_free.iterations[1])
    u_held = st_held.read_corrections(st_held.iterations[1])
    changed = u_free != u_held
    cycle = {(c["k"], "xyz".index(c["axis"])) for c in held["clipped"] if c["cause"] == CLIP_CYCLE}
    assert {(int(k), int(a)) for k, a in zip(*np.nonzero(changed), strict=True)} <= cycle
    res = profile.machine.resolution_mm  # a held share is rounded to the resolution, as the law's output is
    assert np.all(np.abs(u_held) <= np.abs(u_free) + 0.5 * res + 1e-12) and np.all(u_held * u_free >= 0.0)
    note = next(n for n in held["notes"] if n.startswith("cycle-time budget:"))
    assert f"{causes[CLIP_CYCLE]} coordinates held back (clip 'cycle time')" in note and "over the budget" not in note


def test_a_measured_run_still_over_the_budget_is_refused_by_the_guard(tmp_path):
    """With a budget of 0 the unrefined square's first proposal plans 2 ms longer (one servo period on each of
    two sides: no move slowed by more than a period, so none to hold). The step says so; the next step refuses
    that run as the guard refuses a virtual run over the budget (not kept, the gain halved)."""
    prof = _profile(LCNC, tmp_path, 0.0)
    st = tmp_path / "st"
    first = _step(prof, _log(SQUARE, prof, tmp_path / "run0.csv"), st, tmp_path / "sq1.ngc")
    assert first["status"] == "stepped"
    assert any("still over the budget, the guard will refuse its run" in n for n in first["notes"])
    log1 = _log(tmp_path / "sq1.ngc", prof, tmp_path / "run1.csv", against=SQUARE)
    second = _step(prof, log1, st, tmp_path / "sq2.ngc")
    it1 = second["iterations"][1]
    assert it1["kept"] is False and it1["cycle_time_s"] == pytest.approx(4.782, abs=1e-9)
    assert ("iteration 1 made the error worse (cycle time 4.782 s over the budget's 4.780 s): not kept; the next"
            " program starts from iteration 0 with the gain halved") in second["notes"]
    assert LearnState.load(st).gain_scale == 0.5


def test_a_measured_step_stops_when_every_correction_would_be_held(tmp_path):
    """On the example mill with a budget of 0, every corner correction of the refined square slows its planner:
    the step stops with virtual learning's message, writes no program, and the state takes no further log."""
    prof = _profile(MILL, tmp_path, 0.0)
    log = _log(SQUARE, prof, tmp_path / "run0.csv")
    st, out = tmp_path / "st", tmp_path / "sq1.ngc"
    data = _step(prof, log, st, out, "--refine")
    assert data["status"] == "stopped" and not out.exists()
    assert data["message"].startswith("every correction left would slow the planner beyond learning.cycle_budget_pct"
                                      " (0 % of cycle time; 10 coordinates held): learning stopped; keep running")
    assert Counter(c["cause"] for c in data["clipped"]) == {CLIP_CYCLE: 10}
    before = sorted((p.name, p.read_bytes()) for p in st.iterdir())
    other = _log(SQUARE, LCNC, tmp_path / "other.csv")  # a log not used yet (another machine's samples)
    code, msg = _cli("learn", SQUARE, "--profile", prof, "--log", other, "--state", st, "--out", tmp_path / "sq2.ngc")
    assert code == 1 and "the run has ended with status stopped" in msg
    assert sorted((p.name, p.read_bytes()) for p in st.iterdir()) == before


def test_motion_time_of_a_halsampler_log():
    """tests/data/logs/halsampler.txt at 1 kHz: the reader keeps the samples from the first program line on
    (samples 2-6); their commanded position changes from sample 2 to sample 5 and stands at 6: 3 ms."""
    log = read_log(REPO / "tests" / "data" / "logs" / "halsampler.txt", period_s=1e-3)
    assert log.t_s.size == 5
    assert motion_time_s(log.t_s, log.ref_mm) == pytest.approx(3e-3, abs=1e-12)
    assert motion_time_s(log.t_s[3:], log.ref_mm[3:]) is None  # the last two samples stand still

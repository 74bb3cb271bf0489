"""Model-assisted measured learning (``learning.model_steps``, learn.model_assisted_correction).

The "machine" is the virtual CNC with a drive 22 % slower than the profile's model (time constant 34 ms
instead of 27.9 ms), so the model is good but not exact, as a real one is. The part is jscut's jsdc.gcode
(2,381 G01s) on configs/linuxcnc-sim.yaml. Measured 2026-11-23, four measured steps: 50.79 → 41.23 µm RMS
with the measured step alone, 50.79 → 37.02 µm with three model steps after each.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.learning.learner import Learner, model_assisted_correction
from ilcnc.profile.load import load_profile, profile_from_dict
from ilcnc.program import read_program
from ilcnc.vcnc.command_error import CommandSignal

REPO = Path(__file__).resolve().parents[1]
PROFILE = REPO / "configs" / "linuxcnc-sim.yaml"
JSDC = REPO / "samples" / "jsdc.gcode"
runner = CliRunner()


def _cli(*args: object) -> dict:
    res = runner.invoke(app, [str(a) for a in args] + ["--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


def _profile(tmp_path: Path, name: str, **learning: object) -> Path:
    d = load_profile(PROFILE).to_dict()
    d["learning"].update(learning)
    if name == "machine":
        for a in ("x", "y", "z"):
            d["axes"][a]["drive"]["time_constant_s"] = 0.034
    p = tmp_path / f"{name}.yaml"
    import yaml

    p.write_text(yaml.safe_dump(d), encoding="utf-8")
    return p


def _one_measured_step(tmp_path: Path, steps: int) -> tuple[float, float, list[str]]:
    """RMS of the machine's run of the original and of the program one measured step wrote, and the notes."""
    d = tmp_path / f"steps{steps}"
    d.mkdir()
    machine = _profile(tmp_path, "machine")
    model = _profile(d, "model", model_steps=steps)
    log0 = d / "run0.csv"
    run0 = _cli("simulate", JSDC, "--profile", machine, "--log-out", log0)
    step = _cli("learn", JSDC, "--profile", model, "--log", log0, "--state", d / "state", "--out", d / "jsdc.ilc1.gcode")
    run1 = _cli("simulate", d / "jsdc.ilc1.gcode", "--profile", machine, "--against", JSDC)
    return run0["contour_error_mm"]["rms"], run1["contour_error_mm"]["rms"], step["notes"]


def test_model_steps_take_the_measured_step_further(tmp_path: Path) -> None:
    e0, plain, notes0 = _one_measured_step(tmp_path, 0)
    e0b, assisted, notes3 = _one_measured_step(tmp_path, 3)
    assert e0 == e0b
    assert plain < e0
    # the model's steps, checked on the machine: more of the error goes in one measured iteration
    assert assisted < plain - 0.25 * (e0 - plain), (e0, plain, assisted)
    assert not any("model-assisted" in n for n in notes0)
    (note,) = [n for n in notes3 if n.startswith("model-assisted step:")]
    assert "of 3 virtual-CNC steps kept" in note and "predicted" in note


def _measured_step(kind: str) -> tuple[Learner, np.ndarray, CommandSignal, np.ndarray]:
    """A learner on jsdc, no correction run yet, a measured error of 1 µm per axis, a proposed step of 0.5 µm."""
    prog = read_program(JSDC)
    k = prog.n_commands
    sig = CommandSignal(np.full((k, 3), 1e-3), np.arange(k, dtype=float), np.ones(k, bool), kind)
    return Learner.for_program(prog, load_profile(PROFILE)), np.zeros((k, 3)), sig, np.full((k, 3), 5e-4)


def test_zero_steps_keep_the_measured_step() -> None:
    learner, u_meas, sig, u_step = _measured_step("path")
    u, clips, ms = model_assisted_correction(learner, u_meas, sig, u_step, [], 0)
    assert u is u_step and clips == [] and ms.made == 0 and ms.reason == "steps"
    assert ms.predicted_rms_mm == [pytest.approx(np.sqrt(3) * 1e-3)]


def test_a_signal_the_model_does_not_predict_takes_no_model_step() -> None:
    learner, u_meas, sig, u_step = _measured_step("points")
    u, _clips, ms = model_assisted_correction(learner, u_meas, sig, u_step, [], 3)
    assert u is u_step and ms.made == 0 and ms.reason == "kind"


def test_probed_points_take_no_model_step(tmp_path: Path) -> None:
    pts = tmp_path / "probe.csv"
    pts.write_text("k,dx,dy,dz\n" + "".join(f"{k},0.004,-0.002,0\n" for k in range(0, 2381, 7)))
    runs = {}
    for steps in (0, 3):
        model = _profile(tmp_path, f"model{steps}", model_steps=steps)
        runs[steps] = _cli("learn", JSDC, "--profile", model, "--points", pts, "--state", tmp_path / f"st{steps}",
                           "--out", tmp_path / f"p{steps}.gcode")
    assert (tmp_path / "p0.gcode").read_bytes() == (tmp_path / "p3.gcode").read_bytes()
    assert "no model-assisted step: probed points measure end points" in " ".join(runs[3]["notes"])
    assert not any("model-assisted" in n for n in runs[0]["notes"])


def test_model_steps_are_range_checked() -> None:
    d = load_profile(PROFILE).to_dict()
    d["learning"]["model_steps"] = 21
    with pytest.raises(Exception, match=r"learning\.model_steps: must be >= 0 and <= 20, got 21"):
        profile_from_dict(d)


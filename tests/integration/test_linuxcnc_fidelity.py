"""Fidelity against a real controller: the virtual CNC's prediction against LinuxCNC's motion.

``ilcnc simulate PROG --profile configs/linuxcnc-sim.yaml --compare LOG`` on a log LinuxCNC recorded of the
same program. PyCAM's ``tiny_cat_outline.ngc`` (CAMotics example, 2,808 G01 commands, ``G61`` exact path)
runs in ~40 s at ×8; the profile plans as LinuxCNC does (planner.profile linuxcnc) and its drive model was
identified on the same simulation, so the prediction must meet issue 9's targets (correlation ≥ 0.9,
difference ≤ 20 % of the error). Measured 2026-11-23: correlation 1.000, difference 3 %, sample contour RMS
3.23 µm measured against 3.41 µm predicted. A blended (plain ``G64``) program is checked in
test_linuxcnc_learning.py (jsdc: 0.986, 14 %).
"""

from __future__ import annotations

import pytest

from tests.conftest import SAMPLES
from tests.integration._lcnc import PROFILE, cli_json, needs_linuxcnc

pytestmark = needs_linuxcnc()


@pytest.fixture(scope="module")
def tiny_cat(tmp_path_factory: pytest.TempPathFactory) -> dict:
    d = tmp_path_factory.mktemp("lcnc-fidelity")
    part = d / "tiny_cat_outline.ngc"
    part.write_bytes((SAMPLES / "gcode" / "tiny_cat_outline.ngc").read_bytes())
    log = d / "run.csv"
    cli_json("linuxcnc", "run", part, "--log-out", log, "--time-scale", 8)
    return cli_json("simulate", part, "--profile", PROFILE, "--compare", log)["fidelity"]


def test_the_virtual_cnc_predicts_linuxcnc_in_exact_path_mode(tiny_cat: dict) -> None:
    f = tiny_cat
    assert f["commands"] >= 2700
    assert f["correlation"] >= 0.9
    assert all(c >= 0.9 for c in f["axis_correlation"].values())
    assert f["relative_difference"] <= 0.2
    assert f["trusted"] is True
    # the sample contour error, not only E(k): within 10 % in RMS and in max
    for key in ("rms", "max"):
        assert f["contour_predicted_mm"][key] == pytest.approx(f["contour_measured_mm"][key], rel=0.1)

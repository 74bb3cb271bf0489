"""Identify the drive of LinuxCNC's simulation from a step it records (``ilcnc.learning.identify`` on a real controller).

``configs/linuxcnc-sim`` closes a P position loop (``[ILCNC] KV`` = 30 1/s)
around a first-order velocity drive (τ = 5 ms) in HAL. A G1 move in X at
constant feed from rest is a commanded-position ramp (LinuxCNC's trapezoidal
planner: 1000 mm/s² up to 50 mm/s); the fit uses the commanded and actual X
positions of the halsampler log. Measured: first_order_delay T = 27.9 ms,
Td = 5.0 ms (T + Td = 32.9 ms against the loop's ramp lag 1/KV = 33.3 ms),
R² 0.999999999, fit RMS 0.8 µm against a 1.67 mm following error; sopdt
(no loop) ω0 = 86 rad/s, ζ = 1.39, no dead time, fit RMS 0.25 µm.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from ilcnc.learning.identify import identify_step
from ilcnc.learning.step_files import identify_file
from ilcnc.profile.load import load_profile
from ilcnc.profile.sections import FirstOrderDelayDrive
from ilcnc.shop import linuxcnc as lcnc
from ilcnc.vcnc.drives import axis_response

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "configs" / "linuxcnc-sim"
KV = 30.0

pytestmark = [
    pytest.mark.linuxcnc,
    pytest.mark.skipif(
        shutil.which("linuxcnc") is None,
        reason="LinuxCNC is not installed ('linuxcnc' not on PATH; Debian 12: apt-get install linuxcnc-uspace): "
        "cannot record a step on LinuxCNC's motion controller",
    ),
]

PROGRAM = """G21 G90 G17 G64 P0.001 Q0
G0 X0 Y0 Z0
G4 P0.1
G1 X60 F3000
G4 P0.3
M2
"""


@pytest.fixture(scope="module")
def step_run(tmp_path_factory: pytest.TempPathFactory) -> lcnc.RunResult:
    d = tmp_path_factory.mktemp("lcnc-identify")
    prog = d / "step.ngc"
    prog.write_text(PROGRAM)
    return lcnc.run_program(prog, CONFIG, d / "step.hal.log", time_scale=4, settle_s=0.3)


def test_first_order_delay_fits_the_recorded_step(step_run: lcnc.RunResult) -> None:
    log = step_run.log
    ident = identify_step(log.t_s, log.ref_mm[:, 0], log.act_mm[:, 0], model="first_order_delay", signal="position",
                          axis="x", u_name="x_ref", y_name="x_act")
    assert ident.r2 > 0.99999
    assert ident.fit_rms < 0.005
    assert ident.parameters["gain"] == pytest.approx(1.0, abs=1e-3)
    lag = ident.parameters["time_constant_s"] + ident.parameters["delay_s"]
    assert lag == pytest.approx(1.0 / KV, abs=0.002)
    assert 0.0 < ident.parameters["delay_s"] < 0.015  # the 5 ms velocity lag and a sample or two
    assert ident.warnings == ()


def test_sopdt_fits_the_raw_halsampler_log(step_run: lcnc.RunResult) -> None:
    ident = identify_file(step_run.log_path, axis="x", model="sopdt")
    assert ident.signal == "position"
    assert ident.r2 > 0.99999
    assert ident.fit_rms < 0.005


def test_written_model_reproduces_the_run(step_run: lcnc.RunResult, tmp_path: Path) -> None:
    """Store the fit in a copy of the simulation's profile; the virtual CNC then replays LinuxCNC's X axis."""
    prof_path = tmp_path / "linuxcnc-sim.yaml"
    shutil.copy(REPO / "configs" / "linuxcnc-sim.yaml", prof_path)
    ident = identify_file(step_run.log_path, axis="x", model="first_order_delay")
    ident.write_profile(prof_path, date="2026-01-01")
    prof = load_profile(prof_path)
    drive = prof.axes["x"].drive
    assert isinstance(drive, FirstOrderDelayDrive)
    before = load_profile(REPO / "configs" / "linuxcnc-sim.yaml")
    assert prof.axes["y"].drive == before.axes["y"].drive  # the other axes keep the shared model
    log = step_run.log
    replay = axis_response(drive, log.ref_mm[:, 0], prof.machine.servo_period_s)
    err = replay - log.act_mm[:, 0]
    assert float(np.sqrt(np.mean(err**2))) < 0.005  # mm
    assert "# ilcnc: identified 2026-01-01 by ilcnc identify from step.hal.log" in prof_path.read_text()

"""`ilcnc linuxcnc profile INI`: a machine profile from a LinuxCNC configuration (issue 23 item 6).

Run on configs/linuxcnc-sim's own INI (always here) and on LinuxCNC 2.9's sample configurations
(/usr/share/doc/linuxcnc/examples/sample-configs, skipped where LinuxCNC's examples are not installed).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.errors import InputError
from ilcnc.outcomes import DriveSource
from ilcnc.profile.load import load_profile
from ilcnc.shop.linuxcnc_profile import profile_from_ini
from ilcnc.units import MM_PER_INCH
from tests.conftest import OWN, REPO, cli_output

runner = CliRunner()
SIM_INI = REPO / "configs" / "linuxcnc-sim" / "sim.ini"
SIM_PROFILE = REPO / "configs" / "linuxcnc-sim.yaml"
EXAMPLES = Path("/usr/share/doc/linuxcnc/examples/sample-configs")


def _example(rel: str) -> Path:
    path = EXAMPLES / rel
    if not path.is_file():
        pytest.skip(f"needs LinuxCNC's sample configurations: {path} not found (Debian package linuxcnc-uspace)")
    return path


def _write(tmp_path: Path, ini: Path) -> Path:
    out = tmp_path / "gen.yaml"
    res = runner.invoke(app, ["linuxcnc", "profile", str(ini), "--out", str(out)])
    assert res.exit_code == 0, res.output
    return out


def _every_value_commented(text: str) -> None:
    """Each key: value line of the YAML (not a section header) has a comment saying where it comes from."""
    for line in text.splitlines():
        s = line.strip()
        if not s or s.startswith("#") or s.endswith(":") or s.startswith("dialect:"):
            continue
        assert "  # " in line, f"value without a source comment: {line!r}"


def test_sim_ini_agrees_with_the_shipped_profile_on_limits_period_and_path_control(tmp_path: Path) -> None:
    out = _write(tmp_path, SIM_INI)
    gen, ref = load_profile(out), load_profile(SIM_PROFILE)
    text = out.read_text()
    _every_value_commented(text)
    assert gen.machine.units == ref.machine.units == "mm"
    assert gen.machine.servo_period_s == ref.machine.servo_period_s == 0.001
    assert gen.machine.resolution_mm == ref.machine.resolution_mm
    for a in ("x", "y", "z"):
        g, r = gen.axes[a], ref.axes[a]
        assert (g.max_velocity_mm_min, g.max_acceleration_m_s2, g.rapid_mm_min, g.max_jerk_m_s3) == (
            r.max_velocity_mm_min, r.max_acceleration_m_s2, r.rapid_mm_min, r.max_jerk_m_s3)
    for key in ("profile", "corner_tolerance_mm", "path_control", "in_position_s"):
        assert getattr(gen.planner, key) == getattr(ref.planner, key), key
    # The one difference is the drive: the shipped profile holds a model fitted to a recorded step
    # (first_order_delay, T = 27.9 ms, Td = 5 ms); the INI gives only the HAL's PID gain Kv = [ILCNC]KV = 30 1/s.
    assert ref.axes["x"].drive.model == "first_order_delay"
    assert gen.axes["x"].drive.model == "p_ff_friction"
    assert gen.axes["x"].drive.kp_m_min_mm == pytest.approx(30 * 0.06)  # 1 (m/min)/mm = 1000/60 1/s
    assert re.search(r"kp_m_min_mm: 1.8  # sim.hal:\d+ setp pid.x.Pgain \[ILCNC\]KV = 30", text)
    assert re.search(r"velocity_bandwidth_hz: 100  # not from the INI: .*ilcnc identify", text)
    assert "max_velocity_mm_min: 6000  # [AXIS_X] MAX_VELOCITY = 100 mm/s x 60" in text
    assert "servo_period_s: 0.001  # [EMCMOT] SERVO_PERIOD = 1000000 ns" in text
    # travel is written commented out (machine coordinates); uncommented it loads
    travel = "\n".join(ln.replace("  # ", "  ", 1) if re.match(r"  #\s+(travel_mm:|[xyz]: \[)", ln) else ln
                       for ln in text.splitlines())
    p2 = tmp_path / "travel.yaml"
    p2.write_text(travel)
    assert load_profile(p2).machine.travel_mm["x"] == (-1000.0, 1000.0)


def test_generated_profile_runs_a_simulation(tmp_path: Path) -> None:
    out = _write(tmp_path, SIM_INI)
    res = runner.invoke(app, ["simulate", str(OWN / "square.ngc"), "--profile", str(out), "--json"])
    assert res.exit_code == 0, res.output
    d = json.loads(cli_output(res))
    assert d["samples"] > 1000


def test_never_overwrites_without_force_and_never_an_input(tmp_path: Path) -> None:
    out = tmp_path / "p.yaml"
    out.write_text("keep\n")
    res = runner.invoke(app, ["linuxcnc", "profile", str(SIM_INI), "--out", str(out)])
    assert res.exit_code == 2 and "--force" in cli_output(res)
    assert out.read_text() == "keep\n"
    assert runner.invoke(app, ["linuxcnc", "profile", str(SIM_INI), "--out", str(out), "--force"]).exit_code == 0
    assert load_profile(out).machine.units == "mm"
    ini = tmp_path / "m.ini"
    ini.write_text(SIM_INI.read_text().replace("HALFILE = sim.hal", "HALFILE = " + str(SIM_INI.parent / "sim.hal")))
    res = runner.invoke(app, ["linuxcnc", "profile", str(ini), "--out", str(ini), "--force"])
    assert res.exit_code == 1 and "refusing to write over an input" in cli_output(res)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


@pytest.mark.parametrize(("edit", "problem"), [
    (("LINEAR_UNITS = mm\n", ""), "[TRAJ] LINEAR_UNITS is missing"),
    (("LINEAR_UNITS = mm", "LINEAR_UNITS = furlong"), "[TRAJ] LINEAR_UNITS 'furlong'"),
    (("[AXIS_X]\nMIN_LIMIT = -1000\nMAX_LIMIT = 1000\nMAX_VELOCITY = 100", "[AXIS_X]\nMIN_LIMIT = -1000\n"
      "MAX_LIMIT = 1000\nMAX_VELOCITY = fast"), "[AXIS_X] MAX_VELOCITY 'fast' is not a number"),
    (("SERVO_PERIOD = 1000000", "SERVO_PERIOD = 1000000000"), "[EMCMOT] SERVO_PERIOD 1000000000 ns is outside"),
    (("HALFILE = sim.hal", "HALFILE = nothere.hal"), "[HAL] HALFILE nothere.hal: not found"),
])
def test_malformed_ini_is_refused_at_its_line(tmp_path: Path, edit: tuple[str, str], problem: str) -> None:
    text = SIM_INI.read_text()
    assert edit[0] in text
    bad = text.replace(edit[0], edit[1], 1)
    ini = tmp_path / "bad.ini"
    ini.write_text(bad)
    (tmp_path / "sim.hal").write_text((SIM_INI.parent / "sim.hal").read_text())
    res = runner.invoke(app, ["linuxcnc", "profile", str(ini)])
    assert res.exit_code == 1
    err = cli_output(res).strip()
    assert err.startswith(f"error: {ini}") and problem in err and len(err.splitlines()) == 1
    if "is missing" not in problem:  # a bad value names its own line
        line = int(err.split(":")[2])
        assert problem.split()[1].split("'")[0] in bad.splitlines()[line - 1] or "HALFILE" in problem


def test_includes_are_expanded_and_a_missing_one_noted(tmp_path: Path) -> None:
    inc = tmp_path / "traj.inc"
    text = SIM_INI.read_text()
    start, end = text.index("[TRAJ]"), text.index("[KINS]")
    inc.write_text(text[start:end])
    (tmp_path / "sim.hal").write_text((SIM_INI.parent / "sim.hal").read_text())
    ini = tmp_path / "m.ini"
    ini.write_text(text[:start] + "#INCLUDE traj.inc\n#INCLUDE gone.inc\n" + text[end:])
    res = profile_from_ini(ini)
    assert res.units == "mm" and res.axes[0].max_velocity_mm_s == 100
    assert any("gone.inc cannot be read" in n for n in res.notes)
    with pytest.raises(InputError, match=r"traj.inc:\d+: \[TRAJ\] LINEAR_UNITS 'yards'"):
        inc.write_text(text[start:end].replace("LINEAR_UNITS = mm", "LINEAR_UNITS = yards"))
        profile_from_ini(ini)


def test_sim_config_loopback_mm() -> None:
    res = profile_from_ini(_example("sim/axis/axis_mm.ini"))
    assert res.units == "mm" and res.path_control == "g64"
    assert [a.drive for a in res.axes] == [DriveSource.LOOPBACK] * 3
    drive = yaml.safe_load(res.text)["axes"]["x"]["drive"]
    assert drive == {"model": "first_order_delay", "gain": 1, "time_constant_s": 1e-6, "delay_s": 0}


def test_servo_config_pid_gains_from_the_ini_through_hal_inch(tmp_path: Path) -> None:
    ini = _example("by_machine/boss/boss.ini")
    res = profile_from_ini(ini)
    assert res.units == "inch" and res.servo_period_s == pytest.approx(200e-6)
    assert [a.drive for a in res.axes] == [DriveSource.SERVO_PID] * 3
    x = res.axes[0]
    # [AXIS_X] MAX_VELOCITY = 2.0 in/s, [JOINT_0] 2.0, [TRAJ] MAX_LINEAR_VELOCITY 2.5: the smallest, in mm
    assert x.max_velocity_mm_s == pytest.approx(2.0 * MM_PER_INCH)
    assert x.max_acceleration_mm_s2 == pytest.approx(10.0 * MM_PER_INCH)
    d = yaml.safe_load(res.text)["axes"]["x"]["drive"]
    assert d["kp_m_min_mm"] == pytest.approx(60.0 * 0.06) and d["kff"] == 1  # boss.ini [JOINT_0] P = 60, FF1 = 1
    assert "setp pid.0.Pgain [JOINT_0]P = 60.0" in res.text
    assert any("pid.0.Igain [JOINT_0]I = 1250.0" in n for n in res.notes)  # not modelled: said so
    _every_value_commented(res.text)
    out = _write(tmp_path, ini)
    assert load_profile(out).machine.units == "inch"


def test_stepper_config() -> None:
    res = profile_from_ini(_example("by_interface/parport/stepper/stepper_mm.ini"))
    assert [a.drive for a in res.axes] == [DriveSource.STEPGEN] * 3
    d = yaml.safe_load(res.text)["axes"]["x"]["drive"]
    assert d["model"] == "first_order_delay" and d["delay_s"] == res.servo_period_s
    assert "stepgen" in res.text


def test_startup_code_sets_bounded_path_control() -> None:
    res = profile_from_ini(_example("sim/qtvcp_screens/woodpecker/woodpecker_xyz.ini"))
    assert res.path_control == "tolerance" and res.corner_tolerance_mm == pytest.approx(0.005)
    assert "RS274NGC_STARTUP_CODE = G17 G21" in res.text

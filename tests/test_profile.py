"""Tests of the YAML machine profile (ilcnc.profile.schema)."""

from __future__ import annotations

import copy
import dataclasses
import re
from pathlib import Path
from typing import Any

import pytest

from ilcnc.errors import InputError, ProfileError
from ilcnc.profile.docs import schema_markdown
from ilcnc.profile.load import default_profile, load_profile, profile_from_dict
from ilcnc.profile.schema import SPECS
from ilcnc.profile.sections import (
    DRIVE_MODELS,
    FirstOrderDelayDrive,
    MachineProfile,
    MassDamperPidDrive,
    PFfFrictionDrive,
    SopdtDrive,
    TransferFunctionDrive,
    has_position_loop,
)
from ilcnc.units import AXIS_NAMES

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
EXAMPLE = CONFIGS / "example-mill.yaml"

MINIMAL = """\
machine:
  name: test mill
axes:
  x:
    max_velocity_mm_min: 10000
    max_acceleration_m_s2: 2
    max_jerk_m_s3: 20
    drive:
      model: sopdt
      omega0_rad_s: 95.6
      zeta: 1.0
  y:
    max_velocity_mm_min: 10000
    max_acceleration_m_s2: 2
    max_jerk_m_s3: 20
    drive:
      model: first_order_delay
      time_constant_s: 0.02
"""


def write(tmp_path: Path, text: str, name: str = "mill.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def line_of(text: str, fragment: str) -> int:
    """1-based number of the (unique) line containing ``fragment``."""
    hits = [i for i, line in enumerate(text.splitlines(), 1) if fragment in line]
    assert len(hits) == 1, (fragment, hits)
    return hits[0]


def error_of(tmp_path: Path, text: str) -> str:
    p = write(tmp_path, text)
    with pytest.raises(ProfileError) as info:
        load_profile(p)
    msg = str(info.value)
    assert "\n" not in msg
    assert "Traceback" not in msg
    return msg


# -- shipped files ----------------------------------------------------------


def test_example_mill_loads() -> None:
    p = load_profile(EXAMPLE)
    assert p.machine.name
    assert p.axis_names == ("x", "y", "z")
    x = p.axes["x"]
    assert isinstance(x.drive, SopdtDrive)
    assert x.drive.omega0_rad_s == pytest.approx(95.6)
    assert x.drive.zeta == pytest.approx(1.0)
    assert x.drive.delay_s == pytest.approx(0.0066)
    assert x.drive.gain == 1.0
    assert x.drive.position_gain_1_s is None
    assert x.max_velocity_mm_min == 30000
    assert p.path == EXAMPLE
    assert p.source_text == EXAMPLE.read_text(encoding="utf-8")
    # the example documents every top-level section in its comment header
    header = p.source_text.split("\nmachine:")[0]
    for section in ("machine:", "axes:", "controller:", "planner:", "learning:", "output:"):
        assert f"# {section}" in header


def test_example_mill_is_the_default_profile() -> None:
    assert load_profile(EXAMPLE) == default_profile()


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.yaml")), ids=lambda p: p.name)
def test_every_shipped_config_loads(path: Path) -> None:
    p = load_profile(path)
    assert isinstance(p, MachineProfile)
    assert p.axes


def test_there_is_at_least_one_shipped_config() -> None:
    assert EXAMPLE.is_file()


# -- values, defaults and units ---------------------------------------------


def test_defaults_filled(tmp_path: Path) -> None:
    p = load_profile(write(tmp_path, MINIMAL))
    assert p.machine.units == "mm"
    assert p.machine.servo_period_s == 0.001
    assert p.machine.resolution_mm == 0.001
    assert p.machine.travel_mm == {}
    x, y = p.axes["x"], p.axes["y"]
    assert x.rapid_mm_min == x.max_velocity_mm_min == 10000
    assert x.drive == SopdtDrive(omega0_rad_s=95.6, zeta=1.0, gain=1.0, delay_s=0.0, position_gain_1_s=None)
    assert y.drive == FirstOrderDelayDrive(time_constant_s=0.02, delay_s=0.0, gain=1.0)
    assert p.controller.type == "independent"
    assert p.controller.cross_coupling_gain == 0.0
    assert p.controller.coupled_axes == ("x", "y")
    assert p.planner.profile == "seven_phase"
    assert p.planner.corner_tolerance_mm == 0.01
    assert p.planner.lookahead_blocks == 200
    assert p.planner.jerk_time_constant_s == 0.01
    assert p.planner.arc_tolerance_mm == 0.001
    assert p.learning.law == "p"
    assert p.learning.gains == {"gamma": 0.5}
    assert p.learning.iterations == 5
    assert p.learning.correction_bound_mm == 0.5
    assert p.learning.stop_tolerance_mm == 0.001
    assert p.learning.q_filter_hz is None
    assert p.learning.lead_commands == 0
    assert p.output.dialect == "auto"
    assert p.output.decimals is None


def test_dataclass_defaults_match_the_schema() -> None:
    """Defaults are defined once (SPECS); the dataclasses must agree with it."""
    for model, cls in DRIVE_MODELS.items():
        for f in dataclasses.fields(cls):
            spec = next(s for s in SPECS if s.key == f.name and s.when and s.when[1] == model)
            if f.default is dataclasses.MISSING:
                assert spec.required, (model, f.name)
            else:
                assert f.default == spec.default, (model, f.name)


def test_unit_helpers() -> None:
    x = default_profile().axes["x"]
    assert x.max_velocity_mm_s == pytest.approx(30000 / 60)
    assert x.rapid_mm_s == pytest.approx(36000 / 60)
    assert x.max_acceleration_mm_s2 == pytest.approx(3000.0)
    assert x.max_jerk_mm_s3 == pytest.approx(50000.0)
    assert PFfFrictionDrive(kp_m_min_mm=3.0).kp_1_s == pytest.approx(50.0)


def test_min_decimals() -> None:
    p = default_profile()
    assert p.min_decimals("mm") == 3  # 0.001 mm
    assert p.min_decimals("inch") == 5  # 0.001 mm = 0.0000394 in
    fine = profile_from_dict(_with(p.to_dict(), ("machine", "resolution_mm"), 0.0001))
    assert fine.min_decimals("mm") == 4
    assert fine.min_decimals("inch") == 6
    coarse = profile_from_dict(_with(p.to_dict(), ("machine", "resolution_mm"), 0.01))
    assert coarse.min_decimals("mm") == 2
    fixed = profile_from_dict(_with(p.to_dict(), ("output", "decimals"), 4))
    assert fixed.min_decimals("mm") == fixed.min_decimals("inch") == 4
    with pytest.raises(ValueError):
        p.min_decimals("furlong")


def test_exponent_without_dot_is_a_number(tmp_path: Path) -> None:
    text = MINIMAL.replace("  name: test mill\n", "  name: test mill\n  servo_period_s: 5e-4\n")
    assert load_profile(write(tmp_path, text)).machine.servo_period_s == 5e-4


def test_all_drive_models_and_laws(tmp_path: Path) -> None:
    text = """\
machine: {name: m, units: inch, travel_mm: {x: [-10, 500], z: [-300, 0]}}
axes:
  x:
    max_velocity_mm_min: 20000
    max_acceleration_m_s2: 1.5
    max_jerk_m_s3: 30
    rapid_mm_min: 24000
    drive: {model: mass_damper_pid, mass_v_s2_mm: 0.45, damping_v_s_mm: 0.144, kp: 0.96, ki: 0.01, kd: 8}
  y:
    max_velocity_mm_min: 20000
    max_acceleration_m_s2: 1.5
    max_jerk_m_s3: 30
    drive:
      model: p_ff_friction
      kp_m_min_mm: 2
      kff: 0.8
      inertia_kg: 120
      coulomb_n: 40
      static_n: 60
      stribeck_velocity_mm_s: 2
      viscous_n_s_mm: 0.5
  z:
    max_velocity_mm_min: 15000
    max_acceleration_m_s2: 1.0
    max_jerk_m_s3: 20
    drive: {model: sopdt, omega0_rad_s: 80, zeta: 0.7, delay_s: 0.005, position_gain_1_s: 30}
controller: {type: cross_coupled, cross_coupling_gain: 2.5, coupled_axes: [y, x]}
planner: {profile: cubic, jerk_time_constant_s: 0.02}
learning:
  law: second_order
  gains: {q1: {x: 0.5, y: 0.6, z: 0.5}, p1: 0.9, p2: 0.1}
  q_filter_hz: 50
output: {dialect: heidenhain, decimals: 4}
"""
    p = load_profile(write(tmp_path, text))
    assert p.machine.units == "inch"
    assert p.machine.travel_mm == {"x": (-10.0, 500.0), "z": (-300.0, 0.0)}
    assert p.axes["x"].drive == MassDamperPidDrive(0.45, 0.144, 0.96, 0.01, 8.0)
    y = p.axes["y"].drive
    assert isinstance(y, PFfFrictionDrive) and y.has_friction and y.inertia_kg == 120
    assert y.velocity_bandwidth_hz == 100.0
    assert p.axes["z"].drive.position_gain_1_s == 30
    assert p.controller.coupled_axes == ("y", "x")
    assert p.planner.profile == "cubic"
    assert p.learning.gains == {"p1": 0.9, "p2": 0.1, "q1": {"x": 0.5, "y": 0.6, "z": 0.5}, "q2": 0.0}
    assert p.learning.gain("q1", "y") == 0.6
    assert p.learning.gain("p1", "z") == 0.9
    assert p.output.dialect == "heidenhain"
    assert profile_from_dict(p.to_dict()) == p


def test_pid_ace_gains(tmp_path: Path) -> None:
    text = MINIMAL + "learning:\n  law: pid_ace\n  gains: {kp: 0.468, kd: 0.0443, lead_samples: 3}\n"
    p = load_profile(write(tmp_path, text))
    assert p.learning.gains == {"kp": 0.468, "ki": 0.0, "kd": 0.0443, "lead_samples": 3}


def test_empty_sections_take_defaults(tmp_path: Path) -> None:
    text = MINIMAL + "controller:\nplanner:\nlearning:\noutput:\n"
    assert load_profile(write(tmp_path, text)) == load_profile(write(tmp_path, MINIMAL, "b.yaml"))


def test_aliases(tmp_path: Path) -> None:
    text = MINIMAL.replace("    drive:\n      model: sopdt", "    drive: &d\n      model: sopdt").replace(
        "    drive:\n      model: first_order_delay\n      time_constant_s: 0.02\n", "    drive: *d\n"
    )
    p = load_profile(write(tmp_path, text))
    assert p.axes["y"].drive == p.axes["x"].drive


def test_a_merge_key_and_a_key_given_again_are_not_duplicates(tmp_path: Path) -> None:
    # the lines of the keys are read from the text as written, before the data merges '<<' into the mapping
    # (the one parse of ilcnc.profile.load._parse_yaml)
    text = MINIMAL.replace("  x:\n", "  x: &xa\n").replace(
        "  y:\n    max_velocity_mm_min: 10000\n", "  y:\n    <<: *xa\n    max_velocity_mm_min: 12000\n")
    p = load_profile(write(tmp_path, text))
    assert p.axes["y"].max_velocity_mm_min == 12000 and p.axes["y"].max_jerk_m_s3 == 20
    bad = text.replace("max_velocity_mm_min: 12000", "max_velocity_mm_min: -1")
    line = bad.splitlines().index("    max_velocity_mm_min: -1") + 1
    with pytest.raises(ProfileError, match=rf"mill.yaml:{line}: axes.y.max_velocity_mm_min: must be"):
        load_profile(write(tmp_path, bad))


# -- round trip ---------------------------------------------------------------


def test_to_dict_round_trip() -> None:
    p = load_profile(EXAMPLE)
    d = p.to_dict()
    q = profile_from_dict(d)
    assert q == p
    assert q.to_dict() == d
    assert profile_from_dict(copy.deepcopy(d)).to_dict() == d


def test_to_yaml_round_trip(tmp_path: Path) -> None:
    p = default_profile()
    path = write(tmp_path, p.to_yaml(), "dumped.yaml")
    assert load_profile(path) == p


def test_path_and_source_text_do_not_take_part_in_equality(tmp_path: Path) -> None:
    a = load_profile(write(tmp_path, MINIMAL, "a.yaml"))
    b = load_profile(write(tmp_path, "# other comments\n" + MINIMAL, "b.yaml"))
    assert a == b and a.path != b.path


# -- errors: file, line, YAML path, range ------------------------------------


def test_negative_jerk(tmp_path: Path) -> None:
    text = MINIMAL.replace(
        "max_jerk_m_s3: 20\n    drive:\n      model: sopdt", "max_jerk_m_s3: -5\n    drive:\n      model: sopdt"
    )
    msg = error_of(tmp_path, text)
    assert (
        msg
        == f"{tmp_path / 'mill.yaml'}:{line_of(text, '-5')}: axes.x.max_jerk_m_s3: must be >= 0.001 and <= 100000, got -5"
    )


def test_zero_velocity(tmp_path: Path) -> None:
    text = MINIMAL.replace("  y:\n    max_velocity_mm_min: 10000", "  y:\n    max_velocity_mm_min: 0")
    msg = error_of(tmp_path, text)
    assert msg.startswith(f"{tmp_path / 'mill.yaml'}:{line_of(text, 'max_velocity_mm_min: 0')}: ")
    assert "axes.y.max_velocity_mm_min: must be >= 1 and <= 1000000, got 0" in msg


def test_unknown_key(tmp_path: Path) -> None:
    text = MINIMAL.replace(
        "max_jerk_m_s3: 20\n    drive:\n      model: sopdt", "jerk: 20\n    drive:\n      model: sopdt"
    )
    msg = error_of(tmp_path, text)
    assert f"mill.yaml:{line_of(text, 'jerk: 20')}: axes.x.jerk: unknown key; allowed: " in msg
    assert "max_jerk_m_s3" in msg and "max_velocity_mm_min" in msg


def test_unknown_top_level_key(tmp_path: Path) -> None:
    text = MINIMAL + "planer:\n  profile: cubic\n"
    msg = error_of(tmp_path, text)
    assert f"mill.yaml:{line_of(text, 'planer:')}: planer: unknown key; allowed: machine, axes, controller" in msg


def test_key_of_another_drive_model(tmp_path: Path) -> None:
    text = MINIMAL.replace("      zeta: 1.0\n", "      zeta: 1.0\n      time_constant_s: 0.1\n")
    msg = error_of(tmp_path, text)
    assert f"mill.yaml:{line_of(text, 'time_constant_s: 0.1')}: axes.x.drive.time_constant_s: unknown key" in msg
    assert "for model sopdt; allowed: model, gain, omega0_rad_s, zeta, delay_s, position_gain_1_s" in msg


def test_wrong_type(tmp_path: Path) -> None:
    text = MINIMAL.replace("zeta: 1.0", "zeta: critical")
    msg = error_of(tmp_path, text)
    assert msg.endswith(
        f"mill.yaml:{line_of(text, 'critical')}: axes.x.drive.zeta: must be a number > 0 and <= 10, got 'critical'"
    )


def test_wrong_type_integer(tmp_path: Path) -> None:
    text = MINIMAL + "planner:\n  lookahead_blocks: 2.5\n"
    msg = error_of(tmp_path, text)
    assert f"mill.yaml:{line_of(text, '2.5')}: planner.lookahead_blocks: must be an integer >= 1 and <= 100000" in msg


def test_boolean_is_not_a_number(tmp_path: Path) -> None:
    text = MINIMAL.replace("zeta: 1.0", "zeta: true")
    msg = error_of(tmp_path, text)
    assert f":{line_of(text, 'zeta: true')}: axes.x.drive.zeta: must be a number > 0 and <= 10, got true" in msg


def test_nan_is_rejected(tmp_path: Path) -> None:
    text = MINIMAL.replace("zeta: 1.0", "zeta: .nan")
    msg = error_of(tmp_path, text)
    assert f":{line_of(text, '.nan')}: axes.x.drive.zeta: must be a finite number > 0 and <= 10" in msg


def test_bad_choice(tmp_path: Path) -> None:
    text = MINIMAL.replace("model: first_order_delay", "model: pt1")
    msg = error_of(tmp_path, text)
    assert msg.endswith(
        f"mill.yaml:{line_of(text, 'pt1')}: axes.y.drive.model: must be one of sopdt, mass_damper_pid,"
        " p_ff_friction, first_order_delay, transfer_function, got 'pt1'"
    )


def test_missing_drive_parameter(tmp_path: Path) -> None:
    text = MINIMAL.replace("      omega0_rad_s: 95.6\n", "")
    msg = error_of(tmp_path, text)
    # reported at the drive: line, since the key itself is absent
    drive_line = line_of(text, "model: sopdt") - 1
    assert msg.endswith(
        f"mill.yaml:{drive_line}: axes.x.drive.omega0_rad_s: missing required key (rad/s, > 0 and <= 100000)"
    )


def test_missing_required_section(tmp_path: Path) -> None:
    text = MINIMAL.split("axes:")[0]
    msg = error_of(tmp_path, text)
    assert re.search(r"mill\.yaml:1: axes: missing required section", msg), msg


def test_missing_machine_name(tmp_path: Path) -> None:
    text = MINIMAL.replace("  name: test mill\n", "  units: mm\n")
    msg = error_of(tmp_path, text)
    assert msg.endswith("mill.yaml:1: machine.name: missing required key")


def test_no_axes(tmp_path: Path) -> None:
    text = "machine: {name: m}\naxes: {}\n"
    msg = error_of(tmp_path, text)
    assert msg.endswith("mill.yaml:2: axes: at least one axis is required; allowed: x, y, z")


def test_uppercase_axis(tmp_path: Path) -> None:
    text = MINIMAL.replace("  y:\n", "  Y:\n")
    msg = error_of(tmp_path, text)
    assert msg.endswith(
        f"mill.yaml:{line_of(text, '  Y:')}: axes.Y: unknown axis (axis names are lowercase); allowed: x, y, z"
    )


def test_bad_yaml_syntax(tmp_path: Path) -> None:
    text = MINIMAL.replace("zeta: 1.0", "zeta: [1.0")
    msg = error_of(tmp_path, text)
    m = re.match(rf"^{re.escape(str(tmp_path / 'mill.yaml'))}:(\d+): invalid YAML: ", msg)
    assert m, msg
    assert line_of(text, "zeta: [1.0") <= int(m.group(1)) <= len(text.splitlines()) + 1


def test_bad_yaml_indentation(tmp_path: Path) -> None:
    text = MINIMAL.replace("  name: test mill", "  name: test mill\n units: mm")
    msg = error_of(tmp_path, text)
    assert re.search(rf"mill\.yaml:{line_of(text, ' units: mm')}: invalid YAML: ", msg), msg


def test_tab_indentation(tmp_path: Path) -> None:
    text = MINIMAL.replace("  name: test mill", "\tname: test mill")
    msg = error_of(tmp_path, text)
    assert re.search(rf"mill\.yaml:{line_of(text, 'name: test mill')}: invalid YAML: .*'\\t'", msg), msg


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n", "---\n"])
def test_empty_file(tmp_path: Path, text: str) -> None:
    msg = error_of(tmp_path, text)
    assert msg == (
        f"{tmp_path / 'mill.yaml'}:1: empty profile; expected a mapping with the sections"
        " machine, axes, controller, planner, learning, output, geometry, tool, cutting, tuning"
    )


@pytest.mark.parametrize(("text", "got"), [("- a\n- b\n", "a list"), ("just text\n", "'just text'"), ("42\n", "42")])
def test_top_level_not_a_mapping(tmp_path: Path, text: str, got: str) -> None:
    msg = error_of(tmp_path, text)
    assert msg.endswith(
        f"mill.yaml:1: the profile must be a mapping with the sections machine, axes, controller,"
        f" planner, learning, output, geometry, tool, cutting, tuning, got {got}"
    )


def test_duplicate_key(tmp_path: Path) -> None:
    text = MINIMAL.replace("      zeta: 1.0\n", "      zeta: 1.0\n      zeta: 0.7\n")
    msg = error_of(tmp_path, text)
    assert msg.endswith(
        f"mill.yaml:{line_of(text, 'zeta: 0.7')}: axes.x.drive.zeta: duplicate key (first given on line"
        f" {line_of(text, 'zeta: 1.0')})"
    )


def test_section_not_a_mapping(tmp_path: Path) -> None:
    text = MINIMAL + "planner: fast\n"
    msg = error_of(tmp_path, text)
    assert f"mill.yaml:{line_of(text, 'planner: fast')}: planner: must be a mapping with keys profile," in msg
    assert msg.endswith("got 'fast'")


@pytest.mark.parametrize(
    ("extra", "fragment", "expected"),
    [
        ("planner:\n  corner_tolerance_mm: 11\n", "11", "planner.corner_tolerance_mm: must be >= 0 and <= 10, got 11"),
        ("learning:\n  iterations: 0\n", "iterations", "learning.iterations: must be >= 1 and <= 1000, got 0"),
        ("learning:\n  gains: {gamma: 12.5}\n", "gamma", "learning.gains.gamma: must be > 0 and <= 10, got 12.5"),
        (
            "learning:\n  gains:\n    gamma: {x: 0.5, y: 0}\n",
            "gamma",
            "learning.gains.gamma.y: must be > 0 and <= 10, got 0",
        ),
        (
            "learning:\n  gains:\n    gamma: {x: 0.5}\n",
            "gamma",
            "learning.gains.gamma.y: missing; a per-axis gain must give every axis (x, y) or be one number",
        ),
        (
            "learning:\n  gains:\n    gamma: {x: 0.5, y: 0.5, z: 0.5}\n",
            "gamma",
            "learning.gains.gamma.z: axis z is not defined under axes (defined: x, y)",
        ),
        (
            "learning:\n  law: pid_ace\n  gains: {kd: 0.04}\n",
            "gains",
            "learning.gains.kp: missing required key (>= 0 and <= 1000000)",
        ),
        (
            "learning:\n  law: second_order\n  gains: {q1: 11}\n",
            "q1",
            "learning.gains.q1: must be >= -10 and <= 10, got 11",
        ),
        (
            "learning:\n  law: pid_ace\n  gains: {gamma: 0.5}\n",
            "gamma",
            "learning.gains.gamma: unknown key for law pid_ace; allowed: kp, ki, kd, lead_samples",
        ),
        ("output:\n  decimals: 9\n", "decimals", "output.decimals: must be >= 0 and <= 8, got 9"),
        ("output:\n  dialect: siemens\n", "siemens", "output.dialect: must be one of auto, linuxcnc, fanuc, grbl,"),
        (
            "controller:\n  type: cross_coupled\n  cross_coupling_gain: 1\n  theta: drawing\n",
            "theta",
            "controller.theta: must be one of reference, desired, got 'drawing'",
        ),
        (
            "controller:\n  type: cross_coupled\n",
            "type: cross",
            "controller.cross_coupling_gain: must be > 0 and <= 10000 when controller.type is cross_coupled, got 0",
        ),
        (
            "controller:\n  type: cross_coupled\n  cross_coupling_gain: 1\n  coupled_axes: [x, z]\n",
            "coupled_axes",
            "controller.coupled_axes: axis z is not defined under axes (defined: x, y)",
        ),
        (
            "controller:\n  coupled_axes: [x, x]\n",
            "coupled_axes",
            "controller.coupled_axes: must be a list of two different axis names from x, y, z, got [x, x]",
        ),
    ],
)
def test_out_of_range_and_rules(tmp_path: Path, extra: str, fragment: str, expected: str) -> None:
    text = MINIMAL + extra
    msg = error_of(tmp_path, text)
    assert msg.startswith(f"{tmp_path / 'mill.yaml'}:{line_of(text, fragment)}: {expected}"), msg


@pytest.mark.parametrize(
    ("machine", "expected"),
    [
        ("servo_period_s: 1e-6", "machine.servo_period_s: must be >= 1e-05 and <= 0.1, got 1e-06"),
        ("resolution_mm: 0", "machine.resolution_mm: must be >= 1e-06 and <= 0.1, got 0"),
        ("units: cm", "machine.units: must be one of mm, inch, got 'cm'"),
        (
            "travel_mm: {x: [100, 0]}",
            "machine.travel_mm.x: must be a list [min, max] of two numbers >= -100000 and <= 100000 with min < max,"
            " got min 100 >= max 0",
        ),
        ("travel_mm: {z: [0, 100]}", "machine.travel_mm.z: axis z is not defined under axes (defined: x, y)"),
    ],
)
def test_machine_errors(tmp_path: Path, machine: str, expected: str) -> None:
    text = MINIMAL.replace("  name: test mill\n", f"  name: test mill\n  {machine}\n")
    msg = error_of(tmp_path, text)
    assert msg == f"{tmp_path / 'mill.yaml'}:{line_of(text, machine)}: {expected}"


@pytest.mark.parametrize(
    ("drive", "fragment", "expected"),
    [
        (
            "{model: mass_damper_pid, mass_v_s2_mm: 0.45, damping_v_s_mm: 0.1, kp: 1, kd: 8}",
            "mass_damper_pid",
            "axes.x.drive.ki: missing required key (V/(mm·s), >= 0 and <= 1000000)",
        ),
        (
            "{model: p_ff_friction, kp_m_min_mm: 2, coulomb_n: 30}",
            "p_ff_friction",
            "axes.x.drive.inertia_kg: missing; required (> 0 and <= 100000, kg) when a friction term is non-zero",
        ),
        (
            "{model: p_ff_friction, kp_m_min_mm: 2, inertia_kg: 100, coulomb_n: 30, static_n: 20}",
            "p_ff_friction",
            "axes.x.drive.static_n: must be 0 or >= coulomb_n (30), got 20",
        ),
        (
            "{model: p_ff_friction, kp_m_min_mm: 2, inertia_kg: 100, coulomb_n: 30, static_n: 50}",
            "p_ff_friction",
            "axes.x.drive.stribeck_velocity_mm_s: must be > 0 (>= 0 and <= 10000) when static_n > coulomb_n, got 0",
        ),
        (
            "{model: p_ff_friction, kp_m_min_mm: 2, kff: 1.6}",
            "p_ff_friction",
            "axes.x.drive.kff: must be >= 0 and <= 1.5, got 1.6",
        ),
        (
            "{model: first_order_delay, time_constant_s: 0.01, delay_s: 2}",
            "delay_s: 2",
            "axes.x.drive.delay_s: must be >= 0 and <= 1, got 2",
        ),
        (
            "{model: sopdt, omega0_rad_s: 95.6, zeta: 1, position_gain_1_s: 0}",
            "sopdt",
            "axes.x.drive.position_gain_1_s: must be > 0 and <= 10000, got 0",
        ),
    ],
)
def test_drive_errors(tmp_path: Path, drive: str, fragment: str, expected: str) -> None:
    text = MINIMAL.replace(
        "    drive:\n      model: sopdt\n      omega0_rad_s: 95.6\n      zeta: 1.0\n", f"    drive: {drive}\n"
    )
    msg = error_of(tmp_path, text)
    assert msg == f"{tmp_path / 'mill.yaml'}:{line_of(text, fragment)}: {expected}"


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ProfileError) as info:
        load_profile(tmp_path / "nope.yaml")
    assert str(info.value) == f"{tmp_path / 'nope.yaml'}: file not found"
    assert isinstance(info.value, InputError)


def test_not_utf8(tmp_path: Path) -> None:
    p = tmp_path / "mill.yaml"
    p.write_bytes(MINIMAL.replace("test mill", "m\xfchle").encode("latin-1"))
    with pytest.raises(ProfileError) as info:
        load_profile(p)
    assert str(info.value) == f"{p}:2: not UTF-8 text; save the profile as UTF-8"


def test_recursive_alias_does_not_hang(tmp_path: Path) -> None:
    msg = error_of(tmp_path, "machine: &a {name: m, x: *a}\n")
    assert "machine.x: unknown key; allowed: name, units" in msg


def test_profile_from_dict_errors_name_the_path() -> None:
    d = default_profile().to_dict()
    bad = _with(d, ("axes", "z", "max_acceleration_m_s2"), -1)
    with pytest.raises(ProfileError) as info:
        profile_from_dict(bad, path="given.yaml")
    assert str(info.value) == "given.yaml: axes.z.max_acceleration_m_s2: must be >= 0.001 and <= 1000, got -1"
    with pytest.raises(ProfileError, match=r"^<input>: axes.z.max_acceleration_m_s2: "):
        profile_from_dict(bad)
    with pytest.raises(ProfileError, match="empty profile"):
        profile_from_dict(None)  # type: ignore[arg-type]


def test_profiles_are_frozen() -> None:
    p = default_profile()
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.machine = p.machine  # type: ignore[misc]


# -- documentation ------------------------------------------------------------


def test_docs_carry_the_generated_reference() -> None:
    doc = (ROOT / "docs" / "profile.md").read_text(encoding="utf-8")
    m = re.search(r"<!-- BEGIN SCHEMA[^>]*-->\n\n(.*)\n<!-- END SCHEMA -->", doc, re.S)
    assert m, "docs/profile.md lacks the generated reference block"
    assert m.group(1) == schema_markdown(), "docs/profile.md is stale: regenerate with python -m ilcnc.profile"


def test_every_spec_is_documented_with_range_and_default() -> None:
    md = schema_markdown()
    for s in SPECS:
        # a key used by several drive models has one row per model
        rows = [line for line in md.splitlines() if line.startswith(f"| `{s.path}` |")]
        row = next((r for r in rows if s.doc.replace("|", "\\|") in r), None)
        assert row is not None, s.path
        if s.kind in ("float", "int", "axis_float", "choice", "range_pair"):
            assert s.range_text() in row, s.path


def test_example_mill_mentions_seed_gain_normalisation() -> None:
    text = EXAMPLE.read_text(encoding="utf-8")
    assert "1.09e-4" in text and "normalised" in text


def test_axis_names() -> None:
    assert AXIS_NAMES == ("x", "y", "z")


# -- helpers -------------------------------------------------------------------


def _with(d: dict[str, Any], path: tuple[str, ...], value: Any) -> dict[str, Any]:
    out = copy.deepcopy(d)
    node = out
    for key in path[:-1]:
        node = node.setdefault(key, {})
    node[path[-1]] = value
    return out


# -- transfer_function drives, PI velocity loop, cross-coupling checks ----------


def test_transfer_function_drive(tmp_path: Path) -> None:
    text = MINIMAL.replace(
        "      model: first_order_delay\n      time_constant_s: 0.02\n",
        "      model: transfer_function\n      numerator: [1.5, 3]\n      denominator: [1, 5, 0]\n",
    )
    p = load_profile(write(tmp_path, text))
    assert p.axes["y"].drive == TransferFunctionDrive(numerator=(1.5, 3.0), denominator=(1.0, 5.0, 0.0))
    assert p.axes["y"].drive.feedback == "unity"
    assert profile_from_dict(p.to_dict()) == p
    assert load_profile(write(tmp_path, p.to_yaml(), "dumped.yaml")) == p
    assert p.to_dict()["axes"]["y"]["drive"]["numerator"] == [1.5, 3.0]


@pytest.mark.parametrize(
    ("drive", "fragment", "expected"),
    [
        (
            "{model: transfer_function, numerator: [1, 2, 3], denominator: [1, 5, 0]}",
            "transfer_function",
            "axes.x.drive.numerator: must have fewer coefficients than denominator (3): the axis transfer function"
            " must be strictly proper, got 3",
        ),
        (
            "{model: transfer_function, numerator: [0, 2], denominator: [1, 5, 0]}",
            "transfer_function",
            "axes.x.drive.numerator: must be a list of 1 to 10 finite numbers (coefficients in descending powers of s,"
            " the first non-zero), got a leading 0",
        ),
        (
            "{model: transfer_function, numerator: [1, x], denominator: [1, 5, 0]}",
            "transfer_function",
            "axes.x.drive.numerator.1: must be a list of 1 to 10 finite numbers (coefficients in descending powers"
            " of s, the first non-zero), got 'x'",
        ),
        (
            "{model: transfer_function, numerator: 3, denominator: [1, 5, 0]}",
            "transfer_function",
            "axes.x.drive.numerator: must be a list of 1 to 10 finite numbers (coefficients in descending powers of"
            " s, the first non-zero), got 3",
        ),
        (
            "{model: transfer_function, numerator: [-1], denominator: [1, 5, 0]}",
            "transfer_function",
            "axes.x.drive.denominator: 1 + L(s) is unstable: pole(s) with real part >= 0: 0.1926",
        ),
        (
            "{model: transfer_function, numerator: [1], denominator: [1, -1], feedback: none}",
            "transfer_function",
            "axes.x.drive.denominator: the closed loop is unstable: pole(s) with real part >= 0: 1",
        ),
        (
            "{model: p_ff_friction, kp_m_min_mm: 2, velocity_integral_time_s: 0}",
            "p_ff_friction",
            "axes.x.drive.velocity_integral_time_s: must be > 0 and <= 10, got 0",
        ),
    ],
)
def test_new_drive_errors(tmp_path: Path, drive: str, fragment: str, expected: str) -> None:
    text = MINIMAL.replace(
        "    drive:\n      model: sopdt\n      omega0_rad_s: 95.6\n      zeta: 1.0\n", f"    drive: {drive}\n"
    )
    msg = error_of(tmp_path, text)
    assert msg == f"{tmp_path / 'mill.yaml'}:{line_of(text, fragment)}: {expected}"


def test_velocity_integral_time(tmp_path: Path) -> None:
    text = MINIMAL.replace(
        "      model: first_order_delay\n      time_constant_s: 0.02\n",
        "      model: p_ff_friction\n      kp_m_min_mm: 1.6\n      velocity_integral_time_s: 0.02\n",
    )
    p = load_profile(write(tmp_path, text))
    assert p.axes["y"].drive == PFfFrictionDrive(kp_m_min_mm=1.6, velocity_integral_time_s=0.02)
    assert PFfFrictionDrive(kp_m_min_mm=1.0).velocity_integral_time_s is None


def test_cross_coupling_needs_position_loops(tmp_path: Path) -> None:
    text = MINIMAL + "controller: {type: cross_coupled, cross_coupling_gain: 20}\n"
    msg = error_of(tmp_path, text)
    assert msg.endswith(
        "controller.coupled_axes: axis x has no position loop for the cross-coupled controller to act on"
        " (axes.x.drive must be mass_damper_pid, p_ff_friction, sopdt with position_gain_1_s or transfer_function"
        " with feedback unity)"
    )
    ok = MINIMAL.replace("      zeta: 1.0\n", "      zeta: 1.0\n      position_gain_1_s: 30\n").replace(
        "      model: first_order_delay\n      time_constant_s: 0.02\n",
        "      model: transfer_function\n      numerator: [2, 11.76]\n      denominator: [1, 12, 0]\n",
    )
    p = load_profile(write(tmp_path, ok + "controller: {type: cross_coupled, cross_coupling_gain: 20}\n", "ok.yaml"))
    assert all(has_position_loop(p.axes[a].drive) for a in ("x", "y"))
    assert not has_position_loop(FirstOrderDelayDrive(time_constant_s=0.01))
    assert not has_position_loop(TransferFunctionDrive((1.0,), (1.0, 1.0), feedback="none"))


# ---------------------------------------------------------------------------------------------
# geometry / tool / cutting sections (issue 8)
# ---------------------------------------------------------------------------------------------

CUTTING = """\
tool:
  diameter_mm: 12
  teeth: 2
  modes:
    - {direction: normal, natural_frequency_hz: 1500, damping_ratio: 0.03, stiffness_n_um: 15}
cutting:
  model: mechanistic
  ktc_n_mm2: 796
  krc_n_mm2: 168
  axial_depth_mm: 8
  spindle_rpm: 2016
  radial_depth_mm: 9
"""


def test_tool_and_cutting_sections_load_and_round_trip(tmp_path: Path) -> None:
    p = load_profile(write(tmp_path, MINIMAL + CUTTING + "geometry:\n  map: volumetric-x.csv\n"))
    assert p.cutting.enabled and p.cutting.milling == "up" and p.cutting.kte_n_mm == 0.0
    assert p.tool.modes[0].stiffness_n_um == 15.0 and p.tool.modes[0].direction == "normal"
    assert p.resolve(p.geometry.map) == tmp_path / "volumetric-x.csv"
    assert profile_from_dict(p.to_dict(), path=p.path) == p
    assert not load_profile(write(tmp_path, MINIMAL)).cutting.enabled


@pytest.mark.parametrize(
    ("old", "new", "expect"),
    [
        ("damping_ratio: 0.03", "damping_ratio: 1.5", r"mill\.yaml:\d+: tool\.modes\.0\.damping_ratio: must be a number > 0"
                                                      r" and < 1, got 1\.5"),
        ("direction: normal", "direction: up", r"tool\.modes\.0\.direction: must be feed or normal, got 'up'"),
        ("radial_depth_mm: 9", "radial_depth_mm: 13", r"cutting\.radial_depth_mm: must be <= tool\.diameter_mm \(12 mm\),"
                                                      r" got 13"),
        ("  radial_depth_mm: 9\n", "", r"cutting\.model: cutting\.model mechanistic needs cutting\.stock"),
        ("  ktc_n_mm2: 796\n", "", r"cutting\.ktc_n_mm2: missing required key"),
    ],
)
def test_bad_tool_and_cutting_keys_name_the_key(tmp_path: Path, old: str, new: str, expect: str) -> None:
    text = MINIMAL + CUTTING
    assert old in text
    msg = error_of(tmp_path, text.replace(old, new))
    assert re.search(expect, msg), msg


def test_cutting_needs_a_tool_frequency_response(tmp_path: Path) -> None:
    text = MINIMAL + CUTTING.replace(
        "  modes:\n    - {direction: normal, natural_frequency_hz: 1500, damping_ratio: 0.03, stiffness_n_um: 15}\n", "")
    msg = error_of(tmp_path, text)
    assert "needs the tool's frequency response: tool.modes or tool.frf_csv" in msg, msg


# -- tuning.schedule (issue 7, seed 001) ------------------------------------------

SCHEDULE = """\
tuning:
  schedule:
    axis: y
    horizon_samples: 20
    lambda: 0.002
    dk_candidates: [-0.1, 0, 0.1]
    kp_min_m_min_mm: 1.2
    kp_max_m_min_mm: 3
    kinematics: eq10
"""


def test_schedule_tuning_defaults_are_the_papers(tmp_path: Path) -> None:
    p = load_profile(write(tmp_path, MINIMAL))
    s = p.tuning.schedule
    assert s.axis is None and p.schedule_axis == "y"  # no z: the last axis
    assert default_profile().schedule_axis == "z"
    assert (s.horizon_samples, s.lam, s.kp_range, s.kinematics) == (50, 0.01, (1.0, 2.7), "predicted")
    assert s.dk_candidates == pytest.approx([-0.05, -0.04, -0.03, -0.02, -0.01, 0.0, 0.01, 0.02, 0.03, 0.04, 0.05])
    assert "tuning" not in p.to_dict()  # all defaults: not written
    seed = load_profile(CONFIGS / "seed001-duong-p-ff-friction.yaml").tuning.schedule
    # seed 001 adds the C1 scan (§4: the best fixed gain, steps of 0.1 over the stable range [1, 3] of §3.4)
    # and takes the paper's eq. 10 as its kinematic bound
    assert seed == dataclasses.replace(s, axis="z", kinematics="eq10",
                                       baseline_kp_m_min_mm=tuple(round(1.0 + 0.1 * i, 1) for i in range(21)))
    assert s.baseline_kp_m_min_mm is None  # default: C1 is the drive's gain


def test_schedule_tuning_loads_and_round_trips(tmp_path: Path) -> None:
    p = load_profile(write(tmp_path, MINIMAL + SCHEDULE))
    s = p.tuning.schedule
    assert (s.axis, s.horizon_samples, s.lam, s.dk_candidates) == ("y", 20, 0.002, (-0.1, 0.0, 0.1))
    assert (s.kp_range, s.kinematics, p.schedule_axis) == ((1.2, 3.0), "eq10", "y")
    d = p.to_dict()
    assert d["tuning"]["schedule"]["lambda"] == 0.002
    assert profile_from_dict(d) == p
    assert load_profile(write(tmp_path, p.to_yaml(), "again.yaml")) == p


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ("horizon_samples: 20", "horizon_samples: 0", "tuning.schedule.horizon_samples: must be >= 1 and <= 10000, got 0"),
        (
            "horizon_samples: 20",
            "horizon_samples: 2.5",
            "tuning.schedule.horizon_samples: must be an integer >= 1 and <= 10000, got 2.5",
        ),
        ("lambda: 0.002", "lambda: -1", "tuning.schedule.lambda: must be >= 0 and <= 1000000, got -1"),
        ("lambda: 0.002", "lambda: .nan", "tuning.schedule.lambda: must be a finite number >= 0 and <= 1000000"),
        (
            "dk_candidates: [-0.1, 0, 0.1]",
            "dk_candidates: []",
            "tuning.schedule.dk_candidates: must be a list of 1 to 101 finite numbers >= -10 and <= 10, got 0 items",
        ),
        (
            "dk_candidates: [-0.1, 0, 0.1]",
            "dk_candidates: 0.1",
            "tuning.schedule.dk_candidates: must be a list of 1 to 101 finite numbers >= -10 and <= 10, got 0.1",
        ),
        (
            "dk_candidates: [-0.1, 0, 0.1]",
            "dk_candidates: [0, .inf]",
            "tuning.schedule.dk_candidates: must be a list of 1 to 101 finite numbers >= -10 and <= 10, got inf (item 1)",
        ),
        (
            "dk_candidates: [-0.1, 0, 0.1]",
            "dk_candidates: [0, 11]",
            "tuning.schedule.dk_candidates: must be a list of 1 to 101 finite numbers >= -10 and <= 10, got 11 (item 1)",
        ),
        (
            "dk_candidates: [-0.1, 0, 0.1]",
            "dk_candidates: [-0.1, 0.1]",
            "tuning.schedule.dk_candidates: must include 0 (holding the gain is always a candidate), got [-0.1, 0.1]",
        ),
        (
            "dk_candidates: [-0.1, 0, 0.1]",
            "dk_candidates: [0, 0.1, 0.1]",
            "tuning.schedule.dk_candidates: must be distinct, got 0.1 twice in [0, 0.1, 0.1]",
        ),
        ("kp_min_m_min_mm: 1.2", "kp_min_m_min_mm: 0", "tuning.schedule.kp_min_m_min_mm: must be > 0 and <= 100, got 0"),
        (
            "kp_min_m_min_mm: 1.2",
            "kp_min_m_min_mm: 3",
            "tuning.schedule.kp_min_m_min_mm: must be < kp_max_m_min_mm (3), got 3",
        ),
        ("kp_max_m_min_mm: 3", "kp_max_m_min_mm: 101", "tuning.schedule.kp_max_m_min_mm: must be > 0 and <= 100, got 101"),
        ("axis: y", "axis: z", "tuning.schedule.axis: axis z is not defined under axes (defined: x, y)"),
        ("axis: y", "axis: Z", "tuning.schedule.axis: must be one of x, y, z, got 'Z'"),
        ("kinematics: eq10", "kinematics: eq9", "tuning.schedule.kinematics: must be one of predicted, eq10, none"),
        ("kinematics: eq10", "np: 50", "tuning.schedule.np: unknown key; allowed: axis, horizon_samples, lambda,"),
    ],
)
def test_bad_schedule_tuning_names_the_key(tmp_path: Path, old: str, new: str, expected: str) -> None:
    text = MINIMAL + SCHEDULE
    assert old in text
    text = text.replace(old, new)
    msg = error_of(tmp_path, text)
    key = new.split(":")[0]
    assert msg.startswith(f"{tmp_path / 'mill.yaml'}:{line_of(text, new)}: {expected}"), (key, msg)


def test_bad_schedule_tuning_from_dict_names_the_key() -> None:
    d = default_profile().to_dict()
    d["tuning"] = {"schedule": {"kp_min_m_min_mm": 2.7}}
    with pytest.raises(ProfileError, match=r"tuning\.schedule\.kp_min_m_min_mm: must be < kp_max_m_min_mm \(2\.7\),"
                                           r" got 2\.7"):
        profile_from_dict(d)

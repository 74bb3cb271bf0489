"""Editing machine profiles in place (``ilcnc.profile.edit``): comments, order and anchors survive.

Every test works on copies of the shipped ``configs/*.yaml`` and compares the
edited text with the original line by line (``difflib``): only the edited
lines, the notes and (when sharing is broken) the copied mapping may differ.
"""

from __future__ import annotations

import difflib
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from ilcnc.errors import InputError, ProfileError
from ilcnc.profile.edit import NOTE_PREFIX, REMARK_PREFIX, format_scalar, update_profile, update_text
from ilcnc.profile.load import load_profile
from ilcnc.profile.sections import MassDamperPidDrive, SopdtDrive

REPO = Path(__file__).resolve().parents[1]
CONFIGS = sorted((REPO / "configs").glob("*.yaml"))


def _copy(tmp_path: Path, name: str) -> Path:
    dst = tmp_path / name
    shutil.copy(REPO / "configs" / name, dst)
    return dst


def _changes(before: str, after: str) -> tuple[list[str], list[str]]:
    """Removed and added lines of a line diff."""
    removed, added = [], []
    for line in difflib.ndiff(before.splitlines(), after.splitlines()):
        if line.startswith("- "):
            removed.append(line[2:])
        elif line.startswith("+ "):
            added.append(line[2:])
    return removed, added


def _data(path: Path) -> dict:
    return load_profile(path).to_dict()


# --------------------------------------------------------------------------
# Every leaf of every shipped profile
# --------------------------------------------------------------------------


def _numeric_leaves(data: object, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], float]]:
    out = []
    if isinstance(data, dict):
        for k, v in data.items():
            out += _numeric_leaves(v, (*prefix, str(k)))
    elif isinstance(data, (int, float)) and not isinstance(data, bool):
        out.append((prefix, float(data)))
    return out


@pytest.mark.parametrize("config", CONFIGS, ids=[p.name for p in CONFIGS])
def test_every_numeric_leaf_changes_one_line(tmp_path: Path, config: Path) -> None:
    """Setting any number in a shipped profile rewrites exactly that value (its comment kept), nothing else.

    For a value inside a shared (anchored) mapping the sharing is broken and
    the other users keep their values; the loaded profile must equal the
    original with only that key changed.
    """
    text = config.read_text()
    raw = yaml.safe_load(text)
    for keys, value in _numeric_leaves(raw):
        new_value = value * 1.5 + 0.25 if keys[-1] not in ("lookahead_blocks", "iterations", "lead_samples") else int(value) + 1
        new = update_text(text, {".".join(keys): new_value})
        after = yaml.safe_load(new)
        d = after
        for k in keys:
            d = d[k]
        assert d == new_value, keys
        removed, added = _changes(text, new)
        if not any(line.strip().startswith(REMARK_PREFIX.strip()) for line in added):
            assert len(removed) == 1 and len(added) == 1, (keys, removed, added)
            old_line, new_line = removed[0], added[0]
            # the comment stays in its column
            if "#" in old_line:
                assert new_line.index("#") == old_line.index("#") or new_line[: new_line.index("#")].rstrip() != new_line
                assert old_line[old_line.index("#"):] == new_line[new_line.index("#"):]
        # nothing else changed (the expectation without shared nodes: json copies every alias)
        expect = json.loads(json.dumps(yaml.safe_load(text)))
        d = expect
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = new_value
        assert after == expect, keys


@pytest.mark.parametrize("config", CONFIGS, ids=[p.name for p in CONFIGS])
def test_same_values_leave_the_file_byte_identical(tmp_path: Path, config: Path) -> None:
    p = _copy(tmp_path, config.name)
    raw = p.read_bytes()
    data = yaml.safe_load(raw)
    updates = {f"axes.{ax}.drive": dict(a["drive"]) for ax, a in data["axes"].items()}
    updates["learning.gains"] = dict(data["learning"]["gains"])
    update_profile(p, updates)
    assert p.read_bytes() == raw


# --------------------------------------------------------------------------
# Single edits, notes
# --------------------------------------------------------------------------


def test_scalar_edit_keeps_comment_and_column(tmp_path: Path) -> None:
    p = _copy(tmp_path, "seed000-hendrawan-mass-damper-pid.yaml")
    before = p.read_text()
    update_profile(p, {"axes.x.drive.damping_v_s_mm": 0.15123})
    removed, added = _changes(before, p.read_text())
    assert removed == ["      damping_v_s_mm: 0.144     # §III.A"]
    assert added == ["      damping_v_s_mm: 0.15123   # §III.A"]


def test_note_is_one_line_above_the_key_and_replaced_next_time(tmp_path: Path) -> None:
    p = _copy(tmp_path, "seed000-hendrawan-mass-damper-pid.yaml")
    before = p.read_text()
    update_profile(p, {"axes.x.drive": {"model": "mass_damper_pid", "mass_v_s2_mm": 0.46, "damping_v_s_mm": 0.15,
                                        "kp": 0.96, "ki": 0.01, "kd": 8.0}},
                   note="identified 2026-05-01 from step.csv (sha256 0123456789ab)\nR² 0.998")
    first = p.read_text()
    removed, added = _changes(before, first)
    assert removed == ["      mass_v_s2_mm: 0.45        # §III.A", "      damping_v_s_mm: 0.144     # §III.A"]
    assert added == [
        "    # ilcnc: identified 2026-05-01 from step.csv (sha256 0123456789ab) R² 0.998",
        "      mass_v_s2_mm: 0.46        # §III.A",
        "      damping_v_s_mm: 0.15      # §III.A",
    ]
    assert first.splitlines()[first.splitlines().index(added[0]) + 1] == "    drive:"
    update_profile(p, {"axes.x.drive.mass_v_s2_mm": 0.47}, note="identified again")
    second = p.read_text()
    # the note above axes.x.drive stays; a new one goes above the edited key
    assert second.count(NOTE_PREFIX) == 2
    update_profile(p, {"axes.x.drive.mass_v_s2_mm": 0.48}, note="identified a third time")
    third = p.read_text()
    assert third.count(NOTE_PREFIX) == 2
    assert "# ilcnc: identified a third time" in third and "identified again" not in third
    assert load_profile(p).axes["x"].drive == MassDamperPidDrive(0.48, 0.15, 0.96, 0.01, 8.0)


def test_per_axis_gain_and_back(tmp_path: Path) -> None:
    p = _copy(tmp_path, "seed000-hendrawan-mass-damper-pid.yaml")
    before = p.read_text()
    update_profile(p, {"learning.gains.kp": {"x": 0.5, "y": 0.4, "z": 0.4}, "learning.gains.kd": np.float64(0.05)})
    removed, added = _changes(before, p.read_text())
    kd_line = "    kd: 0.05                    # printed 0.443 diverges (see header)"
    assert added == ["    kp: {x: 0.5, y: 0.4, z: 0.4}  # §III.A", kd_line]
    assert len(removed) == 2
    assert load_profile(p).learning.gain("kp", "y") == 0.4
    update_profile(p, {"learning.gains.kp": 0.468})
    assert _changes(before, p.read_text())[1] == [kd_line]


def test_new_key_and_removed_key(tmp_path: Path) -> None:
    p = _copy(tmp_path, "seed004-ward-sopdt.yaml")
    before = p.read_text()
    update_profile(p, {"machine.travel_mm": {"x": [0, 800], "y": [0, 500]}, "learning.q_filter_hz": 50})
    removed, added = _changes(before, p.read_text())
    assert removed == []
    assert added == ["  travel_mm:", "    x: [0, 800]", "    y: [0, 500]", "  q_filter_hz: 50"]
    assert load_profile(p).machine.travel_mm == {"x": (0.0, 800.0), "y": (0.0, 500.0)}
    update_profile(p, {"machine.travel_mm": None, "learning.q_filter_hz": None})
    assert p.read_text() == before


def test_model_change_removes_stale_keys(tmp_path: Path) -> None:
    p = _copy(tmp_path, "seed000-hendrawan-mass-damper-pid.yaml")
    update_profile(p, {"axes.x.drive": {"model": "first_order_delay", "time_constant_s": 0.055, "delay_s": 0.001, "gain": 1.0}})
    text = p.read_text()
    prof = load_profile(p)
    assert prof.axes["x"].drive.model == "first_order_delay"
    assert prof.axes["y"].drive == MassDamperPidDrive(0.65, 0.24, 0.96, 0.01, 8.0)
    x_block = text[text.index("  x:"): text.index("  y:")]
    assert "mass_v_s2_mm" not in x_block and "kd:" not in x_block
    assert "model: first_order_delay" in x_block


# --------------------------------------------------------------------------
# Anchors and aliases
# --------------------------------------------------------------------------


def test_editing_an_alias_gives_that_axis_its_own_copy(tmp_path: Path) -> None:
    p = _copy(tmp_path, "seed004-ward-sopdt.yaml")
    before = p.read_text()
    update_profile(p, {"axes.y.drive.omega0_rad_s": 90.0})
    after = p.read_text()
    removed, added = _changes(before, after)
    assert removed == ["    drive: *sopdt_seed004"]
    assert added[0].startswith(f"    {REMARK_PREFIX}was *sopdt_seed004 (shared with axes.x.drive)")
    assert added[1:] == [
        "    drive:",
        "      model: sopdt",
        "      gain: 1.0                 # printed K = 1.09e-4, normalised (see header)",
        "      omega0_rad_s: 90.0        # §2.1",
        "      zeta: 1.0                 # §2.1",
        "      delay_s: 0.0066           # §2.1",
    ]
    prof = load_profile(p)
    assert prof.axes["x"].drive == SopdtDrive(omega0_rad_s=95.6, zeta=1.0, gain=1.0, delay_s=0.0066)
    assert prof.axes["y"].drive == SopdtDrive(omega0_rad_s=90.0, zeta=1.0, gain=1.0, delay_s=0.0066)
    assert "&sopdt_seed004" in after  # x keeps the anchor


def test_editing_the_anchor_owner_moves_the_anchor(tmp_path: Path) -> None:
    """example-mill: x owns &sopdt_seed004, y and z alias it; editing x keeps y and z as they were."""
    p = _copy(tmp_path, "example-mill.yaml")
    before_prof = _data(p)
    update_profile(p, {"axes.x.drive": {"model": "first_order_delay", "time_constant_s": 0.033, "delay_s": 0.001, "gain": 1.0}},
                   note="identified")
    after = p.read_text()
    prof = load_profile(p)
    assert prof.axes["x"].drive.model == "first_order_delay"
    for ax in ("y", "z"):
        assert prof.to_dict()["axes"][ax] == before_prof["axes"][ax]
    lines = after.splitlines()
    y_drive = lines.index("    drive: &sopdt_seed004")
    assert lines[y_drive - 1].startswith(f"    {REMARK_PREFIX}anchor &sopdt_seed004 moved here from axes.x.drive")
    assert lines[y_drive - 2].strip() == "rapid_mm_min: 36000"  # inside y
    assert after.count("*sopdt_seed004") == 1  # z still aliases it
    assert f"    {REMARK_PREFIX}was &sopdt_seed004, now moved to axes.y.drive" in after
    # x keeps its (long) comment block
    assert "      # SOPDT velocity drive fitted to a velocity step in seed 004 (Ward," in after


def test_alias_edit_with_a_whole_mapping_and_same_values(tmp_path: Path) -> None:
    """Writing the values a shared drive already has changes nothing (no copy, no note-less diff)."""
    p = _copy(tmp_path, "example-mill.yaml")
    raw = p.read_bytes()
    update_profile(p, {"axes.z.drive": {"model": "sopdt", "gain": 1, "omega0_rad_s": 95.6, "zeta": 1, "delay_s": 0.0066}})
    assert p.read_bytes() == raw
    update_profile(p, {"axes.z.drive": {"model": "sopdt", "gain": 1, "omega0_rad_s": 80.0, "zeta": 1, "delay_s": 0.0066}})
    prof = load_profile(p)
    assert prof.axes["z"].drive.omega0_rad_s == 80.0  # type: ignore[union-attr]
    assert prof.axes["x"].drive.omega0_rad_s == 95.6  # type: ignore[union-attr]
    assert prof.axes["y"].drive.omega0_rad_s == 95.6  # type: ignore[union-attr]


def test_scalar_alias_and_merge_key() -> None:
    text = (
        "base: &b {a: 1, b: 2}\n"
        "k: &kd 8.0   # shared gain\n"
        "one:\n  <<: *b\n  c: 3\n"
        "two: *kd\n"
    )
    new = update_text(text, {"one.a": 5, "two": 9.0})
    data = yaml.safe_load(new)
    assert data["one"] == {"a": 5, "b": 2, "c": 3}
    assert data["base"] == {"a": 1, "b": 2}
    assert data["k"] == 8.0 and data["two"] == 9.0
    assert "# shared gain" in new
    new2 = update_text(text, {"k": 7.5})
    assert yaml.safe_load(new2)["two"] == 8.0 and yaml.safe_load(new2)["k"] == 7.5


# --------------------------------------------------------------------------
# Refusals and file handling
# --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("updates", "match"),
    [
        ({"axes.x.drive.zeta": -1.0}, r"axes\.x\.drive\.zeta: must be > 0 and <= 10, got -1"),
        ({"axes.x.drive.bogus": 1.0}, r"axes\.x\.drive\.bogus"),
        ({"axes.x.drive": {"model": "sopdt", "zeta": 1.0}}, r"axes\.x\.drive\.omega0_rad_s: missing"),
        ({"machine.name.first": "a"}, r"machine\.name is not a mapping"),
    ],
)
def test_invalid_update_is_refused_and_file_untouched(tmp_path: Path, updates: dict, match: str) -> None:
    p = _copy(tmp_path, "seed004-ward-sopdt.yaml")
    raw = p.read_bytes()
    os.utime(p, (1_000_000_000, 1_000_000_000))
    with pytest.raises(ProfileError, match=match) as exc:
        update_profile(p, updates)
    assert "profile not changed" in str(exc.value)
    assert str(exc.value).startswith(f"{p}: ")
    assert p.read_bytes() == raw
    assert p.stat().st_mtime == 1_000_000_000
    assert sorted(x.name for x in tmp_path.iterdir()) == [p.name]  # no temporary file left


def test_out_and_protect(tmp_path: Path) -> None:
    p = _copy(tmp_path, "seed004-ward-sopdt.yaml")
    raw = p.read_bytes()
    out = tmp_path / "new.yaml"
    assert update_profile(p, {"axes.x.drive.zeta": 0.9}, out=out) == out
    assert p.read_bytes() == raw
    assert load_profile(out).axes["x"].drive.zeta == 0.9  # type: ignore[union-attr]
    log = tmp_path / "run.csv"
    log.write_text("t_s,u,y\n")
    with pytest.raises(InputError, match="refusing to write over an input file"):
        update_profile(p, {"axes.x.drive.zeta": 0.9}, out=log, protect=(log,))
    with pytest.raises(ProfileError):
        update_profile(log, {"axes.x.drive.zeta": 0.9})  # not a profile


def test_crlf_and_bom_are_kept(tmp_path: Path) -> None:
    p = tmp_path / "win.yaml"
    text = (REPO / "configs" / "seed004-ward-sopdt.yaml").read_text()
    p.write_bytes(b"\xef\xbb\xbf" + text.replace("\n", "\r\n").encode())
    update_profile(p, {"axes.x.drive.zeta": 0.95}, note="n")
    raw = p.read_bytes()
    assert raw.startswith(b"\xef\xbb\xbf")
    assert b"\n" not in raw.replace(b"\r\n", b"")
    assert load_profile(p).axes["x"].drive.zeta == 0.95  # type: ignore[union-attr]


def test_format_scalar() -> None:
    assert format_scalar(1e-5) == "1.0e-05"
    assert format_scalar(2.0) == "2.0"
    assert format_scalar(95.613) == "95.613"
    assert format_scalar(np.float64(0.0066)) == "0.0066"
    assert format_scalar(np.int64(3)) == "3"
    assert format_scalar(True) == "true"
    assert format_scalar("generic 3-axis VMC") == "generic 3-axis VMC"
    assert format_scalar("yes") == '"yes"'
    assert format_scalar("a: b") == '"a: b"'
    for v in (1e-5, 1.5e10, 0.1, 123456.789):
        assert yaml.safe_load(f"k: {format_scalar(v)}")["k"] == v
    with pytest.raises(ValueError, match="non-finite"):
        format_scalar(float("nan"))
    with pytest.raises(ValueError, match="bad profile key path"):
        update_text("a: 1\n", {"a..b": 1})


def test_shape_changes() -> None:
    """A null value becomes the mapping a path needs; a block mapping collapses to a scalar and back."""
    text = "machine:\n  travel_mm:   # limits\n  name: a\nb: 1\n"
    assert update_text(text, {"machine.travel_mm.x": [0, 800]}) == (
        "machine:\n  travel_mm: {x: [0, 800]}  # limits\n  name: a\nb: 1\n"
    )
    nested = "a:\n  b:\n    c: 1\n    d: 2  # dd\n  e: 3  # ee\n"
    assert update_text(nested, {"a.b": 5}) == "a:\n  b: 5\n  e: 3  # ee\n"
    assert update_text(nested, {"a.e": {"f": {"g": 1}}}) == "a:\n  b:\n    c: 1\n    d: 2  # dd\n  e:  # ee\n    f:\n      g: 1\n"

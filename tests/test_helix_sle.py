"""Helical, runout-aware surface location error (ilcnc.vcnc.helix_sle) against the straight-flute model."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from ilcnc.profile.load import load_profile
from ilcnc.vcnc.deflection import ModalFRF, Mode, seed004_cutting, seed004_tool, sle_per_command_mm
from ilcnc.vcnc.helix_sle import flute_radius_offsets_mm, sle_helical_per_command_mm, sle_helical_profile_mm

REPO = Path(__file__).resolve().parents[1]


def test_no_helix_no_runout_is_the_straight_flute_model() -> None:
    tool, cut = seed004_tool(), seed004_cutting()
    straight = sle_per_command_mm([9.0, 6.0, 3.0], 0.1, tool, cut)
    # one disk, 8192 samples per revolution = the straight model's 4096 per tooth period, both with the force
    # cell-averaged at entry and exit: the same sum up to where a cell's boundary falls (measured 0.0021 um)
    helical = sle_helical_per_command_mm([9.0, 6.0, 3.0], 0.1, tool, cut, samples=8192, slices=1)
    assert helical == pytest.approx(straight, abs=5e-6)


def test_runout_on_a_rigid_tool_is_the_long_flute_overcut() -> None:
    rigid = ModalFRF((Mode(1e5, 0.05, 1e9),))  # 1e9 N/um: a 1 kN force moves it 1e-6 um
    tool = dataclasses.replace(seed004_tool(), frf_normal=rigid, helix_deg=30.0, runout_um=30.0)
    assert flute_radius_offsets_mm(tool) == pytest.approx([0.015, -0.015])
    z, sle = sle_helical_profile_mm(6.0, 0.1, tool, seed004_cutting())
    assert z[0] > 0 and z[-1] < 8.0
    assert sle == pytest.approx(np.full(z.size, -0.015), abs=1e-8)  # the wall is the long flute's: 15 um overcut
    half = dataclasses.replace(tool, runout_angle_deg=90.0)  # the offset across the flutes: equal radii
    assert sle_helical_per_command_mm([6.0], 0.1, half, seed004_cutting()) == pytest.approx([0.0], abs=1e-8)


def test_helix_puts_the_chip_under_the_generating_flute() -> None:
    # a straight two-flute tool in up-milling has no edge in the chip when one generates the wall (quasi-static
    # SLE ~0); with a 30 deg helix the flute below the generating point still cuts and pushes the tool away
    tool = dataclasses.replace(seed004_tool(), helix_deg=30.0)
    z, sle = sle_helical_profile_mm(9.0, 0.1, tool, seed004_cutting())
    assert np.all(sle[z > 2.0] > 0.002)  # > 2 um undercut above 2 mm
    assert sle[-1] > sle[0]  # the top of the cut has the most chip below it


@pytest.mark.parametrize(("key", "value", "message"), [
    ("runout_um", -1, "tool.runout_um"),
    ("helix_deg", 80, "tool.helix_deg"),
])
def test_bad_tool_keys_name_the_option(tmp_path: Path, key: str, value: float, message: str) -> None:
    import yaml

    d = yaml.safe_load((REPO / "configs" / "seed004-stepped-cut.yaml").read_text())
    d["cutting"]["stock"] = str(REPO / "samples" / "own" / "seed004_stepped_omi.csv")
    d["tool"][key] = value
    p = tmp_path / "p.yaml"
    p.write_text(yaml.safe_dump(d))
    with pytest.raises(Exception) as info:
        load_profile(p)
    assert message in str(info.value) and str(p) in str(info.value)

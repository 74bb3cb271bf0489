"""Tool deflection and surface location error (ilcnc.vcnc.deflection): forces, FRF, SLE, stock and the seed 004 sample."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from ilcnc.errors import MapError
from ilcnc.program import read_program
from ilcnc.vcnc.deflection import (
    Cutting,
    MeasuredFRF,
    ModalFRF,
    Mode,
    Tool,
    engagement_angles,
    feed_per_tooth_mm,
    milling_force_n,
    read_frf,
    read_stock,
    seed004_cutting,
    seed004_tool,
    sle_frequency_domain_mm,
    sle_per_command_mm,
    sle_time_domain_mm,
    tool_displacement_mm,
    tooth_force_n,
)

OWN = Path(__file__).resolve().parents[1] / "samples" / "own"
STEPPED = OWN / "seed004_stepped.h"
STEPPED_OMI = OWN / "seed004_stepped_omi.csv"


def _tool(teeth: int = 2, modes: tuple[Mode, ...] = (Mode(800.0, 0.03, 20.0), Mode(3000.0, 0.02, 30.0))) -> Tool:
    return Tool(diameter_mm=12.0, teeth=teeth, frf_normal=ModalFRF(modes))


def _cutting(mode: str = "up", *, edge: bool = True, rpm: float = 3000.0) -> Cutting:
    return Cutting(
        ktc_n_mm2=800.0, krc_n_mm2=200.0, kte_n_mm=20.0 if edge else 0.0, kre_n_mm=10.0 if edge else 0.0,
        axial_depth_mm=5.0, spindle_rpm=rpm, mode=mode,
    )


# ---------------------------------------------------------------------------
# Force model
# ---------------------------------------------------------------------------


def test_engagement_angles_up_and_down() -> None:
    st, ex = engagement_angles(3.0, 12.0, "up")  # 25 % immersion: arccos(1 - 0.5) = 60 deg
    assert float(st) == 0.0 and float(ex) == pytest.approx(math.pi / 3)
    st, ex = engagement_angles(3.0, 12.0, "down")
    assert float(st) == pytest.approx(2 * math.pi / 3) and float(ex) == pytest.approx(math.pi)
    st, ex = engagement_angles(12.0, 12.0, "up")  # slot: both are 0..180 deg
    assert float(st) == 0.0 and float(ex) == pytest.approx(math.pi)


def test_tooth_force_against_hand_calculation() -> None:
    tool, cut = _tool(), _cutting()
    # slot, phi = 30 deg: h = 0.1 * sin 30 = 0.05 mm; Ft = 800*5*0.05 + 20*5 = 300 N; Fr = 200*5*0.05 + 10*5 = 100 N
    ft, fr = tooth_force_n(math.radians(30.0), 12.0, 0.1, tool, cut)
    assert float(ft) == pytest.approx(300.0) and float(fr) == pytest.approx(100.0)
    # outside the engagement (25 % up-milling is 0..60 deg): no force; the boundaries are included
    ft, fr = tooth_force_n(np.radians([70.0, 200.0, 0.0, 60.0]), 3.0, 0.1, tool, cut)
    assert ft[:2].tolist() == [0.0, 0.0] and fr[:2].tolist() == [0.0, 0.0]
    assert ft[2] == pytest.approx(100.0)  # entry: edge force only (Kte*a)
    assert ft[3] == pytest.approx(800 * 5 * 0.1 * math.sin(math.pi / 3) + 100.0)
    # summed over two teeth at phi0 = 30 deg: tooth 1 at 210 deg is out of the cut
    f = milling_force_n(math.radians(30.0), 12.0, 0.1, tool, cut)
    c30, s30 = math.cos(math.radians(30)), 0.5
    assert f[0] == pytest.approx(-300 * c30 - 100 * s30)  # Fx = -Ft cos - Fr sin
    assert f[1] == pytest.approx(-300 * s30 + 100 * c30)  # Fy = -Ft sin + Fr cos


def test_four_tooth_slot_force_is_constant() -> None:
    """Slotting with 4 teeth and no edge forces: Fx = -Krc a c and Fy = -Ktc a c at every angle (sin^2 + cos^2 = 1)."""
    tool, cut = _tool(teeth=4), _cutting(edge=False)
    phi = np.linspace(0.0, 2 * math.pi, 97)[:-1] + 1e-3  # avoid exact boundaries
    f = milling_force_n(phi, 12.0, 0.1, tool, cut)
    np.testing.assert_allclose(f[:, 0], -200 * 5 * 0.1, rtol=1e-12)
    np.testing.assert_allclose(f[:, 1], -800 * 5 * 0.1, rtol=1e-12)


@pytest.mark.parametrize("ae", [0.0, -1.0, 12.5, math.nan])
def test_bad_radial_depth(ae: float) -> None:
    with pytest.raises(ValueError, match="radial depth"):
        tooth_force_n(0.1, ae, 0.1, _tool(), _cutting())
    if math.isnan(ae):  # per command, NaN means "no stock information" and gives NaN
        assert math.isnan(sle_per_command_mm([3.0, 6.0, ae], 0.1, _tool(), _cutting())[2])
        return
    with pytest.raises(ValueError, match="command k=2: radial depth"):
        sle_per_command_mm([3.0, 6.0, ae], 0.1, _tool(), _cutting())


def test_radial_depth_message_names_diameter() -> None:
    with pytest.raises(ValueError, match=r"command k=1: radial depth 13 mm is larger than the tool diameter 12 mm"):
        sle_per_command_mm([3.0, 13.0], 0.1, _tool(), _cutting())
    with pytest.raises(ValueError, match=r"command k=0: radial depth 0 mm must be > 0"):
        sle_per_command_mm([0.0, 3.0], 0.1, _tool(), _cutting())


def test_validate_names_the_option() -> None:
    tool = _tool()
    tool.diameter_mm = -3
    with pytest.raises(ValueError, match=r"^tool.diameter_mm must be > 0, got -3$"):
        tool.validate()
    bad = Tool(12.0, 2, ModalFRF((Mode(800.0, 1.5, 20.0),)))
    with pytest.raises(ValueError, match=r"tool.frf_normal.modes\[0\].damping_ratio must be in \(0, 1\), got 1.5"):
        bad.validate()
    with pytest.raises(ValueError, match=r"tool.teeth must be an integer >= 1"):
        Tool(12.0, 0, ModalFRF((Mode(800.0, 0.1, 20.0),))).validate()
    with pytest.raises(ValueError, match=r"cutting.axial_depth_mm must be > 0, got 0"):
        dataclasses.replace(_cutting(), axial_depth_mm=0.0).validate()
    with pytest.raises(ValueError, match=r"cutting.mode must be one of up, down, got 'climb'"):
        dataclasses.replace(_cutting(), mode="climb").validate()
    with pytest.raises(ValueError, match=r"cutting.kre_n_mm must be >= 0"):
        dataclasses.replace(_cutting(), kre_n_mm=-1.0).validate()
    seed004_tool().validate()
    seed004_cutting().validate()


# ---------------------------------------------------------------------------
# FRF
# ---------------------------------------------------------------------------


def test_modal_frf_static_and_resonance() -> None:
    frf = ModalFRF((Mode(800.0, 0.03, 20.0), Mode(3000.0, 0.02, 30.0)))
    # DC: 1/20 + 1/30 = 1/12 um/N
    assert frf.static_compliance_m_n == pytest.approx(1.0 / 12e6)
    assert complex(frf(0.0)) == pytest.approx(1.0 / 12e6)
    one = ModalFRF((Mode(1000.0, 0.05, 10.0),))
    # at f_n: H = 1/(k * 2i zeta) -> purely imaginary, -1/(2 zeta k) = -1 um/N
    assert complex(one(1000.0)) == pytest.approx(-1e-6j, rel=1e-12)


def test_static_sle_hand_calculation_four_tooth_slot() -> None:
    """Constant Fy = -Ktc a c (4 teeth, slot, no edge forces): SLE = Fy/k at DC for any dynamics.

    -800 N/mm^2 * 5 mm * 0.1 mm = -400 N over a static stiffness of 12 N/um: y = -33.33 um; up-milling
    SLE = y (overcut), down-milling SLE = -y (undercut).
    """
    tool = _tool(teeth=4)
    up, down = _cutting("up", edge=False), _cutting("down", edge=False)
    expect = -400.0 / 12.0 * 1e-3
    assert sle_frequency_domain_mm(12.0, 0.1, tool, up) == pytest.approx(expect, rel=1e-9)
    assert sle_frequency_domain_mm(12.0, 0.1, tool, down) == pytest.approx(-expect, rel=1e-9)
    assert sle_time_domain_mm(12.0, 0.1, tool, up) == pytest.approx(expect, rel=1e-6)
    _, y = tool_displacement_mm(12.0, 0.1, tool, up)
    np.testing.assert_allclose(y, expect, rtol=1e-9)  # no harmonics at all


def test_up_milling_overcuts_down_milling_undercuts_quasi_static() -> None:
    """A stiff, fast tool (20 kHz >> tooth passing): SLE = F_y(generation instant)/k.

    4 teeth, 75 % immersion: up-milling cuts 0..120 deg and generates at 0 while a tooth is at 90 deg;
    down-milling cuts 60..180 deg and generates at 180 while a tooth is at 90 deg. There Fy = -Ktc a c
    = -400 N, so y = -400 N / 50 N/um = -8 um: up-milling overcuts (SLE -8 um), down-milling undercuts (+8 um).
    """
    tool = _tool(teeth=4, modes=(Mode(20000.0, 0.3, 50.0),))
    up = sle_frequency_domain_mm(9.0, 0.1, tool, _cutting("up", edge=False))
    down = sle_frequency_domain_mm(9.0, 0.1, tool, _cutting("down", edge=False))
    assert up == pytest.approx(-0.008, rel=0.01)
    assert down == pytest.approx(0.008, rel=0.01)


@pytest.mark.parametrize("mode", ["up", "down"])
@pytest.mark.parametrize("ae", [9.0, 6.0, 3.0, 12.0, 1.0])
def test_frequency_and_time_domain_agree(mode: str, ae: float) -> None:
    tool, cut = seed004_tool(), dataclasses.replace(seed004_cutting(), mode=mode)
    f = sle_frequency_domain_mm(ae, 0.1, tool, cut)
    t = sle_time_domain_mm(ae, 0.1, tool, cut)
    assert f == pytest.approx(t, rel=0.02)
    _, y = tool_displacement_mm(ae, 0.1, tool, cut)
    assert abs(f - t) < 1e-4 * np.max(np.abs(y))  # and close on the scale of the vibration itself


def test_frequency_and_time_domain_agree_three_teeth_other_tool() -> None:
    tool = _tool(teeth=3, modes=(Mode(1100.0, 0.02, 8.0),))
    for mode in ("up", "down"):
        cut = _cutting(mode, rpm=9000.0)
        for ae in (2.0, 7.5):
            want = sle_time_domain_mm(ae, 0.08, tool, cut)
            assert sle_frequency_domain_mm(ae, 0.08, tool, cut) == pytest.approx(want, rel=0.02)


def test_time_domain_needs_modal_frf() -> None:
    f = np.linspace(0.0, 5000.0, 51)
    tool = Tool(12.0, 2, MeasuredFRF(f, ModalFRF((Mode(900.0, 0.05, 10.0),))(f)))
    with pytest.raises(ValueError, match="ModalFRF"):
        sle_time_domain_mm(6.0, 0.1, tool, _cutting())


def test_per_command_equals_frequency_domain_method() -> None:
    rng = np.random.default_rng(4)
    ae = np.concatenate([rng.uniform(0.01, 12.0, 200), [12.0, 6.0, 6.0, math.nan]])
    c = rng.uniform(0.02, 0.2, ae.size)
    for teeth in (2, 3):
        tool = _tool(teeth=teeth)
        for mode in ("up", "down"):
            cut = _cutting(mode)
            got = sle_per_command_mm(ae, c, tool, cut)
            assert math.isnan(got[-1])
            want = np.array([sle_frequency_domain_mm(a, cc, tool, cut) for a, cc in zip(ae[:-1], c[:-1], strict=True)])
            np.testing.assert_allclose(got[:-1], want, rtol=0, atol=1e-12)


def test_per_command_is_linear_in_feed_per_tooth() -> None:
    tool, cut = _tool(), _cutting()
    s0, s1, s2 = sle_per_command_mm([5.0, 5.0, 5.0], [0.0, 0.1, 0.2], tool, cut)
    assert s2 - s1 == pytest.approx(s1 - s0, rel=1e-12)
    with pytest.raises(ValueError, match="command k=1: feed per tooth"):
        sle_per_command_mm([5.0, 5.0], [0.1, -0.1], tool, cut)


def test_feed_per_tooth() -> None:
    assert float(feed_per_tooth_mm(403.4, 2016.0, 2)) == pytest.approx(0.1000496, rel=1e-6)


# ---------------------------------------------------------------------------
# Measured FRF CSV
# ---------------------------------------------------------------------------


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_read_frf_units_and_interpolation(tmp_path: Path) -> None:
    p = _write(tmp_path, "frf.csv", "# impact test\nf_hz,re [µm/N],im [µm/N]\n10,0.1,0\n110,0.3,-0.2\n210,0.1,-0.4\n")
    frf = read_frf(p)
    np.testing.assert_allclose(frf.f_hz, [10, 110, 210])
    assert complex(frf(60.0)) == pytest.approx(0.2e-6 - 0.1e-6j)  # linear between lines, m/N
    assert complex(frf(0.0)) == pytest.approx(0.1e-6)  # held below the first line
    assert complex(frf(420.0)) == pytest.approx((0.1e-6 - 0.4e-6j) / 4)  # mass line above the last
    default = read_frf(_write(tmp_path, "m.csv", "f_hz,re,im\n0,1e-7,0\n100,2e-7,-1e-7\n"))
    assert complex(default(100.0)) == pytest.approx(2e-7 - 1e-7j)


def test_measured_frf_gives_the_modal_sle(tmp_path: Path) -> None:
    tool = seed004_tool()
    f = np.arange(0.0, 40000.0, 2.0)
    h = tool.frf_normal(f)
    rows = "\n".join(f"{a:.1f},{b.real:.9e},{b.imag:.9e}" for a, b in zip(f, h, strict=True))
    frf = read_frf(_write(tmp_path, "modal.csv", "f_hz,re [m/N],im [m/N]\n" + rows + "\n"))
    measured = Tool(12.0, 2, frf)
    for ae in (3.0, 9.0):
        a = sle_frequency_domain_mm(ae, 0.1, tool, seed004_cutting())
        b = sle_frequency_domain_mm(ae, 0.1, measured, seed004_cutting())
        assert b == pytest.approx(a, rel=0.02, abs=2e-5)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("f_hz,re,im\n0,1e-7,0\n100,2e-7,0\n100,3e-7,0\n", r"frf.csv:4: frequency does not increase \(100 Hz then 100 Hz\)"),
        ("f_hz,re,im\n0,1e-7,0\n50,nan,0\n", r"frf.csv:3: re is not a finite number \('nan'\)"),
        ("f_hz,re,im\n0,1e-7,0\n50,2e-7\n", r"frf.csv:3: expected 3 columns, got 2 \(truncated line\?\)"),
        ("f_hz,re,im\n0,1e-7,0\n50,abc,0\n", r"frf.csv:3: re: 'abc' is not a number"),
        ("f_hz,real,im\n0,1e-7,0\n", r"frf.csv:1: FRF header lacks re \(expected f_hz,re,im\)"),
        ("f_hz,re [in/lbf],im\n0,1e-7,0\n", r"frf.csv:1: column re: unknown unit 'in/lbf'"),
        ("f_hz,re,im\n-5,1e-7,0\n10,1e-7,0\n", r"frf.csv:2: frequency must be >= 0 Hz, got -5"),
        ("f_hz,re,im\n0,1e-7,0\n", r"frf.csv: an FRF needs at least 2 lines"),
        ("# nothing\n\n", r"frf.csv: empty FRF file"),
    ],
)
def test_read_frf_bad_input(tmp_path: Path, text: str, message: str) -> None:
    p = _write(tmp_path, "frf.csv", text)
    with pytest.raises(MapError, match=message) as info:
        read_frf(p)
    assert str(info.value).startswith(str(p))


# ---------------------------------------------------------------------------
# Stock (OMI)
# ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def stepped():
    return read_program(STEPPED)


def test_stepped_sample_reads(stepped) -> None:
    stepped.require_complete()
    assert stepped.dialect == "heidenhain" and stepped.units == "mm"
    assert stepped.n_commands == 120  # L Y+0 .. L Y+236 every 2 mm, then L Y+244 out of the block
    end = stepped.command_end_mm
    np.testing.assert_allclose(end[:, 1], [*np.arange(0.0, 237.0, 2.0), 244.0])
    np.testing.assert_allclose(end[:, 0], 27.0)
    np.testing.assert_allclose(end[:, 2], -8.0)
    np.testing.assert_allclose(stepped.command_feed_mm_min, 403.4)
    assert "TOOL CALL 1 Z S2016" in stepped.text
    # 2016 rpm on a 12 mm tool is the paper's 76.01 m/min; 0.100 mm per tooth
    assert math.pi * 12.0 * 2016 / 1000 == pytest.approx(76.01, abs=0.01)


def test_read_stock_stepped_sample(stepped) -> None:
    ae = read_stock(STEPPED_OMI, stepped, seed004_tool())
    assert ae.shape == (120,)
    np.testing.assert_array_equal(ae[:40], 9.0)  # 75 % immersion, Y 0..78
    np.testing.assert_array_equal(ae[40:79], 6.0)  # 50 %, Y 80..156
    np.testing.assert_array_equal(ae[79:119], 3.0)  # 25 %, Y 158..236
    assert np.isnan(ae[119])  # the exit move ends beyond the probed face


def test_stepped_case_sle(stepped) -> None:
    tool, cut = seed004_tool(), seed004_cutting()
    ae = read_stock(STEPPED_OMI, stepped, tool)
    c = feed_per_tooth_mm(stepped.command_feed_mm_min, cut.spindle_rpm, tool.teeth)
    sle = sle_per_command_mm(ae, c, tool, cut)
    assert np.isnan(sle[119])
    zone = {v: sle[ae == v] for v in (9.0, 6.0, 3.0)}
    for v, s in zone.items():
        np.testing.assert_allclose(s, s[0], rtol=1e-12)  # one value per zone
        assert s[0] == pytest.approx(sle_time_domain_mm(v, float(c[0]), tool, cut), rel=0.02)
    # Two straight flutes, up-milling: no other tooth cuts when a tooth generates the wall (the other one is at
    # 180 deg, outside 0..phi_ex), so the SLE is the free vibration left from the previous tooth's cut; its phase
    # swings with the exit angle, its envelope shrinks as the immersion falls (longer free time to decay).
    envelope = [np.max(np.abs(sle_per_command_mm(np.linspace(v - 0.5, v + 0.5, 801), c[0], tool, cut))) for v in (9.0, 6.0, 3.0)]
    assert envelope[0] > envelope[1] > envelope[2]
    # quasi-static tool, no edge forces: the force at the generation instant is zero (h = 0, no other tooth in)
    stiff = Tool(12.0, 2, ModalFRF((Mode(40000.0, 0.2, 10.9),)))
    sharp = dataclasses.replace(cut, kte_n_mm=0.0, kre_n_mm=0.0)
    assert np.max(np.abs(sle_per_command_mm([9.0, 6.0, 3.0], c[0], stiff, sharp))) < 1e-5  # < 0.01 um


def test_read_stock_per_command(tmp_path: Path, stepped) -> None:
    p = _write(tmp_path, "stock.csv", "k,stock_mm\n0,9\n5,4.5\n118,3\n")
    ae = read_stock(p, stepped, seed004_tool())
    assert ae[0] == 9.0 and ae[5] == 4.5 and ae[118] == 3.0
    assert np.isnan(ae[1]) and np.count_nonzero(np.isnan(ae)) == 117  # 120 commands, 3 listed
    um = read_stock(_write(tmp_path, "um.csv", "k,stock [µm]\n3,2500\n"), stepped, seed004_tool())
    assert um[3] == pytest.approx(2.5)


def test_read_stock_partial_points_and_right_wall(tmp_path: Path, stepped) -> None:
    rows = "\n".join(f"27.5,{y},-4" for y in range(100, 151))
    p = _write(tmp_path, "part.csv", "x,y,z\n" + rows + "\n")
    ae = read_stock(p, stepped, seed004_tool())
    covered = ~np.isnan(ae)
    np.testing.assert_array_equal(np.flatnonzero(covered), np.arange(50, 76))  # Y 100..150
    np.testing.assert_allclose(ae[covered], 6.5)  # 27.5 - 27 + 6
    right = read_stock(_write(tmp_path, "r.csv", "x,y\n25,10\n25,20\n"), stepped, seed004_tool(), wall="right")
    assert right[5] == pytest.approx(8.0)  # wall on the +X side: (27 - 25) + 6


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("x,y,z\n30,10,-4\n30,300,-4\n", r"s.csv:3: stock point \(30, 300\) matches no command: it is beside no XY segment"),
        ("x,y,z\n30,10,-4\n40,20,-4\n", r"s.csv:3: stock point \(40, 20\) \(command k=10\): radial depth 19 mm is larger than "
         r"the tool diameter 12 mm"),
        ("x,y,z\n20,10,-4\n", r"s.csv:2: stock point \(20, 10\) \(command k=5\) matches no command: radial depth -1 mm <= 0"),
        ("x,y,z\n30,10\n", r"s.csv:2: expected 3 columns, got 2"),
        ("x,y,z\n30,ten,-4\n", r"s.csv:2: y: 'ten' is not a number"),
        ("k,stock_mm\n0,9\n120,3\n", r"s.csv:3: k=120 matches no command \(the program has 120 commands\)"),
        ("k,stock_mm\n0,9\n0,3\n", r"s.csv:3: duplicate k=0 \(first on line 2\)"),
        ("k,stock_mm\n1.5,9\n", r"s.csv:2: k must be a command index"),
        ("k,stock_mm\n2,13\n", r"s.csv:2: command k=2: radial depth 13 mm is larger than the tool diameter 12 mm"),
        ("k,stock_mm\n2,0\n", r"s.csv:2: command k=2 matches no command: radial depth 0 mm <= 0"),
        ("a,b\n1,2\n", r"s.csv:1: stock header must be x,y,z or k,stock_mm"),
        ("x,y\n", r"s.csv: stock file has a header but no rows"),
    ],
)
def test_read_stock_bad_input(tmp_path: Path, stepped, text: str, message: str) -> None:
    p = _write(tmp_path, "s.csv", text)
    with pytest.raises(MapError, match=message):
        read_stock(p, stepped, seed004_tool())

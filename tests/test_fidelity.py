"""Fidelity of the virtual CNC (ilcnc/shop/fidelity.py, ``ilcnc simulate --compare``).

The "machine" here is the virtual CNC itself, once with the same profile (the prediction must match its own
log exactly) and once with a drive 44 % slower than the profile says (the error lands on the same commands,
so the correlation stays high, but its size is off: not to be trusted). The comparison against LinuxCNC's
real motion is in tests/integration/test_linuxcnc_fidelity.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc.cli import app
from ilcnc.shop.fidelity import TARGET_CORRELATION, TARGET_DIFFERENCE, compare_signals
from ilcnc.vcnc.command_error import CommandSignal

from .conftest import cli_output

REPO = Path(__file__).resolve().parents[1]
PROFILE = REPO / "configs" / "linuxcnc-sim.yaml"
JSDC = REPO / "samples" / "jsdc.gcode"  # jscut engraving, 2,381 G01 commands (samples/MANIFEST.tsv)
runner = CliRunner()


def _cli(*args: object) -> dict:
    res = runner.invoke(app, [str(a) for a in args] + ["--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("fidelity")
    slow = d / "slow-drive.yaml"
    text = PROFILE.read_text(encoding="utf-8")
    assert "time_constant_s: 0.027851" in text
    slow.write_text(text.replace("time_constant_s: 0.027851", "time_constant_s: 0.040"), encoding="utf-8")
    out = {"same": d / "same.csv", "slow": d / "slow.csv"}
    _cli("simulate", JSDC, "--profile", PROFILE, "--log-out", out["same"])
    _cli("simulate", JSDC, "--profile", slow, "--log-out", out["slow"])
    return out


def test_the_virtual_cnc_predicts_its_own_log(logs: dict[str, Path]) -> None:
    f = _cli("simulate", JSDC, "--profile", PROFILE, "--compare", logs["same"])["fidelity"]
    assert f["commands"] == 2381
    assert f["correlation"] > 0.999999
    assert all(c > 0.999999 for c in f["axis_correlation"].values())
    # the log holds positions rounded to 0.1 µm: the difference is that rounding, not a model error
    assert f["rms_difference_mm"] < 1e-6
    assert f["rms_measured_mm"] == pytest.approx(f["rms_predicted_mm"], rel=1e-4)
    assert f["contour_measured_mm"]["rms"] == pytest.approx(f["contour_predicted_mm"]["rms"], rel=1e-4)
    assert f["trusted"] is True


def test_a_slower_drive_than_the_profile_says_is_not_trusted(logs: dict[str, Path]) -> None:
    f = _cli("simulate", JSDC, "--profile", PROFILE, "--compare", logs["slow"])["fidelity"]
    # same commands err (corr 0.996) but by nearly twice as much (40.1 vs 21.8 µm): 46 % of the error is missed
    assert f["correlation"] > TARGET_CORRELATION
    assert f["rms_measured_mm"] > 1.6 * f["rms_predicted_mm"]
    assert f["relative_difference"] > 2 * TARGET_DIFFERENCE
    assert f["trusted"] is False
    # the worst disagreements come first
    w = f["worst"]
    d = [np.linalg.norm(np.subtract(x["measured_um"], x["predicted_um"])) for x in w]
    assert d == sorted(d, reverse=True)


def test_table_output_names_the_verdict(logs: dict[str, Path]) -> None:
    res = runner.invoke(app, ["simulate", str(JSDC), "--profile", str(PROFILE), "--compare", str(logs["slow"])])
    assert res.exit_code == 0, res.output
    assert "correlation of |E(k)|" in res.output
    assert "(learn --log)" in res.output


def test_a_log_of_another_program_is_refused_in_one_line(logs: dict[str, Path]) -> None:
    res = runner.invoke(app, ["simulate", str(REPO / "samples" / "compass.ngc"), "--profile", str(PROFILE),
                              "--compare", str(logs["same"])])
    assert res.exit_code == 1
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and str(logs["same"]) in lines[0]
    assert "not a run of this program" in lines[0]


@pytest.mark.parametrize("opt", ["--log-out", "--against"])
def test_compare_does_not_mix_with_other_runs(logs: dict[str, Path], tmp_path: Path, opt: str) -> None:
    val = tmp_path / "x.csv" if opt == "--log-out" else JSDC
    res = runner.invoke(app, ["simulate", str(JSDC), "--profile", str(PROFILE), "--compare", str(logs["same"]),
                              opt, str(val)])
    assert res.exit_code == 2  # a usage error (issue 25 item 17)
    assert cli_output(res).strip() == f"error: --compare judges the virtual CNC on PROGRAM as it is: it does not go with {opt}"
    assert not (tmp_path / "x.csv").exists()


def test_compare_signals_of_different_programs_raise() -> None:
    a = CommandSignal(np.zeros((3, 3)), np.zeros(3), np.ones(3, bool), "path")
    b = CommandSignal(np.zeros((4, 3)), np.zeros(4), np.ones(4, bool), "path")
    with pytest.raises(ValueError, match="3 and 4 commands"):
        compare_signals(a, b)


def test_compare_signals_only_over_commands_both_measured() -> None:
    e = np.array([[1.0, 0, 0], [2.0, 0, 0], [3.0, 0, 0], [100.0, 0, 0]]) * 1e-3
    m = CommandSignal(e, np.arange(4.0), np.array([True, True, True, False]), "path")
    p = CommandSignal(e * 2, np.arange(4.0), np.array([True, True, True, True]), "path")
    f = compare_signals(m, p, command_line=np.array([10, 11, 12, 13]))
    assert f.commands == 3
    assert f.correlation == pytest.approx(1.0)
    assert np.isnan(f.axis_correlation["y"])  # y never varies: nothing to correlate
    assert f.rms_difference_mm == pytest.approx(np.sqrt((1 + 4 + 9) / 3) * 1e-3)
    assert f.relative_difference == pytest.approx(1.0)
    assert not f.trusted
    assert f.worst[0]["line"] == 12
    assert f.to_json()["axis_correlation"]["y"] is None


def _as_halsampler(csv: Path, out: Path, order: tuple[str, ...]) -> None:
    """Write an ilcnc axis log as a halsampler log (whitespace, no header) with the columns in ``order``."""
    a = np.genfromtxt(csv, delimiter=",", names=True)
    cols = [a[name] if name != "line" else a["line"].astype(int) for name in order]
    with out.open("w", encoding="ascii") as f:
        for row in zip(*cols, strict=True):
            f.write(" ".join(str(int(v)) if i == 0 else f"{v:.6f}" for i, v in enumerate(row)) + "\n")


ORDER = ("line", "x_act", "y_act", "z_act", "x_ref", "y_ref", "z_ref")  # no sample number: halsampler without -t


def test_log_columns_read_a_halsampler_log_in_another_order(logs: dict[str, Path], tmp_path: Path) -> None:
    hal = tmp_path / "jsdc.hal.log"
    _as_halsampler(logs["same"], hal, ORDER)
    cols = " ".join(ORDER)
    f = _cli("simulate", JSDC, "--profile", PROFILE, "--compare", hal, "--log-format", "halsampler",
             "--log-columns", cols)["fidelity"]
    assert f["commands"] == 2381 and f["correlation"] > 0.999999 and f["trusted"] is True
    # learn --log reads it the same way: one measured step
    res = _cli("learn", JSDC, "--profile", PROFILE, "--log", hal, "--log-format", "halsampler", "--log-columns", cols,
               "--state", tmp_path / "state", "--out", tmp_path / "jsdc.ilc1.gcode")
    assert res["status"] == "stepped"
    assert res["iterations"][0]["contour_error_mm"]["rms"] == pytest.approx(f["contour_measured_mm"]["rms"], rel=1e-3)
    # the default order (n line x_ref ...) reads x_act as the program line: refused in one line
    bad = runner.invoke(app, ["simulate", str(JSDC), "--profile", str(PROFILE), "--compare", str(hal),
                              "--log-format", "halsampler"])
    assert bad.exit_code == 1 and cli_output(bad).startswith("error: ") and len(cli_output(bad).strip().splitlines()) == 1


def test_log_columns_name_what_is_wrong(logs: dict[str, Path], tmp_path: Path) -> None:
    hal = tmp_path / "jsdc.hal.log"
    _as_halsampler(logs["same"], hal, ORDER)
    for cols, msg in (("line x_act - z_act x_ref y_ref z_ref", "halsampler column map lacks y_act"),
                      ("line x_act y_act z_act x_ref y_ref speed", "unknown halsampler column name(s) speed"),
                      ("line x_act x_act z_act x_ref y_ref z_ref", "halsampler column 'x_act' given twice")):
        res = runner.invoke(app, ["simulate", str(JSDC), "--profile", str(PROFILE), "--compare", str(hal),
                                  "--log-format", "halsampler", "--log-columns", cols])
        assert res.exit_code == 2, res.output  # the option is wrong whatever the file: a usage error
        assert cli_output(res).startswith("error: ") and msg in cli_output(res) and len(cli_output(res).strip().splitlines()) == 1
    res = runner.invoke(app, ["simulate", str(JSDC), "--profile", str(PROFILE), "--compare", str(logs["same"]),
                              "--log-columns", " ".join(ORDER)])
    assert res.exit_code == 1 and "a column map applies only to halsampler and TNCscope logs" in res.output


def test_log_offset_brings_machine_coordinates_into_the_programs(logs: dict[str, Path], tmp_path: Path) -> None:
    # the same run logged in machine coordinates, with the part's work offset at (100, 50, -20) mm
    a = np.genfromtxt(logs["same"], delimiter=",", names=True)
    shifted = tmp_path / "machine.csv"
    lines = [",".join(a.dtype.names)]
    off = {"x": 100.0, "y": 50.0, "z": -20.0}
    for row in a:
        lines.append(",".join(f"{row[n] + off.get(n[0], 0.0) if n[1:] in ('_ref', '_act') else row[n]:.6f}"
                              if n not in ("k", "line") else str(int(row[n])) for n in a.dtype.names))
    shifted.write_text("\n".join(lines) + "\n", encoding="ascii")
    res = runner.invoke(app, ["simulate", str(JSDC), "--profile", str(PROFILE), "--compare", str(shifted)])
    assert res.exit_code == 1 and "off the path" in res.output
    f = _cli("simulate", JSDC, "--profile", PROFILE, "--compare", shifted, "--log-offset", "100,50,-20")["fidelity"]
    assert f["commands"] == 2381 and f["correlation"] > 0.999999 and f["rms_difference_mm"] < 1e-6
    step = _cli("learn", JSDC, "--profile", PROFILE, "--log", shifted, "--log-offset", "100, 50, -20",
                "--state", tmp_path / "state", "--out", tmp_path / "jsdc.ilc1.gcode")
    assert step["status"] == "stepped"
    assert step["iterations"][0]["contour_error_mm"]["rms"] == pytest.approx(f["contour_measured_mm"]["rms"], rel=1e-6)


@pytest.mark.parametrize("bad", ["100,50", "a,b,c", "1,2,nan"])
def test_a_malformed_log_offset_is_a_usage_error(logs: dict[str, Path], bad: str) -> None:
    res = runner.invoke(app, ["simulate", str(JSDC), "--profile", str(PROFILE), "--compare", str(logs["same"]),
                              "--log-offset", bad])
    assert res.exit_code == 2
    assert cli_output(res).strip() == f"error: --log-offset must be three numbers X,Y,Z (e.g. 100,50,-20), got {bad!r}"

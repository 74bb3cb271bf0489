"""`ilcnc linuxcnc prepare PROG`: what a log run on LinuxCNC needs, on real programs (issue 23 item 6)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from ilcnc.axislog.halsampler import HALSAMPLER_COLUMNS
from ilcnc.cli import app
from ilcnc.outcomes import PathMode
from ilcnc.program import read_program
from ilcnc.shop.linuxcnc_prepare import prepare_run, sampler_hal
from tests.conftest import OWN, REPO, SAMPLES, cli_output

runner = CliRunner()
PROFILE = REPO / "configs" / "linuxcnc-sim.yaml"
SIM_INI = REPO / "configs" / "linuxcnc-sim" / "sim.ini"


def test_docs_hal_file_is_what_prepare_writes() -> None:
    """docs/linuxcnc.md section 2's ilcnc-log.hal is the generator's output for trivkins XYZ (one source)."""
    doc = (REPO / "docs" / "linuxcnc.md").read_text()
    block = re.search(r"```\n(# ilcnc-log.hal:.*?)```", doc, re.S)
    assert block is not None
    assert block.group(1) == sampler_hal({"x": 0, "y": 1, "z": 2})
    # the sampler's pins follow the column order the halsampler reader takes by default
    assert "cfg=s" + "f" * (len(HALSAMPLER_COLUMNS) - 2) in block.group(1)


def test_two_axis_machine_leaves_z_pins_unconnected() -> None:
    hal = sampler_hal({"x": 0, "y": 1})
    assert "joint.2" not in hal and "sampler.0.pin.3 (z_ref) left unconnected" in hal


def test_jsdc_without_path_control_needs_g64_p_q0() -> None:
    res = prepare_run(SAMPLES / "gcode" / "jsdc.gcode", PROFILE, ini_path=SIM_INI)
    assert not res.ready
    assert [r.mode for r in res.ranges] == [PathMode.UNSET] and res.ranges[0].moves == 2381
    assert "LinuxCNC starts in G64 without P" in res.startup
    assert len(res.changes) == 1 and "insert a line `G64 P0.01 Q0` before line" in res.changes[0]
    assert res.joints == {"x": 0, "y": 1, "z": 2}


def test_square_g64_p_beyond_tolerance(tmp_path: Path) -> None:
    res = runner.invoke(app, ["linuxcnc", "prepare", str(OWN / "square.ngc"), "--profile", str(PROFILE), "--json"])
    assert res.exit_code == 0, res.output
    d = json.loads(cli_output(res))
    assert d["ready"] is False and d["settings"] == [{"line": 2, "mode": "G64 P", "p": 0.05, "q": 0.0}]
    assert d["path_control"][0]["mode"] == "G64 P" and d["path_control"][0]["tolerance_mm"] == 0.05
    assert any(c.startswith("line 2: G64 P0.05 rounds corners by up to 0.05 mm") for c in d["changes"])
    assert "--log run0.log" in d["learn"] and d["learn"].startswith("ilcnc learn ")
    assert d["hal"] == sampler_hal({"x": 0, "y": 1, "z": 2})


def test_g64_p_without_q0_and_write_hal(tmp_path: Path) -> None:
    prog = tmp_path / "sq.ngc"
    prog.write_text((OWN / "square.ngc").read_text().replace("G64 P0.05 Q0", "G64 P0.01"))
    hal = tmp_path / "ilcnc-log.hal"
    args = ["linuxcnc", "prepare", str(prog), "--profile", str(PROFILE), "--write-hal", str(hal)]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    out = cli_output(res)
    assert "line 2: G64 P0.01 without Q" in out and "add Q0" in out
    assert hal.read_text() == sampler_hal({"x": 0, "y": 1, "z": 2})
    res = runner.invoke(app, args)
    assert res.exit_code == 2 and "--force" in cli_output(res)
    assert runner.invoke(app, [*args, "--force"]).exit_code == 0


def test_g61_program_is_ready() -> None:
    res = prepare_run(SAMPLES / "gcode" / "tiny_cat_outline.ngc", PROFILE)
    assert res.ready and {r.mode for r in res.ranges} == {PathMode.EXACT_PATH}
    assert [s.line for s in res.settings if s.mode is PathMode.EXACT_PATH] == [11]
    assert any("no --ini" in n for n in res.notes)


def _prepare_out(prog: Path, out: Path, *extra: str):
    return runner.invoke(app, ["linuxcnc", "prepare", str(prog), "--profile", str(PROFILE), "--out", str(out),
                               "--json", *extra])


def test_out_inserts_the_path_control_and_keeps_every_line(tmp_path: Path) -> None:
    """jsdc (no path control): --out inserts one marked `G64 P0.01 Q0` before the first move; every other line is
    the input's, byte for byte; the ready program moves the tool exactly as the input and needs nothing more."""
    src = SAMPLES / "gcode" / "jsdc.gcode"
    out = tmp_path / "jsdc.ready.gcode"
    res = _prepare_out(src, out)
    assert res.exit_code == 0, res.output
    d = json.loads(res.stdout)
    assert d["edits"] == [{"line": 3, "action": "insert", "words": "G64 P0.01 Q0", "why": d["changes"][0]}]
    assert d["out"] == str(out) and f"ilcnc learn {out} " in d["learn"]
    a, b = src.read_bytes().split(b"\n"), out.read_bytes().split(b"\n")
    assert b[2] == b"G64 P0.01 Q0 (ilcnc prepare)" and b[:2] + b[3:] == a
    assert prepare_run(out, PROFILE).ready
    p, q = read_program(src), read_program(out)
    assert np.array_equal(p.moves.end_mm, q.moves.end_mm) and np.array_equal(p.command_line + 1, q.command_line)
    again = _prepare_out(src, out)
    assert again.exit_code == 2 and "--force" in again.output and out.read_bytes() == b"\n".join(b)
    assert _prepare_out(src, src).exit_code == 2 and src.read_bytes() == b"\n".join(a)  # never over an input


def test_out_replaces_g64_words_in_place_with_crlf(tmp_path: Path) -> None:
    """square.ngc's `G64 P0.05 Q0` (beyond the 0.01 mm tolerance) becomes `G64 P0.01 Q0` on its own line, the
    other words and the file's CRLF line ends kept; no line moves."""
    prog = tmp_path / "sq.ngc"
    prog.write_bytes((OWN / "square.ngc").read_bytes().replace(b"\n", b"\r\n"))
    out = tmp_path / "sq.ready.ngc"
    res = _prepare_out(prog, out)
    assert res.exit_code == 0, res.output
    a, b = prog.read_bytes().split(b"\r\n"), out.read_bytes().split(b"\r\n")
    assert b[1] == b"G21 G90 G17 G64 P0.01 Q0 (ilcnc prepare)" and b[:1] + b[2:] == a[:1] + a[2:]
    assert prepare_run(out, PROFILE).ready


def test_out_refuses_a_g64_given_by_a_parameter(tmp_path: Path) -> None:
    prog = tmp_path / "param.ngc"
    prog.write_text((OWN / "square.ngc").read_text().replace("G64 P0.05 Q0", "G64 P[#1 * 0.05]"))
    out = tmp_path / "param.ready.ngc"
    res = _prepare_out(prog, out)
    assert res.exit_code == 1 and not out.exists()
    assert f"{prog}:2:" in res.output and "G64's P or Q is an expression" in res.output

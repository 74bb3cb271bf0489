"""ilcnc diff: the corrections it lists are the learning's, the inserted lines are refinement's, nothing else."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.program.insert import MARKER
from ilcnc.shop.corrections import read_corrections
from ilcnc.shop.diff import diff_files, format_diff

from .conftest import OWN, REPO, SAMPLES

PROFILE = REPO / "configs" / "example-mill.yaml"
_NUM = re.compile(r"[-+]?(\d*)[.,]?(\d*)")


def _cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "ilcnc", *map(str, args)], capture_output=True, text=True,
                          timeout=600)


def _learn(src: Path, out: Path, *extra: str, profile: Path = PROFILE) -> Path:
    r = _cli("learn", src, "--profile", profile, "--out", out, *extra)
    assert r.returncode == 0, r.stderr
    return out


def _output_iteration(out: Path) -> tuple[Path, Path]:
    """The state's program that is byte for byte the output, and its corrections CSV."""
    state = Path(str(out) + ".state")
    for prog in sorted(state.glob("iter-*" + out.suffix)):
        if prog.read_bytes() == out.read_bytes():
            return prog, prog.with_name(prog.name.replace(out.suffix, ".corrections.csv"))
    raise AssertionError("no iteration of the state is the output")


def _decimals(word: str | None) -> int | None:
    if word is None:
        return None
    m = _NUM.search(word.lstrip("IXYZixyz"))
    return len(m.group(2)) if m else None


def _diff_json(orig: Path, out: Path) -> dict:
    r = _cli("diff", orig, out, "--json")
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def _check_against_state(orig: Path, out: Path) -> dict:
    """Every command's correction in the state's corrections.csv is the diff's ΔX/ΔY/ΔZ of its line, within
    half a unit of the last decimal written (the output's word on that axis, else the profile's resolution);
    a line the diff does not list has corrections that round to 0; the inserted lines are exactly the output's
    marked lines; nothing else changed."""
    d = _diff_json(orig, out)
    prog_path, corr_path = _output_iteration(out)
    prog = read_program(prog_path)
    corr = read_corrections(corr_path, prog.n_commands)
    min_dec = load_profile(PROFILE).min_decimals(prog.units)
    # the program the corrections were added to: iteration 0 (the refined program, or the original)
    start = read_program(next(Path(str(out) + ".state").glob("iter-000.*")))
    by_out = {c["out_line"]: c for c in d["changed"]}
    inserted = {i["out_line"] for i in d["inserted"]}
    marked = {n for n, s in enumerate(out.read_text(encoding="latin-1").splitlines(), 1) if MARKER in s}
    assert inserted == marked
    assert all(i["marked"] for i in d["inserted"])
    assert d["summary"]["only_coordinates"] and d["summary"]["breaches"] == []
    assert d["removed"] == []
    n_checked = 0
    for k, line in enumerate(prog.command_line.tolist()):
        if line in inserted:
            continue
        c = by_out.get(line)
        for a, name in enumerate("xyz"):
            if c is None:
                # unchanged text: the correction rounds to nothing at the written resolution, or the line does not
                # write the axis and inherits it from the line before, which carries the same correction (a -1 um X
                # of a 'G1 F800 Y..' after a corrected plunge): the end point moved by it all the same
                moved = prog.moves.end_mm[prog.command_moves[k], a] - start.moves.end_mm[start.command_moves[k], a]
                assert abs(moved - corr[k, a]) <= 0.5 * 10.0 ** -min_dec + 1e-9, (k, line)
                continue
            word = next((w["new"] for w in c["words"] if w["kind"] == "axis" and w["letter"] == name.upper()), None)
            dec = _decimals(word) if word is not None else min_dec
            tol_um = 0.5 * 10.0 ** -dec * 1e3 + 1e-6  # half a unit of the written number's last decimal
            assert abs(c["delta_um"][name] - corr[k, a] * 1e3) <= tol_um, (k, line, name)
            n_checked += 1
    # every listed line is a command's (or an arc's centre / a modal word written out), none is spurious
    cmd_lines = set(prog.command_line.tolist())
    for c in d["changed"]:
        assert c["out_line"] in cmd_lines or any(w["kind"] == "centre" for w in c["words"]) or all(
            w["old"] is None for w in c["words"]), c
    d["_checked"] = n_checked
    return d


def test_refined_square_lists_its_corrections_and_inserted_lines(tmp_path: Path) -> None:
    orig = OWN / "square.ngc"
    out = _learn(orig, tmp_path / "sq.ngc", "--refine")
    d = _check_against_state(orig, out)
    state = json.loads((tmp_path / "sq.ngc.state" / "state.json").read_text())
    assert len(d["inserted"]) == state["part"]["refined"]["inserted_lines"] == 9
    assert d["_checked"] > 0 and d["summary"]["lines_corrected"] == 3
    big = max(np.linalg.norm(list(c["delta_um"].values())) for c in d["changed"])
    assert d["summary"]["largest_correction_um"] == pytest.approx(big, rel=1e-12)
    # each inserted line precedes the original line of the move it splits
    refined = read_program(tmp_path / "sq.ngc.state" / "refined.ngc")
    assert {i["before_line"] for i in d["inserted"]} == {4, 5, 6, 7, 8}
    assert refined.n_commands == read_program(orig).n_commands + 9
    text = _cli("diff", orig, out)
    assert text.returncode == 0
    lines = text.stdout.splitlines()
    assert max(map(len, lines)) <= 80
    assert "only coordinate numbers changed (and marked lines inserted)" in lines
    assert "CONTRACT BREACH" not in text.stdout


def test_jsdc_refined(tmp_path: Path) -> None:
    orig = REPO / "samples" / "jsdc.gcode"
    out = _learn(orig, tmp_path / "jsdc.gcode", "--refine", "--iterations", "2")
    d = _check_against_state(orig, out)
    assert d["_checked"] > 3000 and d["summary"]["lines_inserted"] > 0
    # the corner where a path ends and the tool retracts (behind jsdc's repeated last point) is refined: a point
    # on the retract's part in the material, before the retract's own line
    lines = out.read_text().splitlines()
    retracts = [i for i, ln in enumerate(lines) if ln.startswith("G1 Z1.0000 F2540")]
    assert len(retracts) >= 5
    assert sum(lines[i - 1].endswith("; ilcnc refine") for i in retracts) >= 5


def test_jsdc_retracts_written_out(tmp_path: Path) -> None:
    """Without refinement the point before each retract is corrected; the retract, kept as programmed (air),
    gets the X or Y word it did not need before, which diff lists as a word without an old value."""
    orig = REPO / "samples" / "jsdc.gcode"
    out = _learn(orig, tmp_path / "jsdc.gcode", "--iterations", "2")
    d = _check_against_state(orig, out)
    kept = [c for c in d["changed"] if not any(abs(v) > 1e-6 for v in c["delta_um"].values())]
    assert kept and all(all(w["old"] is None for w in c["words"]) for c in kept)


def test_arc_centre_words_follow_a_corrected_start(tmp_path: Path) -> None:
    orig = OWN / "circle.ngc"
    out = _learn(orig, tmp_path / "circle.ngc", "--iterations", "2")
    d = _check_against_state(orig, out)
    arcs = [c for c in d["changed"] if any(w["kind"] == "centre" for w in c["words"])]
    assert arcs
    src = read_program(orig)
    new = read_program(out)
    for c in arcs:
        # the arc keeps its end point and its centre; its centre words changed because its start moved
        i = int(np.flatnonzero(src.moves.line == c["line"])[-1])
        j = int(np.flatnonzero(new.moves.line == c["out_line"])[-1])
        assert np.allclose(src.moves.center_mm[i], new.moves.center_mm[j], atol=1e-9, equal_nan=True)
        assert all(abs(v) < 1e-6 for v in c["delta_um"].values())
        assert c["line"] - 1 in {x["line"] for x in d["changed"]}  # the line before it was corrected


def test_gates_refined_lists_inserted_lines_only(tmp_path: Path) -> None:
    orig = SAMPLES / "contour" / "Gates_combined_R12.nc"
    out = _learn(orig, tmp_path / "gates.nc", "--refine", "--iterations", "1")
    d = _check_against_state(orig, out)
    state = json.loads((tmp_path / "gates.nc.state" / "state.json").read_text())
    assert len(d["inserted"]) == state["part"]["refined"]["inserted_lines"] > 1000
    # one iteration, kept (24.83 -> 24.47 um max): every changed line carries its command's correction (checked
    # above), the inserted lines are the refined ones
    assert d["changed"] and state["iterations"][-1]["kept"]
    assert d["lines_output"] == d["lines_original"] + len(d["inserted"])


def test_klartext_renumbered_blocks_are_no_change(tmp_path: Path) -> None:
    orig = OWN / "square.h"
    # the Klartext square's corner corrections cost +9.8 % cycle time on the example mill (measured 9.37 -> 7.70 µm
    # max, 5.71 -> 6.27 s), beyond the default learning.cycle_budget_pct: this test of the diff allows them
    text = PROFILE.read_text(encoding="utf-8")
    assert "\nlearning:\n" in text
    wide = tmp_path / "mill.yaml"
    wide.write_text(text.replace("\nlearning:\n", "\nlearning:\n  cycle_budget_pct: 100\n", 1), encoding="utf-8")
    out = _learn(orig, tmp_path / "square.h", "--refine", "--iterations", "2", profile=wide)
    d = _check_against_state(orig, out)
    first = min(i["out_line"] for i in d["inserted"])
    # every block after the first inserted one got a new number, none of them is listed for that
    assert d["summary"]["renumbered"] == d["lines_output"] - first - len(d["inserted"]) + 1
    assert d["summary"]["lines_changed"] == d["summary"]["lines_corrected"] == 4
    # only coordinate words changed on them, never a block number (one corner now takes both X and Y)
    assert all(c["words"] and all(w["kind"] == "axis" for w in c["words"]) for c in d["changed"])
    assert d["summary"]["stamp"] is False


def test_the_provenance_stamp_is_no_change(tmp_path: Path) -> None:
    orig = OWN / "square.h"
    plain = _learn(orig, tmp_path / "plain.h", "--refine", "--iterations", "2")
    stamped = _learn(orig, tmp_path / "stamped.h", "--refine", "--iterations", "2", "--stamp")
    assert "ilcnc: learned from square.h" in stamped.read_text().splitlines()[0]
    a, b = _diff_json(orig, plain), _diff_json(orig, stamped)
    assert b["summary"]["stamp"] is True and b["summary"]["only_coordinates"]
    assert [c["delta_um"] for c in a["changed"]] == [c["delta_um"] for c in b["changed"]]
    assert len(a["inserted"]) == len(b["inserted"])


def test_a_change_besides_coordinates_is_a_loud_breach(tmp_path: Path) -> None:
    orig = OWN / "square.ngc"
    out = _learn(orig, tmp_path / "sq.ngc", "--refine")
    lines = out.read_text().splitlines(keepends=True)
    edited = tmp_path / "edited.ngc"
    # a post-processor's slip: another program end, a lost comment line, an unmarked extra move
    body = [ln.replace("M2", "M30") for ln in lines[1:]]
    body.insert(3, "G1 X1 Y1\n")
    edited.write_text("".join(body))
    d = diff_files(orig, edited)
    breaches = d.breaches
    assert any("M2 -> M30" in b for b in breaches)
    assert "line 1: removed" in breaches
    assert any("without the 'ilcnc refine' marker: G1 X1 Y1" in b for b in breaches)
    r = _cli("diff", orig, edited)
    assert r.returncode == 0  # the diff was computed; the breach is printed, not an error
    assert f"CONTRACT BREACH: {len(breaches)} changes besides" in r.stdout
    assert all(("  " + b)[:79] in r.stdout for b in breaches)
    assert max(map(len, format_diff(d))) <= 80


def test_bad_input_and_usage(tmp_path: Path) -> None:
    r = _cli("diff", OWN / "square.ngc", OWN / "square.h")
    assert r.returncode == 1 and r.stderr.startswith("error: ") and "one dialect" in r.stderr
    r = _cli("diff", OWN / "square.ngc", tmp_path / "missing.ngc")
    assert r.returncode == 1 and "file not found" in r.stderr
    assert _cli("diff", OWN / "square.ngc").returncode == 2


def test_a_program_against_itself_is_no_change() -> None:
    for p in (OWN / "star.h", REPO / "samples" / "circle-inch.gcode", SAMPLES / "contour" / "SheepTile-v2.nc"):
        d = diff_files(p, p)
        assert d.changed == [] and d.inserted == [] and d.removed == [] and d.breaches == []

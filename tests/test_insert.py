"""Inserting straight-feed points on a program's own path (ilcnc.program.insert) on real programs."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from ilcnc.errors import UnsupportedError
from ilcnc.program import read_program
from ilcnc.program.insert import InsertResult, insert_points, required_decimals
from ilcnc.program.model import MOVE_LINE, Program
from tests.conftest import OWN, REPO, SAMPLES

REPO_SAMPLES = REPO / "samples"
CONTOUR = SAMPLES / "contour"
MARK = "ilcnc refine"
_KL_NUMBER = re.compile(r"^\s*\d+(?=[ \t])")


def _write(tmp_path: Path, src: Path, text: str, name: str | None = None) -> Path:
    out = tmp_path / (name or src.name)
    out.write_bytes(text.encode("latin-1"))
    return out


def _lines(text: str) -> list[str]:
    return text.split("\n")


def _all_lines(prog: Program, per_move: int = 2, seed: int = 0) -> dict[int, list[float]]:
    """``per_move`` random fractions on every straight feed command."""
    rng = np.random.default_rng(seed)
    mv = prog.moves
    idx = np.flatnonzero((mv.kind == MOVE_LINE) & (mv.command >= 0))
    return {int(i): sorted(rng.uniform(0.02, 0.98, per_move).tolist()) for i in idx}


def check_round_trip(prog: Program, res: InsertResult, tmp_path: Path, *, numbered: bool = False) -> Program:
    """Re-read the result from a file: same path, pieces on the segments, original lines in order."""
    path = _write(tmp_path, prog.path, res.text)
    again = read_program(path, default_units=prog.units)
    again.require_complete()
    mv, nv = prog.moves, again.moves
    pieces: dict[int, int] = {}
    for ins in res.inserted:
        pieces[ins.move] = pieces.get(ins.move, 0) + 1
    assert len(nv) == len(mv) + res.n_inserted
    r = 0
    for i in range(len(mv)):
        s, e = mv.start_mm[i], mv.end_mm[i]
        d = e - s
        last_t = 0.0
        for k in range(pieces.get(i, 0)):
            p = nv.end_mm[r + k]
            assert nv.kind[r + k] == MOVE_LINE
            t = float(np.dot(p - s, d) / np.dot(d, d))
            assert np.linalg.norm(p - (s + t * d)) < 1e-4, (i, k)  # 0.1 µm
            assert last_t < t < 1.0, (i, k)
            last_t = t
            assert nv.feed_mm_min[r + k] == mv.feed_mm_min[i]
            assert res.line_inserted[int(nv.line[r + k]) - 1]
        j = r + pieces.get(i, 0)
        assert nv.kind[j] == mv.kind[i]
        np.testing.assert_allclose(nv.end_mm[j], e, atol=1e-9, rtol=0)
        np.testing.assert_allclose(nv.start_mm[r], s, atol=1e-9, rtol=0)
        assert int(res.line_origin[int(nv.line[j]) - 1]) == int(mv.line[i])
        r = j + 1
    # every original line present, in order; inserted lines marked; only rewritten lines changed
    old = _lines(prog.text)
    new = _lines(res.text)
    assert len(new) == len(old) + res.n_inserted
    kept = [ln for ln, ins in zip(new, [*res.line_inserted.tolist(), False], strict=False) if not ins]
    assert len(kept) == len(old)
    rewritten = set(res.rewritten_lines)
    for n, (a, b) in enumerate(zip(old, kept, strict=True), start=1):
        if n in rewritten:
            continue
        if numbered:
            a, b = _KL_NUMBER.sub("", a), _KL_NUMBER.sub("", b)
        assert a == b, n
    for ins in res.inserted:
        assert MARK in new[ins.new_line - 1]
        assert new[ins.new_line - 1].rstrip("\r") == ins.text
    assert sum(MARK in ln for ln in new) == res.n_inserted + sum(MARK in ln for ln in old)
    return again


def _strip_marked(text: str) -> str:
    return "".join(ln for ln in text.splitlines(keepends=True) if MARK not in ln)


def test_required_decimals() -> None:
    assert required_decimals(1.0) == 4
    assert required_decimals(25.4) == 6  # 5 inch decimals could be 0.127 µm off


def test_square_ngc(tmp_path: Path) -> None:
    prog = read_program(OWN / "square.ngc")
    res = insert_points(prog, {2: [0.25, 0.5], 3: [0.5]}, min_decimals=3)
    assert res.n_inserted == 3 and not res.skipped
    new = _lines(res.text)
    assert new[4] == "G1 X12.5000 Y0.0000 Z0.0000 F3000 (ilcnc refine)"
    assert new[7] == "G1 X50.0000 Y25.0000 Z0.0000 (ilcnc refine)"  # no F on the move's line: modal feed
    assert [(x.move, x.before_line, x.new_line) for x in res.inserted] == [(2, 5, 5), (2, 5, 6), (3, 6, 8)]
    assert res.original_line(5) == (5, True) and res.original_line(7) == (5, False)
    assert res.decimals == {2: 4, 3: 4}
    check_round_trip(prog, res, tmp_path)
    assert _strip_marked(res.text) == prog.text


def test_pairs_and_skips(tmp_path: Path) -> None:
    prog = read_program(OWN / "square.ngc")
    res = insert_points(prog, [(0, 0.5), (3, 0.5), (3, 0.25)], min_decimals=3)
    assert [s.move for s in res.skipped] == [0] and "not a straight feed" in res.skipped[0].reason
    assert [x.fraction for x in res.inserted] == [0.25, 0.5]
    with pytest.raises(ValueError, match="fraction"):
        insert_points(prog, {3: [1.0]}, min_decimals=3)
    with pytest.raises(ValueError, match="out of range"):
        insert_points(prog, {99: [0.5]}, min_decimals=3)


def test_crlf_copy(tmp_path: Path) -> None:
    src = (OWN / "square.ngc").read_bytes().replace(b"\n", b"\r\n")
    path = tmp_path / "square_crlf.ngc"
    path.write_bytes(src)
    prog = read_program(path)
    res = insert_points(prog, {i: [0.3, 0.6] for i in range(1, 6)}, min_decimals=3)
    assert res.n_inserted == 10
    assert "\n" not in res.text.replace("\r\n", "")
    check_round_trip(prog, res, tmp_path)
    assert _strip_marked(res.text) == prog.text


def test_jsdc_every_move(tmp_path: Path) -> None:
    """grbl, ';' comments: two points on every straight feed of a 2400-line jscut program."""
    prog = read_program(REPO_SAMPLES / "jsdc.gcode")
    want = _all_lines(prog)
    res = insert_points(prog, want, min_decimals=3)
    # the first moves (clearance Z, then X/Y) start at an unknown position; a few are (nearly) zero-length
    assert [s.move for s in res.skipped[:2]] == [0, 1]
    assert all("not set by the program" in s.reason for s in res.skipped[:2])
    assert all(s.reason == "zero-length move" or s.reason.startswith("too short") for s in res.skipped[2:])
    assert len(res.skipped) < len(want) // 50
    assert res.n_inserted == 2 * (len(want) - len(res.skipped))
    assert all(x.text.endswith("; ilcnc refine") for x in res.inserted)
    check_round_trip(prog, res, tmp_path)
    assert _strip_marked(res.text) == prog.text
    first = res.inserted[0].text
    assert first.startswith("G1 X43.9090 Y-28.2880 Z") and first.endswith("; ilcnc refine") and "F" not in first


def test_compass_points_along(tmp_path: Path) -> None:
    prog = read_program(REPO_SAMPLES / "compass.ngc")
    want = _all_lines(prog, per_move=1, seed=3)
    res = insert_points(prog, want, min_decimals=3)
    # a few moves are zero-length or only a few µm long (a piece would be under 0.1 µm)
    assert all(s.reason == "zero-length move" or s.reason.startswith("too short") for s in res.skipped)
    assert len(res.skipped) < len(want) // 20
    # at least the decimals of the move's own words (up to 6 here), and at least 4 (0.05 µm)
    src = _lines(prog.text)
    for x in res.inserted:
        got = [len(d) for d in re.findall(r"[XYZ]-?\d+\.(\d+)", x.text)]
        own = [len(d) for d in re.findall(r"[XYZ]-?\d+\.(\d+)", src[x.before_line - 1])] or [0]
        assert min(got) >= 4 and max(got) >= max(own), x.text
    check_round_trip(prog, res, tmp_path)
    assert _strip_marked(res.text) == prog.text


def test_circle_inch(tmp_path: Path) -> None:
    prog = read_program(REPO_SAMPLES / "circle-inch.gcode")
    assert prog.units == "inch"
    res = insert_points(prog, {i: [0.5] for i in range(len(prog.moves))}, min_decimals=4)
    assert res.n_inserted == 2  # the two G01 plunges; rapids and arcs skipped with a reason
    assert len(res.skipped) == len(prog.moves) - 2
    assert all(s.reason == "not a straight feed (rapid or arc)" for s in res.skipped)
    assert res.inserted[0].text == "G1 X-0.500000 Y0.000000 Z0.050000 F5. (ilcnc refine)"
    check_round_trip(prog, res, tmp_path)
    assert _strip_marked(res.text) == prog.text


def test_incremental_gcode(tmp_path: Path) -> None:
    """G91 moves: the inserted lines are incremental and the move keeps the remaining increment."""
    prog = read_program(OWN / "square-incremental.nc")
    res = insert_points(prog, {i: [0.25, 0.5] for i in range(2, 6)}, min_decimals=3)
    assert [(s.move, s.reason) for s in res.skipped] == [(2, "the line holds G91 (modal change before the inserted line)")]
    new = _lines(res.text)
    assert new[7:10] == ["G1 X0.0000 Y12.5000 Z0.0000 (ilcnc refine)", "G1 X0.0000 Y12.5000 Z0.0000 (ilcnc refine)",
                         "N50 Y25.0000"]
    assert res.rewritten_lines == [8, 9, 10]
    again = check_round_trip(prog, res, tmp_path)
    np.testing.assert_allclose(again.moves.end_mm[-1], prog.moves.end_mm[-1], atol=1e-12)


def test_incremental_uneven_fractions(tmp_path: Path) -> None:
    """Rounded increments add up exactly to the source increment (later positions unchanged)."""
    prog = read_program(OWN / "square-incremental.nc")
    res = insert_points(prog, {3: [1 / 3, 2 / 3], 4: [0.123456789]}, min_decimals=3)
    assert res.n_inserted == 3
    again = check_round_trip(prog, res, tmp_path)
    np.testing.assert_allclose(again.moves.end_mm[-3:], prog.moves.end_mm[-3:], atol=1e-12)


def test_klartext_renumbered(tmp_path: Path) -> None:
    prog = read_program(OWN / "square.h")
    res = insert_points(prog, {i: [0.5] for i in range(len(prog.moves))}, min_decimals=3)
    assert res.renumbered and any("renumbered" in n for n in res.notes)
    assert {s.move for s in res.skipped} == {0, 1, 7}  # the FMAX moves
    new = _lines(res.text)
    numbers = [int(_KL_NUMBER.match(ln).group()) for ln in new if ln.strip()]
    assert numbers == list(range(len(numbers)))
    assert new[7] == "7 L X+0.0000 Y+0.0000 Z+2.5000 F1000 ; ilcnc refine"
    assert new[-2] == f"{len(numbers) - 1} END PGM SQUARE MM"
    check_round_trip(prog, res, tmp_path, numbered=True)


def test_klartext_incremental_crlf_comma(tmp_path: Path) -> None:
    prog = read_program(OWN / "square-incremental.h")
    res = insert_points(prog, {i: [0.4] for i in range(1, 6)}, min_decimals=3)
    assert not res.skipped and not res.renumbered
    assert "\n" not in res.text.replace("\r\n", "") and not res.text.endswith("\n")
    texts = [x.text for x in res.inserted]
    assert texts[1] == "L IX+20,0000 Y+10,0000 Z+0,0000 F3000 ; ilcnc refine"
    assert "L IX+30,0000 F3000" in res.text
    again = check_round_trip(prog, res, tmp_path)
    np.testing.assert_allclose(again.moves.end_mm[-1], prog.moves.end_mm[-1], atol=1e-12)


def test_unsafe_lines_skipped(tmp_path: Path) -> None:
    """Modal or other words on the move's line, unknown starts, inverse time, G53: skipped with a reason."""
    text = (
        "G21 G90\n"
        "G1 X10 Y5 F100\n"  # 1: starts at an unknown X/Y/Z
        "G0 X0 Y0 Z0\n"
        "G1 X10 M8\n"  # 3: M code on the line
        "G1 X20 S1000\n"  # 4: S word
        "G64 P0.01 G1 X30\n"  # 5: modal path control
        "G1 X40 (comment) Y1\n"  # 6: fine
        "/G1 X50\n"  # 7: block delete
        "G93 G1 X60 F10\n"  # 8: modal change and inverse time
        "G1 X70 F20\n"  # 9: inverse time
        "G94 G1 X80 F100\n"  # 10: G94 on the line
        "G1 X90 Y1 Z0 A10\n"  # 11: rotary word
        "M2\n"
    )
    path = tmp_path / "unsafe.ngc"
    path.write_text(text)
    prog = read_program(path)
    prog.require_complete()
    res = insert_points(prog, {i: [0.5] for i in range(len(prog.moves))}, min_decimals=3)
    reasons = {prog.moves.line[s.move]: s.reason for s in res.skipped}
    assert "not set by the program" in reasons[2]
    assert "M8" in reasons[4] and "S1000" in reasons[5] and "G64" in reasons[6]
    assert "block delete" in reasons[8]
    assert "G93" in reasons[9] or "inverse-time" in reasons[9]
    assert "inverse-time" in reasons[10] and "G94" in reasons[11]
    assert "rotary" in reasons[12] or "A10" in reasons[12] or "not a correctable" in reasons[12]
    assert [x.before_line for x in res.inserted] == [7]
    check_round_trip(prog, res, tmp_path)


def test_machine_coordinates_make_start_unknown(tmp_path: Path) -> None:
    text = "G21 G90\nG0 X0 Y0 Z5\nG53 G0 Z0\nG1 X10 F100\nG1 Z-1\nG1 X20\nM2\n"
    path = tmp_path / "g53.ngc"
    path.write_text(text)
    prog = read_program(path)
    res = insert_points(prog, {i: [0.5] for i in range(len(prog.moves)) if prog.moves.command[i] >= 0},
                        min_decimals=3)
    lines = [int(prog.moves.line[s.move]) for s in res.skipped]
    assert lines == [5] and "not set by the program" in res.skipped[0].reason  # Z after G53 moved it
    new = _lines(res.text)
    assert new[3] == "G1 X5.0000 Y0.0000 F100 (ilcnc refine)"  # Z unknown, not moved: not written
    check_round_trip(prog, res, tmp_path)


def test_lowercase_and_joined_words(tmp_path: Path) -> None:
    text = "G21 G90\nG0X0Y0Z1\nG1Z-1F200\nX10.5Y2.25\nx20.5 y3.25\nM2\n"
    path = tmp_path / "joined.nc"
    path.write_text(text)
    prog = read_program(path)
    res = insert_points(prog, {1: [0.5], 2: [0.5], 3: [0.5]}, min_decimals=3)
    assert not res.skipped
    assert [x.text for x in res.inserted] == [
        "G1X0.0000Y0.0000Z0.0000F200 (ilcnc refine)",
        "G1X5.2500Y1.1250Z-1.0000 (ilcnc refine)",
        "g1 x15.5000 y2.7500 z-1.0000 (ilcnc refine)",
    ]
    check_round_trip(prog, res, tmp_path)


def test_incomplete_program_refused(tmp_path: Path) -> None:
    path = tmp_path / "cycle.ngc"
    path.write_text("G21 G90\nG0 X0 Y0 Z5\nG1 X1 F100\nG38.2 Z-10 F10\nG1 X2\nM2\n")
    prog = read_program(path)
    assert prog.unsupported is not None
    with pytest.raises(UnsupportedError):
        insert_points(prog, {1: [0.5]}, min_decimals=3)


@pytest.mark.parametrize("name", ["Gates_combined_R12.nc", "locket_outside.ngc"])
def test_third_party_contours(tmp_path: Path, name: str) -> None:
    src = CONTOUR / name  # in the repository (samples/third_party): never skipped
    local = tmp_path / "src"
    local.mkdir()
    shutil.copy(src, local / name)
    prog = read_program(local / name)
    want = {i: f for n, (i, f) in enumerate(_all_lines(prog, per_move=2, seed=7).items()) if n % 3 == 0}
    res = insert_points(prog, want, min_decimals=3, verify=False)  # check_round_trip re-reads it
    assert res.n_inserted + 2 * len(res.skipped) == 2 * len(want)
    assert all(s.reason == "zero-length move" or s.reason.startswith("too short") for s in res.skipped)
    assert len(res.skipped) <= len(want) // 50, res.skipped[:5]
    out = tmp_path / "out"
    out.mkdir()
    check_round_trip(prog, res, out)
    assert _strip_marked(res.text) == prog.text
    if name.startswith("Gates"):
        assert res.text.count("\r\n") == res.text.count("\n")  # CRLF kept

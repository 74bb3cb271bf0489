"""The vectorised rewrite (ilcnc.program.numwords, issue 24 item 3) writes what the word-by-word code writes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ilcnc.program import read_program, rewrite, scan
from ilcnc.program.model import (
    SPAN_LAZY,
    STYLE_COMMA,
    STYLE_LITERAL,
    STYLE_NO_LEADING_ZERO,
    STYLE_PLUS,
    STYLE_TRAILING_DOT,
)
from ilcnc.program.numwords import parse_plain, spell
from ilcnc.program.rewrite import apply_corrections, format_number, spelling

SAMPLES = Path(__file__).resolve().parents[1] / "samples"
#: Real programs of every kind the rewrite meets: CAM G-code with arcs and modal axes (inch and mm), lower-case
#: and spaced words, Klartext.
PROGRAMS = [
    SAMPLES / "jsdc.gcode",
    SAMPLES / "compass.ngc",
    SAMPLES / "third_party" / "gcode" / "Cereal.ngc",
    SAMPLES / "third_party" / "gcode" / "arcspiral.ngc",
    SAMPLES / "third_party" / "gcode" / "systems.ngc",
    SAMPLES / "third_party" / "contour" / "vcarve.ngc",
    SAMPLES / "third_party" / "heidenhain" / "apt_top-light-cover_11.h",
]


def _words(prog: object) -> tuple[list[str], np.ndarray, np.ndarray]:
    prog.resolve_spans()  # type: ignore[attr-defined]
    mv = prog.moves  # type: ignore[attr-defined]
    have = (mv.word_start >= 0) & ((mv.word_style & STYLE_LITERAL) != 0)
    ws, we = mv.word_start[have], mv.word_end[have]
    text = prog.text  # type: ignore[attr-defined]
    return [text[a:b] for a, b in zip(ws.tolist(), we.tolist(), strict=True)], ws, we


@pytest.mark.parametrize("path", PROGRAMS, ids=lambda p: p.name)
def test_plain_words_read_as_float_and_spelling_read_them(path: Path) -> None:
    prog = read_program(path)
    words, ws, we = _words(prog)
    data = np.frombuffer(prog.text.encode("latin-1"), dtype=np.uint8)
    ok, value, dec, style = parse_plain(data, ws, we)
    assert ok.sum() > 0.5 * len(words)  # most CAM words are plain
    for k in np.flatnonzero(ok).tolist():
        w = words[k]
        assert value[k] == float(w), w  # bit for bit: one correctly rounded division
        assert (int(dec[k]), int(style[k])) == spelling(w), w
    for k in np.flatnonzero(~ok).tolist():  # what is left to the word-by-word code is not plain
        w = words[k]
        assert any(c not in "0123456789.+-" for c in w) or w.count(".") > 1 or len(w) > 15, w
    # the compiled loop (used from 2,000 words on) and the numpy path read the same, bit for bit
    from ilcnc.program import numwords

    if numwords.HAVE_NUMBA:
        bad = np.array([b"+-1", b"1.2.3", b"", b"-", b".", b"+.5", b"12345678901234567", b"1234567890123456", b"7.",
                        b"-0.0", b"1e5", b"+12.500"], dtype=object)
        extra = b"".join(bad)
        at = np.cumsum([0] + [len(b) for b in bad])
        data2 = np.concatenate((data, np.frombuffer(extra, dtype=np.uint8)))
        s2 = np.concatenate((ws, data.size + at[:-1])).astype(np.int64)
        e2 = np.concatenate((we, data.size + at[1:])).astype(np.int64)
        got = numwords._parse_plain_loop(data2, s2, e2)
        ref = numwords._parse_plain_arrays(data2, s2, e2)
        assert np.array_equal(got[0], ref[0])
        assert got[0][-len(bad):].tolist() == [False, False, False, False, False, True, False, False, True, True, False,
                                               True]
        for g, r in zip(got[1:], ref[1:], strict=True):
            assert np.array_equal(g[ref[0]], r[ref[0]])


@pytest.mark.parametrize("klartext", [False, True])
def test_spell_writes_what_format_number_writes(klartext: bool) -> None:
    # the numbers of real programs, moved by learned-size steps, and the halves where rounding is decided
    values = []
    for path in PROGRAMS[:4]:
        _w, _s, _e = _words(read_program(path))
        values.append(np.array([float(w.replace(",", ".")) for w in _w]))
    base = np.concatenate(values)
    rng = np.random.default_rng(24)
    v = np.concatenate((base + rng.normal(0.0, 0.01, base.size), base, -base, [0.0, -0.0, 0.125, -0.125, 2.5, 0.0005,
                                                                               -0.00049, 1e-9, -1e-9, 12345678.9]))
    styles = [STYLE_LITERAL, STYLE_LITERAL | STYLE_PLUS, STYLE_LITERAL | STYLE_COMMA,
              STYLE_LITERAL | STYLE_NO_LEADING_ZERO, STYLE_LITERAL | STYLE_TRAILING_DOT,
              STYLE_LITERAL | STYLE_NO_LEADING_ZERO | STYLE_COMMA | STYLE_PLUS]
    dec = rng.integers(0, 7, v.size)
    sty = np.array(styles)[rng.integers(0, len(styles), v.size)]
    ok, text, length, written = spell(v, dec, sty, klartext=klartext)
    scaled = np.abs(v) * 10.0 ** dec
    near_half = np.abs(scaled - np.floor(scaled) - 0.5) <= 1e-4
    # left to format_number: the halves (where rounding is decided) and numbers too big to round exactly
    assert not np.any(~ok & ~near_half & (scaled < 2.0**36))
    assert ok.mean() > 0.9
    at = np.concatenate(([0], np.cumsum(length)))
    got = text.tobytes().decode("latin-1")
    for k in np.flatnonzero(ok).tolist():
        want = format_number(float(v[k]), int(dec[k]), int(sty[k]), klartext=klartext)
        s = got[at[k]:at[k + 1]]
        assert s == want, (v[k], dec[k], sty[k])
        assert written[k] == float(want.replace(",", ".")), want
    # the compiled loops (from 2,000 numbers on, numba loaded) and the numpy path give the same, byte for byte;
    # also for decimals outside 0..15, infinities and NaN (not spelled)
    from ilcnc.program import numwords

    if not numwords.HAVE_NUMBA:
        return
    v2 = np.concatenate((v, [np.inf, -np.inf, np.nan, 1.0, 2.0**40]))
    dec2 = np.concatenate((dec, [2, 2, 2, -1, 0]))
    sty2 = np.concatenate((sty, [STYLE_LITERAL] * 5))
    ref = numwords._spell_arrays(v2, dec2, sty2, klartext)
    got2 = numwords._spell_loop(v2, dec2, sty2, klartext)
    assert not got2[0][-5:].any()
    assert np.array_equal(got2[0], ref[0]) and np.array_equal(got2[1], ref[1]) and np.array_equal(got2[2], ref[2])
    assert np.array_equal(got2[3][ref[0]], ref[3][ref[0]])


def _corrections(prog: object, seed: int) -> np.ndarray:
    """Learned-size corrections (a few µm, every fifth command none, Z on every other one) on the axes the learner
    corrects."""
    from ilcnc.learning.learner import axes_free_to_move

    n = prog.n_commands  # type: ignore[attr-defined]
    rng = np.random.default_rng(seed)
    corr = rng.normal(0.0, 0.004, (n, 3))
    corr[rng.random(n) < 0.2] = 0.0
    corr[rng.random(n) < 0.5, 2] = 0.0
    corr[~axes_free_to_move(prog)] = 0.0
    return corr


@pytest.mark.parametrize("path", PROGRAMS, ids=lambda p: p.name)
def test_the_vectorised_rewrite_writes_what_the_general_path_writes(path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """The general path (a move at a time, ``format_number``) is the reference: every move through it gives the
    same text and the same edits as the vectorised moves (fast moves and runs of simple ones) with it."""
    prog = read_program(path)
    corr = _corrections(prog, 7)
    text, edits = apply_corrections(prog, corr, min_decimals=3)
    assert len(edits) > 0.5 * np.count_nonzero(corr)
    monkeypatch.setattr(rewrite, "_fast_moves", lambda program, changed, desired: np.zeros(len(program.moves), bool))
    monkeypatch.setattr(rewrite, "_simple_moves", lambda program, fast: np.zeros(len(program.moves), bool))
    ref_text, ref_edits = apply_corrections(read_program(path), corr, min_decimals=3)
    assert text == ref_text
    assert list(edits) == list(ref_edits)


@pytest.mark.skipif(not scan.AVAILABLE, reason="numba is not installed: the spans come from the regular expression")
@pytest.mark.parametrize("path", [PROGRAMS[0], PROGRAMS[1], PROGRAMS[2], PROGRAMS[5]], ids=lambda p: p.name)
def test_the_scanner_finds_the_spans_the_regular_expression_finds(path: Path) -> None:
    every = read_program(path)
    one = read_program(path)
    lazy = np.flatnonzero(one.moves.insert_at == SPAN_LAZY)
    assert lazy.size > 2000  # plain CAM blocks, read without their spans
    every.resolve_spans()  # all at once: the compiled scanner
    for i in lazy.tolist():  # one at a time: the regular expression
        one.resolve_spans([i])
    for name in ("word_start", "word_end", "center_start", "center_end", "insert_at"):
        assert np.array_equal(getattr(every.moves, name), getattr(one.moves, name)), name


#: Programs whose rewrite inserts words and keeps arc centres: lower-case words without spaces under cutter
#: compensation with R arcs in G17 and G18 (comp.ngc), an inch program of R arcs (cap.ngc), spaced mm CAM output
#: with I/J arcs (compass.ngc, Cereal.ngc).
INSERTING = [SAMPLES / "third_party" / "gcode" / "comp.ngc", SAMPLES / "third_party" / "gcode" / "cap.ngc",
             SAMPLES / "compass.ngc", SAMPLES / "third_party" / "gcode" / "Cereal.ngc"]


def _general_only(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(rewrite, "_fast_moves", lambda program, changed, desired: np.zeros(len(program.moves), bool))
    monkeypatch.setattr(rewrite, "_simple_moves", lambda program, fast: np.zeros(len(program.moves), bool))


@pytest.mark.parametrize("path", INSERTING, ids=lambda p: p.name)
def test_runs_of_simple_moves_write_what_the_general_path_writes(path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Moves with a word to insert, arcs after a moved point (their centre kept) and unchanged moves after changed
    ones go through ``_Runs`` a run at a time: the same text and edits as one move at a time, for the learner's
    entry point (G01 commands) and levelling's (every move, rapids and arcs too)."""
    prog = read_program(path)
    prog.resolve_spans()
    from ilcnc.learning.learner import axes_free_to_move

    corr = _corrections(prog, 3)
    corr[:, 2] = np.where(corr[:, 0] != 0.0, 0.003, 0.0)  # Z everywhere: words to insert where a block has none
    corr[~axes_free_to_move(prog)] = 0.0
    mv = prog.moves
    ends = mv.end_mm + np.where(np.arange(len(mv))[:, None] % 3 == 0, [0.0, 0.0, 0.002], 0.0)
    fast_text, fast_edits = apply_corrections(read_program(path), corr, min_decimals=4)
    runs_only = pytest.MonkeyPatch()
    runs_only.setattr(rewrite, "_fast_moves", lambda program, changed, desired: np.zeros(len(program.moves), bool))
    runs_text, runs_edits = apply_corrections(read_program(path), corr, min_decimals=4)
    lev_text, lev_edits = rewrite.apply_move_ends(read_program(path), ends, min_decimals=3)
    runs_only.undo()
    inserted = [e for e in fast_edits if e.start == e.end]
    assert inserted  # the case this test is about
    _general_only(monkeypatch)
    ref_text, ref_edits = apply_corrections(read_program(path), corr, min_decimals=4)
    assert fast_text == ref_text and runs_text == ref_text
    assert list(fast_edits) == list(ref_edits) and list(runs_edits) == list(ref_edits)
    ref_lev_text, ref_lev_edits = rewrite.apply_move_ends(read_program(path), ends, min_decimals=3)
    assert lev_text == ref_lev_text
    assert list(lev_edits) == list(ref_lev_edits)


def test_runs_refuse_what_the_general_path_refuses(monkeypatch: pytest.MonkeyPatch) -> None:
    """An arc whose start a correction moves off its circle: the same refusal (line and message) either way."""
    path = SAMPLES / "third_party" / "gcode" / "cap.ngc"
    prog = read_program(path)
    corr = np.zeros((prog.n_commands, 3))
    corr[:, 0] = 0.05  # 1.3 mm in this inch program: far beyond the control's limit for an arc start
    with pytest.raises(rewrite.CorrectionError) as runs:
        apply_corrections(read_program(path), corr, min_decimals=4)
    _general_only(monkeypatch)
    with pytest.raises(rewrite.CorrectionError) as general:
        apply_corrections(read_program(path), corr, min_decimals=4)
    assert str(runs.value) == str(general.value)
    assert "off its circle" in str(runs.value)

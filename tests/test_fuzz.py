"""Property-based robustness of the readers: mutated lines of real programs.

Each example takes a real sample from samples/third_party (a small one whole, or
a window of a big one: its first 10 lines, 30 lines from anywhere and its last
3 lines), mutates one to three lines (deleted characters, duplicated, swapped
or deleted words, random bytes including NUL and non-ASCII, huge numbers,
stray brackets, comment, parameter and O-word characters, ~20,000-character
lines, deleted, duplicated and swapped lines, ...) and reads the result with
:func:`ilcnc.program.read_program`. The only allowed outcomes are

* the program is read: if it is complete, its end points are finite, every
  coordinate word span holds a number, and a small correction can be applied
  (:func:`~ilcnc.program.rewrite.apply_corrections`) and the rewritten text
  read again, each step either succeeding or raising ilcnc's own error; or
* one of ilcnc's own errors (:class:`~ilcnc.errors.IlcncError`); a
  :class:`~ilcnc.errors.ProgramError` names the program and, unless the whole
  file is empty or binary, a line between 1 and the number of lines.

Any other exception fails, and so does a hang: every example has a hypothesis
``deadline`` (2 s) and a hard CPU-time limit (``SIGPROF``) (5 s). 10,000 examples per
dialect, derandomized (the same cases on every run); the module takes about
two minutes on a 2-core machine. Endless loops (Klartext labels and jumps,
LinuxCNC O-words) must be refused within the same 2 s.

To investigate a failure outside pytest, build the case from the printed
``Case(...)`` with :func:`apply_mutation` or read its ``data`` bytes directly.
"""

from __future__ import annotations

import contextlib
import faulthandler
import re
import signal
import traceback
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import Phase, given, note, settings
from hypothesis import strategies as st

from ilcnc.errors import IlcncError, ProgramError
from ilcnc.program import read_program
from ilcnc.program.model import STYLE_LITERAL, looks_binary
from ilcnc.program.rewrite import apply_corrections

from .conftest import SAMPLES, TEST_ONLY, sample_files, shared_sample_reason

EXAMPLES = 10_000
# Per example; typical examples take a few milliseconds. A mutation can turn a loop of a sample into one
# that runs up to the readers' caps on executed blocks and moves (~1-3 s on 2 busy cores): slow, finite.
DEADLINE_MS = 6000
HARD_LIMIT_S = 15.0  # SIGPROF after this much CPU time: turns a real hang into a failure instead of a stuck CI job
BACKSTOP_S = 120.0  # faulthandler ends the process if even SIGPROF cannot interrupt (a C call that never returns)

SMALL = 60  # files with at most this many lines are used whole
HEAD = 10  # a window of a big file keeps its first HEAD lines ...
WINDOW = 30  # ... WINDOW lines from anywhere ...
TAIL = 3  # ... and its last TAIL lines (M2 / %, END PGM)


# --------------------------------------------------------------------------- samples


@dataclass(frozen=True)
class Sample:
    """A sample file cut into lines (without their b"\\n"; a b"\\r" stays)."""

    path: Path
    lines: tuple[bytes, ...]
    final_newline: bool

    @property
    def big(self) -> bool:
        return len(self.lines) > SMALL

    def __repr__(self) -> str:  # short, for hypothesis' falsifying examples
        return f"Sample({self.path.parent.name}/{self.path.name})"

    def _repr_pretty_(self, p, cycle: bool) -> None:  # hypothesis' pretty printer
        p.text(repr(self))


#: Samples whose unmutated read is too slow for 10,000 examples, made cheaper without changing their
#: structure: lk_Krivka.h is a Q-parameter loop of 75,000 moves (~1.3 s a read); a step of 0,1 instead
#: of 0,001 keeps the loop and makes it 750 moves. flowsnake.ngc recurses through an O-word subroutine
#: 3 * 4**5 times (~2.5 s a read once O-words are interpreted); level 2 keeps the recursion, 48 calls.
SAMPLE_EDITS = {
    "lk_Krivka.h": (b"Q4 = Q4 + 0,001", b"Q4 = Q4 + 0,1"),
    "flowsnake.ngc": (b"#<level> = 5", b"#<level> = 2"),
}


def _load(paths: list[Path]) -> list[Sample]:
    out = []
    for p in paths:
        data = p.read_bytes()
        if p.name in SAMPLE_EDITS:
            old, new = SAMPLE_EDITS[p.name]
            assert old in data, f"{p.name} changed: {old!r} not found"
            data = data.replace(old, new)
        final = data.endswith(b"\n")
        lines = data.split(b"\n")
        if final:
            lines.pop()
        out.append(Sample(p, tuple(lines), final))
    return out


GCODE_SAMPLES = _load(sample_files("gcode", "contour", "interp"))
HEIDENHAIN_SAMPLES = _load(sample_files("heidenhain"))


# --------------------------------------------------------------------------- mutations

_NUMBER = re.compile(rb"[+-]?(?:\d+(?:[.,]\d*)?|[.,]\d+)")
_WORD = re.compile(rb"\S+")

HUGE_NUMBERS = (
    b"1e308", b"-1e308", b"1E999", b"9999999999999999999", b"-9999999999999999999", b"99999999999.9999",
    b"1" + b"0" * 320, b"9" * 400, b"0." + b"0" * 400 + b"1", b"1.7976931348623157e308", b"+1e-400",
    b"4294967296", b"2147483648", b"-2147483649", b"18446744073709551616", b"nan", b"inf", b"-inf",
    b"0x10", b"1_000", b"--5", b"+-5", b"1.2.3", b"1,2,3", b"..5", b"", b"-", b"+", b".", b",",
    b"100000000000000", b"65536", b"32768", b"-32769", b"128", b"255", b"9" * 25 + b"." + b"9" * 25,
)

SPECIAL_BYTES = (
    b"\x00", b"\xff", b"\xfe\xff", b"\xc3\xa9", b"\xe2\x80\x8b", b"\xef\xbb\xbf", b"\x1a", b"\x0c", b"\r",
    b"\t", b"\x7f", b"\xa0", b"\x1b[0m", b"\n", b"\r\n", b"\x0b", b"\x85", b"\xe2\x80\xa8", b"\x01",
)

COMMON_TOKENS = (
    b"[", b"]", b"(", b")", b"#", b"<", b">", b"O", b"o", b";", b"%", b"[[[[", b"]]]]", b"((", b"))",
    b"#<", b"#<x>", b"#1=", b"#1 = [1/0]", b"=", b"*", b"**", b"/", b"\\", b'"', b"'", b"@", b"^", b"$",
    b"!", b"?", b"&", b"|", b"~", b"`", b"{", b"}", b":", b",", b".", b"+", b"-", b"E", b"e", b"N",
    b"G", b"M", b"X", b"Y", b"Z", b"F", b"S", b"T", b"P", b"Q", b"R", b"I", b"J", b"K", b"L", b"A",
    b" ", b"  \t ", b"[" * 300, b"(" * 50, b"#" * 50, b"<" * 50, b"-" * 50,
)

GCODE_TOKENS = (
    *COMMON_TOKENS,
    b"G0", b"G1", b"G2", b"G3", b"G4", b"G5", b"G10 L2 P1", b"G10 L20 P0 X0", b"G17", b"G18", b"G19",
    b"G20", b"G21", b"G28", b"G30", b"G33", b"G38.2", b"G43", b"G52 X1", b"G53", b"G54", b"G59.3",
    b"G64 P0.01", b"G81", b"G90", b"G90.1", b"G91", b"G91.1", b"G92 X0", b"G92.1", b"G93", b"G94",
    b"G95", b"G1.5", b"G999", b"M2", b"M30", b"M98 P1", b"M99", b"M3 S1000", b"F0", b"F-1", b"P0",
    b"P-2", b"R0", b"R-1", b"I0 J0", b"K1e9", b"X#1", b"X#<_x>", b"X[1+]", b"X[SIN[90]]",
    b"X[ATAN[1]/[0]]", b"X[SQRT[-1]]", b"X[LN[0]]", b"X[2**9999]", b"X[1/0]", b"X[EXISTS[#<a>]]",
    b"#5161=1e300", b"#<a>=[1e300*1e300]", b"#[#[#[1]]]=2", b"#0=1", b"#5602=1",
    b"O100 sub", b"O100 endsub", b"O100 call", b"O<x> if [1]", b"O1 while [1]", b"O1 endwhile",
    b"O0001", b"O", b"o<", b"%%", b"/", b"$H", b"$$", b"N10", b"N", b"@1^45", b"(msg,", b"(debug,#1)",
    b"G2 X0 Y0 R0", b"G2 I0 J0 P0", b"G3 X1e9 R1", b"G2 X1 Y1 I1e-12", b"U1", b"W2", b"A90",
)

HEIDENHAIN_TOKENS = (
    *COMMON_TOKENS,
    b"L", b"C", b"CC", b"CR", b"CT", b"CP", b"LP", b"PA", b"PR", b"IPA", b"IX", b"IY", b"IZ", b"RL",
    b"RR", b"R0", b"R+", b"FMAX", b"FAUTO", b"F", b"M91", b"M92", b"DR+", b"DR-", b"RND R", b"CHF",
    b"APPR LCT", b"DEP LT", b"LBL 1", b"LBL 0", b"LBL \"A\"", b"CALL LBL 1", b"CALL LBL 1 REP 3",
    b"CALL PGM", b"Q1", b"Q1 =", b"Q1 = 5", b"FN 0: Q1 =", b"FN 4: Q1 = +1 DIV +0", b"Q999999",
    b"CYCL DEF", b"CYCL DEF 7.0", b"CYCL DEF 7.1 X+1", b"CYCL CALL", b"TOOL CALL", b"TOOL CALL 1 Z S1",
    b"TOOL DEF", b"BLK FORM 0.1 Z", b"BEGIN PGM", b"END PGM", b"BEGIN PGM X MM", b"END PGM X MM",
    b"BEGIN PGM X INCH", b"STOP", b"PLANE", b"FK", b"FL", b"FPOL", b"FC", b"FCT", b"*", b"~", b"X+",
    b"Y-", b"Z+,", b"+,5", b"1,000,000", b"X+1,2,3", b"L X+1e308", b"CC X+0 Y+0", b"C X+0 DR+",
    b"CP IPA+360 DR+", b"LP PR+5 PA+45",
)


#: an index or offset, reduced modulo the number of lines / the line length / the word count when applied
INDEX = st.integers(0, 1 << 16)
LONG_UNITS = (b"", b" ", b"[", b"(", b"X1", b"G1 ", b"9", b"#", b"L X+1 ")


def mutations(tokens: tuple[bytes, ...]) -> st.SearchStrategy[tuple]:
    """One mutation as plain data: (kind, line index, offset, parameter...).

    Built once per dialect from fixed strategies: constructing strategies inside a draw costs more than
    reading the program.
    """

    def kind(name: str, *params: st.SearchStrategy) -> st.SearchStrategy[tuple]:
        return st.tuples(st.just(name), INDEX, INDEX, *params)

    return st.one_of(
        kind("delete", st.integers(1, 8)),  # delete 1..8 characters
        kind("dup_word", INDEX),
        kind("swap_words", INDEX),
        kind("del_word", INDEX),
        kind("bytes", st.binary(min_size=1, max_size=8) | st.sampled_from(SPECIAL_BYTES)),  # insert random bytes
        kind("replace_char", st.binary(min_size=1, max_size=1)),
        kind("huge", st.sampled_from(HUGE_NUMBERS)),  # replace a number
        kind("token", st.sampled_from(tokens)),  # insert a token of the language (or a stray character)
        kind("long", st.sampled_from(LONG_UNITS)),  # make the line ~20,000 characters long
        kind("repeat", st.integers(2, 400)),  # repeat a word up to 400 times
        kind("truncate"),
        kind("del_line"),
        kind("dup_line"),
        kind("swap_lines", INDEX),
        kind("case"),
        kind("strip_ws"),
    )



def _words(line: bytes) -> list[re.Match[bytes]]:
    return list(_WORD.finditer(line))


def apply_mutation(lines: list[bytes], mutation: tuple) -> int | None:
    """Apply one mutation in place; returns the 1-based line it touched (None if nothing changed)."""
    kind, i, pos = mutation[:3]
    if not lines:
        lines.append(b"")
    i %= len(lines)
    s = lines[i]
    p = pos % (len(s) + 1)
    if kind == "delete":
        s = s[:p] + s[p + mutation[3]:]
    elif kind in ("dup_word", "swap_words", "del_word"):
        ws = _words(s)
        if not ws:
            return None
        a = ws[pos % len(ws)]
        b = ws[mutation[3] % len(ws)]
        if kind == "dup_word":
            s = s[:a.end()] + b" " + a.group(0) + s[a.end():]
        elif kind == "del_word":
            s = s[:a.start()] + s[a.end():]
        else:
            if a.start() > b.start():
                a, b = b, a
            s = s[:a.start()] + b.group(0) + s[a.end():b.start()] + a.group(0) + s[b.end():]
    elif kind == "bytes":
        s = s[:p] + mutation[3] + s[p:]
    elif kind == "replace_char":
        s = s[:p] + mutation[3] + s[p + 1:]
    elif kind == "huge":
        ns = list(_NUMBER.finditer(s))
        if ns:
            m = ns[pos % len(ns)]
            sign = m.group(0)[:1] if m.group(0)[:1] in b"+-" and mutation[3][:1] not in b"+-" else b""
            s = s[:m.start()] + sign + mutation[3] + s[m.end():]
        else:
            s = s[:p] + b" X" + mutation[3] + s[p:]
    elif kind == "token":
        s = s[:p] + mutation[3] + s[p:]
    elif kind == "long":
        unit = mutation[3] or (s if s.strip() else b"G1 X1 ")
        s = s + unit * (20_000 // max(1, len(unit)))
    elif kind == "repeat":
        ws = _words(s)
        if not ws:
            return None
        w = ws[pos % len(ws)]
        s = s[:w.end()] + (b" " + w.group(0)) * mutation[3] + s[w.end():]
    elif kind == "truncate":
        s = s[:p]
    elif kind == "del_line":
        del lines[i]
        return min(i + 1, max(1, len(lines)))
    elif kind == "dup_line":
        lines.insert(i, s)
        return i + 1
    elif kind == "swap_lines":
        j = mutation[3] % len(lines)
        lines[i], lines[j] = lines[j], lines[i]
        return min(i, j) + 1
    elif kind == "case":
        s = s.lower() if s != s.lower() else s.upper()
    elif kind == "strip_ws":
        s = re.sub(rb"[ \t]+", b"", s)
    lines[i] = s
    return i + 1


@dataclass(frozen=True)
class Case:
    """One fuzz input: which sample, the mutated bytes and what was done."""

    sample: Sample
    data: bytes
    mutations: tuple[tuple, ...]
    touched: tuple[int | None, ...]
    #: the correction tried on a complete program: (k modulo N, dx, dy, dz in micrometres)
    correction: tuple[int, int, int, int] = (0, 10, 0, 0)

    def __repr__(self) -> str:
        return f"Case({self.sample!r}, mutations={self.mutations!r}, touched={self.touched}, data={self.data!r})"

    def _repr_pretty_(self, p, cycle: bool) -> None:  # hypothesis' pretty printer
        p.text(repr(self))


def _make_case(sample: Sample, start: int, muts: list[tuple], corr: tuple[int, int, int, int]) -> Case:
    lines = list(sample.lines)
    if sample.big:
        start = HEAD + start % (len(lines) - HEAD - TAIL - WINDOW + 1)
        lines = lines[:HEAD] + lines[start:start + WINDOW] + lines[-TAIL:]
    touched = tuple(apply_mutation(lines, m) for m in muts)
    data = b"\n".join(lines) + (b"\n" if sample.final_newline else b"")
    return Case(sample, data, tuple(muts), touched, corr)


def cases(samples: list[Sample], tokens: tuple[bytes, ...]) -> st.SearchStrategy[Case]:
    """A sample (or a window of a big one) with one to three mutations, and a correction to try."""
    um = st.integers(-500, 500)
    return st.builds(
        _make_case,
        st.sampled_from(samples),
        st.integers(0, 1 << 20),  # start of the window in a big file
        st.lists(mutations(tokens), min_size=1, max_size=3),
        # drawn whatever the outcome of the read, so that every example draws the same way
        st.tuples(INDEX, um, um, um),
    )


# --------------------------------------------------------------------------- the property


class Hang(Exception):
    """Raised by SIGPROF when one example works for longer than HARD_LIMIT_S of CPU time."""


@contextlib.contextmanager
def hard_time_limit(seconds: float) -> Iterator[None]:
    """Interrupt the block after ``seconds`` of the process's CPU time (main thread, POSIX); a no-op elsewhere.

    CPU time (``ITIMER_PROF``), not wall time: the budget is the work a hang would go on doing, whatever else
    the machine runs (at a load of 12 on 2 cores an endless-loop example took 6 s of wall time for 0.5 s of
    work). A hang that does no work is ended by faulthandler's wall-clock backstop."""
    if not hasattr(signal, "setitimer"):
        yield
        return

    def _raise(signum: int, frame: object) -> None:
        raise Hang(f"example still running after {seconds} s")

    old = signal.signal(signal.SIGPROF, _raise)
    # fires again every 0.25 s should a Hang be swallowed (raised inside a gc callback, where exceptions
    # are ignored: hypothesis measures gc time with one); a C call that never returns to the
    # interpreter is ended (with every thread's traceback on stderr) by faulthandler after BACKSTOP_S
    signal.setitimer(signal.ITIMER_PROF, seconds, 0.25)
    faulthandler.dump_traceback_later(max(BACKSTOP_S, 10 * seconds), exit=True)
    try:
        yield
    except Hang as exc:
        # re-raised without the interrupted frames (an interrupted C call can leave a frame without a
        # line number, which breaks pytest's traceback printing); the message says where it was
        where = "; ".join(f"{Path(f.filename).name}:{f.lineno} {f.name}" for f in traceback.extract_tb(exc.__traceback__)[-3:])
        raise Hang(f"still running after {seconds} s (hang?) at {where}") from None
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.signal(signal.SIGPROF, old)
        faulthandler.cancel_dump_traceback_later()


def _n_lines(data: bytes) -> int:
    return data.count(b"\n") + (1 if data and not data.endswith(b"\n") else 0)


def _check_error(exc: IlcncError, path: Path, data: bytes) -> None:
    """An expected error: ilcnc's own, with a sane line number."""
    if not isinstance(exc, ProgramError):
        return
    assert exc.file == str(path), f"error names {exc.file!r}, not the program {path}"
    assert "\n" not in str(exc), f"error message is not one line: {exc!r}"
    if exc.line is None:
        # only whole-file problems have no line: empty or binary data
        assert not data.strip() or looks_binary(data), f"error without a line number: {exc}"
        return
    n = _n_lines(data)
    assert 1 <= exc.line <= max(n, 1), f"error line {exc.line} outside 1..{n}: {exc}"


def _check_spans(prog) -> None:
    """Every coordinate and centre word span lies in the text; a literal one holds a number."""
    if hasattr(prog, "resolve_spans"):
        prog.resolve_spans()  # spans a reader leaves for later are found now
    mv, text = prog.moves, prog.text
    for starts, ends, styles, what, letters in (
        (mv.word_start, mv.word_end, mv.word_style, "coordinate", "XYZ"),
        (mv.center_start, mv.center_end, mv.center_style, "centre", "IJK"),
    ):
        for i, a in zip(*np.nonzero(starts >= 0), strict=True):
            ws, we = int(starts[i, a]), int(ends[i, a])
            line = int(mv.line[i])
            assert 0 <= ws <= we <= len(text), f"{what} span {ws}..{we} of move {i} (line {line}) outside the text"
            if styles[i, a] & STYLE_LITERAL:
                number = text[ws:we].replace(",", ".").replace(" ", "").replace("\t", "")
                try:
                    float(number)
                except ValueError:
                    raise AssertionError(
                        f"{what} word {letters[a]} of move {i} (line {line}): span {ws}..{we} holds {text[ws:we]!r}, "
                        "not a number"
                    ) from None


def _check_program(prog, path: Path, case: Case) -> None:
    """A program that was read: complete ones get a small correction and are read again."""
    prog.require_complete()
    mv = prog.moves
    finite = np.isfinite(mv.end_mm).all(axis=1)
    assert finite.all(), (
        f"non-finite end point read without error at line {int(mv.line[np.flatnonzero(~finite)[0]])}"
    )
    _check_spans(prog)
    n = prog.n_commands
    if n == 0:
        return
    corr = np.zeros((n, 3))
    k, dx, dy, dz = case.correction
    corr[k % n] = (dx / 1000.0, dy / 1000.0, dz / 1000.0)
    text, _edits = apply_corrections(prog, corr, min_decimals=3)
    assert isinstance(text, str)
    again = read_program(path, data=text.encode("latin-1"))
    again.require_complete()


def check_case(case: Case) -> None:
    path = case.sample.path
    data = case.data
    with hard_time_limit(HARD_LIMIT_S):
        try:
            prog = read_program(path, data=data)
            _check_program(prog, path, case)
        except IlcncError as exc:
            _check_error(exc, path, data)


FUZZ_SETTINGS = settings(
    max_examples=EXAMPLES,
    derandomize=True,
    database=None,
    deadline=DEADLINE_MS,
    print_blob=True,
    # no "explain" phase: it traces every line (sys.settrace), which makes slow-but-finite examples look like hangs
    phases=(Phase.explicit, Phase.reuse, Phase.generate, Phase.target, Phase.shrink),
)




@pytest.mark.slow
@FUZZ_SETTINGS
@given(case=cases(GCODE_SAMPLES, GCODE_TOKENS))
def test_gcode_reader_survives_mutated_lines(case: Case) -> None:
    note(f"{len(case.data)} bytes, {_n_lines(case.data)} lines, mutations at lines {case.touched}")
    check_case(case)


@pytest.mark.slow
@FUZZ_SETTINGS
@given(case=cases(HEIDENHAIN_SAMPLES, HEIDENHAIN_TOKENS))
def test_heidenhain_reader_survives_mutated_lines(case: Case) -> None:
    note(f"{len(case.data)} bytes, {_n_lines(case.data)} lines, mutations at lines {case.touched}")
    check_case(case)


#: A never-ending program must be refused by the readers' caps within this (not after minutes).
LOOP_BUDGET_S = 6.0

ENDLESS_LOOPS = {
    "Klartext FN 9 jump back": (
        "loop.h",
        b"0 BEGIN PGM LOOP MM\n1 LBL 1\n2 L X+1 R0 F100\n3 FN 9: IF +0 EQU +0 GOTO LBL 1\n4 END PGM LOOP MM\n",
    ),
    "Klartext Q loop without moves": (
        "loop.h",
        b"0 BEGIN PGM LOOP MM\n1 Q1 = 0\n2 LBL 1\n3 Q1 = Q1 + 1\n4 FN 12: IF +Q1 LT +100000000 GOTO LBL 1\n"
        b"5 END PGM LOOP MM\n",
    ),
    "Klartext label calling itself": (
        "loop.h",
        b"0 BEGIN PGM LOOP MM\n1 LBL 1\n2 L X+1 R0 F100\n3 CALL LBL 1\n4 LBL 0\n5 END PGM LOOP MM\n",
    ),
    "Klartext jump back with an incremental move": (
        "loop.h",
        b"0 BEGIN PGM LOOP MM\n1 LBL 1\n2 L IX+1 R0 F100\n3 FN 9: IF +0 EQU +0 GOTO LBL 1\n4 END PGM LOOP MM\n",
    ),
    "Klartext nested repeats, 4e9 moves": (
        "loop.h",
        b"0 BEGIN PGM LOOP MM\n1 LBL 1\n2 L IX+1 R0 F100\n3 LBL 0\n4 LBL 2\n5 CALL LBL 1 REP 65534\n6 LBL 0\n"
        b"7 CALL LBL 2 REP 65534\n8 END PGM LOOP MM\n",
    ),
    "G-code while [1]": ("loop.ngc", b"G21 G90 F100\no100 while [1]\nG1 X1\nG1 X0\no100 endwhile\nM2\n"),
    "G-code do while": ("loop.ngc", b"G21 G90 F100\no100 do\nG1 X1\no100 while [1]\nM2\n"),
    "G-code while [1] with an incremental move": (
        "loop.ngc", b"G21 F100\nG91\no100 while [1]\nG1 X1\no100 endwhile\nM2\n",
    ),
    "G-code while counting to 1e9": (
        "loop.ngc", b"G21 F100\n#1=0\no100 while [#1 LT 1000000000]\n#1=[#1+1]\no100 endwhile\nM2\n",
    ),
    "G-code repeat 1e9": ("loop.ngc", b"G21 F100\nG91\no100 repeat [1000000000]\nG1 X1\no100 endrepeat\nM2\n"),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(ENDLESS_LOOPS), ids=list(ENDLESS_LOOPS))
def test_an_endless_loop_is_refused_in_time(name: str) -> None:
    """A program that never ends (or would run for hours) is read or refused within the budget, not after minutes."""
    file, data = ENDLESS_LOOPS[name]
    with hard_time_limit(LOOP_BUDGET_S):
        try:
            prog = read_program(Path(file), data=data)
            prog.require_complete()
        except IlcncError as exc:
            _check_error(exc, Path(file), data)


def test_the_samples_are_there() -> None:
    assert len(GCODE_SAMPLES) >= 40 and len(HEIDENHAIN_SAMPLES) >= 7
    assert len(GCODE_SAMPLES) == sum(len(list((SAMPLES / d).iterdir())) for d in ("gcode", "contour", "interp"))
    in_repository = [s for s in HEIDENHAIN_SAMPLES if s.path.is_relative_to(SAMPLES)]
    assert len(in_repository) == 7
    assert any(s.big for s in GCODE_SAMPLES) and any(s.big for s in in_repository)


def test_the_test_only_samples_are_there() -> None:
    """The Heidenhain fuzzing also mutates the 7 TEST-ONLY samples of ../shared (all 14, as before the copies)."""
    test_only = sorted(s.path.name for s in HEIDENHAIN_SAMPLES if not s.path.is_relative_to(SAMPLES))
    if test_only != sorted(TEST_ONLY["heidenhain"]):
        pytest.skip(shared_sample_reason("heidenhain"))
    assert len(HEIDENHAIN_SAMPLES) == 14


def test_mutations_do_what_they_say() -> None:
    lines = [b"G1 X1.5 Y-2 F100", b"G0 Z5"]
    assert apply_mutation(lines, ("huge", 0, 2, b"9999999999999999999")) == 1
    assert lines[0] == b"G1 X1.5 Y-9999999999999999999 F100"
    assert apply_mutation(lines, ("swap_words", 1, 0, 1)) == 2 and lines[1] == b"Z5 G0"
    assert apply_mutation(lines, ("delete", 0, 0, 3)) == 1 and lines[0].startswith(b"X1.5")
    assert apply_mutation(lines, ("long", 1, 0, b"[")) == 2 and len(lines[1]) > 10_000
    assert apply_mutation(lines, ("del_line", 1, 0)) == 1 and len(lines) == 1

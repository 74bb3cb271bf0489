"""Plain CAM blocks, the G-code reader's fast path: which lines are plain, their numbers, their word spans.

A plain block is ``[N..] [G0|G1|G2|G3] [X..] [Y..] [Z..] [I..] [J..] [K..] [R..] [F..]`` in this order (X, Y and
Z in any order) with literal numbers (:data:`FAST_LINE`): most lines of CAM output. :func:`classify_lines` reads
all of them in one pass (a regular expression, or the compiled scanner of :mod:`ilcnc.program.scan` for long
programs) and :func:`resolve_fast_spans` finds their words' places in the text when a rewrite needs them.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np

from ilcnc._jit import python_kernels
from ilcnc.errors import ProgramError
from ilcnc.program.model import SPAN_LAZY, Program

__all__ = ["FAST_LINE", "SCANNER_MIN_LINES", "classify_lines", "resolve_fast_spans"]

#: The common CAM block: [N..] [G0-3] [X..] [Y..] [Z..] [I..] [J..] [K..] [R..] [F..] in this order, literal numbers;
#: X, Y and Z in any order, each once (a rewrite inserts a missing axis word after the others: ``X1 Z2 Y3``).
#: ``(?(2)(?!))`` refuses a second X word (group 2 holds the first), likewise Y and Z: such a block is an error
#: the general lexer reports.
_NUM = r"([-+]?(?:\d+(?:\.\d*)?|\.\d+))"
FAST_LINE = re.compile(
    r"[ \t]*(?:[Nn]\d+[ \t]*)?(?:[Gg]0*([0-3])(?![\d.])[ \t]*)?"
    rf"(?:(?(2)(?!))[Xx][ \t]*{_NUM}[ \t]*|(?(3)(?!))[Yy][ \t]*{_NUM}[ \t]*|(?(4)(?!))[Zz][ \t]*{_NUM}[ \t]*){{0,3}}"
    rf"(?:[Ii][ \t]*{_NUM}[ \t]*)?(?:[Jj][ \t]*{_NUM}[ \t]*)?(?:[Kk][ \t]*{_NUM}[ \t]*)?"
    rf"(?:[Rr][ \t]*{_NUM}[ \t]*)?"
    r"(?:[Ff][ \t]*(\d+(?:\.\d*)?|\.\d+)[ \t]*)?\r?"
)
_ALL_LINES = re.compile(rf"^(?:{FAST_LINE.pattern}$|(.+))", re.MULTILINE)


#: Programs with more lines than this are classified by the compiled scanner (its import and first
#: compilation cost more than the regular expression saves on small files).
SCANNER_MIN_LINES = 20_000


def classify_lines(text: str, data: bytes, n: int, line_start: np.ndarray, path: Path,
                   *, force: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Plain-block numbers (n, 9: G X Y Z I J K R F) and the mask of other ("slow") lines."""
    use_scanner = force == "scanner" or (force is None and n >= SCANNER_MIN_LINES)
    if use_scanner:
        from ilcnc.program import scan

        if scan.AVAILABLE and not python_kernels():
            return scan.scan_plain_blocks(data, line_start)
    # one C-level regular-expression pass: plain CAM blocks (numbers captured) or other
    rows = _ALL_LINES.findall(text)
    if len(rows) != n:  # cannot happen for text split on "\n"; guard the invariant all the same
        raise ProgramError(path, None, "internal error: line split mismatch")
    slow = np.array([r[9] for r in rows], dtype=bool)
    return _column_floats(rows, n), slow


def _column_floats(rows: list[tuple[str, ...]], n: int) -> np.ndarray:
    """The G X Y Z I J K R F captures of every line as an (n, 9) float array (NaN where absent).

    Each column is joined into one string and parsed by numpy's C parser in
    one call (measured ~3x faster than flattening all cells, and ~10x faster
    than ``float()`` per cell); empty cells become ``nan`` by string replacement.
    """
    out = np.empty((n, 9))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        for c in range(9):
            col = [r[c] for r in rows]  # one comprehension per column: ~8 ms, a third of zip(*rows)
            text = "|" + "|".join(col) + "|"
            text = text.replace("||", "|nan|").replace("||", "|nan|")
            vals = np.fromstring(text[1:-1], dtype=np.float64, sep="|")
            if vals.shape[0] != n:  # cannot happen for regex-captured numbers; keep a safe path
                vals = np.array([x or "nan" for x in col], dtype=np.float64)
            out[:, c] = vals
    return out


def resolve_fast_spans(program: Program, indices: np.ndarray) -> None:
    """Find the word spans of plain blocks that the fast path left for later (``SPAN_LAZY``).

    With numba, the compiled scanner finds them for all the blocks at once (a regular expression and numpy
    element writes per block cost 25 µs: 4 s for the 150,000 blocks a learned CAM program rewrites); a block
    it does not read as plain (only possible when the regular expression classified the file) goes through
    the regular expression."""
    mv = program.moves
    idx = np.asarray(indices, dtype=np.int64)
    idx = idx[mv.insert_at[idx] == SPAN_LAZY]
    if idx.size == 0:
        return
    text = program.text
    from ilcnc.program import scan

    # in a small job's Python block (ilcnc._jit.kernels_for) the regular expressions below: the scanner's
    # integer arithmetic is numba's int64, not what its Python version computes on uint8 bytes
    if scan.AVAILABLE and idx.size > 1 and not python_kernels():
        data = np.frombuffer(text.encode("latin-1"), dtype=np.uint8)
        offsets = program.line_offsets()
        line0 = mv.line[idx].astype(np.int64) - 1
        starts = offsets[line0]
        ends = np.where(line0 + 1 < offsets.size, offsets[np.minimum(line0 + 1, offsets.size - 1)] - 1, data.size)
        spans, slow = scan.plain_block_spans(data, starts, ends)
        ok = ~slow
        done, spans = idx[ok], spans[ok]
        for a in range(3):
            for start_col, end_col, group in ((mv.word_start, mv.word_end, 1 + a), (mv.center_start, mv.center_end,
                                                                                     4 + a)):
                lazy = start_col[done, a] == SPAN_LAZY
                start_col[done[lazy], a] = spans[lazy, group, 0]
                end_col[done[lazy], a] = spans[lazy, group, 1]
        last = spans[:, :, 1].max(axis=1)
        mv.insert_at[done] = np.where(last >= 0, last, starts[ok] - 1)  # as start + (-1) below: no group
        idx = idx[slow]
    for i in idx.tolist():
        line = int(mv.line[i])
        start = program.line_start(line)
        end = text.find("\n", start)
        s = text[start:] if end < 0 else text[start:end]
        m = FAST_LINE.fullmatch(s)
        if m is None:  # pragma: no cover - the block matched when it was read
            raise ProgramError(program.path, line, "internal error: block changed since it was read")
        regs = m.regs
        last = max(e for (_b, e) in regs[1:10])
        for a in range(3):
            if mv.word_start[i, a] == SPAN_LAZY:
                b, e = regs[2 + a]
                mv.word_start[i, a] = start + b
                mv.word_end[i, a] = start + e
            if mv.center_start[i, a] == SPAN_LAZY:
                b, e = regs[5 + a]
                mv.center_start[i, a] = start + b
                mv.center_end[i, a] = start + e
        mv.insert_at[i] = start + last

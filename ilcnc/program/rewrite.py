"""Rewrite a program with corrected G01 end points, touching nothing else.

The source text is kept as it is; only the numbers of coordinate words are
replaced (or a missing word inserted) where the machine would otherwise go
somewhere else than wanted:

* a corrected command gets its new end point;
* every other move keeps its absolute end point. In incremental mode
  (G91, ``IX``) the next word absorbs the change; in absolute mode a block
  that relied on a modal (unwritten) axis gets that axis written out;
* an arc whose start moved keeps its centre (incremental I/J/K, ``CC IX``
  are rewritten) and its end point.

Corrections are in the consistent (machine) frame. In a work system turned by
``G10 L2 R`` the words are numbers of the turned frame: a move's wanted end is
turned back into it before its words are written, so an X-only correction there
may change the Y word too, or add one (a missing word is inserted as above).

Numbers are written with the decimals the source used, at least
``min_decimals``, in the spelling of the source word (sign, comma, leading
zero, trailing dot).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import overload

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import CorrectionError
from ilcnc.program.model import (
    FLAG_DERIVED,
    FLAG_HOME,
    FLAG_MACHINE,
    FLAG_POLAR,
    FLAG_POSITION_READ,
    FLAG_REPEATED,
    MOVE_ARC_CW,
    PLANE_AXES,
    SPAN_LAZY,
    STYLE_COMMA,
    STYLE_LITERAL,
    STYLE_NO_LEADING_ZERO,
    STYLE_PLUS,
    STYLE_TRAILING_DOT,
    Program,
    arc_off_circle,
    rotate_xy,
)
from ilcnc.program.numwords import parse_plain, spell, splice
from ilcnc.units import AXIS_LETTERS, CENTER_LETTERS

__all__ = ["Edit", "Edits", "apply_corrections", "apply_move_ends", "format_number", "spelling"]

_LETTERS = AXIS_LETTERS
_CENTER_LETTERS = CENTER_LETTERS


@dataclass(frozen=True, slots=True)
class Edit:
    """One replacement in the source text: ``text[start:end]`` becomes ``new``."""

    start: int
    end: int
    new: str
    line: int


def format_number(value: float, decimals: int, style: int, *, klartext: bool = False) -> str:
    """Spell ``value`` with ``decimals`` places in the style of a source word.

    Parameters
    ----------
    value : float
        The number (program units).
    decimals : int
        Decimal places.
    style : int
        ``STYLE_*`` bits of the word it replaces.
    klartext : bool
        Heidenhain: always an explicit sign.
    """
    d = max(0, int(decimals))
    s = f"{abs(value):.{d}f}"
    negative = value < 0 and float(s) != 0.0
    if d == 0 and style & STYLE_TRAILING_DOT:
        s += "."
    if style & STYLE_NO_LEADING_ZERO and s.startswith("0.") and d > 0:
        s = s[1:]
    if style & STYLE_COMMA:
        s = s.replace(".", ",")
    if negative:
        return "-" + s
    if klartext or style & STYLE_PLUS:
        return "+" + s
    return s


def spelling(number: str) -> tuple[int, int]:
    """Decimals and ``STYLE_*`` bits of a literal number as written (``+1,50`` -> (2, PLUS|COMMA|LITERAL))."""
    t = number.replace(" ", "").replace("\t", "")
    style = STYLE_LITERAL
    if t.startswith("+"):
        style |= STYLE_PLUS
    body = t.lstrip("+-")
    sep = "," if "," in body else "."
    if sep == ",":
        style |= STYLE_COMMA
    if body.startswith(sep):
        style |= STYLE_NO_LEADING_ZERO
    if sep in body:
        _ip, fp = body.split(sep, 1)
        if not fp:
            style |= STYLE_TRAILING_DOT
        return len(fp), style
    return 0, style


def _parse(s: str) -> float:
    return float(s.replace(",", ".").replace(" ", "").replace("\t", ""))


def _line_style(text: str, start: int, end: int) -> tuple[bool, str]:
    """(lowercase, separator) used by the words of the block text[start:end]."""
    segment = text[start:end]
    n_letters = sum(map(str.isalpha, segment))  # map of a C method: a third of a generator's time
    lower = n_letters > 0 and sum(map(str.islower, segment)) > n_letters / 2  # (no latin-1 lower case is no letter)
    sep = " " if (" " in segment.strip() or "\t" in segment.strip()) else ""
    return lower, sep


def apply_corrections(
    program: Program,
    corrections_mm: NDArray[np.float64],
    *,
    min_decimals: int = 3,
    extra_edits: list[Edit] | None = None,
) -> tuple[str, Edits]:
    """Return the program text with ``corrections_mm`` added to the command end points.

    Parameters
    ----------
    program : Program
        The program as read.
    corrections_mm : ndarray, shape (N, 3)
        Correction of each command's end point, mm (0 where none).
    min_decimals : int
        Least number of decimals of a rewritten number (the machine's
        resolution in program units).
    extra_edits : list of Edit, optional
        Other edits of the same text to make with them (e.g. the feed words of
        :func:`ilcnc.program.feedwords.feed_edits`); they must not overlap a
        rewritten number.

    Returns
    -------
    text : str
        New program text (latin-1, like :attr:`Program.text`).
    edits : Edits
        Every replacement made, sorted by position.

    Raises
    ------
    CorrectionError
        Wrong shape, non-finite corrections, or a change that would have to
        rewrite a Klartext word holding a Q parameter or a formula (a G-code
        expression or parameter becomes ``[expression+correction]``).
    """
    program.require_complete()
    corr = np.asarray(corrections_mm, dtype=np.float64)
    n = program.n_commands
    if corr.shape != (n, 3):
        raise CorrectionError(program.path, None, f"corrections have shape {corr.shape}, program has {n} commands")
    if not np.all(np.isfinite(corr)):
        k = int(np.flatnonzero(~np.all(np.isfinite(corr), axis=1))[0])
        raise CorrectionError(program.path, int(program.command_line[k]), f"correction of command k={k} is not finite")
    mv = program.moves
    m = len(mv)
    if m == 0 or not np.any(corr):
        if extra_edits:
            return _assemble(program, list(extra_edits))
        none = np.zeros(0, dtype=np.int64)
        return program.text, Edits(none, none, none, b"", none, none)
    desired = mv.end_mm.copy()
    desired[program.command_moves] += corr
    changed = np.zeros(m, dtype=bool)
    changed[program.command_moves] = _any3(corr != 0.0)
    return _rewrite_ends(program, desired, changed, min_decimals, extra_edits)


def apply_move_ends(program: Program, ends_mm: NDArray[np.float64], *, min_decimals: int = 3
                    ) -> tuple[str, list[Edit]]:
    """Return the program text with every move ending at ``ends_mm``: any move, rapids and arcs too.

    An arc keeps its centre (incremental centre words are rewritten when its start moved); an arc whose
    end moves along its plane's normal (Z of a G17 arc) becomes a helix. Moves whose row equals their
    end point are left as written (and absorb a moved start as :func:`apply_corrections` does).

    Parameters
    ----------
    program : Program
        The program as read.
    ends_mm : ndarray, shape (M, 3)
        Wanted end point of every move, mm, the frame of :attr:`MoveTable.end_mm`.
    min_decimals : int
        Least number of decimals of a rewritten number.

    Returns
    -------
    text, edits
        As :func:`apply_corrections`.

    Raises
    ------
    CorrectionError
        Wrong shape or non-finite ends, or a word that cannot take the change (see
        :func:`apply_corrections`).
    """
    program.require_complete()
    mv = program.moves
    ends = np.asarray(ends_mm, dtype=np.float64)
    if ends.shape != mv.end_mm.shape:
        raise CorrectionError(program.path, None, f"end points have shape {ends.shape}, program has {len(mv)} moves")
    if not np.all(np.isfinite(ends)):
        i = int(np.flatnonzero(~np.all(np.isfinite(ends), axis=1))[0])
        raise CorrectionError(program.path, int(mv.line[i]), "the wanted end point of this move is not finite")
    changed = _any3(ends != mv.end_mm)
    if not changed.any():
        return program.text, []
    return _rewrite_ends(program, ends.copy(), changed, min_decimals, None)


def _rewrite_ends(program: Program, desired: NDArray[np.float64], changed: NDArray[np.bool_], min_decimals: int,
                  extra_edits: list[Edit] | None) -> tuple[str, list[Edit]]:
    """The rewrite both entry points share: moves ``changed`` end at ``desired``, every other move keeps its
    absolute end point."""
    mv = program.moves
    # a move whose end point the next block reads (G92, G10 L20, a cycle, G5.1/G5.2: FLAG_POSITION_READ) or that
    # is polar would carry its change into every later move: refused, never written
    bad = np.flatnonzero(changed & ((mv.flags & (FLAG_POSITION_READ | FLAG_POLAR)) != 0))
    if bad.size:
        i = int(bad[0])
        who = f"command k={int(mv.command[i])}" if mv.command[i] >= 0 else "this move"
        raise CorrectionError(program.path, int(mv.line[i]),
                              f"{who} cannot take a correction: the next block reads its end point (or it is"
                              " polar), so every later move would shift with it")
    m = len(mv)
    klartext = program.dialect == "heidenhain"
    realized = mv.end_mm.copy()
    edits: list[Edit] = []
    inserts: dict[int, list[tuple[int, str, int]]] = {}

    idx_changed = np.flatnonzero(changed)
    # the changed moves and the moves after them (those the general path looks at), in one call
    program.resolve_spans(np.flatnonzero(changed | np.concatenate(([False], changed[:-1]))))
    fast = _fast_moves(program, changed, desired)
    data = np.frombuffer(program.text.encode("latin-1"), dtype=np.uint8)
    spliced = [_rewrite_fast(program, data, np.flatnonzero(fast), desired, klartext, min_decimals, realized)]
    # the other moves of absolute literal words go a run at a time (_Runs); the rest one at a time (_rewrite_move)
    simple = _simple_moves(program, fast) if not klartext else np.zeros(m, dtype=bool)
    runs = _Runs(program, data, desired, changed, fast, simple, realized, min_decimals) if simple.any() else None
    general_at = np.flatnonzero(~(simple | fast))
    slow = idx_changed[~fast[idx_changed]]
    follow = idx_changed + 1
    follow = follow[(follow < m) & ~fast[np.minimum(follow, m - 1)]]
    todo = sorted(set(slow.tolist()) | set(follow.tolist()))
    todo_set = set(todo)
    fast_l = fast.tolist()
    simple_l = simple.tolist()
    changed_l = changed.tolist()
    idx = 0
    nxt: int | None = None
    solved_to = 0  # moves below this one are written by a run
    while nxt is not None or idx < len(todo):
        if nxt is not None:  # the move after one that ended elsewhere: next, before the rest of the list
            i, nxt = nxt, None
        else:
            i = todo[idx]
            idx += 1
        if i >= m or fast_l[i] or i < solved_to:  # fast moves are written already; their followers are in the list
            continue
        if simple_l[i] and runs is not None:
            # every move from here to the next one of the general path, at once; the moves of the run that are
            # neither changed nor moved by their start are left as written, as below
            k = int(np.searchsorted(general_at, i))
            solved_to = int(general_at[k]) if k < general_at.size else m
            spliced.append(runs.solve(i, solved_to))
            if solved_to < m and realized[solved_to - 1].tolist() != mv.end_mm[solved_to - 1].tolist() \
                    and solved_to not in todo_set:
                todo_set.add(solved_to)
                nxt = solved_to
            continue
        start_real = realized[i - 1] if i > 0 else mv.start_mm[0]
        if not changed_l[i] and start_real.tolist() == mv.start_mm[i].tolist():
            continue
        end_real = _rewrite_move(program, i, start_real, desired[i], klartext, min_decimals, edits, inserts)
        # a number written back exactly (to float noise) leaves the later moves alone
        end_orig = mv.end_mm[i].tolist()
        end_real = [o if abs(r - o) <= 1e-9 else r for r, o in zip(end_real, end_orig, strict=True)]
        realized[i] = end_real
        if end_real != end_orig and i + 1 < m and i + 1 not in todo_set:
            todo_set.add(i + 1)
            nxt = i + 1

    for pos, items in inserts.items():
        items.sort()
        edits.append(Edit(pos, pos, "".join(s for _a, s, _l in items), items[0][2]))
    if extra_edits:
        edits.extend(extra_edits)
    return _assemble(program, edits, spliced, data)


class Edits(Sequence[Edit]):
    """The replacements of a rewrite, sorted by position (insertions before a replacement at the same place).

    Held as arrays (a big program has hundreds of thousands); an :class:`Edit` is made when one is asked for.
    """

    __slots__ = ("_end", "_line", "_new", "_new_length", "_new_start", "_start")

    def __init__(self, start: NDArray[np.int64], end: NDArray[np.int64], line: NDArray[np.int64], new: bytes,
                 new_start: NDArray[np.int64], new_length: NDArray[np.int64]) -> None:
        self._start, self._end, self._line = start, end, line
        self._new, self._new_start, self._new_length = new, new_start, new_length

    def __len__(self) -> int:
        return int(self._start.size)

    @overload
    def __getitem__(self, i: int) -> Edit: ...

    @overload
    def __getitem__(self, i: slice) -> list[Edit]: ...

    def __getitem__(self, i: int | slice) -> Edit | list[Edit]:
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        k = range(len(self))[i]
        a = int(self._new_start[k])
        new = self._new[a:a + int(self._new_length[k])].decode("latin-1")
        return Edit(int(self._start[k]), int(self._end[k]), new, int(self._line[k]))


@dataclass(frozen=True, slots=True)
class _Spliced:
    """Edits as arrays: ``start``, ``end``, ``line`` (E,), their replacements one after the other in ``new``
    (``new_length`` bytes each)."""

    start: NDArray[np.int64]
    end: NDArray[np.int64]
    line: NDArray[np.int64]
    new: NDArray[np.uint8]
    new_length: NDArray[np.int64]


def _spliced(edits: list[Edit]) -> _Spliced:
    news = [e.new.encode("latin-1") for e in edits]
    return _Spliced(np.array([e.start for e in edits], dtype=np.int64), np.array([e.end for e in edits], dtype=np.int64),
                    np.array([e.line for e in edits], dtype=np.int64),
                    np.frombuffer(b"".join(news), dtype=np.uint8), np.array([len(b) for b in news], dtype=np.int64))


def _assemble(program: Program, edits: list[Edit], first: list[_Spliced] | None = None,
              data: NDArray[np.uint8] | None = None) -> tuple[str, Edits]:
    """The text with the edits ``first`` and then ``edits`` made (sorted by position, stably: an insertion at a
    position comes before a replacement that starts there)."""
    if data is None:
        data = np.frombuffer(program.text.encode("latin-1"), dtype=np.uint8)
    parts = list(first) if first is not None else []
    parts.append(_spliced(edits))
    start = np.concatenate([p.start for p in parts])
    end = np.concatenate([p.end for p in parts])
    line = np.concatenate([p.line for p in parts])
    new = np.concatenate([p.new for p in parts])
    new_length = np.concatenate([p.new_length for p in parts])
    new_start = np.cumsum(new_length) - new_length
    order = np.argsort(start * (data.size + 2) + end, kind="stable")
    start, end, line, new_start, new_length = start[order], end[order], line[order], new_start[order], new_length[order]
    bad = np.flatnonzero(start[1:] < end[:-1])
    if bad.size:
        raise CorrectionError(program.path, int(line[bad[0] + 1]), "overlapping rewrites in one block")
    out = splice(data, start, end, new, new_start, new_length)
    return out.tobytes().decode("latin-1"), Edits(start, end, line, new.tobytes(), new_start, new_length)


def _fast_moves(program: Program, changed: NDArray[np.bool_], desired: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Changed straight moves that only need their own literal absolute words replaced.

    Most corrected CAM commands are like that; they are rewritten in one
    pass by :func:`_rewrite_fast` instead of one call of :func:`_rewrite_move`
    each (~40 µs of Python per move). Everything else -- incremental words,
    a missing word to insert, parameters, arcs, G28/G53 -- goes the general way.
    """
    from ilcnc.program.model import MOVE_LINE

    mv = program.moves
    moved = np.abs(desired - mv.end_mm) > 1e-12
    has_word = (mv.word_start >= 0) & ((mv.word_style & STYLE_LITERAL) != 0)
    ok = changed & (mv.kind == MOVE_LINE) & ((mv.flags & (FLAG_HOME | FLAG_MACHINE)) == 0) & (mv.rotation_deg == 0.0)
    ok &= ~_any3(mv.word_incremental)
    ok &= _all3(~moved | has_word)
    # an axis without a word takes the previous end point (modal): only safe when that did not move
    prev_moved = np.zeros_like(moved)
    prev_moved[1:] = moved[:-1] | _any3(mv.word_incremental[:-1])[:, None]
    prev_moved[0] = True
    ok &= _all3(has_word | ~prev_moved)
    return ok


def _any3(a: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """``np.any(a, axis=1)`` of an (N, 3) array (numpy's reduction over a short last axis costs ~18x this)."""
    return a[:, 0] | a[:, 1] | a[:, 2]


def _all3(a: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """``np.all(a, axis=1)`` of an (N, 3) array."""
    return a[:, 0] & a[:, 1] & a[:, 2]


def _simple_moves(program: Program, fast: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """G-code moves (other than the fast ones) that :class:`_Runs` writes: every end point word an absolute
    literal number, every incremental centre word a literal one, no turned frame, no G28/G53, written once.
    For them the general path's arithmetic depends on the start only through the axes without a word (the
    start's value stays, or the wanted one is inserted), which is what lets a run of them go at once."""
    mv = program.moves
    quiet = FLAG_HOME | FLAG_MACHINE | FLAG_REPEATED | FLAG_POLAR | FLAG_DERIVED | FLAG_POSITION_READ
    ok = ~fast & ((mv.flags & quiet) == 0) & (mv.rotation_deg == 0.0) & ~_any3(mv.word_incremental)
    ok &= _all3((mv.word_start == -1) | ((mv.word_style & STYLE_LITERAL) != 0))
    ok &= _all3((mv.center_start == -1) | ~mv.center_incremental | ((mv.center_style & STYLE_LITERAL) != 0))
    return ok


class _Runs:
    """Writes runs of :func:`_simple_moves` (and fast moves, written already) as :func:`_rewrite_move` would, one
    move after the other, but with array arithmetic.

    What the general path does with such a move ``i`` starting at ``s`` (the previous move's real end): nothing
    when it is not changed and ``s`` is its start as read; else each axis with a word gets the wanted number (or
    keeps its own when that is the same to 1e-9 mm), each axis without one keeps ``s`` when that is within
    1e-12 mm of the wanted end and gets a word inserted otherwise; an end within 1e-9 mm of the one read is
    that one. Words and inserted numbers do not depend on ``s``, so they are worked out once per move
    (:meth:`_info`); the ends are then found for all moves of a run at once, again for the moves after those
    whose end changed, until none does (a chain is rarely longer than two moves), and the edits made from the
    final starts.
    """

    def __init__(self, program: Program, data: NDArray[np.uint8], desired: NDArray[np.float64],
                 changed: NDArray[np.bool_], fast: NDArray[np.bool_], simple: NDArray[np.bool_],
                 realized: NDArray[np.float64], min_decimals: int) -> None:
        self.program, self.data, self.desired, self.changed = program, data, desired, changed
        self.fast, self.simple, self.realized, self.min_decimals = fast, simple, realized, min_decimals
        m = len(program.moves)
        self.done = np.zeros(m, dtype=bool)
        self.has_word = np.zeros((m, 3), dtype=bool)
        self.word_end = np.zeros((m, 3))  # the end on an axis with a word (before the 1e-9 snap)
        self.word_edit = np.zeros((m, 3), dtype=bool)  # that word is rewritten
        self.insert_end = np.zeros((m, 3))  # the end on an axis without a word, when one is inserted
        self.value = np.zeros((m, 3))  # the number written (word or insertion), program units
        self.decimals = np.zeros((m, 3), dtype=np.int64)
        self.style = np.zeros((m, 3), dtype=np.int64)

    def _starts(self, rows: NDArray[np.int64]) -> NDArray[np.float64]:
        s = self.realized[np.maximum(rows - 1, 0)]
        if rows.size and rows[0] == 0:
            s[0] = self.program.moves.start_mm[0]
        return s

    def _info(self, rows: NDArray[np.int64]) -> None:
        """Words, their new numbers and the numbers an insertion would write, of the moves ``rows`` not seen yet."""
        rows = rows[~self.done[rows]]
        if rows.size == 0:
            return
        self.done[rows] = True
        program, mv, data = self.program, self.program.moves, self.data
        program.resolve_spans(rows)
        ws, we = mv.word_start[rows], mv.word_end[rows]
        present = ws >= 0
        r_w, a_w = np.nonzero(present)
        orig, dec, style = _read_words(program.text, data, ws[r_w, a_w], we[r_w, a_w])
        n = rows.size
        block_dec = np.zeros(n, dtype=np.int64)
        np.maximum.at(block_dec, r_w, dec)
        block_style = np.zeros(n, dtype=np.int64)
        np.bitwise_or.at(block_style, r_w, style)
        unit = mv.unit_mm[rows]
        off = mv.offset_mm[rows]
        value = (self.desired[rows] - off) / unit[:, None]
        # axes with a word: the wanted number, or the word's own when that is the same to 1e-9 mm
        u_w = unit[r_w]
        v_w = value[r_w, a_w]
        edit = ~(np.abs(v_w - orig) * u_w < 1e-9)
        dec_w = np.maximum(dec, self.min_decimals)
        _new, _length, written = _spell_numbers(v_w[edit], dec_w[edit], style[edit], False)
        end = mv.end_mm[rows[r_w], a_w].copy()
        end[edit] = written * u_w[edit] + off[r_w[edit], a_w[edit]]
        g_w = rows[r_w]
        self.word_end[g_w, a_w] = end
        self.word_edit[g_w, a_w] = edit
        self.decimals[g_w, a_w] = dec_w
        self.style[g_w, a_w] = style
        # axes without: the number an insertion writes (the fewest decimals that hold it, the block's spelling)
        r_n, a_n = np.nonzero(~present)
        v_n = value[r_n, a_n]
        dec_n = _exact_decimals_of(v_n, np.maximum(self.min_decimals, block_dec[r_n]))
        style_n = block_style[r_n] & (STYLE_COMMA | STYLE_NO_LEADING_ZERO)
        _new, _length, written = _spell_numbers(v_n, dec_n, style_n, False)
        g_n = rows[r_n]
        self.insert_end[g_n, a_n] = written * unit[r_n] + off[r_n, a_n]
        self.decimals[g_n, a_n] = dec_n
        self.style[g_n, a_n] = style_n
        self.has_word[rows] = present
        self.value[rows] = value

    def _ends(self, rows: NDArray[np.int64], s: NDArray[np.float64], lo: int) -> tuple[
            NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
        """Real ends of the moves ``rows`` (of the run from ``lo``) starting at ``s``; which of them the general
        path rewrites, and which of their axes get a word inserted."""
        mv = self.program.moves
        o = mv.end_mm[rows]
        before = rows - 1  # (-1 only for the run's first move, which is visited anyway)
        # the general path looks at a changed move, the one after it and the one after a move that did not end as
        # read; it rewrites those changed or not starting where they did
        visited = (rows == lo) | self.changed[rows] | self.changed[before]
        visited |= _any3(self.realized[before] != mv.end_mm[before])
        processed = visited & (self.changed[rows] | _any3(s != mv.start_mm[rows]))
        hw = self.has_word[rows]
        insert = ~hw & ~(np.abs(self.desired[rows] - s) <= 1e-12) & processed[:, None]
        e = np.where(hw, self.word_end[rows], np.where(insert, self.insert_end[rows], s))
        e = np.where(np.abs(e - o) <= 1e-9, o, e)
        e = np.where(processed[:, None], e, o)
        return e, processed, insert

    def solve(self, lo: int, hi: int) -> _Spliced:
        """Write the moves ``lo`` to ``hi - 1`` (simple or fast; the one before ``lo`` is final) and fill their real
        ends into ``realized``; return the edits."""
        realized, simple = self.realized, self.simple
        # the changed moves and those after a changed one (a fast move's real end is final); then the moves after
        # those that end elsewhere than before, until none does
        span = np.arange(lo + 1, hi)
        look = self.changed[lo + 1:hi] | self.changed[lo:hi - 1]
        rows = np.concatenate(([lo], span[simple[lo + 1:hi] & look])).astype(np.int64)
        seen = [rows]
        while rows.size:
            self._info(rows)
            e, _processed, _insert = self._ends(rows, self._starts(rows), lo)
            moved = _any3(e != realized[rows])
            realized[rows] = e
            rows = rows[moved] + 1
            rows = rows[rows < hi]
            rows = rows[simple[rows]]
            seen.append(rows)
        rows = np.unique(np.concatenate(seen))
        s = self._starts(rows)
        _e, processed, insert = self._ends(rows, s, lo)
        rows, s, insert = rows[processed], s[processed], insert[processed]
        return self._edits(rows, s, insert)

    def _edits(self, rows: NDArray[np.int64], s: NDArray[np.float64], insert: NDArray[np.bool_]) -> _Spliced:
        """The edits of the moves ``rows`` (the general path looks at them) starting at ``s``: their rewritten
        words, inserted words and kept arc centres."""
        program, mv, text = self.program, self.program.moves, self.program.text
        # the first refusal, in the general path's order: a word with no place to go, then an arc's start
        ins_rows = np.any(insert, axis=1)
        nowhere = ins_rows & (mv.insert_at[rows] < 0)
        arcs = np.flatnonzero(mv.kind[rows] >= MOVE_ARC_CW)
        off_circle, r_ref, r_new = self._off_circle(rows[arcs], s[arcs])
        bad = np.concatenate((np.flatnonzero(nowhere), arcs[off_circle]))
        if bad.size:
            k = int(bad.min())
            line = int(mv.line[rows[k]])
            if nowhere[k]:
                a = int(np.flatnonzero(insert[k])[0])
                raise CorrectionError(program.path, line, f"no place to insert a {_LETTERS[a]} word in this block")
            j = int(np.flatnonzero(arcs == k)[0])
            r0, r1 = float(r_ref[j]), float(r_new[j])
            raise CorrectionError(program.path, line, f"the correction before this arc moves its start"
                                  f" {abs(r1 - r0):.4f} mm off its circle (radius {r1:.4f} mm): a control refuses"
                                  " such an arc; correct the point along the circle")
        starts: list[NDArray[np.int64]] = []
        ends: list[NDArray[np.int64]] = []
        lines: list[NDArray[np.int64]] = []
        news: list[NDArray[np.uint8]] = []
        lengths: list[NDArray[np.int64]] = []
        # rewritten words
        r_w, a_w = np.nonzero(self.word_edit[rows])
        g = rows[r_w]
        new, length, _written = _spell_numbers(self.value[g, a_w], self.decimals[g, a_w], self.style[g, a_w], False)
        starts.append(mv.word_start[g, a_w])
        ends.append(mv.word_end[g, a_w])
        lines.append(mv.line[g].astype(np.int64))
        news.append(new)
        lengths.append(length)
        # kept arc centres: incremental centre words of arcs whose start moved on their axis
        ga = rows[arcs]
        cs = mv.center_start[ga]
        moved = (cs >= 0) & mv.center_incremental[ga] & (s[arcs] != mv.start_mm[ga])
        r_c, a_c = np.nonzero(moved)
        g = ga[r_c]
        c_start, c_end = cs[r_c, a_c], mv.center_end[g, a_c]
        _o, dec, style = _read_words(text, self.data, c_start, c_end)
        rel = mv.center_mm[g, a_c] - s[arcs][r_c, a_c]
        new, length, _written = _spell_numbers(rel / mv.unit_mm[g], np.maximum(dec, self.min_decimals), style, False)
        starts.append(c_start)
        ends.append(c_end)
        lines.append(mv.line[g].astype(np.int64))
        news.append(new)
        lengths.append(length)
        # inserted words: one edit per block, its words in axis order, each spelled as the block's letters go
        r_i, a_i = np.nonzero(insert)
        g = rows[r_i]
        new, length, _written = _spell_numbers(self.value[g, a_i], self.decimals[g, a_i], self.style[g, a_i], False)
        numbers = new.tobytes().decode("latin-1")
        at = (np.cumsum(length) - length).tolist()
        pos = mv.insert_at[g]
        lower, sep = _line_styles(text, self.data, program.line_offsets(), pos)
        words = [sp + (_LETTERS[a].lower() if lo else _LETTERS[a]) + numbers[b:b + n]
                 for sp, lo, a, b, n in zip(sep, lower, a_i.tolist(), at, length.tolist(), strict=True)]
        block = np.flatnonzero(np.concatenate(([True], r_i[1:] != r_i[:-1]))) if r_i.size else r_i
        cut = [*block[1:].tolist(), len(words)] if r_i.size else []
        joined = ["".join(words[b:c]).encode("latin-1") for b, c in zip(block.tolist(), cut, strict=True)]
        starts.append(pos[block])
        ends.append(pos[block])
        lines.append(mv.line[g[block]].astype(np.int64))
        news.append(np.frombuffer(b"".join(joined), dtype=np.uint8))
        lengths.append(np.array([len(b) for b in joined], dtype=np.int64))
        return _Spliced(np.concatenate(starts).astype(np.int64), np.concatenate(ends).astype(np.int64),
                        np.concatenate(lines), np.concatenate(news), np.concatenate(lengths))

    def _off_circle(self, arcs: NDArray[np.int64], s: NDArray[np.float64]) -> tuple[
            NDArray[np.bool_], NDArray[np.float64], NDArray[np.float64]]:
        """:func:`_rewrite_center`'s refusal for the arcs ``arcs`` starting at ``s``: (refused, the radius at the
        start, the radius at the end), by ``math.hypot`` as there (numpy's may differ in the last bit)."""
        mv = self.program.moves
        plane = mv.plane[arcs].astype(np.int64)
        ij = np.array([PLANE_AXES.get(int(p), PLANE_AXES[17])[:2] for p in range(max(int(plane.max(initial=0)), 19) + 1)])
        i0, i1 = ij[plane, 0], ij[plane, 1]
        k = np.arange(arcs.size)
        c = mv.center_mm[arcs]
        e = mv.end_mm[arcs]
        hyp = math.hypot
        r0 = np.array([hyp(x, y) for x, y in zip((s[k, i0] - c[k, i0]).tolist(), (s[k, i1] - c[k, i1]).tolist(),
                                                  strict=True)])
        r1 = np.array([hyp(x, y) for x, y in zip((e[k, i0] - c[k, i0]).tolist(), (e[k, i1] - c[k, i1]).tolist(),
                                                  strict=True)])
        return np.asarray(arc_off_circle(r1, r0), dtype=bool).reshape(-1), r0, r1


def _read_words(text: str, data: NDArray[np.uint8], start: NDArray[np.int64], end: NDArray[np.int64]) -> tuple[
        NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """Value, decimals and ``STYLE_*`` bits of the literal number words ``text[start:end]`` (``_parse`` and
    ``spelling``; the plainly written ones at once)."""
    plain, value, dec, style = parse_plain(data, start, end)
    for k in np.flatnonzero(~plain).tolist():
        word = text[int(start[k]):int(end[k])]
        value[k] = _parse(word)
        dec[k], style[k] = spelling(word)
    return value, dec, style


def _exact_decimals_of(value: NDArray[np.float64], least: NDArray[np.int64]) -> NDArray[np.int64]:
    """:func:`_exact_decimals` of every value. ``round(v, d)`` is the number ``format(v, f".{d}f")`` reads back
    as (both round the exact binary value to ``d`` places), which :func:`_spell_numbers` gives."""
    out = np.maximum(least, 8)  # what is left when no count of decimals up to 8 holds the value
    todo = least <= 8
    for d in range(int(least.min(initial=9)), 9):
        k = np.flatnonzero(todo & (least <= d))
        if k.size == 0:
            continue
        if d < 0:  # round to tens, hundreds ...: not what format_number writes
            written = np.array([round(x, d) for x in value[k].tolist()], dtype=np.float64)
        else:
            dd = np.full(k.size, d, dtype=np.int64)
            _new, _length, written = _spell_numbers(value[k], dd, np.zeros(k.size, dtype=np.int64), False)
        hit = np.abs(written - value[k]) <= 1e-9
        out[k[hit]] = d
        todo[k[hit]] = False
    return out


def _line_styles(text: str, data: NDArray[np.uint8], offsets: NDArray[np.int64], pos: NDArray[np.int64]) -> tuple[
        list[bool], list[str]]:
    """:func:`_line_style` of the text before each place ``pos`` on its line. Lines of ASCII at once: letters are
    A-Z and a-z and ``str.strip`` takes bytes 9-13, 28-32 there; the others one by one."""
    n = pos.size
    line0 = offsets[np.searchsorted(offsets, pos, side="right") - 1]
    length = np.maximum(pos - line0, 0)
    index = np.arange(int(length.sum()), dtype=np.int64)
    seg = np.repeat(np.arange(n), length)
    index += np.repeat(line0 - (np.cumsum(length) - length), length)
    ch = data[index]
    upper = ch & 0xDF
    alpha = (upper >= 65) & (upper <= 90) & (ch < 128)
    lower_ch = (ch >= 97) & (ch <= 122)
    n_alpha = np.bincount(seg, alpha, minlength=n)
    n_lower = np.bincount(seg, lower_ch, minlength=n)
    other = np.bincount(seg, ch >= 128, minlength=n) > 0
    space = ((ch >= 9) & (ch <= 13)) | ((ch >= 28) & (ch <= 32))
    # a space or tab with a non-blank character before and after it on the segment
    solid = np.cumsum(~space)
    base = np.concatenate(([0], solid))[np.cumsum(length) - length]
    before = solid - base[seg]  # solid characters up to here (a blank one adds none)
    total = np.bincount(seg, ~space, minlength=n)
    inner = ((ch == 32) | (ch == 9)) & (before > 0) & (before < total[seg])
    sep_at = np.bincount(seg, inner, minlength=n) > 0
    lower = ((n_alpha > 0) & (n_lower > n_alpha / 2)).tolist()
    sep = np.where(sep_at, " ", "").tolist()
    for k in np.flatnonzero(other).tolist():
        lower[k], sep[k] = _line_style(text, int(line0[k]), int(pos[k]))
    return lower, sep


def _rewrite_fast(
    program: Program,
    data: NDArray[np.uint8],
    idx: NDArray[np.int64],
    desired: NDArray[np.float64],
    klartext: bool,
    min_decimals: int,
    realized: NDArray[np.float64],
) -> _Spliced:
    """Replace the coordinate words of the simple moves ``idx`` (see :func:`_fast_moves`); fill ``realized``.

    All words at once (:mod:`ilcnc.program.numwords`); a word or number outside the exact range of that
    arithmetic is read or spelled one by one, with the same result."""
    mv = program.moves
    text = program.text
    unit = mv.unit_mm[idx]
    off = mv.offset_mm[idx]
    new_val = (desired[idx] - off) / unit[:, None]
    end_all = mv.end_mm[idx]
    rows, axes = np.nonzero(np.abs(desired[idx] - end_all) > 1e-12)  # in the order of the moves, then X, Y, Z
    moves = idx[rows]
    ws, we = mv.word_start[moves, axes], mv.word_end[moves, axes]
    u = unit[rows]
    v = new_val[rows, axes]
    plain, orig, dec, style = parse_plain(data, ws, we)
    for k in np.flatnonzero(~plain).tolist():
        word = text[int(ws[k]):int(we[k])]
        orig[k] = _parse(word)
        dec[k], style[k] = spelling(word)
    w = np.flatnonzero(~(np.abs(v - orig) * u < 1e-9))  # a number written back as it is stays
    dec_w = np.maximum(np.maximum(dec[w], min_decimals), 0)
    new, length, written = _spell_numbers(v[w], dec_w, style[w], klartext)
    out_end = end_all.copy()
    out_end[rows[w], axes[w]] = written * u[w] + off[rows[w], axes[w]]
    realized[idx] = out_end
    return _Spliced(ws[w], we[w], mv.line[moves[w]].astype(np.int64), new, length)


def _spell_numbers(value: NDArray[np.float64], decimals: NDArray[np.int64], style: NDArray[np.int64],
                   klartext: bool) -> tuple[NDArray[np.uint8], NDArray[np.int64], NDArray[np.float64]]:
    """``format_number`` of every value, one after the other: (bytes, length of each, the value each reads back
    as). :func:`ilcnc.program.numwords.spell` spells them; the few outside its exact range go one by one."""
    spelled, new, length, written = spell(value, decimals, style, klartext=klartext)
    others = np.flatnonzero(~spelled)
    if others.size:
        extra = []
        for k in others.tolist():
            num = format_number(float(value[k]), int(decimals[k]), int(style[k]), klartext=klartext)
            extra.append(num.encode("latin-1"))
            length[k] = len(extra[-1])
            written[k] = _parse(num)
        # the others after all spelled ones, then back in the order of the values
        order = np.concatenate((np.flatnonzero(spelled), others))
        new = np.concatenate((new, np.frombuffer(b"".join(extra), dtype=np.uint8)))
        flat = np.empty(length.size, dtype=np.int64)
        flat[order] = np.cumsum(length[order]) - length[order]
        new = _reorder(new, flat, length)
    return new, length, written


def _reorder(new: NDArray[np.uint8], at: NDArray[np.int64], length: NDArray[np.int64]) -> NDArray[np.uint8]:
    """The pieces ``new[at[i]:at[i] + length[i]]`` one after the other in the order of ``i``."""
    out_at = np.cumsum(length) - length
    index = np.arange(int(length.sum()), dtype=np.int64)
    index += np.repeat(at - out_at, length)
    return new[index]


def _rewrite_move(
    program: Program,
    i: int,
    start_real: NDArray[np.float64],
    want: NDArray[np.float64],
    klartext: bool,
    min_decimals: int,
    edits: list[Edit],
    inserts: dict[int, list[tuple[int, str, int]]],
) -> list[float]:
    """Rewrite the words of move ``i`` so it ends at ``want`` from ``start_real``; return where it ends.

    The move's fields are taken as Python lists once (numpy scalars cost ~100 ns each, and this runs for every
    move the vectorised path leaves: ~20,000 in a big CAM program); the arithmetic is the same IEEE doubles."""
    mv = program.moves
    if mv.insert_at[i] == SPAN_LAZY:
        program.resolve_spans([i])
    text = program.text
    line = int(mv.line[i])
    unit = float(mv.unit_mm[i])
    flags = int(mv.flags[i])
    if flags & FLAG_HOME:
        # G28/G30 go to a stored machine position whatever the start: nothing to absorb
        return mv.end_mm[i].tolist()
    machine = bool(flags & FLAG_MACHINE)
    off = [0.0, 0.0, 0.0] if machine else mv.offset_mm[i].tolist()
    rot = 0.0 if machine else float(mv.rotation_deg[i])
    end0, start0 = mv.end_mm[i], mv.start_mm[i]
    if rot != 0.0:
        # a turned work system (G10 L2 R): its words are numbers of the turned frame, so the wanted end, the real
        # start and the move as read are turned back into it (offset 0 there) and the end found is turned out again
        machine_off = np.asarray(off)
        start_real, want, end0, start0 = rotate_xy(np.stack([start_real, want, end0, start0]) - machine_off, -rot)
        off = [0.0, 0.0, 0.0]
    starts = start_real.tolist()
    wants = want.tolist()
    ends_mm = end0.tolist()
    starts_mm = start0.tolist()
    word_start = mv.word_start[i].tolist()
    incs = mv.word_incremental[i].tolist()
    block_inc = any(incs)
    end = list(starts)
    for a in range(3):
        ws = word_start[a]
        inc = incs[a]
        if ws >= 0:
            we = int(mv.word_end[i, a])
            style = int(mv.word_style[i, a])
            orig_val = _parse(text[ws:we]) if style & STYLE_LITERAL else None
            new_val = (wants[a] - starts[a]) / unit if inc else (wants[a] - off[a]) / unit
            if orig_val is not None and abs(new_val - orig_val) * unit < 1e-9:
                end[a] = ends_mm[a] if not inc else starts[a] + orig_val * unit
                continue
            if not style & STYLE_LITERAL:
                if klartext:
                    raise CorrectionError(
                        program.path, line,
                        f"the {_LETTERS[a]} word holds a Q parameter or a formula and cannot absorb a correction",
                    )
                # G-code: the expression plus the correction, exact whatever the parameters hold at run time:
                # X[#<xscale>*53.] -> X[[#<xscale>*53.]+0.0012] (the value the reader evaluated + the change)
                now = (ends_mm[a] - starts_mm[a]) / unit if inc else (ends_mm[a] - off[a]) / unit
                delta = new_val - now
                dec = _exact_decimals(round(delta, max(min_decimals, 0) + 3), min_decimals)
                d_txt = f"{abs(delta):.{dec}f}"
                if float(d_txt) == 0.0:
                    end[a] = ends_mm[a] if not inc else starts[a] + now * unit
                    continue
                edits.append(Edit(ws, we, f"[{text[ws:we]}{'-' if delta < 0 else '+'}{d_txt}]", line))
                written = now + (float(d_txt) if delta >= 0 else -float(d_txt))
                end[a] = starts[a] + written * unit if inc else written * unit + off[a]
                continue
            src_dec, style = spelling(text[ws:we])
            dec = max(src_dec, min_decimals)
            s = format_number(new_val, dec, style, klartext=klartext)
            edits.append(Edit(ws, we, s, line))
            written = _parse(s)
        else:
            if abs(wants[a] - starts[a]) <= 1e-12:
                end[a] = starts[a]
                continue
            inc = inc or block_inc
            new_val = (wants[a] - starts[a]) / unit if inc else (wants[a] - off[a]) / unit
            pos = int(mv.insert_at[i])
            if pos < 0:
                raise CorrectionError(program.path, line, f"no place to insert a {_LETTERS[a]} word in this block")
            block_dec, block_style = _block_spelling(text, mv, i)
            dec = _exact_decimals(new_val, max(min_decimals, block_dec))
            s = format_number(new_val, dec, block_style & (STYLE_COMMA | STYLE_NO_LEADING_ZERO), klartext=klartext)
            letter = _LETTERS[a]
            if klartext:
                word = (" I" if inc else " ") + letter + s
            else:
                lower, sep = _line_style(text, _line_start(text, pos), pos)
                word = sep + (letter.lower() if lower else letter) + s
            inserts.setdefault(pos, []).append((a, word, line))
            written = _parse(s)
        end[a] = starts[a] + written * unit if inc else written * unit + off[a]
    if rot != 0.0:
        start_real = rotate_xy(start_real, rot) + machine_off
        end = (rotate_xy(np.asarray(end), rot) + machine_off).tolist()
    if mv.kind[i] >= MOVE_ARC_CW:
        _rewrite_center(program, i, start_real, klartext, min_decimals, edits)
    return end


def _rewrite_center(program: Program, i: int, start_real: NDArray[np.float64], klartext: bool, min_decimals: int,
                    edits: list[Edit]) -> None:
    """Keep an arc's centre where it was when its start moved (incremental centre words); refuse a start moved
    off the circle by more than a control accepts (LinuxCNC's limit, which both readers apply: 0.028 mm and
    0.1 % of the radius). The learner keeps arc starts on their circle, or within ``learning.arc_start_radial_mm``
    of it (a spiral, inside that limit); a corrections file may not."""
    mv = program.moves
    text = program.text
    unit = float(mv.unit_mm[i])
    line = int(mv.line[i])
    i0, i1, _i2 = PLANE_AXES.get(int(mv.plane[i]), PLANE_AXES[17])
    c = mv.center_mm[i]
    r0 = math.hypot(start_real[i0] - c[i0], start_real[i1] - c[i1])
    r1 = math.hypot(mv.end_mm[i, i0] - c[i0], mv.end_mm[i, i1] - c[i1])
    if arc_off_circle(r1, r0):  # the mm limit, relative to the circle's own radius
        raise CorrectionError(program.path, line, f"the correction before this arc moves its start"
                              f" {abs(r1 - r0):.4f} mm off its circle (radius {r1:.4f} mm): a control refuses such an"
                              " arc; correct the point along the circle")
    # the centre relative to the real start, in the (turned) program frame the I/J/K words are numbers of
    rot = float(mv.rotation_deg[i])
    rel = rotate_xy(mv.center_mm[i] - start_real, -rot)
    same = start_real == mv.start_mm[i]
    if rot != 0.0:
        same[:] = bool(np.all(same))  # a turned frame mixes X and Y
    for a in range(3):
        cs = int(mv.center_start[i, a])
        if cs < 0 or not mv.center_incremental[i, a]:
            continue
        if same[a]:
            continue
        style = int(mv.center_style[i, a])
        if not style & STYLE_LITERAL:
            raise CorrectionError(program.path, line,
                                  f"the arc centre word {_CENTER_LETTERS[a]} holds a parameter and cannot be kept")
        ce = int(mv.center_end[i, a])
        new_val = rel[a] / unit
        src_dec, style = spelling(text[cs:ce])
        dec = max(src_dec, min_decimals)
        edits.append(Edit(cs, ce, format_number(new_val, dec, style, klartext=klartext), line))


def _exact_decimals(value: float, least: int) -> int:
    """Fewest decimals (>= least, <= 8) that write ``value`` back to float noise."""
    for d in range(least, 9):
        if abs(round(value, d) - value) <= 1e-9:
            return d
    return max(least, 8)


def _block_spelling(text: str, mv: object, i: int) -> tuple[int, int]:
    """Most decimals and the style of the literal coordinate words of move ``i``."""
    dec, style = 0, 0
    for a in range(3):
        ws = int(mv.word_start[i, a])  # type: ignore[attr-defined]
        if ws >= 0 and mv.word_style[i, a] & STYLE_LITERAL:  # type: ignore[attr-defined]
            d, st = spelling(text[ws:int(mv.word_end[i, a])])  # type: ignore[attr-defined]
            dec = max(dec, d)
            style |= st
    return dec, style


def _line_start(text: str, pos: int) -> int:
    return text.rfind("\n", 0, pos) + 1

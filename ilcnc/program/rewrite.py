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
    FLAG_HOME,
    FLAG_MACHINE,
    FLAG_POLAR,
    FLAG_POSITION_READ,
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
    changed[program.command_moves] = np.any(corr != 0.0, axis=1)
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
    changed = np.any(ends != mv.end_mm, axis=1)
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
    spliced = _rewrite_fast(program, data, np.flatnonzero(fast), desired, klartext, min_decimals, realized)
    slow = idx_changed[~fast[idx_changed]]
    follow = idx_changed + 1
    follow = follow[(follow < m) & ~fast[np.minimum(follow, m - 1)]]
    todo = sorted(set(slow.tolist()) | set(follow.tolist()))
    todo_set = set(todo)
    fast_l = fast.tolist()
    changed_l = changed.tolist()
    idx = 0
    nxt: int | None = None
    while nxt is not None or idx < len(todo):
        if nxt is not None:  # the move after one that ended elsewhere: next, before the rest of the list
            i, nxt = nxt, None
        else:
            i = todo[idx]
            idx += 1
        if i >= m or fast_l[i]:  # fast moves are written already; their followers are in the list
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


def _assemble(program: Program, edits: list[Edit], first: _Spliced | None = None,
              data: NDArray[np.uint8] | None = None) -> tuple[str, Edits]:
    """The text with the edits ``first`` and then ``edits`` made (sorted by position, stably: an insertion at a
    position comes before a replacement that starts there)."""
    if data is None:
        data = np.frombuffer(program.text.encode("latin-1"), dtype=np.uint8)
    parts = [first] if first is not None else []
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
    ok &= ~np.any(mv.word_incremental, axis=1)
    ok &= np.all(~moved | has_word, axis=1)
    # an axis without a word takes the previous end point (modal): only safe when that did not move
    prev_moved = np.zeros_like(moved)
    prev_moved[1:] = moved[:-1] | np.any(mv.word_incremental[:-1], axis=1)[:, None]
    prev_moved[0] = True
    ok &= np.all(has_word | ~prev_moved, axis=1)
    return ok


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
    spelled, new, length, written = spell(v[w], dec_w, style[w], klartext=klartext)
    others = np.flatnonzero(~spelled)
    if others.size:
        extra = []
        for k in others.tolist():
            num = format_number(float(v[w[k]]), int(dec_w[k]), int(style[w[k]]), klartext=klartext)
            extra.append(num.encode("latin-1"))
            length[k] = len(extra[-1])
            written[k] = _parse(num)
        # the replacements of the others after all spelled ones, in the order of the edits
        order = np.concatenate((np.flatnonzero(spelled), others))
        new = np.concatenate((new, np.frombuffer(b"".join(extra), dtype=np.uint8)))
        flat = np.empty(length.size, dtype=np.int64)
        flat[order] = np.cumsum(length[order]) - length[order]
        new = _reorder(new, flat, length)
    out_end = end_all.copy()
    out_end[rows[w], axes[w]] = written * u[w] + off[rows[w], axes[w]]
    realized[idx] = out_end
    return _Spliced(ws[w], we[w], mv.line[moves[w]].astype(np.int64), new, length)


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

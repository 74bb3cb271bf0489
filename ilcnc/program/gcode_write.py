"""Writing a move table as G-code (LinuxCNC, Fanuc or grbl): ``ilcnc export`` of a program in another dialect."""

from __future__ import annotations

import math

from ilcnc.program.model import FLAG_MACHINE, MOVE_ARC_CW, MOVE_RAPID, PLANE_AXES, named_axes
from ilcnc.units import AXIS_LETTERS, MM_PER_INCH

__all__ = ["write_gcode"]


def write_gcode(moves: object, *, units: str = "mm", decimals: int = 3, name: str = "", dialect: str = "linuxcnc",
                events: object = None) -> str:
    """Write a move table (from any dialect) as a plain absolute G-code program.

    Parameters
    ----------
    moves : MoveTable
        The moves, consistent frame; written in the program frame (``end_mm - offset_mm``).
    units : {"mm", "inch"}
        Units of the written program (G21 / G20).
    decimals : int
        Decimal places of coordinates.
    name : str
        Program name for the header comment.
    dialect : str
        ``linuxcnc`` (ends with M2), ``fanuc`` (``%`` delimited, M30) or ``grbl``.
    events : Carried, optional
        The source's machining words by move (:func:`ilcnc.program.carry.carried_events`), written before and
        after their moves.

    A block names only the axes its source block named or the move changes: an axis the source never
    positioned is not invented (the machine stays where it is). A machine-coordinate move (``M91``, ``G53``)
    is ``G53 G0``/``G53 G1`` with its machine coordinates. A work offset (a Klartext datum shift) is a
    ``G52`` local offset (LinuxCNC and Fanuc run it; ``G52 X0 Y0 Z0`` before the end); grbl has no ``G52``,
    so a program with an offset is refused for it.

    Raises
    ------
    ValueError
        A work offset for the ``grbl`` dialect.
    """
    from ilcnc.program.model import MoveTable

    assert isinstance(moves, MoveTable)
    scale = 1.0 / MM_PER_INCH if units == "inch" else 1.0
    d = decimals
    out: list[str] = []
    if dialect == "fanuc":
        out.append("%")
    safe = "".join(c for c in name if c not in "()")
    out.append(f"(converted by ilcnc from {safe})" if safe else "(written by ilcnc)")
    out.append(f"G90 G94 G17 {'G20' if units == 'inch' else 'G21'}")
    plane = 17
    feed = None
    ends = (moves.end_mm - moves.offset_mm) * scale
    starts = (moves.start_mm - moves.offset_mm) * scale
    centers = (moves.center_mm - moves.offset_mm) * scale
    named = named_axes(moves)
    offset = (0.0, 0.0, 0.0)
    last: list[str | None] = [None, None, None]

    def num(v: float) -> str:
        s = f"{v:.{d}f}"
        return s[1:] if s.startswith("-") and float(s) == 0.0 else s

    from ilcnc.program.carry import Carried, gcode_blocks

    carried = events if isinstance(events, Carried) else Carried()
    for i in range(len(moves)):
        out.extend(gcode_blocks(carried.before.get(i, []), dialect))
        kind = int(moves.kind[i])
        machine = bool(moves.flags[i] & FLAG_MACHINE)
        if not machine:
            off = (float(moves.offset_mm[i, 0]), float(moves.offset_mm[i, 1]), float(moves.offset_mm[i, 2]))
            if off != offset:
                if dialect == "grbl":
                    raise ValueError(f"line {int(moves.line[i])}: a work offset (datum shift) has no G52 in grbl")
                out.append("G52 " + " ".join(f"{AXES_LETTERS[a]}{num(off[a] * scale)}" for a in range(3)))
                offset = off
                last = [None, None, None]  # a new frame: every written value is new
        words: list[str] = []
        if kind >= MOVE_ARC_CW and int(moves.plane[i]) != plane:
            plane = int(moves.plane[i])
            words.append(f"G{plane}")
        if machine:
            words.append("G53")
        words.append(("G0", "G1", "G2", "G3")[kind])
        n_motion_words = len(words)
        end = moves.end_mm[i] * scale if machine else ends[i]
        for a in range(3):
            txt = num(end[a])
            if machine:
                if named[i, a]:
                    words.append(f"{AXES_LETTERS[a]}{txt}")
                    last[a] = None  # a machine coordinate: the work position is another number
            elif (named[i, a] and txt != last[a]) or (kind >= MOVE_ARC_CW and a in PLANE_AXES[plane][:2]):
                words.append(f"{AXES_LETTERS[a]}{txt}")
                last[a] = txt
        if len(words) == n_motion_words:
            # a move that changes no written coordinate is still a block (maybe a command k): write the known
            # position so the block is kept
            known = [f"{AXES_LETTERS[a]}{last[a]}" for a in range(3) if last[a] is not None]
            words.extend(known or [f"{AXES_LETTERS[PLANE_AXES[plane][0]]}{num(end[PLANE_AXES[plane][0]])}"])
        if kind >= MOVE_ARC_CW:
            for a in PLANE_AXES[plane][:2]:
                words.append(f"{'IJK'[a]}{centers[i, a] - starts[i, a]:.{d}f}")
            if int(moves.turns[i]) > 1:
                words.append(f"P{int(moves.turns[i])}")
        if kind != MOVE_RAPID:
            f = float(moves.feed_mm_min[i]) * scale
            fs = f"{f:.{max(0, d - 2)}f}"
            if fs != feed and math.isfinite(f):
                words.append(f"F{fs}")
                feed = fs
        out.append(" ".join(words))
        out.extend(gcode_blocks(carried.after.get(i, []), dialect))
    out.extend(gcode_blocks(carried.tail, dialect))
    if offset != (0.0, 0.0, 0.0):
        out.append("G52 X0 Y0 Z0")
    out.append("M30" if dialect == "fanuc" else "M2")
    if dialect == "fanuc":
        out.append("%")
    return "\n".join(out) + "\n"


AXES_LETTERS = AXIS_LETTERS

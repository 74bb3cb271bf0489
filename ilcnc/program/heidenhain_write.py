"""Writing a move table as Heidenhain Klartext: ``ilcnc export`` of a program to ``.h``."""

from __future__ import annotations

import math

import numpy as np

from ilcnc.program.model import FLAG_MACHINE, MOVE_ARC_CCW, MOVE_LINE, MOVE_RAPID, PLANE_AXES, PLANE_XY, MoveTable, named_axes
from ilcnc.units import AXIS_LETTERS, LENGTH_UNITS, MM_PER_INCH

__all__ = ["write_klartext"]


# --------------------------------------------------------------------------------------------
# public API: writer
# --------------------------------------------------------------------------------------------
_AXIS_LETTERS = AXIS_LETTERS


class _Writer:
    """Turns a move table into numbered Klartext blocks."""

    def __init__(self, scale: float, decimals: int) -> None:
        self.scale = scale
        self.decimals = decimals
        self.blocks: list[str] = []
        self.last: list[str | None] = [None, None, None]
        self.feed: str | None = None
        self.offset: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def num(self, value: float) -> str:
        s = f"{value / self.scale:+.{self.decimals}f}"
        if float(s) == 0.0:
            s = "+" + s[1:]
        return s

    def feed_word(self, feed: float) -> str:
        if not math.isfinite(feed):
            return ""
        f = feed / self.scale
        text = f"{f:.3f}".rstrip("0").rstrip(".")
        if text == self.feed:
            return ""
        self.feed = text
        return " F" + text

    def datum(self, off: tuple[float, float, float]) -> None:
        if off == self.offset:
            return
        self.offset = off
        self.blocks.append("CYCL DEF 7.0 DATUM SHIFT")
        for a in range(3):
            self.blocks.append(f"CYCL DEF 7.{a + 1} {_AXIS_LETTERS[a]}{self.num(off[a])}")
        self.last = [None, None, None]

    def axes(self, p: np.ndarray, force: tuple[int, ...] = (), named: list[int] | None = None) -> str:
        """Words of the axes whose written value changes (of ``named`` alone, when given: the axes the source
        named or the move changes, so an axis the source never positioned is not invented) and of ``force``."""
        words = []
        for a in range(3):
            txt = self.num(float(p[a]))
            write = txt != self.last[a] and (named is None or a in named)
            if write or a in force:
                words.append(f" {_AXIS_LETTERS[a]}{txt}")
                self.last[a] = txt
        return "".join(words)

    def machine_axes(self, p: np.ndarray, axes: list[int]) -> str:
        """Words of a machine-coordinate move (M91): only the axes it moves or names."""
        words = []
        for a in axes or [2]:
            words.append(f" {_AXIS_LETTERS[a]}{self.num(float(p[a]))}")
            self.last[a] = None
        return "".join(words)

    def straight(self, kind: int, p: np.ndarray, feed: float, machine: list[int] | None, plane: int,
                 named: list[int] | None = None) -> None:
        if machine is not None:
            words = self.machine_axes(p, machine)
        else:
            words = self.axes(p, named=named)
            if not words:
                words = self.axes(p, force=(PLANE_AXES.get(plane, (0, 1, 2))[0],), named=[])
        if kind == MOVE_RAPID:
            tail = " FMAX"
        else:
            tail = self.feed_word(feed)
        self.blocks.append("L" + words + tail + (" M91" if machine is not None else ""))

    def arc(self, kind: int, s: np.ndarray, p: np.ndarray, c: np.ndarray, plane: int, turns: int, feed: float) -> None:
        i0, i1, i2 = PLANE_AXES.get(plane, PLANE_AXES[PLANE_XY])
        first, second = sorted((i0, i1))
        self.blocks.append(f"CC {_AXIS_LETTERS[first]}{self.num(float(c[first]))} "
                           f"{_AXIS_LETTERS[second]}{self.num(float(c[second]))}")
        dr = " DR+" if kind == MOVE_ARC_CCW else " DR-"
        lin = self.num(float(p[i2]))
        helix = f" {_AXIS_LETTERS[i2]}{lin}" if lin != self.last[i2] else ""
        if turns > 1:
            sweep = _sweep_deg(kind, s, p, c, plane) + 360.0 * (turns - 1)
            sign = "+" if kind == MOVE_ARC_CCW else "-"
            self.blocks.append(f"CP IPA{sign}{sweep:.4f}{helix}{dr}{self.feed_word(feed)}")
            self.last[i0] = self.last[i1] = None
        else:
            self.blocks.append(f"C {_AXIS_LETTERS[first]}{self.num(float(p[first]))} "
                               f"{_AXIS_LETTERS[second]}{self.num(float(p[second]))}{helix}{dr}{self.feed_word(feed)}")
            self.last[first] = self.num(float(p[first]))
            self.last[second] = self.num(float(p[second]))
        self.last[i2] = lin


def _sweep_deg(kind: int, s: np.ndarray, p: np.ndarray, c: np.ndarray, plane: int) -> float:
    """Unsigned sweep of an arc in (0, 360] degrees."""
    i0, i1, _i2 = PLANE_AXES.get(plane, PLANE_AXES[PLANE_XY])
    a0 = math.atan2(s[i1] - c[i1], s[i0] - c[i0])
    a1 = math.atan2(p[i1] - c[i1], p[i0] - c[i0])
    sweep = math.degrees(a1 - a0 if kind == MOVE_ARC_CCW else a0 - a1) % 360.0
    return sweep if sweep > 1e-9 else 360.0


def _clean_name(name: str) -> str:
    cleaned = "".join(c if (c.isalnum() or c in "_-") and ord(c) < 256 else "_" for c in name.strip())
    return cleaned or "PGM"


def _comment_lines(comments: list[str] | None) -> list[str]:
    out: list[str] = []
    for text in comments or []:
        for part in str(text).splitlines() or [""]:
            part = part.encode("latin-1", errors="replace").decode("latin-1").rstrip(" \t~")
            out.append("; " + "".join(c if c >= " " else " " for c in part))
    return out


def write_klartext(moves: MoveTable, *, name: str, units: str = "mm", decimals: int = 3,
                   comments: list[str] | None = None, events: object = None) -> str:
    """Write a move table (of any dialect) as a Heidenhain Klartext program.

    Parameters
    ----------
    moves : MoveTable
        The motion, in execution order.
    name : str
        Program name for ``BEGIN PGM`` / ``END PGM`` (characters other than
        letters, digits, ``_`` and ``-`` become ``_``).
    units : {"mm", "inch"}
        Units of the written program.
    decimals : int
        Decimal places of coordinates (0..6).
    comments : list of str, optional
        Comment lines written after ``BEGIN PGM`` as ``; text``.
    events : Carried, optional
        The source's machining words by move (:func:`ilcnc.program.carry.carried_events`), written before and
        after their moves.

    Returns
    -------
    str
        The program, LF line ends, blocks numbered from 0. Rapids are
        ``L .. FMAX``, straight feeds ``L .. F..`` (only the axes that change,
        F when it changes), arcs ``CC`` + ``C .. DR+/DR-`` (a full circle is a
        ``C`` back to its start point, a helix carries the tool-axis word,
        multi-turn arcs are ``CP IPA..``). Coordinates are in the program
        frame (``end_mm - offset_mm``); an offset is written as a datum shift
        (cycle 7). ``M91`` marks machine-coordinate moves.

    Raises
    ------
    ValueError
        Unknown units or decimals out of range.
    """
    if units not in LENGTH_UNITS:
        raise ValueError(f"units must be 'mm' or 'inch', not {units!r}")
    if not 0 <= int(decimals) <= 6:
        raise ValueError(f"decimals must be 0..6, not {decimals}")
    pgm = _clean_name(name)
    unit_word = "MM" if units == "mm" else "INCH"
    w = _Writer(MM_PER_INCH if units == "inch" else 1.0, int(decimals))
    blocks = w.blocks
    blocks.extend(_comment_lines(comments))
    from ilcnc.program.carry import Carried, klartext_blocks

    carried = events if isinstance(events, Carried) else Carried()
    named_all = named_axes(moves)
    for i in range(len(moves)):
        blocks.extend(klartext_blocks(carried.before.get(i, [])))
        kind = int(moves.kind[i])
        machine = bool(moves.flags[i] & FLAG_MACHINE)
        off = moves.offset_mm[i]
        if not machine:
            w.datum((float(off[0]), float(off[1]), float(off[2])))
        end = moves.end_mm[i] if machine else moves.end_mm[i] - off
        off = np.zeros(3) if machine else off
        plane = int(moves.plane[i])
        if kind in (MOVE_RAPID, MOVE_LINE):
            named = [a for a in range(3) if named_all[i, a]]  # an axis never positioned is not invented
            w.straight(kind, end, float(moves.feed_mm_min[i]), named if machine else None, plane,
                       named=None if machine else named)
        else:
            w.arc(kind, moves.start_mm[i] - off, end, moves.center_mm[i] - off, plane, int(moves.turns[i]),
                  float(moves.feed_mm_min[i]))
        blocks.extend(klartext_blocks(carried.after.get(i, [])))
    blocks.extend(klartext_blocks(carried.tail))
    if w.offset != (0.0, 0.0, 0.0):
        w.datum((0.0, 0.0, 0.0))
    lines = [f"0 BEGIN PGM {pgm} {unit_word}"]
    lines.extend(f"{k} {b}" for k, b in enumerate(blocks, start=1))
    lines.append(f"{len(blocks) + 1} END PGM {pgm} {unit_word}")
    return "\n".join(lines) + "\n"

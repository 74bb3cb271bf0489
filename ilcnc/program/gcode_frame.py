"""The work coordinate systems of a G-code program, as LinuxCNC keeps them.

Nine work offsets (G54..G59.3, set by ``G10 L2`` / ``G10 L20``), each with an XY
rotation (``G10 L2 P.. R``, degrees, counter-clockwise about the work system's Z),
and the one G92/G52 offset all systems share. LinuxCNC's canon
(``emccanon.cc``, ``rotate_and_offset_pos``) turns a program point ``p`` into the
machine frame as

    machine = R(rotation) (p + g92) + g5x

(the G92 offset is added before the turn, the work offset after it; Z never
turns). ilcnc's consistent frame is that machine frame, so a move table stores
``offset_mm = R g92 + g5x`` and ``rotation_deg`` per move
(:class:`ilcnc.program.model.MoveTable`). All lengths here are mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["POSITION_READING_CYCLES", "WorkFrames", "position_reader", "turn_xy"]


#: Canned cycles ilcnc reads (round(G * 10)): G73 G81 G82 G83 G85 G86 G89.
POSITION_READING_CYCLES = frozenset({730, 810, 820, 830, 850, 860, 890})


def position_reader(gcodes: list[int], l_word: float | None, axis_words: bool, motion_codes: list[int],
                    motion: int, absolute: bool, polar: tuple[float | None, float | None] | None,
                    parameter_read: bool) -> str | None:
    """What in one block reads the tool's current position before the block moves, as LinuxCNC's interpreter does
    (its G-code reference: "Coordinate Systems", "G92", "G10 L20", "G28.1", "Canned Cycles", "G5.1", "Polar
    Coordinates", "G5.2 G5.3 NURBS Block", "Numbered Parameters" #5420..#5428); None if nothing does.

    ``gcodes`` are the block's G codes (round(G * 10)), ``l_word`` its L value, ``axis_words`` whether it has axis
    words, ``motion_codes`` its motion G codes and ``motion`` the modal motion before it, ``absolute`` the distance
    mode it runs in (G90), ``polar`` its ``@`` and ``^`` values (None without polar words) and ``parameter_read``
    whether an expression of it read #5420..#5428. Such a block takes the end point of the move before it; when that
    is a corrected G1 the correction would move everything the block sets up (an offset, a stored home, a hole, a
    spline, a NURBS curve), so the reader marks that command never to be corrected (``FLAG_POSITION_READ``).
    """
    if parameter_read:
        return "#5420..#5428 read the current position"
    if 920 in gcodes:
        return "G92 sets its offset from the current position"
    if 100 in gcodes and l_word is not None and round(l_word) in (10, 11, 20):
        return f"G10 L{round(l_word)} sets its offset from the current position"
    if 281 in gcodes or 301 in gcodes:
        return f"G{28 if 281 in gcodes else 30}.1 stores the current position"
    if (280 in gcodes or 300 in gcodes) and axis_words and not absolute:
        return f"G{28 if 280 in gcodes else 30} in G91 goes through a point measured from the current position"
    if any(c in (100, 280, 300, 520, 920) for c in gcodes):
        return None  # the axis words belong to that code: no motion in this block
    mode = motion_codes[0] if motion_codes else motion
    if mode in POSITION_READING_CYCLES and (axis_words or bool(motion_codes)):
        return f"canned cycle G{mode / 10:g} starts from the current position (its retract, initial level, hole)"
    if mode == 51 and axis_words:
        return "G5.1 starts its spline at the current position"
    if 52 in motion_codes:
        return "G5.2 takes the current position as its NURBS curve's first control point"
    if polar is not None and (not absolute or None in polar):
        return "a polar move measured from the current position"
    return None


def turn_xy(x: float, y: float, angle_deg: float) -> tuple[float, float]:
    """(x, y) turned counter-clockwise by ``angle_deg`` about the origin, as LinuxCNC's ``rotate``
    (interp_convert.cc): x' = x cos t - y sin t, y' = x sin t + y cos t. An angle of 0 returns them unchanged."""
    if angle_deg == 0.0:
        return x, y
    t = math.radians(angle_deg)
    c, s = math.cos(t), math.sin(t)
    return x * c - y * s, x * s + y * c


@dataclass(slots=True)
class WorkFrames:
    """The active work system ``cs`` (1..9; 0 unused), every system's offset ``g5x`` (mm) and XY rotation ``rot``
    (degrees), and the G92/G52 offset ``g92`` (mm, added before the rotation)."""

    cs: int = 1
    g5x: list[list[float]] = field(default_factory=lambda: [[0.0, 0.0, 0.0] for _ in range(10)])
    g92: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    rot: list[float] = field(default_factory=lambda: [0.0] * 10)

    def rotation(self) -> float:
        """XY rotation of the active work system, degrees (0 for none or a whole number of turns)."""
        r = self.rot[self.cs]
        return 0.0 if r % 360.0 == 0.0 else r

    def offset(self) -> tuple[float, float, float]:
        """What is added to the turned program coordinates, mm: ``R g92 + g5x`` (``MoveTable.offset_mm``); without
        rotation ``g5x + g92``."""
        o = self.g5x[self.cs]
        g = self.g92
        r = self.rotation()
        if r == 0.0:
            return (o[0] + g[0], o[1] + g[1], o[2] + g[2])
        gx, gy = turn_xy(g[0], g[1], r)
        return (o[0] + gx, o[1] + gy, o[2] + g[2])

    def to_program(self, p: list[float] | tuple[float, ...]) -> list[float]:
        """A consistent-frame point (mm) in the active work system's program frame (mm, not divided by the unit)."""
        off = self.offset()
        x, y = turn_xy(p[0] - off[0], p[1] - off[1], -self.rotation())
        return [x, y, p[2] - off[2]]

    def to_machine(self, q: list[float] | tuple[float, ...]) -> list[float]:
        """A program-frame point (mm) in the consistent frame: the inverse of :meth:`to_program`."""
        off = self.offset()
        x, y = turn_xy(q[0], q[1], self.rotation())
        return [x + off[0], y + off[1], q[2] + off[2]]

    def set_origin(self, l_value: int, cs: int, words_mm: list[float | None], r_deg: float | None,
                   pos: list[float]) -> str | None:
        """``G10 L2`` (``l_value`` 2: the origin's coordinates) or ``G10 L20`` (20: the tool's position ``pos``, mm,
        named in system ``cs``) with the X/Y/Z words ``words_mm`` (None where absent) and rotation ``r_deg``.

        Returns the problem when LinuxCNC's interpreter cannot be followed (then nothing is changed), else None.
        As ``convert_setting_coordinate_system``: L20's X/Y are in the system's turned frame (its words and the
        G92 offset are turned before the offset is found); L2's are not turned. A rotation changed on the active
        system while a G92/G52 XY offset is in force is refused: LinuxCNC's interpreter then recomputes its position
        without that offset, away from where its canon put the tool, and its next moves cannot be followed.
        """
        r_old = self.rot[cs]
        r_new = r_old if r_deg is None else r_deg
        if cs == self.cs and r_new != r_old and (self.g92[0] != 0.0 or self.g92[1] != 0.0):
            return "G10 R changing the rotation of the active work system while G92/G52 offsets are in force"
        g = self.g92
        off = self.g5x[cs]
        axes = (0, 1, 2)
        if l_value == 20 and r_old % 360.0 != 0.0 and (words_mm[0] is not None or words_mm[1] is not None):
            qx, qy = turn_xy(pos[0] - off[0], pos[1] - off[1], -r_old)  # R^-1 (pos - g5x) = program + g92
            wx = words_mm[0] if words_mm[0] is not None else qx - g[0]
            wy = words_mm[1] if words_mm[1] is not None else qy - g[1]
            tx, ty = turn_xy(wx + g[0], wy + g[1], r_old)
            off[0], off[1] = pos[0] - tx, pos[1] - ty
            axes = (2,)
        for i in axes:
            w = words_mm[i]
            if w is not None:
                off[i] = w if l_value == 2 else pos[i] - w - g[i]
        self.rot[cs] = r_new
        return None

    def set_g92(self, words_mm: list[float | None], pos: list[float]) -> None:
        """``G92``: the offset that makes the tool's position ``pos`` (mm) read ``words_mm`` (None: axis not set),
        found before the rotation as LinuxCNC's canon adds it: ``R^-1 (pos - g5x) - words``."""
        o = self.g5x[self.cs]
        base = [pos[0] - o[0], pos[1] - o[1], pos[2] - o[2]]
        base[0], base[1] = turn_xy(base[0], base[1], -self.rotation())
        for i, w in enumerate(words_mm):
            if w is not None:
                self.g92[i] = base[i] - w

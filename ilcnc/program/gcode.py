"""ISO / RS-274 G-code reader (LinuxCNC, Fanuc and grbl dialects).

Two layers, as in pygcode: a *lexer* that cuts every line into words,
comments and parameter assignments with exact character spans, and an
*interpreter* that runs the blocks through the modal machine state (units,
distance modes, plane, offsets) and records every motion in a
:class:`~ilcnc.program.model.MoveTable`.

Every line of a file is lexed, so a syntax error anywhere is reported with
its line. The interpreter stops at the first construct it does not model
(O-word control flow, canned cycles, splines, polar coordinates, ...) and
records it in :attr:`Program.unsupported`: the program can still be written
back byte for byte, but its motion is refused by
:meth:`Program.require_complete` with that line, never misread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ilcnc.errors import ProgramError
from ilcnc.program.expr import Parameters
from ilcnc.program.gcode_flow import has_control_flow, run_control_flow
from ilcnc.program.gcode_frame import POSITION_READING_CYCLES, WorkFrames, position_reader, turn_xy
from ilcnc.program.gcode_lexer import MAX_NUMBER, Block, Lexer, Word, detect_dialect
from ilcnc.program.gcode_plain import classify_lines as _classify
from ilcnc.program.gcode_plain import resolve_fast_spans
from ilcnc.program.geometry import arc_length_mm
from ilcnc.program.model import (
    BLEND_EXACT_PATH,
    BLEND_EXACT_STOP,
    BLEND_NO_BOUND,
    BLEND_PROFILE,
    FLAG_CUTTER_COMP,
    FLAG_DERIVED,
    FLAG_HOME,
    FLAG_MACHINE,
    FLAG_PARAMETRIC,
    FLAG_POLAR,
    MAX_ARC_TURNS,
    MAX_CYCLE_REPEATS,
    MOVE_ARC_CCW,
    MOVE_ARC_CW,
    MOVE_LINE,
    MOVE_RAPID,
    PLANE_AXES,
    PLANE_XY,
    SPAN_LAZY,
    STYLE_LITERAL,
    MoveTable,
    MoveTableBuilder,
    Program,
    Unmodelled,
    arc_off_circle,
    decode_source,
    looks_binary,
)
from ilcnc.program.nurbs import NurbsBlock
from ilcnc.units import MM_PER_INCH

__all__ = ["detect_dialect", "read_gcode"]

_AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}
_CENTER_INDEX = {"I": 0, "J": 1, "K": 2}

_FAST_MOTION = {"0": 0, "1": 10, "2": 20, "3": 30}

# Modal groups of G codes (codes as round(value * 10)).
_MOTION = {0, 10, 20, 30, 330, 331, 382, 383, 384, 385, 50, 51, 52, 53, 730, 760, 800, 810, 820, 830, 840,
           850, 860, 870, 880, 890}
_GROUP0 = {40, 100, 280, 281, 300, 301, 520, 530, 920, 921, 922, 923}
_AXIS_GROUP0 = {100, 280, 300, 520, 920}
_KNOWN_G = _MOTION | _GROUP0 | {
    170, 171, 180, 181, 190, 191, 200, 210, 400, 410, 411, 420, 421, 430, 431, 432, 490, 540, 550, 560, 570,
    580, 590, 591, 592, 593, 610, 611, 640, 700, 710, 720, 760, 800, 900, 901, 910, 911, 930, 940, 950, 960,
    970, 980, 990, 70, 80, 150, 160,
}
_UNSUPPORTED_G = {
    50: "G5 cubic spline",
    70: "G7 lathe diameter mode", 80: "G8 lathe radius mode", 150: "G15 polar mode", 160: "G16 polar mode",
    330: "G33 spindle-synchronised motion", 331: "G33.1 rigid tapping", 382: "G38.2 probing",
    383: "G38.3 probing", 384: "G38.4 probing", 385: "G38.5 probing",
    760: "G76 threading cycle",
    840: "G84 tapping cycle", 870: "G87 back boring cycle", 880: "G88 boring cycle", 411: "G41.1 dynamic cutter compensation",
    421: "G42.1 dynamic cutter compensation", 432: "G43.2 additional tool length offset",
    960: "G96 constant surface speed", 700: "G70 lathe cycle",
    710: "G71 lathe cycle", 720: "G72 lathe cycle",
}
# Arc tolerances of LinuxCNC's interpreter (boundaries measured with rs274): centre-format arcs may
# miss the end radius by 0.02*sqrt(2) mm (mm programs) or 0.001*sqrt(2) inch (model.arc_off_circle), R-format
# arcs may be short of the half chord by 0.00127 mm (0.00005 inch) before they are refused.
_RADIUS_TOLERANCE_MM = 0.00127
#: Largest distance of a G5.1 spline's or a G5.2 NURBS curve's chords from the curve, mm (the moves the reader
#: generates for it).
SPLINE_CHORD_MM = 1e-4
#: Most chords of one G5.1 spline or G5.2 NURBS curve (a curve that needs more is refused with its line).
MAX_SPLINE_CHORDS = 100_000


#: G codes that use a Q word (G5, G10, G64, G73, G76, G83), as round(value * 10).
_Q_CODES = frozenset({50, 100, 640, 730, 760, 830})
_CYCLES = POSITION_READING_CYCLES
_CS_CODES = {540: 1, 550: 2, 560: 3, 570: 4, 580: 5, 590: 6, 591: 7, 592: 8, 593: 9}


@dataclass(slots=True)
class _State(WorkFrames):
    unit: float = 1.0
    plane: int = PLANE_XY
    absolute: bool = True
    arc_absolute: bool = False
    feed_mode: int = 940
    feed: float = 0.0  # program units / min
    spindle: float = 0.0
    motion: int = 800  # G80: no motion mode active at start (as LinuxCNC)
    cutter_comp: bool = False
    pos: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    units_seen: str | None = None
    retract_old_z: bool = False  # G98 / G99 (LinuxCNC starts in G99: retract to R)
    cycle_r: float | None = None
    cycle_il: float | None = None
    cycle_z: float | None = None
    cycle_p: float | None = None
    cycle_q: float | None = None
    blend_tol: float = BLEND_PROFILE  # path control (G61, G61.1, G64 [P]) as MoveTable.blend_tol_mm, mm


class _Interpreter:
    def __init__(self, path: Path, default_units: str, params: Parameters, dialect: str = "linuxcnc") -> None:
        self.path = path
        self.dialect = dialect
        self.st = _State()
        if default_units == "inch":
            self.st.unit = MM_PER_INCH
        self.params = params
        self.builder = MoveTableBuilder()
        self.warnings: list[str] = []
        self.ended = False
        self.axis_warned = False
        self.polar_words: tuple[float | None, float | None] = (None, None)
        self.nurbs: NurbsBlock | None = None  # an open G5.2 block

    def error(self, line: int, problem: str) -> Unmodelled:
        """A block the interpreter refuses (as LinuxCNC would): stops the interpretation."""
        return Unmodelled(line, problem)

    def execute(self, blk: Block) -> None:
        self.polar_words = (None, None)
        if blk.o_word is not None and blk.o_word != "program-number":
            raise Unmodelled(blk.line, f"O-word '{blk.o_word}' (subroutines and control flow) is not modelled")
        if blk.system is not None:
            self.warnings.append(f"line {blk.line}: grbl system command {blk.system!r} ignored")
            return
        st = self.st
        words = blk.words
        position_read = self.params.take_position_read()  # #5420..#5428 in this block's expressions
        if not words:
            self._read_position("#5420..#5428 read the current position" if position_read else None, blk.line)
            self._assign(blk)
            return
        letters: dict[str, Word] = {}
        gcodes: list[int] = []
        mcodes: list[int] = []
        for w in words:
            if w.letter == "G":
                code = round(w.value * 10)
                if abs(w.value * 10 - code) > 1e-6 or code not in _KNOWN_G:
                    raise ProgramError(self.path, blk.line, f"unknown G code G{w.value:g}")
                gcodes.append(code)
            elif w.letter == "M":
                if abs(w.value - round(w.value)) > 1e-6:
                    raise ProgramError(self.path, blk.line, f"bad M code M{w.value:g}")
                mcodes.append(round(w.value))
            else:
                letters[w.letter] = w
        line = blk.line
        if self.nurbs is not None:
            self._nurbs_line(blk, letters, gcodes, mcodes)
            return
        for code in gcodes:
            if code in _UNSUPPORTED_G:
                raise Unmodelled(line, f"{_UNSUPPORTED_G[code]} is not modelled")
        for mc in mcodes:
            if mc in (98, 99):
                raise Unmodelled(line, f"M{mc} subprogram call/return is not modelled")
        if "U" in letters or "V" in letters or "W" in letters:
            raise Unmodelled(line, "U/V/W axes are not modelled")
        # modal groups: at most one per group
        motion_codes = [c for c in gcodes if c in _MOTION]
        if len(motion_codes) == 2 and 800 in motion_codes:
            # "G00 ... G80" (Fanuc-style safety line): LinuxCNC accepts it; the real motion code wins
            motion_codes = [c for c in motion_codes if c != 800]
        if len(motion_codes) > 1:
            raise self.error(line, "two G codes of the motion group in one block")
        if "Q" in letters:  # rs274 refuses a Q no code of the block uses (a G1 with Q is a typo, not a feed)
            moving = motion_codes[0] if motion_codes else (st.motion if any(a in letters for a in "XYZABCUVW") else None)
            if not (any(c in _Q_CODES for c in gcodes) or moving in _Q_CODES
                    or any(m in (19, 66, 67, 68) or 100 <= m <= 199 for m in mcodes)):
                raise self.error(line, "Q word with no G5, G10, G64, G73, G76, G83, M19, M66, M67, M68 or user M code"
                                       " that uses it")
        # order of execution (RS274/NGC): feed mode, F, S, plane, units, comp, cs, distance, group 0, motion
        for c in gcodes:
            if c in (930, 940, 950):
                st.feed_mode = c
        if "F" in letters:
            fw = letters["F"]
            if fw.value < 0:
                raise self.error(line, "negative feed rate")
            st.feed = fw.value
        if "S" in letters:
            st.spindle = abs(letters["S"].value)
        for c in gcodes:
            if c == 40:
                # G4 dwell (before the block's motion, as RS274/NGC orders them): P seconds; Fanuc also X
                tw = letters.get("P")
                if tw is None and self.dialect == "fanuc":
                    tw = letters.pop("X", None)
                if tw is None:
                    raise self.error(line, "G4 dwell without a P word")
                self.builder.add_dwell(self._dwell_s(tw, line, "G4"))
            elif c in (170, 180, 190):
                st.plane = c // 10
            elif c in (171, 181, 191):
                raise Unmodelled(line, f"G{c / 10:g} UVW plane is not modelled")
            elif c == 200:
                st.unit = MM_PER_INCH
                st.units_seen = st.units_seen or "inch"
            elif c == 210:
                st.unit = 1.0
                st.units_seen = st.units_seen or "mm"
            elif c == 400:
                st.cutter_comp = False
            elif c in (410, 420):
                st.cutter_comp = True
            elif c in _CS_CODES:
                st.cs = _CS_CODES[c]
            elif c == 900:
                st.absolute = True
            elif c == 910:
                st.absolute = False
            elif c == 980:
                st.retract_old_z = True
            elif c == 990:
                st.retract_old_z = False
            elif c == 901:
                st.arc_absolute = True
            elif c == 911:
                st.arc_absolute = False
        path_codes = [c for c in gcodes if c in (610, 611, 640)]
        if path_codes:
            self._path_control(path_codes, letters, line)
        if blk.polar:
            self._polar_to_xy(letters, line)
        axis_words = [letters.get(a) for a in "XYZ"]
        has_axis = any(w is not None for w in axis_words) or any(a in letters for a in "ABC")
        group0 = [c for c in gcodes if c in _GROUP0]
        axis_group0 = [c for c in group0 if c in _AXIS_GROUP0]
        if len(axis_group0) > 1:
            raise self.error(line, "two G codes that use axis words in one block")
        if motion_codes and axis_group0 and has_axis:
            raise self.error(line, "axis words used by both a motion and a non-modal G code")
        self._read_position(position_reader(gcodes, letters["L"].value if "L" in letters else None, has_axis, motion_codes,
                                            st.motion, st.absolute, self.polar_words if blk.polar else None,
                                            position_read), line)
        machine = 530 in group0
        for c in group0:
            if c == 100:
                self._g10(letters, line)
            elif c in (280, 300):
                self._home(c, letters, axis_words, line)
            elif c in (281, 301):
                base = 5161 if c == 281 else 5181
                for i in range(3):
                    self.params.numbered[base + i] = st.pos[i] / st.unit
            elif c == 920:
                self._g92(axis_words, line)
                self._save_g92(True)
            elif c == 921:  # G92.1: offsets and their saved copy (#5210..#5213) to zero
                st.g92 = [0.0, 0.0, 0.0]
                self._save_g92(False)
            elif c == 922:  # G92.2: offsets to zero, the saved copy kept
                st.g92 = [0.0, 0.0, 0.0]
            elif c == 923:  # G92.3: the offsets the parameters hold (#5211..#5213, as LinuxCNC restores them)
                st.g92 = [self.params.numbered.get(5211 + i, 0.0) * st.unit for i in range(3)]
            elif c == 520:
                for i, w in enumerate(axis_words):
                    if w is not None:
                        st.g92[i] = w.value * st.unit
                self._save_g92(True)
        if motion_codes and motion_codes[0] in (52, 53):
            if motion_codes[0] == 53:
                raise self.error(line, "cannot use G5.3 without G5.2 first (no NURBS block is open)")
            self._nurbs_open(letters, axis_words, line, machine)
            st.motion = 800
            self._assign(blk)
            return
        prev_motion = st.motion
        if motion_codes:
            st.motion = motion_codes[0]
        if st.motion in _CYCLES and prev_motion != st.motion:
            st.cycle_il = None  # a new cycle starts: its initial level is taken at its first hole
        if "R" in letters and st.motion in _CYCLES:
            st.cycle_r = letters["R"].value
        if st.motion in _CYCLES and ("P" in letters or "Q" in letters):
            if "P" in letters:
                st.cycle_p = self._dwell_s(letters["P"], line, f"G{st.motion / 10:g}")
            st.cycle_q = letters["Q"].value if "Q" in letters else st.cycle_q
        if st.motion in _CYCLES and (has_axis or (motion_codes and motion_codes[0] in _CYCLES)) and not axis_group0:
            self._cycle(st.motion, letters, axis_words, line)
        elif has_axis and not axis_group0:
            if st.motion == 800:
                raise self.error(line, "axis words without an active motion mode (G0/G1/G2/G3)")
            if any(a in letters for a in "ABC"):
                if not self.axis_warned:
                    self.warnings.append(
                        f"line {line}: rotary A/B/C words are read but not modelled; such moves are never corrected"
                    )
                    self.axis_warned = True
            self._motion(st.motion, letters, axis_words, line, blk, machine)
        elif motion_codes and motion_codes[0] in (20, 30) and any(c in letters for c in "IJKR"):
            # full circle in place (no axis words): end point = start point
            self._motion(st.motion, letters, axis_words, line, blk, machine)
        elif machine and not has_axis:
            pass
        for mc in mcodes:
            if mc in (2, 30, 60) and mc != 60:
                self.ended = True
        self._assign(blk)

    def _read_position(self, why: str | None, line: int) -> None:
        """The block at ``line`` reads the current position (``why``, :func:`position_reader`): a G1 ending there is
        never corrected (its correction would move all the block sets up); a reader warning names both lines."""
        if why and (at := self.builder.freeze_last()) > 0:
            self.warnings.append(f"line {line}: {why}: the G1 at line {at} ending there is never corrected")

    def _dwell_s(self, word: Word, line: int, what: str) -> float:
        """A dwell time word (G4 ``P``, Fanuc ``X``; the ``P`` of G82/G86/G89) in seconds. ``P`` is seconds
        (LinuxCNC, grbl); in the Fanuc dialect a ``P`` without decimals is milliseconds (as
        :mod:`ilcnc.program.carry` reads it). A negative time is refused, as LinuxCNC refuses it."""
        v = float(word.value)
        if not v >= 0.0:
            raise self.error(line, f"{what} dwell with a negative time {word.letter}{v:g}")
        if self.dialect == "fanuc" and word.letter == "P" and v.is_integer():
            return v / 1000.0
        return v

    def _path_control(self, codes: list[int], letters: dict[str, Word], line: int) -> None:
        """G61, G61.1, G64 [P] [Q]: the path control mode of the following moves (``MoveTable.blend_tol_mm``).

        As LinuxCNC's interpreter (``Interp::convert_control_mode``): refused while cutter
        compensation is on; ``P`` is the corner tolerance in program units (after this block's
        G20/G21), a missing, zero or negative ``P`` means no tolerance (blend at the best speed).
        ``Q`` (LinuxCNC's naive-CAM tolerance, which merges nearly collinear short G1 blocks) is
        read and ignored: ilcnc never merges commands.
        """
        st = self.st
        if len(codes) > 1:
            raise self.error(line, "two G codes of the path control group (G61, G61.1, G64) in one block")
        if st.cutter_comp:
            raise self.error(line, "cannot change the path control mode with cutter radius compensation on")
        code = codes[0]
        if code == 610:
            st.blend_tol = BLEND_EXACT_PATH
        elif code == 611:
            st.blend_tol = BLEND_EXACT_STOP
        else:
            pw = letters.get("P")
            st.blend_tol = pw.value * st.unit if pw is not None and pw.value > 0 else BLEND_NO_BOUND

    def _cycle(self, code: int, letters: dict[str, Word], axis_words: list[Word | None], line: int) -> None:
        """Drilling cycles G73 G81 G82 G83 G85 G86 G89 in G17, as LinuxCNC executes them.

        Their moves are rapids and feeds along Z at the hole positions; they
        are never corrected (drilling is not contouring). G82, G86 and G89 dwell
        ``P`` at the bottom of each hole: the dwell of the move that leaves it
        (:attr:`MoveTable.dwell_s`); ``P`` is kept for the following cycles, as in LinuxCNC.
        """
        st = self.st
        if st.plane != PLANE_XY:
            raise Unmodelled(line, f"canned cycle G{code / 10:g} outside plane G17 is not modelled")
        if st.cycle_r is None:
            raise self.error(line, f"canned cycle G{code / 10:g} without an R word")
        if st.feed <= 0:
            raise self.error(line, f"canned cycle G{code / 10:g} with zero feed rate")
        if code in (730, 830) and (st.cycle_q is None or st.cycle_q <= 0):
            raise self.error(line, f"G{code / 10:g} needs a positive Q (peck depth)")
        dwell = 0.0
        if code in (820, 860, 890):
            if st.cycle_p is None:
                raise self.error(line, f"G{code / 10:g} without a P word (the dwell time at the bottom)")
            dwell = st.cycle_p
        zw = axis_words[2]
        if zw is not None:
            st.cycle_z = zw.value
        if st.cycle_z is None:
            raise self.error(line, f"canned cycle G{code / 10:g} without a Z word")
        repeats = 1
        if "L" in letters:
            lv = letters["L"].value
            if lv < 0 or abs(lv - round(lv)) > 1e-6:
                raise self.error(line, "L (repeat count) must be a non-negative integer")
            if lv > MAX_CYCLE_REPEATS:
                raise self.error(line, f"L{lv:g}: at most {MAX_CYCLE_REPEATS:,} repeats of a canned cycle in one block")
            repeats = round(lv)
        u = st.unit
        off = st.offset()
        if st.cycle_il is None:
            st.cycle_il = st.pos[2]  # LinuxCNC's "initial level": base of G91 R and the G98 height
        il = st.cycle_il
        if st.absolute:
            r_mm = st.cycle_r * u + off[2]
            bottom = st.cycle_z * u + off[2]
        else:
            r_mm = il + st.cycle_r * u
            bottom = r_mm + st.cycle_z * u
        clear = max(il, r_mm) if st.retract_old_z else r_mm
        delta = 0.010 * MM_PER_INCH  # LinuxCNC's G73/G83 clearance, 0.010 inch
        feed = st.feed * u
        flags = FLAG_DERIVED
        none3: list[Word | None] = [None, None, None]

        def rapid(x: float, y: float, z: float) -> None:
            self._add(MOVE_RAPID, line, (x, y, z), flags=flags, words=none3, offset=off)

        def down(z: float) -> None:
            p = st.pos
            self._add(MOVE_LINE, line, (p[0], p[1], z), flags=flags, words=none3, offset=off, feed=feed)

        polar = self.polar_words if self.polar_words != (None, None) else None
        rot = st.rotation()
        for rep in range(repeats):
            p = st.pos
            if rot != 0.0:
                # a rotated work system: the hole is placed in its program frame, then turned (Z is not turned)
                q = st.to_program(p)
                if polar is not None and not st.absolute and rep > 0:
                    r = math.hypot(q[0], q[1]) + (polar[0] or 0.0) * u
                    a = math.degrees(math.atan2(q[1], q[0])) + (polar[1] or 0.0)
                    q[0], q[1] = r * math.cos(math.radians(a)), r * math.sin(math.radians(a))
                else:
                    for i in (0, 1):
                        if axis_words[i] is not None:
                            q[i] = axis_words[i].value * u + (0.0 if st.absolute else q[i])
                x, y, _ = st.to_machine(q)
            elif polar is not None and not st.absolute and rep > 0:
                # G91 polar repeats step the polar radius and angle again from the new hole
                px, py = (p[0] - off[0]) / u, (p[1] - off[1]) / u
                r = math.hypot(px, py) + (polar[0] or 0.0)
                a = math.degrees(math.atan2(py, px)) + (polar[1] or 0.0)
                x = r * math.cos(math.radians(a)) * u + off[0]
                y = r * math.sin(math.radians(a)) * u + off[1]
            elif st.absolute:
                x = axis_words[0].value * u + off[0] if axis_words[0] is not None else p[0]
                y = axis_words[1].value * u + off[1] if axis_words[1] is not None else p[1]
            else:
                x = p[0] + (axis_words[0].value * u if axis_words[0] is not None else 0.0)
                y = p[1] + (axis_words[1].value * u if axis_words[1] is not None else 0.0)
            if rep == 0 and p[2] <= r_mm:
                rapid(p[0], p[1], clear)
            rapid(x, y, st.pos[2])
            if st.pos[2] != r_mm:
                rapid(x, y, r_mm)
            if code in (730, 830):
                q = st.cycle_q * u  # type: ignore[operator]
                depth = r_mm
                while True:
                    nxt = max(depth - q, bottom)
                    down(nxt)
                    if nxt <= bottom:
                        break
                    if code == 830:
                        rapid(x, y, r_mm)
                    rapid(x, y, nxt + delta)
                    depth = nxt
                rapid(x, y, clear)
            elif code == 850:
                down(bottom)
                down(r_mm)
                if clear != r_mm:
                    rapid(x, y, clear)
            elif code == 890:
                down(bottom)
                self.builder.add_dwell(dwell)
                down(clear)
            else:  # 810, 820, 860
                down(bottom)
                self.builder.add_dwell(dwell)
                rapid(x, y, clear)

    def _polar_to_xy(self, letters: dict[str, Word], line: int) -> None:
        """Replace ``@`` (radius) and ``^`` (angle, degrees) by X and Y words (G17 only).

        As in LinuxCNC: in G90 radius and angle are measured from the origin
        of the work system, a missing one keeps the current value; in G91
        both are increments of the current polar radius and angle.
        """
        st = self.st
        if "X" in letters or "Y" in letters:
            raise self.error(line, "polar coordinates @ ^ cannot be mixed with X or Y words")
        if st.plane != PLANE_XY:
            raise self.error(line, "polar coordinates @ ^ need plane G17")
        if st.rotation() != 0.0:
            q = st.to_program(st.pos)
            px, py = q[0] / st.unit, q[1] / st.unit
        else:
            off = st.offset()
            px = (st.pos[0] - off[0]) / st.unit
            py = (st.pos[1] - off[1]) / st.unit
        r0 = math.hypot(px, py)
        a0 = math.degrees(math.atan2(py, px))
        rw, aw = letters.pop("@", None), letters.pop("^", None)
        self.polar_words = (rw.value if rw is not None else None, aw.value if aw is not None else None)
        if st.absolute:
            r = rw.value if rw is not None else r0
            a = aw.value if aw is not None else a0
            x, y = r * math.cos(math.radians(a)), r * math.sin(math.radians(a))
        else:
            r = r0 + (rw.value if rw is not None else 0.0)
            a = a0 + (aw.value if aw is not None else 0.0)
            x = r * math.cos(math.radians(a)) - px
            y = r * math.sin(math.radians(a)) - py
        anchor = rw if rw is not None else aw
        assert anchor is not None
        # computed words: no literal number in the source, so never rewritten or corrected
        letters["X"] = Word("X", x, anchor.start, anchor.end, 0, 0)
        letters["Y"] = Word("Y", y, anchor.start, anchor.end, 0, 0)

    def _assign(self, blk: Block) -> None:
        for key, value in blk.assignments:
            if isinstance(key, int):
                if key < 1 or key > 5601:
                    raise self.error(blk.line, f"parameter number #{key} out of range")
                self.params.numbered[key] = value
            else:
                self.params.named[key] = value

    def _g10(self, letters: dict[str, Word], line: int) -> None:
        st = self.st
        lw, pw = letters.get("L"), letters.get("P")
        if lw is None:
            raise self.error(line, "G10 without an L word")
        lval = round(lw.value)
        if lval not in (2, 20):
            raise Unmodelled(line, f"G10 L{lval} (tool table) is not modelled")
        rw = letters.get("R")
        if rw is not None and lval == 20:
            raise self.error(line, "R not allowed in G10 L20")
        p = round(pw.value) if pw is not None else 0
        if p < 0 or p > 9:
            raise self.error(line, f"G10 P{p} out of range 0..9")
        words = [letters[a].value * st.unit if a in letters else None for a in "XYZ"]
        problem = st.set_origin(lval, st.cs if p == 0 else p, words, rw.value if rw is not None else None, st.pos)
        if problem is not None:
            raise Unmodelled(line, problem + " is not modelled")

    def _save_g92(self, on: bool) -> None:
        """Keep the G92/G52 offsets in #5210 (on) and #5211..#5213 (program units), as LinuxCNC does."""
        st = self.st
        num = self.params.numbered
        num[5210] = 1.0 if on else 0.0
        for i in range(3):
            num[5211 + i] = st.g92[i] / st.unit if on else 0.0

    def _g92(self, axis_words: list[Word | None], line: int) -> None:
        st = self.st
        if all(w is None for w in axis_words):
            raise self.error(line, "G92 without axis words")
        st.set_g92([w.value * st.unit if w is not None else None for w in axis_words], st.pos)

    def _home(self, code: int, letters: dict[str, Word], axis_words: list[Word | None], line: int) -> None:
        st = self.st
        off = st.offset()
        if any(w is not None for w in axis_words):
            inter = self._target(axis_words, off, machine=False)
            self._add(MOVE_RAPID, line, tuple(inter), flags=FLAG_HOME, words=axis_words, offset=off)
        base = 5161 if code == 280 else 5181
        home = [self.params.numbered.get(base + i, 0.0) * st.unit for i in range(3)]
        target = list(st.pos)
        for i, w in enumerate(axis_words):
            if w is not None or all(x is None for x in axis_words):
                target[i] = home[i]
        self._add(MOVE_RAPID, line, tuple(target), flags=FLAG_HOME | FLAG_MACHINE, words=[None, None, None], offset=off)

    def _target(self, axis_words: list[Word | None], off: tuple[float, float, float], machine: bool) -> list[float]:
        st = self.st
        if not machine and st.rotation() != 0.0:
            # a rotated work system: the words (absolute or incremental) are in its program frame
            q = st.to_program(st.pos)
            for i, w in enumerate(axis_words):
                if w is not None:
                    q[i] = w.value * st.unit + (0.0 if st.absolute else q[i])
            t = st.to_machine(q)
            for i in range(3):
                if axis_words[i] is None and (i == 2 or (axis_words[0] is None and axis_words[1] is None)):
                    t[i] = st.pos[i]  # an axis not named does not move (no turn-and-back rounding)
            return t
        t = list(st.pos)
        for i, w in enumerate(axis_words):
            if w is None:
                continue
            if machine:
                t[i] = w.value * st.unit
            elif st.absolute:
                t[i] = w.value * st.unit + off[i]
            else:
                t[i] = st.pos[i] + w.value * st.unit
        return t

    def _add(
        self,
        kind: int,
        line: int,
        end: tuple[float, ...],
        *,
        flags: int = 0,
        words: list[Word | None],
        offset: tuple[float, float, float],
        feed: float = float("nan"),
        correctable: bool = False,
        center: tuple[float, float, float] = (float("nan"),) * 3,
        plane: int = PLANE_XY,
        turns: int = 1,
        cwords: list[Word | None] | None = None,
        insert_at: int = -1,
        block_time: float = float("nan"),
    ) -> None:
        st = self.st
        inc = not st.absolute and not (flags & FLAG_MACHINE)
        ws = tuple(w.start if w is not None else -1 for w in words)
        we = tuple(w.end if w is not None else -1 for w in words)
        wd = tuple(w.decimals if w is not None else 0 for w in words)
        wst = tuple(w.style if w is not None else 0 for w in words)
        winc = (inc and words[0] is not None, inc and words[1] is not None, inc and words[2] is not None)
        kw = {}
        if cwords is not None:
            cinc = not st.arc_absolute
            kw = {
                "cstart": tuple(w.start if w is not None else -1 for w in cwords),
                "cend": tuple(w.end if w is not None else -1 for w in cwords),
                "cdec": tuple(w.decimals if w is not None else 0 for w in cwords),
                "cstyle": tuple(w.style if w is not None else 0 for w in cwords),
                "cinc": tuple(cinc and w is not None for w in cwords),
            }
        start = (st.pos[0], st.pos[1], st.pos[2])
        endt = (end[0], end[1], end[2])
        self.builder.add(
            kind, line, start, endt, feed=feed, unit=st.unit, offset=offset, center=center, plane=plane,
            turns=turns, correctable=correctable, flags=flags, wstart=ws, wend=we, wdec=wd, wstyle=wst,
            winc=winc, insert_at=insert_at, blend_tol=st.blend_tol, block_time=block_time, rotation=st.rotation(),
            **kw,
        )
        st.pos = [endt[0], endt[1], endt[2]]

    def _block_time_s(self) -> float:
        """Time an inverse-time (G93) feed move takes, ``60 / F`` s; NaN in the other feed modes."""
        st = self.st
        return 60.0 / st.feed if st.feed_mode == 930 and st.feed > 0 else float("nan")

    def _feed_mm_min(self, length_mm: float, line: int, letters: dict[str, Word]) -> float:
        st = self.st
        if st.feed_mode == 930:
            if "F" not in letters:
                raise self.error(line, "inverse time feed mode (G93) needs an F word on every feed move")
            return length_mm * st.feed
        if st.feed_mode == 950:
            if st.spindle <= 0:
                raise Unmodelled(line, "feed per revolution (G95) without a spindle speed")
            return st.feed * st.unit * st.spindle
        return st.feed * st.unit

    def _motion(self, motion: int, letters: dict[str, Word], axis_words: list[Word | None], line: int,
                blk: Block, machine: bool) -> None:
        st = self.st
        off = st.offset()
        target = self._target(axis_words, off, machine)
        flags = FLAG_MACHINE if machine else 0
        if st.cutter_comp:
            flags |= FLAG_CUTTER_COMP
        if any(w is not None and not (w.style & STYLE_LITERAL) for w in axis_words):
            flags |= FLAG_PARAMETRIC | (FLAG_POLAR if self.polar_words != (None, None) else 0)
        has_rotary = any(a in letters for a in "ABC")
        if motion == 0:
            self._add(MOVE_RAPID, line, tuple(target), flags=flags, words=axis_words, offset=off,
                      insert_at=blk.end_offset)
            return
        if motion == 10:
            if st.feed <= 0 and st.feed_mode == 940:
                raise self.error(line, "G1 with zero feed rate (no F word before)")
            length = math.dist(st.pos, target)
            feed = self._feed_mm_min(length, line, letters)
            # a word with a parameter or an expression is corrected as [expression+c] (ilcnc.program.rewrite)
            correctable = not machine and not has_rotary
            self._add(MOVE_LINE, line, tuple(target), flags=flags, words=axis_words, offset=off, feed=feed,
                      correctable=correctable, insert_at=blk.end_offset, block_time=self._block_time_s())
            return
        if motion == 51:
            if machine:
                raise self.error(line, "G53 is only allowed with G0 or G1")
            self._quadratic_spline(letters, target, off, line, flags)
            return
        if motion in (20, 30):
            if machine:
                raise self.error(line, "G53 is only allowed with G0 or G1")
            if st.feed <= 0 and st.feed_mode == 940:
                raise self.error(line, f"G{motion // 10} with zero feed rate (no F word before)")
            self._arc(motion, letters, axis_words, target, off, line, blk, flags)
            return
        raise self.error(line, f"motion mode G{motion / 10:g} is not a motion")

    def fast_run(self, nums: np.ndarray, gcol: np.ndarray, first_line: int) -> int:
        """Interpret consecutive plain blocks ``[N] [G0-3] [X Y Z] [I J K | R] [F]`` with numpy.

        ``nums`` holds the X Y Z I J K R F numbers of each block (NaN where
        absent), ``gcol`` the motion code (0, 10, 20, 30; -1 where absent).
        The modal state (motion mode, feed, unmentioned axes) is carried
        forward with vectorised forward fills and arcs are solved as arrays.

        Returns
        -------
        int
            How many blocks were interpreted: all of them, or fewer when a
            block needs the general interpreter (which then judges it).
        """
        st = self.st
        if st.rotation() != 0.0 or self.nurbs is not None:
            return 0  # a rotated work system (the words turned block by block) or a NURBS block's control points
        count = nums.shape[0]
        vals = nums[:, 0:3]
        cvals = nums[:, 3:6]
        rvals = nums[:, 6]
        fcol = nums[:, 7]
        has = ~np.isnan(vals)
        hasc = ~np.isnan(cvals)
        hasr = ~np.isnan(rvals)
        motion = _ffill(gcol.astype(np.float64), gcol >= 0, float(st.motion)).astype(np.int64)
        feed = _ffill(fcol, ~np.isnan(fcol), st.feed)
        any_word = has.any(axis=1) | hasc.any(axis=1) | hasr
        is_arc = (motion >= 20) & any_word
        has_move = has.any(axis=1) | is_arc
        a1, a2, lin = PLANE_AXES[st.plane]
        # blocks the general interpreter must judge: axis words without a motion mode, IJK off the
        # plane, R with IJK, arcs without a centre, centre words on straight moves, G1-G3 without feed
        plane_ok = ~hasc[:, lin] & ~(hasr & (hasc[:, a1] | hasc[:, a2]))
        ok = np.where(is_arc, plane_ok & (hasr | hasc[:, a1] | hasc[:, a2]), ~(hasc.any(axis=1) | hasr))
        ok &= ~(any_word & (motion == 800))
        ok &= ~(has_move & (motion >= 10) & (feed <= 0))
        if not ok.all():
            count = int(np.argmin(ok))
            if count == 0:
                return 0
            return self.fast_run(nums[:count], gcol[:count], first_line)
        unit = st.unit
        off = np.array(st.offset())
        pos0 = np.array(st.pos)
        if st.absolute:
            target = np.where(has, vals * unit + off, np.nan)
            ends = np.empty_like(target)
            for a in range(3):
                ends[:, a] = _ffill(target[:, a], has[:, a], pos0[a])
        else:
            ends = pos0 + np.cumsum(np.where(has, vals * unit, 0.0), axis=0)
        sel = np.flatnonzero(has_move)
        m = sel.size
        center = np.full((m, 3), np.nan)
        if m:
            mv_end = ends[sel]
            mv_start = np.vstack([pos0[None, :], mv_end[:-1]])
            arc = is_arc[sel]
            if arc.any():
                bad = self._fast_bad_arc(mv_start, mv_end, cvals[sel], hasc[sel], rvals[sel], motion[sel], arc, off, center)
                if bad >= 0:
                    count = int(sel[bad])
                    return self.fast_run(nums[:count], gcol[:count], first_line) if count else 0
        st.motion = int(motion[-1])
        st.feed = float(feed[-1])
        if m:
            mot = motion[sel]
            kind = np.select([mot == 0, mot == 10, mot == 20], [MOVE_RAPID, MOVE_LINE, MOVE_ARC_CW], MOVE_ARC_CCW)
            kind = kind.astype(np.int8)
            is_line = kind == MOVE_LINE
            cmd = np.where(is_line, self.builder.n_commands + np.cumsum(is_line) - 1, -1).astype(np.int32)
            present = has[sel]
            cpresent = hasc[sel] & arc[:, None]
            flags = np.full(m, FLAG_CUTTER_COMP if st.cutter_comp else 0, dtype=np.int16)
            self.builder.add_table(MoveTable(
                kind=kind,
                line=(first_line + sel).astype(np.int32),
                start_mm=mv_start,
                end_mm=mv_end,
                center_mm=center,
                offset_mm=np.broadcast_to(off, (m, 3)).copy(),
                plane=np.full(m, st.plane, dtype=np.int8),
                turns=np.ones(m, dtype=np.int16),
                feed_mm_min=np.where(kind == MOVE_RAPID, np.nan, feed[sel] * unit),
                unit_mm=np.full(m, unit),
                command=cmd,
                flags=flags,
                # spans are found again on demand (Program.resolve_spans): most are never needed
                word_start=np.where(present, SPAN_LAZY, -1),
                word_end=np.where(present, SPAN_LAZY, -1),
                word_decimals=np.zeros((m, 3), dtype=np.int8),
                word_style=np.where(present, STYLE_LITERAL, 0).astype(np.int8),
                word_incremental=present & (not st.absolute),
                center_start=np.where(cpresent, SPAN_LAZY, -1),
                center_end=np.where(cpresent, SPAN_LAZY, -1),
                center_decimals=np.zeros((m, 3), dtype=np.int8),
                center_style=np.where(cpresent, STYLE_LITERAL, 0).astype(np.int8),
                center_incremental=cpresent & (not st.arc_absolute),
                insert_at=np.full(m, SPAN_LAZY, dtype=np.int64),
                blend_tol_mm=np.full(m, st.blend_tol),
                # inverse-time feed (G93) never reaches this path: block_time_s stays NaN
            ))
            st.pos = [float(x) for x in mv_end[-1]]
        return count

    def _fast_bad_arc(self, start: np.ndarray, end: np.ndarray, cvals: np.ndarray, hasc: np.ndarray,
                      rvals: np.ndarray, motion: np.ndarray, arc: np.ndarray, off: np.ndarray,
                      center: np.ndarray) -> int:
        """Fill the arc centres of a run into ``center``; return the first arc the general path must judge, or -1."""
        st = self.st
        unit = st.unit
        a1, a2, _lin = PLANE_AXES[st.plane]
        use_r = arc & ~np.isnan(rvals)
        use_c = arc & ~use_r
        bad = np.zeros(arc.shape[0], dtype=bool)
        for ax in (a1, a2):
            v = np.where(hasc[:, ax], cvals[:, ax] * unit, 0.0)
            if st.arc_absolute:
                c = np.where(hasc[:, ax], v + off[ax], start[:, ax])
            else:
                c = start[:, ax] + v
            center[:, ax] = np.where(use_c, c, np.nan)
        if use_c.any():
            r0 = np.hypot(start[:, a1] - center[:, a1], start[:, a2] - center[:, a2])
            r1 = np.hypot(end[:, a1] - center[:, a1], end[:, a2] - center[:, a2])
            with np.errstate(invalid="ignore"):
                bad |= use_c & ((r0 < 1e-9) | arc_off_circle(r0, r1, unit))
        if use_r.any():
            r = rvals * unit
            dx = end[:, a1] - start[:, a1]
            dy = end[:, a2] - start[:, a2]
            d = np.hypot(dx, dy)
            half = d / 2.0
            ar = np.abs(r)
            short = use_r & (ar < half)
            with np.errstate(invalid="ignore"):
                bad |= use_r & ((d < 1e-9) | (short & (half - ar > _RADIUS_TOLERANCE_MM)))
            ar = np.where(short, half, ar)
            with np.errstate(invalid="ignore", divide="ignore"):
                h = np.sqrt(np.maximum(ar * ar - half * half, 0.0))
                ux, uy = dx / d, dy / d
            sgn = np.where(motion == 20, -1.0, 1.0) * np.where(r >= 0, 1.0, -1.0)
            center[:, a1] = np.where(use_r, start[:, a1] + dx / 2 + sgn * h * -uy, center[:, a1])
            center[:, a2] = np.where(use_r, start[:, a2] + dy / 2 + sgn * h * ux, center[:, a2])
        return int(np.argmax(bad)) if bad.any() else -1

    def _quadratic_spline(self, letters: dict[str, Word], target: list[float], off: tuple[float, float, float],
                          line: int, flags: int) -> None:
        """``G5.1 X Y I J``: the quadratic spline (Bézier) from the current point through the control point at the
        start + (I, J) to (X, Y), as straight moves the reader generates (``FLAG_DERIVED``: never commands, like a
        cycle's motion), with chords within :data:`SPLINE_CHORD_MM` of the curve.

        Its control point and end are not corrected: moving one reshapes the whole curve, and a correction is a
        point's, not a curve's. As LinuxCNC: XY plane only, I and J both required (incremental from the start,
        whatever G90.1 says), no Z word. LinuxCNC runs the curve with its own approximation; the virtual CNC
        follows the chords."""
        st = self.st
        if st.plane != PLANE_XY:
            raise self.error(line, "G5.1 is only allowed in the XY plane (G17)")
        if "I" not in letters and "J" not in letters:
            # rs274 makes no move for such a line (and no error): refused rather than guessed
            raise Unmodelled(line, "X/Y words in G5.1 mode without I and J (LinuxCNC makes no move) are not modelled")
        if "I" not in letters or "J" not in letters:
            raise self.error(line, "must specify both I and J with G5.1")
        if "Z" in letters or "K" in letters or "R" in letters:
            raise self.error(line, "G5.1 moves in the XY plane only (no Z, K or R word)")
        if st.feed <= 0 and st.feed_mode == 940:
            raise self.error(line, "G5.1 with zero feed rate (no F word before)")
        if st.feed_mode == 930:
            raise Unmodelled(line, "G5.1 in inverse time (G93) is not modelled")
        if st.cutter_comp:
            raise self.error(line, "G5.1 with cutter radius compensation is not allowed")
        p0 = np.array(st.pos[:2])
        # I, J are a program-frame vector: turned with the work system (a Bézier curve turns with its points)
        p1 = p0 + np.array(turn_xy(letters["I"].value * st.unit, letters["J"].value * st.unit, st.rotation()))
        p2 = np.array(target[:2])
        # B''(t) = 2 (p0 - 2 p1 + p2): a chord over dt misses the curve by at most |p0 - 2 p1 + p2| dt^2 / 4
        bend = float(np.hypot(*(p0 - 2.0 * p1 + p2)))
        n = max(1, math.ceil(math.sqrt(bend / (4.0 * SPLINE_CHORD_MM))))
        if not n <= MAX_SPLINE_CHORDS:
            raise Unmodelled(line, f"G5.1 spline needs more than {MAX_SPLINE_CHORDS:,} chords of"
                                   f" {SPLINE_CHORD_MM * 1e3:g} µm: not modelled")
        t = np.arange(1, n + 1) / n
        pts = (((1 - t) ** 2)[:, None] * p0 + (2 * t * (1 - t))[:, None] * p1 + (t * t)[:, None] * p2)
        pts[-1] = p2
        none3: list[Word | None] = [None, None, None]
        z = st.pos[2]
        for x, y in pts:
            length = math.dist(st.pos, (x, y, z))
            self._add(MOVE_LINE, line, (float(x), float(y), z), flags=flags | FLAG_DERIVED, words=none3, offset=off,
                      feed=self._feed_mm_min(length, line, letters))

    def _nurbs_open(self, letters: dict[str, Word], axis_words: list[Word | None], line: int, machine: bool) -> None:
        """``G5.2 [X Y P] [L]``: open a NURBS block whose first control point is the current point
        (:class:`~ilcnc.program.nurbs.NurbsBlock` says how LinuxCNC reads it). The control points are not commands:
        one is off the path and moving it bends the curve over several knot spans, not at a point."""
        st = self.st
        if machine:
            raise self.error(line, "G53 is only allowed with G0 or G1")
        if st.plane != PLANE_XY:
            raise Unmodelled(line, "G5.2 outside the XY plane (G17) is not modelled (LinuxCNC reads it without an"
                                   " error; its reference gives the XY plane)")
        if st.feed_mode != 940:
            raise Unmodelled(line, f"G5.2 in feed mode G{st.feed_mode / 10:g} is not modelled")
        if st.feed <= 0:
            raise self.error(line, "cannot make a NURBS with zero feed rate (no F word before)")
        if st.cutter_comp:
            raise Unmodelled(line, "G5.2 with cutter radius compensation is not modelled")
        if not st.absolute:
            # measured: rs274 measures every control point from the curve's start, not from the point before
            raise Unmodelled(line, "G5.2 in incremental distance mode (G91) is not modelled")
        order, weight, has_xy = NurbsBlock.open_words(letters, line)
        nb = NurbsBlock(line, order, st.offset(), FLAG_DERIVED)
        nb.points.append((st.pos[0], st.pos[1]))
        nb.weights.append(1.0 if has_xy else weight)
        if has_xy:
            t = self._target(axis_words, nb.offset, False)
            nb.points.append((t[0], t[1]))
            nb.weights.append(weight)
        self.nurbs = nb

    def _nurbs_line(self, blk: Block, letters: dict[str, Word], gcodes: list[int], mcodes: list[int]) -> None:
        """A line inside an open G5.2 block: a control point ``X Y P``, or ``G5.3``, which moves along the curve
        through chords within :data:`SPLINE_CHORD_MM` (``FLAG_DERIVED``: never commands), reported on the G5.3 line
        as LinuxCNC reports them; anything else is not modelled."""
        nb = self.nurbs
        assert nb is not None
        line = blk.line
        if mcodes or blk.polar or (gcodes and gcodes != [53]):
            what = "the program's end" if any(m in (2, 30) for m in mcodes) else "a G or M code or polar words"
            raise Unmodelled(line, f"{what} inside the G5.2 NURBS block of line {nb.line} (before its G5.3) is not"
                                   " modelled")
        if gcodes:
            if set(letters) - {"N"}:
                raise Unmodelled(line, "G5.3 with words other than N is not modelled")
            pts = nb.chord_ends(line, SPLINE_CHORD_MM, MAX_SPLINE_CHORDS)
            self.nurbs = None
            st = self.st
            z = st.pos[2]
            none3: list[Word | None] = [None, None, None]
            for x, y in pts.tolist():
                self._add(MOVE_LINE, line, (x, y, z), flags=nb.flags, words=none3, offset=nb.offset,
                          feed=st.feed * st.unit)
        else:
            weight = nb.point_words(letters, line)
            if weight is not None:
                t = self._target([letters["X"], letters["Y"], None], nb.offset, False)
                nb.points.append((t[0], t[1]))
                nb.weights.append(weight)
        self._assign(blk)

    def _arc(self, motion: int, letters: dict[str, Word], axis_words: list[Word | None], target: list[float],
             off: tuple[float, float, float], line: int, blk: Block, flags: int) -> None:
        st = self.st
        a1, a2, _ = PLANE_AXES[st.plane]
        cw = motion == 20
        rot = st.rotation()
        if rot != 0.0:
            if st.plane != PLANE_XY:
                # LinuxCNC turns the arc's plane with the work system (emccanon.cc ARC_FEED): an arc in a tilted
                # plane, which the move table (arcs in G17/G18/G19) cannot hold
                raise Unmodelled(line, f"an arc in plane G{st.plane} in a rotated work system (G10 R) is not"
                                       " modelled: LinuxCNC tilts its plane")
            # the centre is found in the program frame (I/J, R and G90.1 are program numbers), then turned
            start = st.to_program(st.pos)
            machine_target, target, c_off = target, st.to_program(target), (0.0, 0.0, 0.0)
        else:
            start = st.pos
            machine_target, c_off = target, off
        rw = letters.get("R")
        center = [float("nan")] * 3
        cwords: list[Word | None] = [letters.get("I"), letters.get("J"), letters.get("K")]
        for i in range(3):
            if cwords[i] is not None and i not in (a1, a2):
                raise self.error(line, f"{'IJK'[i]} word not allowed in plane G{st.plane}")
        turns = 1
        if "P" in letters:
            pv = letters["P"].value
            if pv < 1 or abs(pv - round(pv)) > 1e-6:
                raise self.error(line, f"arc P{pv:g} must be a positive integer number of turns")
            if pv > MAX_ARC_TURNS:
                raise self.error(line, f"arc P{pv:g}: at most {MAX_ARC_TURNS:,} turns of one arc or helix")
            turns = round(pv)
        if rw is not None:
            if cwords[a1] is not None or cwords[a2] is not None:
                raise self.error(line, "arc with both R and I/J/K")
            r = rw.value * st.unit
            dx = target[a1] - start[a1]
            dy = target[a2] - start[a2]
            d = math.hypot(dx, dy)
            if d < 1e-9:
                raise self.error(line, "arc with R: start and end are the same point (a full circle needs I/J/K)")
            half = d / 2.0
            ar = abs(r)
            if ar < half:
                if half - ar > _RADIUS_TOLERANCE_MM:
                    raise self.error(line, f"arc radius {ar:g} mm too small to reach the end point")
                ar = half
            h = math.sqrt(max(ar * ar - half * half, 0.0))
            ux, uy = dx / d, dy / d
            nx, ny = -uy, ux
            sgn = (-1.0 if cw else 1.0) * (1.0 if r >= 0 else -1.0)
            mx, my = start[a1] + dx / 2, start[a2] + dy / 2
            center[a1] = mx + sgn * h * nx
            center[a2] = my + sgn * h * ny
        else:
            if cwords[a1] is None and cwords[a2] is None:
                raise self.error(line, "arc without I/J/K or R")
            for i in (a1, a2):
                w = cwords[i]
                v = w.value * st.unit if w is not None else 0.0
                if st.arc_absolute:
                    center[i] = (v + c_off[i]) if w is not None else start[i]
                else:
                    center[i] = start[i] + v
            r0 = math.hypot(start[a1] - center[a1], start[a2] - center[a2])
            r1 = math.hypot(target[a1] - center[a1], target[a2] - center[a2])
            if r0 < 1e-9:
                raise self.error(line, "arc with zero radius (centre at the start point)")
            # LinuxCNC's limits, measured against rs274 (its sample good-arc.small sits at 0.028 mm, 0.11 %)
            if arc_off_circle(r0, r1, st.unit):
                raise self.error(line, f"arc radius to end ({r1:.4f} mm) differs from radius to start ({r0:.4f} mm)")
        lin = PLANE_AXES[st.plane][2]
        center[lin] = float("nan")
        length = arc_length_mm(start, target, center, a1, a2, lin, cw, turns)
        feed = self._feed_mm_min(length, line, letters)
        kind = MOVE_ARC_CW if cw else MOVE_ARC_CCW
        if rot != 0.0:
            center = st.to_machine(center)  # XY plane: the turn keeps the direction (G2 stays clockwise)
            center[lin] = float("nan")
        self._add(kind, line, tuple(machine_target), flags=flags, words=axis_words, offset=off, feed=feed,
                  center=(center[0], center[1], center[2]), plane=st.plane, turns=turns,
                  cwords=cwords if rw is None else None, insert_at=blk.end_offset, block_time=self._block_time_s())


def _ffill(values: np.ndarray, valid: np.ndarray, initial: float) -> np.ndarray:
    """Forward-fill ``values`` where ``valid`` is False, starting from ``initial``."""
    idx = np.where(valid, np.arange(values.shape[0]), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, values[np.maximum(idx, 0)], initial)


class _Lines:
    """Lines of a text by index, sliced on demand (without the newline)."""

    __slots__ = ("_n", "_start", "_text")

    def __init__(self, text: str, line_start: np.ndarray) -> None:
        self._text = text
        self._start = line_start
        self._n = int(line_start.shape[0])

    def __getitem__(self, i: int) -> str:
        start = int(self._start[i])
        end = int(self._start[i + 1]) - 1 if i + 1 < self._n else len(self._text)
        return self._text[start:end]

    def __len__(self) -> int:
        return self._n


def _general(lexer: Lexer, interp: _Interpreter, lines: _Lines, line_start: np.ndarray, i: int, running: bool,
             unsupported: tuple[int, str] | None) -> tuple[bool, tuple[int, str] | None]:
    """Run line ``i`` through the general lexer and interpreter; returns (running, unsupported)."""
    raw = lines[i]
    s = raw[:-1] if raw.endswith("\r") else raw
    blk = lexer.lex(s, int(line_start[i]), i + 1)
    try:
        interp.execute(blk)
    except Unmodelled as exc:
        lexer.lenient = True
        return False, (exc.line, exc.problem)
    if interp.ended:
        lexer.lenient = True
        return False, unsupported
    return running, unsupported


def read_gcode(path: str | Path, data: bytes, *, default_units: str = "mm", dialect: str | None = None) -> Program:
    """Read a G-code program.

    Parameters
    ----------
    path : str or Path
        File name (for messages and the dialect guess).
    data : bytes
        The file content.
    default_units : {"mm", "inch"}
        Units when the program has no G20/G21 before its first move.
    dialect : str, optional
        Force ``linuxcnc``, ``fanuc`` or ``grbl``; guessed when omitted.

    Returns
    -------
    Program
        With :attr:`Program.unsupported` set if the interpreter stopped early.

    Raises
    ------
    ProgramError
        Binary or empty file, or a syntax error on any line.
    """
    p = Path(path)
    if not data.strip():
        raise ProgramError(p, None, "empty program")
    if looks_binary(data):
        raise ProgramError(p, None, "binary file, not a G-code program")
    text = decode_source(data)
    params = Parameters()
    params.named.update({"_value": 0.0, "_value_returned": 0.0})  # predefined by LinuxCNC
    lexer = Lexer(p, params)
    interp = _Interpreter(p, default_units, params, dialect or detect_dialect(p, text))
    unsupported: tuple[int, str] | None = None
    percent_count = 0
    running = True
    # line offsets from the bytes (one numpy pass); the text of a line is sliced only when needed
    line_start = np.concatenate(([0], np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == 10) + 1))
    n = int(line_start.shape[0])
    lines = _Lines(text, line_start)
    table, slow_mask = _classify(text, data, n, line_start, p)
    # O-words only stand in lines that are not plain blocks: look there only
    if has_control_flow("\n".join([lines[i] for i in np.flatnonzero(slow_mask)])):
        unsupported = run_control_flow(lexer, interp, text.split("\n"), line_start)
        return _finish(p, text, interp, unsupported, default_units)
    nums = table[:, 1:9]
    # absurd numbers (overflowing to inf) go through the general lexer, which names them
    huge = np.any(np.abs(nums) > MAX_NUMBER, axis=1)
    slow_mask |= huge
    nums[huge] = np.nan
    slow = np.flatnonzero(slow_mask).tolist()
    gcol = np.where(np.isnan(table[:, 0]), -1, np.nan_to_num(table[:, 0]) * 10).astype(np.int64)
    slow.append(n)
    i = 0
    for nxt in slow:
        # lines i .. nxt-1 are plain blocks, nxt needs the general lexer
        while running and i < nxt:
            if interp.st.feed_mode != 940:
                done = 0
            else:
                done = interp.fast_run(nums[i:nxt], gcol[i:nxt], i + 1)
            i += done
            if i < nxt:
                # a plain block the general interpreter must judge
                running, unsupported = _general(lexer, interp, lines, line_start, i, running, unsupported)
                i += 1
        if nxt >= n:
            break
        i = nxt
        raw = lines[i]
        s = raw[:-1] if raw.endswith("\r") else raw
        blk = lexer.lex(s, int(line_start[i]), i + 1)
        i += 1
        if blk.percent:
            percent_count += 1
            if percent_count >= 2 and running:
                running = False
                lexer.lenient = True
            continue
        if not running:
            continue
        try:
            interp.execute(blk)
        except Unmodelled as exc:
            unsupported = (exc.line, exc.problem)
            running = False
            lexer.lenient = True
            continue
        if interp.ended:
            running = False
            lexer.lenient = True
    return _finish(p, text, interp, unsupported, default_units)


def _finish(p: Path, text: str, interp: _Interpreter, unsupported: tuple[int, str] | None, default_units: str
            ) -> Program:
    units = interp.st.units_seen or default_units
    if interp.nurbs is not None and unsupported is None:
        # LinuxCNC drops a block M2 ends (measured) and refuses a file that ends without M2 or %
        unsupported = (interp.nurbs.line, "the G5.2 NURBS block is not closed by G5.3 before the program ends")
    return Program(path=p, text=text, dialect=interp.dialect, units=units, moves=interp.builder.build(), name=p.stem,
                   warnings=interp.warnings, unsupported=unsupported, trailing_dwell_s=interp.builder.pending_dwell_s,
                   span_resolver=resolve_fast_spans)



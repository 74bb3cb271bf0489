"""Heidenhain Klartext (TNC conversational) reader and writer.

Reading happens in two layers.

Lexical layer
    The text is split into lines on ``"\\n"`` only (a trailing ``"\\r"`` is
    part of the line ending, a stray CR inside a line is just a character);
    lines ending in ``~`` are joined with the next one into one block; every
    block is parsed into a small record that keeps the character span of each
    coordinate number. Syntax errors raise :class:`~ilcnc.errors.ProgramError`
    naming the line. The whole file is always lexed, so a syntax error is
    reported even after a construct the interpreter does not model.

Interpretation
    The blocks are executed as the control would: Q parameters (``FN 0..8``,
    ``FN 13``, formulas), conditional jumps (``FN 9..12``), label calls and
    repeats, datum shift (cycle 7), straight lines, circles (``CC``/``C``,
    ``CR``, ``CT``, polar ``LP``/``CP``), rounding and chamfers (``RND``,
    ``CHF``), tangential and normal approach / departure (``APPR``/``DEP`` LT
    and LN). Every motion goes into a :class:`~ilcnc.program.model.MoveTable`
    in execution order. A construct that cannot be evaluated faithfully (values
    read from the machine, tilted or mirrored frames, cycles whose motion is
    not modelled, ...) stops the interpretation and is recorded in
    :attr:`~ilcnc.program.model.Program.unsupported`; the moves read so far
    are kept.

Conventions
-----------
* Positions start at (0, 0, 0) in the program frame (the control's position
  before the program is unknown). Unprogrammed axes do not move.
* ``offset_mm`` is the datum shift of cycle 7 (absolute or incremental);
  ``end_mm - offset_mm`` is what the program wrote.
* ``M91``/``M92`` coordinates are machine coordinates; they are recorded as
  written (like G-code ``G53``: the axes of the block get offset 0) and the
  move carries ``FLAG_MACHINE``.
* A command (the G01 equivalent, index k) is an ``L`` with a feed (not
  ``FMAX``) whose X/Y/Z words are plain numbers, that runs exactly once, is
  not ``M91``/``M92``, does not touch a helper move of ``APPR``/``RND``/
  ``CHF``/``DEP`` (its end or direction shapes it) and is followed by a move
  whose words can absorb a changed start (not polar, parametric or repeated). When the interpretation stopped early, no
  move after the first label that a call or jump can reach is a command (it
  might run again).
* ``CC`` spans go to the first ``C``/``CP`` after it (an incremental ``CC``
  only when no move lies between); later arcs around the same pole have
  ``center_mm`` but no centre spans.
* ``RND`` and ``CHF`` are modelled between two straight lines in the working
  plane; ``APPR``/``DEP`` ``LT`` and ``LN`` in the working plane. Their helper
  moves carry ``FLAG_DERIVED``. Other cases stop the interpretation.
* ``CALL LBL n`` runs the label once, ``CALL LBL n REP r`` jumps to it r
  times (a section repeat therefore runs r + 1 times); a subprogram returns at
  ``LBL 0``. Moves of text that ran more than once get ``FLAG_REPEATED``.
* Q parameters that are read from the control (``FN 18``), set by a caller or
  the tool table are unknown; an unknown value stops the interpretation only
  where it is used for a position, a jump or a repeat count.
* The old fixed cycles 1-5, 17 and 18 return the tool to where they started;
  their calls (``CYCL CALL``, ``M99``, ``M89``) are recorded as warnings, their
  internal motion is not in the table. Every other cycle call stops the
  interpretation, as do mirrored, rotated, scaled or tilted frames when a move
  is made in them (cycles 8, 10, 11, 19, 26, ``PLANE``, ``M128``).
* In inch programs (``BEGIN PGM .. INCH``) lengths and feeds are read as
  inch and inch/min and converted to mm and mm/min.
* Cycle 32 (``CYCL DEF 32.0 TOLERANZ`` / ``TOLERANCE``, ``CYCL DEF 32.1 T0.02``) sets the
  path tolerance of the moves after it (``MoveTable.blend_tol_mm``, mm; ``T0`` is an exact
  path, stop at every corner); a ``32.1`` without ``T`` resets it to the machine's (the
  profile's) tolerance. ``32.2`` (HSC mode, rotary tolerance ``TA``) is read and ignored.
* Cycle 9 (``CYCL DEF 9.1 DWELL 1.5``, ``V.ZEIT``, a Q parameter) and ``FUNCTION DWELL TIME`` (s) or ``REV``
  (spindle revolutions at the last ``TOOL CALL``'s S) dwell before the next move (``MoveTable.dwell_s``; after
  the last move: ``Program.trailing_dwell_s``); a negative time stops the interpretation with its line.
* Runs of plain ``L`` blocks (no M word) are read with numpy; everything
  else block by block. Both give the same table.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ilcnc.errors import ProgramError
from ilcnc.program.heidenhain_expr import qget
from ilcnc.program.heidenhain_lexer import (
    AXIS_INDEX,
    K_APPR,
    K_BEGIN,
    K_C,
    K_CALL_LBL,
    K_CALL_PGM,
    K_CC,
    K_CHF,
    K_CP,
    K_CR,
    K_CT,
    K_CYCL_CALL,
    K_CYCL_DEF,
    K_DEP,
    K_END,
    K_FASTL,
    K_FN_ARITH,
    K_FN_ERROR,
    K_FN_JUMP,
    K_FN_OTHER,
    K_FN_SYSREAD,
    K_L,
    K_LBL,
    K_LOOSE,
    K_LP,
    K_M,
    K_PLANE,
    K_Q,
    K_QS,
    K_RND,
    K_RUN,
    K_STOP,
    K_TOOL_CALL,
    K_TOOL_DEF,
    RCOMP_CODE,
    RCOMP_NAME,
    Block,
    KlartextLexer,
    Motion,
    Run,
    Stop,
    cycle_name,
    dwell_value,
    fast_motion,
    ffill,
)
from ilcnc.program.model import (
    BLEND_PROFILE,
    FLAG_CUTTER_COMP,
    FLAG_DERIVED,
    FLAG_MACHINE,
    FLAG_PARAMETRIC,
    FLAG_POLAR,
    FLAG_POSITION_READ,
    FLAG_REPEATED,
    MAX_ARC_TURNS,
    MOVE_ARC_CCW,
    MOVE_ARC_CW,
    MOVE_LINE,
    MOVE_RAPID,
    PLANE_AXES,
    PLANE_XY,
    PLANE_XZ,
    PLANE_YZ,
    MoveTable,
    MoveTableBuilder,
    Program,
    arc_off_circle,
    decode_source,
    looks_binary,
)
from ilcnc.units import MM_PER_INCH

__all__ = ["read_heidenhain"]

#: Blocks executed before the interpreter gives up on a loop.
MAX_BLOCKS = 600_000
#: Blocks executed without any motion before the interpreter gives up on a loop.
MAX_IDLE_BLOCKS = 100_000
#: Moves produced before the interpreter gives up.
MAX_MOVES = 100_000
#: Difference of start and end radius of a C above which a warning is given, mm.
ARC_TOLERANCE_MM = 0.01
#: Deepest nesting of label calls (the TNC allows far fewer).
MAX_CALL_DEPTH = 64

_NAN = float("nan")
_NAN3 = (_NAN, _NAN, _NAN)
_NONE3 = (-1, -1, -1)
_ZERO3 = (0, 0, 0)
_FALSE3 = (False, False, False)

# (first, second, normal) axis of each plane; angles are measured from the first axis
_TOOL_AXIS_PLANE = {2: PLANE_XY, 1: PLANE_XZ, 0: PLANE_YZ}
_PAIR_PLANE = {frozenset((0, 1)): PLANE_XY, frozenset((0, 2)): PLANE_XZ, frozenset((1, 2)): PLANE_YZ}

# old fixed cycles that end where they started (the tool returns to the starting position)
_RETURNING_CYCLES = frozenset((1, 2, 3, 4, 5, 17, 18))
# cycles that act when defined (never called)
_DEF_ACTIVE = frozenset((7, 8, 9, 10, 11, 13, 14, 19, 20, 26, 32, 247))

# --------------------------------------------------------------------------------------------
# interpreter
# --------------------------------------------------------------------------------------------
# fields of a move record (a list, so a held move can still be shortened by RND / CHF)
(R_KIND, R_LINE, R_START, R_END, R_FEED, R_OFF, R_CEN, R_PLANE, R_TURNS, R_CORR, R_FLAGS, R_WS, R_WE, R_WD,
 R_WST, R_WI, R_CS, R_CE, R_CD, R_CST, R_CI, R_INS) = range(22)
_EPS = 1e-9
_NEVER_SET = "is never set in this program (its value comes from the control or a calling program)"
_LOOSE_STOP = {
    "TCH PROBE": "touch probe cycles move the tool; their motion is not modelled",
    "FPOL": "FK free contour programming is not modelled",
    "FL": "FK free contour programming is not modelled",
    "FLT": "FK free contour programming is not modelled",
    "FC": "FK free contour programming is not modelled",
    "FCT": "FK free contour programming is not modelled",
    "FSELECT": "FK free contour programming is not modelled",
    "LN": "LN blocks (3-D tool compensation with surface normals) are not modelled",
    "CALL SELECTED PGM": "CALL SELECTED PGM: the called program is not read",
    "SQL": "SQL functions set Q parameters from tables; their values are not known",
    "PRESET": "PRESET changes the workpiece datum; the new datum is not known",
}


def _rec(kind: int, line: int, start: list[float], end: list[float], feed: float, off: list[float],
         plane: int, flags: int) -> list:
    """A move record with no word spans (derived moves)."""
    return [kind, line, start, end, feed, tuple(off), _NAN3, plane, 1, False, flags, _NONE3, _NONE3, _ZERO3,
            _ZERO3, _FALSE3, _NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3, -1]


def _spans(mo: Motion) -> tuple[list[int], list[int], list[int], list[int], list[bool]]:
    ws = [-1, -1, -1]
    we = [-1, -1, -1]
    wd = [0, 0, 0]
    wst = [0, 0, 0]
    wi = [False, False, False]
    for ax, inc, _v, s, e, dec, style in mo.coords:
        ws[ax] = s
        we[ax] = e
        wd[ax] = dec
        wst[ax] = style
        wi[ax] = inc
    return ws, we, wd, wst, wi


class _Interp:
    """Executes the lexed blocks and collects the moves."""

    def __init__(self, lex: KlartextLexer, unit: float) -> None:
        self.path = lex.path
        self.text = lex.text
        self._tb: np.ndarray | None = None
        self.blocks = lex.blocks
        self.labels = lex.labels
        self.unit = unit
        self.b = MoveTableBuilder()
        self.q: dict[str, float] = {}
        self.unknown: dict[str, tuple[str, str]] = {}
        self.pos = [0.0, 0.0, 0.0]
        self.off = [0.0, 0.0, 0.0]
        self.feed = _NAN
        self.tool_feed = _NAN
        self.spindle = _NAN
        self.rcomp = "R0"
        self.plane = PLANE_XY
        self.pole: tuple[list[float], int] | None = None
        self.cc_spans: tuple | None = None
        self.dr = 0
        self.rot = 0.0
        self.frame: dict[str, tuple[int, str]] = {}
        self.cycle: tuple[int, str, int] | None = None
        self.m89 = False
        self.cycle_calls: dict[int, list] = {}
        self.stack: list[list[int]] = []
        self.pending: list | None = None
        self.pending_tol = BLEND_PROFILE  # path tolerance when the held move was programmed
        self.dwell_s = 0.0  # dwell met since the last move (after the held one): the next move's, s
        self.tol = BLEND_PROFILE  # cycle 32 tolerance (MoveTable.blend_tol_mm), mm
        self.corner: tuple[str, float, float, int] | None = None
        self.appr: tuple | None = None
        self.last: list | None = None
        self.tools: dict[float, float] = {}
        self.tool: float | None = None
        self.warnings: list[str] = []
        self.warned: set[str] = set()
        self.unsupported: tuple[int, str] | None = None
        self.n_moves = 0
        self.counts = [0] * len(self.blocks)
        self.handlers: dict[int, Callable[[Block, int], int | None]] = {
            K_BEGIN: self.h_nothing, K_END: self.h_end, K_L: self.h_l, K_LP: self.h_lp, K_C: self.h_c,
            K_CC: self.h_cc, K_CR: self.h_cr, K_CT: self.h_ct, K_CP: self.h_cp, K_RND: self.h_corner,
            K_CHF: self.h_corner, K_APPR: self.h_appr, K_DEP: self.h_dep, K_M: self.h_m, K_STOP: self.h_m,
            K_FN_ARITH: self.h_assign, K_Q: self.h_assign, K_FN_JUMP: self.h_jump, K_FN_ERROR: self.h_fn_error,
            K_FN_SYSREAD: self.h_sysread, K_FN_OTHER: self.h_fn_other, K_QS: self.h_qs, K_LBL: self.h_lbl,
            K_CALL_LBL: self.h_call_lbl, K_CALL_PGM: self.h_call_pgm, K_CYCL_DEF: self.h_cycl_def,
            K_CYCL_CALL: self.h_cycl_call, K_TOOL_CALL: self.h_tool_call, K_TOOL_DEF: self.h_tool_def,
            K_PLANE: self.h_plane, K_LOOSE: self.h_loose, K_FASTL: self.h_fastl, K_RUN: self.h_run,
        }
        self.executed = 0
        self.moved_at = 0
        self.loop_saved: tuple | None = None
        self.loop_power = 1
        self.loop_count = 0

    def text_bytes(self) -> np.ndarray:
        if self._tb is None:
            self._tb = np.frombuffer(self.text.encode("latin-1"), dtype=np.uint8)
        return self._tb

    # ---- driver -------------------------------------------------------------------------------
    def run(self) -> None:
        blocks = self.blocks
        counts = self.counts
        handlers = self.handlers
        n = len(blocks)
        i = 0
        try:
            while i < n:
                blk = blocks[i]
                counts[i] += 1
                self.executed += 1
                if self.executed > MAX_BLOCKS:
                    raise Stop(blk.line, f"loop does not terminate (more than {MAX_BLOCKS:,} blocks executed)")
                nxt = handlers[blk.kind](blk, i)
                if nxt is None:
                    i += 1
                elif nxt < 0:
                    break
                else:
                    if nxt <= i:
                        self.loop_check(nxt, blk.line)
                    i = nxt
            self.finish(blocks[min(i, n - 1)].line)
        except Stop as stop:
            self.unsupported = (stop.line, stop.problem)
            if self.corner is None and self.pending is not None:
                self.add(self.pending, self.pending_tol)
            self.pending = None
            self.flush_dwell()
        self.cycle_warnings()

    def control_state(self) -> tuple:
        """Everything that steers the program flow besides the Q parameters (positions never do)."""
        feed = None if self.feed != self.feed else self.feed
        tool_feed = None if self.tool_feed != self.tool_feed else self.tool_feed
        return (tuple(tuple(f) for f in self.stack), tuple(self.off), feed, tool_feed, self.plane, self.rcomp,
                self.cycle, tuple(sorted(self.frame)), self.m89, self.dr, self.rot, self.tool,
                None if self.pole is None else (tuple(self.pole[0]), self.pole[1]),
                self.corner is None, self.appr is None, self.pending is None)

    def loop_check(self, target: int, line: int) -> None:
        """Detect a program that jumps back into a state it was in before (Brent's cycle detection).

        Control flow depends only on the Q parameters and the state of
        :meth:`control_state`, so coming back to the same block in the same
        state means the program repeats itself forever.
        """
        if self.executed - self.moved_at > MAX_IDLE_BLOCKS:
            raise Stop(line, f"loop does not terminate (more than {MAX_IDLE_BLOCKS:,} blocks without a move)")
        saved = self.loop_saved
        if (saved is not None and saved[0] == target and saved[1] == self.q and saved[2] == self.unknown
                and saved[3] == self.control_state()):
            raise Stop(line, f"endless loop: the program jumps back to line {self.blocks[target].line} in the "
                              "same state again and again")
        self.loop_count += 1
        if self.loop_count >= self.loop_power:
            self.loop_saved = (target, dict(self.q), dict(self.unknown), self.control_state())
            self.loop_power *= 2
            self.loop_count = 0

    def finish(self, line: int) -> None:
        if self.corner is not None:
            raise Stop(self.corner[3], f"{self.corner[0]} without a following contour element")
        if self.appr is not None:
            raise Stop(self.appr[0], "APPR without a following contour element")
        if self.pending is not None:
            self.add(self.pending, self.pending_tol)
            self.pending = None
        self.flush_dwell()

    def warn(self, key: str, text: str) -> None:
        if key not in self.warned:
            self.warned.add(key)
            self.warnings.append(text)

    # ---- values -------------------------------------------------------------------------------
    def num(self, v: Any, line: int) -> float:
        """Evaluate a word value (float or Q closure); unknown values stop the interpretation."""
        if type(v) is float:
            return v
        try:
            r = v(self.q)
        except KeyError as exc:
            raise Stop(line, self.unknown_text(str(exc.args[0]))) from None
        except (ZeroDivisionError, ValueError, OverflowError) as exc:
            raise Stop(line, f"Q parameter arithmetic fails ({exc}); the control stops here") from None
        if not math.isfinite(r):
            raise Stop(line, f"Q parameter arithmetic gives {r}; the control stops here")
        return float(r)

    def root(self, key: str) -> tuple[str, str]:
        return self.unknown.get(key, (key, _NEVER_SET))

    def unknown_text(self, key: str) -> str:
        root, why = self.root(key)
        if root == key:
            return f"{key} is not known: it {why}"
        return f"{key} is not known: it depends on {root}, which {why}"

    def assign(self, key: str, f: Callable, line: int) -> None:
        try:
            r = f(self.q)
        except KeyError as exc:
            self.q.pop(key, None)
            self.unknown[key] = self.root(str(exc.args[0]))
            return
        except (ZeroDivisionError, ValueError, OverflowError) as exc:
            raise Stop(line, f"{key}: Q parameter arithmetic fails ({exc}); the control stops here") from None
        if not math.isfinite(r):
            raise Stop(line, f"{key}: Q parameter arithmetic gives {r}; the control stops here")
        self.q[key] = float(r)

    def set_unknown(self, key: str, why: str) -> None:
        self.q.pop(key, None)
        self.unknown[key] = (key, why)

    # ---- move output --------------------------------------------------------------------------
    def add(self, r: list, tol: float | None = None) -> None:
        """Append move record ``r``; ``tol`` is its path tolerance (default: the one now in force)."""
        self.moved_at = self.executed
        self.n_moves += 1
        if self.n_moves > MAX_MOVES:
            raise Stop(r[R_LINE], f"more than {MAX_MOVES:,} moves; the program is not interpreted further")
        self.b.add(
            r[R_KIND], r[R_LINE], tuple(r[R_START]), tuple(r[R_END]), feed=r[R_FEED], unit=self.unit,
            offset=r[R_OFF], center=tuple(r[R_CEN]), plane=r[R_PLANE], turns=r[R_TURNS], correctable=r[R_CORR],
            flags=r[R_FLAGS], wstart=tuple(r[R_WS]), wend=tuple(r[R_WE]), wdec=tuple(r[R_WD]),
            wstyle=tuple(r[R_WST]), winc=tuple(r[R_WI]), cstart=tuple(r[R_CS]), cend=tuple(r[R_CE]),
            cdec=tuple(r[R_CD]), cstyle=tuple(r[R_CST]), cinc=tuple(r[R_CI]), insert_at=r[R_INS],
            blend_tol=self.tol if tol is None else tol,
        )

    def emit(self, r: list, hold: bool = False) -> None:
        """Append a move (after the helper moves of a pending APPR / RND / CHF)."""
        pre: list[list] = []
        if self.appr is not None:
            pre = self.resolve_appr(r)
        if self.corner is not None:
            pre = self.resolve_corner(r)
        if self.pending is not None:
            self.add(self.pending, self.pending_tol)
            self.pending = None
        self.flush_dwell()
        for p in pre:
            self.add(p)
        if hold:
            self.pending = r
            self.pending_tol = self.tol
        else:
            self.add(r)
        self.last = r
        self.pos = list(r[R_END])

    def flush_dwell(self) -> None:
        """Hand the dwell met since the last move to the table (the next move's ``dwell_s``; after the last move:
        the trailing dwell). Called once the held move, which the dwell follows, is in the table."""
        if self.dwell_s:
            self.b.add_dwell(self.dwell_s)
            self.dwell_s = 0.0

    def dwell(self, value: Any, line: int, what: str, per_rev: bool = False) -> None:
        """A dwell of ``value`` seconds (``per_rev``: spindle revolutions) before the next move."""
        if value is None:
            raise Stop(line, f"{what} without a dwell time")
        t = self.num(value, line)
        if t < 0.0:
            raise Stop(line, f"{what} with a negative dwell time {t:g}")
        if per_rev:
            if not self.spindle > 0.0:
                self.warn(f"rev{line}", f"line {line}: {what}: a dwell in spindle revolutions without a known spindle"
                                        " speed is not modelled (no stand-still)")
                return
            t *= 60.0 / self.spindle
        self.dwell_s += t

    def check_frame(self, line: int) -> None:
        if self.frame:
            what, (dline, desc) = next(iter(self.frame.items()))
            _ = what
            raise Stop(line, f"{desc} at line {dline} is active: positions in a transformed frame are not modelled")

    def comp_flags(self, rcomp: str | None) -> int:
        if rcomp is not None and rcomp not in ("RL", "RR", "R0"):
            return FLAG_CUTTER_COMP  # paraxial R+ / R-
        if rcomp is not None:
            self.rcomp = rcomp
        return FLAG_CUTTER_COMP if self.rcomp in ("RL", "RR") else 0

    def set_feed(self, f: Any, line: int) -> bool:
        """Apply a feed word; True for FMAX (rapid, this block only)."""
        if f is None:
            return False
        if f == "MAX":
            return True
        if f == "AUTO":
            self.feed = self.tool_feed
            return False
        if type(f) is tuple:
            value = self.feed_value(f[1], line)
            if f[0] == "U" and math.isfinite(self.spindle):
                self.feed = value * self.spindle
            else:
                self.warn("fz", f"line {line}: feed per {'revolution' if f[0] == 'U' else 'tooth'} (F{f[0]}) "
                                "is not converted to mm/min; feed unknown")
                self.feed = _NAN
            return False
        value = self.feed_value(f, line)
        if value < 0:
            raise Stop(line, f"negative feed rate F{value / self.unit:g}")
        self.feed = value
        return False

    def feed_value(self, f: Any, line: int) -> float:
        if type(f) is float:
            return f * self.unit
        try:
            return self.num(f, line) * self.unit
        except Stop as stop:
            self.warn("feedq", f"line {line}: feed unknown ({stop.problem})")
            return _NAN

    def target(self, mo: Motion, line: int, machine: bool = False) -> tuple[list[float], bool]:
        pos = self.pos
        off = self.off
        unit = self.unit
        end = [pos[0], pos[1], pos[2]]
        param = False
        for ax, inc, v, _s, _e, _d, _st in mo.coords:
            if type(v) is not float:
                v = self.num(v, line)
                param = True
            if inc:
                end[ax] = pos[ax] + v * unit
            elif machine:
                end[ax] = v * unit
            else:
                end[ax] = v * unit + off[ax]
        return end, param

    def m_pre(self, ms: list[int], line: int) -> bool:
        machine = False
        for m in ms:
            if m in (91, 92):
                machine = True
                self.warn("m91", f"line {line}: M91/M92 positions are machine coordinates; recorded as written "
                                 "(moves flagged FLAG_MACHINE)")
            elif m == 128:
                self.frame["tcpm"] = (line, "M128 (tool centre point management)")
            elif m == 129:
                self.frame.pop("tcpm", None)
            elif m == 140:
                raise Stop(line, "M140 retracts along the tool axis to a machine-dependent position")
            elif m == 104:
                raise Stop(line, "M104 re-activates a datum that is not known")
        return machine

    def m_post(self, ms: list[int], line: int, moved: bool) -> bool:
        """Cycle calls and program end after the block; True when the program ends."""
        called = False
        for m in ms:
            if m == 99:
                self.cycle_call(line)
                self.m89 = False
                called = True
            elif m == 89:
                self.m89 = True
        if self.m89 and moved and not called:
            self.cycle_call(line)
        return any(m in (2, 30) for m in ms)

    # ---- straight lines -----------------------------------------------------------------------
    def h_l(self, blk: Block, i: int) -> int | None:
        mo: Motion = blk.data
        line = blk.line
        machine = self.m_pre(mo.ms, line) if mo.ms else False
        rapid = self.set_feed(mo.feed, line)
        flags = self.comp_flags(mo.rcomp)
        if mo.rotary:
            self.warn("rot", f"line {line}: rotary axis words (A, B, C, U, V, W) are read but not modelled")
        moved = False
        if mo.coords:
            self.check_frame(line)
            end, param = self.target(mo, line, machine)
            if param:
                flags |= FLAG_PARAMETRIC
            if machine:
                flags |= FLAG_MACHINE
            ws, we, wd, wst, wi = _spans(mo)
            kind = MOVE_RAPID if rapid else MOVE_LINE
            if not rapid:
                self.check_feed(line)
            # a block with a rotary or parallel axis word is never corrected (as in G-code): what it does with
            # that axis is not modelled
            corr = not (rapid or param or machine or mo.rotary)
            off = tuple(self.off) if not machine else tuple(0.0 if ws[a] >= 0 else self.off[a] for a in range(3))
            self.emit([kind, line, self.pos, end, _NAN if rapid else self.feed, off, _NAN3, self.plane,
                       1, corr, flags, ws, we, wd, wst, wi, _NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3, mo.insert_at],
                      blk.hold)
            moved = True
        if mo.ms and self.m_post(mo.ms, line, moved):
            return -1
        if self.m89 and moved and not mo.ms:
            self.cycle_call(line)
        return None

    def h_fastl(self, blk: Block, i: int) -> int | None:
        blk.data = fast_motion(blk.data, blk.pos, True)
        blk.kind = K_L
        return self.h_l(blk, i)

    def h_run(self, blk: Block, i: int) -> int | None:
        """Execute a run of plain L blocks with numpy (falls back to one block when a state needs care)."""
        run: Run = blk.data
        n = len(run.lines)
        self.executed += n - 1
        if self.executed > MAX_BLOCKS:
            raise Stop(run.lines[0], f"loop does not terminate (more than {MAX_BLOCKS:,} blocks executed)")
        if self.appr is not None or self.corner is not None or self.m89 or self.frame:
            for b in run.blocks():
                self.h_l(b, i)
            return None
        c = run.columns(self.text_bytes())
        if c is None:
            for b in run.blocks():
                self.h_l(b, i)
            return None
        unit = self.unit
        has, inc, vals = c["has"], c["inc"], c["vals"] * unit
        ends = np.empty((n, 3))
        for a in range(3):
            absolute = has[:, a] & ~inc[:, a]
            csum = np.cumsum(np.where(has[:, a] & inc[:, a], vals[:, a], 0.0))
            idx = np.maximum.accumulate(np.where(absolute, np.arange(n), -1))
            safe = np.maximum(idx, 0)
            target = vals[safe, a] + self.off[a]
            ends[:, a] = np.where(idx >= 0, target + (csum - csum[safe]), self.pos[a] + csum)
        rapid = c["rapid"]
        fval = c["fval"] * unit
        feed = ffill(fval, ~np.isnan(fval), self.feed)
        rcomp = ffill(c["rcomp"], c["rcomp"] > 0, RCOMP_CODE[self.rcomp])
        sel = has.any(axis=1)
        m = int(sel.sum())
        if self.pending is not None:
            self.add(self.pending, self.pending_tol)
            self.pending = None
        self.feed = float(feed[-1])
        if m:
            self.flush_dwell()
        self.rcomp = RCOMP_NAME[int(rcomp[-1])]
        if m == 0:
            return None
        self.n_moves += m
        self.moved_at = self.executed
        if self.n_moves > MAX_MOVES:
            raise Stop(run.lines[0], f"more than {MAX_MOVES:,} moves; the program is not interpreted further")
        starts = np.vstack((np.array(self.pos)[None, :], ends[:-1]))[sel]
        ends_sel = ends[sel]
        kind = np.where(rapid, MOVE_RAPID, MOVE_LINE)[sel].astype(np.int8)
        is_line = kind == MOVE_LINE
        self.b.add_table(MoveTable(
            kind=kind, line=c["line"][sel], start_mm=starts, end_mm=ends_sel, center_mm=np.full((m, 3), np.nan),
            offset_mm=np.tile(np.array(self.off), (m, 1)), plane=np.full(m, self.plane, dtype=np.int8),
            turns=np.ones(m, dtype=np.int16), feed_mm_min=np.where(rapid, np.nan, feed)[sel],
            unit_mm=np.full(m, unit), command=np.where(is_line, self.b.n_commands + np.cumsum(is_line) - 1, -1)
            .astype(np.int32), flags=np.where(rcomp >= 2, FLAG_CUTTER_COMP, 0)[sel].astype(np.int16),
            word_start=c["ws"][sel], word_end=c["we"][sel], word_decimals=c["dec"][sel],
            word_style=c["style"][sel], word_incremental=c["inc"][sel] & has[sel],
            center_start=np.full((m, 3), -1, dtype=np.int64), center_end=np.full((m, 3), -1, dtype=np.int64),
            center_decimals=np.zeros((m, 3), dtype=np.int8), center_style=np.zeros((m, 3), dtype=np.int8),
            center_incremental=np.zeros((m, 3), dtype=bool), insert_at=c["ins"][sel],
            blend_tol_mm=np.full(m, self.tol),
        ))
        self.pos = [float(x) for x in ends_sel[-1]]
        self.last = _rec(int(kind[-1]), int(c["line"][sel][-1]), [float(x) for x in starts[-1]], list(self.pos),
                         self.feed, self.off, self.plane, 0)
        return None

    def h_m(self, blk: Block, i: int) -> int | None:
        mo: Motion = blk.data
        self.m_pre(mo.ms, blk.line)
        self.set_feed(mo.feed, blk.line)
        if self.m_post(mo.ms, blk.line, False):
            return -1
        return None

    # ---- polar, circles -----------------------------------------------------------------------
    def need_pole(self, line: int, what: str) -> tuple[list[float], int]:
        if self.pole is None:
            raise Stop(line, f"{what} without a circle centre / pole CC")
        return self.pole

    def polar_start(self, pole: list[float], plane: int) -> tuple[float, float]:
        i0, i1, _i2 = PLANE_AXES[plane]
        ra = self.pos[i0] - self.off[i0] - pole[i0]
        rb = self.pos[i1] - self.off[i1] - pole[i1]
        return math.hypot(ra, rb), math.degrees(math.atan2(rb, ra))

    def centre(self, pole: list[float], plane: int) -> list[float]:
        i0, i1, i2 = PLANE_AXES[plane]
        c = [0.0, 0.0, 0.0]
        c[i0] = pole[i0] + self.off[i0]
        c[i1] = pole[i1] + self.off[i1]
        c[i2] = self.pos[i2]
        return c

    def direction(self, mo: Motion, line: int, what: str) -> int:
        if mo.dr:
            self.dr = mo.dr
        if not self.dr:
            raise Stop(line, f"{what} without a direction of rotation DR+ / DR-")
        return self.dr

    def take_cc_spans(self) -> tuple:
        spans = self.cc_spans
        self.cc_spans = None
        if spans is None:
            return (_NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3)
        cs, ce, cd, cst, ci, at = spans
        if any(ci) and at != self.pos:
            return (_NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3)
        return cs, ce, cd, cst, ci

    def h_cc(self, blk: Block, i: int) -> int | None:
        mo: Motion = blk.data
        line = blk.line
        prog = [self.pos[a] - self.off[a] for a in range(3)]
        axes = set()
        cs, ce, cd, cst, ci = _spans(mo)
        for ax, inc, v, _s, _e, _d, _st in mo.coords:
            v = self.num(v, line) * self.unit
            prog[ax] = prog[ax] + v if inc else v
            axes.add(ax)
        plane = _PAIR_PLANE.get(frozenset(axes), self.plane) if len(axes) == 2 else self.plane
        if len(axes) > 2:
            raise Stop(line, "CC with three coordinates: the plane of the circle is ambiguous")
        if not {PLANE_AXES[plane][0], PLANE_AXES[plane][1]} <= axes:
            # a pole coordinate not given is the last programmed position's: the move ending there is never corrected
            if self.pending is not None:
                at = -1 if self.pending[R_FLAGS] & FLAG_POLAR or self.pending[R_CORR] is False else self.pending[R_LINE]
                self.pending[R_FLAGS] |= FLAG_POSITION_READ
            else:
                at = self.b.freeze_last()
            if at > 0:
                self.warnings.append(f"line {line}: CC without both pole coordinates takes the current position: the"
                                     f" L at line {at} ending there is never corrected")
        self.pole = (prog, plane)
        self.cc_spans = (cs, ce, cd, cst, ci, list(self.pos))
        return None

    def arc_rec(self, kind: int, line: int, end: list[float], centre: list[float], plane: int, flags: int,
                mo: Motion, turns: int = 1, cc: tuple | None = None, insert: bool = True) -> list:
        ws, we, wd, wst, wi = _spans(mo)
        cs, ce, cd, cst, ci = cc if cc is not None else (_NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3)
        return [kind, line, self.pos, end, self.feed, tuple(self.off), centre, plane, turns, False, flags,
                ws, we, wd, wst, wi, cs, ce, cd, cst, ci, mo.insert_at if insert else -1]

    def motion_prologue(self, blk: Block) -> tuple[Motion, int, bool, int]:
        mo: Motion = blk.data
        line = blk.line
        machine = self.m_pre(mo.ms, line) if mo.ms else False
        if machine:
            raise Stop(line, "M91/M92 on a circle or polar move is not modelled")
        rapid = self.set_feed(mo.feed, line)
        if not rapid:
            self.check_feed(line)
        flags = self.comp_flags(mo.rcomp)
        if mo.rotary:
            self.warn("rot", f"line {line}: rotary axis words (A, B, C, U, V, W) are read but not modelled")
        self.check_frame(line)
        return mo, line, rapid, flags

    def check_feed(self, line: int) -> None:
        """A feed move needs a positive feed (the G-code reader refuses the same)."""
        if self.feed == 0.0:
            raise Stop(line, "feed move with zero feed rate (F0)")

    def epilogue(self, mo: Motion, line: int) -> int | None:
        if mo.ms and self.m_post(mo.ms, line, True):
            return -1
        if self.m89 and not mo.ms:
            self.cycle_call(line)
        return None

    def h_c(self, blk: Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        dr = self.direction(mo, line, "C")
        pole, plane = self.need_pole(line, "C")
        end, param = self.target(mo, line)
        if param:
            flags |= FLAG_PARAMETRIC
        kind = MOVE_ARC_CCW if dr > 0 else MOVE_ARC_CW
        centre = self.centre(pole, plane)
        self.check_radius(self.pos, end, centre, plane, line)
        r = self.arc_rec(kind, line, end, centre, plane, flags, mo, cc=self.take_cc_spans())
        if rapid:
            r[R_FEED] = _NAN
        self.emit(r, blk.hold)
        return self.epilogue(mo, line)

    def check_radius(self, start: list[float], end: list[float], centre: list[float], plane: int, line: int) -> None:
        """Refuse a C whose centre is its start, or whose end point is off the circle through its start by more
        than the G-code reader allows an arc (LinuxCNC's limits: 0.028 mm and 0.1 % of the radius); warn from
        ``ARC_TOLERANCE_MM`` on (the TNC may reject it)."""
        i0, i1, _i2 = PLANE_AXES[plane]
        r0 = math.hypot(start[i0] - centre[i0], start[i1] - centre[i1])
        r1 = math.hypot(end[i0] - centre[i0], end[i1] - centre[i1])
        if r0 < 1e-9:
            raise Stop(line, "circle with zero radius (the centre CC is the start point)")
        off = abs(r1 - r0)
        if arc_off_circle(r0, r1):  # the mm limit, as before for MM and INCH programs alike
            raise Stop(line, f"the end point of C is {off:.4f} mm off the circle (radius {r0:.4f} mm at the start,"
                              f" {r1:.4f} mm at the end)")
        if off > ARC_TOLERANCE_MM:
            self.warnings.append(f"line {line}: the end point of C is {off:.4f} mm off the circle "
                                 f"(radius {r0:.4f} mm at the start, {r1:.4f} mm at the end)")

    def h_cr(self, blk: Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        dr = self.direction(mo, line, "CR")
        plane = self.plane
        i0, i1, i2 = PLANE_AXES[plane]
        radius = self.num(mo.radius, line) * self.unit
        end, param = self.target(mo, line)
        if param:
            flags |= FLAG_PARAMETRIC
        start = self.pos
        if abs(end[i2] - start[i2]) > _EPS:
            raise Stop(line, "CR with a tool-axis move (helix) is not modelled")
        da, db = end[i0] - start[i0], end[i1] - start[i1]
        chord = math.hypot(da, db)
        if chord < 1e-9 or radius == 0:
            raise Stop(line, "CR with identical start and end point or zero radius: the circle is not defined")
        h2 = radius * radius - chord * chord / 4
        if h2 < 0:
            if -h2 > (1e-6 + 1e-6 * abs(radius)) * abs(radius):
                raise Stop(line, f"CR radius {abs(radius):g} mm is smaller than half the chord ({chord / 2:g} mm)")
            h2 = 0.0
        h = math.sqrt(h2)
        side = 1.0 if (dr > 0) == (radius > 0) else -1.0
        c = [0.0, 0.0, 0.0]
        c[i0] = start[i0] + da / 2 - side * h * db / chord
        c[i1] = start[i1] + db / 2 + side * h * da / chord
        c[i2] = start[i2]
        kind = MOVE_ARC_CCW if dr > 0 else MOVE_ARC_CW
        r = self.arc_rec(kind, line, end, c, plane, flags, mo)
        if rapid:
            r[R_FEED] = _NAN
        self.emit(r, blk.hold)
        return self.epilogue(mo, line)

    def end_tangent(self, r: list | None, line: int, what: str) -> tuple[float, float]:
        """Unit tangent of a move at its end, in the working plane."""
        if r is None:
            raise Stop(line, f"{what} needs a preceding contour element")
        return self._tangent(r, R_END, line, what, "after", "preceding")

    def start_tangent(self, r: list, line: int, what: str) -> tuple[float, float]:
        """Unit tangent of a move at its start, in the working plane."""
        return self._tangent(r, R_START, line, what, "before", "following")

    def _tangent(self, r: list, at: int, line: int, what: str, rel: str, which: str) -> tuple[float, float]:
        i0, i1, _i2 = PLANE_AXES[self.plane]
        if r[R_KIND] >= MOVE_ARC_CW:
            if r[R_PLANE] != self.plane:
                raise Stop(line, f"{what} {rel} an arc outside the working plane is not modelled")
            ra = r[at][i0] - r[R_CEN][i0]
            rb = r[at][i1] - r[R_CEN][i1]
            ta, tb = (-rb, ra) if r[R_KIND] == MOVE_ARC_CCW else (rb, -ra)
        else:
            ta = r[R_END][i0] - r[R_START][i0]
            tb = r[R_END][i1] - r[R_START][i1]
        n = math.hypot(ta, tb)
        if n < 1e-9:
            raise Stop(line, f"{what}: the {which} element has no direction in the working plane")
        return ta / n, tb / n

    def h_ct(self, blk: Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        plane = self.plane
        i0, i1, i2 = PLANE_AXES[plane]
        if self.corner is not None:
            raise Stop(line, "CT after RND/CHF is not modelled")
        ta, tb = self.end_tangent(self.last, line, "CT")
        end, param = self.target(mo, line)
        if param:
            flags |= FLAG_PARAMETRIC
        start = self.pos
        if abs(end[i2] - start[i2]) > _EPS:
            raise Stop(line, "CT with a tool-axis move (helix) is not modelled")
        da, db = end[i0] - start[i0], end[i1] - start[i1]
        denom = 2 * (-tb * da + ta * db)
        d2 = da * da + db * db
        if abs(denom) <= 1e-9 * math.sqrt(d2) or d2 < 1e-18:
            raise Stop(line, "CT end point lies on the tangent: no tangential arc")
        s = d2 / denom
        c = [0.0, 0.0, 0.0]
        c[i0] = start[i0] - s * tb
        c[i1] = start[i1] + s * ta
        c[i2] = start[i2]
        kind = MOVE_ARC_CCW if s > 0 else MOVE_ARC_CW
        r = self.arc_rec(kind, line, end, c, plane, flags, mo)
        if rapid:
            r[R_FEED] = _NAN
        self.emit(r, blk.hold)
        return self.epilogue(mo, line)

    def polar_values(self, mo: Motion, line: int, r0: float, a0: float) -> tuple[float | None, float | None, bool]:
        """(radius, angle or sweep, angle incremental) of the polar words; None when absent."""
        r = a = None
        inc_a = False
        if "PR" in mo.polar:
            v, inc = mo.polar["PR"]
            v = self.num(v, line) * self.unit
            r = r0 + v if inc else v
        if "PA" in mo.polar:
            v, inc_a = mo.polar["PA"]
            a = self.num(v, line)
        return r, a, inc_a

    def polar_param(self, mo: Motion) -> bool:
        return any(type(v) is not float for v, _inc in mo.polar.values())

    def h_lp(self, blk: Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        pole, plane = self.need_pole(line, "LP")
        i0, i1, i2 = PLANE_AXES[plane]
        if any(ax != i2 for ax, *_rest in mo.coords):
            raise Stop(line, "LP with a coordinate in the plane of the pole")
        r0, a0 = self.polar_start(pole, plane)
        r, a, inc_a = self.polar_values(mo, line, r0, a0)
        r = r0 if r is None else r
        a = a0 if a is None else (a0 + a if inc_a else a)
        end, param = self.target(mo, line)
        end[i0] = pole[i0] + self.off[i0] + r * math.cos(math.radians(a))
        end[i1] = pole[i1] + self.off[i1] + r * math.sin(math.radians(a))
        flags |= FLAG_POLAR
        if param or self.polar_param(mo):
            flags |= FLAG_PARAMETRIC
        ws, we, wd, wst, wi = _spans(mo)
        kind = MOVE_RAPID if rapid else MOVE_LINE
        self.emit([kind, line, self.pos, end, _NAN if rapid else self.feed, tuple(self.off), _NAN3, self.plane, 1,
                   False, flags, ws, we, wd, wst, wi, _NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3, -1], blk.hold)
        return self.epilogue(mo, line)

    def h_cp(self, blk: Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        dr = self.direction(mo, line, "CP")
        pole, plane = self.need_pole(line, "CP")
        i0, i1, i2 = PLANE_AXES[plane]
        if any(ax != i2 for ax, *_rest in mo.coords):
            raise Stop(line, "CP with a coordinate in the plane of the pole")
        r0, a0 = self.polar_start(pole, plane)
        if r0 < 1e-9:
            raise Stop(line, "CP starts at the pole: the circle is not defined")
        r, a, inc_a = self.polar_values(mo, line, r0, a0)
        if r is not None and abs(r - r0) > 1e-3:
            raise Stop(line, f"CP radius {r:g} differs from the distance to the pole {r0:g}: not a circle")
        if a is None:
            raise Stop(line, "CP without an angle PA / IPA")
        sweep = self.cp_sweep(a, inc_a, a0, dr, line)
        n = abs(sweep) / 360.0
        if n > MAX_ARC_TURNS:
            raise ProgramError(self.path, line, f"CP sweeps {n:,.0f} turns: at most {MAX_ARC_TURNS:,} turns of one arc or helix")
        full = abs(n - round(n)) < 1e-9 and round(n) >= 1
        turns = round(n) if full else math.floor(n) + 1
        end, param = self.target(mo, line)
        if full:
            end[i0], end[i1] = self.pos[i0], self.pos[i1]
        else:
            ang = math.radians(a0 + sweep)
            end[i0] = pole[i0] + self.off[i0] + r0 * math.cos(ang)
            end[i1] = pole[i1] + self.off[i1] + r0 * math.sin(ang)
        flags |= FLAG_POLAR
        if param or self.polar_param(mo):
            flags |= FLAG_PARAMETRIC
        kind = MOVE_ARC_CCW if sweep > 0 else MOVE_ARC_CW
        rec = self.arc_rec(kind, line, end, self.centre(pole, plane), plane, flags, mo, turns=turns,
                           cc=self.take_cc_spans(), insert=False)
        if rapid:
            rec[R_FEED] = _NAN
        self.emit(rec, blk.hold)
        return self.epilogue(mo, line)

    def cp_sweep(self, a: float, inc: bool, a0: float, dr: int, line: int) -> float:
        if inc:
            if a == 0:
                raise Stop(line, "CP with IPA+0: no circle")
            if (a > 0) != (dr > 0):
                raise Stop(line, "CP: the sign of IPA contradicts DR")
            return a
        delta = (a - a0) % 360.0
        if dr > 0:
            return delta if delta > 1e-9 else 360.0
        back = (a0 - a) % 360.0
        return -(back if back > 1e-9 else 360.0)

    # ---- rounding, chamfer, approach, departure --------------------------------------------------
    def h_corner(self, blk: Block, i: int) -> int | None:
        mo: Motion = blk.data
        line = blk.line
        what = "RND" if blk.kind == K_RND else "CHF"
        if self.pending is None or self.corner is not None:
            raise Stop(line, f"{what} must follow a contour element")
        value = self.num(mo.radius, line) * self.unit
        if value <= 0:
            raise Stop(line, f"{what} with a non-positive size {value:g}")
        feed = self.feed if mo.feed is None else self.feed_value(mo.feed, line)
        self.corner = (what, value, feed, line)
        return None

    def resolve_corner(self, nxt: list) -> list[list]:
        what, value, feed, line = self.corner  # type: ignore[misc]
        self.corner = None
        prev = self.pending
        if prev is None:
            raise Stop(line, f"{what} must follow a contour element")
        if prev[R_KIND] >= MOVE_ARC_CW or nxt[R_KIND] >= MOVE_ARC_CW:
            raise Stop(line, f"{what} next to a circular arc is not modelled")
        i0, i1, i2 = PLANE_AXES[self.plane]
        a, p, b = prev[R_START], prev[R_END], nxt[R_END]
        if abs(a[i2] - p[i2]) > _EPS or abs(b[i2] - p[i2]) > _EPS:
            raise Stop(line, f"{what} between lines that move the tool axis is not modelled")
        ua, ub = p[i0] - a[i0], p[i1] - a[i1]
        va, vb = b[i0] - p[i0], b[i1] - p[i1]
        lu, lv = math.hypot(ua, ub), math.hypot(va, vb)
        if lu < 1e-9 or lv < 1e-9:
            raise Stop(line, f"{what} next to a line of zero length")
        ua, ub, va, vb = ua / lu, ub / lu, va / lv, vb / lv
        cross = ua * vb - ub * va
        if abs(cross) < 1e-9:
            raise Stop(line, f"{what} between collinear lines")
        if what == "RND":
            d = value * math.tan(math.atan2(abs(cross), ua * va + ub * vb) / 2)
        else:
            d = value
        if d > lu + 1e-9 or d > lv + 1e-9:
            raise Stop(line, f"{what} {value:g} does not fit between the lines")
        t1 = list(p)
        t2 = list(p)
        t1[i0], t1[i1] = p[i0] - d * ua, p[i1] - d * ub
        t2[i0], t2[i1] = p[i0] + d * va, p[i1] + d * vb
        prev[R_END] = t1
        prev[R_CORR] = False
        nxt[R_START] = t2
        flags = FLAG_DERIVED | (prev[R_FLAGS] & FLAG_CUTTER_COMP)
        r = _rec(MOVE_LINE, line, t1, t2, feed, list(prev[R_OFF]), self.plane, flags)
        if what == "RND":
            sign = 1.0 if cross > 0 else -1.0
            c = list(t1)
            c[i0], c[i1] = t1[i0] - sign * value * ub, t1[i1] + sign * value * ua
            r[R_KIND] = MOVE_ARC_CCW if cross > 0 else MOVE_ARC_CW
            r[R_CEN] = c
        return [r]

    def len_value(self, mo: Motion, line: int, what: str) -> float:
        if "LEN" not in mo.extra:
            raise Stop(line, f"{what} without LEN")
        v = self.num(mo.extra["LEN"], line) * self.unit
        if v <= 0:
            raise Stop(line, f"{what} with LEN {v:g}: must be positive")
        return v

    def h_appr(self, blk: Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        what = f"APPR {mo.sub}"
        if mo.sub not in ("LT", "LN"):
            raise Stop(line, f"{what} is not modelled")
        _i0, _i1, i2 = PLANE_AXES[self.plane]
        if mo.polar or "CCA" in mo.extra or mo.radius is not None:
            raise Stop(line, f"{what} with polar words, CCA or R is not valid here")
        if any(ax == i2 for ax, *_rest in mo.coords):
            raise Stop(line, f"{what} with a tool-axis coordinate (3-D approach) is not modelled")
        if self.corner is not None or self.appr is not None:
            raise Stop(line, f"{what} directly after RND/CHF/APPR")
        length = self.len_value(mo, line, what)
        if self.rcomp not in ("RL", "RR") and mo.sub == "LN":
            raise Stop(line, f"{what} needs radius compensation RL or RR")
        end, param = self.target(mo, line)
        if param:
            flags |= FLAG_PARAMETRIC
        feed = _NAN if rapid else self.feed
        self.appr = (line, mo.sub, list(self.pos), end, length, self.rcomp, feed, flags)
        self.pos = end
        if mo.ms and self.m_post(mo.ms, line, False):
            return -1
        return None

    def resolve_appr(self, nxt: list) -> list[list]:
        line, sub, ps, pa, length, rcomp, feed, flags = self.appr  # type: ignore[misc]
        self.appr = None
        i0, i1, _i2 = PLANE_AXES[self.plane]
        ta, tb = self.start_tangent(nxt, line, f"APPR {sub}")
        ph = list(pa)
        if sub == "LT":
            ph[i0], ph[i1] = pa[i0] - length * ta, pa[i1] - length * tb
        else:
            na, nb = (tb, -ta) if rcomp == "RR" else (-tb, ta)
            ph[i0], ph[i1] = pa[i0] + length * na, pa[i1] + length * nb
        flags |= FLAG_DERIVED
        kind = MOVE_RAPID if feed != feed else MOVE_LINE
        return [_rec(kind, line, ps, ph, feed, self.off, self.plane, flags),
                _rec(MOVE_LINE, line, ph, list(pa), self.feed, self.off, self.plane, flags)]

    def h_dep(self, blk: Block, i: int) -> int | None:
        mo, line, rapid, flags = self.motion_prologue(blk)
        what = f"DEP {mo.sub}"
        if mo.sub not in ("LT", "LN"):
            raise Stop(line, f"{what} is not modelled")
        if mo.coords or mo.polar or "CCA" in mo.extra or mo.radius is not None:
            raise Stop(line, f"{what} with coordinates, CCA or R is not modelled")
        if self.corner is not None or self.appr is not None:
            raise Stop(line, f"{what} directly after RND/CHF/APPR")
        length = self.len_value(mo, line, what)
        i0, i1, _i2 = PLANE_AXES[self.plane]
        ta, tb = self.end_tangent(self.last, line, what)
        comp = self.rcomp
        end = list(self.pos)
        if mo.sub == "LT":
            end[i0], end[i1] = end[i0] + length * ta, end[i1] + length * tb
        else:
            if comp not in ("RL", "RR"):
                raise Stop(line, f"{what} needs radius compensation RL or RR")
            na, nb = (tb, -ta) if comp == "RR" else (-tb, ta)
            end[i0], end[i1] = end[i0] + length * na, end[i1] + length * nb
        flags |= FLAG_DERIVED | (FLAG_CUTTER_COMP if comp in ("RL", "RR") else 0)
        kind = MOVE_RAPID if rapid else MOVE_LINE
        self.emit(_rec(kind, line, self.pos, end, _NAN if rapid else self.feed, self.off, self.plane, flags))
        self.rcomp = "R0"
        if mo.ms and self.m_post(mo.ms, line, True):
            return -1
        return None

    # ---- program flow ---------------------------------------------------------------------------
    def h_nothing(self, blk: Block, i: int) -> int | None:
        return None

    def h_end(self, blk: Block, i: int) -> int | None:
        return -1

    def h_assign(self, blk: Block, i: int) -> int | None:
        key, f = blk.data
        self.assign(key, f, blk.line)
        return None

    def h_sysread(self, blk: Block, i: int) -> int | None:
        self.set_unknown(blk.data, f"is read from the control by FN 18 SYSREAD at line {blk.line}")
        return None

    def h_qs(self, blk: Block, i: int) -> int | None:
        self.warn("qs", f"line {blk.line}: string parameters (QS) are ignored")
        return None

    def h_fn_error(self, blk: Block, i: int) -> int | None:
        raise Stop(blk.line, f"FN 14 raises error {blk.data}: the control stops the program here")

    def h_fn_other(self, blk: Block, i: int) -> int | None:
        num, _text = blk.data
        if num in (15, 16, 19, 20, 26, 27, 29, 37, 38):
            self.warn(f"fn{num}", f"line {blk.line}: FN {num} has no effect on the motion and is ignored")
            return None
        if num == 17:
            raise Stop(blk.line, "FN 17 SYSWRITE changes control data that is not modelled")
        if num == 28:
            raise Stop(blk.line, "FN 28 TABREAD reads Q parameters from a table; the values are not known")
        raise Stop(blk.line, f"FN {num} is not modelled")

    def label_index(self, key: Any, line: int) -> int:
        if isinstance(key, tuple):
            if key[1].startswith("QS"):
                raise Stop(line, f"jump to a label named by the string parameter {key[1]} is not modelled")
            v = self.num(qget(key[1], False), line)
            if v != int(v):
                raise Stop(line, f"label number {key[1]} = {v:g} is not a whole number")
            key = int(v)
        idx = self.labels.get(key)
        if idx is None:
            name = f'"{key}"' if isinstance(key, str) else str(key)
            raise Stop(line, f"label {name} is not defined in this program")
        return idx

    def h_jump(self, blk: Block, i: int) -> int | None:
        cmp, fa, fb, key = blk.data
        a = self.num(fa, blk.line)
        b = self.num(fb, blk.line)
        if (cmp == "EQU" and a == b) or (cmp == "NE" and a != b) or (cmp == "GT" and a > b) or (cmp == "LT" and a < b):
            return self.label_index(key, blk.line)
        return None

    def h_lbl(self, blk: Block, i: int) -> int | None:
        if blk.data != 0 or not self.stack:
            return None
        frame = self.stack[-1]
        if frame[1] > 0:
            frame[1] -= 1
            return frame[2]
        self.stack.pop()
        return frame[0] + 1

    def h_call_lbl(self, blk: Block, i: int) -> int | None:
        key, rep = blk.data
        line = blk.line
        st = self.stack
        for depth in range(len(st) - 1, -1, -1):
            if st[depth][0] == i:
                del st[depth + 1:]
                frame = st[depth]
                if frame[1] > 0:
                    frame[1] -= 1
                    return frame[2]
                st.pop()
                return None
        if not isinstance(rep, int):
            v = self.num(rep, line)
            if v != int(v) or v < 0:
                raise Stop(line, f"REP count {v:g} is not a whole number >= 0")
            rep = int(v)
        if len(st) >= MAX_CALL_DEPTH:
            raise Stop(line, f"label calls nested deeper than {MAX_CALL_DEPTH}")
        target = self.label_index(key, line)
        st.append([i, max(rep - 1, 0), target])
        return target

    def h_call_pgm(self, blk: Block, i: int) -> int | None:
        raise Stop(blk.line, f"CALL PGM {blk.data}: the called program is not read")

    # ---- cycles ----------------------------------------------------------------------------------
    def h_cycl_def(self, blk: Block, i: int) -> int | None:
        num, sub, data = blk.data
        line = blk.line
        if sub is None or sub == 0:
            name = cycle_name(data) if isinstance(data, str) else ""
            if num == 247:
                self.frame["datum"] = (line, "datum setting from the preset table (cycle 247)")
            elif num == 26:
                self.frame["scaling"] = (line, "axis-specific scaling (cycle 26)")
            elif num not in _DEF_ACTIVE:
                self.cycle = (num, name, line)
            return None
        if num == 7:
            self.datum_shift(data, line)
        elif num == 9 and sub == 1:
            self.dwell(data, line, "cycle 9 DWELL TIME")
        elif num == 32 and sub == 1:
            # tolerance for the following moves; 32.1 without T resets it to the machine's
            self.tol = BLEND_PROFILE if data is None else max(self.num(data, line), 0.0) * self.unit
        elif num == 8:
            if data:
                self.frame["mirror"] = (line, "mirror image (cycle 8)")
            else:
                self.frame.pop("mirror", None)
        elif num == 10:
            for name, v in data:
                a = self.num(v, line)
                self.rot = self.rot + a if name.startswith("I") else a
            if abs(self.rot % 360.0) > 1e-12 and abs(self.rot % 360.0 - 360.0) > 1e-12:
                self.frame["rotation"] = (line, f"coordinate rotation by {self.rot:g} degrees (cycle 10)")
            else:
                self.frame.pop("rotation", None)
        elif num == 11:
            for _name, v in data:
                if abs(self.num(v, line) - 1.0) > 1e-12:
                    self.frame["scaling"] = (line, "scaling (cycle 11)")
                else:
                    self.frame.pop("scaling", None)
        elif num == 19 and sub == 1:
            angles = [self.num(v, line) for name, v in data if name in ("A", "B", "C")]
            if any(abs(a) > 1e-12 for a in angles):
                self.frame["tilt"] = (line, "tilted working plane (cycle 19)")
            else:
                self.frame.pop("tilt", None)
        return None

    def datum_shift(self, data: Any, line: int) -> None:
        if isinstance(data, tuple):
            self.frame["datum"] = (line, "datum shift from a datum table (cycle 7 #)")
            return
        for name, v in data:
            axis = name[-1]
            if axis not in AXIS_INDEX:
                self.warn("rotshift", f"line {line}: datum shift of a rotary axis is not modelled")
                continue
            ax = AXIS_INDEX[axis]
            value = self.num(v, line) * self.unit
            self.off[ax] = self.off[ax] + value if name[0] == "I" else value

    def h_cycl_call(self, blk: Block, i: int) -> int | None:
        mo: Motion = blk.data
        line = blk.line
        if mo.sub == "PAT":
            raise Stop(line, "CYCL CALL PAT (point pattern) is not modelled")
        if mo.sub == "POS" and mo.coords:
            rapid = self.set_feed(mo.feed, line)
            self.check_frame(line)
            end, param = self.target(mo, line)
            flags = self.comp_flags(mo.rcomp) | (FLAG_PARAMETRIC if param else 0)
            kind = MOVE_RAPID if rapid else MOVE_LINE
            ws, we, wd, wst, wi = _spans(mo)
            self.emit([kind, line, self.pos, end, _NAN if rapid else self.feed, tuple(self.off), _NAN3, self.plane,
                       1, False, flags, ws, we, wd, wst, wi, _NONE3, _NONE3, _ZERO3, _ZERO3, _FALSE3, -1])
        self.m_pre(mo.ms, line)
        self.cycle_call(line)
        if any(m in (2, 30) for m in mo.ms):
            return -1
        return None

    def cycle_call(self, line: int) -> None:
        self.check_frame(line)
        if self.corner is not None or self.appr is not None:
            raise Stop(line, "cycle call between RND/CHF/APPR and its contour element")
        if self.cycle is None:
            raise Stop(line, "cycle call without a cycle definition")
        num, name, dline = self.cycle
        if num not in _RETURNING_CYCLES:
            label = f"cycle {num} {name}".strip()
            raise Stop(line, f"{label} (defined at line {dline}) moves the tool; its motion is not modelled")
        self.cycle_calls.setdefault(dline, [num, name, []])[2].append(line)
        # the move that brought the tool to the cycle's position is the cycle's, not a contour's: never corrected
        self.b.uncommand_last()

    def cycle_warnings(self) -> None:
        for dline, (num, name, lines) in self.cycle_calls.items():
            where = ", ".join(str(x) for x in lines[:6]) + (", ..." if len(lines) > 6 else "")
            self.warnings.append(
                f"line {lines[0]}: cycle {num} {name} (defined at line {dline}) called {len(lines)} time(s) "
                f"(lines {where}): its internal motion is not modelled; the tool returns to its start position")

    # ---- tools, frames, others ---------------------------------------------------------------------
    def h_tool_call(self, blk: Block, i: int) -> int | None:
        d = blk.data
        line = blk.line
        axis = d.get("axis")
        if axis is not None:
            if axis not in AXIS_INDEX:
                raise Stop(line, f"tool axis {axis} (parallel axis) is not modelled")
            self.plane = _TOOL_AXIS_PLANE[AXIS_INDEX[axis]]
        if "F" in d:
            self.tool_feed = self.feed_value(d["F"], line)
        if "S" in d:
            try:
                self.spindle = self.num(d["S"], line)
            except Stop:
                self.spindle = _NAN
        tool = d.get("tool")
        if tool is not None:
            try:
                self.tool = self.num(tool, line)
            except Stop:
                self.tool = None
        self.tool_radius(d, line)
        return None

    def tool_radius(self, d: dict[str, Any], line: int) -> None:
        base = self.tools.get(self.tool) if self.tool is not None else None
        if base is None:
            self.set_unknown("Q108", f"is the radius of the tool in the tool table (TOOL CALL at line {line})")
            return
        delta = 0.0
        if "DR" in d:
            try:
                delta = self.num(d["DR"], line) * self.unit
            except Stop:
                self.set_unknown("Q108", f"depends on an unknown DR in TOOL CALL at line {line}")
                return
        self.q["Q108"] = (base + delta) / self.unit

    def h_tool_def(self, blk: Block, i: int) -> int | None:
        d = blk.data
        try:
            tool = self.num(d["tool"], blk.line) if d.get("tool") is not None else None
            if tool is not None and "R" in d:
                self.tools[tool] = self.num(d["R"], blk.line) * self.unit
        except Stop:
            pass
        return None

    def h_plane(self, blk: Block, i: int) -> int | None:
        tokens: list[str] = blk.data
        line = blk.line
        if tokens and tokens[0] == "RESET":
            self.frame.pop("tilt", None)
            return None
        kind = tokens[0] if tokens else ""
        angles = []
        for t in tokens[1:]:
            m = re.fullmatch(r"(SPA|SPB|SPC|PROPR|PROMIN|PROROT|EULPR|EULNU|EULROT|ROT|[ABC])([+-]?[\d.,]+)", t)
            if m:
                angles.append(float(m.group(2).replace(",", ".")))
        if kind in ("SPATIAL", "PROJECTED", "EULER", "RELATIV", "AXIAL") and angles and not any(angles):
            if kind != "RELATIV":
                self.frame.pop("tilt", None)
            return None
        self.frame["tilt"] = (line, f"tilted working plane (PLANE {kind})")
        return None

    def h_loose(self, blk: Block, i: int) -> int | None:
        name, tokens = blk.data
        line = blk.line
        head = name.split()[0]
        if name in _LOOSE_STOP or head in _LOOSE_STOP:
            raise Stop(line, _LOOSE_STOP.get(name) or _LOOSE_STOP[head])
        if head in ("DECLARE", "PATTERN", "CONTOUR"):
            return None
        if head == "SEL":
            self.warn(name, f"line {line}: {name} is ignored")
            return None
        if head == "FUNCTION":
            if "TCPM" in tokens:
                if "RESET" in tokens or "OFF" in tokens:
                    self.frame.pop("tcpm", None)
                else:
                    self.frame["tcpm"] = (line, "FUNCTION TCPM (tool centre point management)")
                return None
            if tokens and tokens[0] == "DWELL":
                rest = " ".join(tokens[1:])
                self.dwell(dwell_value(rest), line, "FUNCTION DWELL", per_rev=rest.startswith("REV"))
                return None
            if tokens and tokens[0] == "FEED":
                return None
            raise Stop(line, f"FUNCTION {' '.join(tokens[:2])} is not modelled")
        if name == "TRANS DATUM":
            if tokens and tokens[0] == "RESET":
                self.off = [0.0, 0.0, 0.0]
                return None
            raise Stop(line, "TRANS DATUM with values is not modelled")
        raise Stop(line, f"{name} is not modelled")


# --------------------------------------------------------------------------------------------
# public API: reader
# --------------------------------------------------------------------------------------------
def _first_bad_line(data: bytes) -> int:
    """Line of the first NUL or stray control byte (for binary input)."""
    for k, b in enumerate(data[:65536]):
        if b == 0 or (b < 32 and b not in (9, 10, 12, 13, 26)):
            return data.count(b"\n", 0, k) + 1
    return 1


def read_heidenhain(path: Path, data: bytes) -> Program:
    """Read a Heidenhain Klartext program.

    Parameters
    ----------
    path : Path
        The file (used in messages and stored in the program).
    data : bytes
        The file content.

    Returns
    -------
    Program
        ``dialect="heidenhain"``; the text decoded as latin-1 (byte for byte);
        the moves in execution order with the correctable ``L`` commands;
        ``unsupported`` set when the interpretation stopped at a construct that
        is not modelled (the lexical layer is complete in any case).

    Raises
    ------
    ProgramError
        A syntax error, binary data or an empty file (one line: file, line,
        problem).
    """
    path = Path(path)
    if looks_binary(data):
        raise ProgramError(path, _first_bad_line(data), "binary data, not a Klartext program")
    text = decode_source(data)
    if not text.strip():
        raise ProgramError(path, 1, "empty program (no BEGIN PGM)")
    lex = KlartextLexer(path, text)
    lex.run()
    assert lex.begin is not None
    name, unit_word, _line = lex.begin
    unit = MM_PER_INCH if unit_word == "INCH" else 1.0
    interp = _Interp(lex, unit)
    interp.run()
    moves = _finish_table(interp, lex)
    warnings = list(lex.warnings)
    if lex.cycle_misspelled is not None:
        warnings.append(f"line {lex.cycle_misspelled}: 'CYCLE DEF' (misspelled by the post-processor) read as CYCL DEF")
    if lex.skipped_lines:
        warnings.append(f"line {lex.skipped_lines[0]}: blocks marked '/' ({len(lex.skipped_lines)}) are read as "
                        "executed (block skip off)")
    warnings.extend(interp.warnings)
    unmodelled = None
    if interp.cycle_calls:  # the first cycle called (its first call's line)
        dline, (num, cname, lines) = next(iter(interp.cycle_calls.items()))
        unmodelled = (lines[0], f"cycle {num} {cname} (defined at line {dline}) moves the tool at its {len(lines)}"
                                f" call(s); that motion is not modelled, so a run of the program is neither simulated"
                                " nor learned (the contour around it would be judged without it)")
    return Program(
        path=path, text=text, dialect="heidenhain", units="inch" if unit_word == "INCH" else "mm", moves=moves,
        name=name, warnings=warnings, unsupported=interp.unsupported, unmodelled=unmodelled,
        trailing_dwell_s=interp.b.pending_dwell_s,
    )


def _finish_table(interp: _Interp, lex: KlartextLexer) -> MoveTable:
    """Freeze the moves; drop the commands that are not executed exactly once or cannot be rewritten."""
    mt = interp.b.build()
    m = len(mt)
    if m == 0:
        return mt
    last_line = lex.last_line
    counts = np.zeros(last_line + 2, dtype=np.int64)
    for blk, c in zip(lex.blocks, interp.counts, strict=True):
        if blk.kind == K_RUN:
            counts[blk.data.lines] = c
        else:
            counts[blk.line] = c
    repeated = counts[mt.line] > 1
    mt.flags[repeated] |= FLAG_REPEATED
    cmd = (mt.command >= 0) & ~repeated
    if interp.unsupported is not None:
        first = _first_target_line(lex)
        if first is not None:
            cmd &= mt.line < first
    # the next move must absorb a changed start; a move after a helper move (APPR, RND, CHF) shapes it
    blocking = (mt.flags & (FLAG_DERIVED | FLAG_POLAR | FLAG_PARAMETRIC | FLAG_REPEATED)) != 0
    cmd[:-1] &= ~blocking[1:]
    cmd[1:] &= (mt.flags[:-1] & FLAG_DERIVED) == 0
    command = np.full(m, -1, dtype=np.int32)
    command[cmd] = np.arange(int(cmd.sum()), dtype=np.int32)
    mt.command = command
    return mt


def _first_target_line(lex: KlartextLexer) -> int | None:
    """Line of the first label a jump or call can reach (text after it may run again)."""
    best = None
    for key, idx in lex.labels.items():
        if lex.dynamic_targets or key in lex.targets:
            line = lex.blocks[idx].line
            best = line if best is None else min(best, line)
    return best



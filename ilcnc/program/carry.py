"""What a converted program must carry besides its motion: tools, spindle, coolant, dwells, stops, comments.

``export`` to the other dialect writes the motion from the move table (the
readers' interpretation). This module reads the *machining* words of the
source, line by line, as :class:`Event` s placed before or after a move, so
the writers can put them back in the target's syntax at the same place in
the run:

========================  ==================================  =================================
what                      G-code                              Klartext
========================  ==================================  =================================
comment                   ``( )``, ``;``                      ``; ``
spindle                   ``M3``/``M4``/``M5``, ``S``          ``M3``/``M4``/``M5``, ``TOOL CALL Z S``
coolant                   ``M7``/``M8``/``M9``                 ``M7``/``M8``/``M9``
tool change               ``T.. M6`` with ``G43 H..``          ``TOOL CALL n Z S..``
dwell                     ``G4 P`` (s; Fanuc ``P`` in ms)      cycle 9 ``DWELL``
stop                      ``M0``/``M1``                        ``STOP`` / ``M0``/``M1``
========================  ==================================  =================================

A Klartext tool call applies the tool table's length; in G-code that is
``G43 H``, which the converted program writes after ``T.. M6``. A G-code
``T.. M6`` becomes a tool call whether or not the source had ``G43``: on a
Heidenhain the tool lengths are in the tool table.

When in a block: G-code (LinuxCNC's order of execution) runs ``S``, ``T``,
``M6``, spindle, coolant and dwell before the block's motion and stops and
the end after it; Klartext runs ``M3``/``M4``/``M8`` (and ``M13``/``M14``)
at the beginning of the block and ``M5``/``M9``/``M0``/``M2``/``M30`` at
its end.

What cannot be carried safely is refused with the line
(:class:`ilcnc.errors.UnsupportedError`): canned cycles the reader does not
expand into their moves, cycle definitions and calls other than the datum
shift and the dwell, tool calls with deltas or by name, ``G55``..``G59.3`` (offsets stored in the machine), rotary and parallel
axes, machine-specific M functions, parameters in these words, and
machining words in a program that jumps back (loops, subprograms), whose
order in the run the text alone does not give.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from ilcnc.errors import UnsupportedError
from ilcnc.program.comments import split_gcode_comments
from ilcnc.program.model import FLAG_REPEATED, Program

__all__ = ["Carried", "Event", "carried_events", "dwell_blocks", "gcode_blocks", "klartext_blocks"]

#: M functions both dialects run alike (spindle, coolant, stops, program end).
_COMMON_M = {0, 1, 2, 3, 4, 5, 7, 8, 9, 30}
_KL_BEGIN_M = {3, 4, 8, 13, 14}  # Klartext M functions that act at the beginning of their block
_GC_WORD = re.compile(r"([A-Za-z])[ \t]*([+-]?[ \t]*(?:\d+\.?\d*|\.\d+))")
# G codes whose meaning the readers turn into the motion itself (frames, units, modes, expanded cycles)
_GC_MOTION_G = {0.0, 1.0, 2.0, 3.0, 17.0, 18.0, 19.0, 20.0, 21.0, 40.0, 49.0, 53.0, 54.0, 61.0, 61.1, 64.0, 80.0,
                81.0, 83.0, 73.0, 85.0, 90.0, 91.0, 90.1, 91.1, 93.0, 94.0, 95.0, 98.0, 99.0, 92.0, 92.1, 92.2, 52.0,
                10.0}


@dataclass(frozen=True, slots=True)
class Event:
    """One machining word of the source.

    Attributes
    ----------
    kind : str
        ``comment`` (value: text), ``m`` (value: M number), ``spindle`` (value: rpm), ``tool`` (value: tool
        number; ``rpm`` the speed given with it, or None), ``dwell`` (value: seconds).
    value : float or str
    line : int
        Source line (1-based).
    rpm : float or None
        Spindle speed given with a tool change.
    """

    kind: str
    value: float | str
    line: int
    rpm: float | None = None


@dataclass(slots=True)
class Carried:
    """The source's machining words by the move they come before or after (move index), and those after the
    last move (``tail``)."""

    before: dict[int, list[Event]] = field(default_factory=dict)
    after: dict[int, list[Event]] = field(default_factory=dict)
    tail: list[Event] = field(default_factory=list)

    @property
    def count(self) -> int:
        return sum(map(len, self.before.values())) + sum(map(len, self.after.values())) + len(self.tail)


#: Largest spindle speed and tool number both dialects take (the TNC: 5 digits and 4 decimals; tools 0..32767).
MAX_RPM = 99999.9999
MAX_TOOL = 32767


def _check_range(program: Program, line: int, what: str, value: float, most: float, *, integer: bool = False) -> None:
    if not (0.0 <= value <= most) or (integer and value != int(value)):
        raise _refuse(program, line, f"{what} {value:g} is outside what both dialects take (0..{most:g}"
                                     f"{', whole' if integer else ''})")


def _refuse(program: Program, line: int, what: str) -> UnsupportedError:
    return UnsupportedError(program.path, line, f"{what}: not converted (export to the other dialect carries"
                                                f" only what the target runs the same way)")


def _lines(program: Program) -> list[str]:
    return program.text.replace("\r\n", "\n").replace("\r", "\n").split("\n")


def _gcode_line(program: Program, line: int, s: str) -> tuple[list[Event], list[Event], bool]:
    """(events before the line's motion, after it, whether the line holds a tool change) of one G-code line."""
    before: list[Event] = []
    after: list[Event] = []
    blanked, texts = split_gcode_comments(s, lenient=True)
    for text in texts:
        if text.strip():
            before.append(Event("comment", text.strip(), line))
    code = (blanked or "").strip()
    if not code or code.startswith("%"):
        return before, after, False
    if code.startswith("$"):  # a grbl system command ($H homing, $X unlock): kept in sight as a comment
        before.append(Event("comment", f"grbl command {code} (not a program block of this control)", line))
        return before, after, False
    if code.startswith("/"):
        raise _refuse(program, line, "block delete '/'")
    if re.match(r"(?i)^(?:N\s*\d+\s*)?O", code):
        return before, after, False  # O-words: control flow, the linearity check decides
    if "#" in code or "[" in code:
        if re.search(r"(?i)(?<![A-Za-z_<])[MSTP]\s*[#\[]", code):
            raise _refuse(program, line, "a machining word holds a parameter or an expression")
        return before, after, False
    words = [(m.group(1).upper(), float(m.group(2).replace(" ", "").replace("\t", ""))) for m in
             _GC_WORD.finditer(code)]
    gs = [v for k, v in words if k == "G"]
    ms = [int(v) for k, v in words if k == "M"]
    letters = {k: v for k, v in words}
    tool_change = 6 in ms
    dwell: list[Event] = []
    for g in gs:
        g = round(g, 1)
        if g == 4.0:
            p = letters.get("P", letters.get("X"))
            if p is None:
                raise _refuse(program, line, "G4 without a time")
            secs = p / 1000.0 if program.dialect == "fanuc" and "P" in letters and float(p).is_integer() else p
            dwell.append(Event("dwell", float(secs), line))
        elif g in (41.0, 42.0, 41.1, 42.1):
            raise _refuse(program, line, f"cutter radius compensation G{g:g}")
        elif g in (43.0, 43.1, 43.2):
            continue  # tool length: checked with the tool change
        elif 55.0 <= g <= 59.3:
            raise _refuse(program, line, f"work coordinate system G{g:g} (its offset is stored in the machine)")
        elif g not in _GC_MOTION_G:
            raise _refuse(program, line, f"G{g:g}")
    for k, _v in words:
        if k in "ABCUVW":
            raise _refuse(program, line, f"the rotary or parallel axis word {k}")
    if "S" in letters:
        _check_range(program, line, "spindle speed S", letters["S"], MAX_RPM)
    if "S" in letters and not tool_change:
        before.append(Event("spindle", letters["S"], line))
    if tool_change:
        if "T" not in letters:
            raise _refuse(program, line, "M6 without a T word on its line")
        _check_range(program, line, "tool number T", letters["T"], MAX_TOOL, integer=True)
        before.append(Event("tool", letters["T"], line, letters.get("S")))
    for m in ms:
        if m == 6:
            continue
        if m not in _COMMON_M:
            raise _refuse(program, line, f"the machine-specific M{m}")
        (after if m in (0, 1, 2, 30) else before).append(Event("m", float(m), line))
    before.extend(dwell)  # LinuxCNC's order: speed, tool, spindle, coolant, then the dwell, then the motion
    return before, after, tool_change


_KL_SKIP = re.compile(r"^(?:BEGIN\s+PGM|END\s+PGM|BLK\s+FORM|TOOL\s+DEF|FN\s*\d|Q\d|LBL|CALL\s+LBL|CYCLE?\s+DEF\s+7\.|"
                      r"CYCLE?\s+DEF\s+32\.)", re.IGNORECASE)
_KL_MOTION = re.compile(r"^(?:L|C|CR|CT|CC|LP|CP|RND|CHF|APPR|DEP)\b")


def _klartext_line(program: Program, line: int, s: str) -> tuple[list[Event], list[Event]]:
    before: list[Event] = []
    after: list[Event] = []
    code = re.sub(r"^\s*\d+\s+", "", s).strip()
    semi = code.find(";")
    if semi >= 0:
        text = code[semi + 1:].strip()
        if text:
            before.append(Event("comment", text, line))
        code = code[:semi].strip()
    if code.startswith("*"):
        text = code.lstrip("*").strip(" -")
        if text:
            before.append(Event("comment", text, line))
        return before, after
    if not code or _KL_SKIP.match(code):
        return before, after
    up = code.upper()
    if up.startswith("TOOL CALL"):
        rest = up[len("TOOL CALL"):].strip()
        m = re.match(r"^(\d+)?\s*([XYZ])?\s*(.*)$", rest)
        if m is None or '"' in rest:
            raise _refuse(program, line, "a tool call by name")
        num, axis, tail = m.group(1), m.group(2), m.group(3)
        if axis not in (None, "Z"):
            raise _refuse(program, line, f"a tool call in the {axis} axis")
        sm = re.search(r"\bS\s*([+]?\d+(?:[.,]\d+)?)", tail)
        rpm = float(sm.group(1).replace(",", ".")) if sm else None
        if rpm is not None:
            _check_range(program, line, "spindle speed S", rpm, MAX_RPM)
        if num is not None:
            _check_range(program, line, "tool number", float(num), MAX_TOOL, integer=True)
        if re.search(r"\bD[LR]2?\s*[+-]?\s*\d*[.,]?\d*[1-9]", tail):
            raise _refuse(program, line, "a tool call with a length or radius delta (DL / DR)")
        if num is not None:
            before.append(Event("tool", float(num), line, rpm))
        elif rpm is not None:
            before.append(Event("spindle", rpm, line))
        return before, after
    up = re.sub(r"^CYCLE(?=\s+DEF)", "CYCL", up)  # some posts spell it CYCLE
    if up.startswith("CYCL DEF 9."):
        m = re.search(r"(?:DWELL|TIME)\s*([+]?\d+(?:[.,]\d+)?)", up)
        if m is not None:
            before.append(Event("dwell", float(m.group(1).replace(",", ".")), line))
        return before, after
    if up.startswith(("CYCL", "CALL PGM", "PGM CALL", "TCH PROBE", "PLANE", "FUNCTION", "SEL ")):
        raise _refuse(program, line, f"'{' '.join(code.split()[:3])}'")
    if up.startswith("STOP") and not re.search(r"(?<![A-Z])M\s*0*[01](?!\d)", up):
        after.append(Event("m", 0.0, line))  # STOP alone is M0
    motion = _KL_MOTION.match(up) is not None
    if motion and re.search(r"(?<![A-Z])(?:I?[ABCUVW])\s*[+-]?\s*[\d.,Q]", up):
        raise _refuse(program, line, "a rotary or parallel axis word")
    for mm in re.finditer(r"(?<![A-Z])M\s*(\d+)", up):
        m_no = int(mm.group(1))
        if m_no in (91, 92):
            continue  # machine coordinates: the motion itself
        if m_no not in _COMMON_M and m_no not in (13, 14):
            raise _refuse(program, line, f"the machine-specific M{m_no}")
        if m_no in (13, 14):  # spindle and coolant together
            events = [Event("m", 3.0 if m_no == 13 else 4.0, line), Event("m", 8.0, line)]
        else:
            events = [Event("m", float(m_no), line)]
        (before if m_no in _KL_BEGIN_M else after).extend(events)
    return before, after


def carried_events(program: Program) -> Carried:
    """The machining words of ``program`` placed by move (module docstring).

    Raises
    ------
    UnsupportedError
        A word that cannot be carried, with its line.
    """
    mv = program.moves
    lines = _lines(program)
    out = Carried()
    m = len(mv)
    move_lines = mv.line.astype(np.int64)
    linear = m == 0 or (bool(np.all(np.diff(move_lines) >= 0)) and not np.any(mv.flags & FLAG_REPEATED))
    first_move = {}
    last_move = {}
    for i in range(m):
        ln = int(move_lines[i])
        first_move.setdefault(ln, i)
        last_move[ln] = i
    klartext = program.dialect == "heidenhain"
    pending: list[Event] = []
    for idx, s in enumerate(lines):
        line = idx + 1
        if klartext:
            before, after = _klartext_line(program, line, s)
        else:
            before, after, _tool = _gcode_line(program, line, s)
        if not linear and any(e.kind != "comment" for e in before + after):
            raise _refuse(program, line, "machining words in a program that jumps back (loops, subprograms):"
                                         " their place in the run")
        if line in first_move:
            if pending or before:
                out.before.setdefault(first_move[line], []).extend(pending + before)
                pending = []
            if after:
                out.after.setdefault(last_move[line], []).extend(after)
        else:
            pending.extend(before + after)
    out.tail.extend(pending)
    return out


def _num(value: float) -> str:
    """A number as both dialects write it: fixed point, no exponent, at most 4 decimals."""
    return f"{value:.4f}".rstrip("0").rstrip(".") or "0"


def _comment_text(text: str) -> str:
    return "".join(c if " " <= c <= "~" or ord(c) > 160 else " " for c in text).strip()


def dwell_blocks(dialect: str, secs: str) -> list[str]:
    """The blocks of a dwell of ``secs`` seconds, the number as given: ``G4 P`` (Fanuc ``G4 X``, seconds there),
    Klartext cycle 9 in two blocks (without block numbers)."""
    if dialect == "heidenhain":
        return ["CYCL DEF 9.0 DWELL TIME", f"CYCL DEF 9.1 DWELL {secs}"]
    return [f"G4 X{secs}" if dialect == "fanuc" else f"G4 P{secs}"]


def gcode_blocks(events: list[Event], dialect: str) -> list[str]:
    """The G-code lines of ``events`` (a program end is the writer's own last line)."""
    out: list[str] = []
    for e in events:
        if e.kind == "comment":
            out.append("(" + _comment_text(str(e.value)).replace("(", "[").replace(")", "]") + ")")
        elif e.kind == "spindle":
            out.append(f"S{_num(float(e.value))}")
        elif e.kind == "tool":
            n = int(float(e.value))
            out.append(f"T{n} M6" + (f" S{_num(e.rpm)}" if e.rpm is not None else ""))
            out.append(f"G43 H{n}")  # the tool table's length, as a Klartext tool call applies it
        elif e.kind == "m":
            if int(float(e.value)) not in (2, 30):
                out.append(f"M{int(float(e.value))}")
        elif e.kind == "dwell":
            out.extend(dwell_blocks(dialect, _num(float(e.value))))
    return out


def klartext_blocks(events: list[Event]) -> list[str]:
    """The Klartext blocks of ``events`` (without block numbers; the program end is ``END PGM``)."""
    out: list[str] = []
    for e in events:
        if e.kind == "comment":
            out.append("; " + _comment_text(str(e.value)).rstrip(" ~"))
        elif e.kind == "spindle":
            out.append(f"TOOL CALL Z S{_num(float(e.value))}")
        elif e.kind == "tool":
            out.append(f"TOOL CALL {int(float(e.value))} Z" + (f" S{_num(e.rpm)}" if e.rpm is not None else ""))
        elif e.kind == "m":
            if int(float(e.value)) not in (2, 30):
                out.append(f"M{int(float(e.value))}")
        elif e.kind == "dwell":
            out.extend(dwell_blocks("heidenhain", _num(float(e.value))))
    return out

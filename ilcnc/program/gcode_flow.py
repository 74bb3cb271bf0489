"""O-word control flow of LinuxCNC G-code: subroutines, calls, if/while/do/repeat, Fanuc M98/M99.

Fanuc-style subprograms, as LinuxCNC 2.9 runs them: a subprogram starts at a
line holding only its number (``O1000``) and ends at the first ``M99`` after
it; ``M98 P1000 L3`` calls it three times. Unlike an ``o-sub`` it has no
local parameters (#1-#30 are the caller's). Met in the program's flow, the
number line does nothing (a program number) and the lines after it run (as
LinuxCNC's ``rs274`` runs it); a call that reaches the end of the file is an
error, as in rs274. A call to a subprogram that stands before it is not
modelled (rs274 seeks the number after the call only). ``M99`` in the main program (a control restarts the
program, endlessly) is not modelled.

A program with O-word control flow is executed line by line with a program
counter (no vectorised fast path: such programs are written by hand and
small). Every line is lexed when it is executed, so parameters and
expressions take the values they have at that moment, as in LinuxCNC.

Moves whose line runs more than once (a loop body, a subroutine called
twice) are flagged ``FLAG_REPEATED`` and are never corrected: one source
line cannot hold two different corrections.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ilcnc.errors import ProgramError
from ilcnc.program.expr import ExprError, ExprValueError, read_value
from ilcnc.program.model import FLAG_REPEATED, Unmodelled


class BlockLexer(Protocol):
    """What control flow needs of the G-code lexer (:mod:`ilcnc.program.gcode`)."""

    path: Path
    params: Any
    lenient: bool

    def lex(self, s: str, base: int, line: int) -> Any: ...


class BlockInterpreter(Protocol):
    """What control flow needs of the G-code interpreter (:mod:`ilcnc.program.gcode`)."""

    st: Any
    builder: Any
    ended: bool

    def execute(self, blk: Any) -> None: ...

__all__ = ["MAX_EXECUTED_LINES", "MAX_REPEATED_BYTES", "has_control_flow", "run_control_flow"]

#: Executed lines after which a program is taken not to terminate.
MAX_EXECUTED_LINES = 80_000
#: Bytes of lines executed again (a loop or a subprogram call) after which a program is refused: each run of a
#: line lexes it anew, and a loop of 800 over a line of 7 MB (a fuzzed spiral.ngc) took minutes. 64 MB is 80,000
#: repeated lines of 800 bytes; a long program that runs straight through repeats nothing.
MAX_REPEATED_BYTES = 64_000_000

_OLINE = re.compile(
    r"\s*(?:/\s*)?(?:[Nn]\s*\d+\s*)?[Oo]\s*(<[^>]*>|\d+)\s*"
    r"(sub|endsub|call|return|if|elseif|else|endif|while|endwhile|do|repeat|endrepeat|break|continue)\b(.*)",
    re.IGNORECASE,
)
# Found anywhere (a comment may hold one too: then the line-by-line path simply runs, still correct);
# no anchor, so the scan jumps from one O to the next instead of testing every line start.
_HAS_FLOW = re.compile(r"[Oo][ \t]*(?:<[^>]*>|\d+)[ \t]*(?i:sub|call|if|while|do|repeat)\b|[Mm][ \t]*0*9[89](?![0-9.])")
#: A Fanuc subprogram's first line: its number alone (a block number and comments may stand with it).
_FANUC_SUB = re.compile(r"\s*(?:/\s*)?(?:[Nn]\s*\d+\s*)?[Oo]\s*(\d+)\s*(?:\([^)]*\)\s*)*(?:;.*)?$")


def has_control_flow(text: str) -> bool:
    """True when the program uses O-word subroutines or control structures."""
    return _HAS_FLOW.search(text) is not None


@dataclass(slots=True)
class _OLine:
    label: str
    keyword: str
    rest: str


@dataclass(slots=True)
class _Frame:
    return_to: int
    name: str
    numbered: dict[int, float]
    named: dict[str, float]


@dataclass(slots=True)
class _Loop:
    label: str
    kind: str  # while, do, repeat
    start: int  # line index of the opening o-word
    count: int = 0


@dataclass(slots=True)
class _Structure:
    olines: dict[int, _OLine] = field(default_factory=dict)
    subs: dict[str, tuple[int, int]] = field(default_factory=dict)  # label -> (sub line, endsub line)
    partner: dict[int, int] = field(default_factory=dict)  # opening -> closing line and back
    branches: dict[int, list[int]] = field(default_factory=dict)  # if line -> [elseif/else lines..., endif]
    fanuc: dict[int, int] = field(default_factory=dict)  # Fanuc subprogram number -> its O line


@dataclass(slots=True)
class _FanucCall:
    """An ``M98`` call in progress: where to return, the subprogram's first line and the repeats left."""

    return_to: int
    start: int
    left: int


def _strip_comment(s: str) -> str:
    out = re.sub(r"\([^)]*\)", "", s)
    cut = out.find(";")
    return out if cut < 0 else out[:cut]


def _scan(path: object, lines: list[str]) -> _Structure:
    """Find every O-word line and match the blocks (sub/endsub, if/endif, ...)."""
    st = _Structure()
    stack: list[tuple[str, str, int]] = []
    for i, raw in enumerate(lines):
        if "o" not in raw and "O" not in raw:
            continue
        m = _OLINE.match(raw)
        if m is None:
            f = _FANUC_SUB.match(raw)
            if f is not None:
                num = int(f.group(1))
                if num in st.fanuc:
                    raise ProgramError(path, i + 1, f"subprogram O{num} is defined twice (line {st.fanuc[num] + 1})")
                st.fanuc[num] = i
            continue
        label = m.group(1).replace(" ", "").lower()
        kw = m.group(2).lower()
        st.olines[i] = _OLine(label, kw, _strip_comment(m.group(3)))
        line = i + 1
        if kw in ("sub", "if", "while", "repeat", "do"):
            if kw == "while" and stack and stack[-1][0] == label and stack[-1][1] == "do":
                _, _, j = stack.pop()
                st.partner[j] = i
                st.partner[i] = j
                continue
            stack.append((label, kw, i))
            if kw == "if":
                st.branches[i] = []
        elif kw in ("endsub", "endif", "endwhile", "endrepeat"):
            want = {"endsub": "sub", "endif": "if", "endwhile": "while", "endrepeat": "repeat"}[kw]
            if not stack or stack[-1][0] != label or stack[-1][1] != want:
                raise ProgramError(path, line, f"o{label} {kw} without a matching o{label} {want}")
            _, _, j = stack.pop()
            st.partner[j] = i
            st.partner[i] = j
            if kw == "endsub":
                st.subs[label] = (j, i)
            if kw == "endif":
                st.branches[j].append(i)
        elif kw in ("elseif", "else"):
            if not stack or stack[-1][0] != label or stack[-1][1] != "if":
                raise ProgramError(path, line, f"o{label} {kw} without a matching o{label} if")
            st.branches[stack[-1][2]].append(i)
    if stack:
        label, kw, j = stack[-1]
        raise ProgramError(path, j + 1, f"o{label} {kw} is never closed")
    return st


def run_control_flow(
    lexer: BlockLexer,
    interp: BlockInterpreter,
    lines: list[str],
    line_start: np.ndarray,
) -> tuple[int, str] | None:
    """Execute a program with O-word control flow; returns ``unsupported`` (or None).

    Lines that are never executed (bodies of skipped branches, subroutines
    never called, text after the program end) are still lexed for syntax.
    """
    path = lexer.path
    struct = _scan(path, lines)
    params = lexer.params
    n = len(lines)
    executed = np.zeros(n, dtype=np.int64)
    frames: list[_Frame] = []
    loops: list[_Loop] = []
    fanuc_calls: list[_FanucCall] = []
    unsupported: tuple[int, str] | None = None
    pc = 0
    steps = 0
    percent = 0
    seen_states: dict[int, set[tuple]] = {}

    def jump_back(loop_line: int, target: int, extra: object = None) -> int:
        """Jump to the head of a loop, refusing a loop that comes back to a state it was in before."""
        states = seen_states.setdefault(loop_line, set())
        if len(states) < 100_000:
            st = interp.st
            key = (
                target, extra, tuple(sorted(params.numbered.items())), tuple(sorted(params.named.items())),
                tuple(st.pos), st.motion, st.feed, st.plane, st.unit, st.absolute, st.cs, tuple(st.g92),
                len(frames),
            )
            if key in states:
                o = struct.olines[loop_line]
                raise Unmodelled(loop_line + 1, f"o{o.label} {o.keyword} loops forever: it comes back to a state "
                                                  "it was in before (no parameter or position changed)")
            states.add(key)
        return target

    def read_at(text: str, pos: int, line: int) -> tuple[float, int]:
        """One value at ``pos``: undefined values stop the interpretation, malformed ones are errors."""
        try:
            return read_value(text, pos, params)
        except ExprValueError as exc:
            raise Unmodelled(line, str(exc)) from None
        except ExprError as exc:
            raise ProgramError(path, line, str(exc)) from None
        except RecursionError:
            raise ProgramError(path, line, "expression nested too deeply") from None

    def value(text: str, line: int) -> float:
        v, end = read_at(text, 0, line)
        if text[end:].strip():
            raise ProgramError(path, line, f"unexpected text after the value: {text[end:].strip()!r}")
        return v

    def args(text: str, line: int) -> list[float]:
        out: list[float] = []
        pos = 0
        t = text.strip()
        while pos < len(t):
            if t[pos].isspace():
                pos += 1
                continue
            v, pos = read_at(t, pos, line)
            out.append(v)
        return out

    repeated = 0
    try:
        while pc < n:
            steps += 1
            if steps > MAX_EXECUTED_LINES:
                raise Unmodelled(pc + 1, f"program executes more than {MAX_EXECUTED_LINES} lines (endless loop?)")
            i = pc
            line = i + 1
            pc += 1
            o = struct.olines.get(i)
            if o is None:
                raw = lines[i]
                if executed[i]:
                    repeated += len(raw)
                    if repeated > MAX_REPEATED_BYTES:
                        raise Unmodelled(line, f"program executes more than {MAX_REPEATED_BYTES // 1_000_000} MB of"
                                               " lines again in loops or calls (a loop over very long lines?)")
                s = raw[:-1] if raw.endswith("\r") else raw
                blk = lexer.lex(s, int(line_start[i]), line)
                if blk.percent:
                    percent += 1
                    if percent >= 2:
                        break
                    continue
                executed[i] += 1
                m98 = _fanuc_word(blk)
                if m98 == 98:
                    num, times = _fanuc_call(blk, path)
                    start = struct.fanuc.get(num)
                    if start is None:
                        raise Unmodelled(line, f"M98 P{num}: subprogram O{num} is not in this file (files are not"
                                               " searched)")
                    if start < i:
                        # rs274 seeks the number after the call and stops at the end of the file
                        raise Unmodelled(line, f"M98 P{num}: O{num} stands before the call (line {start + 1});"
                                               " LinuxCNC looks for it after the call: not modelled")
                    if len(fanuc_calls) + len(frames) > 200:
                        raise Unmodelled(line, "subprogram calls nested deeper than 200")
                    if times > 0:
                        fanuc_calls.append(_FanucCall(pc, start + 1, times - 1))
                        pc = start + 1
                    continue
                if m98 == 99:
                    if not fanuc_calls:
                        raise Unmodelled(line, "M99 in the main program (restart it, endlessly) is not modelled")
                    call = fanuc_calls[-1]
                    if call.left > 0:
                        call.left -= 1
                        pc = call.start
                    else:
                        fanuc_calls.pop()
                        pc = call.return_to
                    continue
                interp.execute(blk)
                if interp.ended:
                    break
                continue
            kw = o.keyword
            executed[i] += 1
            if kw == "sub":
                pc = struct.partner[i] + 1  # a definition: skip the body
            elif kw == "call":
                target = struct.subs.get(o.label)
                if target is None:
                    raise Unmodelled(line, f"o{o.label} call: subroutine not defined in this file (files are not searched)")
                vals = args(o.rest, line)
                if len(vals) > 30:
                    raise ProgramError(path, line, "more than 30 call arguments")
                if len(frames) > 200:
                    raise Unmodelled(line, "subroutine calls nested deeper than 200")
                frames.append(_Frame(pc, o.label, dict(params.numbered), dict(params.named)))
                for k in range(1, 31):
                    params.numbered[k] = vals[k - 1] if k <= len(vals) else 0.0
                params.named = {k: v for k, v in params.named.items() if k.startswith("_")}
                loops.append(_Loop("", "frame", -1))
                pc = target[0] + 1
            elif kw in ("endsub", "return"):
                if not frames:
                    if kw == "endsub":
                        raise ProgramError(path, line, f"o{o.label} endsub reached outside a call")
                    raise ProgramError(path, line, f"o{o.label} return outside a subroutine")
                ret = o.rest.strip()
                rv = value(ret, line) if ret else None
                frame = frames.pop()
                while loops and loops[-1].kind != "frame":
                    loops.pop()
                if loops:
                    loops.pop()
                globals_now = {k: v for k, v in params.named.items() if k.startswith("_")}
                numbered = {k: v for k, v in params.numbered.items() if k > 30}  # globals stay as the sub left them
                numbered.update({k: v for k, v in frame.numbered.items() if k <= 30})
                params.numbered = numbered
                params.named = {k: v for k, v in frame.named.items() if not k.startswith("_")}
                params.named.update(globals_now)
                params.named["_value"] = rv if rv is not None else 0.0
                params.named["_value_returned"] = 1.0 if rv is not None else 0.0
                pc = frame.return_to
            elif kw == "if":
                branches = struct.branches[i]
                if value(o.rest.strip(), line) != 0.0:
                    continue
                pc = _next_branch(struct, branches, lines, params, value)
            elif kw in ("elseif", "else"):
                # reached after a taken branch: leave the if block
                if_line = _owner_if(struct, i)
                pc = struct.branches[if_line][-1] + 1
            elif kw == "endif":
                pass
            elif kw == "while":
                end = struct.partner[i]
                if end < i:  # tail of a do-while
                    if value(o.rest.strip(), line) != 0.0:
                        pc = jump_back(end, end + 1)
                    else:
                        _pop_loop(loops, o.label)
                    continue
                if value(o.rest.strip(), line) != 0.0:
                    if not loops or loops[-1].start != i:
                        loops.append(_Loop(o.label, "while", i))
                else:
                    _pop_loop(loops, o.label)
                    pc = end + 1
            elif kw == "endwhile":
                pc = jump_back(struct.partner[i], struct.partner[i])
            elif kw == "do":
                if not loops or loops[-1].start != i:
                    loops.append(_Loop(o.label, "do", i))
            elif kw == "repeat":
                if loops and loops[-1].start == i:
                    loop = loops[-1]
                else:
                    cnt = value(o.rest.strip(), line)
                    body = struct.partner[i] - i
                    if not cnt * body < MAX_EXECUTED_LINES:
                        raise Unmodelled(line, f"o{o.label} repeat [{cnt:g}] would run more than "
                                                 f"{MAX_EXECUTED_LINES} lines: not modelled")
                    loop = _Loop(o.label, "repeat", i, round(cnt))
                    loops.append(loop)
                if loop.count <= 0:
                    _pop_loop(loops, o.label)
                    pc = struct.partner[i] + 1
                else:
                    loop.count -= 1
            elif kw == "endrepeat":
                pc = struct.partner[i]
            elif kw in ("break", "continue"):
                loop = next((lp for lp in reversed(loops) if lp.label == o.label and lp.kind != "frame"), None)
                if loop is None:
                    raise ProgramError(path, line, f"o{o.label} {kw} outside an o{o.label} loop")
                close = struct.partner[loop.start]
                if kw == "break":
                    _pop_loop(loops, o.label)
                    pc = close + 1
                elif loop.kind == "do":
                    pc = close  # evaluate the do-while condition
                else:
                    pc = loop.start if loop.kind == "while" else close
            else:  # pragma: no cover - the regex admits only the keywords above
                raise ProgramError(path, line, f"unknown O-word keyword {kw}")
        if fanuc_calls and pc >= n:
            start = fanuc_calls[-1].start  # the line after the subprogram's number, 1-based: its O line + 1
            raise ProgramError(path, start, f"the file ends inside subprogram {lines[start - 1].strip()} (no M99;"
                                            " LinuxCNC stops with 'File ended with no percent sign or program end')")
    except Unmodelled as exc:
        unsupported = (exc.line, exc.problem)
    lexer.lenient = True
    # lex every line never executed, for syntax errors
    for i in np.flatnonzero(executed == 0):
        if int(i) in struct.olines:
            continue
        raw = lines[i]
        s = raw[:-1] if raw.endswith("\r") else raw
        lexer.lex(s, int(line_start[i]), int(i) + 1)
    _mark_repeated(interp, executed)
    return unsupported


def _fanuc_word(blk: Any) -> int | None:
    """98 or 99 when the block holds ``M98`` / ``M99`` (then nothing but P, L and N may stand with it)."""
    found = None
    for w in blk.words:
        if w.letter == "M" and w.value in (98.0, 99.0):
            found = int(w.value)
    if found is None:
        return None
    other = [w.letter for w in blk.words if w.letter not in ("M", "P", "L", "N") or
             (w.letter == "M" and w.value not in (98.0, 99.0))]
    if other or blk.assignments:
        raise Unmodelled(blk.line, f"M{found} with other words on its line ({', '.join(other) or 'a parameter'}) is"
                                   " not modelled")
    return found


def _fanuc_call(blk: Any, path: Path) -> tuple[int, int]:
    """The subprogram number (P) and the number of calls (L, default 1) of an ``M98`` block."""
    p = next((w.value for w in blk.words if w.letter == "P"), None)
    times = next((w.value for w in blk.words if w.letter == "L"), 1.0)
    if p is None or p < 0 or p != round(p):
        raise ProgramError(path, blk.line, "M98 needs P, the number of the subprogram to call")
    if times < 0 or times != round(times):
        raise ProgramError(path, blk.line, f"M98 L must be a whole number of calls, got L{times:g}")
    if times >= MAX_EXECUTED_LINES:
        raise Unmodelled(blk.line, f"M98 L{times:g} would run more than {MAX_EXECUTED_LINES} lines: not modelled")
    return int(p), int(times)


def _pop_loop(loops: list[_Loop], label: str) -> None:
    while loops and loops[-1].kind != "frame":
        lp = loops.pop()
        if lp.label == label:
            return


def _owner_if(struct: _Structure, i: int) -> int:
    for if_line, br in struct.branches.items():
        if i in br:
            return if_line
    raise KeyError(i)  # pragma: no cover


def _next_branch(struct: _Structure, branches: list[int], lines: list[str], params: object, value: object) -> int:
    """Line to continue at after a false ``if``: the first true ``elseif``, the ``else``, or after ``endif``."""
    for b in branches:
        o = struct.olines[b]
        if o.keyword == "elseif":
            if value(o.rest.strip(), b + 1) != 0.0:  # type: ignore[operator]
                return b + 1
        elif o.keyword == "else":
            return b + 1
        else:  # endif
            return b + 1
    return branches[-1] + 1  # pragma: no cover


def _mark_repeated(interp: BlockInterpreter, executed: np.ndarray) -> None:
    """Flag moves of lines run more than once and renumber the commands."""
    b = interp.builder
    b._flush()
    if not b._chunks:
        return
    table = b.build()
    rep = executed[table.line - 1] > 1
    if rep.any():
        table.flags[rep] |= FLAG_REPEATED
        keep = (table.command >= 0) & ~rep
        table.command[:] = -1
        table.command[keep] = np.arange(int(keep.sum()), dtype=np.int32)
    b._chunks = [table]
    b.n_commands = int(np.count_nonzero(table.command >= 0))

"""The program with ``ilcnc linuxcnc prepare``'s path-control edits made (``prepare --out READY``).

Each edit (:class:`ilcnc.shop.linuxcnc_prepare.PathEdit`) either inserts a line ``G64 P… Q0`` before the first
move, or replaces the ``G64`` words (with their P and Q) of a line that sets the path control. Nothing else of
the program changes: every other line is kept byte for byte, in order, with the file's own line ends. Each
edited or inserted line is marked ``(ilcnc prepare)`` so a person can see it. The inserted line shifts the lines
after it by one: the ready program is the one to run, log and learn (its own line numbers).
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from ilcnc.errors import InputError
from ilcnc.program.comments import split_gcode_comments
from ilcnc.program.insert import lines_inserted, reread, same_moves
from ilcnc.program.model import Program
from ilcnc.shop.linuxcnc_prepare import PathEdit

__all__ = ["MARK", "apply_path_edits", "ready_program_text"]

#: The comment that marks an inserted or edited line.
MARK = "ilcnc prepare"

# G64 with its P and Q words, literal numbers only (a word given by an expression is edited by hand)
_G64 = re.compile(r"(?i)G\s*0*64(?![\d.])((?:\s*[PQ]\s*[-+]?(?:\d+\.?\d*|\.\d+))*)")
_PQ_EXPR = re.compile(r"(?i)^\s*[PQ]\s*[#\[]")


def apply_path_edits(program: Program, edits: Sequence[PathEdit]) -> str:
    """``program``'s text with ``edits`` made (module docstring).

    Raises
    ------
    InputError
        A line to edit whose ``G64`` cannot be found as words, or whose P or Q is an expression or a parameter:
        the line is named; edit it by hand.
    """
    text = program.text
    lines = text.split("\n")
    inserts: dict[int, list[str]] = {}
    for e in edits:
        if e.insert:
            inserts.setdefault(e.line, []).append(f"{e.words} ({MARK})")
            continue
        i = e.line - 1
        if not 0 <= i < len(lines):
            raise InputError(program.path, e.line, "no such line to set the path control on")
        raw = lines[i]
        cr = "\r" if raw.endswith("\r") else ""
        body = raw[:len(raw) - len(cr)]
        words, _texts = split_gcode_comments(body)
        m = _G64.search(words) if words is not None else None
        if m is None:
            raise InputError(program.path, e.line, "G64 not found as words on this line: set the path control by hand"
                             f" (`{e.words}`)")
        rest = words[m.end():]
        if _PQ_EXPR.match(rest):
            raise InputError(program.path, e.line, "G64's P or Q is an expression or a parameter: set the path"
                             f" control by hand (`{e.words}`)")
        if re.search(r"(?i)[PQ]", words[:m.start()] + rest):
            raise InputError(program.path, e.line, "a P or Q word apart from G64's on"
                             f" this line: set the path control by hand (`{e.words}`)")
        if body[m.start():m.end()] != words[m.start():m.end()]:  # a comment between the words: keep it, by hand
            raise InputError(program.path, e.line, "a comment between G64 and its P or Q: set the path control by"
                             f" hand (`{e.words}`)")
        # offsets of the comment-blanked line are those of the line itself
        lines[i] = f"{body[:m.start()]}{e.words} ({MARK}){body[m.end():]}{cr}"
    return lines_inserted("\n".join(lines), inserts)


def ready_program_text(program: Program, edits: Sequence[PathEdit]) -> str:
    """:func:`apply_path_edits`, checked: the edited text, read again, moves the tool exactly as the program does
    (the same moves, start and end points and feeds; only the path control between them differs).

    Raises
    ------
    InputError
        An edit that would change a move (it names the program): nothing is written.
    """
    text = apply_path_edits(program, edits)
    if not same_moves(program, reread(program, text)):
        raise InputError(program.path, None, "the path-control edits would change the moves: set the path control"
                         " by hand")
    return text

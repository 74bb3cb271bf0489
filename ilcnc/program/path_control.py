"""The blocks of a G-code program that set its path control (``G61``, ``G61.1``, ``G64`` with its ``P`` and ``Q``),
as written: what ``ilcnc linuxcnc prepare`` keeps and what a tighter tolerance restores after its lines.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from ilcnc.errors import InputError
from ilcnc.outcomes import PathMode
from ilcnc.program.expr import Parameters
from ilcnc.program.gcode_lexer import Lexer
from ilcnc.program.model import Program

__all__ = ["PathSetting", "path_settings"]

_PATH_WORD = re.compile(r"(?i)G\s*0*6\s*[14]")


@dataclass(frozen=True, kw_only=True)
class PathSetting:
    """One block of the program that sets the path control (its source line and words)."""

    line: int
    mode: PathMode
    p: float | None  # program units
    q: float | None

    def to_json(self) -> dict[str, Any]:
        return {"line": self.line, "mode": str(self.mode), "p": self.p, "q": self.q}


def path_settings(program: Program) -> list[PathSetting]:
    """Every block that sets the path control, with its P and Q as written (literal or evaluated words)."""
    lexer = Lexer(program.path, Parameters(permissive=True))
    out: list[PathSetting] = []
    for no, raw in enumerate(program.text.split("\n"), 1):
        s = raw.rstrip("\r")
        if not _PATH_WORD.search(s):
            continue
        try:
            blk = lexer.lex(s, 0, no)
        except InputError:
            continue  # the reader already accepted the program; a line it cannot lex alone is not a setting
        gs = [w.value for w in blk.words if w.letter == "G"]
        words = {w.letter: w.value for w in blk.words if w.letter in "PQ"}
        if 61.1 in gs or any(abs(g - 61.1) < 1e-9 for g in gs):
            mode = PathMode.EXACT_STOP
        elif 61.0 in gs:
            mode = PathMode.EXACT_PATH
        elif 64.0 in gs:
            mode = PathMode.BOUNDED if words.get("P", 0.0) > 0 else PathMode.UNBOUNDED
        else:
            continue
        out.append(PathSetting(line=no, mode=mode, p=words.get("P") if mode is PathMode.BOUNDED else None,
                               q=words.get("Q") if mode in (PathMode.BOUNDED, PathMode.UNBOUNDED) else None))
    return out

"""Part programs: reading, the command table, writing.

``read_program`` picks the reader by suffix and content: Heidenhain Klartext
for ``.h`` files or files that begin with ``BEGIN PGM``, G-code otherwise.
"""

from __future__ import annotations

import re
from pathlib import Path

from ilcnc.errors import ProgramError
from ilcnc.fileio import read_bytes
from ilcnc.program.model import Program

__all__ = ["GCODE_SUFFIXES", "HEIDENHAIN_SUFFIXES", "Program", "is_heidenhain", "read_program"]

GCODE_SUFFIXES = (".nc", ".ngc", ".tap", ".gcode", ".gc", ".g", ".cnc", ".txt")
HEIDENHAIN_SUFFIXES = (".h",)
_BEGIN_PGM = re.compile(rb"^\s*(?:\d+\s+)?BEGIN\s+PGM\b", re.IGNORECASE)


def is_heidenhain(path: Path, data: bytes) -> bool:
    """True when the file is Heidenhain Klartext (by suffix or by its first block)."""
    if path.suffix.lower() in HEIDENHAIN_SUFFIXES:
        return True
    return _BEGIN_PGM.match(data[:200]) is not None


def _check_bytes(path: Path, data: bytes) -> None:
    """Refuse what the controls refuse before a word is read: a UTF-8 byte-order mark (LinuxCNC: "Bad
    character"), and line ends of a lone CR (classic Mac OS), which a control reads as one long line."""
    if data.startswith(b"\xef\xbb\xbf"):
        raise ProgramError(path, 1, "the file starts with a UTF-8 byte-order mark, which LinuxCNC refuses ('Bad"
                                    " character'): save it without one (plain ASCII or UTF-8 without BOM)")
    if b"\n" not in data and data.count(b"\r") > 1:
        raise ProgramError(path, 1, "its lines end in CR alone (classic Mac OS), so a control reads the file as one"
                                    " line: convert the line ends to LF or CR LF")


def read_program(path: str | Path, *, default_units: str = "mm", data: bytes | None = None) -> Program:
    """Read a part program (G-code or Klartext) into a :class:`Program`.

    Parameters
    ----------
    path : str or Path
        The program file.
    default_units : {"mm", "inch"}
        Units of a G-code program that sets neither G20 nor G21.
    data : bytes, optional
        The content, if already read.
    """
    p = Path(path)
    if data is None:
        data = read_bytes(p)
    _check_bytes(p, data)
    if is_heidenhain(p, data):
        from ilcnc.program.heidenhain import read_heidenhain

        return read_heidenhain(p, data)
    from ilcnc.program.gcode import read_gcode

    return read_gcode(p, data, default_units=default_units)

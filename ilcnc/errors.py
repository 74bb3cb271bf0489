"""The small hierarchy of ilcnc's own exceptions.

Every error a user can cause by bad input is an :class:`InputError`: its
message is one line naming the file, the line (when known) and the problem,
which is exactly what the command line prints before exiting with code 1.
"""

from __future__ import annotations

from pathlib import Path


class IlcncError(Exception):
    """Base class of every error raised on purpose by ilcnc."""


class InputError(IlcncError):
    """Bad input: a file, a line in it and what is wrong.

    Parameters
    ----------
    file : str or Path or None
        The file the problem is in (``None`` when there is no file, e.g. an option).
    line : int or None
        1-based line number, when known.
    problem : str
        What is wrong, in one line.
    """

    def __init__(self, file: str | Path | None, line: int | None, problem: str) -> None:
        self.file = str(file) if file is not None else None
        self.line = line
        self.problem = " ".join(str(problem).split())
        super().__init__(self.format())

    def format(self) -> str:
        """Return the one-line message ``file:line: problem``."""
        where = self.file or "<input>"
        if self.line is not None:
            where = f"{where}:{self.line}"
        return f"{where}: {self.problem}"


class ProgramError(InputError):
    """A part program that cannot be read (syntax, unknown word, bad value)."""


class UnsupportedError(ProgramError):
    """A valid construct that ilcnc does not model (reported, never misread)."""


class ProfileError(InputError):
    """A machine profile with a missing, unknown or out-of-range key."""


class CorrectionError(InputError):
    """A corrections file or a correction that cannot be applied."""


class StateError(InputError):
    """A learning-state directory that is missing, damaged or belongs to another part."""


class LogError(InputError):
    """A measured log or probe file that does not belong to the program it claims."""


class MapError(InputError):
    """A volumetric error map, a tool FRF or a stock (OMI) file that cannot be used."""

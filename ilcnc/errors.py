"""The small hierarchy of ilcnc's own exceptions: one root, one line each, an exit code each.

Every error a user can cause is an :class:`IlcncError`; :meth:`IlcncError.format` is the one
line the command line prints (``error: ...``) and :attr:`IlcncError.exit_code` the code it
exits with: 1 for bad input (:class:`InputError`: the file, the line when known, the problem),
2 for a bad use of the command line (:class:`UsageError`: the option and what is wrong with
it). Anything else that escapes a command is a defect of ilcnc, not of the input.
"""

from __future__ import annotations

from pathlib import Path


class IlcncError(Exception):
    """Base class of every error raised on purpose by ilcnc."""

    #: What the command line exits with.
    exit_code: int = 1

    def format(self) -> str:
        """Return the one-line message the command line prints."""
        return " ".join(str(self).split())


class UsageError(IlcncError):
    """An option out of its range, or options that do not go together (exit code 2, as for typer's own).

    Parameters
    ----------
    option : str
        The option, as typed (``--log-period``).
    problem : str
        What is wrong with it, completing the sentence (``must be a number of seconds > 0, got -1``).
    """

    exit_code = 2

    def __init__(self, option: str, problem: str) -> None:
        self.option = option
        self.problem = " ".join(str(problem).split())
        super().__init__(f"{option} {self.problem}")


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

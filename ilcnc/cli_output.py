"""What every command of the command line shares: the error line and its exit code, the console, the table
that fits 80 columns, the check of a numeric option."""

from __future__ import annotations

import math
from typing import Any, NoReturn

import typer

from ilcnc.cli_options import debug_on
from ilcnc.errors import IlcncError, UsageError

__all__ = ["console", "fail", "finite", "table"]


def fail(exc: IlcncError) -> NoReturn:
    """Print ``error: <line>`` and exit with the error's code (``--debug``: raise it, with its traceback)."""
    if debug_on():
        raise exc
    typer.echo(f"error: {exc.format()}", err=True)
    raise typer.Exit(exc.exit_code)


def finite(option: str, value: float | None, *, lo: float | None = None, open_lo: bool = False,
            hi: float | None = None, unit: str = "") -> None:
    """Refuse a numeric option that is NaN, infinite or outside its range (a :class:`UsageError`, exit 2)."""
    if value is None:
        return
    below = lo is not None and (value <= lo if open_lo else value < lo)
    above = hi is not None and value > hi
    if not math.isfinite(value) or below or above:
        rng = "a finite number" + ("" if lo is None else f" {'>' if open_lo else '>='} {lo:g}")
        rng += "" if hi is None else f"{' and' if lo is not None else ''} <= {hi:g}"
        raise UsageError(option, f"must be {rng}{' ' + unit if unit else ''}, got {value:g}")


def console() -> Any:
    """A rich console (rich is imported on first use)."""
    from rich.console import Console

    return Console()


def table(title: str, *, show_header: bool = True) -> Any:
    """A table that fits a terminal of 80 columns without cutting anything (issue 23 item 7): light rules, one
    space between columns, and every column added with ``overflow="fold"`` (a long name or number wraps onto
    the next line instead of ending in '…'). Numbers in full are in ``--json``."""
    from rich import box
    from rich.table import Table

    return Table(title=title, show_header=show_header, box=box.SIMPLE_HEAD, padding=(0, 1), collapse_padding=True,
                 pad_edge=False)

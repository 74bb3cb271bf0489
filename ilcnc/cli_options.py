"""How the command line meets the shell: help names, flags, ``--debug``, renamed options (issue 23 item 8).

:class:`IlcncApp` is the typer app every ilcnc command hangs on. Its commands and groups

- answer ``-h`` as ``--help`` (the context setting :data:`CONTEXT_SETTINGS`, inherited by every subcommand);
- show no type after a flag in ``--help`` (typer's rich help prints ``<bool>`` after every flag, though a flag
  takes no value: the flags get an empty metavar);
- accept the old name of a renamed option (:data:`RENAMED_OPTIONS`) for one release, with one line on stderr
  saying it is deprecated and naming the new one;
- read a plain option value (a path, text, a number) without pydantic (:mod:`ilcnc.cli_values`);
- build only the command that runs (:meth:`IlcncApp.only`).

:data:`DebugOption` is ``--debug`` after a subcommand (``ilcnc learn ... --debug``): the same switch as
``ilcnc --debug learn ...``, read with :func:`debug_on`.
"""

from __future__ import annotations

import copy
import os
import sys
from collections.abc import Sequence
from typing import Annotated, Any

import typer
from typer.core import TyperCommand, TyperGroup

from ilcnc.cli_values import plain_values

__all__ = ["CONTEXT_SETTINGS", "RENAMED_OPTIONS", "DebugOption", "IlcncApp", "debug_on", "renamed_args", "set_debug"]

#: ``-h`` is ``--help`` everywhere (click reads the help names from the root context down).
CONTEXT_SETTINGS: dict[str, Any] = {"help_option_names": ["--help", "-h"]}

#: Options renamed so that one concept has one name across commands: (command, old name) -> new name. The old
#: name works for one release (0.1.x) and warns; then it goes. A log file a command writes is ``--log-out``
#: (``learn --log`` reads one); the format, unit and sample period of a log read are ``--log-format``,
#: ``--log-units`` and ``--log-period`` in every command that reads one.
RENAMED_OPTIONS: dict[tuple[str, str], str] = {
    ("simulate", "--out"): "--log-out",
    ("linuxcnc run", "--log"): "--log-out",
    ("identify", "--format"): "--log-format",
    ("identify", "--units"): "--log-units",
    ("identify", "--period-s"): "--log-period",
}

_debug = {"on": False}


def set_debug(on: bool) -> None:
    """Set ``--debug`` (the root option: ``ilcnc --debug COMMAND``)."""
    _debug["on"] = on


def debug_on() -> bool:
    """Whether ``--debug`` was given, before or after the subcommand."""
    return _debug["on"]


def _debug_after_command(value: bool) -> None:
    if value:  # never clears: the root's --debug may have set it
        _debug["on"] = True


#: ``--debug`` of a subcommand: every command declares it (``tests/test_cli_ergonomics.py`` checks).
DebugOption = Annotated[bool, typer.Option("--debug", callback=_debug_after_command,
                                           help="Show tracebacks of errors.")]


def _command_name(ctx: Any) -> str:
    """``simulate`` or ``linuxcnc run``: the subcommand path without the program name."""
    names = []
    while ctx is not None and ctx.parent is not None:
        names.append(ctx.info_name or "")
        ctx = ctx.parent
    return " ".join(reversed(names))


def renamed_args(command: str, args: Sequence[str], value_options: set[str]) -> tuple[list[str], list[str]]:
    """The arguments of ``command`` with each old option name replaced by its new one, and the warnings.

    Parameters
    ----------
    command : str
        The subcommand path (``simulate``, ``linuxcnc run``).
    args : sequence of str
        The command's arguments as the shell gave them.
    value_options : set of str
        The command's option names that take a value: the word after one is its value, never an option
        (``--profile --out`` gives --profile the value ``--out``, as click reads it).

    Returns
    -------
    list of str
        The arguments, ``--out x`` / ``--out=x`` as ``--log-out x`` / ``--log-out=x``; nothing after ``--``.
    list of str
        One ``warning: ...`` line per old name used.
    """
    renames = {old: new for (cmd, old), new in RENAMED_OPTIONS.items() if cmd == command}
    if not renames:
        return list(args), []
    out: list[str] = []
    warnings: list[str] = []
    value_next = False
    for i, arg in enumerate(args):
        if value_next:
            out.append(arg)
            value_next = False
            continue
        if arg == "--":
            out.extend(args[i:])
            break
        name, eq, value = arg.partition("=")
        if name in renames:
            line = f"warning: {name} of {command} is deprecated, use {renames[name]}"
            if line not in warnings:
                warnings.append(line)
            name = renames[name]
            arg = name + eq + value
        out.append(arg)
        value_next = name in value_options and not eq
    return out, warnings


def _flags_without_metavar(params: list[Any]) -> list[Any]:
    """The parameters, each flag with an empty metavar: typer's rich help would print ``<bool>`` after it."""
    for p in params:
        if getattr(p, "is_flag", False) and p.metavar is None:
            p.metavar = ""
    return params


class _Command(TyperCommand):
    """An ilcnc subcommand: renamed options still work (with a warning); flags show no ``<bool>``."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _flags_without_metavar(super().get_params(ctx))

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        takes_value = {o for p in self.params if getattr(p, "param_type_name", "") == "option"
                       and not getattr(p, "is_flag", False) and not getattr(p, "count", False) for o in p.opts}
        args, warnings = renamed_args(_command_name(ctx), args, takes_value)
        if not ctx.resilient_parsing:  # shell completion parses too: it must print nothing
            for line in warnings:
                typer.echo(line, err=True)
        plain_values(self.get_params(ctx))
        return super().parse_args(ctx, args)


class _Group(TyperGroup):
    """The ilcnc app and its groups (``linuxcnc``): flags show no ``<bool>``."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _flags_without_metavar(super().get_params(ctx))

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        plain_values(self.get_params(ctx))
        return super().parse_args(ctx, args)


class IlcncApp(typer.Typer):
    """A typer app whose commands and groups behave as the module says (``-h``, flags, renamed options, option
    values, the one command built)."""

    def __init__(self, **kwargs: Any) -> None:
        kwargs.setdefault("cls", _Group)
        kwargs.setdefault("context_settings", CONTEXT_SETTINGS)
        super().__init__(**kwargs)

    def command(self, *args: Any, **kwargs: Any) -> Any:
        """:meth:`typer.Typer.command` with ilcnc's command class."""
        kwargs.setdefault("cls", _Command)
        return super().command(*args, **kwargs)

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        """Run the command line (``main``), building only the command it names (:meth:`only`)."""
        argv = kwargs.get("args", args[0] if args else None)
        return typer.Typer.__call__(self.only(sys.argv[1:] if argv is None else argv), *args, **kwargs)

    def only(self, argv: Sequence[str]) -> IlcncApp:
        """This app with only the command or group ``argv[0]`` names, or the whole app.

        typer builds the click command of every command before it runs one, reading each one's signature: ~35 ms
        of a 0.5 s ``ilcnc check`` for 15 commands (issue 24). When the first argument names a command, the
        others are never run nor shown (``--help``, usage lines and errors of a command show that command only),
        so the copy returned leaves them out; the root's options and callback stay. Anything else (no command,
        a root option first, an unknown name, shell completion) gets the whole app.
        """
        if not argv or any(k.endswith("_COMPLETE") for k in os.environ):
            return self
        name = argv[0]
        commands = [c for c in self.registered_commands
                    if (c.name or typer.main.get_command_name(c.callback.__name__ if c.callback else "")) == name]
        groups = [g for g in self.registered_groups if g.name == name]
        if len(commands) + len(groups) != 1:
            return self
        trimmed = copy.copy(self)
        trimmed.registered_commands, trimmed.registered_groups = commands, groups
        return trimmed

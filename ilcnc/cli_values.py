"""An option's text as its value without pydantic where the answer is plain (issue 24, start-up).

typer (0.2x) turns each argument and option of the command that runs into its value through a pydantic
``TypeAdapter`` built for it: importing ``typer._adapters`` (pydantic) and building the adapters took
~0.1 s of a 0.5 s ``ilcnc check``. ilcnc's options are paths, text, numbers (some with a range) and flags,
so :class:`PlainValue` answers those itself, as typer's adapter would, and hands every other value to
typer's own coercion, built when first needed:

- ``str``: the text;
- ``Path``: ``Path(text)``, then typer's own checks (``typer._param_types.coerce_cli_path``: readable,
  ``exists``, ``dir_okay`` ...), which need no pydantic once the value is a ``Path``;
- ``float``: a decimal number in ASCII digits (``0.05``, ``-1``, ``.5``, ``1e-3``), ``float(text)``;
- ``int``: up to 18 ASCII digits with an optional sign, ``int(text)``;
- a ``float`` or ``int`` default as pydantic gives it (an ``int`` for a ``float`` option becomes a float);
- a number's range (``min`` / ``max``, no ``clamp``) checked; a number outside it goes to typer, which
  says why in its own words;
- ``list[...]`` of those (``check PROGRAMS...``), as a list.

Anything else (whitespace, ``1_000``, ``inf``, ``nan``, an empty path, choices, a parser, clamping, a type
not listed) goes to typer, so a value's result and every error message stay typer's;
``tests/test_startup.py`` checks the plain answers against typer's on every option of every command.
This reaches into typer's parameter internals (``type_descriptor``, ``_runtime_param``): where a typer
version has none, :func:`plain_values` leaves its parameters alone and typer parses as before.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

__all__ = ["PlainValue", "plain_values"]

#: A decimal number pydantic and ``float`` read alike (ASCII digits only: ``float`` also reads other scripts').
_FLOAT = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
#: An integer, at most 18 digits (far inside both readers' limits).
_INT = re.compile(r"[+-]?\d{1,18}", re.ASCII)
_PLAIN_TYPES = (str, Path, float, int, bool)
#: "Not a plain value": hand it to typer.
_TYPER = object()


def _leaf_kind(annotation: Any, info: Any) -> type | None:
    """The plain type of one value of a parameter, or None when typer must parse it."""
    if annotation not in _PLAIN_TYPES or getattr(info, "parser", None) is not None:
        return None
    if annotation is Path and getattr(info, "path_type", None) not in (None, Path):
        return None
    if annotation in (float, int) and getattr(info, "clamp", False):
        return None
    return annotation


class PlainValue:
    """typer's coercion of one parameter (its ``RuntimeParam.coerce``) that answers plain values itself.

    Parameters
    ----------
    param : typer's click parameter
        An argument or option of an ilcnc command (it has typer's ``type_descriptor``).
    """

    def __init__(self, param: Any) -> None:
        desc = param.type_descriptor
        self._desc = desc
        self._info = desc.parameter_info
        self._typer: Any = None
        ann = desc.annotation
        self._is_list = bool(getattr(desc, "is_list", False))
        if self._is_list:
            args = getattr(ann, "__args__", ())
            ann = args[0] if len(args) == 1 else None
        elif getattr(desc, "is_tuple", False):
            ann = None
        self._kind = _leaf_kind(ann, self._info)

    def typer_coercion(self) -> Any:
        """typer's own coercion of this parameter (built on first use: it imports pydantic)."""
        if self._typer is None:
            from typer._coercion import build_runtime_param

            self._typer = build_runtime_param(self._desc)
        return self._typer

    def coerce(self, value: Any, param: Any, ctx: Any) -> Any:
        """The parameter's value, as typer's ``RuntimeParam.coerce`` gives it."""
        multi = param.multiple or param.nargs == -1
        if value is None:  # as typer: nothing given, no default
            return () if multi else None
        if self._kind is not None and not (multi and isinstance(value, str)):
            if self._is_list:
                if isinstance(value, (list, tuple)):
                    out = [self._leaf(v, param, ctx) for v in value]
                    if not any(v is _TYPER for v in out):
                        return out
            else:
                v = self._leaf(value, param, ctx)
                if v is not _TYPER:
                    return v
        return self.typer_coercion().coerce(value, param=param, ctx=ctx)

    def _leaf(self, value: Any, param: Any, ctx: Any) -> Any:
        kind = self._kind
        if kind is str:
            return value if type(value) is str else _TYPER
        if kind is bool:
            return value if type(value) is bool else _TYPER
        if kind is Path:
            if isinstance(value, Path) or (type(value) is str and value):
                from typer._param_types import coerce_cli_path

                return coerce_cli_path(Path(value), self._info, path_type=Path, param=param, ctx=ctx)
            return _TYPER
        if kind is float:
            if type(value) is float or type(value) is int:
                num: Any = float(value)
            elif type(value) is str and _FLOAT.fullmatch(value):
                num = float(value)
            else:
                return _TYPER
        else:  # int
            if type(value) is int:
                num = value
            elif type(value) is str and _INT.fullmatch(value):
                num = int(value)
            else:
                return _TYPER
        lo, hi = getattr(self._info, "min", None), getattr(self._info, "max", None)
        if (lo is not None and not num >= lo) or (hi is not None and not num <= hi):
            return _TYPER  # typer's message says which bound
        return num


def plain_values(params: list[Any]) -> None:
    """Give each typer parameter of a command a :class:`PlainValue` (typer versions without one: nothing)."""
    for p in params:
        if hasattr(p, "type_descriptor") and getattr(p, "_runtime_param", False) is None:
            p._runtime_param = PlainValue(p)

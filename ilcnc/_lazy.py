"""Lazy public names of a package: a module is imported when one of its names is first used.

A package's ``__init__`` lists which of its modules holds each public name; ``from
ilcnc.vcnc import simulate_program`` then imports :mod:`ilcnc.vcnc.simulate` alone,
not the whole virtual CNC (start-up time: a command imports only what it runs).
``tests/test_architecture.py`` checks each table against the modules' ``__all__``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(package: str, table: dict[str, tuple[str, ...]]
                 ) -> tuple[Callable[[str], Any], Callable[[], list[str]], list[str]]:
    """``__getattr__``, ``__dir__`` and ``__all__`` for ``package`` from ``{module: names}``."""
    owner = {name: mod for mod, names in table.items() for name in names}

    def __getattr__(name: str) -> Any:
        mod = owner.get(name)
        if mod is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{mod}"), name)

    def __dir__() -> list[str]:
        return sorted(owner)

    return __getattr__, __dir__, sorted(owner)

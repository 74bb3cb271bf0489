"""Lazy public names of a package: a module is imported when one of its names is first used.

A package's ``__init__`` lists which of its modules holds each public name; ``from
ilcnc.vcnc import simulate_program`` then imports :mod:`ilcnc.vcnc.simulate` alone,
not the whole virtual CNC (start-up time: a command imports only what it runs).
``tests/test_architecture.py`` checks each table against the modules' ``__all__``.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["defer_numpy_extras", "lazy_exports"]

#: numpy submodules that SciPy's array-API layer imports without using them, and no ilcnc command uses.
NUMPY_EXTRAS = ("numpy.f2py", "numpy.testing", "numpy.ma", "numpy.polynomial")
_defer_lock = threading.Lock()


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


def defer_numpy_extras() -> list[str]:
    """Make :data:`NUMPY_EXTRAS` load on first use instead of at ``import scipy.linalg``; returns the ones deferred.

    ``scipy.linalg`` (imported by numba when it loads its first kernel, for its BLAS check, and by the drive
    models' matrix exponential) copies every public attribute of numpy at import
    (``scipy._lib.array_api_compat.numpy``), and reading ``numpy.f2py`` and ``numpy.testing`` imports them:
    0.06-0.12 s and 0.01-0.03 s (``unittest``) of a 1 s ``ilcnc simulate`` (issue 24); ``numpy.ma`` and
    ``numpy.polynomial`` another ~0.015 and ~0.004 s (``numpy.random`` and ``numpy.fft`` are left alone:
    SciPy uses them while it imports). Each one not
    imported yet is put in ``sys.modules`` as a lazy module (:class:`importlib.util.LazyLoader`, standard
    library): it is the same module, and its code runs when one of its attributes is first read.
    """
    done: list[str] = []
    numpy = sys.modules.get("numpy")
    if numpy is None:
        return done
    with _defer_lock:
        for name in NUMPY_EXTRAS:
            if name in sys.modules:
                continue
            spec = importlib.util.find_spec(name)
            if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
                continue
            loader = importlib.util.LazyLoader(spec.loader)
            spec.loader = loader
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            loader.exec_module(module)
            setattr(numpy, name.rpartition(".")[2], module)  # as an import does: numpy.__getattr__ is not asked
            done.append(name)
    return done

"""The one place that imports numba.

numba is a runtime dependency; when it is missing (a stripped install) :func:`njit`
leaves a function as plain Python, sets ``py_func`` like numba does, and
:data:`HAVE_NUMBA` tells the callers to take their numpy paths instead.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["HAVE_NUMBA", "njit", "set_component"]

try:  # pragma: no cover - exercised by the environment, not by a test
    from numba import njit

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - the numpy paths do the same work
    HAVE_NUMBA = False

    def njit(*args: Any, **kwargs: Any) -> Any:  # type: ignore[no-redef]
        """Stand-in for :func:`numba.njit`: the function stays Python."""

        def wrap(f: Callable[..., Any]) -> Callable[..., Any]:
            f.py_func = f  # type: ignore[attr-defined]
            return f

        if args and callable(args[0]):
            return wrap(args[0])
        return wrap


@njit(cache=True, nogil=True, inline="always")
def set_component(x0: float, x1: float, x2: float, axis: int, value: float) -> tuple[float, float, float]:  # pragma: no cover
    """``(x0, x1, x2)`` with component ``axis`` replaced: compiled loops keep a point in three scalars (registers);
    a small array would be a heap allocation per call."""
    if axis == 0:
        return value, x1, x2
    if axis == 1:
        return x0, value, x2
    return x0, x1, value

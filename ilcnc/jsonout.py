"""Values for ``--json`` output: JSON has no inf or NaN."""

from __future__ import annotations

import math

__all__ = ["json_float"]


def json_float(v: float | None) -> float | None:
    """``v`` as a float, or ``None`` (JSON ``null``) for ``None``, inf and NaN."""
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None

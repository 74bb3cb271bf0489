"""The figures of an error: max, mean and RMS, mm.

Every run, measurement and iteration reports its contour error as these three numbers, once for the cutting
moves and once for the air moves (:mod:`ilcnc.contour.air`). :class:`ErrorFigures` holds them as named,
typed fields (``max_mm``, ``mean_mm``, ``rms_mm``); it is also a read-only mapping with the keys ``max``,
``mean`` and ``rms``, which is what ``--json``, ``state.json`` and reports write (:meth:`to_json`), so
the files read exactly as before.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["ErrorFigures"]

_KEYS = ("max", "mean", "rms")


@dataclass(frozen=True, slots=True, eq=False)  # equality is the mapping's: equal to {"max": .., "mean": .., "rms": ..}
class ErrorFigures(Mapping[str, float]):
    """Max, mean and RMS of an error, mm (zeros when nothing was measured)."""

    max_mm: float = 0.0
    mean_mm: float = 0.0
    rms_mm: float = 0.0

    @classmethod
    def of(cls, d_mm: ArrayLike) -> ErrorFigures:
        """The figures of the finite values of ``d_mm`` (mm)."""
        d = np.asarray(d_mm, dtype=np.float64)
        d = d[np.isfinite(d)]
        if d.size == 0:
            return cls()
        return cls(float(d.max()), float(d.mean()), float(np.sqrt(np.mean(d * d))))

    @classmethod
    def from_json(cls, data: Mapping[str, float]) -> ErrorFigures:
        """From a mapping with the keys ``max``, ``mean`` (optional) and ``rms``."""
        return cls(float(data["max"]), float(data.get("mean", 0.0)), float(data["rms"]))

    def to_json(self) -> dict[str, float]:
        """``{"max": ..., "mean": ..., "rms": ...}``, mm."""
        return {"max": self.max_mm, "mean": self.mean_mm, "rms": self.rms_mm}

    def __getitem__(self, key: str) -> float:
        if key == "max":
            return self.max_mm
        if key == "mean":
            return self.mean_mm
        if key == "rms":
            return self.rms_mm
        raise KeyError(key)

    def __iter__(self) -> Iterator[str]:
        return iter(_KEYS)

    def __len__(self) -> int:
        return len(_KEYS)

"""The learning guard: an iteration that makes the error worse is refused, the gain halved, then learning stops.

The same policy for learning on the virtual CNC (:func:`ilcnc.learning.learner.learn_virtual`) and on the
machine (:func:`ilcnc.shop.workflow.learn_part` with a log or points): a run is compared with the best
statistics of all kept iterations (:func:`grew`, both the RMS and the max of the cutting moves); the first
time it grew, the iteration is not kept and the next starts from the best one with the gain halved
(:attr:`LearningGuard.gain_scale`); when it grows again with the gain halved, learning stops (``diverged``)
and the best iteration is the output. A growth within the tolerance of :func:`grew` does not count.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from ilcnc.contour.figures import ErrorFigures
from ilcnc.outcomes import GuardVerdict

__all__ = ["GROWTH_ABS_MM", "GROWTH_REL", "GROWTH_RESOLUTION_SHARE", "LearningGuard", "best_stats", "grew"]

#: Relative growth of the RMS or max error that the guard counts as "grew"
#: (plus half the resolution, at least :data:`GROWTH_ABS_MM`): rounding of the
#: written numbers alone moves the error by a fraction of the resolution, and a
#: maximum pinned at a spot no end point can fix (a rapid's corner, a plunge)
#: wobbles by a few tenths of a percent from run to run (measured on LinuxCNC:
#: 412.3 -> 413.5 µm while the RMS fell). The reference is the best value of
#: all kept iterations, so a creep below the tolerance cannot accumulate.
GROWTH_REL = 5e-3
GROWTH_ABS_MM = 1e-5
#: The half-resolution allowance is at most this share of the figure itself: on a part whose whole RMS is
#: below the resolution (compass: 0.685 µm on a 1 µm machine) half a resolution would let the RMS grow by
#: 70 % unseen (issue 25 item 18: 12 % and 23 % growths were kept); 5 % still covers the rounding wobble.
GROWTH_RESOLUTION_SHARE = 0.05


def best_stats(stats: list[Mapping[str, float]]) -> ErrorFigures:
    """The lowest of each figure over kept iterations (the guard's reference): they may come from different
    iterations."""
    return ErrorFigures(min(s["max"] for s in stats), min(s.get("mean", 0.0) for s in stats),
                        min(s["rms"] for s in stats))


def grew(new: Mapping[str, float], best: Mapping[str, float], *, resolution_mm: float = 0.0) -> list[str]:
    """The statistics (``rms``, ``max``) of ``new`` that grew beyond ``best``.

    A growth within :data:`GROWTH_REL` of the value plus half the machine's
    resolution (at most :data:`GROWTH_RESOLUTION_SHARE` of the value, at least
    :data:`GROWTH_ABS_MM`) does not count: rounding the written numbers to the
    resolution alone moves the error that much, and a maximum pinned at a spot no
    end point can fix wobbles by as little.
    """
    out = []
    for key in ("rms", "max"):
        tol_abs = max(GROWTH_ABS_MM, min(0.5 * resolution_mm, GROWTH_RESOLUTION_SHARE * best[key]))
        if new[key] > best[key] * (1.0 + GROWTH_REL) + tol_abs:
            out.append(key)
    return out


@dataclass(slots=True, kw_only=True)
class LearningGuard:
    """The guard of one learning run (see the module docstring).

    Attributes
    ----------
    resolution_mm : float
        The machine's resolution: half of it is within the growth tolerance.
    gain_scale : float
        The factor on the law's gain: 1, halved at each refused iteration.
    halved : bool
        A growth was refused since the last reset: the next one stops learning.
    """

    resolution_mm: float
    gain_scale: float = 1.0
    halved: bool = False

    def compare(self, new: Mapping[str, float], kept: list[Mapping[str, float]]
                ) -> tuple[list[str], ErrorFigures | None]:
        """The figures of ``new`` (``rms``, ``max``) that grew beyond the best of the ``kept`` runs' statistics,
        and that reference (None before any run was kept)."""
        if not kept:
            return [], None
        ref = best_stats(kept)
        return grew(new, ref, resolution_mm=self.resolution_mm), ref

    def refuse(self) -> GuardVerdict:
        """A run grew: halve the gain (``HALVED``) or, when it is halved already, stop (``STOPPED``)."""
        if self.halved:
            return GuardVerdict.STOPPED
        self.halved = True
        self.gain_scale *= 0.5
        return GuardVerdict.HALVED

    @staticmethod
    def grown(what: str, ref: Mapping[str, float], new: Mapping[str, float]) -> str:
        """One grown figure for a message: ``RMS 1.23 → 1.45 µm``."""
        return f"{what.upper()} {ref[what] * 1e3:.2f} → {new[what] * 1e3:.2f} µm"

    @staticmethod
    def stopped_message(iteration: int, what: str) -> str:
        """The start of the message of a run that stops: what grew again with the gain halved."""
        return f"iteration {iteration} made the error worse again ({what}) with the gain halved"

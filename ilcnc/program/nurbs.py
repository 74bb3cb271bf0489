"""The NURBS curve of a ``G5.2`` ... ``G5.3`` block, as LinuxCNC defines it, and its chords.

LinuxCNC's G-code reference ("G5.2 G5.3 NURBS Block") gives the control points
and their weights; the knots are not programmed, LinuxCNC computes them. Measured
with its interpreter (the ``gcode`` module puts its straight feeds on the curve at
u = umax i / (15 (n + 1)); this module's points there agree to 3e-14 mm for orders
3, 4 and 5 with uneven weights, ``tests/test_nurbs.py``) the knot vector is the
clamped uniform one with integer knots: for ``n + 1`` control points and order
``k`` (degree ``k - 1``)

    0 (k times), 1, 2, ..., n - k + 1, n - k + 2 (k times)

so the curve starts at the first control point, ends at the last and runs over
the parameter range ``[0, n - k + 2]``. A point of the curve is the weighted
B-spline in homogeneous coordinates (de Boor's algorithm on ``(w x, w y, w)``).
All lengths are in the caller's unit (mm in the reader).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ilcnc.program.gcode_lexer import Word
from ilcnc.program.model import Unmodelled

__all__ = ["NurbsBlock", "clamped_knots", "nurbs_chord_parameters", "nurbs_points"]

#: The order LinuxCNC gives a NURBS block without an L word (measured: the curve of order 3).
DEFAULT_ORDER = 3
#: Words a G5.2 line may have besides its G codes (F and S are read before the motion, as in any block).
_OPEN_WORDS = frozenset("NXYPLFS")
#: Words a control-point line may have.
_POINT_WORDS = frozenset("NXYP")

#: Samples per knot span from which a span's largest second derivative is estimated.
_SAMPLES_PER_SPAN = 64
#: Margin on that estimate (the samples can miss the peak between two of them).
_SECOND_DERIVATIVE_MARGIN = 1.5


def clamped_knots(count: int, order: int) -> np.ndarray:
    """The knot vector LinuxCNC gives ``count`` control points of order ``order``.

    Parameters
    ----------
    count : int
        Number of control points (``n + 1``), at least ``order``.
    order : int
        The curve's order ``k`` (degree ``k - 1``), at least 2.

    Returns
    -------
    numpy.ndarray
        ``count + order`` knots: ``order`` zeros, the integers 1 .. ``count - order``, ``order`` times
        ``count - order + 1`` (dimensionless).
    """
    if order < 2 or count < order:
        raise ValueError(f"a NURBS of order {order} needs at least {max(order, 2)} control points, not {count}")
    inner = np.arange(1, count - order + 1, dtype=np.float64)
    end = float(count - order + 1)
    return np.concatenate((np.zeros(order), inner, np.full(order, end)))


def nurbs_points(ctrl: np.ndarray, weights: np.ndarray, order: int, u: np.ndarray) -> np.ndarray:
    """Points of the NURBS curve at the parameters ``u`` (de Boor's algorithm in homogeneous coordinates).

    Parameters
    ----------
    ctrl : numpy.ndarray
        Control points, shape ``(n + 1, 2)`` (any length unit).
    weights : numpy.ndarray
        Their weights, shape ``(n + 1,)``, all positive.
    order : int
        The order ``k`` (degree ``k - 1``).
    u : numpy.ndarray
        Parameters in ``[0, n - k + 2]`` (dimensionless), shape ``(m,)``.

    Returns
    -------
    numpy.ndarray
        The curve's points, shape ``(m, 2)``, in the unit of ``ctrl``.
    """
    ctrl = np.asarray(ctrl, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    count = ctrl.shape[0]
    knots = clamped_knots(count, order)
    p = order - 1
    # span s with knots[s] <= u < knots[s + 1], p <= s <= n (the end parameter takes the last span)
    span = np.clip(np.searchsorted(knots, u, side="right") - 1, p, count - 1)
    homo = np.column_stack((ctrl * w[:, None], w))
    d = [homo[span - p + j] for j in range(p + 1)]  # each (m, 3)
    for r in range(1, p + 1):
        for j in range(p, r - 1, -1):
            lo = knots[span - p + j]
            hi = knots[span + 1 + j - r]
            alpha = ((u - lo) / (hi - lo))[:, None]
            d[j] = (1.0 - alpha) * d[j - 1] + alpha * d[j]
    out = d[p]
    return out[:, :2] / out[:, 2:3]


def nurbs_chord_parameters(ctrl: np.ndarray, weights: np.ndarray, order: int, tol: float,
                           max_chords: int) -> np.ndarray | None:
    """Parameters of chord ends whose chords stay within ``tol`` of the curve.

    Each knot span is cut into equal parameter steps ``h`` with ``h**2 / 8 * max|C''| <= tol``: a chord between
    two curve points at ``u0`` and ``u0 + h`` is the linear interpolant of the curve there, which misses it by at
    most ``h**2 / 8`` times the largest second derivative ``|C''(u)|`` over the step (the interpolation error of a
    vector function). ``max|C''|`` of a span is estimated from second differences of
    ``_SAMPLES_PER_SPAN`` samples, with a margin of ``_SECOND_DERIVATIVE_MARGIN``.

    Parameters
    ----------
    ctrl, weights, order
        The curve, as :func:`nurbs_points` takes it.
    tol : float
        Largest distance of a chord from the curve, in the unit of ``ctrl``.
    max_chords : int
        The most chords the caller accepts.

    Returns
    -------
    numpy.ndarray or None
        The chord ends' parameters, increasing, the last the curve's end (the start, 0, not included); None when
        more than ``max_chords`` chords would be needed.
    """
    count = np.asarray(ctrl).shape[0]
    end = count - order + 1
    pieces: list[np.ndarray] = []
    total = 0
    for a in range(end):
        s = np.linspace(a, a + 1, _SAMPLES_PER_SPAN + 1)
        h = 1.0 / _SAMPLES_PER_SPAN
        pts = nurbs_points(ctrl, weights, order, s)
        second = np.hypot(*(pts[2:] - 2.0 * pts[1:-1] + pts[:-2]).T) / (h * h)
        bound = float(second.max()) * _SECOND_DERIVATIVE_MARGIN if second.size else 0.0
        if not math.isfinite(bound):
            return None
        n = max(1, math.ceil(math.sqrt(bound / (8.0 * tol)))) if bound > 0 else 1
        total += n
        if total > max_chords:
            return None
        pieces.append(a + np.arange(1, n + 1) / n)
    u = np.concatenate(pieces)
    u[-1] = float(end)
    return u


@dataclass(slots=True)
class NurbsBlock:
    """An open ``G5.2`` block: its line, the order, the control points read so far (consistent frame, mm) with
    their weights, and the offset and move flags of the G5.2 line.

    LinuxCNC's reading, measured with rs274 and the ``gcode`` module (``tests/test_nurbs.py``): the current point
    is the first control point, with weight 1 or the P of a G5.2 line without X and Y; a G5.2 line with X and Y
    adds a control point; every following line with X and Y adds one and needs a positive P; L (an integer, on
    the G5.2 line) is the order, 3 without one; ``G5.3`` ends the block and moves along the curve; after it no
    motion mode is active. What LinuxCNC reads in a way ilcnc does not follow raises ``Unmodelled``.
    """

    line: int
    order: int
    offset: tuple[float, float, float]
    flags: int
    points: list[tuple[float, float]] = field(default_factory=list)
    weights: list[float] = field(default_factory=list)

    @staticmethod
    def open_words(letters: dict[str, Word], line: int) -> tuple[int, float, bool]:
        """Check a G5.2 line's words; its order, the weight P (1 without one) and whether it has a control point.

        Raises ``Unmodelled`` for what LinuxCNC refuses (one of X and Y, a weight not positive, L not an integer)
        and for what it reads but ilcnc does not follow."""
        extra = sorted(set(letters) - _OPEN_WORDS)
        if extra:
            raise Unmodelled(line, f"G5.2 with {', '.join(extra)} words is not modelled (a NURBS block has X Y P L)")
        has_xy = _both_xy(letters, line)
        if has_xy and "P" not in letters:
            # measured: rs274 takes an undefined weight for this point (the gcode module's curve left by 1e15 mm)
            raise Unmodelled(line, "G5.2 X Y without a P word: LinuxCNC reads an undefined weight for that control"
                                   " point; give the weight (P1)")
        weight = _weight(letters, line) if "P" in letters else 1.0
        order = DEFAULT_ORDER
        if "L" in letters:
            lv = letters["L"].value
            if abs(lv - round(lv)) > 1e-6:
                raise Unmodelled(line, f"G5.2 L{lv:g}: the order L must be an integer")
            order = round(lv)
            if order < 3:
                # measured: LinuxCNC's L2 curve is not the polyline of the control points; L0 and L1 are no order
                raise Unmodelled(line, f"G5.2 L{order}: NURBS orders below 3 are not modelled (LinuxCNC reads them"
                                       " without an error, L2 not as the polyline of its control points)")
        return order, weight, has_xy

    def point_words(self, letters: dict[str, Word], line: int) -> float | None:
        """Check a line inside the block (no G or M code); the weight of its control point, None without one."""
        extra = sorted(set(letters) - _POINT_WORDS)
        if extra:
            raise Unmodelled(line, f"{', '.join(extra)} words inside the G5.2 NURBS block of line {self.line} are not"
                                   " modelled (a control point has X Y P)")
        if not _both_xy(letters, line):
            if "P" in letters:
                raise Unmodelled(line, "P word without X and Y inside a G5.2 NURBS block is not modelled")
            return None
        if "P" not in letters:
            raise Unmodelled(line, "must specify a positive weight P for every NURBS control point")
        return _weight(letters, line)

    def chord_ends(self, line: int, tol: float, max_chords: int) -> np.ndarray:
        """The curve's chord ends (consistent frame, mm), the start excluded, each chord within ``tol`` mm of the
        curve (:func:`nurbs_chord_parameters`); ``Unmodelled`` at ``line`` (the G5.3) for too few control points
        (as LinuxCNC) or too many chords."""
        count = len(self.points)
        if count < self.order:
            raise Unmodelled(line, f"a NURBS of order L={self.order} needs at least {self.order} control points (the"
                                   f" current point and those of the block), this one has {count}")
        ctrl = np.array(self.points, dtype=np.float64)
        w = np.array(self.weights, dtype=np.float64)
        u = nurbs_chord_parameters(ctrl, w, self.order, tol, max_chords)
        if u is None:
            raise Unmodelled(line, f"G5.2 NURBS curve needs more than {max_chords:,} chords of {tol * 1e3:g} µm:"
                                   " not modelled")
        pts = nurbs_points(ctrl, w, self.order, u)
        pts[-1] = ctrl[-1]  # the curve ends at the last control point (clamped knots)
        return pts


def _both_xy(letters: dict[str, Word], line: int) -> bool:
    """Whether a NURBS line names a control point; LinuxCNC's error for one of X and Y alone."""
    if ("X" in letters) != ("Y" in letters):
        raise Unmodelled(line, "must specify both X and Y coordinates for a NURBS control point")
    return "X" in letters


def _weight(letters: dict[str, Word], line: int) -> float:
    pv = letters["P"].value
    if not pv > 0:
        raise Unmodelled(line, f"P{pv:g}: a NURBS control point's weight must be positive")
    return float(pv)

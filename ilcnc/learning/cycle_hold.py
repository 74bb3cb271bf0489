"""The cycle-time budget of geometric learning: corrections that slow the planner are held back.

A corrected end point bends the commanded path; where that bend lies within a corner the planner already runs
at its tolerance (``G64 P``, the profile's corner tolerance), the planner must take the corner slower to keep
its rounding of the *commanded* path within that tolerance -- a real blending planner does the same. On the
example mill the learned corners of square.ngc cost +3.9 % cycle time, Gates_combined_R12 +11 %.

``learning.cycle_budget_pct`` bounds that cost. When a proposed correction's program plans longer than the
original program's cycle time plus the budget, :func:`hold_cycle_time` finds the moves the planner slowed
(against the original program's plan) and halves the new part of the correction (``U_new - U_prev``) of every
command within ``NEIGHBOUR_MOVES`` moves of them, re-plans, and repeats; after ``HALVINGS`` halvings those
commands keep their previous correction. Every coordinate held is reported as a clip with the cause
``"cycle time"`` (:data:`CLIP_CYCLE`): a limiter on the law's output, counted like the correction bound.

Only the plan is re-run (not the drives nor the contour error): the planner alone sets the cycle time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["CLIP_CYCLE", "HALVINGS", "NEIGHBOUR_MOVES", "CycleHold", "hold_cycle_time", "slowed_moves"]

#: Why a correction was changed after the law computed it: it slowed the planner beyond the cycle-time budget.
CLIP_CYCLE = "cycle time"
#: Halvings of the new part of a held command's correction before it keeps its previous correction.
HALVINGS = 3
#: Commands within this many moves of a slowed move are held: the planner's corner speed depends on every
#: direction change within its filters' span, and refinement puts a corner's handles within a few moves of it.
NEIGHBOUR_MOVES = 2
#: A move counts as slowed when it takes more than this many servo periods longer than in the original plan
#: (one period: the interpolator's rounding of a move's end to a tick).
SLOWED_PERIODS = 1


@dataclass(frozen=True, slots=True)
class CycleHold:
    """What :func:`hold_cycle_time` did.

    Attributes
    ----------
    corrections_mm : ndarray (K, 3)
        The corrections after holding, mm.
    held : ndarray (K,) bool
        Commands whose correction was held back.
    rounds : int
        Re-plans made (0: the proposal was within the budget).
    cycle_time_s : float
        Planned cycle time of the returned corrections, s.
    within : bool
        The returned corrections plan within the budget.
    """

    corrections_mm: NDArray[np.float64]
    held: NDArray[np.bool_]
    rounds: int
    cycle_time_s: float
    within: bool


def slowed_moves(times_s: NDArray[np.float64], times0_s: NDArray[np.float64], period_s: float) -> NDArray[np.bool_]:
    """Moves planned more than :data:`SLOWED_PERIODS` servo periods longer than in the original plan (M,)."""
    return np.asarray(times_s) > np.asarray(times0_s) + (SLOWED_PERIODS + 0.5) * period_s


def _near(mask: NDArray[np.bool_], width: int) -> NDArray[np.bool_]:
    """``mask`` widened by ``width`` entries on each side."""
    if width <= 0 or not mask.any():
        return mask.copy()
    c = np.concatenate(([0], np.cumsum(mask.astype(np.int64))))
    n = mask.shape[0]
    i = np.arange(n)
    return c[np.minimum(i + width + 1, n)] - c[np.maximum(i - width, 0)] > 0


def hold_cycle_time(u_prev_mm: NDArray[np.float64], u_new_mm: NDArray[np.float64],
                    plan: Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], float]],
                    times0_s: NDArray[np.float64], limit_s: float, command_of_move: NDArray[np.integer],
                    period_s: float, *, resolution_mm: float = 0.0) -> CycleHold:
    """Hold back the corrections that slow the planner until the program plans within ``limit_s``.

    Parameters
    ----------
    u_prev_mm, u_new_mm : ndarray (K, 3)
        The correction of the program the proposal starts from, and the law's proposal, mm.
    plan : callable
        ``plan(u) -> (times_s (M,), cycle_time_s)``: each move's planned time and the cycle time of the program
        with corrections ``u``, s.
    times0_s : ndarray (M,)
        Each move's planned time in the original program, s.
    limit_s : float
        The longest cycle time allowed (the original's plus the budget), s.
    command_of_move : ndarray (M,) int
        Command index of each move (-1: not a correctable straight feed).
    period_s : float
        Servo period, s.
    resolution_mm : float
        The machine's resolution: a held correction is rounded to it, as the law's are, mm.

    Returns
    -------
    CycleHold
    """
    u_prev = np.asarray(u_prev_mm, dtype=np.float64)
    u = np.asarray(u_new_mm, dtype=np.float64).copy()
    k = u.shape[0]
    held = np.zeros(k, dtype=bool)
    times, cycle = plan(u)
    rounds = 0
    # a command's share of its new correction: 1, then halved at every round it is held, 0 after HALVINGS
    share = np.ones(k)
    cmd = np.asarray(command_of_move)
    while cycle > limit_s:
        slow = _near(slowed_moves(times, times0_s, period_s), NEIGHBOUR_MOVES)
        ks = np.unique(cmd[slow & (cmd >= 0)])
        ks = ks[share[ks] > 0.0]
        if ks.size == 0:
            break
        share[ks] = np.where(share[ks] <= 0.5 ** HALVINGS, 0.0, 0.5 * share[ks])
        held[ks] = True
        u = u_prev + share[:, None] * (np.asarray(u_new_mm) - u_prev)
        if resolution_mm > 0:
            u = np.round(u / resolution_mm) * resolution_mm
        times, cycle = plan(u)
        rounds += 1
    return CycleHold(u, held, rounds, float(cycle), bool(cycle <= limit_s))

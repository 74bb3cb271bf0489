"""The cycle-time budget of geometric learning: corrections that slow the planner are held back.

A corrected end point bends the commanded path; where that bend lies within a corner the planner already runs
at its tolerance (``G64 P``, the profile's corner tolerance), the planner must take the corner slower to keep
its rounding of the *commanded* path within that tolerance -- a real blending planner does the same. On the
example mill the learned corners of square.ngc cost +3.9 % cycle time, Gates_combined_R12 +11 %.

``learning.cycle_budget_pct`` bounds that cost. When a proposed correction's program plans longer than the
original program's cycle time plus the budget, :func:`hold_cycle_time` finds the spots the planner slowed
(:func:`slowed_spots`: runs of moves within ``NEIGHBOUR_MOVES`` moves of a move planned longer than in the plan
of the program the proposal starts from) and ranks them by their extra time per mm of new correction
(``|U_new - U_prev|`` summed over the spot's commands: the error the law addresses there). Costliest first, it
halves the new part of the correction of a spot's commands until the halvings' assumed saving (half a spot's
extra time; all of it at its last hold) covers the excess, re-plans, and repeats with the spots still slowed;
after ``HALVINGS`` halvings a command keeps its previous correction. A small budget so goes to the corrections
that buy the most error per second. Every coordinate held is reported as a clip with the cause
``"cycle time"`` (:data:`CLIP_CYCLE`): a limiter on the law's output, counted like the correction bound.

Only the plan is re-run (not the drives nor the contour error): the planner alone sets the cycle time.

:class:`CycleBudget` is the budget of one learning run, virtual or measured: the original program's plan (the
reference), the limit, the hold of a proposal and the messages. A measured step plans the proposal with the
profile's planner model (``planner.profile: linuxcnc`` is LinuxCNC's, :mod:`ilcnc.vcnc.plan_tp`) and compares it
with the plan of the original program by the same model, so like is compared with like; the log's own motion
time (:func:`motion_time_s`) is reported next to it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ilcnc.learning.feed import FeedLaw
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import Program
from ilcnc.wording import plural

__all__ = ["CLIP_CYCLE", "HALVINGS", "NEIGHBOUR_MOVES", "CycleBudget", "CycleHold", "hold_cycle_time", "motion_time_s",
           "slowed_moves", "slowed_spots"]

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


def slowed_spots(times_s: NDArray[np.float64], times_ref_s: NDArray[np.float64], period_s: float,
                 command_of_move: NDArray[np.integer], live: NDArray[np.bool_]
                 ) -> list[tuple[NDArray[np.intp], float]]:
    """The spots the planner slowed: each a run of moves within :data:`NEIGHBOUR_MOVES` moves of a slowed move.

    Parameters
    ----------
    times_s, times_ref_s : ndarray (M,)
        Each move's planned time with the proposal and in the reference plan, s.
    period_s : float
        Servo period, s.
    command_of_move : ndarray (M,) int
        Command index of each move (-1: not a correctable straight feed).
    live : ndarray (K,) bool
        Commands whose correction may still be held.

    Returns
    -------
    list of (ndarray of int, float)
        Per spot, in program order: its live commands (ascending, not empty) and its extra time against the
        reference (the sum of ``times_s - times_ref_s`` over its moves, at least 0), s.
    """
    near = _near(slowed_moves(times_s, times_ref_s, period_s), NEIGHBOUR_MOVES)
    if not near.any():
        return []
    edges = np.diff(np.concatenate(([0], near.astype(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    extra = np.asarray(times_s) - np.asarray(times_ref_s)
    cmd = np.asarray(command_of_move)
    spots = []
    for a, b in zip(starts, stops, strict=True):
        ks = np.unique(cmd[a:b][cmd[a:b] >= 0])
        ks = ks[live[ks]]
        if ks.size:
            spots.append((ks, max(float(extra[a:b].sum()), 0.0)))
    return spots


def hold_cycle_time(u_prev_mm: NDArray[np.float64], u_new_mm: NDArray[np.float64],
                    plan: Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], float]],
                    times0_s: NDArray[np.float64], limit_s: float, command_of_move: NDArray[np.integer],
                    period_s: float, *, resolution_mm: float = 0.0) -> CycleHold:
    """Hold back the corrections that slow the planner until the program plans within ``limit_s``, the costly
    spots first (see the module docstring).

    Parameters
    ----------
    u_prev_mm, u_new_mm : ndarray (K, 3)
        The correction of the program the proposal starts from, and the law's proposal, mm.
    plan : callable
        ``plan(u) -> (times_s (M,), cycle_time_s)``: each move's planned time and the cycle time of the program
        with corrections ``u``, s.
    times0_s : ndarray (M,)
        Each move's planned time in the original program, s (the reference when ``u_prev_mm`` is 0).
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
    u_full = np.asarray(u_new_mm, dtype=np.float64)
    u = u_full.copy()
    k = u.shape[0]
    held = np.zeros(k, dtype=bool)
    times, cycle = plan(u)
    rounds = 0
    if cycle <= limit_s:
        return CycleHold(u, held, rounds, float(cycle), True)
    du = u_full - u_prev
    # the error a command's new correction addresses: the law's step (|E(k)| times the command's gain for the
    # P law; the same ranking as |E(k)| on jsdc, measured), available to virtual and measured learning alike
    w = np.sqrt(np.einsum("ij,ij->i", du, du))
    # the reference: the plan of the program the proposal starts from (the hold goes back no further)
    times_ref = np.asarray(times0_s) if not np.any(u_prev) else plan(u_prev)[0]
    # a command's share of its new correction: 1, then halved at every round it is held, 0 after HALVINGS
    share = np.ones(k)
    live = np.any(du != 0.0, axis=1)
    while cycle > limit_s:
        spots = slowed_spots(times, times_ref, period_s, command_of_move, live & (share > 0.0))
        if not spots:
            break
        # seconds per mm of error addressed: the costliest first; ties in program order (deterministic)
        cost = np.array([extra for _ks, extra in spots])
        err = np.array([float(w[ks].sum()) for ks, _extra in spots])
        ratio = cost / np.maximum(err, np.finfo(np.float64).tiny)
        order = np.lexsort((np.arange(len(spots)), -ratio))
        need, saved = cycle - limit_s, 0.0
        for i in order:
            ks, extra = spots[i]
            # a halving is assumed to save half the spot's extra time, the last hold the rest
            last = share[ks].max() <= 0.5 ** HALVINGS
            share[ks] = np.where(share[ks] <= 0.5 ** HALVINGS, 0.0, 0.5 * share[ks])
            held[ks] = True
            saved += extra if last else 0.5 * extra
            if saved >= need:
                break
        u = u_prev + share[:, None] * du
        if resolution_mm > 0:
            u = np.round(u / resolution_mm) * resolution_mm
        times, cycle = plan(u)
        rounds += 1
    return CycleHold(u, held, rounds, float(cycle), bool(cycle <= limit_s))


def motion_time_s(t_s: NDArray[np.float64], pos_mm: NDArray[np.float64]) -> float | None:
    """The time from the first to the last change of a log's commanded position, s (its run's measured motion
    time: the log's lead-in and settle tail, where the command stands still, do not count).

    Parameters
    ----------
    t_s : ndarray (N,)
        Sample times, s.
    pos_mm : ndarray (N, 3)
        Commanded position of each sample, mm (a column the log lacks is NaN and is left out).

    Returns
    -------
    float or None
        None when the log has no commanded position or it never changes.
    """
    t = np.asarray(t_s, dtype=np.float64)
    pos = np.asarray(pos_mm, dtype=np.float64)
    cols = np.all(np.isfinite(pos), axis=0)
    if t.size < 2 or not cols.any():
        return None
    moved = np.flatnonzero(np.any(np.diff(pos[:, cols], axis=0) != 0.0, axis=1))
    if moved.size == 0:
        return None
    # a change between samples i and i+1: motion runs from sample first to sample last + 1
    return float(t[moved[-1] + 1] - t[moved[0]])


@dataclass(slots=True)
class CycleBudget:
    """``learning.cycle_budget_pct`` in one learning run, virtual or measured (see the module docstring).

    Attributes
    ----------
    program : Program
        The program learned on, uncorrected (refined, when refined): its plan is the budget's reference.
    profile : MachineProfile
        Its planner model, servo period, resolution and ``learning.cycle_budget_pct``.
    rewrite : callable
        ``rewrite(u_mm, feed_scale) -> Program``: the program with corrections ``u_mm`` (K, 3) and feed factors
        (M,) or None, as it will run.
    cycle0_s : float or None
        The original's planned cycle time, s (None: planned when first needed; virtual learning gives its first
        run's, which is that plan's).
    times0_s : ndarray (M,) or None
        Each move's planned time in the original, s (planned when first needed).
    spent_s : float
        Cycle time ``program`` already spends on refinement's tighter tolerance (``learning.refine.tolerance``),
        s: it counts inside the budget, so the corrections may add that much less.
    """

    program: Program
    profile: MachineProfile
    rewrite: Callable[[NDArray[np.float64], NDArray[np.float64] | None], Program]
    cycle0_s: float | None = None
    times0_s: NDArray[np.float64] | None = None
    spent_s: float = 0.0

    def _original(self) -> None:
        from ilcnc.vcnc.plan import planned_move_times_s

        self.times0_s, self.cycle0_s = planned_move_times_s(self.program, self.profile)

    @property
    def original_s(self) -> float:
        """The original program's planned cycle time, s."""
        if self.cycle0_s is None:
            self._original()
        assert self.cycle0_s is not None
        return self.cycle0_s

    def limit_s(self, feed_law: FeedLaw | None = None) -> float:
        """The longest cycle time the corrections may give, s (with feed learning, at least its own budget's)."""
        limit = self.original_s * (1.0 + self.profile.learning.cycle_budget_pct / 100.0) - self.spent_s
        return max(limit, feed_law.cycle0_s + feed_law.budget_s) if feed_law is not None else limit

    def planned_s(self, program: Program) -> float:
        """A program's cycle time on the profile's planner model, s."""
        from ilcnc.vcnc.plan import planned_duration_s

        return float(planned_duration_s(program, self.profile))

    def hold(self, u_prev_mm: NDArray[np.float64], u_new_mm: NDArray[np.float64],
             feed_scale: NDArray[np.float64] | None = None, feed_law: FeedLaw | None = None) -> CycleHold:
        """The proposal ``u_new_mm`` with the corrections that slow the planner held back (:func:`hold_cycle_time`;
        ``u_prev_mm``: the correction the proposal starts from). Within the budget it comes back unchanged
        (``rounds`` 0)."""
        from ilcnc.vcnc.plan import planned_move_times_s

        if self.times0_s is None:
            self._original()
        assert self.times0_s is not None

        def plan(u: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
            return planned_move_times_s(self.rewrite(u, feed_scale), self.profile)

        times0 = self.times0_s
        if feed_scale is not None and np.any(np.asarray(feed_scale) != 1.0) and not np.any(u_prev_mm):
            times0 = plan(np.asarray(u_prev_mm, dtype=np.float64))[0]  # the reference at the proposal's feeds
        return hold_cycle_time(u_prev_mm, u_new_mm, plan, times0, self.limit_s(feed_law),
                               self.program.moves.command, self.profile.machine.servo_period_s,
                               resolution_mm=self.profile.machine.resolution_mm)

    def stop_message(self, n_held: int) -> str:
        """Why learning stops when every correction left would be held."""
        return (f"every correction left would slow the planner beyond learning.cycle_budget_pct"
                f" ({self.profile.learning.cycle_budget_pct:g} % of cycle time; {plural(n_held, 'coordinate')} held)")

    def over_message(self, cycle_s: float, feed_law: FeedLaw | None = None) -> str:
        """The guard's words for a run over the budget."""
        return f"cycle time {cycle_s:.3f} s over the budget's {self.limit_s(feed_law):.3f} s"

    def note(self, what: str, cycle_s: float, motion_s: float | None = None) -> str:
        """One note for the user: ``what`` (a program) plans ``cycle_s`` on the profile's planner against the
        original and the limit; ``motion_s``: its log's measured motion time (:func:`motion_time_s`), s."""
        c0 = self.original_s
        change = f" ({cycle_s / c0 - 1.0:+.2%})" if c0 > 0 else ""
        text = (f"{what} plans {cycle_s:.3f} s on the profile's planner ({self.profile.planner.profile}), the original"
                f" {c0:.3f} s{change}; learning.cycle_budget_pct {self.profile.learning.cycle_budget_pct:g} % allows"
                f" {self.limit_s():.3f} s")
        if motion_s is not None:
            text += f"; its log's motion took {motion_s:.3f} s"
        return text

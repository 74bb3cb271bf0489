"""The feed as a second degree of freedom of the learning (``learning.refine.feed``).

Where the geometry cannot be shaped (an arc, whose end points are held; a
corner the planner already runs at its tolerance; a move whose corrections
would cost more time in the planner than they save) the contour error still
falls with the speed: a drive that lags by a time ``τ`` cuts a corner or an
arc by an amount that grows with the feed (the lag length ``v·τ``, the arc's
shrinkage ``v²τ²/(2R)``). Ward et al. (seed 004) judge a program by its form
error without longer machining, so the feed is spent sparingly: a
*budget* of cycle time (``feed_budget_pct``, default +2 % of the original's)
goes to the moves with the largest error first.

Each iteration, per feed move ``m`` with error ``e_m`` (the largest contour
error of the cutting samples whose nearest point or whose reference lies on
the move, mm) and feed factor ``s_m`` (1 = as programmed)::

    s_m ← clip(s_m · min(1, T / e_m)^γ, feed_min_ratio, 1)

a multiplicative step down to the *water level* ``T`` (``γ`` a gain, 1). A
move above the level is slowed; a feed is never given back, since that would
re-time the path the geometry has learned on. ``T`` is the lowest level (not below the
physical floor, twice the resolution) whose predicted cycle time fits the
budget. The time model is the planner's own: move ``m`` took ``t_m`` in the
original's run, and at feed ``s_m F_m`` it takes at least ``L_m / (s_m F_m)``,
so the cost is ``Σ max(0, L_m/(s_m F_m) − t_m)``, times a factor ``κ`` for the
braking and speeding up around a slowed move (1.5 at first; measured on
every run that comes out longer than predicted). The error is assumed to
fall in proportion to the speed (``e ∝ v``: the lag length; an arc's
shrinkage falls faster, so the step is on the safe side), and every step is
judged by the next run: the guard refuses an iteration whose cutting error
grew or whose cycle time left the budget.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ilcnc.wording import plural

__all__ = ["FeedLaw", "feed_cost_s", "move_errors_mm", "move_times_s"]

#: First guess of the time the braking and speeding up around slowed moves adds, as a factor on the time model.
KAPPA_START = 1.5


def move_times_s(move: NDArray[np.integer], period_s: float, n_moves: int) -> NDArray[np.float64]:
    """Time the reference spent on each move, s (M,): its samples times the servo period."""
    mv = np.asarray(move)
    ok = mv >= 0
    return np.bincount(mv[ok], minlength=n_moves)[:n_moves].astype(np.float64) * float(period_s)


def move_errors_mm(dist_mm: NDArray[np.float64], cutting: NDArray[np.bool_], foot_move: NDArray[np.integer],
                   ref_move: NDArray[np.integer], n_moves: int) -> NDArray[np.float64]:
    """Largest contour error of the cutting samples per move, mm (M,).

    A sample counts for the move its nearest point on the drawing lies on and for the move its reference was on
    at that instant: the tool lags, so the error a corner shows is made by the motion just before it.
    """
    d = np.where(cutting & np.isfinite(dist_mm), dist_mm, 0.0)
    out = np.zeros(n_moves)
    for idx in (np.asarray(foot_move), np.asarray(ref_move)):
        ok = (idx >= 0) & (idx < n_moves) & (d > 0)
        np.maximum.at(out, idx[ok], d[ok])
    return out


def feed_cost_s(scale: NDArray[np.float64], length_mm: NDArray[np.float64], feed_mm_s: NDArray[np.float64],
                time0_s: NDArray[np.float64]) -> float:
    """Predicted extra cycle time of feed factors ``scale`` (M,) against the original's run, s (time model of
    the module docstring, without ``κ``)."""
    slow = scale < 1.0
    if not slow.any():
        return 0.0
    t = length_mm[slow] / (scale[slow] * feed_mm_s[slow])
    return float(np.sum(np.maximum(0.0, t - time0_s[slow])))


@dataclass(slots=True)
class FeedLaw:
    """The feed-factor update of one learning run (module docstring).

    Attributes
    ----------
    adjustable : ndarray (M,) bool
        Cutting feed moves whose feed may change (:func:`ilcnc.program.feedwords.feed_moves`).
    length_mm, feed_mm_s, time0_s : ndarray (M,)
        Each move's length, programmed feed (mm/s) and time in the original's run (s).
    cycle0_s : float
        The original's cycle time, s.
    budget_s : float
        Most extra cycle time of the output against the original, s.
    min_ratio : float
        Least feed factor.
    floor_mm : float
        No move is slowed for an error at or below this (the physical floor), mm.
    kappa : float
        Factor of the time model (braking and speeding up), measured as the run goes.
    """

    adjustable: NDArray[np.bool_]
    length_mm: NDArray[np.float64]
    feed_mm_s: NDArray[np.float64]
    time0_s: NDArray[np.float64]
    cycle0_s: float
    budget_s: float
    min_ratio: float
    floor_mm: float
    kappa: float = KAPPA_START

    def cost_s(self, scale: NDArray[np.float64]) -> float:
        """Predicted extra cycle time of ``scale``, s (with ``κ``)."""
        return self.kappa * feed_cost_s(scale, self.length_mm, self.feed_mm_s, self.time0_s)

    def _step(self, scale: NDArray[np.float64], err: NDArray[np.float64], level: float, gain: float
              ) -> NDArray[np.float64]:
        out = scale.copy()
        a = self.adjustable
        ratio = np.minimum(level / np.maximum(err[a], 1e-12), 1.0)  # only ever lower: a feed given back re-times
        out[a] = np.clip(scale[a] * ratio ** gain, self.min_ratio, 1.0)  # the path the geometry learned on
        return np.minimum(out, scale)

    def propose(self, scale: NDArray[np.float64], err_mm: NDArray[np.float64], cycle_s: float, *,
                gain: float = 1.0) -> tuple[NDArray[np.float64], float]:
        """Next feed factors from the run of ``scale`` (its per-move errors ``err_mm`` and cycle time
        ``cycle_s``); returns them and the water level ``T`` (mm; inf: every feed back to 1)."""
        scale = np.asarray(scale, dtype=np.float64)
        err = np.asarray(err_mm, dtype=np.float64)
        a = self.adjustable
        if not a.any():
            return scale.copy(), float("inf")
        # the cycle time the geometry alone gives: the run's, less what its feeds are predicted to cost
        room = self.cycle0_s + self.budget_s - (cycle_s - self.cost_s(scale))
        top = float(np.max(err[a]))
        if room <= 0.0 or top <= self.floor_mm:  # no time left, or every error at the floor: nothing to lower
            return scale.copy(), float("inf")
        lo, hi = max(self.floor_mm, 1e-9), max(top * 1.0001, self.floor_mm * 1.0001)
        if self.cost_s(self._step(scale, err, lo, gain)) <= room:
            return self._step(scale, err, lo, gain), lo
        for _ in range(60):  # bisection on log T: the cost falls as the level rises
            mid = float(np.sqrt(lo * hi))
            if self.cost_s(self._step(scale, err, mid, gain)) <= room:
                hi = mid
            else:
                lo = mid
            if hi / lo < 1.0 + 1e-6:
                break
        return self._step(scale, err, hi, gain), hi

    def measured(self, scale: NDArray[np.float64], cycle_s: float, cycle_before_s: float,
                 scale_before: NDArray[np.float64]) -> None:
        """Learn ``κ`` from a run: the extra time the feeds' change took against what the model predicted."""
        pred = feed_cost_s(scale, self.length_mm, self.feed_mm_s, self.time0_s) - feed_cost_s(
            scale_before, self.length_mm, self.feed_mm_s, self.time0_s)
        got = cycle_s - cycle_before_s
        if pred > 1e-6 and got > self.kappa * pred:
            self.kappa = min(got / pred, 20.0)


@dataclass(slots=True)
class FeedOutcome:
    """What the feed learning did to the output (reported per move).

    Attributes
    ----------
    slowed : list of dict
        One entry per move of the output that runs slower than programmed: ``move``, ``line``, ``k`` (command
        index, -1 for an arc), ``kind`` (``line`` / ``arc``), ``feed_mm_min`` (programmed, written) and
        ``error_mm`` (its largest cutting error in the first run).
    budget_pct : float
        The cycle-time budget, % of the original's cycle time.
    cycle_time_s : tuple of float
        Cycle time of the first run and of the output, s.
    not_adjustable : dict
        Cutting feed moves whose feed may not change, counted by reason.
    kappa : float
        The time model's factor at the end (measured braking and speeding up).
    """

    slowed: list[dict[str, object]]
    budget_pct: float
    cycle_time_s: tuple[float, float]
    not_adjustable: dict[str, int]
    kappa: float

    def to_json(self) -> dict[str, object]:
        a, b = self.cycle_time_s
        return {"slowed_moves": self.slowed, "budget_pct": self.budget_pct,
                "cycle_time_s": {"first": a, "output": b, "change": (b / a - 1.0) if a > 0 else 0.0},
                "not_adjustable": dict(self.not_adjustable), "time_model_factor": self.kappa}

    def notes(self, limit: int = 5) -> list[str]:
        a, b = self.cycle_time_s
        change = (b / a - 1.0) if a > 0 else 0.0
        n = len(self.slowed)
        out = [f"feed: {plural(n, 'move')} {'runs' if n == 1 else 'run'} slower than programmed (budget"
               f" +{self.budget_pct:g} % cycle"
               f" time; cycle time {a:.2f} -> {b:.2f} s, {change:+.2%})"]
        worst = sorted(self.slowed, key=lambda d: -float(d["error_mm"]))[:limit]  # type: ignore[arg-type]
        for d in worst:
            f0, f1 = d["feed_mm_min"]  # type: ignore[misc]
            out.append(f"feed: line {d['line']} ({d['kind']}) F {f0:g} -> {f1:g} mm/min"
                       f" (first-run error {float(d['error_mm']) * 1e3:.2f} µm)")  # type: ignore[arg-type]
        if len(self.slowed) > limit:
            out.append(f"feed: ... and {len(self.slowed) - limit} more (--json lists every one)")
        for reason, n in sorted(self.not_adjustable.items(), key=lambda x: -x[1])[:3]:
            out.append(f"feed: {n} cutting moves keep their feed ({reason})")
        return out

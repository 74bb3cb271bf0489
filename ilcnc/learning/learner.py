"""Iterative learning control on G01 end points: the iteration driver.

The learning index is the G01 command k (seed 004): the correction ``U(k)``
(x, y, z, mm) is added to the programmed end point of command k, the machine
runs the corrected program, and the error ``E(k)`` measured on that run
(:mod:`ilcnc.vcnc.command_error`) drives the next correction through the
profile's law (:mod:`ilcnc.learning.laws`).

Around the law (:class:`UpdateShaper`, :class:`Learner`): a lead of
``learning.lead_commands`` commands (the error of command ``k + lead``
corrects command ``k``), an optional zero-phase low-pass Q-filter on the
update (Butterworth, forwards and backwards over time along each cut, so it
adds no phase lag), corrections clipped to ``learning.correction_bound_mm``
with every clip reported, commands that cannot be corrected (executed more
than once, parametric or polar words, machine-coordinate and home moves,
moves the reader generated) frozen at zero, arc starts kept on their circle
and no move turned around.

The driver (:func:`learn_virtual`) runs plan → drives → contour error →
``E(k)`` → law → bounded correction → rewritten program, judging each
program against the *original* drawing. Its monotonic-convergence guard
keeps an iteration only when neither the RMS nor the max contour error grew;
the first time one grows the gain is halved and the iteration retried from
the best program, the second time learning stops (status ``diverged``) and
the best program is the result. Outcomes are explicit states, not
exceptions: ``converged`` (max error below ``learning.stop_tolerance_mm``),
``stopped`` (no more improvement), ``diverged`` (the guard stopped it),
``max_iterations``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.contour.air import (
    MOVE_CUT,
    CuttingRule,
    air_above_mm,
    air_command_mask,
    cutting_samples,
    profile_cutting_rule,
    profile_move_classes,
)
from ilcnc.contour.figures import ErrorFigures
from ilcnc.errors import UnsupportedError
from ilcnc.learning.feed import FeedLaw, FeedOutcome, move_errors_mm, move_times_s
from ilcnc.learning.guard import LearningGuard
from ilcnc.learning.laws import AXES, LearningLaw, cut_runs, make_law
from ilcnc.outcomes import GuardVerdict, LearnStatus, ModelStepEnd
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import (
    FLAG_CUTTER_COMP,
    FLAG_DERIVED,
    FLAG_HOME,
    FLAG_MACHINE,
    FLAG_POLAR,
    FLAG_REPEATED,
    MOVE_ARC_CW,
    MOVE_RAPID,
    Program,
    center_arc_tolerance_mm,
)
from ilcnc.vcnc.command_error import CommandSignal, error_kind, measurement_gate_mm, signal_of_simulation
from ilcnc.wording import plural

__all__ = [
    "CLIP_ARC", "CLIP_BOUND", "CLIP_MOVE_LENGTH", "Clip", "IterationRecord", "LearnResult", "Learner", "UpdateShaper",
    "changed_coordinates", "clip_corrections", "correctable_commands", "keep_arcs_valid", "keep_moves_forward",
    "learn_virtual", "program_with_corrections"
]


#: Flags of commands whose end point is never corrected.
# (a G-code word with a parameter is corrected as [expression+c]; Klartext Q words are no commands)
FROZEN_FLAGS = FLAG_REPEATED | FLAG_POLAR | FLAG_MACHINE | FLAG_HOME | FLAG_DERIVED

#: Relative RMS improvement below which learning has "stopped improving".
STALL_REL = 0.01


# ---------------------------------------------------------------------------------------------
# Commands, cuts, the update shaper
# ---------------------------------------------------------------------------------------------


def correctable_commands(program: Program) -> NDArray[np.bool_]:
    """Commands whose end point may be corrected (see :data:`FROZEN_FLAGS`)."""
    flags = program.moves.flags[program.command_moves]
    return (flags & FROZEN_FLAGS) == 0


@dataclass(slots=True)
class UpdateShaper:
    """Lead, zero-phase Q-filter and correctability mask around a law.

    Parameters
    ----------
    runs : ndarray (K,) int
        Cut of each command (:func:`cut_runs`).
    correctable : ndarray (K,) bool
        Commands that may be corrected.
    lead_commands : int
        The error of command ``k + lead`` (same cut) corrects command k.
    q_filter_hz : float or None
        Cut-off of the zero-phase low-pass on the update, Hz.
    period_s : float
        Servo period, s (the time grid of the Q-filter).
    order : int
        Butterworth order of the Q-filter (applied twice: forwards and backwards).
    """

    runs: NDArray[np.int64]
    correctable: NDArray[np.bool_]
    lead_commands: int = 0
    q_filter_hz: float | None = None
    period_s: float = 1e-3
    order: int = 2

    def lead(self, e: NDArray[np.float64]) -> NDArray[np.float64]:
        """Shift ``e`` (K, ...) by the lead within each cut (the last commands of a cut keep the cut's last value)."""
        n = self.lead_commands
        if n <= 0 or e.shape[0] == 0:
            return e
        k = np.arange(e.shape[0])
        j = np.minimum(k + n, e.shape[0] - 1)
        # last index of each command's cut
        last = np.searchsorted(self.runs, self.runs, side="right") - 1
        j = np.minimum(j, last)
        return e[j]

    def filter(self, du: NDArray[np.float64], t_s: NDArray[np.float64]) -> NDArray[np.float64]:
        """Zero-phase low-pass of the update ``du`` (K, 3) over time, cut by cut."""
        fc = self.q_filter_hz
        if fc is None or du.shape[0] < 3:
            return du
        from scipy.signal import butter, sosfiltfilt

        out = du.copy()
        bounds = np.flatnonzero(np.diff(self.runs)) + 1
        starts = np.concatenate(([0], bounds))
        ends = np.concatenate((bounds, [du.shape[0]]))
        for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
            if e - s < 3:
                continue
            t = t_s[s:e]
            span = float(t[-1] - t[0])
            if not span > 0:
                continue
            # grid: the servo period, coarsened for long cuts (still >= 20 points per filter period)
            dt = max(self.period_s, min(1.0 / (20.0 * fc), span / 20.0))
            grid = t[0] + np.arange(int(span / dt) + 2) * dt
            nyq = 0.5 / dt
            if fc >= 0.99 * nyq:
                continue
            sos = butter(self.order, fc, fs=1.0 / dt, output="sos")
            tt = np.maximum.accumulate(t)  # time stamps may repeat (commands of zero duration)
            for a in range(3):
                col = du[s:e, a]
                if not np.any(col):
                    continue
                g = np.interp(grid, tt, col)
                pad = min(3 * (2 * self.order + 1) * 3, g.size - 1)
                f = sosfiltfilt(sos, g, padtype="even", padlen=pad)
                out[s:e, a] = np.interp(tt, grid, f)
        return out


def arc_start_constraint(program: Program) -> tuple[NDArray[np.int64], dict[str, NDArray[np.float64]]]:
    """Commands whose end point starts an arc, with what keeps that arc valid.

    The rewriter keeps an arc's centre and end point when its start moves, so
    a start moved off the circle makes the arc a spiral (most controls refuse
    a start and end radius that differ by more than a few µm) and a start
    moved past the end along a short arc turns it into a nearly full circle.

    Returns
    -------
    k : ndarray (J,)
        Commands followed directly by an arc.
    geometry : dict
        ``center``, ``start`` (J, 3) mm, ``axes`` (J, 3) plane axes (first,
        second, linear), ``direction`` (J,) +1 counter-clockwise, -1 clockwise,
        ``length_mm`` (J,) arc length in the plane.
    """
    from ilcnc.program.model import MOVE_ARC_CCW, MOVE_ARC_CW, PLANE_AXES

    mv = program.moves
    cm = program.command_moves
    nxt = cm + 1
    ok = nxt < len(mv)
    nk = np.where(ok, mv.kind[np.minimum(nxt, len(mv) - 1)], MOVE_RAPID) if len(mv) else np.zeros(0, np.int8)
    sel = np.flatnonzero(ok & ((nk == MOVE_ARC_CW) | (nk == MOVE_ARC_CCW)))
    arc = nxt[sel]
    axes = np.array([PLANE_AXES[int(p)] for p in mv.plane[arc]], dtype=np.int64).reshape(-1, 3)
    start = mv.start_mm[arc]
    center = mv.center_mm[arc]
    end = mv.end_mm[arc]
    rows = np.arange(arc.size)
    r0 = np.hypot(start[rows, axes[:, 0]] - center[rows, axes[:, 0]], start[rows, axes[:, 1]] - center[rows, axes[:, 1]])
    a0 = np.arctan2(start[rows, axes[:, 1]] - center[rows, axes[:, 1]], start[rows, axes[:, 0]] - center[rows, axes[:, 0]])
    a1 = np.arctan2(end[rows, axes[:, 1]] - center[rows, axes[:, 1]], end[rows, axes[:, 0]] - center[rows, axes[:, 0]])
    direction = np.where(mv.kind[arc] == MOVE_ARC_CCW, 1.0, -1.0)
    sweep = np.mod(direction * (a1 - a0), 2 * np.pi)
    sweep = np.where(sweep < 1e-12, 2 * np.pi, sweep) + 2 * np.pi * np.maximum(mv.turns[arc].astype(np.float64) - 1, 0)
    r1 = np.hypot(end[rows, axes[:, 0]] - center[rows, axes[:, 0]], end[rows, axes[:, 1]] - center[rows, axes[:, 1]])
    return sel, {"center": center, "start": start, "axes": axes, "direction": direction,
                 "length_mm": r0 * sweep, "radius_mm": r0, "end_radius_mm": r1,
                 "radial_mm": np.zeros(arc.size)}


def keep_arcs_valid(u: NDArray[np.float64], sel: NDArray[np.int64], geo: dict[str, NDArray[np.float64]],
                    *, share: float = 0.1) -> NDArray[np.float64]:
    """Restrict the corrections of arc-starting commands to what keeps their arc one the control runs.

    The in-plane part of the correction along the arc's tangent is kept, at
    most ``share`` of the arc's length, and the point is moved along the
    circle (same centre). The radial part is kept within ``geo["radial_mm"]``
    of the end's radius (0: none, the arc stays a true arc; more: the arc
    becomes a spiral whose start and end radii differ by at most that much,
    which controls run as a spiral, see
    :func:`~ilcnc.program.model.arc_off_circle`); the out-of-plane part is
    dropped.
    """
    if sel.size == 0:
        return u
    out = u.copy()
    ax = geo["axes"]
    rows = np.arange(sel.size)
    c1, c2 = geo["center"][rows, ax[:, 0]], geo["center"][rows, ax[:, 1]]
    p1, p2 = geo["start"][rows, ax[:, 0]], geo["start"][rows, ax[:, 1]]
    r = geo["radius_mm"]
    ang = np.arctan2(p2 - c2, p1 - c1)
    # unit tangent in the direction of travel
    t1, t2 = -np.sin(ang) * geo["direction"], np.cos(ang) * geo["direction"]
    uu = u[sel]
    along = uu[rows, ax[:, 0]] * t1 + uu[rows, ax[:, 1]] * t2
    lim = share * geo["length_mm"]
    along = np.clip(along, -lim, lim)
    with np.errstate(invalid="ignore", divide="ignore"):
        dang = np.where(r > 0, along / r, 0.0) * geo["direction"]
    radial = uu[rows, ax[:, 0]] * np.cos(ang) + uu[rows, ax[:, 1]] * np.sin(ang)
    lim_r = geo["radial_mm"]
    r1 = geo["end_radius_mm"]
    rn = np.clip(r + radial, r1 - lim_r, r1 + lim_r)
    rn = np.where(lim_r > 0, rn, r)
    n1, n2 = c1 + rn * np.cos(ang + dang), c2 + rn * np.sin(ang + dang)
    new = np.zeros_like(uu)
    new[rows, ax[:, 0]] = n1 - p1
    new[rows, ax[:, 1]] = n2 - p2
    out[sel] = new
    return out


def axes_free_to_move(program: Program) -> NDArray[np.bool_]:
    """(K, 3): may command k's end point move along each axis without rewriting another kind of block?

    The block after a command inherits an axis it does not write (modal
    coordinates), and an incremental word absorbs a moved start. When that
    block is not itself a G01 command (a rapid, a retract, a home move), moving
    command k along that axis would make the rewriter write a word into that
    block; the learning leaves that axis of command k alone instead, so the
    output differs from the input only in G01 coordinate words. Arcs that
    start at a command are handled by :func:`keep_arcs_valid`.
    """
    mv = program.moves
    cm = program.command_moves
    free = np.ones((cm.size, 3), bool)
    nxt = cm + 1
    has = nxt < len(mv)
    n = nxt[has]
    other = (mv.command[n] < 0) & (mv.kind[n] < MOVE_ARC_CW)
    needs_word = (mv.word_start[n] < 0) | mv.word_incremental[n]
    rows = np.flatnonzero(has)
    free[rows] = ~(other[:, None] & needs_word)
    return free


def start_corrections(program: Program) -> NDArray[np.int64]:
    """For each command, the command whose end point is its start (-1: the start is not a command's end)."""
    mv = program.moves
    cm = program.command_moves
    prev = cm - 1
    out = np.full(cm.size, -1, np.int64)
    ok = prev >= 0
    p = prev[ok]
    joined = np.all(np.abs(mv.end_mm[p] - mv.start_mm[cm[ok]]) <= 1e-9, axis=1)
    k_prev = mv.command[p].astype(np.int64)
    out[np.flatnonzero(ok)] = np.where(joined, k_prev, -1)
    return out


def keep_moves_forward(u: NDArray[np.float64], vec_mm: NDArray[np.float64], prev_k: NDArray[np.int64],
                       *, share: float = 0.5, passes: int = 4,
                       timed: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """Limit corrections so that no G01 move is turned around or shrunk to nothing.

    The corrected move ``d + U_k - U_prev`` of a move ``d`` must not differ
    from ``d`` by more than ``share·|d|``; a zero-length move keeps zero
    length (its end point follows its start point). Corrections bigger than
    that are scaled down (a few passes settle the coupling between neighbours).

    ``timed`` (K,) marks moves whose duration the program fixes (inverse-time
    feed, ``G93``: ``60/F`` s whatever their length): they are left as the
    law wants them. A speed feed (``G94``) makes a shrunk move shorter in time
    and a turned one run backwards, which the limiter prevents; a timed move
    keeps its instant, so its length protects nothing.
    """
    out = u.copy()
    length = np.linalg.norm(vec_mm, axis=1)
    has_prev = prev_k >= 0
    zero = length <= 1e-6
    if timed is not None:
        length = np.where(timed, np.inf, length)
        zero &= ~timed
    for _ in range(passes):
        up = np.where(has_prev[:, None], out[np.maximum(prev_k, 0)], 0.0)
        out[zero] = up[zero]
        diff = np.linalg.norm(out - up, axis=1)
        lim = share * length
        over = (~zero) & (diff > lim + 1e-12)
        if not over.any():
            break
        f = lim[over] / diff[over]
        out[over] = up[over] + (out[over] - up[over]) * f[:, None]
    return out


#: Why a correction was changed after the law computed it (:attr:`Clip.cause`).
CLIP_BOUND = "bound"  #: beyond ``learning.correction_bound_mm``
CLIP_MOVE_LENGTH = "move length"  #: it would turn a G01 move around or shrink it by more than half its length
CLIP_ARC = "arc start"  #: an arc's start must stay on its circle (the end point before it follows)


@dataclass(frozen=True, slots=True)
class Clip:
    """One coordinate of one command whose correction the tool changed after the law computed it.

    ``cause`` says why (:data:`CLIP_BOUND`, :data:`CLIP_MOVE_LENGTH`, :data:`CLIP_ARC`): every change of a
    law's output is counted and reported as a clip, not only the correction bound's.
    """

    k: int
    line: int
    axis: str
    wanted_mm: float
    applied_mm: float
    cause: str = CLIP_BOUND


def changed_coordinates(before: NDArray[np.float64], after: NDArray[np.float64], lines: NDArray[np.integer],
                        cause: str, *, tol_mm: float = 1e-9) -> list[Clip]:
    """A :class:`Clip` for every coordinate a limiter moved by more than ``tol_mm``."""
    ks, axs = np.nonzero(np.abs(after - before) > tol_mm)
    return [Clip(int(k), int(lines[k]), AXES[a], float(before[k, a]), float(after[k, a]), cause)
            for k, a in zip(ks.tolist(), axs.tolist(), strict=True)]


def clip_corrections(
    u: NDArray[np.float64], bound_mm: float, lines: NDArray[np.integer]
) -> tuple[NDArray[np.float64], list[Clip]]:
    """Clip every coordinate of ``u`` (K, 3) to ``±bound_mm``; report each clip with its source line."""
    clipped = np.clip(u, -bound_mm, bound_mm)
    return clipped, changed_coordinates(u, clipped, lines, CLIP_BOUND, tol_mm=0.0)


# ---------------------------------------------------------------------------------------------
# Iteration records and the driver
# ---------------------------------------------------------------------------------------------


@dataclass(slots=True, eq=False, kw_only=True)
class IterationRecord:
    """One learning iteration: the program run and what it measured.

    Attributes
    ----------
    iteration : int
        0 for the uncompensated program.
    stats : dict
        ``max``, ``mean``, ``rms`` contour error of the cutting moves against the original drawing, mm
        (:mod:`ilcnc.contour.air`; the guard judges these).
    corrections_mm : ndarray (K, 3)
        Correction ``U`` of the program of this iteration, mm.
    signal : CommandSignal or None
        ``E(k)`` measured on this iteration's run.
    clipped : list of Clip
        Clips made when computing this iteration's corrections.
    kept : bool
        The guard kept it (its RMS and max did not grow).
    gain_scale : float
        Factor on the law's error gains used to compute its corrections.
    text : str
        Program text of this iteration.
    run : object
        The run (``SimulationResult`` on the virtual CNC), for reports.
    timings_s : dict
        Wall time per stage, s.
    shares : dict
        Each error source's ``max`` / ``mean`` / ``rms``, mm, when geometric or
        cutting errors are on (``SimulationResult.shares``).
    air_stats : ErrorFigures or None
        The air moves' ``max`` / ``mean`` / ``rms``, mm (reported apart, never judged).
    cycle_time_s : float or None
        Cycle time of this iteration's program, s (a part is judged by its error without longer machining).
    feed_scale : ndarray (M,) or None
        Feed factor of every move of this iteration's program (``learning.refine.feed``; None: as programmed).
    """

    iteration: int
    stats: ErrorFigures
    corrections_mm: NDArray[np.float64]
    signal: CommandSignal | None
    clipped: list[Clip] = field(default_factory=list)
    kept: bool = True
    gain_scale: float = 1.0
    text: str = ""
    run: Any = None
    timings_s: dict[str, float] = field(default_factory=dict)
    shares: dict[str, dict[str, float]] = field(default_factory=dict)
    air_stats: ErrorFigures | None = None
    cycle_time_s: float | None = None
    feed_scale: NDArray[np.float64] | None = None

    def to_json(self) -> dict[str, Any]:
        out = {"iteration": self.iteration, "contour_error_mm": self.stats.to_json(),
               "clipped": len(self.clipped), "kept": self.kept, "gain_scale": self.gain_scale}
        if self.air_stats is not None:
            out["air_error_mm"] = self.air_stats.to_json()
        if self.cycle_time_s is not None:
            out["cycle_time_s"] = self.cycle_time_s
        if self.shares:
            out["error_shares_mm"] = {k: dict(v) for k, v in self.shares.items()}  # ErrorFigures: as simulate's
        if self.feed_scale is not None:
            out["slowed_moves"] = int(np.count_nonzero(self.feed_scale < 1.0))
        return out


@dataclass(slots=True, eq=False, kw_only=True)
class LearnResult:
    """Outcome of a learning run.

    Attributes
    ----------
    program : Program
        The original program.
    iterations : list of IterationRecord
        Every iteration run, kept or not (0 = uncompensated).
    status : str
        ``converged``, ``stopped``, ``diverged`` or ``max_iterations``.
    message : str
        One line saying why it ended.
    best : int
        Index in :attr:`iterations` of the best kept iteration (the output).
    frozen : int
        Commands never corrected (see :data:`FROZEN_FLAGS`; air commands apart).
    air_commands : int
        Commands in the air kept as programmed (``learning.air_moves: keep``).
    cutting : CuttingRule or None
        The rule that told cutting from air moves (:mod:`ilcnc.contour.air`).
    feed : FeedOutcome or None
        What the feed learning did (``learning.refine.feed: on``; :mod:`ilcnc.learning.feed`).
    """

    program: Program
    iterations: list[IterationRecord]
    status: LearnStatus
    message: str
    best: int
    frozen: int = 0
    air_commands: int = 0
    cutting: CuttingRule | None = None
    feed: FeedOutcome | None = None

    @property
    def best_record(self) -> IterationRecord:
        return self.iterations[self.best]

    @property
    def clips(self) -> list[Clip]:
        """Every clip of the corrections of the best program's history."""
        return [c for r in self.iterations if r.kept for c in r.clipped]

    def reduction(self, key: str = "rms") -> float:
        """Fractional reduction of a statistic from iteration 0 to the best iteration."""
        a = self.iterations[0].stats[key]
        b = self.best_record.stats[key]
        return float(1.0 - b / a) if a > 0 else 0.0

    def to_json(self, output: str | None) -> dict[str, Any]:
        return {
            "program": str(self.program.path),
            "output": output,
            "iterations": [r.to_json() for r in self.iterations],
            "status": self.status,
            "message": self.message,
            "best_iteration": self.iterations[self.best].iteration,
            "frozen_commands": self.frozen,
            "air_commands": self.air_commands,
            "cutting_rule": None if self.cutting is None else self.cutting.to_json(),
            "feed": None if self.feed is None else self.feed.to_json(),
        }


@dataclass(slots=True)
class Learner:
    """The law with its shaping, bound and frozen commands, for one program.

    :meth:`propose` computes the next correction from the kept history.
    """

    program: Program
    profile: MachineProfile
    law: LearningLaw
    shaper: UpdateShaper
    bound_mm: float
    arc_sel: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    arc_geo: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    prev_k: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))
    vec_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    free: NDArray[np.bool_] | None = None
    air_kept: NDArray[np.bool_] | None = None  # commands left as programmed because they are in the air
    timed: NDArray[np.bool_] | None = None  # inverse-time (G93) commands: keep_moves_forward leaves them alone

    @classmethod
    def for_program(cls, program: Program, profile: MachineProfile, law: LearningLaw | None = None) -> Learner:
        sec = profile.learning
        law = law if law is not None else make_law(profile, program)
        correctable = correctable_commands(program)
        air_kept = air_command_mask(program, profile) if sec.air_moves == "keep" else np.zeros(program.n_commands, bool)
        correctable = correctable & ~air_kept
        shaper = UpdateShaper(cut_runs(program), correctable, sec.lead_commands, sec.q_filter_hz,
                              profile.machine.servo_period_s)
        sel, geo = arc_start_constraint(program)
        # the corrected point is then rounded to the resolution (at most resolution / sqrt 2 away): stay that far
        # inside the control's limit, which the rewriter checks
        geo["radial_mm"][:] = max(0.0, min(sec.arc_start_radial_mm,
                                           center_arc_tolerance_mm(1.0) - profile.machine.resolution_mm))
        cm = program.command_moves
        vec = program.moves.end_mm[cm] - program.moves.start_mm[cm]
        program.resolve_spans()
        timed = np.isfinite(program.moves.block_time_s[cm])
        return cls(program, profile, law, shaper, sec.correction_bound_mm, sel, geo, start_corrections(program), vec,
                   axes_free_to_move(program), air_kept, timed if timed.any() else None)

    def axis_mask(self) -> NDArray[np.float64]:
        return np.array([1.0 if a in self.profile.axes else 0.0 for a in AXES])

    def free_coordinates(self) -> NDArray[np.bool_]:
        """(K, 3): the coordinates :meth:`propose` may move (correctable commands, the profile's axes, words
        free to change)."""
        out = self.shaper.correctable[:, None] & (self.axis_mask()[None, :] > 0)
        return out & self.free if self.free is not None else out

    def propose(
        self,
        u_hist: list[NDArray[np.float64]],
        sig_hist: list[CommandSignal],
        *,
        scale: float = 1.0,
    ) -> tuple[NDArray[np.float64], list[Clip]]:
        """``U_{i+1}``: the law on the (lead-shifted) errors, Q-filtered update, frozen commands, clipped."""
        e_hist = [self.shaper.lead(s.e_mm) for s in sig_hist]
        t_hist = [s.t_s for s in sig_hist]
        u_new = self.law.next_correction(u_hist, e_hist, t_hist, scale=scale)
        du = self.shaper.filter(u_new - u_hist[-1], t_hist[-1])
        du *= self.axis_mask()
        du[~self.shaper.correctable] = 0.0
        if self.free is not None:
            du[~self.free] = 0.0
        u_next = u_hist[-1] + du
        u_next[~self.shaper.correctable] = 0.0
        lines = self.program.command_line
        u_next, clips = clip_corrections(u_next, self.bound_mm, lines)
        # every later change of the law's output is reported as a clip with its cause (issue 22 item 1: the move
        # limiter removed up to 4.9 mm from 68-116 commands per update of seed 000 while 'clipped' said 0)
        before = u_next
        u_next = keep_arcs_valid(u_next, self.arc_sel, self.arc_geo)
        clips += changed_coordinates(before, u_next, lines, CLIP_ARC)
        if self.prev_k.size:
            before = u_next
            u_next = keep_moves_forward(u_next, self.vec_mm, self.prev_k, timed=self.timed)
            u_next[~self.shaper.correctable] = 0.0
            if self.free is not None:
                u_next[~self.free] = 0.0
            clips += changed_coordinates(before, u_next, lines, CLIP_MOVE_LENGTH)
            # the limiter moves an end point with its start: an arc's start must stay on its circle
            before = u_next
            u_next = keep_arcs_valid(u_next, self.arc_sel, self.arc_geo)
            clips += changed_coordinates(before, u_next, lines, CLIP_ARC)
        # a correction finer than the machine's resolution cannot be programmed: round it off
        # (so a coordinate that would only move by noise is not rewritten at all; not a clip: the written
        # number's own precision)
        res = self.profile.machine.resolution_mm
        if res > 0:
            u_next = np.round(u_next / res) * res
        return u_next, clips


@dataclass(slots=True)
class ModelSteps:
    """What the virtual-CNC steps after a measured step did (:func:`model_assisted_correction`).

    Attributes
    ----------
    made : int
        Model steps kept (0: the measured step alone was kept).
    predicted_rms_mm : list of float
        RMS ``|E(k)|``: measured, then as the model predicts it after the measured step and after each kept
        model step, mm.
    reason : str
        Why the steps ended (``"steps"``: all made; ``"no gain"``: the next one would not lower the predicted
        error; ``"law"``: the law keeps a history and takes no model step; ``"kind"``: the measurement's
        error estimate is not one the virtual CNC predicts, e.g. probed points).
    """

    made: int
    predicted_rms_mm: list[float]
    reason: ModelStepEnd

    def why(self, law: str, error: str) -> str:
        """Why the steps ended, as the end of a note (empty when all were made); every state handled."""
        match self.reason:
            case ModelStepEnd.STEPS:
                return ""
            case ModelStepEnd.NO_GAIN:
                return ": the next would not lower the predicted error"
            case ModelStepEnd.LAW:
                return f": the {law} law keeps a history"
            case ModelStepEnd.KIND:
                return f": the virtual CNC does not predict the {error} estimate"
        raise AssertionError(f"unhandled model-step end {self.reason!r}")


def virtual_run(original: Program, u_mm: NDArray[np.float64] | None, profile: MachineProfile, kind: str, *,
                sources: Any = None, free: NDArray[np.bool_] | None = None) -> tuple[Any, CommandSignal]:
    """Run ``original`` with corrections ``u_mm`` (K, 3; None or zeros: as it is) on the virtual CNC of
    ``profile``: the run (its ``stats``) and the ``E(k)`` it predicts, chunk by chunk where the profile allows.

    ``sources`` are the profile's error sources when already loaded (:class:`ilcnc.vcnc.machine_errors.ErrorSources`);
    ``free`` the coordinates the learning may move (the ``lifted`` estimate solves for those alone).
    """
    from ilcnc.vcnc.run import run_virtual
    from ilcnc.vcnc.stream import StreamedRun

    prog = original
    if u_mm is not None and np.any(u_mm):
        _text, prog = program_with_corrections(original, u_mm, profile)
    gate = measurement_gate_mm(profile)
    run = run_virtual(prog, profile, against=None if prog is original else original, kind=kind, sources=sources,
                      gate_mm=gate)
    if isinstance(run, StreamedRun):
        return run, run.signal
    return run, signal_of_simulation(run, original, kind, gate, profile=profile, free=free)


def model_assisted_correction(learner: Learner, u_meas: NDArray[np.float64], measured: CommandSignal,
                              u_step: NDArray[np.float64], clips_step: list[Clip], steps: int, *, scale: float = 1.0
                              ) -> tuple[NDArray[np.float64], list[Clip], ModelSteps]:
    """Refine a measured learning step with up to ``steps`` steps on the virtual CNC.

    The machine ran corrections ``u_meas`` and measured ``measured``; the law proposed ``u_step`` (with
    ``clips_step``) from it. For a correction ``u`` the virtual CNC predicts the error
    ``E_meas + S(u) − S(u_meas)``, where ``S`` is its own ``E(k)``: the measurement carries what the model
    gets wrong, the model only the *change* a new correction makes (model-assisted iterative learning). Each
    step applies the law to that prediction as a measured step would (same Q filter, bound, frozen
    commands). A step is kept only while the predicted RMS ``|E(k)|`` falls, so a model that disagrees with
    the machine stops early; the next measured run checks the result as usual (the learning guard).

    Returns the correction, its clips and what was done.
    """
    kind = measured.kind

    def rms(e: NDArray[np.float64], ok: NDArray[np.bool_]) -> float:
        return float(np.sqrt(np.mean(np.einsum("ij,ij->i", e[ok], e[ok])))) if ok.any() else 0.0

    pred = [rms(measured.e_mm, measured.valid)]
    if steps <= 0:
        return u_step, clips_step, ModelSteps(0, pred, ModelStepEnd.STEPS)
    if learner.law.memory != 1:
        return u_step, clips_step, ModelSteps(0, pred, ModelStepEnd.LAW)
    if kind not in ("path", "crossing", "lifted"):
        return u_step, clips_step, ModelSteps(0, pred, ModelStepEnd.KIND)  # e.g. probed points: no E(k) the model predicts
    from ilcnc.vcnc.machine_errors import ErrorSources

    profile, original = learner.profile, learner.program
    sources = ErrorSources.from_profile(profile)  # map, FRF and stock files read once for all the runs
    free = learner.free_coordinates()
    _run, s_meas = virtual_run(original, u_meas, profile, kind, sources=sources, free=free)

    def predicted(u: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_], float]:
        _run, s_u = virtual_run(original, u, profile, kind, sources=sources, free=free)
        ok = measured.valid & s_meas.valid & s_u.valid
        e = np.where(ok[:, None], measured.e_mm + s_u.e_mm - s_meas.e_mm, 0.0)
        return e, ok, rms(e, ok)

    e, ok, r = predicted(u_step)
    pred.append(r)
    u, clips, made, reason = u_step, clips_step, 0, ModelStepEnd.STEPS
    for j in range(1, steps + 1):
        u_new, clips_new = learner.propose([u], [CommandSignal(e, measured.t_s, ok, kind)], scale=scale)
        e_new, ok_new, r_new = predicted(u_new)
        if not r_new < r:
            reason = ModelStepEnd.NO_GAIN
            break
        u, clips, e, ok, r, made = u_new, clips_new, e_new, ok_new, r_new, j
        pred.append(r)
    return u, clips, ModelSteps(made, pred, reason)


def require_learnable(program: Program) -> None:
    """Raise :class:`UnsupportedError` (with the line) for a program the virtual CNC cannot run as the machine
    does: one it could not read in full, motion it does not model (a cycle's own), or cutter radius
    compensation (the machine runs the tool-centre path; issue 20 item 10)."""
    program.require_modelled()
    comp = np.flatnonzero(program.moves.flags & FLAG_CUTTER_COMP)
    if comp.size:
        raise UnsupportedError(program.path, int(program.moves.line[comp[0]]), "cutter radius compensation"
                               " (G41/G42, RL/RR) is active here: the machine runs the tool-centre path, which the"
                               " virtual CNC does not model; learning the programmed contour would correct another"
                               " path (learn a tool-centre program: CAM output with compensation in the computer,"
                               " G40 / R0)")


def program_with_corrections(
    program: Program, corrections_mm: NDArray[np.float64], profile: MachineProfile, *,
    feed_scale: NDArray[np.float64] | None = None,
) -> tuple[str, Program]:
    """Rewrite the program with corrections (and, with ``feed_scale`` (M,), each move's feed times its factor:
    ``learning.refine.feed``) and read the result back (what the machine will run)."""
    from ilcnc.program import read_program
    from ilcnc.program.rewrite import apply_corrections

    extra = None
    if feed_scale is not None and np.any(feed_scale != 1.0):
        from ilcnc.program.feedwords import feed_edits

        mv = program.moves
        extra = feed_edits(program, np.where(feed_scale != 1.0, mv.feed_mm_min * feed_scale, np.nan))
    text, _edits = apply_corrections(program, corrections_mm, min_decimals=profile.min_decimals(program.units),
                                     extra_edits=extra)
    prog = read_program(program.path, default_units=program.units, data=text.encode("latin-1"))
    return text, prog


def learn_virtual(
    program: Program,
    profile: MachineProfile,
    *,
    iterations: int | None = None,
    law: LearningLaw | None = None,
    keep_runs: bool = False,
    guard: bool = True,
    stop_on_stall: bool = True,
    initial_corrections_mm: NDArray[np.float64] | None = None,
    first_iteration: int = 0,
    progress: Callable[[int, int, str], None] | None = None,
    on_record: Callable[[IterationRecord], None] | None = None,
    error: str | None = None,
    initial_feed_scale: NDArray[np.float64] | None = None,
) -> LearnResult:
    """Learn corrections for a program on the virtual CNC of a profile.

    Parameters
    ----------
    program : Program
        The original program (the drawing every run is judged against).
    profile : MachineProfile
        Machine, planner, drives and ``learning`` section.
    iterations : int, optional
        Largest number of learning iterations (default ``learning.iterations``);
        every run after the first counts, kept or not.
    law : LearningLaw, optional
        Use this law instead of the profile's (e.g. with a per-command Γ).
    keep_runs : bool
        Keep each iteration's simulation in its record (memory: one run each). Without it, a run
        whose profile allows it goes chunk by chunk and keeps only its figures and ``E(k)``
        (:func:`ilcnc.vcnc.stream.simulate_streamed`: the same numbers, memory bounded by a chunk).
    guard : bool
        Apply the monotonic-convergence guard (default). ``False`` runs the
        law as printed, every iteration kept -- for reproducing a paper's
        iteration history, never for a program that goes to a machine.
    stop_on_stall : bool
        Stop when an iteration improves the RMS error by less than 1 %.
    initial_corrections_mm : ndarray (K, 3), optional
        Continue a run: start from the program with these corrections.
    first_iteration : int
        Number of the first record (a continued run goes on counting).
    progress : callable, optional
        ``progress(iteration, total, stage)`` as the loop goes.
    on_record : callable, optional
        Called with every iteration record as soon as it exists (the state
        directory writes each iteration's program and errors there, so a run
        killed later keeps every finished iteration).
    error : str, optional
        The error estimate (default: the profile's, :func:`ilcnc.vcnc.command_error.error_kind`).
    initial_feed_scale : ndarray (M,), optional
        Continue a run with ``learning.refine.feed: on``: the feed factor of every move of the program it
        continues (1: as programmed).

    Returns
    -------
    LearnResult
    """
    from ilcnc.vcnc.machine_errors import ErrorSources
    from ilcnc.vcnc.run import run_virtual
    from ilcnc.vcnc.stream import StreamedRun

    require_learnable(program)
    n_iter = profile.learning.iterations if iterations is None else int(iterations)
    kind = error_kind(profile) if error is None else error
    learner = Learner.for_program(program, profile, law)
    air = learner.air_kept if learner.air_kept is not None else np.zeros(program.n_commands, bool)
    frozen = int(np.count_nonzero(~learner.shaper.correctable & ~air))
    n_air = int(np.count_nonzero(air & correctable_commands(program)))
    rule = profile_cutting_rule(program, profile)

    sources = ErrorSources.from_profile(profile)  # map, FRF and stock files read once for all runs

    # a run that keeps only its figures goes chunk by chunk (bounded memory, the same numbers: ilcnc.vcnc.stream)
    feed_on = profile.learning.refine.feed == "on"
    # per-move figures for the feed learning need the whole run
    keep_samples = keep_runs or feed_on
    n_moves = len(program.moves)
    last_feed: dict[str, Any] = {}  # the last run's per-move errors and times (feed learning)
    if feed_on:
        rule_f, classes_f = profile_move_classes(program, profile)
        above_f = air_above_mm(program, rule_f, classes_f, resolution_mm=profile.machine.resolution_mm)

    free_coords = learner.free_coordinates()

    def run(prog: Program, it: int) -> tuple[Any, CommandSignal, dict[str, float]]:
        if progress:
            progress(it, n_iter, "simulate")
        t0 = time.perf_counter()
        sim = run_virtual(prog, profile, against=None if prog is program else program, kind=kind,
                          keep_samples=keep_samples, sources=sources, gate_mm=measurement_gate_mm(profile))
        if isinstance(sim, StreamedRun):
            timings = dict(sim.timings_s)
            timings["simulate"] = time.perf_counter() - t0 - timings["error"]
            return sim, sim.signal, timings
        t1 = time.perf_counter()
        if feed_on:
            ref_move = sim.reference.move
            cut = cutting_samples(ref_move, classes_f, sim.error.foot_mm[:, 2], above_f)
            last_feed["err"] = move_errors_mm(sim.error.dist_mm, cut, sim.error.seg, ref_move, n_moves)
            last_feed["time"] = move_times_s(ref_move, sim.period_s, n_moves)
        sig = signal_of_simulation(sim, program, kind, measurement_gate_mm(profile), profile=profile,
                                   free=free_coords)
        timings = dict(sim.timings_s)
        timings["error"] = time.perf_counter() - t1
        timings["simulate"] = t1 - t0
        return sim, sig, timings

    k = program.n_commands
    u0 = np.zeros((k, 3)) if initial_corrections_mm is None else np.asarray(initial_corrections_mm, dtype=np.float64)
    f0 = None
    if feed_on:
        f0 = np.ones(n_moves) if initial_feed_scale is None else np.asarray(initial_feed_scale, dtype=np.float64)
    if np.any(u0) or (f0 is not None and np.any(f0 != 1.0)):
        text0, prog0 = program_with_corrections(program, u0, profile, feed_scale=f0)
    else:
        text0, prog0 = program.text, program
    sim0, sig0, tim0 = run(prog0, 0)
    records = [IterationRecord(iteration=first_iteration, stats=sim0.stats, corrections_mm=u0, signal=sig0,
                               clipped=[], kept=True, gain_scale=1.0, text=text0, run=sim0 if keep_runs else None,
                               timings_s=tim0, shares=dict(sim0.shares), air_stats=sim0.air_stats,
                               cycle_time_s=float(sim0.cycle_time_s), feed_scale=f0)]
    feed_law, not_adjustable = (_feed_law(program, profile, classes_f, last_feed["time"], f0, float(sim0.cycle_time_s))
                                if f0 is not None else (None, {}))
    feed_err0 = last_feed.get("err")
    if on_record:
        on_record(records[0])
    stats0 = records[0].stats
    del sim0  # one run held at a time: a large program's run is several GB
    u_hist = [u0]
    s_hist = [sig0]
    err_best = feed_err0  # per-move errors of the best kept run (feed learning)
    stall_msg: str | None = None
    best = 0
    guard_ = LearningGuard(resolution_mm=profile.machine.resolution_mm)
    status, message = LearnStatus.MAX_ITERATIONS, f"ran {plural(n_iter, 'iteration')}"
    if stats0.max_mm <= profile.learning.stop_tolerance_mm:
        return LearnResult(program=program, iterations=records, status=LearnStatus.CONVERGED,
                           message=f"max contour error {stats0.max_mm * 1e3:.2f} µm is already within the stop tolerance",
                           best=0, frozen=frozen, air_commands=n_air, cutting=rule)
    if k == 0 or not sig0.valid.any():
        return LearnResult(program=program, iterations=records, status=LearnStatus.STOPPED,
                           message="the program has no G01 command to correct", best=0, frozen=frozen,
                           air_commands=n_air, cutting=rule)
    it = 0
    # learning.refine.feed: when the geometry stalls (or its step is refused twice), the next step lowers the
    # feed where the error is left (the geometry held), then the geometry learns on at the new feeds
    feed_step = False
    feed_done = feed_law is None
    while it < n_iter:
        it += 1
        if progress:
            progress(it, n_iter, "learn")
        t0 = time.perf_counter()
        best_rec_now = records[best]
        f_best = best_rec_now.feed_scale
        cycle_best = float(best_rec_now.cycle_time_s or 0.0)
        if feed_step:
            assert feed_law is not None and f_best is not None and err_best is not None
            u_new, clips = u_hist[-1], []
            f_new, _level = feed_law.propose(f_best, err_best, cycle_best)
            if np.array_equal(f_new, f_best):
                it -= 1
                feed_done = True
                feed_step = False
                if stall_msg is not None:
                    status, message = LearnStatus.STOPPED, stall_msg + "; no feed left to lower within the budget"
                    break
                continue
        else:
            u_new, clips = learner.propose(u_hist[-learner.law.memory:], s_hist[-learner.law.memory:],
                                           scale=guard_.gain_scale)
            f_new = f_best
        t_law = time.perf_counter() - t0
        t0 = time.perf_counter()
        text, prog = program_with_corrections(program, u_new, profile, feed_scale=f_new)
        t_write = time.perf_counter() - t0
        sim, sig, tim = run(prog, it)
        tim["law"] = t_law
        tim["write"] = t_write
        stats = sim.stats
        cycle = float(sim.cycle_time_s)
        worse, ref_stats = guard_.compare(stats, [r.stats for r in records if r.kept])
        assert ref_stats is not None  # iteration 0 is always kept
        if not guard:  # an unguarded run keeps every iteration; the reference still names what grew
            worse = []
        if feed_step:
            assert feed_law is not None and f_new is not None and f_best is not None
            feed_law.measured(f_new, cycle, cycle_best, f_best)
            if guard and cycle > feed_law.cycle0_s + feed_law.budget_s:
                worse.append("cycle")
            if guard and not worse and stats.max_mm >= ref_stats.max_mm:
                worse.append("max")  # a feed step is taken for the max: one that does not lower it costs time
        rec = IterationRecord(iteration=first_iteration + it, stats=stats, corrections_mm=u_new, signal=sig,
                              clipped=clips, kept=not worse, gain_scale=guard_.gain_scale, text=text,
                              run=sim if keep_runs else None, timings_s=tim, shares=dict(sim.shares),
                              air_stats=sim.air_stats, cycle_time_s=cycle, feed_scale=f_new)
        del sim, prog  # one run held at a time: a large program's run is several GB
        records.append(rec)
        if on_record:
            on_record(rec)
        if worse:
            what = " and ".join(_grown(w, ref_stats, stats, rec, feed_law) for w in worse)
            if feed_step:  # the feed learning ends; the geometry's outcome stands
                feed_step, feed_done = False, True
                status = LearnStatus.STOPPED
                message = f"the feed step of iteration {rec.iteration} did not lower the error ({what})"
                break
            match guard_.refuse():
                case GuardVerdict.HALVED:
                    continue
                case GuardVerdict.STOPPED:
                    if not feed_done:
                        feed_step, stall_msg = True, None
                        continue
                    status = LearnStatus.DIVERGED
                    message = guard_.stopped_message(rec.iteration, what)
                    break
        prev_rms = records[best].stats.rms_mm
        best = len(records) - 1
        err_best = last_feed.get("err")
        u_hist.append(u_new)
        s_hist.append(sig)
        if stats.max_mm <= profile.learning.stop_tolerance_mm:
            status = LearnStatus.CONVERGED
            message = (f"max contour error {stats.max_mm * 1e3:.3f} µm is within the stop tolerance "
                       f"{profile.learning.stop_tolerance_mm * 1e3:g} µm after iteration {rec.iteration}")
            break
        if feed_step:  # kept: the geometry learns on at the new feeds
            feed_step, guard_.halved = False, False
            continue
        if stop_on_stall and prev_rms - stats.rms_mm < STALL_REL * prev_rms:
            # the message says what happened: a kept iteration may also be a hair worse (within the guard's tolerance)
            how = (f"improved the RMS contour error by less than {STALL_REL:.0%}" if stats.rms_mm < prev_rms
                   else "did not improve the RMS contour error")
            stall_msg = f"iteration {rec.iteration} {how} ({prev_rms * 1e3:.3f} → {stats.rms_mm * 1e3:.3f} µm)"
            if not feed_done:
                feed_step = True
                continue
            status = LearnStatus.STOPPED
            message = stall_msg
            break
    # the output: the kept iteration with the lowest RMS error (a kept iteration may be a hair
    # worse than the one before, within the resolution); unguarded runs keep every iteration
    kept_idx = [i for i, r in enumerate(records) if r.kept]
    if feed_law is not None:  # feed steps are taken for the max
        best = min(kept_idx, key=lambda i: (records[i].stats.max_mm, records[i].stats.rms_mm, -i))
    else:
        best = min(kept_idx, key=lambda i: (records[i].stats.rms_mm, -i))
    if status == LearnStatus.MAX_ITERATIONS:
        message = f"ran {plural(n_iter, 'iteration')}"
    if status in (LearnStatus.MAX_ITERATIONS, LearnStatus.DIVERGED):
        message += f"; the output is iteration {records[best].iteration}"
    feed_out = None
    if feed_law is not None:
        feed_out = _feed_outcome(program, profile, feed_law, not_adjustable, records[best], records[0], feed_err0)
    return LearnResult(program=program, iterations=records, status=status, message=message, best=best, frozen=frozen,
                       air_commands=n_air, cutting=rule, feed=feed_out)


def _grown(what: str, ref: Mapping[str, float], new: Mapping[str, float], rec: IterationRecord,
           feed_law: FeedLaw | None) -> str:
    """One grown figure for the guard's message."""
    if what == "cycle":
        assert feed_law is not None and rec.cycle_time_s is not None
        limit = feed_law.cycle0_s + feed_law.budget_s
        return f"cycle time {rec.cycle_time_s:.2f} s over the feed budget's {limit:.2f} s"
    return LearningGuard.grown(what, ref, new)


def _feed_law(program: Program, profile: MachineProfile, classes: NDArray[np.int8], time_s: NDArray[np.float64],
              scale0: NDArray[np.float64], cycle_s: float) -> tuple[FeedLaw, dict[str, int]]:
    """The feed law of a run from its first run (its per-move times ``time_s`` and cycle time, :mod:`ilcnc.learning.feed`),
    and the cutting moves whose feed may not change, counted by reason."""
    from ilcnc.program.feedwords import feed_moves
    from ilcnc.program.geometry import move_lengths_mm

    sec = profile.learning.refine
    mv = program.moves
    ok, refused = feed_moves(program)
    not_adjustable: dict[str, int] = {}
    for i, why in refused:
        if classes[i] == MOVE_CUT:
            not_adjustable[why] = not_adjustable.get(why, 0) + 1
    length = move_lengths_mm(mv)  # an arc's along its circle (the planner's time is on the arc)
    feed_mm_s = np.where(np.isfinite(mv.feed_mm_min), mv.feed_mm_min, 0.0) / 60.0
    adjustable = ok & (classes == MOVE_CUT) & (length > 0) & (feed_mm_s > 0)
    time0 = np.asarray(time_s, dtype=np.float64).copy()
    slowed = scale0 < 1.0
    # a continued run: what its slowed moves took at the programmed feed is not measured; the ideal time stands in
    time0[slowed] = length[slowed] / np.maximum(feed_mm_s[slowed], 1e-12)
    law = FeedLaw(adjustable, length, feed_mm_s, time0, 0.0, 0.0, sec.feed_min_ratio,
                  max(2.0 * profile.machine.resolution_mm, profile.learning.stop_tolerance_mm))
    cycle0 = cycle_s - law.cost_s(scale0)
    law.cycle0_s = cycle0
    law.budget_s = sec.feed_budget_pct / 100.0 * cycle0
    return law, not_adjustable


def _feed_outcome(program: Program, profile: MachineProfile, law: FeedLaw, not_adjustable: dict[str, int],
                  best: IterationRecord, first: IterationRecord, err0: NDArray[np.float64] | None) -> FeedOutcome:
    from ilcnc.program import read_program

    mv = program.moves
    scale = best.feed_scale if best.feed_scale is not None else np.ones(len(mv))
    out_prog_feed = None
    if np.any(scale < 1.0):  # the feeds as written (rounded to the feed word's decimals): the output read back
        prog = read_program(program.path, default_units=program.units, data=best.text.encode("latin-1"))
        out_prog_feed = prog.moves.feed_mm_min
    slowed = []
    for i in np.flatnonzero(scale < 1.0):
        i = int(i)
        written = float(out_prog_feed[i]) if out_prog_feed is not None else float(mv.feed_mm_min[i] * scale[i])
        slowed.append({"move": i, "line": int(mv.line[i]), "k": int(mv.command[i]),
                       "kind": "line" if mv.kind[i] == 1 else "arc",
                       "feed_mm_min": [float(mv.feed_mm_min[i]), written],
                       "error_mm": float(err0[i]) if err0 is not None else float("nan")})
    return FeedOutcome(slowed, profile.learning.refine.feed_budget_pct,
                       (float(first.cycle_time_s or 0.0), float(best.cycle_time_s or 0.0)), not_adjustable, law.kappa)



@dataclass(slots=True, eq=False)
class Refinement:
    """A program refined for learning (:func:`refine_for_learning`).

    Attributes
    ----------
    program : Program
        The refined program: the original with the inserted straight feeds (the learning index from now on).
    plan : RefinePlan
        Where the points went and why (:mod:`ilcnc.learning.refine`).
    inserted : InsertResult
        The inserted lines, and the moves left alone with their reasons (:mod:`ilcnc.program.insert`).
    first_stats : dict
        The original program's first run: cutting moves' ``max`` / ``mean`` / ``rms``, mm.
    cycle_time_s : tuple of float
        Planned cycle time of the original and of the refined program, s.
    """

    program: Program
    plan: Any
    inserted: Any
    first_stats: dict[str, float]
    cycle_time_s: tuple[float, float]

    @property
    def cycle_change(self) -> float:
        a, b = self.cycle_time_s
        return b / a - 1.0 if a > 0 else 0.0

    def to_json(self) -> dict[str, Any]:
        out = self.plan.summary()
        out.update({"inserted_lines": self.inserted.n_inserted, "skipped_moves": len(self.inserted.skipped),
                    "renumbered": bool(self.inserted.renumbered), "first_run_mm": dict(self.first_stats),
                    "cycle_time_s": {"original": self.cycle_time_s[0], "refined": self.cycle_time_s[1]}})
        return out

    def notes(self) -> list[str]:
        """One line each for the user: what was inserted where, what was left alone and why, the cost."""
        js = self.plan.summary()
        out = [f"refined: {plural(self.inserted.n_inserted, 'line')} inserted on {plural(js['moves_split'], 'move')} at"
               f" {plural(js['corners'], 'corner')}, {plural(js['arcs'], 'arc junction')} and"
               f" {plural(js['rapids'], 'feed start')} after a rapid"
               f" (first-run error >= {js['threshold_mm'] * 1e3:.1f}"
               f" µm); planned cycle time {self.cycle_time_s[0]:.2f} -> {self.cycle_time_s[1]:.2f} s"
               f" ({self.cycle_change:+.2%})"]
        for reason, n in sorted(js["passed"].items()):
            out.append(f"refine: {plural(n, 'spot')} left alone ({reason})")
        reasons: dict[str, int] = {}
        for s in self.inserted.skipped:
            reasons[s.reason] = reasons.get(s.reason, 0) + 1
        for reason, n in sorted(reasons.items(), key=lambda x: -x[1])[:5]:
            out.append(f"refine: {plural(n, 'move')} not split: {reason}")
        if self.inserted.renumbered:
            out.append("refine: block numbers renumbered after the first inserted line (Klartext needs them consecutive)")
        return out


def refine_for_learning(original: Program, profile: MachineProfile) -> Refinement:
    """Run the original program once on the virtual CNC and refine it where that run says (:mod:`ilcnc.learning.refine`).

    The refined program runs the original path (every inserted point on it within 0.05 µm per axis, checked
    by :func:`ilcnc.program.insert.insert_points` on the program read back).
    """
    from ilcnc.vcnc.simulate import simulate_program

    original.require_complete()
    sim = simulate_program(original, profile)
    first = sim.stats
    t0 = float(sim.cycle_time_s)
    dist, seg, u = sim.error.dist_mm, sim.error.seg, sim.error.u
    del sim
    return refine_from_errors(original, profile, dist_mm=dist, seg=seg, u=u, first_stats=first, cycle_time_s=t0)


def refine_from_errors(original: Program, profile: MachineProfile, *, dist_mm: NDArray[np.float64],
                       seg: NDArray[np.int64], u: NDArray[np.float64], first_stats: ErrorFigures,
                       cycle_time_s: float | None = None) -> Refinement:
    """Refine ``original`` where a run of it erred: the run's per-sample contour error (mm), the move of each
    sample's foot and its path parameter (a virtual run, or the machine's log of the original program: no
    extra machine run is needed); ``cycle_time_s`` the original's planned cycle time (planned when absent)."""
    from ilcnc.learning.refine import plan_refinement
    from ilcnc.program import read_program
    from ilcnc.program.insert import insert_points
    from ilcnc.vcnc.plan import plan_program

    _rule, classes = profile_move_classes(original, profile)
    plan = plan_refinement(original, profile, dist_mm=dist_mm, seg=seg, u=u, classes=classes)
    t0 = float(plan_program(original, profile).duration_s) if cycle_time_s is None else float(cycle_time_s)
    res = insert_points(original, plan.points, min_decimals=profile.min_decimals(original.units))
    refined = read_program(original.path, default_units=original.units, data=res.text.encode("latin-1"))
    t1 = float(plan_program(refined, profile).duration_s) if res.n_inserted else t0
    return Refinement(refined, plan, res, dict(first_stats), (t0, t1))

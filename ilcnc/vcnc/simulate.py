"""The virtual CNC: plan the reference, run the drives, measure the contour error.

``simulate_program`` is what ``ilcnc simulate`` and the learning loop call:

    reference r(t)  = plan (jerk-limited FIR interpolation, :mod:`ilcnc.vcnc.plan`)
    actual q(t)     = drive models of the profile (:mod:`ilcnc.vcnc.drives`)
    contour error   = exact windowed nearest distance of q(t) to the programmed
                      path (:mod:`ilcnc.contour.search`), optionally to another
                      program's path (a compensated program is judged against
                      the original drawing)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc._jit import njit
from ilcnc.axislog.log import AxisLog
from ilcnc.contour.air import (
    MOVE_CUT,
    MOVE_NOT_FED,
    CuttingRule,
    air_above_mm,
    cutting_samples,
    profile_move_classes,
)
from ilcnc.contour.figures import ErrorFigures
from ilcnc.errors import InputError
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import MOVE_LINE, Program
from ilcnc.vcnc.machine_errors import ErrorSources
from ilcnc.vcnc.plan import Reference, plan_program

__all__ = ["SimulationResult", "desired_direction", "simulate_program"]


@dataclass(slots=True, kw_only=True)
class SimulationResult:
    """Everything one virtual-CNC run produced.

    Attributes
    ----------
    reference : Reference
        Planned reference r(t).
    actual_mm : ndarray (N, 3)
        Actual positions q(t), mm.
    error : ContourError
        Exact contour error of every sample.
    feed_mask : ndarray (N,) bool
        Samples on feed moves (the statistics are over these; rapids are not cut).
    stats : dict
        ``max``, ``mean``, ``rms`` contour error over the cutting moves' samples, mm (:mod:`ilcnc.contour.air`).
    worst_sample : int
        Sample of the largest contour error of the cutting moves (-1 when there is none).
    timings_s : dict
        Wall time of each stage, s: ``plan``, ``drives``, ``contour``, ``stats`` (feed mask and statistics),
        and ``errors`` when geometric or cutting errors are on.
    shares : dict
        With geometric or cutting errors on (:mod:`ilcnc.vcnc.machine_errors`): ``max`` / ``mean`` / ``rms`` of
        each source over the feed samples, mm: ``dynamic`` is the contour error the run would have on a
        machine without geometric and cutting errors (for a compensated program: with the corrections
        that compensate them), ``geometric`` and ``cutting`` the length of what each adds to the tool
        position. Empty otherwise.
    """

    reference: Reference
    actual_mm: NDArray[np.float64]
    error: Any
    feed_mask: NDArray[np.bool_]
    stats: ErrorFigures
    worst_sample: int
    timings_s: dict[str, float] = field(default_factory=dict)
    shares: dict[str, dict[str, float]] = field(default_factory=dict)
    air_stats: ErrorFigures = field(default_factory=ErrorFigures)
    cutting: CuttingRule = field(default_factory=lambda: CuttingRule(None, "none"))
    worst_at: dict[str, int] | None = None  # command and line of the worst sample on the judged path
    #: seed 004's eq. (4) per command with the cutting error on (ErrorSources.surface_error_mm): E(k) and valid
    surface: tuple[NDArray[np.float64], NDArray[np.bool_]] | None = None

    @property
    def cycle_time_s(self) -> float:
        return self.reference.duration_s

    @property
    def n_samples(self) -> int:
        return self.reference.n_samples

    @property
    def period_s(self) -> float:
        return self.reference.period_s

    def worst(self, program: Program) -> dict[str, int]:
        """Command index and source line of the worst sample (of ``program``'s path; of the judged path, the
        ``against`` program's, when the run had one)."""
        if self.worst_sample < 0:
            return {"k": -1, "line": 0}
        if self.worst_at is not None:
            return dict(self.worst_at)
        seg = int(self.error.seg[self.worst_sample])
        if seg < 0:
            seg = int(self.reference.move[self.worst_sample])
        return {"k": int(program.moves.command[seg]), "line": int(program.moves.line[seg])}

    def axis_log(self) -> AxisLog:
        """The run as an axis log (DESIGN.md CSV format)."""
        ref = self.reference
        return AxisLog(ref.t_s, ref.command.astype(np.int64), ref.line.astype(np.int64), ref.pos_mm, self.actual_mm)

    def to_json(self, program: Program) -> dict[str, Any]:
        return run_json(self, program)


def run_json(run: Any, program: Program) -> dict[str, Any]:
    """The JSON object of a run (``simulate --json``): a :class:`SimulationResult` or a streamed run, which
    both have ``n_samples``, ``cycle_time_s``, ``stats`` (the cutting moves'), ``air_stats``, ``cutting``,
    ``shares`` and ``worst(program)``."""
    out = {
        "program": str(program.path),
        "samples": run.n_samples,
        "cycle_time_s": run.cycle_time_s,
        "contour_error_mm": run.stats.to_json(),
        "air_error_mm": run.air_stats.to_json(),
        "cutting_rule": run.cutting.to_json(),
        "worst": run.worst(program),
    }
    if run.shares:
        out["error_shares_mm"] = {k: dict(v) for k, v in run.shares.items()}
    return out


def simulate_program(
    program: Program,
    profile: MachineProfile,
    *,
    against: Program | None = None,
    progress: Callable[[str], None] | None = None,
    sources: ErrorSources | None = None,
    gain_schedule: Mapping[str, tuple[NDArray[np.float64], NDArray[np.float64]]] | None = None,
    vertices: Any = None,
) -> SimulationResult:
    """Run a program on the virtual CNC of a profile.

    Parameters
    ----------
    program : Program
        What the machine runs.
    profile : MachineProfile
        Limits, planner and drive models.
    against : Program, optional
        Measure the contour error against this program's path instead (it
        must have the same moves, e.g. the original of a compensated program).
    progress : callable, optional
        Called with the name of each stage as it starts.
    sources : ErrorSources, optional
        Geometric and cutting errors to add to the drives' positions (default:
        those the profile names, loaded here; the learning loop loads them once).
    gain_schedule : mapping of axis to (t_s, kp), optional
        A position-loop gain schedule of an axis: gain ``kp`` ((m/min)/mm) from each instant ``t_s`` (s) on
        (seed 001's schedule, ``ilcnc tune --method schedule``, :func:`ilcnc.vcnc.schedule.read_schedule`); held per
        servo period over the planned run (see :func:`ilcnc.vcnc.drives.simulate_drives`).
    vertices : ilcnc.vcnc.rounding.VertexMax, optional
        Given: the cutting samples' largest error near each end point of the judged path is added to it
        (:mod:`ilcnc.vcnc.rounding`).

    Raises
    ------
    InputError
        The program has unsupported constructs, or ``against`` does not
        match it move for move.
    """
    from ilcnc.contour.path import PathGeometry
    from ilcnc.contour.search import contour_error
    from ilcnc.vcnc.drives import simulate_drives

    program.require_modelled()
    target = against if against is not None else program
    move_map = check_against(program, against)
    check_travel(program, profile)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    if progress:
        progress("plan")
    ref = plan_program(program, profile)
    timings["plan"] = time.perf_counter() - t0
    if ref.n_samples == 0:
        raise InputError(program.path, None, "the program has no motion to simulate")
    t0 = time.perf_counter()
    if progress:
        progress("drives")
    gains = None
    if gain_schedule:
        from ilcnc.vcnc.schedule import schedule_on_samples

        gains = {ax: schedule_on_samples(t, kp, ref.n_samples, ref.period_s) for ax, (t, kp) in gain_schedule.items()}
    # the path with its rapids: a feed sample still on the line of the rapid before it is in the air, not off
    # the cut (its E(k) counts for no command: command_error.PathWeightedSums)
    path = PathGeometry.from_moves(target.moves, include_rapids=True)
    # the search reaches as far along the path as the machine lags behind its reference (contour.py): the
    # reference may leave its move by the corner tolerance, and a compensated program's moves lie off the
    # drawing's by their corrections
    slack: Any = profile.planner.corner_tolerance_mm
    if against is not None:
        slack = slack + against_slack_mm(program, target, move_map)
    reach = {"reference_mm": ref.pos_mm, "reference_slack_mm": slack}
    on_target = moves_on_target(ref.move, move_map)
    way = None
    if profile.controller.type == "cross_coupled" and profile.controller.theta == "desired":
        way = desired_direction(path, ref.pos_mm, on_target, slack)
    act = simulate_drives(ref.pos_mm, profile, gain_schedule=gains, contour_direction=way)
    timings["drives"] = time.perf_counter() - t0
    if sources is None:
        sources = ErrorSources.from_profile(profile)
    rule, classes = profile_move_classes(target, profile)
    shares: dict[str, dict[str, float]] = {}
    surface = None
    if sources.enabled and move_map is not None:
        raise InputError(against.path if against is not None else None, None, "--against a program with fewer points"
                         " (a refined output) is not modelled with geometric or cutting errors on")
    if sources.enabled:
        t0 = time.perf_counter()
        if progress:
            progress("errors")
        # the dynamic share: the contour error of the drives alone
        err_dyn = contour_error(path, act, ref.move, **reach)
        _feed, shares["dynamic"], _w = _feed_stats(ref.move, classes, err_dyn.dist_mm)
        del err_dyn
        disp = sources.displacements_mm(act, ref.command, program, target, ref.line)
        if sources.cutting is not None:
            surface = sources.surface_error_mm(program, target)
        for name, d in disp.items():
            _feed, shares[name], _w = _feed_stats(ref.move, classes, np.sqrt(np.einsum("ij,ij->i", d, d)))
            act += d
        del disp
        timings["errors"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if progress:
        progress("contour")
    err = contour_error(path, act, on_target, **reach)  # the hint: the reference's move (clipped to >= 0 there)
    timings["contour"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    acc = FeedStats()
    above = air_above_mm(target, rule, classes, resolution_mm=profile.machine.resolution_mm)
    feed = acc.add(on_target, classes, err.dist_mm, foot_z_mm=err.foot_mm[:, 2], above_mm=above)
    stats, worst = acc.result()
    if vertices is not None:
        vertices.add(err.dist_mm, err.u, err.seg, cutting_samples(on_target, classes, err.foot_mm[:, 2], above))
    timings["stats"] = time.perf_counter() - t0
    worst_at = None
    if against is not None and worst >= 0:
        seg = int(err.seg[worst]) if err.seg[worst] >= 0 else int(on_target[worst])
        worst_at = {"k": int(target.moves.command[seg]), "line": int(target.moves.line[seg])}
    return SimulationResult(reference=ref, actual_mm=act, error=err, feed_mask=feed, stats=stats, worst_sample=worst,
                            timings_s=timings, shares=shares, air_stats=acc.air_result(), cutting=rule,
                            worst_at=worst_at, surface=surface)



def desired_direction(path: Any, ref_mm: NDArray[np.float64], hint_seg: NDArray[np.integer],
                      slack_mm: Any) -> NDArray[np.float64]:
    """Direction of the drawing at the point nearest each reference sample, (N, 3) unit vectors (0: none there).

    What ``controller.theta: desired`` gives the cross-coupled controller: the tangent of ``path`` (a
    :class:`ilcnc.contour.path.PathGeometry` of the original program) at the foot of each sample of the
    reference ``ref_mm`` (N, 3), searched from ``hint_seg`` (the move of the original the sample is on)
    within ``slack_mm`` (how far a corrected program's moves lie off the original's). On the uncorrected
    program the foot is the reference itself.
    """
    from ilcnc.contour.search import contour_error

    err = contour_error(path, ref_mm, hint_seg, reference_mm=ref_mm, reference_slack_mm=slack_mm)
    out = np.zeros((ref_mm.shape[0], 3))
    ok = err.seg >= 0
    seg = err.seg[ok]
    out[ok] = path.tangent_at(seg, np.clip(err.u[ok] - seg, 0.0, 1.0))
    return out


def _feed_stats(move: NDArray[np.int32], classes: NDArray[np.int8], dist: NDArray[np.float64]
                ) -> tuple[NDArray[np.bool_], dict[str, float], int]:
    """Feed mask, max / mean / RMS of the finite distances on cutting samples and the worst cutting sample.

    ``classes`` is the class of every move (:func:`ilcnc.contour.air.move_classes`: rapid, cutting, air; a bool
    array is read as "rapid"). One compiled pass (:func:`_feed_values`) instead of ``np.where`` plus
    ``np.nanmax`` / ``nanargmax`` / ``nanmean`` (eight temporaries of the sample count): the maximum
    and its first sample are exact; the sums are compensated (Neumaier), within a few ulp of numpy's
    pairwise sums.
    """
    acc = FeedStats()
    feed = acc.add(move, classes, dist)
    stats, worst = acc.result()
    return feed, stats, worst


def _as_classes(classes: NDArray[Any]) -> NDArray[np.int8]:
    if classes.dtype == np.bool_:  # a "rapid" mask: every other move cuts
        return np.where(classes, MOVE_NOT_FED, MOVE_CUT).astype(np.int8)
    return np.ascontiguousarray(classes, dtype=np.int8)


class FeedStats:
    """Max / mean / RMS of the contour error over the cutting and the air samples of a run, added stretch
    by stretch.

    The running sums carry on from one stretch to the next, so a run handed over in chunks
    (:mod:`ilcnc.vcnc.stream`) gives the figures of one pass, bit for bit.
    """

    def __init__(self) -> None:
        # per class (cutting, air): count, worst sample, largest, sum and its compensation, sum of squares
        # and its compensation
        self.acc = np.array([[0.0, -1.0, -math.inf, 0.0, 0.0, 0.0, 0.0]] * 2)

    def add(self, move: NDArray[np.int32], classes: NDArray[Any], dist: NDArray[np.float64],
            first_sample: int = 0, *, foot_z_mm: NDArray[np.float64] | None = None,
            above_mm: NDArray[np.float64] | None = None) -> NDArray[np.bool_]:
        """Add one stretch (its first sample is ``first_sample`` of the run); returns its feed mask (cutting
        and air samples). With ``foot_z_mm`` (per sample, the Z of its nearest point on the drawing) and
        ``above_mm`` (per move, :func:`ilcnc.contour.air.air_above_mm`), a cutting move's sample above the stock top
        counts with the air moves."""
        feed = np.empty(move.shape[0], dtype=np.bool_)
        if foot_z_mm is None or above_mm is None:
            fz, ab, use = np.zeros(1), np.full(1, np.inf), False
        else:
            fz, ab, use = np.ascontiguousarray(foot_z_mm, dtype=np.float64), np.ascontiguousarray(above_mm), True
        _feed_values(move, _as_classes(classes), dist, feed, self.acc, int(first_sample), fz, ab, use)
        return feed

    @property
    def worst_sample(self) -> int:
        """The run's worst cutting sample so far (-1: none)."""
        return int(self.acc[0, 1])

    @staticmethod
    def _figures(a: NDArray[np.float64]) -> ErrorFigures:
        cnt, _worst, peak, s1, c1, s2, c2 = a
        if cnt == 0:
            return ErrorFigures()
        return ErrorFigures(float(peak), float((s1 + c1) / cnt), float(np.sqrt((s2 + c2) / cnt)))

    def result(self) -> tuple[ErrorFigures, int]:
        """The cutting moves' statistics (mm) and the run's worst cutting sample (-1 when none had a finite
        error)."""
        if self.acc[0, 0] == 0:
            return self._figures(self.acc[0]), -1
        return self._figures(self.acc[0]), int(self.acc[0, 1])

    def air_result(self) -> ErrorFigures:
        """The air moves' statistics, mm (zeros when the run has no air move)."""
        return self._figures(self.acc[1])

    @property
    def air_samples(self) -> int:
        return int(self.acc[1, 0])


@njit(cache=True, nogil=True)
def _feed_values(move, cls, dist, feed, acc, offset, foot_z, above, use_z):  # pragma: no cover - compiled
    """``feed = move >= 0 & cls[move] != 0``, and over the finite ``dist`` where feed, per class (row 0: cutting,
    1: air; with ``use_z`` a cutting sample whose ``foot_z`` is above its move's ``above`` is air): how many,
    the first sample of the largest (+ ``offset``), the largest, the sum and the sum of squares
    (Neumaier-compensated sums), carried on in ``acc``."""
    for k in range(move.shape[0]):
        mv = move[k]
        c = cls[mv] if mv >= 0 else 0
        if use_z and c == 1 and foot_z[k] > above[mv]:
            c = 2
        f = c != 0
        feed[k] = f
        x = dist[k]
        if f and math.isfinite(x):
            r = 0 if c == 1 else 1
            acc[r, 0] += 1.0
            if x > acc[r, 2]:
                acc[r, 2] = x
                acc[r, 1] = k + offset
            s1 = acc[r, 3]
            t = s1 + x
            acc[r, 4] += (s1 - t) + x if abs(s1) >= abs(x) else (x - t) + s1
            acc[r, 3] = t
            x2 = x * x
            s2 = acc[r, 5]
            t = s2 + x2
            acc[r, 6] += (s2 - t) + x2 if abs(s2) >= abs(x2) else (x2 - t) + s2
            acc[r, 5] = t


def check_against(program: Program, against: Program | None) -> NDArray[np.int64] | None:
    """Refuse an ``against`` program that is not the same part as ``program``; return the move map.

    The same part: the same moves, only coordinates differ; or ``program`` is a refined one (``learn
    --refine``) whose inserted straight feeds, marked on their lines, split moves of ``against``: the
    same path with more points. Returns, for a refined ``program``, the move of ``against`` each of its
    moves lies on (an inserted piece belongs to the move its line precedes); else ``None``.
    """
    if against is None:
        return None
    against.require_complete()
    if len(against.moves) == len(program.moves) and np.array_equal(against.moves.kind, program.moves.kind):
        return None
    from ilcnc.program.insert import inserted_moves, split_move_of

    ins = inserted_moves(program)
    own = np.flatnonzero(~ins)
    if ins.any() and own.size == len(against.moves) and np.array_equal(program.moves.kind[own], against.moves.kind) \
            and np.all(program.moves.kind[ins] == MOVE_LINE):
        nxt = split_move_of(ins)
        if nxt.max() < own.size and np.all(against.moves.kind[nxt[ins]] == MOVE_LINE):
            return nxt
    raise InputError(against.path, None,
                     f"--against program has {len(against.moves)} moves, {program.path.name} has "
                     f"{len(program.moves)}{f' ({int(ins.sum())} inserted by ilcnc refine)' if ins.any() else ''}: it"
                     " is not the same part (only coordinates may differ, or refined points be added)")


def moves_on_target(move: NDArray[np.int32], move_map: NDArray[np.int64] | None) -> NDArray[np.int32]:
    """The samples' moves on the judged path: a refined program's pieces on the moves they split (-1 stays)."""
    if move_map is None:
        return move
    return np.where(move >= 0, move_map[np.maximum(move, 0)], -1).astype(move.dtype)


def against_slack_mm(program: Program, target: Program, move_map: NDArray[np.int64] | None) -> NDArray[np.float64]:
    """How far each move of ``target`` may lie from ``program``'s (their corrections), mm per target move."""
    if move_map is None:
        off = np.maximum(np.linalg.norm(program.moves.start_mm - target.moves.start_mm, axis=1),
                         np.linalg.norm(program.moves.end_mm - target.moves.end_mm, axis=1))
        return np.nan_to_num(off)
    # a piece's end against the target move it lies on: the distance from that segment
    a, b = target.moves.start_mm[move_map], target.moves.end_mm[move_map]
    p = program.moves.end_mm
    d = b - a
    dd = np.einsum("ij,ij->i", d, d)
    t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    dist = np.linalg.norm(p - (a + t[:, None] * d), axis=1)
    off = np.zeros(len(target.moves))
    np.maximum.at(off, move_map, np.nan_to_num(dist))
    return off


def check_travel(program: Program, profile: MachineProfile) -> None:
    """Refuse a program whose moves leave the machine's travel (profile ``machine.travel_mm``)."""
    travel = profile.machine.travel_mm
    if not travel:
        return
    mv = program.moves
    for a, name in enumerate("xyz"):
        if name not in travel:
            continue
        lo, hi = travel[name]
        pts = mv.end_mm[:, a]
        bad = np.flatnonzero((pts < lo - 1e-9) | (pts > hi + 1e-9))
        if bad.size:
            i = int(bad[0])
            raise InputError(program.path, int(mv.line[i]),
                             f"move goes to {name.upper()}{pts[i]:.3f} mm, outside the machine travel "
                             f"{lo:g}..{hi:g} mm of profile {profile.machine.name}")

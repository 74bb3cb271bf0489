"""Measurements from the real machine: an axis log or probe points, checked against the program.

A shop records a log on the machine (ilcnc CSV, LinuxCNC halsampler,
TNCscope export; :func:`ilcnc.axislog.detect.read_log`) or measures points on the
part (CMM, probe; :func:`ilcnc.axislog.points.read_points`). Before one learning step
is made from it, the measurement must be shown to belong to the program it
claims: its block lines must be lines of that program, its positions must
follow the program's path (a log in the wrong unit or of another part does
not), its duration must match the program's planned cycle time, and it must
cover most of the program's commands. :mod:`ilcnc.shop.log_identity` then
shows it is one whole run of that very program (block numbers, first to last
once, columns the right way round, commanded positions on its path, not an
earlier iteration's). Each refusal is one line naming the file and the problem.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.axislog.halsampler import moves_from_lines
from ilcnc.axislog.log import AxisLog
from ilcnc.axislog.points import MeasuredPoints
from ilcnc.contour.air import MOVE_AIR, air_above_mm, profile_move_classes
from ilcnc.contour.figures import ErrorFigures
from ilcnc.errors import LogError
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import FLAG_CUTTER_COMP, MOVE_RAPID, Program
from ilcnc.shop.log_identity import LogIdentity, check_block_numbers, check_log_identity, check_log_order
from ilcnc.units import MM_PER_INCH
from ilcnc.vcnc.command_error import CommandSignal, command_signal_from_run, measurement_gate_mm, reference_command_samples
from ilcnc.wording import plural

__all__ = ["Measurement", "check_log_memory", "interpolate_along_path", "measure_log", "measure_points"]

#: Share of feed samples allowed farther than the measurement gate from the path.
OFF_PATH_SHARE = 0.02
#: Share of log samples allowed on lines that hold no move of the program.
FOREIGN_LINE_SHARE = 0.05
#: Least share of the program's commands a measurement must cover.
MIN_COVERAGE = 0.5
#: Allowed ratio of the log's duration to the planned cycle time.
DURATION_RATIO = (0.5, 3.0)
#: Peak memory of reading and measuring a log, bytes per sample: measured 474 (peak RSS of ``learn --log`` on
#: synthetic ilcnc logs, 1.38 GB at 2 M samples, 3.23 GB at 6 M, 2026-12-02), with room for a program's moves.
LOG_BYTES_PER_SAMPLE = 600


@dataclass(slots=True, eq=False, kw_only=True)
class Measurement:
    """What one measurement says about the program that ran.

    Attributes
    ----------
    kind : str
        ``log`` or ``points``.
    signal : CommandSignal
        ``E(k)`` per command.
    stats : dict
        ``max``, ``mean``, ``rms`` error, mm: the contour error of the cutting
        moves' samples (log, :mod:`ilcnc.contour.air`), or the point errors ``|E(k)|``
        of the measured commands (points).
    actual_mm, contour_mm, signed_mm, foot_mm, path_pos_mm, feed_mask : ndarray or None
        Per-sample data of a log, for reports.
    notes : list of str
        Things the user should know (points left alone, ...).
    """

    kind: str
    signal: CommandSignal
    stats: ErrorFigures
    actual_mm: NDArray[np.float64] | None = None
    contour_mm: NDArray[np.float64] | None = None
    signed_mm: NDArray[np.float64] | None = None
    foot_mm: NDArray[np.float64] | None = None
    path_pos_mm: NDArray[np.float64] | None = None
    feed_mask: NDArray[np.bool_] | None = None
    notes: list[str] = field(default_factory=list)
    air_stats: ErrorFigures | None = None
    seg: NDArray[np.int64] | None = None  # move of each sample's foot point (-1: none)
    u: NDArray[np.float64] | None = None  # its path parameter (move + fraction)
    identity: LogIdentity | None = None  # what the log's identity checks measured (ilcnc.shop.log_identity)


def _stats(d: NDArray[np.float64]) -> ErrorFigures:
    return ErrorFigures.of(d)


def sample_moves(log: AxisLog, ran: Program) -> NDArray[np.int64]:
    """Move of the running block at each sample (-1 before the first), from the log's k or line columns."""
    return _forward_filled(numbered_moves(log, ran))


def _forward_filled(mv: NDArray[np.int64]) -> NDArray[np.int64]:
    """Samples that name no block (the settle tail, a line without motion) take the last one named before."""
    idx = np.where(mv >= 0, np.arange(mv.size), -1)
    np.maximum.accumulate(idx, out=idx)
    return np.where(idx >= 0, mv[np.maximum(idx, 0)], -1)


def file_lines(log: AxisLog, ran: Program) -> NDArray[np.int64]:
    """The log's line column as file lines of ``ran``: a TNC's block numbers (a TNCscope export) become the lines
    of those Klartext blocks (0 where no block has the number). G-code logs name file lines already."""
    line = np.asarray(log.line, dtype=np.int64)
    if not log.line_is_block_number or ran.dialect != "heidenhain":
        return line
    from ilcnc.program.heidenhain_lexer import block_number_lines

    table = block_number_lines(ran.text)
    ok = (line >= 0) & (line < table.size)
    return np.where(ok, table[np.where(ok, line, 0)], 0)


def numbered_moves(log: AxisLog, ran: Program, lines: NDArray[np.int64] | None = None) -> NDArray[np.int64]:
    """Move of the block each sample names by its k or line column (-1 where it names none); ``lines``: the
    log's :func:`file_lines`, when the caller has them."""
    mv = np.full(log.n_samples, -1, np.int64)
    k = np.asarray(log.k, dtype=np.int64)
    cm = ran.command_moves
    has_k = (k >= 0) & (k < cm.size)
    if has_k.any():
        mv[has_k] = cm[k[has_k]]
    if lines is None:
        lines = file_lines(log, ran)
    need = ~has_k & (lines > 0)
    if need.any():
        by_line = moves_from_lines(lines, ran)
        mv[need] = by_line[need]
    return mv


def measure_log(
    log: AxisLog,
    ran: Program,
    original: Program,
    profile: MachineProfile,
    kind: str,
    *,
    source: str | Path,
    units: str = "mm",
    earlier: Sequence[tuple[str, Program]] = (),
) -> Measurement:
    """Check that a log is a run of ``ran`` and measure ``E(k)`` on it against the original drawing.

    Parameters
    ----------
    log : AxisLog
        The measured run (positions in mm).
    ran : Program
        The program the machine ran (the original, or a compensated iteration of it).
    original : Program
        The drawing: errors are measured against its path.
    profile : MachineProfile
        Planner (for the cycle time check) and learning section.
    kind : str
        Error estimate (``learning.error`` resolved).
    source : path
        The log file (for messages).
    units : {"mm", "inch"}
        The unit the user said the log is in (for the unit hint).
    earlier : sequence of (str, Program)
        Programs that ran before ``ran`` (what to call each, the program): the log must not fit one of them
        better (:func:`ilcnc.shop.log_identity.check_log_identity`).

    Raises
    ------
    LogError
        The log does not belong to the program (lines, path, duration, coverage).
    """
    original.require_modelled()
    ran.require_modelled()
    from ilcnc.contour.path import PathGeometry
    from ilcnc.contour.search import contour_error
    from ilcnc.vcnc.plan import plan_program

    src = Path(source)
    comp = np.flatnonzero((ran.moves.flags & FLAG_CUTTER_COMP) != 0)
    if comp.size:
        raise LogError(original.path, int(ran.moves.line[comp[0]]),
                       "cutter radius compensation (G41/G42, RL/RR) is active here: the log records the tool centre,"
                       " offset from the programmed contour by the tool radius; learn from a tool-centre program"
                       " (CAM output with compensation in the computer, G40 / R0)")
    n = log.n_samples
    if n < 10:
        raise LogError(src, None, f"the log has only {n} samples")
    act = np.array(log.act_mm, dtype=np.float64)
    if not log.has_z:
        act[:, 2] = 0.0 if not np.any(ran.moves.end_mm[:, 2]) else np.nan
        if np.isnan(act[:, 2]).any():
            raise LogError(src, None, "the log has no Z column but the program moves Z")
    line = file_lines(log, ran)
    prog_lines = np.unique(ran.moves.line)
    with_line = line > 0
    if with_line.any():
        foreign = with_line & ~np.isin(line, prog_lines)
        share = foreign.sum() / with_line.sum()
        if share > FOREIGN_LINE_SHARE:
            bad = int(line[np.flatnonzero(foreign)[0]])
            raise LogError(src, None, f"{share:.0%} of the log's samples run lines that hold no move of {ran.path.name}"
                           f" (e.g. line {bad}): it is a log of another program")
    t_s = np.asarray(log.t_s, dtype=np.float64)
    numbered = numbered_moves(log, ran, line)
    check_block_numbers(numbered, src)
    mv = _forward_filled(numbered)
    # the path with its rapids: a feed sample still on the line of the rapid before it (LinuxCNC starts a
    # plunge while the axes lag behind the rapid) is in the air, not off the cut (simulate does the same)
    path = PathGeometry.from_moves(original.moves, include_rapids=True)
    hint = np.where(mv >= 0, mv, int(mv[mv >= 0][0]))
    mv_or_first = hint
    # the search reaches as far along the path as the machine lags behind its commanded position (as the
    # virtual CNC's does): without it, a sample lagging behind a sharp corner can be matched to the wrong side
    # of the corner (issue 25). The commanded position may leave its move by the blend (the profile's corner
    # tolerance, the program's G64 P) and lies off the drawing by the corrections of the program that ran.
    reach: dict[str, Any] = {}
    ref_log = np.asarray(log.ref_mm, dtype=np.float64)
    if not log.has_z:
        ref_log = ref_log.copy()
        ref_log[:, 2] = act[:, 2]
    if np.all(np.isfinite(ref_log)) and len(ran.moves) == len(original.moves):
        from ilcnc.vcnc.simulate import against_slack_mm

        blend = ran.moves.blend_tol_mm
        tol = float(np.max(blend[np.isfinite(blend) & (blend > 0)], initial=profile.planner.corner_tolerance_mm))
        reach = {"reference_mm": ref_log, "reference_slack_mm": tol + against_slack_mm(ran, original, None)}
    err = contour_error(path, act, hint, **reach)
    feed = (ran.moves.kind[mv_or_first] != MOVE_RAPID) & (mv >= 0)
    gate = measurement_gate_mm(profile)
    d = np.where(feed, err.dist_mm, np.nan)
    fin = np.isfinite(d)
    off = ~fin & feed | (fin & (d > gate))
    if feed.any() and off.sum() / feed.sum() > OFF_PATH_SHARE:
        _unit_hint(path, act, hint, feed, gate, units, src)
        i = int(np.flatnonzero(off)[0])
        raise LogError(src, None, f"{off.sum() / feed.sum():.0%} of the log's feed samples are more than {gate:g} mm off"
                       f" the path of {original.path.name} (first at t = {log.t_s[i]:.3f} s): it is not a run of this"
                       " program, or not in the same coordinates (a log of machine coordinates needs the work offset:"
                       " --log-offset)")
    check_log_order(numbered, ran, src, t_s)
    ref = plan_program(ran, profile)
    identity = check_log_identity(ref_log, act, t_s, ran, act_seg=err.seg, act_frac=err.u - err.seg, drawing=path,
                                  sample_move=mv_or_first, feed=feed, planned_mm=ref.pos_mm, planned_move=ref.move,
                                  resolution_mm=profile.machine.resolution_mm, source=src, earlier=earlier)
    span = float(log.t_s[-1] - log.t_s[0])
    lo, hi = DURATION_RATIO
    if ref.duration_s > 0 and not lo <= span / ref.duration_s <= hi:
        raise LogError(src, None, f"the log spans {span:.2f} s but {ran.path.name} takes {ref.duration_s:.2f} s on the"
                       f" profile's planner: it is not a whole run of this program")
    cs = None
    if kind not in ("crossing", "path"):
        cs = reference_command_samples(np.maximum.accumulate(mv), original.command_moves)
    if kind == "lifted":
        dt = np.diff(np.asarray(log.t_s, dtype=np.float64))
        per = profile.machine.servo_period_s
        if dt.size and not abs(float(np.median(dt)) / per - 1.0) <= 0.01:
            raise LogError(src, None, f"the log is sampled every {float(np.median(dt)) * 1e3:.4g} ms, the servo period"
                           f" (machine.servo_period_s) is {per * 1e3:.4g} ms: learning.error 'lifted' filters the"
                           " log's reference through the drive models, which needs samples at the servo period"
                           " (log at that rate, or use learning.error: path)")
    sig = command_signal_from_run(kind, path=path, err=err, actual_mm=act, t_s=np.asarray(log.t_s), command_sample=cs,
                                  ref_mm=np.nan_to_num(log.ref_mm), gate_mm=gate, sample_move=mv, on_feed=feed,
                                  program=ran, profile=profile)
    cover = sig.valid.sum() / max(sig.valid.size, 1)
    if sig.valid.size and cover < MIN_COVERAGE:
        raise LogError(src, None, f"the log measures only {cover:.0%} of the {sig.valid.size} G01 commands of"
                       f" {ran.path.name}: an incomplete run")
    notes = []
    if sig.valid.size and cover < 1.0:
        n_out = int((~sig.valid).sum())
        notes.append(f"{plural(n_out, 'command')} not measured by the log {'is' if n_out == 1 else 'are'} left as"
                     f" {'it is' if n_out == 1 else 'they are'}")
    rule, classes = profile_move_classes(original, profile)
    above = air_above_mm(original, rule, classes, resolution_mm=profile.machine.resolution_mm)
    # an air move, or a cutting move's sample whose nearest point on the drawing is above the stock top
    air = (classes[mv_or_first] == MOVE_AIR) | (np.nan_to_num(err.foot_mm[:, 2], nan=-np.inf) > above[mv_or_first])
    return Measurement(kind="log", signal=sig, stats=_stats(np.where(air, np.nan, d)), actual_mm=act,
                       contour_mm=err.dist_mm, signed_mm=err.signed_mm, foot_mm=err.foot_mm,
                       path_pos_mm=path_position_mm(err), feed_mask=feed, notes=notes,
                       air_stats=_stats(np.where(air, d, np.nan)), seg=err.seg, u=err.u, identity=identity)


def check_log_memory(path: str | Path) -> None:
    """Refuse, before reading it, a log whose measurement needs more memory than this process may still take.

    Linux would let the reading start and kill the process when the memory runs out, with no message. The need
    is the log's estimated sample count (:func:`ilcnc.axislog.detect.estimate_log_samples`) times
    :data:`LOG_BYTES_PER_SAMPLE`, the peak measured on ``learn --log`` with synthetic ilcnc logs.
    """
    from ilcnc._memory import available_memory_bytes
    from ilcnc.axislog.detect import estimate_log_samples

    n = estimate_log_samples(path)
    need = n * LOG_BYTES_PER_SAMPLE
    free = available_memory_bytes()
    if free is not None and need > free:
        raise LogError(Path(path), None, f"measuring this log needs about {need / 2**30:.1f} GiB ({n / 1e6:.1f} M"
                       f" samples at about {LOG_BYTES_PER_SAMPLE} bytes each) and {free / 2**30:.1f} GiB are free:"
                       " record a shorter run, or keep every n-th sample (a resampled log measures alike)")


def path_position_mm(err: Any) -> NDArray[np.float64]:
    """Arc length along the programmed path of each sample's foot point, mm (for plots along the path)."""
    path = err.path
    seg_len = np.concatenate(([0.0], np.cumsum(path.length_mm)))
    seg = np.clip(err.seg, 0, len(path) - 1)
    return seg_len[seg] + np.clip(err.u - seg, 0, 1) * path.length_mm[seg]


def _unit_hint(path: Any, act: NDArray[np.float64], hint: NDArray[np.int64], feed: NDArray[np.bool_], gate: float,
               units: str, src: Path) -> None:
    """Raise a unit-mismatch error when the log fits the path once scaled by 25.4."""
    from ilcnc.contour.search import contour_error

    for factor, said, real in ((1.0 / MM_PER_INCH, "inch", "mm"), (MM_PER_INCH, "mm", "inch")):
        if units != said:
            continue
        e = contour_error(path, act * factor, hint)
        d = np.where(feed, e.dist_mm, np.nan)
        ok = np.isfinite(d) & (d <= gate)
        if feed.any() and ok.sum() / feed.sum() >= 1.0 - OFF_PATH_SHARE:
            raise LogError(src, None, f"the log's positions are in {real}, not {said}: scaled by "
                           f"{'1/25.4' if factor < 1 else '25.4'} they follow the path (use --log-units {real})")


def command_times_s(program: Program) -> NDArray[np.float64]:
    """Rough time stamps of each command's end point at the programmed feeds (for filters on point data), s."""
    from ilcnc.program.geometry import move_lengths_mm

    mv = program.moves
    length = move_lengths_mm(mv)
    feed = np.where(np.isfinite(mv.feed_mm_min) & (mv.feed_mm_min > 0), mv.feed_mm_min, 1000.0) / 60.0
    t_end = np.cumsum(length / feed)
    return t_end[program.command_moves]


def measure_points(
    points: MeasuredPoints,
    original: Program,
    profile: MachineProfile,
    *,
    source: str | Path,
    reach_mm: float | None = None,
) -> Measurement:
    """``E(k)`` from measured points: per command index, or by the nearest command end point.

    The deviation ``d`` of a point is measured minus nominal, so ``E = -d``
    (DESIGN.md: seed 002's ``u + γe`` with ``e = actual - nominal`` doubles the
    error). Commands between measured ones take the error interpolated along
    the path (:func:`interpolate_along_path`, within ``reach_mm``); commands
    far from any measurement are left alone and reported.

    Raises
    ------
    LogError
        A point whose k does not exist, or that is far from every command end point.
    """
    src = Path(source)
    kk = original.n_commands
    e = np.full((kk, 3), np.nan)
    ends = original.command_end_mm
    gate = measurement_gate_mm(profile)
    if points.k is not None:
        bad = np.flatnonzero(points.k >= kk)
        if bad.size:
            i = int(bad[0])
            raise LogError(src, int(points.line[i]), f"command k={int(points.k[i])} does not exist"
                           f" ({original.path.name} has k = 0..{kk - 1})")
        e[points.k] = -points.dev_mm
    else:
        from scipy.spatial import cKDTree

        xyz = np.array(points.xyz_mm, dtype=np.float64)
        flat = np.isnan(xyz[:, 2])
        xyz[flat, 2] = 0.0
        e2 = ends.copy()
        if flat.all():
            e2[:, 2] = 0.0
        dist, idx = cKDTree(e2).query(xyz)
        far = np.flatnonzero(dist > gate)
        if far.size:
            i = int(far[0])
            raise LogError(src, int(points.line[i]), f"point ({xyz[i, 0]:g}, {xyz[i, 1]:g}, {xyz[i, 2]:g}) is {dist[i]:.3f} mm"
                           f" from the nearest G01 end point of {original.path.name} (more than {gate:g} mm)")
        # commands that end at the same place (a closed contour's first and last point) are one location:
        # a point there measures all of them, and two points there measure the same place twice
        _u, loc = np.unique(np.round(e2, 9), axis=0, return_inverse=True)
        loc = loc.ravel()
        uniq, first = np.unique(loc[idx], return_index=True)
        if uniq.size != idx.size:
            dup = np.setdiff1d(np.arange(idx.size), first)[0]
            raise LogError(src, int(points.line[dup]), f"two points measure the same command k={int(idx[dup])}"
                           " (or the same place, where several commands end)")
        order = np.argsort(loc, kind="stable")
        starts = np.searchsorted(loc[order], loc[idx], side="left")
        stops = np.searchsorted(loc[order], loc[idx], side="right")
        for i in range(idx.size):
            e[order[starts[i]:stops[i]]] = -points.dev_mm[i]
    measured = np.all(np.isfinite(e), axis=1)
    e, filled, reach = interpolate_along_path(e, original, reach_mm=reach_mm)
    sig_t = command_times_s(original)
    valid = np.all(np.isfinite(e), axis=1)
    big = measured & (np.linalg.norm(np.nan_to_num(e), axis=1) > gate)
    if big.any():
        k = int(np.flatnonzero(big)[0])
        raise LogError(src, None, f"the deviation measured at command k={k} (line {int(original.command_line[k])}) is"
                       f" {np.linalg.norm(e[k]):.3f} mm, more than {gate:g} mm: not a form error ilcnc can learn")
    ee = np.where(valid[:, None], e, 0.0)
    sig = CommandSignal(ee, sig_t, valid, "points")
    notes = []
    if filled.any():
        n_filled = int(filled.sum())
        notes.append(f"{plural(n_filled, 'command')} between measured ones (at most {reach:.3g} mm of path apart)"
                     f" {'takes' if n_filled == 1 else 'take'} the error interpolated along the path")
    if (~valid).any():
        far = np.flatnonzero(~valid)
        lines = ", ".join(str(int(original.command_line[k])) for k in far[:8]) + (", ..." if far.size > 8 else "")
        notes.append(f"{far.size} of {plural(kk, 'command')} {'is' if far.size == 1 else 'are'} far from any measured"
                     f" point and {'is left as it is' if far.size == 1 else 'are left as they are'}"
                     f" (lines {lines})")
    return Measurement(kind="points", signal=sig, stats=_stats(np.linalg.norm(e[measured], axis=1)), notes=notes)


def interpolate_along_path(
    e_mm: NDArray[np.float64], program: Program, *, reach_mm: float | None = None
) -> tuple[NDArray[np.float64], NDArray[np.bool_], float]:
    """Fill the error of unmeasured commands between measured ones, linearly in path length.

    A command takes a value only when it lies in the same cut (an unbroken
    run of G01 commands: no rapid, arc or other move in between) as a
    measured command before it and one after it, and those two are at most
    ``reach_mm`` of path apart. Commands outside the measured span of their
    cut, or in a gap longer than the reach, stay NaN: far from any
    measurement, they are left alone.

    Parameters
    ----------
    e_mm : ndarray (K, 3)
        Error of each command, mm; NaN rows are unmeasured.
    program : Program
        The program the commands belong to.
    reach_mm : float, optional
        Longest gap of path between two measured commands that is bridged,
        mm. Default: three times the median path distance between
        neighbouring measured commands of a cut (a regular probing pattern is
        bridged, a hole in it is not).

    Returns
    -------
    e_mm : ndarray (K, 3)
        The errors with the bridged commands filled.
    filled : ndarray (K,) bool
        Commands that took an interpolated value.
    reach_mm : float
        The reach used, mm.
    """
    e = np.array(e_mm, dtype=np.float64)
    kk = e.shape[0]
    measured = np.all(np.isfinite(e), axis=1)
    filled = np.zeros(kk, dtype=bool)
    if kk < 3 or measured.sum() < 2:
        return e, filled, 0.0 if reach_mm is None else float(reach_mm)
    ends = program.command_end_mm
    mv = np.asarray(program.command_moves, dtype=np.int64)
    step = np.linalg.norm(np.diff(ends, axis=0), axis=1)
    same_cut = np.diff(mv) == 1
    s = np.concatenate([[0.0], np.cumsum(np.where(same_cut, step, 0.0))])
    cut = np.concatenate([[0], np.cumsum(~same_cut)])
    mk = np.flatnonzero(measured)
    pair = cut[mk[1:]] == cut[mk[:-1]]
    gaps = (s[mk[1:]] - s[mk[:-1]])[pair]
    if reach_mm is None:
        reach_mm = 3.0 * float(np.median(gaps)) if gaps.size else 0.0
    # for each unmeasured command: the measured command before and after it
    after = np.searchsorted(mk, np.arange(kk))
    lo = np.clip(after - 1, 0, mk.size - 1)
    hi = np.clip(after, 0, mk.size - 1)
    ka, kb = mk[lo], mk[hi]
    ok = (~measured) & (after > 0) & (after < mk.size) & (cut[ka] == cut[kb]) & (s[kb] - s[ka] <= reach_mm + 1e-9)
    ok &= (cut == cut[ka]) & (s[kb] > s[ka])
    if ok.any():
        w = ((s - s[ka]) / np.where(s[kb] > s[ka], s[kb] - s[ka], 1.0))[ok, None]
        e[ok] = (1.0 - w) * e[ka[ok]] + w * e[kb[ok]]
        filled[ok] = True
    return e, filled, float(reach_mm)


def log_on_refined(log: AxisLog, original: Program, refined: Program, inserted: Any) -> AxisLog:
    """The log of ``original`` read as a log of its refined program (:mod:`ilcnc.learning.refine`): each sample's line
    becomes the line of the piece its commanded position is on (the refined program plans the original's
    path in the original's time, so its run is this run). ``inserted`` is the
    :class:`ilcnc.program.insert.InsertResult` that made ``refined``."""
    mv = sample_moves(log, original)
    m = len(original.moves)
    fr: list[list[float]] = [[] for _ in range(m)]
    for x in inserted.inserted:
        fr[x.move].append(float(x.fraction))
    fr = [sorted(f) for f in fr]
    n_ins = np.array([len(f) for f in fr], dtype=np.int64)
    first = np.arange(m) + np.concatenate(([0], np.cumsum(n_ins)[:-1]))  # refined index of each move's first piece
    if first[-1] + n_ins[-1] != len(refined.moves) - 1:
        raise ValueError("the refined program is not the original with the inserted pieces")
    piece = np.zeros(log.n_samples, dtype=np.int64)
    ok = mv >= 0
    split = ok & (n_ins[np.maximum(mv, 0)] > 0)
    if split.any():
        j = mv[split]
        a, b = original.moves.start_mm[j], original.moves.end_mm[j]
        d = b - a
        ref = np.nan_to_num(np.asarray(log.ref_mm, dtype=np.float64)[split])
        f = np.einsum("ij,ij->i", ref - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
        piece[split] = [int(np.searchsorted(fr[jj], ff, side="right")) for jj, ff in zip(j.tolist(), f.tolist(), strict=True)]
        # along a move the pieces only go forward: where a blend takes the commanded position round a corner
        # sharper than 90°, its projection on the move falls back while the control still names the move
        # (jsdc on LinuxCNC's planner: back from a retract's piece to the one before)
        starts = np.flatnonzero(np.diff(np.concatenate(([-2], np.where(split, mv, -2)))) != 0)
        for a_, b_ in zip(starts.tolist(), np.concatenate((starts[1:], [log.n_samples])).tolist(), strict=True):
            if split[a_] and b_ - a_ > 1:
                piece[a_:b_] = np.maximum.accumulate(piece[a_:b_])
    new_mv = np.where(ok, first[np.maximum(mv, 0)] + piece, -1)
    line = np.where(new_mv >= 0, refined.moves.line[np.maximum(new_mv, 0)], 0).astype(np.int64)
    cmd = np.where(new_mv >= 0, refined.moves.command[np.maximum(new_mv, 0)], -1).astype(np.int64)
    return AxisLog(log.t_s, cmd, line, log.ref_mm, log.act_mm)


def settle_windows(log: AxisLog, original: Program, settled: dict[int, float]) -> NDArray[np.bool_]:
    """Samples of a log of ``original`` that a settle of its refined program changes: for each settled move (index
    -> dwell, s; :attr:`ilcnc.program.insert.InsertResult.settled`), its first ``dwell`` seconds. There the axes were
    still closing the rapid's lag, which the settle closes before the feed starts, so this log says nothing of how
    the refined program runs there."""
    out = np.zeros(log.n_samples, dtype=bool)
    if not settled:
        return out
    mv = sample_moves(log, original)
    t = np.asarray(log.t_s, dtype=np.float64)
    for j, secs in settled.items():
        on = np.flatnonzero(mv == j)
        if on.size:
            out[on[t[on] < t[on[0]] + secs]] = True
    return out

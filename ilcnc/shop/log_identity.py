"""Is an axis log one whole run of the program the learning state says ran last?

A log is the ground truth of one learning step: its errors become corrections
of the next program. Before any error is read from it, :func:`check_log_identity`
shows it is a run of *that* program, from its first command to its last, in the
program's coordinates, with its columns the right way round. Each check is one
line naming the file and what to do:

* **Block numbers** (``k`` or ``line``): a sample is tied to its command by the
  block the controller ran. A log without any (a TNCscope export without the
  block-number signal, an ilcnc CSV with ``k = -1, line = 0``) is refused: a
  lagging sample cannot be told from the command it belongs to by position
  alone, and a guess turned a 13 µm error into 16,031 µm (issue 25).
* **Exactly once, first to last**: the blocks run in program order, never back
  (two runs back to back go back), from the first correctable command to the
  last (a log cut off at 52 % does not reach it).
* **Columns the right way round**: the actual position lags the commanded one
  along the path (by about v / Kv); when it runs ahead on nearly every sample,
  the two are swapped.
* **On this program's path**: the commanded positions lie on the path of the
  program that ran, within the log's number resolution, wherever the planner
  does not blend a corner. A log of an earlier iteration's program (the same
  lines, other coordinates), or one shifted by a work offset, lies off it. The
  share of the log's commanded samples on the path must be at least
  :data:`MIN_ON_PATH_SHARE` of the share the profile's planner keeps on it,
  move by move (a filter planner leaves a dense program's path nearly
  everywhere: where it keeps fewer than 50 samples, or 5 %, on the path, this
  check says nothing). Measured on LinuxCNC logs of CAM programs: jsdc 96 %,
  compass 99.8 %, tiny_cat_outline 100 % on the path; the log of jsdc's
  original against its first corrected program 11 %; jsdc shifted by
  0.01 mm 16 %. When a constant offset puts the log on the path, the message
  names it.
* **Forward, on the named moves**: along a move, the commanded position never
  goes back (repeated samples do), and it lies on the move its block names
  more often than on the one before or after (line numbers of another version
  of the program do not).
* **Not an earlier program's**: where the program that ran and an earlier one
  of the run differ, the commanded positions must not lie nearer the earlier.

The log's samples also get a fingerprint independent of how they are written
(:func:`samples_fingerprint`), so a log used once is recognised again after its
text was edited (a comment added, numbers reformatted).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ilcnc.axislog.log import AxisLog
from ilcnc.contour.path import PathGeometry
from ilcnc.errors import LogError
from ilcnc.program.model import MOVE_RAPID, Program

__all__ = ["MIN_ON_PATH_SHARE", "LogIdentity", "check_block_numbers", "check_log_identity", "check_log_order",
           "log_quantum_mm", "samples_fingerprint"]

#: Least share, relative to the profile's planner's, of the commanded feed samples on the path of the program that ran.
MIN_ON_PATH_SHARE = 0.5
#: Share of the samples with a measurable lag on which the actual position must run ahead for "swapped".
SWAPPED_SHARE = 0.9
#: Largest step back along the path of the commanded position from one sample to the next, mm.
MAX_BACK_MM = 0.01
#: Least share of the commanded feed samples on the move their block number names.
MIN_BLOCK_MATCH = 0.2
#: Least number of samples that must vote for an earlier program before a log is refused as its run.
MIN_VOTES = 20
#: Most samples the identity checks search the path for (every n-th of a longer log).
MAX_CHECK_SAMPLES = 2_000_000
#: Decimals of the fingerprint (1 nm: finer than any log's numbers, coarser than the parse's rounding).
FINGERPRINT_DECIMALS = 6


@dataclass(frozen=True, slots=True, kw_only=True)
class LogIdentity:
    """What the identity checks measured on a log that passed them.

    Attributes
    ----------
    on_path_share : float or None
        Share of the commanded feed samples within ``on_path_tol_mm`` of the path of the program
        that ran (None: the log has no commanded positions).
    on_path_tol_mm : float
        Half the machine resolution, or the rounding of the log's numbers when coarser, mm.
    lead_mm : float or None
        Median lead of the commanded over the actual position along the path, mm.
    """

    on_path_share: float | None
    on_path_tol_mm: float
    lead_mm: float | None


def samples_fingerprint(log: AxisLog) -> str:
    """SHA-256 of the log's samples (block, commanded and actual positions rounded to 1 nm), not of its text."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(log.k, dtype=np.int64).tobytes())
    h.update(np.ascontiguousarray(log.line, dtype=np.int64).tobytes())
    for a in (log.ref_mm, log.act_mm):
        v = np.round(np.asarray(a, dtype=np.float64), FINGERPRINT_DECIMALS) + 0.0  # -0.0 -> 0.0
        h.update(np.ascontiguousarray(np.nan_to_num(v, nan=np.inf)).tobytes())
    return h.hexdigest()


def log_quantum_mm(values: NDArray[np.float64], *, max_decimals: int = 9) -> float:
    """The step of the numbers a log was written with (``10**-d`` for the fewest decimals ``d`` that hold them), mm."""
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)][:20000]
    for d in range(max_decimals + 1):
        scaled = v * 10.0**d
        if np.all(np.abs(scaled - np.round(scaled)) <= 1e-3 + 1e-12 * np.abs(scaled)):  # parse rounding: ~1e-16 rel
            return 10.0**-d
    return 10.0**-max_decimals


def check_block_numbers(moves: NDArray[np.int64], source: str | Path) -> None:
    """Refuse a log none of whose samples names a block of the program (``moves``: each sample's move from its
    block number, -1: none)."""
    if not (moves >= 0).any():
        raise LogError(Path(source), None, "the log has no block numbers (every k is -1 and every line 0): its samples"
                       " cannot be tied to the program's commands; record the block number with the positions"
                       " (LinuxCNC: motion.program-line; TNCscope: the block-number signal)")


def check_log_order(moves: NDArray[np.int64], ran: Program, source: str | Path, t_s: NDArray[np.float64]) -> None:
    """Refuse a log that does not run the program's commands once, first to last (after
    :func:`check_block_numbers`).

    Parameters
    ----------
    moves : ndarray (N,) int
        Move of each sample from its block number (-1: none), before any filling.
    ran : Program
        The program that ran.
    source : path
        The log (for messages).
    t_s : ndarray (N,)
        Sample times, s (for messages).
    """
    check_block_numbers(moves, source)
    src = Path(source)
    known = np.flatnonzero(moves >= 0)
    seq = moves[known]
    back = np.flatnonzero(np.diff(seq) < 0)
    if back.size:
        i = int(known[back[0] + 1])
        line_back, line_before = int(ran.moves.line[seq[back[0] + 1]]), int(ran.moves.line[seq[back[0]]])
        raise LogError(src, None, f"the log goes back from line {line_before} to line {line_back} at t = {t_s[i]:.3f} s:"
                       " it holds more than one run (a log must record one run of the program, once)")
    cm = ran.command_moves
    if cm.size:
        first, last = int(cm[0]), int(cm[-1])
        if seq[0] > first:
            raise LogError(src, None, f"the log starts at line {int(ran.moves.line[seq[0]])}, after the program's first"
                           f" command (line {int(ran.moves.line[first])}): record the whole run, from its start")
        if seq[-1] < last:
            i = int(known[-1])
            raise LogError(src, None, f"the log ends at line {int(ran.moves.line[seq[-1]])} (t = {t_s[i]:.3f} s), before"
                           f" the program's last command (line {int(ran.moves.line[last])}): it is not a whole run")


def _every_nth(idx: NDArray[np.int64]) -> NDArray[np.int64]:
    """``idx``, or every n-th of it when it holds more than :data:`MAX_CHECK_SAMPLES`."""
    step = -(-idx.size // MAX_CHECK_SAMPLES)
    return idx[::step] if step > 1 else idx


def _shift_estimate(resid: NDArray[np.float64], tangent: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """The constant offset ``s`` that best explains the residuals ``r_i = (I - t_i t_i^T) s`` (least squares)."""
    a = np.eye(3) * resid.shape[0] - tangent.T @ tangent
    b = resid.sum(axis=0)
    try:
        s = np.linalg.lstsq(a, b, rcond=1e-6)[0]
    except np.linalg.LinAlgError:
        return None
    return s if np.all(np.isfinite(s)) else None


def _find_shift(path: PathGeometry, ref: NDArray[np.float64], hint: NDArray[np.int64], first: object, tol: float,
                *, need: float, rounds: int = 6) -> NDArray[np.float64] | None:
    """A constant offset that puts the commanded positions on the path, if one does (None otherwise).

    Least squares on the residuals perpendicular to the path, repeated from the shifted positions (near a
    sharp corner the nearest point moves with the shift, so one round is biased: 1.022 mm for 1 mm on a star).
    """
    from ilcnc.contour.search import contour_error

    e = first
    total = np.zeros(3)
    for _ in range(rounds):
        d = e.dist_mm  # type: ignore[attr-defined]
        ok = np.isfinite(d)
        if not ok.any():
            return None
        ok &= d <= max(2.0 * float(np.median(d[ok])), tol)  # trimmed: the blends' own deviation biases it
        seg = np.clip(e.seg, 0, len(path) - 1)  # type: ignore[attr-defined]
        t = path.tangent_at(seg, np.clip(e.u - e.seg, 0.0, 1.0))  # type: ignore[attr-defined]
        step = _shift_estimate((ref - total - e.foot_mm)[ok], t[ok])  # type: ignore[attr-defined]
        if step is None:
            return None
        total = total + step
        e = contour_error(path, ref - total, hint)
        if float(np.linalg.norm(step)) <= 0.1 * tol:
            break
    on = np.isfinite(e.dist_mm) & (e.dist_mm <= tol)
    return total if float(np.mean(on)) >= need else None


def check_log_identity(ref_mm: NDArray[np.float64], act_mm: NDArray[np.float64], t_s: NDArray[np.float64],
                       ran: Program, *,
                       act_seg: NDArray[np.int64], act_frac: NDArray[np.float64],
                       drawing: PathGeometry, sample_move: NDArray[np.int64], feed: NDArray[np.bool_],
                       planned_mm: NDArray[np.float64], planned_move: NDArray[np.integer], resolution_mm: float,
                       source: str | Path, earlier: Sequence[tuple[str, Program]] = ()) -> LogIdentity:
    """Refuse a log whose columns are swapped or whose commanded positions are not on the path of ``ran``.

    Parameters
    ----------
    ref_mm, act_mm : ndarray (N, 3)
        The log's commanded and actual positions, mm (work offset applied; Z 0 in a 2-axis log).
    t_s : ndarray (N,)
        Sample times, s (for messages).
    ran : Program
        The program the state says ran last.
    act_seg, act_frac : ndarray (N,)
        Each actual sample's nearest point on ``drawing`` (segment, fraction), from the contour search.
    drawing : PathGeometry
        The drawing's path the actual samples were measured against.
    sample_move : ndarray (N,) int
        Move of ``ran`` running at each sample (filled, >= 0 where known).
    feed : ndarray (N,) bool
        Samples on feed moves.
    planned_mm, planned_move : ndarray (P, 3), (P,)
        The profile's planner's commanded positions for ``ran`` and their moves (what share of each move's
        commanded positions a planner keeps on the path).
    resolution_mm : float
        The machine's resolution (``machine.resolution_mm``).
    source : path
        The log (for messages).
    earlier : sequence of (str, Program)
        The programs that ran before ``ran`` in this learning run, each with what to call it ("the program
        of iteration 0 (iter-000.ngc)"): the log must not fit one of them better than ``ran``.

    Raises
    ------
    LogError
        Columns swapped, commanded positions off the path (a shift is named when one explains it), or closer
        to an earlier program's path than to the one of ``ran``.
    """
    from ilcnc.contour.search import contour_error

    src = Path(source)
    ref = np.asarray(ref_mm, dtype=np.float64)
    act = np.asarray(act_mm, dtype=np.float64)
    usable = feed & np.all(np.isfinite(ref), axis=1) & (act_seg >= 0)
    quantum = log_quantum_mm(ref[usable][:, :2]) if usable.any() else 0.0
    tol = max(0.5 * resolution_mm, float(np.sqrt(3.0)) * 0.5 * quantum)
    if not usable.any():
        return LogIdentity(on_path_share=None, on_path_tol_mm=tol, lead_mm=None)
    # columns: the actual position lags the commanded one along the path
    tangent = drawing.tangent_at(act_seg[usable], np.clip(act_frac[usable], 0.0, 1.0))
    lead = np.einsum("ij,ij->i", ref[usable] - act[usable], tangent)
    big = np.abs(lead) > resolution_mm
    lead_med = float(np.median(lead))
    if big.sum() >= max(10, 0.01 * usable.sum()) and np.mean(lead[big] < 0) > SWAPPED_SHARE:
        raise LogError(src, None, f"the actual positions run ahead of the commanded ones along the path on"
                       f" {np.mean(lead[big] < 0):.0%} of the feed samples that lag (median {-lead_med:.4g} mm): the"
                       " commanded and actual columns are swapped (--log-columns)")
    # the commanded positions lie on the path of the program that ran, wherever the profile's planner keeps its
    # own commanded positions on it (a filter planner leaves dense short moves everywhere: no test there)
    path = PathGeometry.from_moves(ran.moves, include_rapids=True)
    hint = np.maximum(sample_move, 0)
    on_feed = usable & (ran.moves.kind[hint] != MOVE_RAPID)
    pm = np.asarray(planned_move, dtype=np.int64)
    p_feed = (pm >= 0) & (ran.moves.kind[np.maximum(pm, 0)] != MOVE_RAPID)
    if not on_feed.any() or not p_feed.any():
        return LogIdentity(on_path_share=None, on_path_tol_mm=tol, lead_mm=lead_med)
    # long runs are judged on every n-th sample (at most MAX_CHECK_SAMPLES): the shares are statistics, and a
    # contour search over every planned sample would double the cost of measuring a log
    p_idx = _every_nth(np.flatnonzero(p_feed))
    dp = contour_error(path, np.asarray(planned_mm, dtype=np.float64)[p_idx], pm[p_idx]).dist_mm
    n_moves = len(ran.moves)
    planned_on = np.bincount(pm[p_idx], weights=(np.isfinite(dp) & (dp <= tol)).astype(np.float64),
                             minlength=n_moves) / np.maximum(np.bincount(pm[p_idx], minlength=n_moves), 1)
    keep = _every_nth(np.flatnonzero(on_feed))
    on_feed = np.zeros_like(on_feed)
    on_feed[keep] = True
    e = contour_error(path, ref[on_feed], hint[on_feed])
    d = e.dist_mm
    share = float(np.mean(np.isfinite(d) & (d <= tol)))
    expected = float(np.mean(planned_on[hint[on_feed]]))
    judged = expected * on_feed.sum() >= max(50.0, 0.05 * on_feed.sum())
    if judged and share < MIN_ON_PATH_SHARE * expected:
        med = float(np.nanmedian(d))
        where = (f"{share:.0%} of the log's commanded feed positions lie on the path of {ran.path.name} within"
                 f" {tol * 1e3:.2g} µm, where the profile's planner keeps {expected:.0%} of its own on it (median"
                 f" distance {med * 1e3:.3g} µm)")
        shift = _find_shift(path, ref[on_feed], hint[on_feed], e, tol, need=MIN_ON_PATH_SHARE * expected)
        if shift is not None:
            shift = np.round(shift, 4) + 0.0  # no -0
            xyz = ",".join(f"{v:.4f}".rstrip("0").rstrip(".") for v in shift)
            raise LogError(src, None, f"{where}: they are shifted by X{shift[0]:+.4f} Y{shift[1]:+.4f}"
                           f" Z{shift[2]:+.4f} mm from it: a work offset? (--log-offset {xyz})")
        # a log of an earlier program of the run is named as such
        _check_not_earlier(ref[on_feed], hint[on_feed], ran, path, earlier, tol, src, planned_on=planned_on)
        raise LogError(src, None, f"{where}: it is not a log of this program as the state says it ran last (a log of"
                       " an earlier iteration's program, or of another part)")
    # on the path: its samples' places on it tell whether they run forward, on the moves their blocks name
    _check_forward(path, e, hint[on_feed], np.asarray(t_s, dtype=np.float64)[on_feed], src)
    _check_blocks_name_moves(e, hint[on_feed], src)
    _check_not_earlier(ref[on_feed], hint[on_feed], ran, path, earlier, tol, src, planned_on=planned_on)
    return LogIdentity(on_path_share=share, on_path_tol_mm=tol, lead_mm=lead_med)


def _check_forward(path: PathGeometry, e: object, hint: NDArray[np.int64], t_s: NDArray[np.float64],
                   src: Path) -> None:
    """Refuse a log whose commanded position goes back along a move (samples repeated within a block).

    Judged between consecutive samples on the move their block names whose nearest points lie on it, away from
    its ends (a closed contour's last point is also its first: a tie, not a step back). Measured on LinuxCNC
    logs (jsdc, its first corrected run, compass, tiny_cat_outline): never back by more than 1 µm;
    :data:`MAX_BACK_MM` allows 10.
    """
    seg = np.asarray(e.seg, dtype=np.int64)  # type: ignore[attr-defined]
    frac = np.asarray(e.u, dtype=np.float64) - seg  # type: ignore[attr-defined]
    on = (seg == hint) & (frac > 1e-9) & (frac < 1.0 - 1e-9)
    length = path.length_mm[np.clip(seg, 0, len(path) - 1)]
    pos = frac * length
    pair = on[:-1] & on[1:] & (seg[:-1] == seg[1:])
    step = np.diff(pos)
    back = np.flatnonzero(pair & (step < -MAX_BACK_MM))
    if back.size:
        i = back[0]
        raise LogError(src, None, f"the commanded position goes back along the path by {-step[i]:.4g} mm at"
                       f" t = {t_s[i + 1]:.3f} s: samples are repeated (a log must record one run, once)")


def _check_blocks_name_moves(e: object, hint: NDArray[np.int64], src: Path) -> None:
    """Refuse a log whose block numbers name other moves than the ones its commanded positions are on.

    The commanded position of a sample lies on the move its block number names, or, in a blend, on a
    neighbour: the named move must hold more of them than the move before or after it, and at least
    :data:`MIN_BLOCK_MATCH` of them. Measured on LinuxCNC logs: jsdc 67 % on the named move (LinuxCNC
    names a blend's first block through it), tiny_cat_outline 99.8 %, compass 98 %; with every line
    number moved by one: 4 % and 0 %, by minus one 31 % (and 67 % on the next move).
    """
    seg = np.asarray(e.seg, dtype=np.int64)  # type: ignore[attr-defined]
    if seg.size < MIN_VOTES:
        return
    here = float(np.mean(seg == hint))
    before = float(np.mean(seg == hint - 1))
    after = float(np.mean(seg == hint + 1))
    if here < MIN_BLOCK_MATCH or max(before, after) > here:
        other = "the move before" if before >= after else "the move after"
        raise LogError(src, None, f"the log's block numbers do not name the moves its commanded positions are on"
                       f" ({here:.0%} of the feed samples lie on the move their block names, {max(before, after):.0%}"
                       f" on {other}): its line numbers are not this program's (a log of another version of it?)")


def _check_not_earlier(ref: NDArray[np.float64], hint: NDArray[np.int64], ran: Program, path: PathGeometry,
                       earlier: Sequence[tuple[str, Program]], tol: float, src: Path, *,
                       planned_on: NDArray[np.float64]) -> None:
    """Refuse a log that fits an earlier program of the run better than ``ran``, where the two paths differ.

    Only the samples on moves whose end points differ by more than ``tol`` judge (elsewhere the two
    programs are one path), and of those only the moves on which the profile's planner keeps most of its
    own commanded positions on the path (``planned_on`` >= 0.5): where a planner smooths a dense curve, its
    commanded positions leave the program's path by more than the corrections, and the corrections are
    made to bring them back onto the drawing, so the log of a corrected program lies nearer the original's
    path there (measured: compass's first 60 lines on example-mill's filter planner, 2.0 µm from its own
    path, 0.3 µm from the original's). A sample votes for the program whose path is nearer by more than
    ``tol`` and lies on it (within ``tol``); more than twice as many votes for an earlier program, and at least
    :data:`MIN_VOTES`, refuse.
    """
    from ilcnc.contour.search import contour_error

    for what, prog in earlier:
        if len(prog.moves) != len(ran.moves):
            continue  # another command table (refined): its lines tell it apart
        moved = (np.abs(prog.moves.start_mm - ran.moves.start_mm).max(axis=1) > tol) \
            | (np.abs(prog.moves.end_mm - ran.moves.end_mm).max(axis=1) > tol)
        sel = moved[hint] & (planned_on[hint] >= 0.5)
        if sel.sum() < MIN_VOTES:
            continue
        d_ran = contour_error(path, ref[sel], hint[sel]).dist_mm
        d_old = contour_error(PathGeometry.from_moves(prog.moves, include_rapids=True), ref[sel], hint[sel]).dist_mm
        # a sample votes only where it lies on one of the two paths: inside a blend it is off both, and which
        # it is nearer to there depends on how the corrections moved the corner, not on which program ran
        old_wins = int(np.sum((d_old <= tol) & (d_old < d_ran - tol)))
        ran_wins = int(np.sum((d_ran <= tol) & (d_ran < d_old - tol)))
        if old_wins >= MIN_VOTES and old_wins > 2 * ran_wins:
            raise LogError(src, None, f"the log's commanded positions fit {what} better than {ran.path.name}, which"
                           f" the state says ran last (nearer on {old_wins} of the {int(sel.sum())} samples where the"
                           f" two differ, farther on {ran_wins}): a log of an earlier run; record a run of"
                           f" {ran.path.name}")

"""The error E(k) of a run, per G01 command: the signal the learning laws learn from.

Five estimates (profile key ``learning.error``):

* ``path`` -- hat-weighted mean contour error of the two moves that meet at
  command k's end point (least squares over the whole path; the default of
  the ``p`` law);
* ``crossing`` -- end point minus the actual position where the machine
  passes closest to it (seed 004's point error, as probing measures it);
* ``contour`` -- exact contour error vector when the reference reaches the
  end of command k (seed 000's ACE);
* ``tangent`` -- seed 000's Frenet-frame estimate at that instant (the
  normal part of desired minus actual, with the original path's tangent);
* ``tracking`` -- end point minus actual at that instant (seed 003);
* ``lifted`` -- the end-point moves that, passed through the drives, best
  cancel the sampled contour error (damped least squares,
  :mod:`ilcnc.vcnc.lifted`): the estimate that sees a corner.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc._jit import compiled_for, njit
from ilcnc.profile.schema import DEFAULT_ERROR
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import MOVE_RAPID, Program

__all__ = [
    "CommandSignal",
    "PathWeightedSums",
    "command_end_tangents",
    "command_signal_from_run",
    "error_kind",
    "measurement_gate_mm",
    "path_weighted_error",
    "plane_crossings",
    "reference_command_samples",
    "signal_of_simulation",
]


# ---------------------------------------------------------------------------------------------
# The per-command error signal
# ---------------------------------------------------------------------------------------------


@dataclass(slots=True, eq=False)
class CommandSignal:
    """The error ``E(k)`` of one run, per G01 command.

    Attributes
    ----------
    e_mm : ndarray (K, 3)
        Error vector of every command, mm (desired minus actual); 0 where not valid.
    t_s : ndarray (K,)
        Time stamp of each command's error (when the machine passed / the
        reference reached its end point), s; interpolated where not valid.
    valid : ndarray (K,) bool
        The run measured this command.
    kind : str
        The estimate: ``crossing``, ``contour``, ``tangent`` or ``tracking``.
    """

    e_mm: NDArray[np.float64]
    t_s: NDArray[np.float64]
    valid: NDArray[np.bool_]
    kind: str

    @property
    def norm_mm(self) -> NDArray[np.float64]:
        """``|E(k)|``, mm (NaN where not valid)."""
        n = np.sqrt(np.einsum("ij,ij->i", self.e_mm, self.e_mm))
        return np.where(self.valid, n, np.nan)


def finish_signal(e: NDArray[np.float64], t: NDArray[np.float64], kind: str) -> CommandSignal:
    valid = np.all(np.isfinite(e), axis=1) & np.isfinite(t)
    e = np.where(valid[:, None], e, 0.0)
    tt = np.asarray(t, dtype=np.float64).copy()
    if valid.any() and not valid.all():
        k = np.arange(tt.size)
        tt[~valid] = np.interp(k[~valid], k[valid], tt[valid])
    elif not valid.any():
        tt = np.arange(tt.size, dtype=np.float64)
    return CommandSignal(e, tt, valid, kind)


def command_signal_from_run(
    kind: str,
    *,
    path: Any,
    err: Any,
    actual_mm: NDArray[np.float64],
    t_s: NDArray[np.float64] | float,
    command_sample: NDArray[np.float64] | None = None,
    ref_mm: NDArray[np.float64] | None = None,
    gate_mm: float | None = None,
    sample_move: NDArray[np.integer] | None = None,
    max_lag_s: float = 0.5,
    on_feed: NDArray[np.bool_] | None = None,
    program: Program | None = None,
    profile: MachineProfile | None = None,
    free: NDArray[np.bool_] | None = None,
) -> CommandSignal:
    """``E(k)`` of a run (simulated or measured) by one of the estimates.

    Parameters
    ----------
    kind : {"path", "crossing", "contour", "tangent", "tracking", "lifted"}
        The estimate (see the profile key ``learning.error``).
    path : PathGeometry
        The *original* programmed path (the drawing).
    err : ContourError
        Exact contour error of every sample against ``path``.
    actual_mm : ndarray (N, 3)
        Actual positions, mm.
    t_s : ndarray (N,) or float
        Sample times, s; or the period, s, of uniform samples from t = 0
        (not for ``crossing``).
    command_sample : ndarray (K,), optional
        Sample at which the reference reaches the end of each command
        (needed by the time-indexed estimates).
    ref_mm : ndarray (N, 3), optional
        Reference positions of the run. Not used: ``tangent`` takes the
        desired reference and its tangent from the original ``path`` (the
        run's reference holds the corrections); kept for callers.
    gate_mm : float, optional
        An error longer than this is not a measurement (the command is left alone).
    sample_move : ndarray (N,) int, optional
        Move the reference (or the running block of a log) is on at each
        sample, -1 before the first (needed by ``crossing``).
    max_lag_s : float
        ``crossing``: how long after the reference left a command the machine
        may still pass its end point, s.
    on_feed : ndarray (N,) bool, optional
        ``path``, ``lifted``: samples that count (the machine executes a feed move).
    program : Program, optional
        ``lifted``: the program whose moves the run's reference is on.
    profile : MachineProfile, optional
        ``lifted``: the drive models and servo period.
    free : ndarray (K, 3) bool, optional
        ``lifted``: the coordinates the learning may move (default: every axis of the profile).
    """
    from ilcnc.contour.estimates import tangent_error

    kk = path.n_commands
    gate = gate_mm if gate_mm is not None else math.inf
    if kind == "path":
        e, t = path_weighted_error(path, err, t_s, on_feed=on_feed)
        e[np.linalg.norm(np.nan_to_num(e, nan=np.inf), axis=1) > gate] = np.nan
        return finish_signal(e, t, kind)
    if kind == "crossing":
        if sample_move is None:
            raise ValueError("error estimate 'crossing' needs the move each sample's reference is on")
        ts = np.arange(actual_mm.shape[0]) * t_s if np.ndim(t_s) == 0 else t_s
        e, t = plane_crossings(path, actual_mm, ts, sample_move, max_lag_s=max_lag_s)
        e[np.linalg.norm(np.nan_to_num(e, nan=np.inf), axis=1) > gate] = np.nan
        return finish_signal(e, t, kind)
    if command_sample is None:
        raise ValueError(f"error estimate {kind!r} needs the sample of each command")
    if kind == "lifted":
        from ilcnc.vcnc.lifted import lifted_error

        if program is None or profile is None or ref_mm is None or sample_move is None:
            raise ValueError("error estimate 'lifted' needs the program, the profile, the reference and its moves")
        ns = actual_mm.shape[0]
        w = np.ones(ns, bool) if on_feed is None else np.asarray(on_feed, bool)
        fr = np.ones((kk, 3), bool) if free is None else np.asarray(free, bool)
        e, t, ok = lifted_error(program=program, profile=profile, path=path, err=err, ref_mm=ref_mm,
                                sample_move=sample_move, weight=w, command_sample=command_sample, t_s=t_s,
                                free=fr, gate_mm=gate)
        e[~ok] = np.nan
        return finish_signal(e, t, kind)
    cs = np.asarray(command_sample, dtype=np.float64)
    ok = np.isfinite(cs)
    idx = np.where(ok, cs, 0).astype(np.int64)
    idx = np.clip(idx, 0, max(actual_mm.shape[0] - 1, 0))
    e = np.full((kk, 3), np.nan)
    if kind == "contour":
        v = err.vector_mm[idx]
    elif kind == "tangent":
        # against the *original* desired reference: where it is when the run's reference reaches command k's end
        # (the original end point) and its tangent there; never the run's own (corrected) reference, which
        # holds the correction U itself (r_run - q = r - q + U would feed U back into the next update)
        v, _n = tangent_error(path.end_mm[path.move_of_command], actual_mm[idx], tangent=command_end_tangents(path))
    elif kind == "tracking":
        v = path.end_mm[path.move_of_command] - actual_mm[idx]
    elif kind == "surface":
        raise ValueError("error estimate 'surface' is the virtual CNC's wall (seed 004 eq. 4): a measured log has"
                         " none; set learning.error to crossing")
    else:
        raise ValueError(f"unknown error estimate {kind!r}")
    e[ok] = v[ok]
    e[~np.isfinite(e)] = np.nan
    e[np.linalg.norm(np.nan_to_num(e, nan=np.inf), axis=1) > gate] = np.nan
    t = np.where(ok, idx * t_s if np.ndim(t_s) == 0 else np.asarray(t_s)[idx], np.nan)
    return finish_signal(e, t, kind)


def path_weighted_error(
    path: Any,
    err: Any,
    t_s: NDArray[np.float64] | float,
    *,
    on_feed: NDArray[np.bool_] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``E(k)`` as the contour error along the two moves that end and start at command k's end point.

    Moving end point k by ``U`` shifts the programmed path by the "hat"
    ``(1 - f)·U`` along the move that starts there and ``f·U`` along the move
    that ends there (``f`` the fraction along the move). The error of the
    whole path is least-squares reduced by the hat-weighted mean of the
    contour error vectors (foot − actual) of the samples on those two moves
    (the gradient of the squared error, normalised by the lumped weights): a
    gradient ILC in path space. Where segments are short this is the local
    error at the point; where a point joins two long segments a local error
    at the corner (a rounded corner) is diluted by the rest of the segments,
    which is right: moving that point would tilt both segments over their
    whole length.

    Parameters
    ----------
    path : PathGeometry
        The original programmed path.
    err : ContourError
        Contour error of every sample against ``path``.
    t_s : ndarray (N,) or float
        Sample times, s; or the sample period, s, when the samples are
        uniform from t = 0 (a virtual-CNC run: no N-long time array is made).
    on_feed : ndarray (N,) bool, optional
        Samples that count (the machine executes a feed move).

    Returns
    -------
    e_mm : ndarray (K, 3)
        Weighted mean error vector, mm (NaN where no sample touches the command).
    t_s : ndarray (K,)
        Weighted mean time, s.
    """
    acc = PathWeightedSums(path)
    acc.add(err, t_s, on_feed=on_feed)
    return acc.result()


class PathWeightedSums:
    """The sums of :func:`path_weighted_error`, accumulated over a run handed over in consecutive stretches.

    A long run is simulated chunk by chunk (:mod:`ilcnc.vcnc.stream`): each chunk's contour error is added
    (:meth:`add`, with the index of its first sample) and dropped; the sums are those of one pass over
    the whole run, in the same order, so :meth:`result` is :func:`path_weighted_error`'s, bit for bit.
    Memory O(K).
    """

    def __init__(self, path: Any) -> None:
        self.path = path
        kk = path.n_commands
        cmd = np.asarray(path.command, dtype=np.int64)
        nseg = cmd.size
        # the command whose end point starts each move; -1 for the first move, and where the previous
        # move's end is not this move's start (a gap in the table)
        k_start = np.full(nseg, -1, dtype=np.int64)
        if nseg > 1:
            joined = np.all(np.abs(path.end_mm[:-1] - path.start_mm[1:]) <= 1e-9, axis=1)
            k_start[1:] = np.where(joined, cmd[:-1], -1)
        # a sample whose foot is on a rapid (the tool still on the rapid's line as the feed move starts: in
        # the air) is no error of the cut: no command's E(k)
        k_start[np.asarray(path.kind) == MOVE_RAPID] = -1
        self.cmd, self.k_start = cmd, k_start
        self.num = np.zeros((kk, 3))
        self.den = np.zeros(kk)
        self.tnum = np.zeros(kk)

    def add(self, err: Any, t_s: NDArray[np.float64] | float, *, on_feed: NDArray[np.bool_] | None = None,
            first_sample: int = 0) -> None:
        """Add the samples of one stretch: ``err`` its contour error, ``t_s`` its times (or the period of
        uniform samples from t = 0, then ``first_sample`` is the index of the stretch's first sample)."""
        if self.den.size == 0 or len(err.dist_mm) == 0:
            return
        feed = np.ones(1, dtype=np.bool_) if on_feed is None else np.asarray(on_feed, dtype=np.bool_)
        if np.ndim(t_s) == 0:
            period, times = float(t_s), np.zeros(1)
        else:
            period, times = -1.0, np.ascontiguousarray(t_s, dtype=np.float64)
        args = (np.asarray(err.seg, dtype=np.int64), np.asarray(err.u, dtype=np.float64),
                np.asarray(err.vector_mm, dtype=np.float64), np.asarray(err.dist_mm, dtype=np.float64),
                feed, on_feed is not None, times, period, int(first_sample), self.cmd, self.k_start, self.num,
                self.den, self.tnum)
        if compiled_for(0):  # in a small run (ilcnc._jit.kernels_for): the numpy path
            _path_weighted_kernel_jit()(*args)
        else:  # pragma: no cover - numba is a runtime dependency
            _path_weighted_numpy(*args)

    def result(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(e_mm, t_s)`` as :func:`path_weighted_error` returns them."""
        kk = self.den.size
        e = np.full((kk, 3), np.nan)
        t = np.full(kk, np.nan)
        has = self.den > 0
        e[has] = self.num[has] / self.den[has, None]
        t[has] = self.tnum[has] / self.den[has]
        return e, t


def _path_weighted_numpy(seg, u, vec, dist, feed, use_feed, times, period, offset, cmd, k_start, num, den, tnum):
    """Numpy form of :func:`_path_weighted_kernel` (the reference of its test; memory: several N-long temporaries)."""
    ok = (seg >= 0) & np.isfinite(dist)
    if use_feed:
        ok &= feed
    idx_s = np.flatnonzero(ok)
    s = seg[idx_s]
    f = np.clip(u[idx_s] - s, 0.0, 1.0)
    ts = (idx_s + offset) * period if period >= 0 else times[idx_s]
    idx = np.concatenate([cmd[s], k_start[s]])
    w = np.concatenate([f, 1.0 - f])
    sel = (idx >= 0) & (w > 0)
    idx, w = idx[sel], w[sel]
    kk = den.size
    vv = np.concatenate([vec[idx_s], vec[idx_s]])[sel]
    den += np.bincount(idx, weights=w, minlength=kk)
    for a in range(3):
        num[:, a] += np.bincount(idx, weights=w * vv[:, a], minlength=kk)
    tnum += np.bincount(idx, weights=w * np.concatenate([ts, ts])[sel], minlength=kk)


def _path_weighted_kernel(  # pragma: no cover - compiled
    seg, u, vec, dist, feed, use_feed, times, period, offset, cmd, k_start, num, den, tnum
):
    """One pass over the samples, accumulating the hat-weighted sums per command (memory O(K), not O(N))."""
    for i in range(seg.shape[0]):
        s = seg[i]
        if s < 0 or not np.isfinite(dist[i]):
            continue
        if use_feed and not feed[i]:
            continue
        f = u[i] - s
        if f < 0.0:
            f = 0.0
        elif f > 1.0:
            f = 1.0
        ti = (i + offset) * period if period >= 0.0 else times[i]
        k = cmd[s]
        if k >= 0 and f > 0.0:
            den[k] += f
            tnum[k] += f * ti
            for a in range(3):
                num[k, a] += f * vec[i, a]
        k = k_start[s]
        g = 1.0 - f
        if k >= 0 and g > 0.0:
            den[k] += g
            tnum[k] += g * ti
            for a in range(3):
                num[k, a] += g * vec[i, a]


def _path_weighted_kernel_jit() -> Any:
    k = _KERNELS.get("path_weighted")
    if k is None:
        k = _KERNELS["path_weighted"] = njit(cache=True, nogil=True)(_path_weighted_kernel)
    return k


def plane_crossings(
    path: Any,
    actual_mm: NDArray[np.float64],
    t_s: NDArray[np.float64],
    sample_move: NDArray[np.integer],
    *,
    max_lag_s: float = 0.5,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where the machine passes the end point of each G01 command (seed 004's ``E(k)``).

    The machine passes the end point B of command k where it comes closest
    to B: ``E(k) = B - q`` at that instant. On a smooth polyline that is where
    it crosses the plane normal to the path at B (the error is normal to the
    path); at a corner it is the tip of the rounded corner (the error points
    along the bisector, and pushing B out along it sharpens the corner); at
    a hairpin or a plunge it is the turning point. The search runs from the
    sample before the reference enters the command's move until the machine
    clearly moves away again, at most ``max_lag_s`` after the reference left
    the move; the closest point is refined on the chords to the neighbouring
    samples.

    The nearest-point foot of the contour error is not used on purpose: where
    the path runs back over itself (V-carving, a plunge and retract on one
    line) the nearest point jumps between the two passes, and a plane
    crossing never happens at a corner that the machine rounds off (it
    approaches the plane of B asymptotically while already moving along the
    next move).

    Returns
    -------
    e_mm : ndarray (K, 3)
        ``B - q`` at the closest approach, mm (NaN: the command was never reached).
    t_s : ndarray (K,)
        Time of the closest approach, s (NaN: never reached).
    """

    q = np.ascontiguousarray(np.nan_to_num(np.asarray(actual_mm, dtype=np.float64)))
    if q.shape[1] == 2:
        q = np.column_stack([q, np.zeros(q.shape[0])])
    mk = np.asarray(path.move_of_command, dtype=np.int64)
    a = np.ascontiguousarray(path.start_mm[mk])
    b = np.ascontiguousarray(path.end_mm[mk])
    mv = np.asarray(sample_move, dtype=np.int64)
    # the block index of a log can stand still or step back (a loop): a running max is monotone
    mvmax = np.maximum.accumulate(mv) if mv.size else mv
    s_enter = np.searchsorted(mvmax, mk, side="left")
    s_leave = np.searchsorted(mvmax, mk, side="right")
    ts = np.asarray(t_s, dtype=np.float64)
    period = float(np.median(np.diff(ts))) if ts.size > 1 else 1.0
    lag = int(np.ceil(max_lag_s / period)) if period > 0 else 0
    kernel = _crossing_kernel_jit(njit)
    e = np.full((mk.size, 3), np.nan)
    frac = np.full(mk.size, np.nan)
    kernel(q, a, b, s_enter.astype(np.int64), s_leave.astype(np.int64), lag, e, frac)
    t = np.full(mk.size, np.nan)
    ok = np.isfinite(frac)
    if ok.any():
        t[ok] = np.interp(frac[ok], np.arange(ts.size), ts)
    return e, t


_KERNELS: dict[str, Any] = {}


def _crossing_kernel_jit(njit: Any) -> Any:
    k = _KERNELS.get("crossing")
    if k is None:
        k = _KERNELS["crossing"] = njit(cache=True)(_crossing_kernel)
    return k


def _crossing_kernel(q, a, b, s_enter, s_leave, lag, e, frac):  # pragma: no cover - compiled
    n = q.shape[0]
    for j in range(a.shape[0]):
        if s_enter[j] >= n:
            continue
        s = max(s_enter[j] - 1, 0)
        stop = min(s_leave[j] + lag, n - 1)
        best = np.inf
        best_i = -1
        i = s
        while i <= stop:
            d0 = b[j, 0] - q[i, 0]
            d1 = b[j, 1] - q[i, 1]
            d2 = b[j, 2] - q[i, 2]
            d = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if d < best:
                best = d
                best_i = i
            elif i > s_leave[j] and d > 2.0 * best + 0.05:
                break  # clearly moving away again: the closest approach is behind
            i += 1
        if best_i < 0:
            continue
        # refine between the neighbouring samples: nearest point of the two sample chords
        fbest = float(best_i)
        px = q[best_i, 0]
        py = q[best_i, 1]
        pz = q[best_i, 2]
        for side in (-1, 1):
            o = best_i + side
            if o < 0 or o >= n:
                continue
            c0 = q[o, 0] - q[best_i, 0]
            c1 = q[o, 1] - q[best_i, 1]
            c2 = q[o, 2] - q[best_i, 2]
            cc = c0 * c0 + c1 * c1 + c2 * c2
            if cc <= 0.0:
                continue
            w = ((b[j, 0] - q[best_i, 0]) * c0 + (b[j, 1] - q[best_i, 1]) * c1 + (b[j, 2] - q[best_i, 2]) * c2) / cc
            if w <= 0.0:
                continue
            if w > 1.0:
                w = 1.0
            x = q[best_i, 0] + w * c0
            y = q[best_i, 1] + w * c1
            z = q[best_i, 2] + w * c2
            dd = np.sqrt((b[j, 0] - x) ** 2 + (b[j, 1] - y) ** 2 + (b[j, 2] - z) ** 2)
            if dd < best:
                best = dd
                px = x
                py = y
                pz = z
                fbest = best_i + side * w
        e[j, 0] = b[j, 0] - px
        e[j, 1] = b[j, 1] - py
        e[j, 2] = b[j, 2] - pz
        frac[j] = fbest


def command_end_tangents(path: Any) -> NDArray[np.float64]:
    """Unit tangent of the original path at the end point of every command, (K, 3).

    Seed 000's Frenet tangent ``T = ṙ/‖ṙ‖`` (eq. 3) of the *desired*
    reference at the instant it reaches command k's end: the direction of
    the command's move at its end, and at a vertex joined to the next active
    move the normalised sum of the two unit directions (what the central
    difference of the reference samples either side of the vertex gives at
    a constant feed: the bisector at a sharp corner). A zero-length command
    gets 0 (:func:`ilcnc.contour.estimates.tangent_error` then uses the nearest
    defined tangent).

    Parameters
    ----------
    path : PathGeometry
        The original programmed path.

    Returns
    -------
    ndarray (K, 3)
    """
    mk = np.asarray(path.move_of_command, dtype=np.int64)
    if mk.size == 0:
        return np.zeros((0, 3))
    m = len(path)
    t_end = path.tangent_at(mk, np.ones(mk.size))
    nxt = np.minimum(mk + 1, m - 1)
    joined = ((mk + 1 < m) & np.asarray(path.active, bool)[nxt]
              & np.all(np.abs(path.start_mm[nxt] - path.end_mm[mk]) <= 1e-9, axis=1))
    t_next = path.tangent_at(nxt, np.zeros(mk.size))
    t = np.where(joined[:, None], t_end + t_next, t_end)
    norm = np.linalg.norm(t, axis=1)
    # a reversal (t_end = -t_next) has no bisector: keep the direction of the command's own move
    t = np.where((norm > 1e-9)[:, None], t, t_end)
    norm = np.linalg.norm(t, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm[:, None] > 1e-12, t / norm[:, None], 0.0)


def reference_command_samples(ref_move: NDArray[np.integer], command_moves: NDArray[np.int64]) -> NDArray[np.float64]:
    """Sample at which the reference reaches the end of each command's move (NaN if never).

    The last sample whose reference is on the command's move (the planner
    marks the sample that lands on a move's end point with that move).
    """
    mv = np.asarray(ref_move, dtype=np.int64)
    # the reference's move index never decreases; -1 before the first move
    last = np.searchsorted(mv, command_moves, side="right") - 1
    ok = (last >= 0) & (mv[np.clip(last, 0, max(mv.size - 1, 0))] == command_moves) if mv.size else np.zeros(0, bool)
    return np.where(ok, last, np.nan).astype(np.float64)



def error_kind(profile: MachineProfile, *, refined: bool = False) -> str:
    """The error estimate the profile asks for (``auto`` resolved by the law; for the ``p`` law on a refined
    program ``lifted``: its corners are what the refinement is for, and ``path`` dilutes them)."""
    k = profile.learning.error
    if k != "auto":
        return k
    if refined and profile.learning.law == "p":
        return "lifted"
    return DEFAULT_ERROR[profile.learning.law]



def measurement_gate_mm(profile: MachineProfile) -> float:
    """Largest error that counts as a measurement of a command: 4 correction bounds, at least 2 mm."""
    return max(2.0, 4.0 * profile.learning.correction_bound_mm)


def signal_of_simulation(sim: Any, original: Program, kind: str, gate_mm: float | None = None, *,
                         profile: MachineProfile | None = None, free: NDArray[np.bool_] | None = None
                         ) -> CommandSignal:
    """``E(k)`` of a virtual-CNC run against the original drawing (``profile`` and ``free``: for ``lifted``, see
    :func:`command_signal_from_run`)."""
    ref = sim.reference
    path = sim.error.path
    cs = None
    if kind == "surface":
        if getattr(sim, "surface", None) is None:
            raise ValueError("error estimate 'surface' needs the cutting error model (cutting.model mechanistic)")
        e, ok = sim.surface
        cs = reference_command_samples(ref.move, original.command_moves)
        return finish_signal(np.where(ok[:, None], e, np.nan), np.asarray(cs, dtype=np.float64) * ref.period_s,
                             "surface")
    if kind not in ("crossing", "path"):
        cs = reference_command_samples(ref.move, original.command_moves)
    # uniform samples from t = 0: the period stands for the N-long time array (only ``crossing`` needs it)
    t_s = ref.t_s if kind == "crossing" else ref.period_s
    return command_signal_from_run(kind, path=path, err=sim.error, actual_mm=sim.actual_mm, t_s=t_s,
                                   command_sample=cs, ref_mm=ref.pos_mm, gate_mm=gate_mm, sample_move=ref.move,
                                   on_feed=sim.feed_mask, program=original, profile=profile, free=free)



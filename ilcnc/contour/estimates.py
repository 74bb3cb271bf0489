"""Error estimates other than the exact search: seed 000's Frenet-frame estimate, ``E(k)`` at the end points.

* :func:`tangent_error` -- seed 000's Frenet-frame estimate: the component of the tracking error ``r - q``
  normal to the reference tangent at ``r``.
* :func:`per_command_error` -- the error vector ``E(k)`` at the instant the machine passes the end point of G01
  command ``k`` (the learning index of seed 004), found from where the foot parameter ``u`` of the exact
  search (:func:`ilcnc.contour.search.contour_error`) crosses the end of the command's move.
* :func:`summary` -- max / mean / RMS and the worst sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ilcnc.contour.path import PathGeometry
from ilcnc.contour.search import ContourError
from ilcnc.program.model import MOVE_RAPID

__all__ = ["CommandError", "per_command_error", "sample_command", "summary", "tangent_error"]


# ---------------------------------------------------------------------------------------------
# Frenet / tangent estimate (seed 000)
# ---------------------------------------------------------------------------------------------


def tangent_error(
    ref_mm: ArrayLike, actual_mm: ArrayLike, *, tangent: ArrayLike | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Seed 000's contour error estimate: the part of ``r - q`` normal to the reference tangent at ``r``.

    ``e = (r - q) - ((r - q) . T) T`` with ``T`` the unit tangent of the
    reference at the reference sample (the ``[0, e_n, e_b]`` components of
    seed 000's eq. (6) expressed in world axes; their split between N and B
    does not change the vector). ``T`` is the central difference of the
    reference samples unless given; where the reference stands still the
    nearest defined tangent is used.

    Returns
    -------
    vector_mm : (N, 3)
        Estimated error vector, pointing from the actual towards the tangent line.
    norm_mm : (N,)
        Its length.
    """
    r = np.asarray(ref_mm, dtype=np.float64)
    q = np.asarray(actual_mm, dtype=np.float64)
    if r.shape != q.shape or r.ndim != 2:
        raise ValueError("ref_mm and actual_mm must both be (N, 2) or (N, 3)")
    e = r - q
    n = r.shape[0]
    if tangent is None:
        t = np.gradient(r, axis=0) if n > 1 else np.zeros_like(r)
    else:
        t = np.array(tangent, dtype=np.float64).reshape(r.shape)
    norm = np.sqrt(np.einsum("ij,ij->i", t, t))
    ok = norm > 1e-12 * max(1.0, float(np.nanmax(np.abs(r))) if n else 1.0)
    if not ok.all() and ok.any():
        i = np.arange(n)
        prev = np.maximum.accumulate(np.where(ok, i, -1))
        nxt = np.minimum.accumulate(np.where(ok, i, n)[::-1])[::-1]
        use = np.where(prev >= 0, prev, nxt)
        use = np.where((nxt < n) & (prev >= 0) & (nxt - i < i - prev), nxt, use)
        t = t[use]
        norm = norm[use]
        ok = ok[use]
    tu = np.where(ok[:, None], t / np.where(ok, norm, 1.0)[:, None], 0.0)
    vec = e - np.einsum("ij,ij->i", e, tu)[:, None] * tu
    return vec, np.sqrt(np.einsum("ij,ij->i", vec, vec))


# ---------------------------------------------------------------------------------------------
# Per-command error E(k)
# ---------------------------------------------------------------------------------------------


@dataclass(slots=True, eq=False)
class CommandError:
    """Error at the instant the machine passes each G01 command's end point.

    Attributes
    ----------
    e_mm : float64 (K, 3)
        ``E(k) = end point of command k - actual position`` at the crossing, mm (NaN if not reached).
    sample : float64 (K,)
        Fractional sample index of the crossing (NaN if not reached).
    time_s : float64 (K,) or None
        Time of the crossing, when sample times were given.
    reached : bool (K,)
        The foot parameter reached the end of the command's move.
    move : int64 (K,)
        Move index ``m_k`` of each command.
    line : int32 (K,)
        Source line of each command.
    """

    e_mm: NDArray[np.float64]
    sample: NDArray[np.float64]
    time_s: NDArray[np.float64] | None
    reached: NDArray[np.bool_]
    move: NDArray[np.int64]
    line: NDArray[np.int32]

    @property
    def norm_mm(self) -> NDArray[np.float64]:
        """``|E(k)|``, mm."""
        return np.sqrt(np.einsum("ij,ij->i", self.e_mm, self.e_mm))


def per_command_error(
    path: PathGeometry,
    err: ContourError,
    actual_mm: ArrayLike,
    *,
    t_s: ArrayLike | None = None,
) -> CommandError:
    """``E(k)``: the error vector when the machine passes the end point of G01 command k.

    For command k on move ``m_k`` the crossing is the first sample pair
    ``i - 1, i`` with ``u[i - 1] < m_k + 1 <= u[i]``, on the running maximum of
    the foot parameter (the furthest the machine has got along the path, so
    noise that moves the foot back and forth does not make extra crossings).
    The actual position is interpolated linearly between the two samples at
    the fraction where ``u`` reaches ``m_k + 1``, and ``E(k)`` is the command's
    end point minus that position. When the actual path cuts the corner, the
    foot jumps from before the vertex to after it between two samples; that is
    a crossing like any other (the foot of the crossing is the vertex).
    Commands whose end is never reached (the log stops earlier, or the first
    sample is already past them) are NaN with ``reached = False``.
    """
    q = np.asarray(actual_mm, dtype=np.float64)
    if q.shape[1] == 2:
        q = np.column_stack([q, np.zeros(q.shape[0])])
    mk = path.move_of_command
    kk = mk.size
    target = mk.astype(np.float64) + 1.0
    u = np.where(np.isfinite(err.u), err.u, -np.inf)
    n = u.shape[0]
    e = np.full((kk, 3), np.nan)
    sample = np.full(kk, np.nan)
    reached = np.zeros(kk, bool)
    if n and kk:
        umax = np.maximum.accumulate(u)
        i = np.searchsorted(umax, target, side="left")
        tol = 1e-12 * np.maximum(1.0, np.abs(target))
        first_ok = (i == 0) & (n > 0) & (np.abs(u[0] - target) <= tol)
        ok = ((i > 0) & (i < n)) | first_ok
        ii = np.clip(i, 1, max(n - 1, 1))
        ua, ub = u[np.clip(ii - 1, 0, n - 1)], u[np.minimum(ii, n - 1)]
        with np.errstate(invalid="ignore", divide="ignore"):
            alpha = np.where(np.isfinite(ua) & (ub > ua), (target - ua) / (ub - ua), 1.0)
        alpha = np.clip(alpha, 0.0, 1.0)
        alpha = np.where(first_ok, 0.0, alpha)
        ia = np.where(first_ok, 0, np.clip(ii - 1, 0, n - 1))
        ib = np.where(first_ok, 0, np.minimum(ii, n - 1))
        pos = q[ia] + alpha[:, None] * (q[ib] - q[ia])
        end = path.end_mm[mk]
        e[ok] = (end - pos)[ok]
        sample[ok] = (ia + alpha)[ok]
        reached = ok
    time = None
    if t_s is not None:
        ts = np.asarray(t_s, dtype=np.float64)
        time = np.full(kk, np.nan)
        if reached.any():
            time[reached] = np.interp(sample[reached], np.arange(ts.size), ts)
    return CommandError(e_mm=e, sample=sample, time_s=time, reached=reached, move=mk, line=path.line[mk])


def sample_command(err: ContourError) -> NDArray[np.int64]:
    """Command index k of each sample: that of the move its foot is on (-1: not a G01 command, or no foot)."""
    k = err.path.command[np.clip(err.seg, 0, len(err.path) - 1)].astype(np.int64)
    k[err.seg < 0] = -1
    return k


# ---------------------------------------------------------------------------------------------
# Summary
# ---------------------------------------------------------------------------------------------


def summary(err: ContourError, mask: ArrayLike | None = None) -> dict:
    """Max / mean / RMS of the contour error over feed moves, and the worst sample.

    By default the samples counted are those with a foot on a feed move whose
    hint (the reference) is also on a feed move -- samples taken while the
    reference is in a rapid are left out. ``mask`` (N,) bool restricts further.

    Returns
    -------
    dict
        ``max``, ``mean``, ``rms`` (mm), ``n`` (samples counted), ``worst_index``
        (sample), ``worst_move``, ``worst_command`` (k of the foot's move, -1 if
        that move is not a G01 command), ``worst_line``. With no sample counted
        the statistics are NaN and the indices -1.
    """
    path = err.path
    d = err.dist_mm
    ok = np.isfinite(d) & (err.seg >= 0)
    feed = path.kind != MOVE_RAPID
    ok &= feed[np.clip(err.seg, 0, len(path) - 1)] & feed[err.hint]
    if mask is not None:
        ok &= np.asarray(mask, bool)
    sel = d[ok]
    if sel.size == 0:
        nan = float("nan")
        return {"max": nan, "mean": nan, "rms": nan, "n": 0, "worst_index": -1, "worst_move": -1,
                "worst_command": -1, "worst_line": -1}
    idx = np.flatnonzero(ok)
    w = int(idx[int(np.argmax(sel))])
    mv = int(err.seg[w])
    return {
        "max": float(sel.max()),
        "mean": float(sel.mean()),
        "rms": float(np.sqrt(np.mean(sel * sel))),
        "n": int(sel.size),
        "worst_index": w,
        "worst_move": mv,
        "worst_command": int(path.command[mv]),
        "worst_line": int(path.line[mv]),
    }

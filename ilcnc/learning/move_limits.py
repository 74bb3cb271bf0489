"""How far a correction may change a straight feed's own move: kept forward, and repeated points moved together.

A correction ``U_k`` moves the end point of command ``k``; the move itself changes by ``U_k − U_prev`` (its
start is the previous command's end). :func:`keep_moves_forward` keeps every move going the way the program
sends it; :func:`tie_repeated_points` gives a point a program repeats (a zero-length block, as jscut writes
before each retract) one correction for all its copies, so the corner it stands at can be shaped at all.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ilcnc.program.model import Program

__all__ = ["ZERO_LENGTH_MM", "keep_moves_forward", "repeated_points", "start_corrections", "tie_repeated_points"]

#: A move this short (mm) is a repeated point: below any machine's resolution.
ZERO_LENGTH_MM = 1e-6


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
    zero = length <= ZERO_LENGTH_MM
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



def repeated_points(vec_mm: NDArray[np.float64], prev_k: NDArray[np.int64],
                    timed: NDArray[np.bool_] | None = None) -> NDArray[np.int64]:
    """For each command, the first command of the run of zero-length moves it repeats (itself if none).

    A zero-length move (shorter than :data:`ZERO_LENGTH_MM`, speed-fed) whose start is the previous command's
    end repeats that command's point; a chain of them repeats the first.
    """
    k = vec_mm.shape[0]
    root = np.arange(k, dtype=np.int64)
    zero = (np.linalg.norm(vec_mm, axis=1) <= ZERO_LENGTH_MM) & (prev_k >= 0)
    if timed is not None:
        zero &= ~timed
    for i in np.flatnonzero(zero):  # in program order: a chain's root is already known
        root[i] = root[prev_k[i]]
    return root


def tie_repeated_points(du: NDArray[np.float64], root: NDArray[np.int64],
                        free: NDArray[np.bool_]) -> NDArray[np.float64]:
    """One update for every copy of a repeated point: per axis, the largest of its copies' updates.

    The error at a point a program repeats is estimated at one of its copies or shared between them, depending
    on the estimate and on when the motion passes each (jsdc: 3.3 µm at the zero-length block before a retract,
    0 at the move that reaches the corner). Moving the copies apart would make the zero-length move a move
    (:func:`keep_moves_forward` takes it back, a ``move length`` clip), so each copy takes the update of the
    copy whose error says most, axis by axis: the larger one, not the sum, so a point whose error every copy
    sees is not corrected twice as fast.

    Parameters
    ----------
    du : ndarray (K, 3)
        The law's update per command, mm.
    root : ndarray (K,)
        :func:`repeated_points`.
    free : ndarray (K, 3) bool
        The coordinates that may move: one that may not is left as it is and takes no part in the choice.

    Returns
    -------
    ndarray (K, 3)
        The update with every repeated point's copies equal where they may move, mm.
    """
    tied = np.flatnonzero(root != np.arange(root.size))
    if tied.size == 0:
        return du
    out = du.copy()
    groups = np.unique(root[tied])
    members = np.concatenate((groups, tied))
    keys = root[members]
    cand = np.where(free[members], du[members], 0.0)
    best = np.zeros((groups.size, 3))
    g_of = np.searchsorted(groups, keys)
    for m, g in enumerate(g_of):  # few repeated points in a program: a loop is clearer than a segmented argmax
        bigger = np.abs(cand[m]) > np.abs(best[g])
        best[g] = np.where(bigger, cand[m], best[g])
    out[members] = np.where(free[members], best[g_of], du[members])
    return out

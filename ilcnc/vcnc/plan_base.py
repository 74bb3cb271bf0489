"""What both trajectory planners share: the axes' limits, the moves' tangents and their capped speeds.

:mod:`ilcnc.vcnc.plan` (ilcnc's own jerk-limited planner) and
:mod:`ilcnc.vcnc.plan_tp` (LinuxCNC's trapezoidal planner) plan the same move
table under the same :class:`PlanLimits`; both start from each move's unit
tangent at its ends (:func:`move_directions`: lines, arcs and helices) and
its programmed feed capped by the axes' velocity limits
(:func:`nominal_speed_mm_s`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import InputError
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.geometry import arc_sweep_rad, move_lengths_mm
from ilcnc.program.model import MOVE_ARC_CW, MOVE_RAPID, PLANE_AXES, MoveTable

__all__ = ["EPS_MM", "MAX_RUN_SAMPLES", "PlanLimits", "check_run_length", "dwell_samples", "move_directions",
           "nominal_samples", "nominal_speed_mm_s"]

#: Lengths below this are zero, mm.
EPS_MM = 1e-9


@dataclass(frozen=True, slots=True)
class PlanLimits:
    """Per-axis kinematic limits in mm and s (arrays of 3; inf for an axis without limits)."""

    velocity_mm_s: NDArray[np.float64]
    rapid_mm_s: NDArray[np.float64]
    acceleration_mm_s2: NDArray[np.float64]
    jerk_mm_s3: NDArray[np.float64]

    @classmethod
    def from_profile(cls, profile: MachineProfile) -> PlanLimits:
        v = np.full(3, np.inf)
        r = np.full(3, np.inf)
        a = np.full(3, np.inf)
        j = np.full(3, np.inf)
        for i, name in enumerate("xyz"):
            ax = profile.axes.get(name)
            if ax is None:
                continue
            v[i] = ax.max_velocity_mm_s
            r[i] = ax.rapid_mm_s
            a[i] = ax.max_acceleration_mm_s2
            j[i] = ax.max_jerk_mm_s3
        return cls(v, r, a, j)


def move_directions(moves: MoveTable) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unit tangent at the start and at the end of every move."""
    d = moves.end_mm - moves.start_mm
    n = np.linalg.norm(d, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = d / n[:, None]
    u = np.nan_to_num(u)
    t_start = u.copy()
    t_end = u.copy()
    is_arc = moves.kind >= MOVE_ARC_CW
    if is_arc.any():
        sweep = arc_sweep_rad(moves)
        for plane, (a1, a2, lin) in PLANE_AXES.items():
            sel = np.flatnonzero(is_arc & (moves.plane == plane))
            if sel.size == 0:
                continue
            c = moves.center_mm[sel]
            s = moves.start_mm[sel]
            e = moves.end_mm[sel]
            sign = np.where(moves.kind[sel] == MOVE_ARC_CW, -1.0, 1.0)
            r = np.hypot(s[:, a1] - c[:, a1], s[:, a2] - c[:, a2])
            arc_len = r * sweep[sel]
            dz = e[:, lin] - s[:, lin]
            for tvec, p in ((t_start, s), (t_end, e)):
                rx, ry = p[:, a1] - c[:, a1], p[:, a2] - c[:, a2]
                tx, ty = -ry * sign, rx * sign  # CCW tangent is (-ry, rx)
                norm = np.hypot(arc_len, dz)
                with np.errstate(invalid="ignore", divide="ignore"):
                    k = np.where(norm > 0, arc_len / norm, 1.0) / np.maximum(r, EPS_MM)
                    lz = np.where(norm > 0, dz / norm, 0.0)
                tvec[sel, a1] = tx * k
                tvec[sel, a2] = ty * k
                tvec[sel, lin] = lz
    return t_start, t_end


def nominal_speed_mm_s(moves: MoveTable, length: NDArray[np.float64], limits: PlanLimits) -> NDArray[np.float64]:
    """Programmed speed of every move, capped so no axis exceeds its velocity limit (mm/s)."""
    d = np.abs(moves.end_mm - moves.start_mm)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(length[:, None] > EPS_MM, d / length[:, None], 0.0)
    rapid = moves.kind == MOVE_RAPID
    vmax_axis = np.where(rapid[:, None], limits.rapid_mm_s[None, :], limits.velocity_mm_s[None, :])
    with np.errstate(divide="ignore", invalid="ignore"):
        cap = np.min(np.where(u > 1e-12, vmax_axis / np.maximum(u, 1e-300), np.inf), axis=1)
    is_arc = moves.kind >= MOVE_ARC_CW
    # an arc sweeps through every direction of its plane: cap by the slowest axis of the plane
    if is_arc.any():
        for plane, (a1, a2, _lin) in PLANE_AXES.items():
            sel = is_arc & (moves.plane == plane)
            cap[sel] = np.minimum(cap[sel], min(limits.velocity_mm_s[a1], limits.velocity_mm_s[a2]))
    feed = np.where(rapid, np.inf, moves.feed_mm_min / 60.0)
    feed = np.where(np.isfinite(feed) & (feed > 0) | rapid, feed, cap)
    v = np.minimum(feed, cap)
    v = np.where(np.isfinite(v), v, np.nanmin(np.where(np.isfinite(limits.velocity_mm_s), limits.velocity_mm_s, 1e3)))
    return np.maximum(v, 1e-6)


#: Most servo periods a virtual-CNC run may take (11.6 days at 1 ms; stellabee1, 169k lines, takes 27 M): a
#: program beyond it is refused before planning, not planned for days (a coordinate typed 999999999).
MAX_RUN_SAMPLES = 1e9


def _nominal_move_times(moves: MoveTable, profile: MachineProfile) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each move's length (mm) and its time at the programmed feed capped by the axes' velocities plus the dwell
    before it (s)."""
    length = move_lengths_mm(moves)
    return length, length / nominal_speed_mm_s(moves, length, PlanLimits.from_profile(profile)) + moves.dwell_s


def nominal_samples(moves: MoveTable, profile: MachineProfile) -> int:
    """Servo periods the moves take at least (:func:`check_run_length`'s bound): the size of a run before it is
    planned, which decides whether its kernels are worth compiling (:func:`ilcnc._jit.kernels_for`)."""
    if len(moves) == 0:
        return 0
    total_s = float(np.sum(_nominal_move_times(moves, profile)[1]))
    return int(min(total_s / profile.machine.servo_period_s, MAX_RUN_SAMPLES)) if math.isfinite(total_s) else int(
        MAX_RUN_SAMPLES)


def check_run_length(program: object, moves: MoveTable, profile: MachineProfile) -> None:
    """Refuse a program whose motion alone takes more than :data:`MAX_RUN_SAMPLES` servo periods.

    The bound is each move's length over its programmed feed capped by the axes' velocities
    (:func:`nominal_speed_mm_s`) and its dwell (``moves.dwell_s``; the program's ``trailing_dwell_s``),
    summed: the planner can only take longer. The error names the longest move's line.
    """
    if len(moves) == 0:
        return
    length, t = _nominal_move_times(moves, profile)
    trailing = float(getattr(program, "trailing_dwell_s", 0.0))
    total_s = float(np.sum(t)) + trailing
    period = profile.machine.servo_period_s
    if not total_s / period > MAX_RUN_SAMPLES:
        return
    i = int(np.argmax(t))
    what = (f"a dwell of {trailing / 3600:,.1f} h follows the last move, here" if trailing > t[i] else
            f"the longest move is here: {length[i]:,.0f} mm in {t[i] / 3600:,.1f} h"
            + (f" with the dwell before it ({moves.dwell_s[i] / 3600:,.1f} h)" if moves.dwell_s[i] > 0 else ""))
    raise InputError(getattr(program, "path", None), int(moves.line[-1] if trailing > t[i] else moves.line[i]),
                     f"the program's motion takes at least {total_s / 3600:,.0f} h at the profile's feeds"
                     f" ({total_s / period:.3g} servo periods, more than the {MAX_RUN_SAMPLES:.0e} a virtual run takes);"
                     f" {what}")


def dwell_samples(seconds: NDArray[np.float64] | float, period_s: float) -> NDArray[np.int64] | int:
    """Servo periods a dwell of ``seconds`` (s, >= 0; scalar or array) stands still: ``round(seconds / period_s)``,
    halves up (a dwell shorter than half a period is none)."""
    n = np.floor(np.asarray(seconds, dtype=np.float64) / period_s + 0.5).astype(np.int64)
    return int(n) if n.ndim == 0 else n

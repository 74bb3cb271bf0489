"""Receding-horizon gain schedule of one axis (seed 001): its design on the program.

``schedule`` -- the receding-horizon offline gain adjustment of seed 001 (:func:`schedule_gains`)
    A per-servo-period position gain ``K_p`` of one axis, chosen at every
    instant among ``K_{k−1} + ΔK`` by the cost ``J = ε̂ᵀε̂ + λ ΔK²`` (ε̂ in µm) of the
    contour error predicted over ``Np`` samples (eqs. 3-5) with the nonlinear
    (friction) axis model, kept in the stable range (eqs. 6-7) and within the
    kinematic limits (eqs. 8-10, with eq. 10's division by ``E_Z`` guarded). Np, λ, the ΔK
    candidates, the gain range and the axis come from the profile's ``tuning.schedule`` (seed 001's
    values by default).

The schedule file is read back by :mod:`ilcnc.vcnc.schedule`. Nothing here prints.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ilcnc.profile.sections import MachineProfile, PFfFrictionDrive
from ilcnc.units import AXIS_NAMES

__all__ = ["DEFAULT_DK", "ScheduleResult", "schedule_gains", "seed001_standin_program"]


# ---------------------------------------------------------------------------------------------
# Receding-horizon gain schedule (seed 001)
# ---------------------------------------------------------------------------------------------

#: (m/min)/mm → 1/s.
_KP_TO_1_S = 1000.0 / 60.0
#: Kinematic check modes of the schedule kernel.
_KIN_MODES = {"none": 0, "predicted": 1, "eq10": 2}
#: Seed 001's gain increments ΔK per period, (m/min)/mm: -0.05 to 0.05 in steps of 0.01 (the default of the
#: profile key ``tuning.schedule.dk_candidates``).
DEFAULT_DK = np.round(np.arange(-0.05, 0.051, 0.01), 12)
#: λ of J = ε̂ᵀε̂ + λ ΔK² is given with ε̂ in µm (seed 001 prints its contour errors in µm, and only then is its
#: λ = 0.01 "the same MSE" as λ = 0, Fig. 7.c); the kernel sums ε̂ in mm, so λ is scaled by 1 µm² / 1 mm².
_LAM_MM2_PER_UM2 = 1e-6
#: Reference segments searched on either side of the hint for the predicted contour error.
_SCHEDULE_SEARCH = 20


def _bump(u: NDArray[np.float64]) -> NDArray[np.float64]:
    """``b(u) = 64 u³ (1 − u)³`` on 0 <= u <= 1, 0 elsewhere (peak 1 at u = 0.5)."""
    return np.where((u >= 0.0) & (u <= 1.0), 64.0 * u**3 * (1.0 - u) ** 3, 0.0)


def seed001_standin_program(*, step_mm: float = 0.5, feed_mm_min: float = 3000.0, x_end_mm: float = 135.0) -> str:
    """The stand-in X-Z test path of seed 001 (its Fig. 6 path is not published) as a G01 program.

    ``z = 2·b((x − 20)/60) − b((x − 90)/30)`` with ``b(u) = 64u³(1 − u)³`` on
    ``0 <= u <= 1`` (0 elsewhere): a 2 mm bump on x 20..80 and a 1 mm dip on
    x 90..120, x from 0 to ``x_end_mm`` in G01 steps of ``step_mm`` at ``feed_mm_min``.

    Returns
    -------
    str
        LinuxCNC/ISO G-code (G21 G90 G18, 4 decimals).
    """
    if step_mm <= 0 or x_end_mm <= 0:
        raise ValueError("step_mm and x_end_mm must be > 0")
    n = round(x_end_mm / step_mm)
    x = np.linspace(0.0, x_end_mm, n + 1)
    z = 2.0 * _bump((x - 20.0) / 60.0) - _bump((x - 90.0) / 30.0)
    lines = ["(ilcnc stand-in of seed 001: z = 2 b[u1] - b[u2], u1 = [x - 20]/60, u2 = [x - 90]/30, b = 64 u^3 [1 - u]^3)",
             "G21 G90 G18", "G0 X0.0000 Z0.0000"]
    lines.append(f"G1 X{x[1]:.4f} Z{z[1]:.4f} F{feed_mm_min:g}")
    lines += [f"G1 X{a:.4f} Z{b:.4f}" for a, b in zip(x[2:], z[2:], strict=True)]
    lines.append("M2")
    return "\n".join(lines) + "\n"


def _schedule_plant_arrays(drive: PFfFrictionDrive, period_s: float) -> dict[str, Any]:
    """Sub-step matrices of the friction loop (:func:`ilcnc.vcnc.drive_loop.friction_steps`), also without friction."""
    from ilcnc.vcnc.discrete import FRICTION_SUBSTEP_S, pff_plant, zoh_discretize
    from ilcnc.vcnc.drive_loop import stuck_system

    p = pff_plant(drive)
    nsub = max(1, math.ceil(period_s / FRICTION_SUBSTEP_S - 1e-9))
    bf = p.bf if p.bf is not None else np.zeros(p.n)
    phih, gh = zoh_discretize(p.a, np.column_stack([p.bu, bf]), period_s / nsub)
    cv = p.cv if p.cv is not None else np.eye(p.n)[1]
    phis, gus = zoh_discretize(*stuck_system(p.a, p.bu, cv), period_s / nsub)
    return {"cq": np.ascontiguousarray(p.c, dtype=np.float64), "kff": float(p.kff), "nsub": int(nsub),
            "phih": np.ascontiguousarray(phih), "guh": np.ascontiguousarray(gh[:, 0]),
            "gfh": np.ascontiguousarray(gh[:, 1]), "cv": np.ascontiguousarray(cv, dtype=np.float64),
            "bstick": float(cv @ gh[:, 1]), "fc": float(p.coulomb_n), "fbreak": float(p.breakaway_n),
            "vs": float(p.stribeck_mm_s), "phis": np.ascontiguousarray(phis), "gus": np.ascontiguousarray(gus)}


def _seg_dist_py(p, pa, pb, h, w):  # pragma: no cover - compiled (its Python twin runs without numba)
    """Distance of point ``p`` (3,) to the nearest of the segments ``h − w .. h + w`` of ``pa → pb``."""
    m = pa.shape[0]
    best = 1e300
    lo = h - w if h - w > 0 else 0
    hi = h + w + 1 if h + w + 1 < m else m
    for s in range(lo, hi):
        d0 = pb[s, 0] - pa[s, 0]
        d1 = pb[s, 1] - pa[s, 1]
        d2 = pb[s, 2] - pa[s, 2]
        l2 = d0 * d0 + d1 * d1 + d2 * d2
        t = 0.0
        if l2 > 0.0:
            t = ((p[0] - pa[s, 0]) * d0 + (p[1] - pa[s, 1]) * d1 + (p[2] - pa[s, 2]) * d2) / l2
            t = min(max(t, 0.0), 1.0)
        f0 = pa[s, 0] + t * d0 - p[0]
        f1 = pa[s, 1] + t * d1 - p[1]
        f2 = pa[s, 2] + t * d2 - p[2]
        dd = f0 * f0 + f1 * f1 + f2 * f2
        if dd < best:
            best = dd
    return math.sqrt(best)


def _schedule_kernel_py(dev, vref, r0, other, ai, pa, pb, hint, w, k0, kmin, kmax, dks, lam, npred, period,
                        vmax, amax, jmax, mode, cq, kff, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus,
                        seg_dist, steps):  # pragma: no cover - compiled; its Python twin is what runs without numba
    """Receding-horizon choice of the position gain of one axis, period by period (seed 001 §3.6).

    At every period k, for every candidate ``K = K_{k−1} + ΔK`` inside ``[kmin, kmax]``
    (eq. 6-7), the axis is simulated from its current state for ``npred`` periods
    with ``K`` held, the contour error of the predicted positions (the other axes
    at their own actual positions) to the reference polyline is summed squared and
    ``lam·ΔK²`` is added (eq. 3-5); the kinematic check (``mode``: 0 none,
    1 the predicted actual displacement of the axis, 2 eq. 10 with the velocity
    loop taken as 1 and the division by ``E`` guarded) removes candidates, and
    when it removes all, the least violating one is taken. The best ``K`` is
    applied for one period. Gains in (m/min)/mm.

    The cost is eq. 5, ``J = ε̂ᵀε̂ + λ·ΔK²``: ε̂ holds the Np contour errors (eq. 1) of the positions the
    candidate gain produces, ``P̂(k+1) .. P̂(k+Np)`` (the position at k is already fixed when ``K_k`` is
    chosen, so it adds the same to every candidate), and the caller passes ``lam`` scaled to ε̂ in mm.
    """
    n = dev.shape[0]
    ns = cq.shape[0]
    conv = 1000.0 / 60.0
    x = np.zeros(ns)
    xn = np.zeros(ns)
    xs = np.zeros(ns)
    kout = np.empty(n)
    qout = np.empty(n)
    pt = np.empty(3)
    kprev = k0
    qprev = 0.0
    qprev2 = 0.0
    uprev = 0.0
    uprev2 = 0.0
    nc = dks.shape[0]
    n_limited = 0
    n_infeasible = 0
    n_guarded = 0
    for k in range(n):
        q = 0.0
        for i in range(ns):
            q += cq[i] * x[i]
        qout[k] = q
        ez = dev[k] - q
        d1 = q - qprev if k > 0 else 0.0
        d2 = qprev - qprev2 if k > 1 else 0.0
        if mode == 2:
            # eq. 9 takes the velocity loop as 1, so the stored displacements of eq. 8 are the commanded ones
            # (u·T of the last two periods): eq. 10 then bounds the velocity command consistently
            d1 = uprev * period if k > 0 else 0.0
            d2 = uprev2 * period if k > 1 else 0.0
        # eq. 8: bounds of the next displacement from the limits and the stored displacements
        lo = max(-vmax * period, d1 - amax * period * period, 2.0 * d1 - d2 - jmax * period**3)
        hi = min(vmax * period, d1 + amax * period * period, 2.0 * d1 - d2 + jmax * period**3)
        guarded = False
        if mode == 2 and abs(ez) * conv * 0.05 < 1e-12:
            guarded = True  # eq. 10 divides by E: the gain cannot move u, no bound from it
            n_guarded += 1
        best_cost = 1e300
        best_viol = 1e300
        best_k = kprev
        best_dk = 1e300
        any_ok = False
        excluded = False
        for c in range(nc):
            kc = kprev + dks[c]
            if kc < kmin - 1e-12 or kc > kmax + 1e-12:
                continue
            viol = 0.0
            if mode == 2 and not guarded:
                u = kff * vref[k] + kc * conv * ez
                ds = u * period
                if ds < lo:
                    viol = (lo - ds) / (jmax * period**3)
                elif ds > hi:
                    viol = (ds - hi) / (jmax * period**3)
            for i in range(ns):
                xs[i] = x[i]
            cost = lam * dks[c] * dks[c]
            for j in range(max(npred, 1)):
                kk = k + j
                if kk >= n:
                    break
                qq = 0.0
                for i in range(ns):
                    qq += cq[i] * xs[i]
                u = kff * vref[kk] + kc * conv * (dev[kk] - qq)
                steps(xs, xn, u, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus)
                qn = 0.0
                for i in range(ns):
                    qn += cq[i] * xs[i]
                if j == 0 and mode == 1:
                    ds = qn - q
                    ev = abs(ds) / period - vmax
                    ea = abs(ds - d1) / (period * period) - amax
                    ej = abs(ds - 2.0 * d1 + d2) / period**3 - jmax if k > 1 else -1.0
                    viol = max(0.0, ev / vmax, ea / amax, ej / jmax)
                if npred > 0 and kk + 1 < n:
                    pt[0] = other[kk + 1, 0]
                    pt[1] = other[kk + 1, 1]
                    pt[2] = other[kk + 1, 2]
                    pt[ai] = r0 + qn
                    e = seg_dist(pt, pa, pb, hint[kk + 1], w)
                    cost += e * e
            if viol > 0.0:
                excluded = True
            # equal costs (the gain cannot move the axis: at rest, or stuck in friction): the smallest |ΔK|
            tie = cost == best_cost and abs(dks[c]) < abs(best_dk)
            if viol == 0.0:
                if not any_ok or cost < best_cost or tie:
                    best_cost = cost
                    best_k = kc
                    best_dk = dks[c]
                any_ok = True
            elif not any_ok and (viol < best_viol or (viol == best_viol and (cost < best_cost or tie))):
                best_viol = viol
                best_cost = cost
                best_k = kc
                best_dk = dks[c]
        if excluded:
            n_limited += 1
        if not any_ok:
            n_infeasible += 1
        kout[k] = best_k
        kprev = best_k
        u = kff * vref[k] + best_k * conv * ez
        steps(x, xn, u, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus)
        qprev2 = qprev
        qprev = q
        uprev2 = uprev
        uprev = u
    return kout, qout, n_limited, n_infeasible, n_guarded


_SCHEDULE_KERNELS: dict[str, Any] = {}


def _schedule_kernel() -> tuple[Any, Any, Any]:
    """The compiled kernel, its distance function and the friction step of :mod:`ilcnc.vcnc.drives` (plain Python
    without numba). The loop is :mod:`ilcnc.vcnc.drives`'s own (its private sub-step and matrices), so with a
    constant gain it reproduces :func:`ilcnc.vcnc.drives.simulate_drives` to rounding."""
    from ilcnc._jit import njit
    from ilcnc.vcnc.drive_loop import friction_steps

    k = _SCHEDULE_KERNELS.get("kernel")
    if k is None:
        dist = njit(cache=True)(_seg_dist_py)
        kern = njit(cache=True)(_schedule_kernel_py)
        _SCHEDULE_KERNELS["kernel"] = k = (kern, dist, friction_steps)
    return k


@dataclass(frozen=True, eq=False)
class ScheduleResult:
    """Result of :func:`schedule_gains`.

    Attributes
    ----------
    axis : str
        The scheduled axis.
    t_s : ndarray (N,)
        Servo instants, s.
    kp : ndarray (N,)
        Position gain applied in each period, (m/min)/mm (C2).
    kp_fixed : float
        The fixed gain of the comparison run (C1), (m/min)/mm.
    mse_before_um2, mse_after_um2 : float
        Mean square contour error of C1 and C2 against the reference (the
        desired setpoint polyline, seed 001 eq. 1), µm².
    max_before_um, max_after_um : float
        Largest contour error, µm.
    mse_program_before_um2, mse_program_after_um2 : float
        The same against the programmed G01 path (includes the planner's own
        corner rounding, which no servo gain removes), µm².
    kinematics_before, kinematics_after : dict
        Largest |velocity| mm/s, |acceleration| m/s², |jerk| m/s³ of the actual
        scheduled axis, and its limits.
    limited, infeasible, guarded : int
        Periods where the kinematic check removed a candidate, removed every
        candidate (the least violating was taken), or (``eq10``) where the
        division by ``E`` was guarded.
    horizon, lam, dk, kp_range, kinematics :
        The settings (``lam`` with ε in µm and ΔK in (m/min)/mm).
    reference_mm, actual_before_mm, actual_after_mm : ndarray (N, 3)
        The runs.
    baseline_scan : tuple of (float, float, bool)
        With ``tuning.schedule.baseline_kp_m_min_mm``: every fixed gain tried for C1, its MSE (µm²) and
        whether every axis stayed within its V, A, J limits; C1 is the feasible one of least MSE. Empty
        when C1 is the drive's gain.
    within_limits_before, within_limits_after : bool
        Whether the actual motion of every axis stays within its V, A, J limits (C1, C2).
    elapsed_s : float
        Wall time of the optimisation, s.
    """

    axis: str
    t_s: NDArray[np.float64]
    kp: NDArray[np.float64]
    kp_fixed: float
    mse_before_um2: float
    mse_after_um2: float
    max_before_um: float
    max_after_um: float
    mse_program_before_um2: float
    mse_program_after_um2: float
    kinematics_before: dict[str, float]
    kinematics_after: dict[str, float]
    limited: int
    infeasible: int
    guarded: int
    horizon: int
    lam: float
    dk: NDArray[np.float64]
    kp_range: tuple[float, float]
    kinematics: str
    reference_mm: NDArray[np.float64] = field(repr=False)
    actual_before_mm: NDArray[np.float64] = field(repr=False)
    actual_after_mm: NDArray[np.float64] = field(repr=False)
    baseline_scan: tuple[tuple[float, float, bool], ...] = ()
    within_limits_before: bool = True
    within_limits_after: bool = True
    elapsed_s: float = 0.0

    @property
    def reduction(self) -> float:
        """Fractional cut of the contour-error MSE, ``1 − after/before``."""
        return 1.0 - self.mse_after_um2 / self.mse_before_um2 if self.mse_before_um2 > 0 else 0.0

    def csv_text(self) -> str:
        """The schedule as CSV ``t_s,kp`` (s, (m/min)/mm), one row per servo period."""
        rows = ["t_s,kp"] + [f"{t:.6f},{k:.6g}" for t, k in zip(self.t_s.tolist(), self.kp.tolist(), strict=True)]
        return "\n".join(rows) + "\n"

    def write_csv(self, path: str | Path, *, protect: Sequence[str | Path] = ()) -> Path:
        """Write :meth:`csv_text` atomically; returns the path."""
        from ilcnc.fileio import write_atomic

        return write_atomic(path, self.csv_text(), protect=tuple(protect))

    def to_json(self) -> dict[str, Any]:
        return {"method": "schedule",
                "axes": {self.axis: {"law": "schedule",
                                     "gains": {"kp_fixed": self.kp_fixed, "kp_min": float(self.kp.min()),
                                               "kp_max": float(self.kp.max()), "kp_mean": float(self.kp.mean())},
                                     "epsilon": None, "peak_hz": None, "converges": None}},
                "schedule": {"mse_before_um2": self.mse_before_um2, "mse_after_um2": self.mse_after_um2,
                             "reduction": self.reduction, "max_before_um": self.max_before_um,
                             "max_after_um": self.max_after_um,
                             "mse_program_before_um2": self.mse_program_before_um2,
                             "mse_program_after_um2": self.mse_program_after_um2,
                             "kinematics_before": self.kinematics_before, "kinematics_after": self.kinematics_after,
                             "limited": self.limited, "infeasible": self.infeasible, "guarded": self.guarded,
                             "horizon": self.horizon, "lam": self.lam, "dk": [float(x) for x in self.dk],
                             "kp_range": list(self.kp_range), "kinematics": self.kinematics,
                             "baseline_scan": [{"kp": k, "mse_um2": m, "within_limits": ok}
                                               for k, m, ok in self.baseline_scan],
                             "within_limits_before": self.within_limits_before,
                             "within_limits_after": self.within_limits_after,
                             "samples": int(self.t_s.size), "elapsed_s": self.elapsed_s}}


def _kinematics(pos: NDArray[np.float64], period: float, axis: Any) -> dict[str, float]:
    v = np.diff(pos) / period
    a = np.diff(v) / period
    j = np.diff(a) / period
    return {"velocity_mm_s": float(np.max(np.abs(v))) if v.size else 0.0,
            "acceleration_m_s2": float(np.max(np.abs(a))) / 1000.0 if a.size else 0.0,
            "jerk_m_s3": float(np.max(np.abs(j))) / 1000.0 if j.size else 0.0,
            "limit_velocity_mm_s": axis.max_velocity_mm_s, "limit_acceleration_m_s2": axis.max_acceleration_m_s2,
            "limit_jerk_m_s3": axis.max_jerk_m_s3}


def _within_limits(act: NDArray[np.float64], period: float, profile: MachineProfile) -> bool:
    """Every defined axis's actual |velocity|, |acceleration|, |jerk| within its limits (the planner's check,
    ``ilcnc.vcnc.plan.check_limits``, on the actual motion; 1e-9 relative for the float noise of differences)."""
    for i, name in enumerate(AXIS_NAMES):
        ax = profile.axes.get(name)
        if ax is None:
            continue
        k = _kinematics(act[:, i], period, ax)
        if (k["velocity_mm_s"] > ax.max_velocity_mm_s * (1 + 1e-9)
                or k["acceleration_m_s2"] > ax.max_acceleration_m_s2 * (1 + 1e-9)
                or k["jerk_m_s3"] > ax.max_jerk_m_s3 * (1 + 1e-9)):
            return False
    return True


def schedule_gains(program: Any, profile: MachineProfile, *, axis: str | None = None,
                   kp_range: tuple[float, float] | None = None, horizon: int | None = None, lam: float | None = None,
                   dk: ArrayLike | None = None, kp0: float | None = None,
                   kinematics: str | None = None) -> ScheduleResult:
    """Receding-horizon offline adjustment of a per-instant position gain of one axis (seed 001).

    Every setting left at ``None`` is taken from the profile's ``tuning.schedule`` section
    (:class:`ilcnc.profile.sections.ScheduleTuning`; seed 001's values by default: z, [1, 2.7], Np 50, λ 0.01,
    ΔK -0.05..0.05 step 0.01, ``predicted``).

    Parameters
    ----------
    program : Program
        The part program (planned with the profile's planner).
    profile : MachineProfile
        The machine; ``axis`` must have a ``p_ff_friction`` drive. The other
        axes run with their fixed gains.
    axis : str, optional
        The scheduled axis (``tuning.schedule.axis``; absent there: z, else the last axis).
    kp_range : (float, float), optional
        Gain range, (m/min)/mm (eq. 6: the stable range; seed 001's C2: [1, 2.7]).
    horizon : int, optional
        Np, servo periods (>= 1).
    lam : float, optional
        λ of ``J = ε̂ᵀε̂ + λ ΔK²`` (eq. 5) with ε̂ in µm and ΔK in (m/min)/mm (>= 0).
    dk : array_like, optional
        Candidate increments ΔK per period, (m/min)/mm. Where candidates cost the same (the gain
        cannot move the axis: at rest, or stuck in friction) the smallest |ΔK| is taken.
    kp0 : float, optional
        Gain before the first period, which is also the fixed gain of the comparison run C1. Default: the
        best of ``tuning.schedule.baseline_kp_m_min_mm`` (seed 001 §4: the fixed gain of least contour-error
        MSE among those that keep every axis within its V, A, J limits), else the drive's ``kp_m_min_mm``.
    kinematics : {"predicted", "eq10", "none"}, optional
        How the kinematic limits (V, A, J of the axis, eq. 2) restrict ΔK:
        ``predicted`` checks the displacement of the next period that the model
        predicts for the candidate; ``eq10`` is the paper's bound on ΔK from the
        velocity command with the velocity loop taken as 1 (so eq. 8's stored
        displacements are the commanded ``u·T`` of the last two periods; its division by
        ``E_Z`` is guarded: where ``E_Z`` is ~0 the gain cannot change the
        command and gives no bound; for ``E_Z < 0`` the bounds swap); ``none``.

    Returns
    -------
    ScheduleResult
        Contour errors are measured against the reference setpoints (seed 001
        eq. 1: the closest desired position and its neighbouring segments).
    """
    from ilcnc.contour.path import PathGeometry
    from ilcnc.contour.search import contour_error
    from ilcnc.program.model import MOVE_RAPID
    from ilcnc.vcnc.drives import simulate_drives
    from ilcnc.vcnc.plan import plan_program

    t0 = time.perf_counter()
    cfg = profile.tuning.schedule
    axis = profile.schedule_axis if axis is None else axis
    kp_range = cfg.kp_range if kp_range is None else kp_range
    horizon = cfg.horizon_samples if horizon is None else horizon
    lam = cfg.lam if lam is None else lam
    dk = cfg.dk_candidates if dk is None else dk
    kinematics = cfg.kinematics if kinematics is None else kinematics
    if axis not in profile.axes:
        raise ValueError(f"axis {axis!r} is not in the profile")
    drive = profile.axes[axis].drive
    if not isinstance(drive, PFfFrictionDrive):
        raise ValueError(f"axis {axis}: the schedule needs a p_ff_friction drive (a P position loop), not {drive.model}")
    if profile.controller.type == "cross_coupled":
        raise ValueError("the schedule is for independent axes (controller.type: independent)")
    if kinematics not in _KIN_MODES:
        raise ValueError(f"kinematics must be one of {', '.join(_KIN_MODES)}")
    kmin, kmax = float(kp_range[0]), float(kp_range[1])
    if not (0 < kmin <= kmax):
        raise ValueError(f"kp_range must satisfy 0 < min <= max, got {kp_range}")
    dks = np.round(np.asarray(dk, dtype=np.float64), 12)
    if dks.ndim != 1 or dks.size == 0 or not np.all(np.isfinite(dks)):
        raise ValueError("dk must be a non-empty 1-D array of finite numbers")
    if int(horizon) != horizon or horizon < 1:
        raise ValueError(f"horizon must be an integer >= 1, got {horizon}")
    if not (math.isfinite(lam) and lam >= 0):
        raise ValueError(f"lam must be >= 0, got {lam}")
    period = profile.machine.servo_period_s
    ref = plan_program(program, profile)
    r = np.asarray(ref.pos_mm, dtype=np.float64)
    n = r.shape[0]
    if n < 3:
        raise ValueError("the program has no motion to schedule")
    ai = AXIS_NAMES.index(axis)
    act1 = simulate_drives(r, profile)  # C1: every axis with its fixed gain
    # the desired contour: the reference setpoints as a polyline (eq. 1)
    poly = PathGeometry.from_polyline(r, commands=False)
    err1 = contour_error(poly, act1, np.maximum(np.arange(n) - 1, 0))
    hint = np.clip(np.asarray(err1.seg, dtype=np.int64), 0, n - 2)
    dev = r[:, ai] - r[0, ai]
    vref = np.diff(dev, prepend=dev[:1]) / period
    arr = _schedule_plant_arrays(drive, period)
    kern, dist, steps = _schedule_kernel()
    ax_prof = profile.axes[axis]
    pa = np.ascontiguousarray(r[:-1])
    pb = np.ascontiguousarray(r[1:])
    other = np.ascontiguousarray(act1)
    common = (ax_prof.max_velocity_mm_s, ax_prof.max_acceleration_mm_s2, ax_prof.max_jerk_mm_s3)
    plant = (arr["cq"], arr["kff"], arr["nsub"], arr["phih"], arr["guh"], arr["gfh"], arr["cv"], arr["bstick"],
             arr["fc"], arr["fbreak"], arr["vs"], arr["phis"], arr["gus"])

    def run(k_start: float, lo: float, hi: float, cands: NDArray[np.float64], npred: int, mode: int) -> tuple:
        return kern(np.ascontiguousarray(dev), np.ascontiguousarray(vref), float(r[0, ai]), other, ai, pa, pb, hint,
                    _SCHEDULE_SEARCH, k_start, lo, hi, cands, float(lam) * _LAM_MM2_PER_UM2, int(npred), period,
                    *common, mode, *plant,
                    dist, steps)

    mv = np.maximum(np.asarray(ref.move, dtype=np.int64), 0)
    feed = (np.asarray(ref.move) >= 0) & (program.moves.kind[mv] != MOVE_RAPID)

    def fixed_run(kf: float) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """C1 with the scheduled axis's gain fixed at ``kf``: its motion, every axis's, its MSE (µm²)."""
        _k, q, *_ = run(kf, kf, kf, np.zeros(1), 0, 0)
        act = act1.copy()
        act[:, ai] = r[0, ai] + q
        d = np.where(feed, contour_error(poly, act, hint).dist_mm, np.nan)
        return q, act, float(np.nanmean(d**2)) * 1e6

    scan: list[tuple[float, float, bool]] = []
    if kp0 is None and cfg.baseline_kp_m_min_mm is not None:
        for kf in cfg.baseline_kp_m_min_mm:
            _q, act, mse = fixed_run(float(kf))
            scan.append((float(kf), mse, _within_limits(act, period, profile)))
        ok = [s for s in scan if s[2]] or scan  # none within the limits: the least MSE, reported as such
        k_fixed = min(ok, key=lambda s: s[1])[0]
    else:
        k_fixed = float(drive.kp_m_min_mm if kp0 is None else kp0)
    q1, _act, _mse = fixed_run(k_fixed)
    start = min(max(k_fixed, kmin), kmax)
    k2, q2, limited, infeasible, guarded = run(start, kmin, kmax, dks, int(horizon), _KIN_MODES[kinematics])
    before = act1.copy()
    before[:, ai] = r[0, ai] + q1
    after = act1.copy()
    after[:, ai] = r[0, ai] + q2
    path = PathGeometry.from_moves(program.moves)

    def stats(act: NDArray[np.float64]) -> tuple[float, float, float]:
        e = contour_error(poly, act, hint)
        d = np.where(feed, e.dist_mm, np.nan)
        ep = contour_error(path, act, mv)
        dp = np.where(feed, ep.dist_mm, np.nan)
        return (float(np.nanmean(d**2)) * 1e6, float(np.nanmax(d)) * 1e3, float(np.nanmean(dp**2)) * 1e6)

    m1, x1, p1 = stats(before)
    m2, x2, p2 = stats(after)
    return ScheduleResult(axis, np.asarray(ref.t_s, dtype=np.float64), np.asarray(k2, dtype=np.float64), k_fixed,
                          m1, m2, x1, x2, p1, p2, _kinematics(before[:, ai], period, ax_prof),
                          _kinematics(after[:, ai], period, ax_prof), int(limited), int(infeasible), int(guarded),
                          int(horizon), float(lam), dks, (kmin, kmax), kinematics, r, before, after,
                          tuple(scan), _within_limits(before, period, profile), _within_limits(after, period, profile),
                          time.perf_counter() - t0)



"""Learning-gain design: learning gains that provably converge, from the profile's drive models.

Three methods, one per learning law of the profile (``ilcnc tune``):

``time`` -- the time-domain PID-type law of seed 000 (:func:`design_time_domain`)
    With ``T(z)`` the exact discrete closed loop reference → position of an
    axis (:func:`ilcnc.drives.discrete_model`, convention: ``q[k]`` depends on
    ``r[0..k-1]``), the learning update ``U_{i+1} = U_i + z^η K_l(z) e_i`` makes
    the error of the next iteration ``e_{i+1} = (1 − z^η T K_l) e_i``. The
    convergence factor is

        ε = max over f in [f_min, f_max] of |1 − z^η T(z) K_l(z)|,   z = e^{j2πf t_s},

    with ``K_l(z) = K_Pl + K_Il t_s/(1 − z⁻¹) + K_Dl (1 − z⁻¹)/t_s`` (the
    backward difference: seed 000's printed operator ``(z⁻¹ − 1)/(t_s z⁻¹)``
    is its conjugate and reverses the sense of the lead η). It is evaluated on
    a dense grid (linear on [f_min, f_max] plus logarithmic down to 1 µHz, where
    the slow PID poles of seed 000 live) and minimised over the gains for each
    lead η = 0..lead_max. ``ε`` is affine in the gains inside the modulus, so
    the problem is convex: a linear programme on a polygon approximation of
    the modulus finds the global optimum to 2 % (scipy ``linprog``), and a
    smooth epigraph formulation (scipy ``SLSQP``, several starts, exchange of
    the active frequencies) polishes it. With ``K_Il > 0``, ``|K_l|`` grows
    without bound as f → 0, so ``K_Il`` is fixed at 0 unless ``f_min > 0`` and
    ``fix_ki=False``; the result says which.

``lifted`` -- the command-index law ``U_{i+1}(k) = U_i(k) + Γ E_i(k)`` of seed 004 (:func:`check_lifted`)
    The lifted map ``G`` (``E(U) ≈ E_0 − G U`` on the program) is built by
    simulation, column by column, with the planner's time law held fixed: a
    correction of end point k moves the planned reference by the hat of the
    two moves that meet there, the linear drives turn that into an actual
    motion (exact superposition: only the few hundred samples the hat and the
    drive's settling touch are simulated), and the profile's own error
    estimate (:mod:`ilcnc.command_error`) turns it into ``E``. With the update
    shaper of :mod:`ilcnc.learn` (lead, zero-phase Q-filter ``Q``) the error
    propagates as ``E_{i+1} = (I − G Q Γ S) E_i``; monotone convergence in the
    2-norm is ``‖I − G Q Γ S‖₂ < 1`` on the errors the estimate can produce
    (normal to the path: a tangential shift of an end point moves no contour
    error, so those directions have eigenvalue 1 and are left out), and
    asymptotic convergence is a spectral radius ≤ 1. Γ and the Q-filter
    cut-off are chosen from candidates.

``schedule`` -- the receding-horizon offline gain adjustment of seed 001 (:func:`schedule_gains`)
    A per-servo-period position gain ``K_p`` of one axis, chosen at every
    instant among ``K_{k−1} + ΔK`` by the cost ``J = ε̂ᵀε̂ + λ ΔK²`` of the
    contour error predicted over ``Np`` samples (eqs. 3-5) with the nonlinear
    (friction) axis model, kept in the stable range (eqs. 6-7) and within the
    kinematic limits (eqs. 8-10, with eq. 10's division by ``E_Z`` guarded). Np, λ, the ΔK
    candidates, the gain range and the axis come from the profile's ``tuning.schedule`` (seed 001's
    values by default).

:func:`tune_profile` is what ``ilcnc tune`` calls: it picks the method from
the profile's law, runs it and, with ``write=True``, stores the gains in the
profile with :func:`ilcnc.profile_edit.update_profile` (comments kept).

All functions take and return numpy arrays and explicit result dataclasses;
nothing here prints.
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

from ilcnc.profile import AXIS_NAMES, MachineProfile, PFfFrictionDrive

__all__ = [
    "DEFAULT_DK",
    "DEFAULT_F_MAX_HZ",
    "DEFAULT_GAMMAS",
    "DEFAULT_MAX_COMMANDS",
    "DEFAULT_Q_FILTERS_HZ",
    "METHODS",
    "AxisDesign",
    "EpsilonCurve",
    "LeadOption",
    "LiftedCandidate",
    "LiftedCheck",
    "LiftedModel",
    "ScheduleResult",
    "TuneReport",
    "TuneResult",
    "check_lifted",
    "design_time_domain",
    "epsilon_of",
    "frequency_grid",
    "learning_response",
    "lifted_model",
    "schedule_gains",
    "seed001_standin_program",
    "tune_profile",
]

#: Upper end of the default design band, Hz (seed 000: "0 < Ω < 100 Hz").
DEFAULT_F_MAX_HZ = 100.0
#: Lowest frequency of the logarithmic part of the grid, Hz (seed 000's slowest PID pole is at 1.8 mHz).
GRID_F_LOW_HZ = 1e-6
#: Points of the linear part of the grid and per decade of the logarithmic part.
GRID_LINEAR_POINTS = 4001
GRID_POINTS_PER_DECADE = 200
#: Sides of the polygon that approximates the modulus in the linear programme (error 1/cos(π/M) − 1 = 2 %; the polish removes it).
_POLYGON_SIDES = 16
#: Largest learning gain the profile accepts (``learning.gains.kp/kd/ki``).
_GAIN_MAX = 1e6

# ---------------------------------------------------------------------------------------------
# Time-domain design (seed 000)
# ---------------------------------------------------------------------------------------------


def frequency_grid(f_min_hz: float, f_max_hz: float, period_s: float, *, linear_points: int = GRID_LINEAR_POINTS,
                   per_decade: int = GRID_POINTS_PER_DECADE) -> NDArray[np.float64]:
    """The dense design grid on ``[f_min_hz, f_max_hz]``, Hz.

    Parameters
    ----------
    f_min_hz, f_max_hz : float
        Band, Hz; ``0 <= f_min_hz < f_max_hz <= 0.5/period_s`` (Nyquist).
    period_s : float
        Servo period, s.
    linear_points : int
        Points of the evenly spaced part.
    per_decade : int
        Points per decade of the logarithmic part (from ``max(f_min, 1 µHz)``), which
        resolves the slow poles of a PID loop that an even grid misses.

    Returns
    -------
    ndarray (F,)
        Sorted unique frequencies, Hz, both ends included.
    """
    nyq = 0.5 / period_s
    if not (0.0 <= f_min_hz < f_max_hz):
        raise ValueError(f"the band must satisfy 0 <= f_min < f_max, got [{f_min_hz}, {f_max_hz}] Hz")
    if f_max_hz > nyq * (1 + 1e-12):
        raise ValueError(f"f_max {f_max_hz:g} Hz is above the Nyquist frequency {nyq:g} Hz of the servo period")
    lin = np.linspace(f_min_hz, f_max_hz, int(linear_points))
    lo = max(f_min_hz, GRID_F_LOW_HZ)
    if lo < f_max_hz:
        n = max(2, math.ceil(math.log10(f_max_hz / lo) * per_decade) + 1)
        lin = np.concatenate([lin, np.geomspace(lo, f_max_hz, n)])
    return np.unique(lin)


def learning_response(freq_hz: ArrayLike, period_s: float, kp: float, ki: float, kd: float) -> NDArray[np.complex128]:
    """``K_l(e^{j2πf t_s}) = K_Pl + K_Il t_s/(1 − z⁻¹) + K_Dl (1 − z⁻¹)/t_s`` (inf at f = 0 when ``ki > 0``).

    Parameters
    ----------
    freq_hz : array_like
        Frequencies, Hz.
    period_s : float
        Servo period t_s, s.
    kp, ki, kd : float
        K_Pl (1), K_Il (1/s), K_Dl (s).
    """
    f = np.asarray(freq_hz, dtype=np.float64)
    zinv = np.exp(-2j * np.pi * f * period_s)
    out = kp + kd * (1.0 - zinv) / period_s + 0j
    if ki:
        pos = f > 0
        integ = period_s / np.where(pos, 1.0 - zinv, 1.0)
        out = np.where(pos, out + ki * integ, np.inf + 0j)
    return out


@dataclass(frozen=True)
class EpsilonCurve:
    """``|1 − z^η T(z) K_l(z)|`` of one axis on a grid.

    Attributes
    ----------
    freq_hz : ndarray (F,)
        Grid, Hz.
    magnitude : ndarray (F,)
        ``|1 − z^η T K_l|`` (inf where ``K_l`` is, i.e. at 0 Hz with ``K_Il > 0``).
    epsilon : float
        Its maximum over the grid.
    peak_hz : float
        Where the maximum is, Hz.
    """

    freq_hz: NDArray[np.float64]
    magnitude: NDArray[np.float64]
    epsilon: float
    peak_hz: float


def _closed_loop(profile: MachineProfile, axis: str, freq_hz: NDArray[np.float64]) -> NDArray[np.complex128]:
    from ilcnc.drives import discrete_model

    if axis not in profile.axes:
        raise ValueError(f"axis {axis!r} is not in the profile (it has {', '.join(profile.axes)})")
    model = discrete_model(profile.axes[axis].drive, profile.machine.servo_period_s)
    return model.frequency_response(freq_hz)


def epsilon_of(profile: MachineProfile, axis: str, kp: float, ki: float, kd: float, lead: int, *,
               f_min_hz: float = 0.0, f_max_hz: float = DEFAULT_F_MAX_HZ,
               freq_hz: ArrayLike | None = None) -> EpsilonCurve:
    """Evaluate the convergence factor of given learning gains on one axis.

    Parameters
    ----------
    profile : MachineProfile
        The machine (its drive model of ``axis`` and servo period).
    axis : str
        ``"x"``, ``"y"`` or ``"z"``.
    kp, ki, kd : float
        K_Pl (1), K_Il (1/s), K_Dl (s).
    lead : int
        η, servo periods.
    f_min_hz, f_max_hz : float
        Band, Hz (ignored when ``freq_hz`` is given).
    freq_hz : array_like, optional
        Evaluate on these frequencies instead of :func:`frequency_grid`.

    Returns
    -------
    EpsilonCurve
        ``epsilon`` is ``inf`` (at 0 Hz) when ``ki > 0`` and the band starts at 0.
    """
    ts = profile.machine.servo_period_s
    f = frequency_grid(f_min_hz, f_max_hz, ts) if freq_hz is None else np.asarray(freq_hz, dtype=np.float64)
    t = _closed_loop(profile, axis, f)
    zlead = np.exp(2j * np.pi * f * ts * int(lead))
    kl = learning_response(f, ts, kp, ki, kd)
    with np.errstate(invalid="ignore"):
        mag = np.abs(1.0 - zlead * t * kl)
    mag = np.where(np.isfinite(kl), mag, np.inf)
    i = int(np.argmax(mag))
    return EpsilonCurve(f, mag, float(mag[i]), float(f[i]))


def _local_maxima(v: NDArray[np.float64]) -> NDArray[np.int64]:
    """Indices of the local maxima of ``v`` (ends included)."""
    if v.size < 3:
        return np.arange(v.size)
    left = np.concatenate(([True], v[1:] >= v[:-1]))
    right = np.concatenate((v[:-1] >= v[1:], [True]))
    return np.flatnonzero(left & right)


def _minimax(a: NDArray[np.complex128], b: NDArray[np.complex128], starts: Sequence[NDArray[np.float64]],
             ) -> tuple[NDArray[np.float64], float, int]:
    """Minimise ``max_i |a_i + b_i·x|`` over ``x >= 0`` (convex): LP on a polygon, then SLSQP from several starts.

    Parameters
    ----------
    a : ndarray (F,) complex
    b : ndarray (F, P) complex
    starts : sequence of ndarray (P,)
        Extra starting points of the polish (the LP solution is always one).

    Returns
    -------
    x : ndarray (P,)
    value : float
        ``max |a + b x|`` on all F points.
    peak : int
        Index of that maximum.
    """
    from scipy.optimize import linprog, minimize

    nf, npar = b.shape
    ar, ai = np.ascontiguousarray(a.real), np.ascontiguousarray(a.imag)
    br, bi = np.ascontiguousarray(b.real), np.ascontiguousarray(b.imag)

    def modulus(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.hypot(ar + br @ x, ai + bi @ x)

    def objective(x: NDArray[np.float64]) -> float:
        return float(np.max(modulus(x)))

    theta = 2.0 * np.pi * np.arange(_POLYGON_SIDES) / _POLYGON_SIDES
    c, s = np.cos(theta), np.sin(theta)
    # start from a thinned grid, add the worst frequencies of the dense one (exchange)
    active = np.unique(np.concatenate([np.linspace(0, nf - 1, min(nf, 200)).astype(np.int64), [0, nf - 1]]))
    bounds = [(0.0, _GAIN_MAX)] * npar + [(0.0, None)]
    x_lp = np.zeros(npar)
    for _ in range(8):
        # Re(e^{-jθ}(a + b x)) <= t  for every polygon direction θ
        rows = (br[active][None, :, :] * c[:, None, None] + bi[active][None, :, :] * s[:, None, None]).reshape(-1, npar)
        rhs = -(ar[active][None, :] * c[:, None] + ai[active][None, :] * s[:, None]).reshape(-1)
        a_ub = np.column_stack([rows, -np.ones(rows.shape[0])])
        res = linprog(np.r_[np.zeros(npar), 1.0], A_ub=a_ub, b_ub=rhs, bounds=bounds, method="highs")
        if res.status != 0:  # pragma: no cover - a bounded feasible LP
            break
        x_lp = np.asarray(res.x[:npar], dtype=np.float64)
        t_lp = float(res.x[-1])
        mag = modulus(x_lp)
        if mag.max() <= t_lp / math.cos(math.pi / _POLYGON_SIDES) * (1 + 1e-9):
            break
        cand = _local_maxima(mag)
        cand = cand[mag[cand] > t_lp]
        new = np.setdiff1d(cand[np.argsort(mag[cand])[::-1][:50]], active)
        if new.size == 0:
            break
        active = np.union1d(active, new)

    best_x, best_v = x_lp, objective(x_lp)
    for x0 in [x_lp, *starts]:
        x = np.clip(np.asarray(x0, dtype=np.float64), 0.0, _GAIN_MAX)
        for _ in range(4):
            mag = modulus(x)
            top = float(mag.max())
            cand = _local_maxima(mag)
            sel = cand[mag[cand] >= 0.8 * top]
            sel = sel[np.argsort(mag[sel])[::-1][:30]]
            sel = np.unique(np.clip(np.concatenate([sel - 1, sel, sel + 1]), 0, nf - 1))
            sar, sai, sbr, sbi = ar[sel], ai[sel], br[sel], bi[sel]

            def cons(z: NDArray[np.float64], sar=sar, sai=sai, sbr=sbr, sbi=sbi) -> NDArray[np.float64]:
                wr, wi = sar + sbr @ z[:-1], sai + sbi @ z[:-1]
                return z[-1] ** 2 - (wr * wr + wi * wi)

            def jac(z: NDArray[np.float64], sar=sar, sai=sai, sbr=sbr, sbi=sbi) -> NDArray[np.float64]:
                wr, wi = sar + sbr @ z[:-1], sai + sbi @ z[:-1]
                g = -2.0 * (wr[:, None] * sbr + wi[:, None] * sbi)
                return np.column_stack([g, np.full(len(wr), 2.0 * z[-1])])

            res = minimize(lambda z: z[-1], np.r_[x, top], jac=lambda z: np.r_[np.zeros(npar), 1.0],
                           constraints=[{"type": "ineq", "fun": cons, "jac": jac}],
                           bounds=[(0.0, _GAIN_MAX)] * npar + [(0.0, None)], method="SLSQP",
                           options={"maxiter": 200, "ftol": 1e-12})
            xn = np.clip(np.asarray(res.x[:npar], dtype=np.float64), 0.0, _GAIN_MAX)
            if objective(xn) < objective(x) - 1e-14:
                x = xn
            else:
                break
        v = objective(x)
        if v < best_v:
            best_x, best_v = x, v
    return best_x, best_v, int(np.argmax(modulus(best_x)))


@dataclass(frozen=True)
class LeadOption:
    """The optimum of one lead η on one axis.

    Attributes
    ----------
    lead : int
        η, servo periods.
    kp, ki, kd : float
        K_Pl (1), K_Il (1/s), K_Dl (s).
    epsilon : float
        ``max |1 − z^η T K_l|`` on the band.
    peak_hz : float
        Frequency of the maximum, Hz.
    """

    lead: int
    kp: float
    ki: float
    kd: float
    epsilon: float
    peak_hz: float


@dataclass(frozen=True)
class AxisDesign:
    """Learning gains of one axis for the time-domain law (``pid_ace``).

    Attributes
    ----------
    axis : str
    kp, ki, kd : float
        K_Pl (1), K_Il (1/s), K_Dl (s) at the chosen lead.
    lead_samples : int
        η of the result (common to all axes: the law has one lead).
    epsilon : float
        Convergence factor on the band at that lead (inf if the drive has no linear model).
    peak_hz : float
        Frequency of the maximum, Hz.
    converges : bool
        ``epsilon < 1``.
    reason : str
        Why it does not converge ("" when it does).
    options : tuple of LeadOption
        The optimum of every lead tried (η = 0..lead_max).
    best_lead : int
        The lead that is best for this axis alone.
    notes : tuple of str
        E.g. that a friction drive was designed on its linear part.
    """

    axis: str
    kp: float
    ki: float
    kd: float
    lead_samples: int
    epsilon: float
    peak_hz: float
    converges: bool
    reason: str
    options: tuple[LeadOption, ...]
    best_lead: int
    notes: tuple[str, ...] = ()

    def gains(self) -> dict[str, float | int]:
        return {"kp": self.kp, "ki": self.ki, "kd": self.kd, "lead_samples": self.lead_samples}

    def to_json(self) -> dict[str, Any]:
        return {"law": "pid_ace", "gains": self.gains(), "epsilon": _json_float(self.epsilon),
                "peak_hz": _json_float(self.peak_hz), "converges": self.converges, "reason": self.reason,
                "best_lead": self.best_lead,
                "by_lead": [{"lead_samples": o.lead, "kp": o.kp, "ki": o.ki, "kd": o.kd,
                             "epsilon": _json_float(o.epsilon), "peak_hz": _json_float(o.peak_hz)}
                            for o in self.options],
                "notes": list(self.notes)}


@dataclass(frozen=True)
class TuneResult:
    """Result of :func:`design_time_domain`.

    Attributes
    ----------
    axes : dict of str to AxisDesign
        Per axis, at the common lead.
    lead_samples : int
        The common lead η (the one with the smallest worst-axis ε).
    f_min_hz, f_max_hz : float
        Band, Hz.
    ki_mode : str
        ``"fixed_zero"`` (K_Il = 0: with f_min = 0, ε is unbounded for K_Il > 0, or
        ``fix_ki=True``) or ``"free"`` (optimised on [f_min > 0, f_max]).
    ki_note : str
        One sentence saying which and why.
    elapsed_s : float
        Wall time, s.
    """

    axes: dict[str, AxisDesign]
    lead_samples: int
    f_min_hz: float
    f_max_hz: float
    ki_mode: str
    ki_note: str
    elapsed_s: float = 0.0

    @property
    def converges(self) -> bool:
        return all(a.converges for a in self.axes.values())

    def to_json(self) -> dict[str, Any]:
        return {"method": "time", "axes": {k: v.to_json() for k, v in self.axes.items()},
                "lead_samples": self.lead_samples, "band_hz": [self.f_min_hz, self.f_max_hz],
                "ki_mode": self.ki_mode, "ki_note": self.ki_note, "converges": self.converges}


def _group_delay_samples(t: NDArray[np.complex128], f: NDArray[np.float64], ts: float) -> float:
    """Low-frequency group delay ``−dφ/dω`` of a response ``t`` on grid ``f``, in servo periods."""
    pos = np.flatnonzero(f > 0)
    if pos.size < 2:
        return math.nan
    i0, i1 = pos[0], pos[min(5, pos.size - 1)]
    dphi = float(np.angle(t[i1] / t[i0]))
    return -dphi / (2.0 * np.pi * (f[i1] - f[i0])) / ts


def _hashable(x: object) -> bool:
    try:
        hash(x)
    except TypeError:
        return False
    return True


def _json_float(v: float | None) -> float | None:
    """JSON has no inf/NaN: ``None`` for them."""
    if v is None or not math.isfinite(v):
        return None
    return float(v)


def design_time_domain(profile: MachineProfile, *, f_min_hz: float = 0.0, f_max_hz: float = DEFAULT_F_MAX_HZ,
                       lead_max: int = 3, fix_ki: bool = True, axes: Sequence[str] | None = None) -> TuneResult:
    """Design the PID-type learning gains of every axis by minimising the convergence factor ε.

    Parameters
    ----------
    profile : MachineProfile
        The machine; every axis with a linear drive model (a friction drive is
        designed on its linear part, and says so).
    f_min_hz, f_max_hz : float
        Band of the design, Hz (``f_max`` at most the Nyquist frequency).
    lead_max : int
        Leads η = 0..lead_max (servo periods) are tried.
    fix_ki : bool
        Keep K_Il = 0 (default). With ``False`` and ``f_min_hz > 0`` K_Il is
        optimised too; with ``f_min_hz == 0`` it stays 0 anyway (ε would be
        unbounded) and ``ki_note`` says so.
    axes : sequence of str, optional
        Only these axes (default: all of the profile).

    Returns
    -------
    TuneResult
        Per axis K_Pl, K_Il, K_Dl, ε, its peak frequency, ``converges``
        (ε < 1) and the reason when not; the lead is common to all axes (the
        law has one), the one whose worst axis ε is smallest.
    """
    from ilcnc.drives import DriveModelError

    t0 = time.perf_counter()
    ts = profile.machine.servo_period_s
    f = frequency_grid(f_min_hz, f_max_hz, ts)
    if lead_max < 0:
        raise ValueError("lead_max must be >= 0")
    free_ki = (not fix_ki) and f_min_hz > 0
    if free_ki:
        ki_mode, ki_note = "free", f"K_Il optimised on [{f_min_hz:g}, {f_max_hz:g}] Hz (f_min > 0 keeps ε bounded)"
    elif not fix_ki:
        ki_mode, ki_note = "fixed_zero", "K_Il fixed at 0: with f_min = 0 any K_Il > 0 makes ε unbounded (|K_l| → ∞ at 0 Hz)"
    else:
        ki_mode, ki_note = "fixed_zero", (f"K_Il fixed at 0 (ε evaluated on [{f_min_hz:g}, {f_max_hz:g}] Hz;"
                                          " with K_Il > 0 it is unbounded as f → 0)")
    zinv = np.exp(-2j * np.pi * f * ts)
    basis = [np.ones_like(zinv), (1.0 - zinv) / ts]
    if free_ki:
        basis.insert(1, ts / (1.0 - zinv))  # f_min > 0: no division by zero
    basis_m = np.column_stack(basis)
    names = tuple(profile.axes) if axes is None else tuple(axes)
    per_axis: dict[str, list[LeadOption]] = {}
    notes: dict[str, tuple[str, ...]] = {}
    failed: dict[str, str] = {}
    done: dict[Any, str] = {}  # an axis whose drive equals an earlier axis's has the same design
    delays: dict[str, float] = {}
    for ax in names:
        drive = profile.axes[ax].drive
        nt: list[str] = []
        if isinstance(drive, PFfFrictionDrive) and (drive.coulomb_n > 0 or drive.static_n > 0):
            nt.append("designed on the linear part of the drive (Coulomb/Stribeck friction left out)")
        if profile.controller.type == "cross_coupled" and ax in profile.controller.coupled_axes:
            nt.append("designed on the uncoupled loop (the cross-coupled controller is left out)")
        notes[ax] = tuple(nt)
        twin = done.get(drive) if _hashable(drive) else None
        if twin is not None:
            per_axis[ax] = per_axis[twin]
            if twin in delays:
                delays[ax] = delays[twin]
            if twin in failed:
                failed[ax] = failed[twin]
            continue
        if _hashable(drive):
            done[drive] = ax
        try:
            t = _closed_loop(profile, ax, f)
        except DriveModelError as exc:
            failed[ax] = f"no linear model: {exc}"
            per_axis[ax] = []
            continue
        dc = abs(t[0]) if f[0] == 0 else 1.0
        opts = []
        for eta in range(lead_max + 1):
            h = np.exp(2j * np.pi * f * ts * eta) * t
            b = -h[:, None] * basis_m
            a = np.ones_like(h)
            # start of the polish: the inverse of the loop at low frequency (K_Pl = 1/T(0), nothing else)
            guess = np.zeros(basis_m.shape[1])
            guess[0] = 1.0 / dc if dc > 0 else 1.0
            x, v, i = _minimax(a, b, [guess])
            kp, kd = float(x[0]) + 0.0, float(x[-1]) + 0.0  # + 0.0: no -0.0
            ki = float(x[1]) + 0.0 if free_ki else 0.0
            opts.append(LeadOption(eta, kp, ki, kd, float(v), float(f[i])))
        per_axis[ax] = opts
        delays[ax] = _group_delay_samples(t, f, ts)
    # the common lead: smallest worst-axis ε
    ok_axes = [a for a in names if per_axis[a]]
    if ok_axes:
        worst = [max(per_axis[a][eta].epsilon for a in ok_axes) for eta in range(lead_max + 1)]
        lead = int(np.argmin(worst))
    else:
        lead = 0
    out: dict[str, AxisDesign] = {}
    for ax in names:
        opts = per_axis[ax]
        if not opts:
            out[ax] = AxisDesign(ax, 0.0, 0.0, 0.0, lead, math.inf, math.nan, False, failed[ax], (), lead, notes[ax])
            continue
        o = opts[lead]
        best = min(opts, key=lambda p: (p.epsilon, p.lead))
        conv = o.epsilon < 1.0
        if conv:
            reason = ""
        elif o.kp == 0.0 and o.kd == 0.0 and o.ki == 0.0:
            reason = (f"no gains K_Pl, K_Dl >= 0 bring ε below 1 for any lead 0..{lead_max} (the best is not to learn,"
                      f" ε = {o.epsilon:.3g}); the loop lags its reference by about {delays.get(ax, math.nan):.1f}"
                      " servo periods at low frequency: try a larger lead_max")
        else:
            reason = (f"ε = {o.epsilon:.3g} >= 1 at {o.peak_hz:.3g} Hz with lead η = {lead}: the update amplifies"
                      " the error there")
        out[ax] = AxisDesign(ax, o.kp, o.ki, o.kd, lead, o.epsilon, o.peak_hz, conv, reason, tuple(opts), best.lead,
                             notes[ax])
    return TuneResult(out, lead, float(f_min_hz), float(f_max_hz), ki_mode, ki_note, time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------------
# The lifted map of the command-index law (seed 004)
# ---------------------------------------------------------------------------------------------

#: Γ candidates of :func:`check_lifted`.
DEFAULT_GAMMAS = (0.1, 0.2, 0.3, 0.5, 0.7, 1.0)
#: Q-filter cut-off candidates, Hz (``None``: no filter).
DEFAULT_Q_FILTERS_HZ: tuple[float | None, ...] = (None, 50.0, 20.0, 10.0, 5.0)
#: Largest window of the lifted model, commands (the matrix is (n·axes)², its eigenvalues O(n³)).
DEFAULT_MAX_COMMANDS = 200
#: A spectral radius up to 1 + this counts as 1: the Q-filter leaves its stop band unlearned (eigenvalues → 1).
RHO_TOL = 1e-4
#: Relative size of the drive's impulse response below which it counts as settled.
_SETTLE_TOL = 1e-7
#: Longest settling horizon simulated after a correction's hat, s.
_SETTLE_MAX_S = 5.0
#: A vertex whose two moves turn by more than this (degrees) is a corner: its error may point anywhere.
_CORNER_DEG = 20.0


@dataclass(frozen=True, eq=False)
class LiftedModel:
    """The lifted map of a program: ``E(U) ≈ E_0 − G·U`` on a window of commands.

    The columns (and rows) are the correctable coordinates ``(command, axis)``
    of the window, axis-major: all of x, then all of y, ...

    Attributes
    ----------
    g : ndarray (n, n)
        ``G = −∂E/∂U`` (dimensionless: mm of error per mm of correction).
    command : ndarray (n,) int
        Command index k of each row/column.
    axis : ndarray (n,) int
        Axis (0 x, 1 y, 2 z) of each row/column.
    t_s : ndarray (n,)
        Time stamp of each command's error on the uncorrected run, s.
    e0_mm : ndarray (n,)
        The uncorrected run's error ``E_0``, mm.
    normal_basis : ndarray (n, r)
        Orthonormal basis of the errors the estimate can produce (normal to the
        path: per command the directions normal to its tangent, all directions
        at a corner; the identity for the ``tracking`` estimate).
    window : (int, int)
        First command and one past the last command of the window.
    kind : str
        The error estimate (``learning.error`` resolved).
    linear : bool
        The drives are linear (exact superposition of the corrections); otherwise
        ``g`` is the Jacobian at ``U = 0`` from full re-simulations.
    step_mm : float
        Finite-difference step, mm.
    simulations : int
        Drive simulations made (one per column).
    elapsed_s : float
        Wall time, s.
    """

    g: NDArray[np.float64]
    command: NDArray[np.int64]
    axis: NDArray[np.int64]
    t_s: NDArray[np.float64]
    e0_mm: NDArray[np.float64]
    normal_basis: NDArray[np.float64]
    window: tuple[int, int]
    kind: str
    linear: bool
    step_mm: float
    simulations: int
    elapsed_s: float

    @property
    def n(self) -> int:
        return int(self.g.shape[0])


def _linear_drives(profile: MachineProfile) -> bool:
    """True when every axis responds linearly to its reference (superposition holds)."""
    if profile.controller.type == "cross_coupled":
        return False  # θ of the coupling depends on the reference itself
    return not any(isinstance(ax.drive, PFfFrictionDrive) and (ax.drive.coulomb_n > 0 or ax.drive.static_n > 0)
                   for ax in profile.axes.values())


def _settle_samples(profile: MachineProfile, period_s: float, n_max: int) -> int:
    """Samples after which every axis's response to a pulse is below :data:`_SETTLE_TOL` of its peak."""
    from ilcnc.drives import discrete_model, filter_deviation

    cap = int(min(n_max, math.ceil(_SETTLE_MAX_S / period_s)))
    out = 1
    for ax in profile.axes.values():
        try:
            m = discrete_model(ax.drive, period_s)
        except Exception:  # a nonlinear / unstable model: the cap
            return cap
        pulse = np.zeros(cap + 1)
        pulse[1] = 1.0
        h = np.abs(filter_deviation(m, pulse))
        big = np.flatnonzero(h > _SETTLE_TOL * max(h.max(), 1e-300))
        out = max(out, int(big[-1]) + 2 if big.size else 2)
    return min(out, cap)


def _normal_basis(path: Any, command: NDArray[np.int64], axis: NDArray[np.int64], kind: str,
                  ) -> NDArray[np.float64]:
    """Orthonormal basis of the error directions the estimate can produce (see :class:`LiftedModel`)."""
    from ilcnc.command_error import command_end_tangents

    n = command.size
    if kind == "tracking":
        return np.eye(n)
    tang = command_end_tangents(path)
    mk = np.asarray(path.move_of_command, dtype=np.int64)
    m = len(path)
    nxt = np.minimum(mk + 1, m - 1)
    t_end = path.tangent_at(mk, np.ones(mk.size))
    t_next = path.tangent_at(nxt, np.zeros(mk.size))
    joined = ((mk + 1 < m) & np.asarray(path.active, bool)[nxt]
              & np.all(np.abs(path.start_mm[nxt] - path.end_mm[mk]) <= 1e-9, axis=1))
    cosang = np.einsum("ij,ij->i", t_end, t_next)
    corner = joined & (cosang < math.cos(math.radians(_CORNER_DEG)))
    cols: list[NDArray[np.float64]] = []
    for k in np.unique(command):
        idx = np.flatnonzero(command == k)
        axes_k = axis[idx]
        t = tang[k, axes_k]
        tn = float(np.linalg.norm(t))
        if corner[k] or tn < 1.0 - 1e-6:
            # a corner, or a tangent with a part outside the free axes: any error of these axes can occur
            for i in idx:
                v = np.zeros(n)
                v[i] = 1.0
                cols.append(v)
            continue
        # normals: orthonormal complement of t/|t| in the free axes of command k
        q, _ = np.linalg.qr(np.column_stack([t / tn, np.eye(idx.size)]))
        for c in range(1, idx.size):
            v = np.zeros(n)
            v[idx] = q[:, c]
            cols.append(v)
    return np.column_stack(cols) if cols else np.zeros((n, 0))


def lifted_model(program: Any, profile: MachineProfile, *, commands: tuple[int, int] | None = None,
                 max_commands: int = DEFAULT_MAX_COMMANDS, step_mm: float = 1e-4) -> LiftedModel:
    """Build the lifted map ``G`` of the command-index law on a program by simulation.

    Why column by column on a window: ``G`` couples every correction to the
    errors of the commands its motion reaches (tens of commands for G01s
    shorter than the drive's lag), so it is dense in a band and has no
    structure a few matrix-vector products would reveal reliably; the norm
    ``‖I − ΓG‖₂`` needs ``Gᵀ`` too, which simulation does not give. With the
    planner's time law fixed and linear drives, each column costs the drive
    filter on the samples the correction's hat and the settling touch, the
    contour error of those samples and the error estimate of the commands
    they reach: milliseconds. So ``G`` is built exactly, column by column, on
    the whole program when it has at most ``max_commands`` commands, else on
    a window of that many commands around the largest error (or the window
    given), as if the window were the program (its edges see no corrections
    from outside).

    Parameters
    ----------
    program : Program
        The part program (uncorrected).
    profile : MachineProfile
        Machine, planner, drives; ``learning.error`` selects the estimate.
    commands : (int, int), optional
        Window ``[k0, k1)`` of commands.
    max_commands : int
        Largest automatic window.
    step_mm : float
        Finite-difference step, mm (the drives are linear: any small step gives the
        same column; the contour error is smooth at this scale).

    Returns
    -------
    LiftedModel

    Notes
    -----
    Held fixed: the planner's timing. Rewriting an end point also changes the
    corner angles the planner limits its feed by, which changes the timing of
    the whole rest of the program; that response is not linear (it has a kink
    at collinear points) and is not in ``G``.
    """
    from ilcnc.command_error import (
        error_kind,
        measurement_gate_mm,
        path_weighted_error,
        signal_of_simulation,
    )
    from ilcnc.contour import ContourError, contour_error
    from ilcnc.drives import discrete_model, filter_deviation, simulate_drives
    from ilcnc.learn import Learner
    from ilcnc.lifted_error import sample_fractions
    from ilcnc.simulate import simulate_program

    t0 = time.perf_counter()
    if step_mm <= 0:
        raise ValueError("step_mm must be > 0")
    kind = error_kind(profile)
    gate = measurement_gate_mm(profile)
    sim0 = simulate_program(program, profile)
    sig0 = signal_of_simulation(sim0, program, kind, gate)
    ref = sim0.reference
    period = profile.machine.servo_period_s
    kk = program.n_commands
    if kk == 0:
        raise ValueError("the program has no G01 command")
    if commands is None:
        if kk <= max_commands:
            k0, k1 = 0, kk
        else:
            norm = np.where(sig0.valid, np.linalg.norm(sig0.e_mm, axis=1), -1.0)
            c = int(np.argmax(norm))
            k0 = int(np.clip(c - max_commands // 2, 0, kk - max_commands))
            k1 = k0 + max_commands
    else:
        k0, k1 = int(commands[0]), int(commands[1])
        if not (0 <= k0 < k1 <= kk):
            raise ValueError(f"window [{k0}, {k1}) is not within the program's {kk} commands")
    learner = Learner.for_program(program, profile)
    ok = learner.shaper.correctable[:, None] & (learner.axis_mask()[None, :] > 0) & sig0.valid[:, None]
    if learner.free is not None:
        ok &= learner.free
    cols = [(k, a) for a in range(3) for k in range(k0, k1) if ok[k, a]]
    if not cols:
        raise ValueError("no correctable coordinate in the window")
    command = np.array([c[0] for c in cols], dtype=np.int64)
    axis = np.array([c[1] for c in cols], dtype=np.int64)
    n = len(cols)

    moves = program.moves
    nm = len(moves)
    cm = program.command_moves
    ns = ref.n_samples
    mvs = np.asarray(ref.move, dtype=np.int64)
    lam = sample_fractions(moves, ref.move, ref.pos_mm)
    mv_idx = np.arange(nm)
    first = np.searchsorted(mvs, mv_idx, side="left")
    last = np.searchsorted(mvs, mv_idx, side="right")
    joined_next = np.zeros(nm, bool)
    if nm > 1:
        joined_next[:-1] = np.all(np.abs(moves.end_mm[:-1] - moves.start_mm[1:]) <= 1e-9, axis=1)
    err0 = sim0.error
    path = err0.path
    q0 = sim0.actual_mm
    feed = sim0.feed_mask
    ts = ref.t_s
    linear = _linear_drives(profile)
    settle = _settle_samples(profile, period, ns) if linear else ns
    models = {}
    if linear:
        for i, name in enumerate(AXIS_NAMES):
            if name in profile.axes:
                models[i] = discrete_model(profile.axes[name].drive, period)
    # sample ranges of each foot segment of the base run (which samples an E(k) of kind "path" reads)
    seg0 = np.asarray(err0.seg, dtype=np.int64)
    sfirst = np.full(nm, ns, dtype=np.int64)
    slast = np.full(nm, -1, dtype=np.int64)
    has = seg0 >= 0
    np.minimum.at(sfirst, seg0[has], np.flatnonzero(has))
    np.maximum.at(slast, seg0[has], np.flatnonzero(has))
    fields_ = ("dist_mm", "foot_mm", "vector_mm", "seg", "u", "signed_mm")
    row_k = command
    row_a = axis
    g = np.zeros((n, n))
    base_cache: dict[tuple[int, int], NDArray[np.float64]] = {}

    def path_e(err: Any, b0: int, b1: int) -> NDArray[np.float64]:
        ce = ContourError(*(getattr(err, f)[b0:b1] for f in (*fields_, "hint")), err.path)
        e, _t = path_weighted_error(path, ce, ts[b0:b1], on_feed=feed[b0:b1])
        return np.nan_to_num(e)

    for j, (k, a) in enumerate(cols):
        mk = int(cm[k])
        nxt = mk + 1 if (mk + 1 < nm and joined_next[mk]) else mk
        a0 = int(first[mk])
        a1 = int(last[nxt])
        if a1 <= a0:
            continue
        seg = mvs[a0:a1]
        w = np.where(seg == mk, lam[a0:a1], np.where((seg == nxt) & (nxt != mk), 1.0 - lam[a0:a1], 0.0))
        if nxt == mk:
            w = np.where(seg == mk, lam[a0:a1], 0.0)
        hi = min(ns, a1 + settle) if linear else ns
        dr = np.zeros(hi - a0)
        dr[: a1 - a0] = w * step_mm
        if linear:
            q = q0[a0:hi].copy()
            if a in models:
                q[:, a] += filter_deviation(models[a], dr)
        else:
            full = ref.pos_mm.copy()
            full[a0:hi, a] += dr
            q = simulate_drives(full, profile)[a0:hi]
        e_new = contour_error(path, q, err0.hint[a0:hi], workers=1)
        new = ContourError(*(getattr(err0, f).copy() for f in (*fields_, "hint")), path)
        for f in fields_:
            getattr(new, f)[a0:hi] = getattr(e_new, f)
        if kind == "path":
            touched = np.unique(np.concatenate([seg0[a0:hi], np.asarray(e_new.seg, dtype=np.int64)]))
            touched = touched[touched >= 0]
            touched = np.unique(np.clip(np.concatenate([touched - 1, touched, touched + 1]), 0, nm - 1))
            b0 = int(min(a0, sfirst[touched].min()))
            b1 = int(max(hi, slast[touched].max() + 1))
            key = (b0, b1)
            base = base_cache.get(key)
            if base is None:
                base = base_cache[key] = path_e(err0, b0, b1)
                if len(base_cache) > 64:
                    base_cache.pop(next(iter(base_cache)))
            de = path_e(new, b0, b1) - base
        else:
            from dataclasses import replace

            sim = replace(sim0, actual_mm=np.concatenate([q0[:a0], q, q0[hi:]]), error=new)
            de = np.nan_to_num(signal_of_simulation(sim, program, kind, gate).e_mm) - np.nan_to_num(sig0.e_mm)
        g[:, j] = -de[row_k, row_a] / step_mm
    b = _normal_basis(path, command, axis, kind)
    return LiftedModel(g, command, axis, sig0.t_s[command], sig0.e_mm[command, axis], b, (k0, k1), kind, linear,
                       float(step_mm), n, time.perf_counter() - t0)


@dataclass(frozen=True)
class LiftedCandidate:
    """One (Γ, Q-filter) pair on a lifted model.

    Attributes
    ----------
    gamma : float
        Learning gain Γ (all axes).
    q_filter_hz : float or None
        Q-filter cut-off, Hz (``None``: no filter).
    norm : float
        ``‖(I − G Q Γ S) B‖₂`` with B the normal basis: the guaranteed contraction of
        ``‖E‖`` per iteration for the errors the estimate produces (monotone if < 1).
    norm_full : float
        ``‖I − G Q Γ S‖₂`` on all coordinates (tangential ones included).
    spectral_radius : float
        ``ρ(Bᵀ(I − G Q Γ S)B)``: the iteration of the errors the estimate produces
        converges asymptotically if <= 1 (+ :data:`RHO_TOL`).
    spectral_radius_full : float
        ``ρ(I − G Q Γ S)`` on all coordinates: above 1 while ``spectral_radius`` is not,
        a tangential mode of the corrections creeps (it moves no contour error).
    predicted_ratio : float
        ``‖(I − G Q Γ S) E_0‖ / ‖E_0‖``: this program's error after one iteration.
    predicted_ratio_n : float
        The same after ``iterations`` iterations.
    iterations : int
        n of ``predicted_ratio_n``.
    status : str
        ``monotone`` (norm < 1), ``asymptotic`` (ρ <= 1 + tol, the norm is not < 1:
        ``‖E‖`` may grow by up to ``norm`` in an iteration before it falls) or
        ``divergent`` (ρ > 1 + tol: a mode grows every iteration).
    """

    gamma: float
    q_filter_hz: float | None
    norm: float
    norm_full: float
    spectral_radius: float
    spectral_radius_full: float
    predicted_ratio: float
    predicted_ratio_n: float
    iterations: int
    status: str

    def to_json(self) -> dict[str, Any]:
        return {"gamma": self.gamma, "q_filter_hz": self.q_filter_hz, "norm": self.norm, "norm_full": self.norm_full,
                "spectral_radius": self.spectral_radius, "spectral_radius_full": self.spectral_radius_full,
                "predicted_ratio": self.predicted_ratio,
                "predicted_ratio_n": self.predicted_ratio_n, "iterations": self.iterations, "status": self.status}


@dataclass(frozen=True, eq=False)
class LiftedCheck:
    """Result of :func:`check_lifted`.

    Attributes
    ----------
    model : LiftedModel
        The lifted map it was computed on.
    candidates : tuple of LiftedCandidate
        Every (Γ, Q) evaluated, in the order tried.
    chosen : LiftedCandidate
        The pick: the smallest ``norm`` of the monotone candidates; else, of
        the asymptotic ones, the smallest ``predicted_ratio_n``; else the
        smallest spectral radius (then ``converges`` is False).
    converges : bool
        The chosen candidate is monotone or asymptotic.
    monotone : bool
        The chosen candidate is monotone (``norm < 1``).
    contraction : float
        Expected per-iteration contraction of ``‖E‖``: ``norm`` when monotone, else the
        geometric mean ``predicted_ratio_n ** (1/n)`` on this program's error.
    reason : str
        Why it is not monotone / does not converge ("" when monotone).
    lead_commands : int
        The profile's lead used (``S``).
    """

    model: LiftedModel
    candidates: tuple[LiftedCandidate, ...]
    chosen: LiftedCandidate
    converges: bool
    monotone: bool
    contraction: float
    reason: str
    lead_commands: int

    @property
    def gamma(self) -> float:
        return self.chosen.gamma

    @property
    def q_filter_hz(self) -> float | None:
        return self.chosen.q_filter_hz

    def to_json(self) -> dict[str, Any]:
        m = self.model
        axes = sorted({AXIS_NAMES[int(a)] for a in m.axis}, key=AXIS_NAMES.index)
        c = self.chosen
        per_axis = {a: {"law": "p", "gains": {"gamma": c.gamma, "q_filter_hz": c.q_filter_hz},
                        "epsilon": _json_float(c.norm), "peak_hz": None, "converges": self.converges,
                        "monotone": self.monotone, "spectral_radius": _json_float(c.spectral_radius),
                        "contraction": _json_float(self.contraction), "reason": self.reason} for a in axes}
        return {"method": "lifted", "axes": per_axis,
                "lifted": {"window": list(m.window), "coordinates": m.n, "error": m.kind, "linear": m.linear,
                           "simulations": m.simulations, "build_s": m.elapsed_s,
                           "chosen": c.to_json(), "candidates": [x.to_json() for x in self.candidates]}}


def _q_matrix(model: LiftedModel, runs: NDArray[np.int64], correctable: NDArray[np.bool_], q_hz: float | None,
              lead: int, period_s: float) -> NDArray[np.float64]:
    """The shaper's linear map on the window, ``ΔU = Q S E`` (per axis the same), as an (n, n) matrix."""
    from ilcnc.learn import UpdateShaper

    k0, k1 = model.window
    w = k1 - k0
    # every command of the window needs a time stamp: the rows' stamps, interpolated in between
    ks = model.command - k0
    kk, first = np.unique(ks, return_index=True)
    t = np.interp(np.arange(w), kk, model.t_s[first])
    shaper = UpdateShaper(runs[k0:k1], correctable[k0:k1], lead, q_hz, period_s)
    # lead: E of k + lead (same cut) corrects k
    s = shaper.lead(np.eye(w))
    qm = np.zeros((w, w))
    for j in range(0, w, 3):
        du = np.zeros((w, 3))
        m = min(3, w - j)
        du[j + np.arange(m), np.arange(m)] = 1.0
        out = shaper.filter(du, t)
        qm[:, j:j + m] = out[:, :m]
    full = qm @ s
    return full[np.ix_(ks, ks)] * (model.axis[:, None] == model.axis[None, :])


def check_lifted(program: Any, profile: MachineProfile, *, gamma: float | None = None,
                 q_filter_hz: float | None = None, gammas: Sequence[float] = DEFAULT_GAMMAS,
                 q_filters_hz: Sequence[float | None] = DEFAULT_Q_FILTERS_HZ, commands: tuple[int, int] | None = None,
                 max_commands: int = DEFAULT_MAX_COMMANDS, iterations: int | None = None,
                 model: LiftedModel | None = None) -> LiftedCheck:
    """Check (and choose) Γ and the Q-filter of the command-index law by the lifted map.

    Parameters
    ----------
    program : Program
        The part program.
    profile : MachineProfile
        Machine and learning section (its ``lead_commands`` and error estimate are used).
    gamma : float, optional
        Evaluate only this Γ (default: choose among ``gammas``).
    q_filter_hz : float, optional
        Evaluate only this cut-off, Hz; 0 means no filter (default: choose among
        ``q_filters_hz``, where ``None`` is no filter).
    gammas, q_filters_hz : sequences
        Candidates.
    commands : (int, int), optional
        Window of commands (see :func:`lifted_model`).
    max_commands : int
        Largest automatic window.
    iterations : int, optional
        n of the n-step prediction (default ``learning.iterations``).
    model : LiftedModel, optional
        Reuse a model built before.

    Returns
    -------
    LiftedCheck
    """
    from ilcnc.laws import cut_runs
    from ilcnc.learn import correctable_commands

    mdl = model if model is not None else lifted_model(program, profile, commands=commands, max_commands=max_commands)
    n_it = int(profile.learning.iterations if iterations is None else iterations)
    gs = [float(gamma)] if gamma is not None else [float(x) for x in gammas]
    if q_filter_hz is not None:
        qs: list[float | None] = [None if q_filter_hz <= 0 else float(q_filter_hz)]
    else:
        qs = [None if q is None else float(q) for q in q_filters_hz]
    runs = cut_runs(program)
    corr = correctable_commands(program)
    lead = int(profile.learning.lead_commands)
    period = profile.machine.servo_period_s
    n = mdl.n
    eye = np.eye(n)
    b = mdl.normal_basis
    e0 = mdl.e0_mm
    e0n = float(np.linalg.norm(e0))
    cands: list[LiftedCandidate] = []
    with _one_blas_thread():
        for q in qs:
            qm = _q_matrix(mdl, runs, corr, q, lead, period)
            gq = mdl.g @ qm
            for gam in gs:
                cands.append(_candidate(eye - gam * gq, b, e0, e0n, gam, q, n_it))
    mono = [c for c in cands if c.status == "monotone"]
    asym = [c for c in cands if c.status == "asymptotic"]
    if mono:
        chosen = min(mono, key=lambda c: (c.norm, c.predicted_ratio_n))
        contraction, reason = chosen.norm, ""
    elif asym:
        chosen = min(asym, key=lambda c: (c.predicted_ratio_n, c.norm))
        contraction = chosen.predicted_ratio_n ** (1.0 / max(n_it, 1))
        reason = (f"not monotone: ‖(I − GQΓ)B‖₂ = {chosen.norm:.4g} >= 1 (an error can grow by that factor in one"
                  f" iteration); spectral radius {chosen.spectral_radius:.6f} <= 1 + {RHO_TOL:g}: converges"
                  " asymptotically")
    else:
        chosen = min(cands, key=lambda c: (c.spectral_radius, c.norm))
        contraction = chosen.predicted_ratio_n ** (1.0 / max(n_it, 1))
        reason = (f"divergent: spectral radius {chosen.spectral_radius:.6f} > 1 for every candidate (a mode of the"
                  f" error grows every iteration); best norm {chosen.norm:.4g}")
    if chosen.spectral_radius_full > 1.0 + RHO_TOL:
        reason = (reason + "; " if reason else "") + (
            f"a tangential mode of the corrections grows (ρ on all coordinates {chosen.spectral_radius_full:.6f}):"
            " it moves no contour error, but the corrections creep along the path")
    return LiftedCheck(mdl, tuple(cands), chosen, chosen.status != "divergent", chosen.status == "monotone",
                       float(contraction), reason, lead)


def _candidate(m: NDArray[np.float64], b: NDArray[np.float64], e0: NDArray[np.float64], e0n: float, gamma: float,
               q: float | None, n_it: int) -> LiftedCandidate:
    """Norms, spectral radii and the predicted error ratios of one iteration matrix ``m``."""
    mb = m @ b
    nb = float(np.linalg.norm(mb, 2)) if b.shape[1] else 0.0
    nf = float(np.linalg.norm(m, 2))
    rho_n = float(np.max(np.abs(np.linalg.eigvals(b.T @ mb)))) if b.shape[1] else 0.0
    rho_f = float(np.max(np.abs(np.linalg.eigvals(m))))
    if e0n > 0:
        r1 = float(np.linalg.norm(m @ e0) / e0n)
        e = e0.copy()
        for _ in range(n_it):
            e = m @ e
        rn = float(np.linalg.norm(e) / e0n)
    else:
        r1 = rn = 0.0
    status = "monotone" if nb < 1.0 else ("asymptotic" if rho_n <= 1.0 + RHO_TOL else "divergent")
    return LiftedCandidate(gamma, q, nb, nf, rho_n, rho_f, r1, rn, n_it, status)


class _one_blas_thread:
    """Run the small dense linear algebra on one BLAS thread (threadpoolctl, when installed).

    The matrices are a few hundred wide: threads gain nothing, and on a loaded machine
    OpenBLAS's spinning threads make ``eigvals`` tens of times slower.
    """

    def __enter__(self) -> None:
        try:
            from threadpoolctl import threadpool_limits
        except ImportError:  # pragma: no cover - optional
            self._ctx = None
            return
        self._ctx = threadpool_limits(1, user_api="blas")
        self._ctx.__enter__()

    def __exit__(self, *exc: object) -> None:
        if self._ctx is not None:
            self._ctx.__exit__(*exc)


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
    """Sub-step matrices of the friction loop (:func:`ilcnc.drives._friction_steps`), also without friction."""
    from ilcnc.drives import FRICTION_SUBSTEP_S, _pff_plant, _stuck, _zoh

    p = _pff_plant(drive)
    nsub = max(1, math.ceil(period_s / FRICTION_SUBSTEP_S - 1e-9))
    bf = p.bf if p.bf is not None else np.zeros(p.n)
    phih, gh = _zoh(p.a, np.column_stack([p.bu, bf]), period_s / nsub)
    cv = p.cv if p.cv is not None else np.eye(p.n)[1]
    phis, gus = _zoh(*_stuck(p.a, p.bu, cv), period_s / nsub)
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
    return kout, qout, n_limited, n_infeasible, n_guarded


_SCHEDULE_KERNELS: dict[str, Any] = {}


def _schedule_kernel() -> tuple[Any, Any, Any]:
    """The compiled kernel, its distance function and the friction step of :mod:`ilcnc.drives` (plain Python
    without numba). The loop is :mod:`ilcnc.drives`'s own (its private sub-step and matrices), so with a
    constant gain it reproduces :func:`ilcnc.drives.simulate_drives` to rounding."""
    from ilcnc._jit import njit
    from ilcnc.drives import _friction_steps

    k = _SCHEDULE_KERNELS.get("kernel")
    if k is None:
        dist = njit(cache=True)(_seg_dist_py)
        kern = njit(cache=True)(_schedule_kernel_py)
        _SCHEDULE_KERNELS["kernel"] = k = (kern, dist, _friction_steps)
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
        The settings (``lam`` with ε in mm and ΔK in (m/min)/mm).
    reference_mm, actual_before_mm, actual_after_mm : ndarray (N, 3)
        The runs.
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


def read_schedule(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Read a gain-schedule CSV ``t_s,kp`` (what :meth:`ScheduleResult.write_csv` writes).

    Returns
    -------
    t_s : ndarray (N,)
        Start of each period, s (increasing).
    kp : ndarray (N,)
        Position gain from that instant on, (m/min)/mm.

    Raises
    ------
    InputError
        No ``t_s,kp`` header, a bad or non-finite number, a gain <= 0, times
        that do not increase (``file:line: problem``).
    """
    from ilcnc.errors import InputError
    from ilcnc.fileio import read_bytes
    from ilcnc.logs import _decode_text

    p = Path(path)
    lines = _decode_text(read_bytes(p)).splitlines()
    rows = [(i + 1, ln.strip()) for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    if not rows or [c.strip().lower() for c in rows[0][1].split(",")][:2] != ["t_s", "kp"]:
        raise InputError(p, rows[0][0] if rows else 1, "a gain schedule starts with the header t_s,kp")
    t, k = [], []
    for no, ln in rows[1:]:
        cells = ln.split(",")
        try:
            ti, ki = float(cells[0]), float(cells[1])
        except (ValueError, IndexError):
            raise InputError(p, no, f"expected two numbers t_s,kp, got {ln!r}") from None
        if not (math.isfinite(ti) and math.isfinite(ki)) or ki <= 0:
            raise InputError(p, no, f"kp must be a finite gain > 0 at a finite time, got {ln!r}")
        if t and ti <= t[-1]:
            raise InputError(p, no, f"t_s {ti:g} does not increase (previous {t[-1]:g})")
        t.append(ti)
        k.append(ki)
    if not t:
        raise InputError(p, rows[0][0], "the gain schedule has no rows")
    return np.array(t), np.array(k)


def schedule_on_samples(t_s: NDArray[np.float64], kp: NDArray[np.float64], n: int, period_s: float
                        ) -> NDArray[np.float64]:
    """The gain in each of ``n`` servo periods (sample k at k·period_s): the last row at or before it (held);
    before the first row, the first gain."""
    tk = np.arange(n) * period_s
    i = np.searchsorted(np.asarray(t_s), tk + 1e-9 * period_s, side="right") - 1
    return np.asarray(kp, dtype=np.float64)[np.clip(i, 0, len(kp) - 1)]


def schedule_gains(program: Any, profile: MachineProfile, *, axis: str | None = None,
                   kp_range: tuple[float, float] | None = None, horizon: int | None = None, lam: float | None = None,
                   dk: ArrayLike | None = None, kp0: float | None = None,
                   kinematics: str | None = None) -> ScheduleResult:
    """Receding-horizon offline adjustment of a per-instant position gain of one axis (seed 001).

    Every setting left at ``None`` is taken from the profile's ``tuning.schedule`` section
    (:class:`ilcnc.profile.ScheduleTuning`; seed 001's values by default: z, [1, 2.7], Np 50, λ 0.01,
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
        λ of ``J = ε̂ᵀε̂ + λ ΔK²`` with ε̂ in mm and ΔK in (m/min)/mm (>= 0).
    dk : array_like, optional
        Candidate increments ΔK per period, (m/min)/mm. Where candidates cost the same (the gain
        cannot move the axis: at rest, or stuck in friction) the smallest |ΔK| is taken.
    kp0 : float, optional
        Gain before the first period (default: the drive's ``kp_m_min_mm``), which is
        also the fixed gain of the comparison run C1.
    kinematics : {"predicted", "eq10", "none"}, optional
        How the kinematic limits (V, A, J of the axis, eq. 2) restrict ΔK:
        ``predicted`` checks the displacement of the next period that the model
        predicts for the candidate; ``eq10`` is the paper's bound on ΔK from the
        velocity command with the velocity loop taken as 1 (its division by
        ``E_Z`` is guarded: where ``E_Z`` is ~0 the gain cannot change the
        command and gives no bound; for ``E_Z < 0`` the bounds swap); ``none``.

    Returns
    -------
    ScheduleResult
        Contour errors are measured against the reference setpoints (seed 001
        eq. 1: the closest desired position and its neighbouring segments).
    """
    from ilcnc.contour import PathGeometry, contour_error
    from ilcnc.drives import simulate_drives
    from ilcnc.plan import plan_program
    from ilcnc.program.model import MOVE_RAPID

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
    k_fixed = float(drive.kp_m_min_mm if kp0 is None else kp0)
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
                    _SCHEDULE_SEARCH, k_start, lo, hi, cands, float(lam), int(npred), period, *common, mode, *plant,
                    dist, steps)

    _k1, q1, *_ = run(k_fixed, k_fixed, k_fixed, np.zeros(1), 0, 0)
    start = min(max(k_fixed, kmin), kmax)
    k2, q2, limited, infeasible, guarded = run(start, kmin, kmax, dks, int(horizon), _KIN_MODES[kinematics])
    before = act1.copy()
    before[:, ai] = r[0, ai] + q1
    after = act1.copy()
    after[:, ai] = r[0, ai] + q2
    mv = np.maximum(np.asarray(ref.move, dtype=np.int64), 0)
    feed = (np.asarray(ref.move) >= 0) & (program.moves.kind[mv] != MOVE_RAPID)
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
                          time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------------
# What `ilcnc tune` calls
# ---------------------------------------------------------------------------------------------

#: Methods of :func:`tune_profile`.
METHODS = ("auto", "time", "lifted", "schedule")


def _sig(v: float, digits: int = 6) -> float:
    """``v`` rounded to ``digits`` significant digits (what is written into the profile)."""
    return float(f"{v:.{digits}g}")


def _fmt(v: float | None, spec: str = ".4g") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "∞" if v is not None and v > 0 else "–"
    return format(v, spec)


@dataclass(eq=False)
class TuneReport:
    """What ``ilcnc tune`` prints and writes.

    Attributes
    ----------
    method : str
        ``time``, ``lifted`` or ``schedule`` (``auto`` resolved).
    profile_path : Path
    program_path : Path or None
    result : TuneResult, LiftedCheck or ScheduleResult
    updates : dict
        Dotted profile keys and the values ``--write`` stores (empty for a schedule
        or when nothing converged).
    written : Path or None
        The profile written (``write=True`` and something to write).
    schedule_csv : Path or None
        The schedule CSV written (method ``schedule`` with ``write=True``).
    note : str
        One line: what was (not) written and why.
    """

    method: str
    profile_path: Path
    program_path: Path | None
    result: Any
    updates: dict[str, Any] = field(default_factory=dict)
    written: Path | None = None
    schedule_csv: Path | None = None
    note: str = ""

    @property
    def converges(self) -> bool | None:
        r = self.result
        if isinstance(r, TuneResult):
            return r.converges
        if isinstance(r, LiftedCheck):
            return r.converges
        return None

    def to_json(self) -> dict[str, Any]:
        """DESIGN.md's ``tune --json`` object plus the method's details.

        ``{"axes": {axis: {"law", "gains", "epsilon", "peak_hz", "converges", ...}}, "method", "profile",
        "program", "updates", "written", "schedule_csv", "note", ...}``. For ``time`` ``epsilon`` is ε on the
        band and ``peak_hz`` where it peaks; for ``lifted`` (law ``p``, the same entry for every axis: G couples
        them) ``epsilon`` is ``‖(I − GQΓ)B‖₂`` and ``peak_hz`` is null, details under ``"lifted"``; for
        ``schedule`` they are null and the figures are under ``"schedule"``. inf/NaN are written as null.
        """
        out = self.result.to_json()
        out.update({"method": self.method, "profile": str(self.profile_path),
                    "program": str(self.program_path) if self.program_path else None,
                    "updates": {k: v for k, v in self.updates.items()},
                    "written": str(self.written) if self.written else None,
                    "schedule_csv": str(self.schedule_csv) if self.schedule_csv else None, "note": self.note})
        return out

    def columns(self) -> tuple[str, ...]:
        """Header of :meth:`rows`."""
        if self.method == "time":
            return ("axis", "law", "K_Pl", "K_Il 1/s", "K_Dl s", "lead η", "ε", "peak Hz", "converges", "note")
        if self.method == "lifted":
            return ("Γ", "Q-filter Hz", "‖(I−GQΓ)B‖₂", "ρ", "‖E₁‖/‖E₀‖", "‖Eₙ‖/‖E₀‖", "status", "")
        return ("axis", "K_p fixed", "K_p min", "K_p mean", "K_p max", "MSE before µm²", "MSE after µm²", "cut")

    def rows(self) -> list[tuple[str, ...]]:
        """Rows of strings for a table (``rich.table.Table(*report.columns())``)."""
        r = self.result
        if isinstance(r, TuneResult):
            out = []
            for a in r.axes.values():
                note = a.reason or "; ".join(a.notes)
                out.append((a.axis, "pid_ace", _fmt(a.kp), _fmt(a.ki), _fmt(a.kd), str(a.lead_samples),
                            _fmt(a.epsilon), _fmt(a.peak_hz), "yes" if a.converges else "NO", note))
            return out
        if isinstance(r, LiftedCheck):
            out = []
            for c in r.candidates:
                out.append((_fmt(c.gamma), "none" if c.q_filter_hz is None else _fmt(c.q_filter_hz), _fmt(c.norm, ".5f"),
                            _fmt(c.spectral_radius, ".6f"), _fmt(c.predicted_ratio, ".3f"), _fmt(c.predicted_ratio_n, ".3f"),
                            c.status, "← chosen" if c is r.chosen else ""))
            return out
        s: ScheduleResult = r
        return [(s.axis, _fmt(s.kp_fixed), _fmt(float(s.kp.min())), _fmt(float(s.kp.mean())), _fmt(float(s.kp.max())),
                 _fmt(s.mse_before_um2), _fmt(s.mse_after_um2), f"{s.reduction:.1%}")]


def _time_updates(res: TuneResult, profile: MachineProfile) -> dict[str, Any]:
    kp = {a: _sig(d.kp) for a, d in res.axes.items()}
    kd = {a: _sig(d.kd) for a, d in res.axes.items()}
    ki: Any = {a: _sig(d.ki) for a, d in res.axes.items()} if res.ki_mode == "free" else 0.0
    if profile.learning.law == "pid_ace":
        return {"learning.gains.kp": kp, "learning.gains.ki": ki, "learning.gains.kd": kd,
                "learning.gains.lead_samples": int(res.lead_samples)}
    return {"learning.law": "pid_ace",
            "learning.gains": {"kp": kp, "ki": ki, "kd": kd, "lead_samples": int(res.lead_samples)}}


def tune_profile(profile_path: str | Path, *, method: str = "auto", program: Any = None, write: bool = False,
                 out: str | Path | None = None, f_min_hz: float = 0.0, f_max_hz: float = DEFAULT_F_MAX_HZ,
                 lead_max: int = 3, fix_ki: bool = True, gamma: float | None = None, q_filter_hz: float | None = None,
                 commands: tuple[int, int] | None = None, max_commands: int = DEFAULT_MAX_COMMANDS,
                 axis: str | None = None, kp_range: tuple[float, float] | None = None, horizon: int | None = None,
                 lam: float | None = None, dk: ArrayLike | None = None, kinematics: str | None = None,
                 schedule_csv: str | Path | None = None) -> TuneReport:
    """Design or check the learning gains of a profile (``ilcnc tune``).

    Parameters
    ----------
    profile_path : str or Path
        The profile YAML.
    method : {"auto", "time", "lifted", "schedule"}
        ``auto``: ``time`` for ``learning.law: pid_ace``, ``lifted`` for ``p``
        (needs ``program``). ``schedule`` needs ``program``.
    program : str, Path or Program, optional
        The part program (``lifted``, ``schedule``).
    write : bool
        Store the result: the gains with :func:`ilcnc.profile_edit.update_profile`
        (comments kept) -- ``learning.gains.kp/ki/kd/lead_samples`` per axis
        (``time``; the law is set to ``pid_ace`` if it was another), or
        ``learning.gains.gamma`` and ``learning.q_filter_hz`` (``lifted``);
        only gains that converge are written. ``schedule`` writes the CSV
        ``t_s,kp`` instead (``schedule_csv``, default next to the program:
        ``<stem>.kp-<axis>.csv``).
    out : str or Path, optional
        Write the profile here instead of in place.
    f_min_hz, f_max_hz, lead_max, fix_ki :
        See :func:`design_time_domain`.
    gamma, q_filter_hz, commands, max_commands :
        See :func:`check_lifted`.
    axis, kp_range, horizon, lam, dk, kinematics :
        See :func:`schedule_gains`; ``None`` (the default): the profile's ``tuning.schedule`` values.
    schedule_csv : str or Path, optional
        Where ``write=True`` puts the schedule.

    Returns
    -------
    TuneReport

    Raises
    ------
    ValueError
        Unknown method, or a method that needs a program without one, or a law
        there is no method for (``second_order``: its condition (3) is checked
        by ``learn``).
    ProfileError, InputError
        From reading the profile or the program, or from writing.
    """
    from ilcnc.profile import load_profile

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    ppath = Path(profile_path)
    profile = load_profile(ppath)
    prog = None
    prog_path: Path | None = None
    if program is not None:
        if isinstance(program, (str, Path)):
            from ilcnc.program import read_program

            prog_path = Path(program)
            prog = read_program(prog_path, default_units=profile.machine.units)
        else:
            prog = program
            prog_path = Path(prog.path) if getattr(prog, "path", None) else None
    m = method
    if m == "auto":
        law = profile.learning.law
        if law == "pid_ace":
            m = "time"
        elif law == "p":
            m = "lifted"
        else:
            raise ValueError(f"learning.law {law}: tune has no method for it (its condition (3) is checked by learn);"
                             " use --method time to design a pid_ace law instead")
    if m in ("lifted", "schedule") and prog is None:
        raise ValueError(f"method {m} needs a part program (the lifted map and the schedule are per program)")
    report = TuneReport(m, ppath, prog_path, None)
    if m == "time":
        res = design_time_domain(profile, f_min_hz=f_min_hz, f_max_hz=f_max_hz, lead_max=lead_max, fix_ki=fix_ki)
        report.result = res
        if res.converges:
            report.updates = _time_updates(res, profile)
            eps = ", ".join(f"{a} {d.epsilon:.3g}" for a, d in res.axes.items())
            note = f"tune: time domain {res.f_min_hz:g}-{res.f_max_hz:g} Hz, lead {res.lead_samples}, eps {eps}"
        else:
            bad = ", ".join(a for a, d in res.axes.items() if not d.converges)
            report.note = f"not written: no convergent gains on axis {bad}"
    elif m == "lifted":
        chk = check_lifted(prog, profile, gamma=gamma, q_filter_hz=q_filter_hz, commands=commands,
                           max_commands=max_commands)
        report.result = chk
        c = chk.chosen
        if chk.converges:
            report.updates = {"learning.gains.gamma": _sig(c.gamma), "learning.q_filter_hz": c.q_filter_hz}
            name = prog_path.name if prog_path else "the program"
            note = (f"tune: lifted map of {name} (commands {chk.model.window[0]}-{chk.model.window[1] - 1}),"
                    f" {c.status}, norm {c.norm:.4g}, spectral radius {c.spectral_radius:.6f}")
        else:
            report.note = f"not written: {chk.reason}"
    else:
        sch = schedule_gains(prog, profile, axis=axis, kp_range=kp_range, horizon=horizon, lam=lam, dk=dk,
                             kinematics=kinematics)
        report.result = sch
        if write:
            if schedule_csv is None:
                base = prog_path if prog_path is not None else Path("program")
                schedule_csv = base.with_name(f"{base.stem}.kp-{sch.axis}.csv")
            protect = [ppath] + ([prog_path] if prog_path else [])
            report.schedule_csv = sch.write_csv(schedule_csv, protect=protect)
            report.note = f"schedule written to {report.schedule_csv}"
        return report
    if write and report.updates:
        from ilcnc.profile_edit import update_profile

        protect = [prog_path] if prog_path else []
        report.written = update_profile(ppath, report.updates, out=out, note=note, protect=protect)
        report.note = f"written to {report.written}"
    elif report.updates and not report.note:
        report.note = "not written (use --write)"
    return report

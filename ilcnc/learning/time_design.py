"""Learning gains of the time-domain PID-type law (seed 000): the convergence factor ε and its minimax design.

``time`` -- the time-domain PID-type law of seed 000 (:func:`design_time_domain`)
    With ``T(z)`` the exact discrete closed loop reference → position of an
    axis (:func:`ilcnc.vcnc.discrete.discrete_model`, convention: ``q[k]`` depends on
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

Nothing here prints; :mod:`ilcnc.learning.tune` is what ``ilcnc tune`` calls.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ilcnc.jsonout import json_float
from ilcnc.profile.sections import MachineProfile, PFfFrictionDrive

__all__ = [
    "DEFAULT_F_MAX_HZ",
    "AxisDesign",
    "EpsilonCurve",
    "LeadOption",
    "TuneResult",
    "design_time_domain",
    "epsilon_of",
    "frequency_grid",
    "learning_response"
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
    from ilcnc.vcnc.discrete import discrete_model

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
        return {"law": "pid_ace", "gains": self.gains(), "epsilon": json_float(self.epsilon),
                "peak_hz": json_float(self.peak_hz), "converges": self.converges, "reason": self.reason,
                "best_lead": self.best_lead,
                "by_lead": [{"lead_samples": o.lead, "kp": o.kp, "ki": o.ki, "kd": o.kd,
                             "epsilon": json_float(o.epsilon), "peak_hz": json_float(o.peak_hz)}
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
    from ilcnc.vcnc.discrete import DriveModelError

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



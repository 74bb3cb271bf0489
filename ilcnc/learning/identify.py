"""Drive models from measured step responses: least-squares fits and fit quality.

A shop rarely knows its drive parameters; this module fits the drive models
of :mod:`ilcnc.profile.schema` to a measured step response, reports how well the
data determine them, and returns the profile keys to store
(:meth:`Identification.profile_updates`, written by
:func:`ilcnc.profile.edit.update_profile`).

Models (``model=``)
-------------------
``sopdt`` (seed 004 §2.1)
    Velocity drive ``V/U = K·ω0²·e^{−s·Td}/(s² + 2ζω0 s + ω0²)``; parameters
    ``gain`` (K), ``omega0_rad_s``, ``zeta``, ``delay_s``. With a velocity
    signal, ``u`` is the commanded velocity and ``y`` the measured velocity
    (mm/s); with a position signal, ``u`` is the commanded position and
    ``y`` the actual position (mm): the position is the integral of the
    drive's velocity, the drive fed with the velocity the commanded positions
    imply, ``(u[k] − u[k−1])/T`` (exactly what the virtual CNC does). If the
    profile's drive of the axis has a position loop (``position_gain_1_s``),
    a position signal is fitted with that loop closed around the drive.
``first_order_delay``
    Closed position loop ``K·e^{−s·Td}/(T s + 1)``; parameters ``gain``,
    ``time_constant_s``, ``delay_s``. Position signal: commanded and actual
    position; velocity signal: commanded and actual velocity (the same
    transfer function).
``mass_damper`` (seed 000 §II.D)
    Axis ``m·q̈ + c·q̇ = u`` under the profile axis's known position PID (the
    drive of ``axes.<axis>`` must be ``mass_damper_pid``, or ``pid=`` given);
    parameters ``mass_v_s2_mm``, ``damping_v_s_mm``. The fitted response is
    the closed loop's to the commanded position. Note that only the sum
    ``c + K_D`` shapes the fast response, so with a large ``K_D`` (seed 000:
    8 against c = 0.144) the damping is determined only to a few per cent
    even from clean data.

Every model response is computed with the simulator's own discretisation
(:func:`ilcnc.vcnc.drives.axis_response`: exact zero-order hold, exact fractional
dead time), so identified parameters reproduce the measurement when the
virtual CNC runs them. The one response the simulator has no use for, the
sampled *velocity* of the SOPDT drive, is discretised here the same way
(exact ZOH of the state-space model, modified z-transform for the fractional
dead time); velocities are the drive's velocity *at* the sample instants. A
velocity obtained by differencing positions is a mean over the preceding
period, half a period late: fit the positions instead (``signal="position"``).

Timing conventions: ``u[k]`` is held from ``t_k`` to ``t_{k+1}``; the
response starts at rest; a constant offset of ``y`` is fitted along (sensor
zero, initial position) and not reported as a parameter.

Fitting
-------
``scipy.optimize.least_squares`` (trust-region reflective, bounds) on the
sum of squared residuals ``y − ŷ``. The parameters that enter linearly (the
gain K of sopdt and first_order_delay, and the offset) are eliminated in
closed form at every evaluation (variable projection), so the nonlinear
search runs over 2–3 parameters. Starting points: the lag of the response
behind the command (the shift of ``u`` that best explains ``y``) gives the
time scale; a small grid of damping ratios and delay fractions around it is
evaluated and the least-squares search starts from the best three; the best
result wins. A final central-difference Jacobian over all parameters gives
the covariance ``s²·(JᵀJ)⁻¹`` (``s²`` = residual variance), the standard
errors and 95 % confidence intervals (Student t). They assume white noise;
coloured noise (drift, vibration) makes them optimistic.

Fit quality and warnings
------------------------
``fit_rms`` (units of ``y``) and ``r2`` (1 − SSR/SST) are reported. The
warnings (each one line, starting with a keyword):

* ``poor fit``: R² < 0.98, or the residual RMS exceeds 5 % of the response's
  dynamic part (the largest difference between the fitted response and a
  static gain) and twice the noise;
* ``systematic misfit``: the residual RMS exceeds twice the noise estimated
  from the data (MAD of second differences) — unmodelled dynamics;
* ``noisy``: the noise is more than 5 % of the dynamic part;
* ``too short``: the record ends less than the dead time + 5 dominant time
  constants after the step;
* ``saturated``: ``y`` sits exactly at its extreme over a run of samples
  while it is noisy elsewhere (a clipped signal);
* ``poorly determined``: a 95 % interval wider than ±25 % of its value;
* ``at bound``: a parameter ended on a bound of the search (e.g. no dead
  time: ``delay_s`` = 0, one-sided interval);
* ``gain``: K is more than 5 % away from 1 (check units and the step size);
* ``sampling``: the record's period differs from the profile's servo period
  or its time stamps jitter by more than 5 %.

A record without a step (``u`` constant, or ``y`` not responding above its
noise) raises :class:`ilcnc.errors.InputError` ``no step in the data``.

Gain normalisation
------------------
A CNC velocity loop reaches its commanded velocity and a position loop its
commanded position, so a fitted K within :data:`GAIN_TOLERANCE` (5 %) of 1 is
a scale error of the measurement (or noise), and
:meth:`Identification.profile_updates` writes ``gain: 1.0``; the fitted K is
still reported in ``parameters``. Further from 1 it is written as fitted,
with a ``gain`` warning. (Seed 004 prints K = 1.09e-4, which no unit
conversion makes a velocity gain: the profiles use 1.)
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import expm
from scipy.optimize import least_squares
from scipy.signal import lfilter
from scipy.special import stdtrit

from ilcnc.errors import InputError
from ilcnc.learning.identification import GAIN_TOLERANCE, MODEL_ALIASES, MODELS, PARAMETERS, SIGNALS, Identification
from ilcnc.profile.sections import FirstOrderDelayDrive, MachineProfile, MassDamperPidDrive, SopdtDrive
from ilcnc.vcnc.discrete import DriveModelError
from ilcnc.vcnc.drives import axis_response

__all__ = ["identify_step", "sopdt_velocity_response"]

_DELAY_SNAP = 1e-9
_MIN_SAMPLES = 20


# --------------------------------------------------------------------------
# Model responses
# --------------------------------------------------------------------------


def _zoh(a: NDArray[np.float64], b: NDArray[np.float64], dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(e^{A dt}, ∫_0^dt e^{Aσ}dσ·b)`` by one matrix exponential."""
    n = a.shape[0]
    m = np.zeros((n + 1, n + 1))
    m[:n, :n] = a * dt
    m[:n, n] = b * dt
    e = expm(m)
    return e[:n, :n], e[:n, n]


def _split_delay(delay_s: float, period_s: float) -> tuple[int, float]:
    tau = delay_s / period_s
    d = math.floor(tau + _DELAY_SNAP)
    f = tau - d
    return d, (0.0 if f < _DELAY_SNAP else f)


def sopdt_velocity_response(
    u: ArrayLike, omega0_rad_s: float, zeta: float, delay_s: float, period_s: float, gain: float = 1.0
) -> NDArray[np.float64]:
    """Sampled velocity of the SOPDT drive for a commanded velocity held over each period.

    Parameters
    ----------
    u : array_like, shape (N,)
        Commanded velocity ``u[k]``, held from ``t_k`` to ``t_{k+1}``; the
        drive starts at rest at ``gain·u[0]``.
    omega0_rad_s, zeta, delay_s : float
        ω0 (rad/s), ζ, dead time Td (s).
    period_s : float
        Sample period T, s.
    gain : float
        Static gain K.

    Returns
    -------
    ndarray, shape (N,)
        The drive's velocity at ``t_k`` (exact: zero-order hold and a dead
        time ``Td = (d + f)·T`` by the modified z-transform, as
        :mod:`ilcnc.vcnc.drives` discretises every model).
    """
    uu = np.asarray(u, dtype=float)
    if uu.size == 0:
        return uu.copy()
    w, z, t = float(omega0_rad_s), float(zeta), float(period_s)
    a = np.array([[0.0, 1.0], [-w * w, -2.0 * z * w]])
    b = np.array([0.0, w * w])
    d, f = _split_delay(float(delay_s), t)
    phi, gam = _zoh(a, b, t)
    if f == 0.0:
        g0, g1 = gam, np.zeros(2)
    else:
        _, g_f = _zoh(a, b, f * t)
        phi_r, g_r = _zoh(a, b, (1.0 - f) * t)
        g0, g1 = g_r, phi_r @ g_f
    # y = c (zI − Φ)⁻¹ (g0 z^{-d} + g1 z^{-d-1}) u with c = [1, 0]
    num = np.zeros(d + 4)
    num[d + 1] += g0[0]
    num[d + 2] += phi[0, 1] * g0[1] - phi[1, 1] * g0[0]
    num[d + 2] += g1[0]
    num[d + 3] += phi[0, 1] * g1[1] - phi[1, 1] * g1[0]
    den = np.array([1.0, -(phi[0, 0] + phi[1, 1]), phi[0, 0] * phi[1, 1] - phi[0, 1] * phi[1, 0]])
    u0 = uu[0]
    return gain * (u0 + lfilter(num, den, uu - u0))


@dataclass
class _Spec:
    """One fitting problem: the model's nonlinear parameters and its response."""

    names: tuple[str, ...]  # nonlinear parameter names (profile keys)
    linear_gain: bool  # K enters linearly (eliminated by variable projection)
    lower: NDArray[np.float64]
    upper: NDArray[np.float64]
    response: Callable[[NDArray[np.float64]], NDArray[np.float64]]  # unit-gain deviation response
    candidates: list[NDArray[np.float64]]
    tau: Callable[[NDArray[np.float64]], float]  # dominant time constant
    delay_index: int | None  # index of delay_s in names
    typical: NDArray[np.float64]  # typical magnitudes (search scaling, finite-difference steps)


def _sopdt_tau(w: float, z: float) -> float:
    if z < 1.0:
        return 1.0 / (z * w)
    return 1.0 / (w * (z - math.sqrt(z * z - 1.0)))


def _mass_damper_tau(m: float, c: float, kp: float, ki: float, kd: float) -> float:
    """Slowest closed-loop pole that carries at least 10 % of a unit step (the slow PID poles do not)."""
    num = np.array([kd, kp, ki])
    den = np.array([m, c + kd, kp, ki])
    poles = np.roots(den)
    dden = np.polyder(den)
    taus = []
    for p in poles:
        if abs(p) < 1e-300:
            continue
        res = np.polyval(num, p) / (p * np.polyval(dden, p))
        if abs(res) >= 0.1 and p.real < 0:
            taus.append(-1.0 / p.real)
    if not taus:
        stable = [p for p in poles if p.real < 0]
        return -1.0 / max(p.real for p in stable) if stable else math.inf
    return max(taus)


def _lag(du: NDArray[np.float64], y: NDArray[np.float64], period_s: float) -> float:
    """Shift of the command that best explains the response (least squares), s: the time scale of the response."""
    n = du.shape[0]
    top = max(2, n // 3)
    shifts = np.unique(np.concatenate([[0], np.round(np.geomspace(1, top, 48)).astype(int)]))
    yc = y - y.mean()
    best_j, best = 0, -1.0
    for j in shifts:
        us = np.concatenate([np.full(j, du[0]), du[: n - j]]) if j else du
        uc = us - us.mean()
        den = float(uc @ uc)
        score = float(uc @ yc) ** 2 / den if den > 0 else 0.0
        if score > best:
            best, best_j = score, int(j)
    return max(best_j, 1) * period_s


def _build_spec(
    model: str,
    signal: str,
    du: NDArray[np.float64],
    period_s: float,
    duration_s: float,
    lag_s: float,
    pid: tuple[float, float, float] | None,
    kv: float | None,
) -> _Spec:
    t = period_s
    s = max(lag_s, 2.0 * t)
    if model == "sopdt":
        names = ("omega0_rad_s", "zeta", "delay_s")
        lower = np.array([0.1 / duration_s, 0.05, 0.0])
        upper = np.array([20.0 / t, 20.0, duration_s / 2.0])
        if signal == "velocity":

            def resp(th: NDArray[np.float64]) -> NDArray[np.float64]:
                return sopdt_velocity_response(du, th[0], th[1], th[2], t)

        elif kv is None:

            def resp(th: NDArray[np.float64]) -> NDArray[np.float64]:
                return axis_response(SopdtDrive(omega0_rad_s=th[0], zeta=th[1], gain=1.0, delay_s=th[2]), du, t)

        else:
            names = ("gain", "omega0_rad_s", "zeta", "delay_s")
            lower = np.array([1e-3, *lower])
            upper = np.array([100.0, *upper])

            def resp(th: NDArray[np.float64]) -> NDArray[np.float64]:
                drive = SopdtDrive(omega0_rad_s=th[1], zeta=th[2], gain=th[0], delay_s=th[3], position_gain_1_s=kv)
                return axis_response(drive, du, t)

        cands = []
        for z in (0.5, 0.7, 1.0, 1.5, 2.5):
            for fd in (0.0, 0.25, 0.5, 0.75):
                for mult in (1.0, 2.0):
                    td = fd * s
                    w = mult * 2.0 * z / max(s - td, t)
                    th = np.array([w, z, td])
                    cands.append(np.array([1.0, *th]) if kv is not None else th)
        off = 1 if kv is not None else 0

        def tau(th: NDArray[np.float64]) -> float:
            return _sopdt_tau(th[off], th[off + 1])

        typical = np.array([*([1.0] if kv is not None else []), 2.0 / s, 1.0, t])
        return _Spec(names, kv is None, lower, upper, resp, cands, tau, off + 2, typical)
    if model == "first_order_delay":
        names = ("time_constant_s", "delay_s")
        lower = np.array([t / 100.0, 0.0])
        upper = np.array([10.0 * duration_s, duration_s / 2.0])

        def resp(th: NDArray[np.float64]) -> NDArray[np.float64]:
            return axis_response(FirstOrderDelayDrive(time_constant_s=th[0], delay_s=th[1], gain=1.0), du, t)

        cands = [
            np.array([mult * max(s - fd * s, t), fd * s]) for fd in (0.0, 0.2, 0.4, 0.6, 0.8) for mult in (1.0, 1.45)
        ]
        return _Spec(names, True, lower, upper, resp, cands, lambda th: float(th[0]), 1, np.array([s, t]))
    # mass_damper
    assert pid is not None
    kp, ki, kd = pid
    names = ("mass_v_s2_mm", "damping_v_s_mm")
    # c may go negative in the search as long as c + K_D > 0: next to a large K_D the data hardly tell c
    # from 0, and a bound at 0 would stall the search in the long valley m/(c + K_D) = const
    lower = np.array([1e-12, -0.999 * kd])
    upper = np.array([1e6, 1e6])

    def resp(th: NDArray[np.float64]) -> NDArray[np.float64]:
        drive = MassDamperPidDrive(mass_v_s2_mm=th[0], damping_v_s_mm=th[1], kp=kp, ki=ki, kd=kd)
        return axis_response(drive, du, t)

    cands = []
    for tau_f in (0.7, 1.0, 1.5):
        tau_c = tau_f * s
        if kd > 0:
            for cf in (0.0, 0.02, 0.1, 0.5):
                c = cf * kd
                cands.append(np.array([tau_c * (c + kd), c]))
        if kp > 0:
            m = kp * tau_c * tau_c
            for zf in (0.5, 1.0, 2.0):
                cands.append(np.array([m, max(0.0, 2.0 * zf * math.sqrt(kp * m) - kd)]))
    if not cands:
        cands.append(np.array([1.0, 1.0]))

    def tau_md(th: NDArray[np.float64]) -> float:
        return _mass_damper_tau(th[0], th[1], kp, ki, kd)

    typical = np.array([max(float(c[0]) for c in cands), max(kd, *(float(c[1]) for c in cands), 1e-9)])
    return _Spec(names, False, lower, upper, resp, cands, tau_md, None, typical)


# --------------------------------------------------------------------------
# Data checks
# --------------------------------------------------------------------------


def _noise_rms(y: NDArray[np.float64]) -> float:
    """White-noise level from the MAD of second differences (robust to steps and smooth motion)."""
    if y.shape[0] < 5:
        return 0.0
    d2 = y[2:] - 2.0 * y[1:-1] + y[:-2]
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


def _longest_run(mask: NDArray[np.bool_]) -> tuple[int, int]:
    """Length and start of the longest run of True."""
    if not mask.any():
        return 0, 0
    m = np.concatenate([[0], mask.astype(np.int8), [0]])
    d = np.diff(m)
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1)
    lengths = ends - starts
    i = int(np.argmax(lengths))
    return int(lengths[i]), int(starts[i])


def _saturation(
    y: NDArray[np.float64], y_fit: NDArray[np.float64], dyn: float, period_s: float, y_name: str
) -> str | None:
    """A run of samples exactly at the extreme of ``y`` where the rest of the record is noisy, and the fit disagrees.

    A settled noise-free (or coarsely quantised) signal also repeats its last
    value: only when the rest of the record shows noise well above the
    signal's resolution is an exactly flat run implausible, and only when the
    fitted response leaves the run systematically (it would go beyond the
    clip) is it a clip.
    """
    n = y.shape[0]
    need = max(5, int(0.01 * n))
    steps = np.abs(np.diff(y))
    nonzero = steps[steps > 0]
    quantum = float(nonzero.min()) if nonzero.size else 0.0
    for extreme, word, sign in ((float(y.max()), "maximum", 1.0), (float(y.min()), "minimum", -1.0)):
        tol = 1e-12 * max(1.0, abs(extreme))
        at = np.abs(y - extreme) <= tol
        length, start = _longest_run(at)
        if length < need:
            continue
        rest = np.ones(n, dtype=bool)
        rest[start: start + length] = False
        noise = _noise_rms(y[rest])
        if not (noise > 2.0 * quantum and noise > 1e-6 * dyn):
            continue
        beyond = sign * float(np.mean(y_fit[start: start + length] - extreme))
        if beyond > max(2.0 * noise / math.sqrt(length), 1e-4 * dyn):
            return (
                f"saturated: {y_name} sits exactly at its {word} {extreme:.6g} for {length} samples"
                f" ({length * period_s:.3g} s) while it is noisy elsewhere: a clipped or limited signal"
                " (current, velocity or ADC limit); the fit cannot see the true response there"
            )
    return None


def _onset(u: NDArray[np.float64]) -> int | None:
    """Index of the first change of the command, or None when it never changes."""
    scale = max(1.0, float(np.max(np.abs(u))))
    noise = _noise_rms(u)
    tol = 1e-9 * scale + 5.0 * noise
    moved = np.flatnonzero(np.abs(u - u[0]) > tol)
    return int(moved[0]) if moved.size else None


def _moving_average(y: NDArray[np.float64], w: int) -> NDArray[np.float64]:
    if w <= 1 or y.shape[0] < w:
        return y
    c = np.cumsum(np.concatenate([[0.0], y]))
    out = (c[w:] - c[:-w]) / w
    return np.concatenate([np.full(w - 1, out[0]), out])


# --------------------------------------------------------------------------
# The fit
# --------------------------------------------------------------------------


def _single_thread() -> contextlib.AbstractContextManager[object]:
    """Limit BLAS to one thread during a fit.

    A fit evaluates the model a few hundred times, each with a few 3×3 matrix
    exponentials (the exact discretisation); a multi-threaded BLAS spends
    milliseconds per tiny product synchronising its threads (100× the work
    on a loaded 2-core machine). Without threadpoolctl this is a no-op.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


class _Counter:
    def __init__(self) -> None:
        self.n = 0


def _projected(
    g: NDArray[np.float64], y: NDArray[np.float64], linear_gain: bool
) -> tuple[NDArray[np.float64], float, float]:
    """Residual, gain and offset with the linear parameters solved in closed form."""
    if linear_gain:
        gm = float(g.mean())
        ym = float(y.mean())
        gc = g - gm
        den = float(gc @ gc)
        k = float(gc @ (y - ym)) / den if den > 0 else 0.0
        off = ym - k * gm
        return y - off - k * g, k, off
    off = float(np.mean(y - g))
    return y - off - g, 1.0, off


def identify_step(
    t_s: ArrayLike,
    u: ArrayLike | float,
    y: ArrayLike,
    *,
    model: str,
    signal: str = "velocity",
    profile: MachineProfile | None = None,
    axis: str | None = None,
    period_s: float | None = None,
    step_time_s: float | None = None,
    pid: tuple[float, float, float] | None = None,
    source: str | Path | None = None,
    u_name: str = "u",
    y_name: str = "y",
) -> Identification:
    """Fit a drive model to a measured step response.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Sample times, s (increasing, constant period).
    u : array_like, shape (N,), or float
        The command: commanded velocity (mm/s) for a velocity signal,
        commanded position (mm) for a position signal. A number instead is
        the size of a step applied at ``step_time_s``: a velocity step (mm/s)
        for sopdt (with a position signal the commanded positions are the
        ramp it implies; inside the profile's position loop it is a position
        step, mm), else a step of the signal's quantity (mm/s or mm).
    y : array_like, shape (N,)
        The measured response (mm/s or mm).
    model : {"sopdt", "mass_damper", "first_order_delay"}
        The drive model (``"mass_damper_pid"`` is accepted for ``"mass_damper"``).
    signal : {"velocity", "position"}
        What ``u`` and ``y`` are.
    profile : MachineProfile, optional
        Gives the axis's known loop (mass_damper: its PID; sopdt with a
        position signal: ``position_gain_1_s``) and the servo period the
        sampling is compared with.
    axis : str, optional
        Axis name (``"x"``, ``"y"``, ``"z"``).
    period_s : float, optional
        Sample period, s (default: the median step of ``t_s``).
    step_time_s : float, optional
        When ``u`` is a step size: the time of the step (default: t = 0 when
        the record covers it, else its first sample).
    pid : (kp, ki, kd), optional
        PID gains for mass_damper without a profile (V/mm, V/(mm·s), V·s/mm).
    source : str or Path, optional
        File the data came from (error messages, plots, notes).
    u_name, y_name : str
        Names of the command and the response in messages (e.g. ``x_ref``, ``x_act``).

    Returns
    -------
    Identification

    Raises
    ------
    InputError
        ``no step in the data`` (the command does not change or the response
        does not follow it), too few samples, non-finite or non-increasing
        time, or a missing PID for mass_damper.
    ValueError
        Unknown model or signal, arrays of different shapes.
    """
    with _single_thread():
        return _identify_step(
            t_s, u, y, model=model, signal=signal, profile=profile, axis=axis, period_s=period_s,
            step_time_s=step_time_s, pid=pid, source=source, u_name=u_name, y_name=y_name,
        )


def _identify_step(
    t_s: ArrayLike,
    u: ArrayLike | float,
    y: ArrayLike,
    *,
    model: str,
    signal: str,
    profile: MachineProfile | None,
    axis: str | None,
    period_s: float | None,
    step_time_s: float | None,
    pid: tuple[float, float, float] | None,
    source: str | Path | None,
    u_name: str,
    y_name: str,
) -> Identification:
    clock = time.perf_counter()
    model = MODEL_ALIASES.get(model, model)
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r} (known: {', '.join(MODELS)})")
    if signal not in SIGNALS:
        raise ValueError(f"unknown signal {signal!r} (known: {', '.join(SIGNALS)})")
    src = str(source) if source is not None else None
    t = np.asarray(t_s, dtype=float).ravel()
    yy = np.asarray(y, dtype=float).ravel()
    if t.shape != yy.shape:
        raise ValueError(f"t_s and y must have the same length, got {t.shape[0]} and {yy.shape[0]}")
    n = t.shape[0]
    if n < _MIN_SAMPLES:
        raise InputError(src, None, f"too few samples for a fit ({n}; at least {_MIN_SAMPLES})")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(yy))):
        raise InputError(src, None, f"t_s or {y_name} contains NaN or infinite values")
    dt = np.diff(t)
    if np.any(dt <= 0):
        k = int(np.flatnonzero(dt <= 0)[0])
        raise InputError(src, None, f"time does not increase at sample {k + 1} ({t[k]:.6g} s then {t[k + 1]:.6g} s)")
    med = float(np.median(dt))
    period = float(period_s) if period_s is not None else med
    if not period > 0:
        raise InputError(None, None, f"the sample period must be a number of seconds > 0, got {period_s}")
    warnings: list[str] = []
    jitter = float(np.max(np.abs(dt - med))) / med
    if jitter > 0.05:
        warnings.append(
            f"sampling: time steps vary by up to {jitter:.0%} of the period {med * 1e3:.4g} ms; the fit assumes a constant period"
        )
    if profile is not None and abs(period / profile.machine.servo_period_s - 1.0) > 0.01:
        warnings.append(
            f"sampling: the record's period {period * 1e3:.4g} ms differs from the profile's servo period"
            f" {profile.machine.servo_period_s * 1e3:.4g} ms (the fitted parameters are continuous-time and still apply)"
        )

    drive = profile.axes[axis].drive if (profile is not None and axis is not None and axis in profile.axes) else None
    fixed: dict[str, float] = {}
    kv: float | None = None
    if model == "mass_damper":
        if pid is None:
            if not isinstance(drive, MassDamperPidDrive):
                where = f"axes.{axis}.drive" if axis else "the axis's drive"
                have = f" (it is {drive.model})" if drive is not None else ""
                raise InputError(
                    profile.path if profile is not None else src,
                    None,
                    f"model mass_damper needs the known PID gains: {where} of the profile must be mass_damper_pid{have}",
                )
            pid = (drive.kp, drive.ki, drive.kd)
        fixed = {"kp": float(pid[0]), "ki": float(pid[1]), "kd": float(pid[2])}
    if model == "sopdt" and isinstance(drive, SopdtDrive) and drive.position_gain_1_s is not None:
        fixed = {"position_gain_1_s": float(drive.position_gain_1_s)}
        if signal == "position":
            kv = float(drive.position_gain_1_s)

    # the command
    if np.ndim(u) == 0:
        size = float(u)  # type: ignore[arg-type]
        if size == 0.0 or not math.isfinite(size):
            raise InputError(src, None, f"no step in the data: the step size must be a non-zero number, got {size}")
        ts = step_time_s if step_time_s is not None else (0.0 if t[0] <= 0.0 <= t[-1] else float(t[0]))
        ks = int(np.searchsorted(t, ts - 0.5 * period))
        if ks >= n - 1:
            raise InputError(src, None, f"no step in the data: the step time {ts:.6g} s is not inside the record")
        on = (np.arange(n) >= ks).astype(float)
        if model == "sopdt" and signal == "position" and kv is None:
            uu = size * period * np.cumsum(on)  # the ramp a velocity step commands: (u[k] − u[k−1])/T = size from t_ks
        else:
            uu = size * on
        u_name = "the step"
    else:
        uu = np.asarray(u, dtype=float).ravel()
        if uu.shape != t.shape:
            raise ValueError(f"u must have the length of t_s ({n}), got {uu.shape[0]}")
        if not np.all(np.isfinite(uu)):
            raise InputError(src, None, f"{u_name} contains NaN or infinite values")
    k0 = _onset(uu)
    if k0 is None:
        raise InputError(src, None, f"no step in the data: the command {u_name} does not change")
    y_init = float(np.median(yy[:k0])) if k0 >= 3 else float(yy[0])
    noise = _noise_rms(yy)
    smooth = _moving_average(yy, 5)
    change = float(np.max(np.abs(smooth[k0:] - y_init)))
    scale = max(1.0, float(np.max(np.abs(yy))))
    if change <= max(6.0 * noise, 1e-9 * scale):
        raise InputError(
            src,
            None,
            f"no step in the data: the response {y_name} does not follow the command {u_name}"
            f" (largest change {change:.3g}, noise {noise:.3g})",
        )

    du = uu - uu[0]
    duration = float(t[-1] - t[0]) + period
    lag = _lag(du, yy, period)
    spec = _build_spec(model, signal, du, period, duration, lag, pid, kv)
    count = _Counter()
    bad_scale = 1e3 * (float(np.ptp(yy)) + 1.0)

    def g_of(th: NDArray[np.float64]) -> NDArray[np.float64] | None:
        count.n += 1
        try:
            g = spec.response(th)
        except (DriveModelError, ValueError, np.linalg.LinAlgError):
            return None
        return g if np.all(np.isfinite(g)) else None

    def resid(th: NDArray[np.float64]) -> NDArray[np.float64]:
        g = g_of(th)
        if g is None:
            return np.full(n, bad_scale)
        return _projected(g, yy, spec.linear_gain)[0]

    # the search runs on log(θ) for the parameters that are positive by nature (scale-free steps)
    log_mask = spec.lower > 0
    lo_x = np.where(log_mask, np.log(np.where(log_mask, spec.lower, 1.0)), spec.lower)
    hi_x = np.where(log_mask, np.log(np.where(log_mask, spec.upper, 1.0)), spec.upper)
    x_floor = spec.typical.copy()

    def to_theta(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.where(log_mask, np.exp(np.where(log_mask, x, 0.0)), x)

    def to_x(th: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.clip(np.where(log_mask, np.log(np.where(log_mask, th, 1.0)), th), lo_x, hi_x)

    def resid_x(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return resid(to_theta(x))

    x_scale = np.where(log_mask, 1.0, x_floor)
    # starting points: a grid around the response's time scale; coarse searches from the best three ...
    scored = []
    for c in spec.candidates:
        x = to_x(c)
        r = resid_x(x)
        scored.append((float(r @ r), x))
    scored.sort(key=lambda x: x[0])
    # (the next starting point is tried only while the fit does not explain the data down to the noise)
    good_enough = n * (1.5 * noise + 1e-9 * scale) ** 2
    best = None
    for _, x0 in scored[:3]:
        res = least_squares(
            resid_x, x0, bounds=(lo_x, hi_x), x_scale=x_scale, method="trf", ftol=1e-6, xtol=1e-6, gtol=1e-10, diff_step=1e-6,
            max_nfev=30 * (x0.size + 1),
        )
        cost = float(res.fun @ res.fun)
        if best is None or cost < best[0]:
            best = (cost, res.x)
        if best[0] <= good_enough:
            break
    assert best is not None
    # ... and the best one polished, with a central-difference Jacobian at scipy's default step: a
    # forward difference at the coarse searches' step of 1e-6 is accurate only to ~1e-6 relative, and the
    # polish then stalled that far from a noise-free optimum (zeta = 1: 1.3e-6 off with scipy 1.17)
    res = least_squares(
        resid_x, best[1], bounds=(lo_x, hi_x), x_scale=x_scale, method="trf", ftol=1e-12, xtol=1e-12, gtol=1e-12,
        jac="3-point", max_nfev=100 * (best[1].size + 1),
    )
    if float(res.fun @ res.fun) <= best[0]:
        best = (float(res.fun @ res.fun), res.x)
    theta = to_theta(best[1])
    g = g_of(theta)
    if g is None:  # pragma: no cover - the optimum is a valid model
        raise InputError(src, None, "the fit did not converge to a valid model")
    r, k_lin, offset = _projected(g, yy, spec.linear_gain)
    y_fit = yy - r

    # full parameter vector: [K] + theta + [offset]; Jacobian of the model ŷ
    cols: list[NDArray[np.float64]] = []
    names: list[str] = []
    if spec.linear_gain:
        cols.append(g)
        names.append("gain")
    gain = k_lin if spec.linear_gain else 1.0
    for j, name in enumerate(spec.names):
        h = 1e-6 * max(abs(theta[j]), x_floor[j])
        up, dn = theta.copy(), theta.copy()
        up[j] = min(theta[j] + h, spec.upper[j])
        dn[j] = max(theta[j] - h, spec.lower[j])
        gu, gd = g_of(up), g_of(dn)
        if gu is None or gd is None or up[j] == dn[j]:
            cols.append(np.zeros(n))
        else:
            cols.append(gain * (gu - gd) / (up[j] - dn[j]))
        names.append(name)
    cols.append(np.ones(n))
    jac = np.column_stack(cols)
    ssr = float(r @ r)
    dof = max(n - jac.shape[1], 1)
    s2 = ssr / dof
    norms = np.sqrt(np.sum(jac * jac, axis=0))
    norms[norms == 0] = 1.0
    jn = jac / norms
    cov = np.linalg.pinv(jn.T @ jn) / np.outer(norms, norms) * s2
    se_all = np.sqrt(np.maximum(np.diag(cov), 0.0))
    values_all = [*([k_lin] if spec.linear_gain else []), *theta]
    tq = float(stdtrit(dof, 0.975))  # Student t quantile
    params: dict[str, float] = {}
    stderr: dict[str, float] = {}
    ci: dict[str, tuple[float, float]] = {}
    value_of = dict(zip(names, values_all, strict=False))
    se_of = dict(zip(names, se_all[: len(names)], strict=False))
    for name in PARAMETERS[model]:
        v = float(value_of[name])
        se = float(se_of[name])
        if not np.any(jac[:, names.index(name)]):
            se = math.nan
        params[name] = v
        stderr[name] = se
        ci[name] = (v - tq * se, v + tq * se)

    # fit quality
    sst = float(np.sum((yy - yy.mean()) ** 2))
    r2 = 1.0 - ssr / sst if sst > 0 else math.nan
    rms = math.sqrt(ssr / n)
    static_gain = gain if spec.linear_gain else 1.0
    y_static = offset + static_gain * du
    dyn = max(float(np.max(np.abs(y_fit - y_static))), 1e-300)
    if model == "sopdt":
        th_off = 1 if kv is not None else 0
        delay = float(theta[th_off + 2])
    elif model == "first_order_delay":
        delay = float(theta[1])
    else:
        delay = 0.0
    tau = float(spec.tau(theta))

    poor = r2 < 0.98 or (rms > 0.05 * dyn and rms > 2.0 * noise)
    if poor:
        why = (
            "the residual is at the noise level: the data are too noisy rather than the model wrong"
            if rms <= 1.5 * noise
            else f"the {model} model does not describe these data (another model, or data not from one step?)"
        )
        warnings.append(
            f"poor fit: R² = {r2:.4f}, residual RMS {rms:.3g} = {rms / dyn:.1%} of the response's dynamic part; {why}"
        )
    elif rms > 2.0 * noise and rms > 0.005 * dyn:
        warnings.append(
            f"systematic misfit: the residual RMS {rms:.3g} is {rms / max(noise, 1e-300):.3g}× the noise level {noise:.3g}"
            " estimated from the data: unmodelled dynamics (friction, backlash, resonance, another model?)"
        )
    if noise > 0.05 * dyn:
        warnings.append(
            f"noisy: the noise ({noise:.3g}) is {noise / dyn:.0%} of the response's dynamic part ({dyn:.3g});"
            " the parameters are uncertain (see the intervals): a larger step or averaging helps"
        )
    after = float(t[-1] - t[k0])
    need = delay + 5.0 * tau
    if after < need:
        warnings.append(
            f"too short: the record covers {after:.3g} s after the step, less than the dead time + 5 time constants"
            f" ({need:.3g} s) of the fitted model: the final value and the slow part are extrapolated"
        )
    sat = _saturation(yy, y_fit, dyn, period, y_name)
    if sat:
        warnings.append(sat)
    at_bound: set[str] = set()
    for j, name in enumerate(spec.names):
        if name not in params:
            continue
        lo, hi = spec.lower[j], spec.upper[j]
        tol = 1e-6 * max(abs(theta[j]), x_floor[j])
        if name == "delay_s":
            tol = max(tol, 1e-3 * period)  # a thousandth of a period is no dead time
        if theta[j] - lo <= tol or hi - theta[j] <= tol:
            which = "lower" if theta[j] - lo <= tol else "upper"
            bound = lo if which == "lower" else hi
            at_bound.add(name)
            what = " (no dead time detected)" if name == "delay_s" and which == "lower" else ""
            warnings.append(
                f"at bound: {name} ended on its {which} bound {bound:.4g}{what}; its interval is one-sided"
            )
    for name, v in params.items():
        se = stderr[name]
        if name in at_bound:
            continue
        ref = max(abs(v), period) if name == "delay_s" else abs(v)  # a dead time is judged against one period at least
        if ref > 0 and math.isfinite(se) and tq * se > 0.25 * ref:
            warnings.append(
                f"poorly determined: {name} = {v:.4g} ± {tq * se:.2g} (95 %): the data do not excite the model"
                " enough (longer record, larger step, less noise)"
            )
        elif not math.isfinite(se):
            warnings.append(f"poorly determined: {name} has no finite standard error: the data do not determine it")
    if model == "mass_damper" and params["damping_v_s_mm"] < 0:
        warnings.append(
            f"negative damping: damping_v_s_mm = {params['damping_v_s_mm']:.4g} ± {stderr['damping_v_s_mm']:.2g}: next to"
            f" K_D = {fixed['kd']:.4g} the data do not tell c from 0 (written as 0)"
        )
    if "gain" in params and abs(params["gain"] - 1.0) > GAIN_TOLERANCE:
        warnings.append(
            f"gain: K = {params['gain']:.4g} is not 1 ± {GAIN_TOLERANCE:.0%}: a CNC axis reaches its commanded"
            f" {'velocity' if signal == 'velocity' and model == 'sopdt' else 'position'}; check the units of u and y and"
            " the step size (written as fitted)"
        )

    return Identification(
        axis=axis,
        model=model,
        signal=signal,
        parameters=params,
        stderr=stderr,
        ci95=ci,
        fixed=fixed,
        fit_rms=rms,
        r2=r2,
        noise_rms=noise,
        dynamic_amplitude=dyn,
        warnings=tuple(warnings),
        period_s=period,
        step_time_s=float(t[k0]),
        time_constant_s=tau,
        offset=offset,
        evaluations=count.n,
        fit_time_s=time.perf_counter() - clock,
        t_s=t,
        u=uu,
        y=yy,
        y_fit=y_fit,
        source=src,
    )



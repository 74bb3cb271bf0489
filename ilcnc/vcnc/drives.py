"""Closed-loop axis models: planned reference in, actual axis position out.

The virtual CNC feeds the planned reference ``r(t)``, sampled at the servo
period ``T`` (mm), through a model of each axis and gets the actual position
``q(t)`` (mm) at the same instants. The model of an axis is chosen in the
machine profile (``axes.<axis>.drive``, see :mod:`ilcnc.profile.schema`); the
controller section may couple two axes with a cross-coupled contour
controller.

Public API
----------
:func:`axis_response`
    One axis, ``(N,) -> (N,)``.
:func:`simulate_drives`
    All axes of a profile, ``(N, 3) -> (N, 3)`` (columns x, y, z; an axis the
    profile does not define follows its reference exactly).
:func:`cross_coupled_response`
    Two axes under the cross-coupled controller of seed 003.
:func:`loop_response`
    One axis with a position loop simulated in the compiled sampled loop
    (friction, cross-coupling); for verification.
:func:`discrete_model`
    The exact discrete transfer function of a linear model (for tuning).

Conventions
-----------
* The reference is held over each servo period (zero-order hold, ZOH), as a
  CNC's interpolator does. ``q[k]`` is the position at ``t_k = k·T``; it
  depends on ``r[0..k-1]`` only (a strictly proper model: one period of hold
  delay), plus the dead time of the model.
* The axis starts at rest at its first reference ``r[0]``; the models act on
  the deviation ``r − r[0]``.
* The velocity fed forward or commanded from the reference is the backward
  difference ``v[k] = (r[k] − r[k−1]) / T`` (mm/s), ``v[0] = 0``.

Models (``axes.<axis>.drive.model``)
------------------------------------
``sopdt`` (seed 004 §2.1)
    Velocity drive ``V/U = K·ω0²·e^{−s·Td} / (s² + 2ζω0 s + ω0²)``, position
    the integral of the velocity. Without ``position_gain_1_s`` the drive is
    fed with the planned velocity ``v[k]`` (as in seed 004, which has no
    position loop). With it, the CNC closes a P position loop at the servo
    period: ``u[k] = Kv·(r[k] − q[k])``. Seed 004 fits ω0 = 95.6 rad/s,
    ζ = 1.0, Td = 6.6 ms and prints K = 1.09e-4; no unit conversion of a
    velocity step (1000 mm/min) makes that a gain of a velocity drive that
    reaches its commanded speed, so K is normalised to 1 (unity velocity
    gain) in the shipped profiles.
``mass_damper_pid`` (seed 000 §II.A, §II.D, §III.A)
    Plant ``P = 1/(m s² + c s)`` (u in volts) under the PID
    ``K = K_P + K_I/s + K_D·s`` on the error ``e = r − q``: the paper's
    eq. (17) closed loop ``G = PK/(1 + PK) = (K_D s² + K_P s + K_I) /
    (m s³ + (c + K_D) s² + K_P s + K_I)``, discretised exactly. The printed
    gains ``[K_P, K_I, K_D] = [0.96 V/mm, 0.01 V/(s·mm), 8 V·s/mm]`` are in
    that order (their units say so): the loop is derivative-dominated and
    behaves like a first-order lag ``m/(c + K_D)`` ≈ 55 ms (x) whose last
    ~2 % settle with two slow, almost cancelled PID poles (≈ −0.0115 and −0.107
    rad/s).
``p_ff_friction`` (seed 001 §3.3, Fig. 3)
    P position loop with velocity feed-forward, closed by the CNC at the
    servo period: ``u[k] = kff·v[k] + Kv·(r[k] − q[k])`` (mm/s). The velocity
    loop is continuous: force ``F_m = K_f·(u − v) [+ K_f/Ti·∫(u − v)dt]`` with
    ``K_f = 2π·bandwidth·mass`` (a first-order velocity loop of that
    bandwidth, or a PI loop when ``velocity_integral_time_s`` is given), on
    the mass ``m·v̇ = F_m − B·v − F_f(v)`` with viscous friction ``B`` (linear)
    and Coulomb + Stribeck friction
    ``F_f = sign(v)·[F_c + (F_s − F_c)·exp(−(v/v_s)²)]``. Without Coulomb and
    static friction the model is linear and discretised exactly; with them it
    runs in a compiled loop (numba) with :data:`FRICTION_SUBSTEP_S` sub-steps:
    the linear part of each sub-step is exact (matrix exponential), the
    friction force is held over the sub-step and resolved implicitly
    (stick-slip: the axis sticks when the force it would need to keep moving
    is below the breakaway force), so the loop is stable for any friction and
    reduces exactly (to rounding) to the linear model without friction.
``first_order_delay``
    The closed position loop ``gain·e^{−s·Td}/(T s + 1)``.
``transfer_function`` (seed 003 §III)
    ``numerator/denominator`` in s: either the forward path ``L(s)`` closed
    with unity feedback (``q/r = L/(1 + L)``) or the closed loop itself.

Discretisation of the linear models
-----------------------------------
Each linear model is converted to state space and discretised exactly for a
ZOH input with :func:`scipy.signal.cont2discrete` (``method="zoh"``). A dead
time ``Td = (d + f)·T`` (``d`` integer, ``0 < f < 1``) is exact too (the
modified z-transform): within each period the delayed input switches at
``f·T``, so ``x[k+1] = Φ x[k] + Γ0 u[k−d] + Γ1 u[k−d−1]`` with
``Γ0 = Γ((1−f)T)`` and ``Γ1 = e^{A(1−f)T}·Γ(fT)``. Position loops the CNC
closes (sopdt with a position gain, p_ff_friction) are closed in discrete
time around the exactly discretised drive (a sampled-data loop, as in the
CNC; it also keeps a dead time inside the loop exact). Models given as
continuous closed loops (mass_damper_pid, first_order_delay,
transfer_function) are discretised as closed loops.

The resulting transfer function ``H(z) = z^{−d}·B(z⁻¹)/A(z⁻¹)`` is simulated
with :func:`scipy.signal.lfilter` (:func:`filter_deviation`, :func:`axis_response`;
:func:`simulate_drives` runs the same recursion, operation for operation, in
one compiled pass per axis that also forms the deviation, the difference, the
delay and the offset, the axes in parallel threads) — no per-sample Python
loop — in a deflated form that keeps the static gain exact: with the model's DC gain
``g`` (known exactly from the continuous model),
``H = g + (1 − z⁻¹)·C(z⁻¹)/A(z⁻¹)``, so ``q = r0 + g·(r − r0) +
C/A·Δr``. Servo-rate poles cluster near ``z = 1`` (the slow PID poles of
seed 000 are 1e-5 from it), where the DC gain of a transfer function in
coefficient form is only known to ~eps/∏(1 − p) ≈ 1e-5 (a plain
``lfilter(b, a, r)`` of seed 000's x axis ends 14 µm off on a 1 m move); in
the deflated form the filter only carries the dynamic part (the following
error), and the error stays below 10 nm.

Cross-coupled control (seed 003 §II.B, Fig. 1)
----------------------------------------------
The contour controller runs in the CNC at the servo period. With ``θ`` the
direction of the reference in the plane of the two coupled axes and
``n = (−sin θ, cos θ)`` its normal, the contour error estimate is
``ε = e·n = E_y·cos θ − E_x·sin θ = E_y·C_y − E_x·C_x`` (``e = r − q``) and
each axis's loop is fed ``e' = e + C·ε·n`` instead of ``e``:
``e'_x = E_x − C·C_x·ε``, ``e'_y = E_y + C·C_y·ε``. This reproduces the
paper's coupled equations ``[1 + (1 + C·C_x²)·G1]·x = … + C·C_x·C_y·G1·y``.
Seed 003's ``G1 = (2s + 11.76)/(s² + 12s)`` and ``G2 = (1.5s + 3)/(s² + 5s)``
are the forward paths "PD position controller × axis" (the paper calls them
plants), closed with unity feedback. The coupled loop is time-varying (θ)
and, with friction, nonlinear, so it runs in the compiled loop; each axis's
forward path is discretised exactly and fed the error sampled and held at
the servo period. For the continuous loops (mass_damper_pid,
transfer_function) this sampled-data loop differs from the continuous
closed loop of :func:`axis_response` by O(ω·T) (seed 003's G1 at 1 ms: 0.03 %
of the following error); with ``C = 0`` it is :func:`loop_response`.

numba
-----
The compiled loops use ``numba.njit(cache=True)``. Without numba the same
code runs as plain Python (correct, ~100× slower) and a warning is issued
once.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.signal import cont2discrete, lfilter, ss2tf, tf2ss

from ilcnc._jit import HAVE_NUMBA, njit
from ilcnc.errors import ProfileError
from ilcnc.profile.schema import (
    AXIS_NAMES,
    DriveModel,
    FirstOrderDelayDrive,
    MachineProfile,
    MassDamperPidDrive,
    PFfFrictionDrive,
    SopdtDrive,
    TransferFunctionDrive,
    has_position_loop,
)

__all__ = [
    "FRICTION_SUBSTEP_S",
    "HAVE_NUMBA",
    "DiscreteModel",
    "DriveModelError",
    "DriveStream",
    "axis_response",
    "cross_coupled_response",
    "discrete_model",
    "filter_deviation",
    "loop_response",
    "path_normals",
    "simulate_drives",
]

#: Longest sub-step of the friction loop, s (a 1 ms servo period gets 4 sub-steps). The linear
#: part of a sub-step is exact; only the friction force is held over it, so the error is first order
#: in the sub-step: on a 47 µm quadrant glitch (seed 001 profile, 150/200 N friction) 0.25 ms is
#: 0.07 µm off the limit of small sub-steps, one 1 ms step 0.3 µm.
FRICTION_SUBSTEP_S = 2.5e-4

#: A dead time within this many periods of a whole number of periods is taken as whole.
_DELAY_SNAP = 1e-9

#: Reference steps shorter than this (mm) do not define a path direction (the axis stands).
_STANDSTILL_MM = 1e-9


class DriveModelError(ValueError):
    """A drive model whose discrete closed loop is unstable (or not a valid model)."""


# --------------------------------------------------------------------------
# Discrete models
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class DiscreteModel:
    """Exact discrete transfer function of a linear axis model.

    ``q(z) / r(z) = z^{−delay_samples} · B(z⁻¹) / A(z⁻¹)`` with
    ``B = b[0] + b[1] z⁻¹ + …`` (``b[0] != 0``) and ``A = a[0] + …``
    (``a[0] = 1``), for the reference held over each servo period. The
    leading zero taps of the numerator (the one-period hold delay and the
    whole periods of any dead time) are counted in ``delay_samples``.
    It unpacks as ``b, a, delay_samples = discrete_model(...)``.

    Parameters
    ----------
    b : ndarray
        Numerator coefficients in powers of z⁻¹.
    a : ndarray
        Denominator coefficients in powers of z⁻¹, ``a[0] = 1``.
    delay_samples : int
        Pure delay in servo periods (>= 1 for a strictly proper model).
    dc_gain : float
        Static gain ``H(1)``, exact (from the continuous model), not
        ``sum(b)/sum(a)`` (which rounding spoils when poles are close to 1).
    period_s : float
        Servo period T, s.
    """

    b: np.ndarray
    a: np.ndarray
    delay_samples: int
    dc_gain: float
    period_s: float

    def __iter__(self) -> Iterator[object]:
        """Unpack as ``(b, a, delay_samples)``."""
        return iter((self.b, self.a, self.delay_samples))

    def poles(self) -> np.ndarray:
        """Return the poles (roots of A in z)."""
        return np.roots(self.a) if len(self.a) > 1 else np.zeros(0)

    def is_stable(self) -> bool:
        """True when every pole is strictly inside the unit circle."""
        p = self.poles()
        return bool(p.size == 0 or np.max(np.abs(p)) < 1.0 - 1e-12)

    def frequency_response(self, freq_hz: np.ndarray) -> np.ndarray:
        """Return ``H(e^{jωT})`` at the frequencies ``freq_hz`` (Hz), including the delay."""
        zinv = np.exp(-2j * np.pi * np.asarray(freq_hz, dtype=float) * self.period_s)
        num = np.polyval(self.b[::-1], zinv)
        den = np.polyval(self.a[::-1], zinv)
        return zinv**self.delay_samples * num / den


@dataclass(frozen=True)
class _DiscreteSS:
    """``x[k+1] = Φ x[k] + Γ0 u[k−d] + Γ1 u[k−d−1]``, ``y[k] = c·x[k]`` (exact ZOH with dead time)."""

    phi: np.ndarray
    g0: np.ndarray
    g1: np.ndarray
    c: np.ndarray
    delay: int

    def tf(self) -> tuple[np.ndarray, np.ndarray]:
        """Numerator and denominator in z⁻¹ including the dead time (leading zeros kept)."""
        n0, den = _ss_tf(self.phi, self.g0, self.c)
        num = np.concatenate([n0, [0.0]])
        if np.any(self.g1):
            n1, _ = _ss_tf(self.phi, self.g1, self.c)
            num = num + np.concatenate([[0.0], n1])
        num = np.concatenate([np.zeros(self.delay), num])
        return num, den


def _ss_tf(phi: np.ndarray, g: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    num, den = ss2tf(phi, g.reshape(-1, 1), c.reshape(1, -1), np.zeros((1, 1)))
    return np.asarray(num[0], dtype=float), np.asarray(den, dtype=float)


def zoh_discretize(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretisation ``(e^{A dt}, ∫_0^dt e^{Aσ}dσ·B)``; ``b`` is (n,) or (n, m)."""
    bb = b.reshape(a.shape[0], -1)
    n = a.shape[0]
    ad, bd, _, _, _ = cont2discrete((a, bb, np.zeros((1, n)), np.zeros((1, bb.shape[1]))), dt, method="zoh")
    return ad, (bd[:, 0] if b.ndim == 1 else bd)


def _split_delay(delay_s: float, period_s: float) -> tuple[int, float]:
    """Whole periods ``d`` and fraction ``f`` of a dead time, ``Td = (d + f)·T``."""
    tau = delay_s / period_s
    d = math.floor(tau + _DELAY_SNAP)
    f = tau - d
    return d, (0.0 if f < _DELAY_SNAP else f)


def _discretise(a: np.ndarray, b: np.ndarray, c: np.ndarray, period_s: float, delay_s: float = 0.0) -> _DiscreteSS:
    """Exact ZOH discretisation of ``(A, b, c)`` with an input dead time (see the module docstring)."""
    d, f = _split_delay(delay_s, period_s)
    phi, g = zoh_discretize(a, b, period_s)
    if f == 0.0:
        return _DiscreteSS(phi, g, np.zeros_like(g), c, d)
    _, g_f = zoh_discretize(a, b, f * period_s)
    phi_r, g_r = zoh_discretize(a, b, (1.0 - f) * period_s)
    return _DiscreteSS(phi, g_r, phi_r @ g_f, c, d)


def _tf_ss(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """State space ``(A, b, c)`` of a strictly proper transfer function in s."""
    a, b, c, d = tf2ss(num, den)
    if np.any(np.abs(d) > 0):  # pragma: no cover - the profile rejects biproper models
        raise DriveModelError("the transfer function must be strictly proper")
    return np.asarray(a, float), np.asarray(b, float)[:, 0], np.asarray(c, float)[0]


def _dc_gain(num: np.ndarray, den: np.ndarray) -> float:
    """``G(0)`` of ``num/den`` in s, cancelling common factors s."""
    num = np.trim_zeros(np.asarray(num, float), "f")
    den = np.trim_zeros(np.asarray(den, float), "f")
    while len(num) > 1 and len(den) > 1 and num[-1] == 0.0 and den[-1] == 0.0:
        num, den = num[:-1], den[:-1]
    if den[-1] == 0.0:
        raise DriveModelError("the closed loop has a pole at s = 0 (it does not settle)")
    return float(num[-1] / den[-1])


def _strip_delay(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Normalise ``den[0]`` to 1 and move the exact leading zeros of ``num`` into a delay count."""
    k = 0
    while k < len(num) - 1 and num[k] == 0.0:
        k += 1
    b = np.asarray(num[k:], float) / den[0]
    a = np.asarray(den, float) / den[0]
    # trailing zeros carry nothing
    b = np.trim_zeros(b, "b") if np.any(b) else np.zeros(1)
    a = np.trim_zeros(a, "b")
    return b, a, k


def _model(num: np.ndarray, den: np.ndarray, dc_gain: float, period_s: float) -> DiscreteModel:
    b, a, d = _strip_delay(num, den)
    m = DiscreteModel(b=b, a=a, delay_samples=d, dc_gain=float(dc_gain), period_s=float(period_s))
    if not m.is_stable():
        rho = float(np.max(np.abs(m.poles())))
        raise DriveModelError(f"the discrete closed loop is unstable (largest pole magnitude {rho:.6g} >= 1)")
    return m


# --------------------------------------------------------------------------
# Continuous plants of the loops the CNC closes
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class _Plant:
    """Continuous plant from the loop input ``u`` to the position ``q`` and the loop law around it.

    ``ẋ = A x + bu·u(t − Td) − bf·F``, ``q = c·x``, axis velocity ``cv·x``;
    the CNC applies ``u[k] = kff·v_ref[k] + kerr·e[k]`` (held over the period),
    with ``e = r − q`` (plus the cross-coupling correction). ``F`` is the
    Coulomb/Stribeck friction force, N (``bf`` is zero without friction).
    """

    a: np.ndarray
    bu: np.ndarray
    c: np.ndarray
    kff: float = 0.0
    kerr: float = 1.0
    delay_s: float = 0.0
    bf: np.ndarray | None = None
    cv: np.ndarray | None = None
    coulomb_n: float = 0.0
    breakaway_n: float = 0.0
    stribeck_mm_s: float = 0.0

    @property
    def n(self) -> int:
        return self.a.shape[0]

    @property
    def nonlinear(self) -> bool:
        return self.breakaway_n > 0.0


def _sopdt_plant(drive: SopdtDrive) -> _Plant:
    """Velocity command (mm/s) → position (mm): ``K ω0² e^{−sTd}/(s² + 2ζω0 s + ω0²) · 1/s``."""
    w0, z = drive.omega0_rad_s, drive.zeta
    a = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, -(w0**2), -2.0 * z * w0]])
    b = np.array([0.0, 0.0, drive.gain * w0**2])
    c = np.array([1.0, 0.0, 0.0])
    kv = drive.position_gain_1_s or 0.0
    return _Plant(a, b, c, kff=0.0, kerr=kv, delay_s=drive.delay_s)


def pff_plant(drive: PFfFrictionDrive) -> _Plant:
    """Velocity command (mm/s) → position (mm) of the friction-loaded axis under its velocity loop."""
    wb = 2.0 * math.pi * drive.velocity_bandwidth_hz
    accel = 1000.0 / drive.inertia_kg if drive.inertia_kg else 0.0  # mm/s² per N
    damp = wb + accel * drive.viscous_n_s_mm
    ti = drive.velocity_integral_time_s
    if ti is None:
        a = np.array([[0.0, 1.0], [0.0, -damp]])
        bu = np.array([0.0, wb])
    else:  # states q, v, ∫(u − v)dt
        a = np.array([[0.0, 1.0, 0.0], [0.0, -damp, wb / ti], [0.0, -1.0, 0.0]])
        bu = np.array([0.0, wb, 1.0])
    n = a.shape[0]
    c = np.eye(n)[0]
    cv = np.eye(n)[1]
    breakaway = max(drive.static_n, drive.coulomb_n)
    bf = cv * accel if breakaway > 0 else np.zeros(n)
    return _Plant(
        a,
        bu,
        c,
        kff=drive.kff,
        kerr=drive.kp_1_s,
        bf=bf,
        cv=cv,
        coulomb_n=drive.coulomb_n,
        breakaway_n=breakaway,
        stribeck_mm_s=drive.stribeck_velocity_mm_s if drive.static_n > drive.coulomb_n else 0.0,
    )


def _forward_path(drive: DriveModel) -> tuple[np.ndarray, np.ndarray]:
    """Forward path ``L(s)`` (position error → position) of a continuous position loop."""
    if isinstance(drive, MassDamperPidDrive):
        num = np.array([drive.kd, drive.kp, drive.ki])
        den = np.array([drive.mass_v_s2_mm, drive.damping_v_s_mm, 0.0, 0.0])
        return num, den
    if isinstance(drive, TransferFunctionDrive) and drive.feedback == "unity":
        return np.array(drive.numerator), np.array(drive.denominator)
    raise DriveModelError(f"drive model {drive.model} has no forward path")  # pragma: no cover


def _loop_plant(drive: DriveModel) -> _Plant:
    """The plant and loop law of a drive with a position loop (for the compiled loop)."""
    if not has_position_loop(drive):
        raise DriveModelError(
            f"drive model {drive.model} has no position loop (sopdt needs position_gain_1_s, transfer_function"
            " needs feedback unity)"
        )
    if isinstance(drive, SopdtDrive):
        return _sopdt_plant(drive)
    if isinstance(drive, PFfFrictionDrive):
        return pff_plant(drive)
    num, den = _forward_path(drive)
    a, b, c = _tf_ss(num, den)
    return _Plant(a, b, c, kff=0.0, kerr=1.0)


def closed_continuous(drive: DriveModel) -> tuple[np.ndarray, np.ndarray]:
    """Closed loop ``q/r`` in s of the models given as continuous closed loops."""
    if isinstance(drive, FirstOrderDelayDrive):
        return np.array([drive.gain]), np.array([drive.time_constant_s, 1.0])
    if isinstance(drive, TransferFunctionDrive) and drive.feedback == "none":
        return np.array(drive.numerator), np.array(drive.denominator)
    num, den = _forward_path(drive)
    return num, np.polyadd(den, num)


# --------------------------------------------------------------------------
# discrete_model
# --------------------------------------------------------------------------


def discrete_model(drive: DriveModel, period_s: float) -> DiscreteModel:
    """Return the exact discrete transfer function of a linear drive model.

    Parameters
    ----------
    drive : DriveModel
        A drive of the profile. For ``p_ff_friction`` the linear part is
        returned (viscous friction included, Coulomb/Stribeck friction left
        out).
    period_s : float
        Servo period T, s.

    Returns
    -------
    DiscreteModel
        ``b, a, delay_samples`` (it unpacks as that tuple) and the exact
        ``dc_gain``; see :class:`DiscreteModel`.

    Raises
    ------
    DriveModelError
        If the discrete closed loop is unstable.
    """
    if period_s <= 0:
        raise ValueError(f"period_s must be > 0, got {period_s}")
    if isinstance(drive, SopdtDrive) and drive.position_gain_1_s is None:
        return _open_sopdt_model(drive, period_s)
    if isinstance(drive, (SopdtDrive, PFfFrictionDrive)):
        return _sampled_loop_model(_loop_plant(drive), period_s)
    num, den = closed_continuous(drive)
    a, b, c = _tf_ss(num, den)
    delay = drive.delay_s if isinstance(drive, FirstOrderDelayDrive) else 0.0
    bn, an = _discretise(a, b, c, period_s, delay).tf()
    return _model(bn, an, _dc_gain(num, den), period_s)


def _open_sopdt_model(drive: SopdtDrive, period_s: float) -> DiscreteModel:
    """Seed 004: the velocity drive fed with ``v[k] = (r[k] − r[k−1])/T``, position its integral.

    ``H = P(z)·(1 − z⁻¹)/T`` with ``P`` the exact ZOH model of ``V(s)/s``; the
    integrator pole of ``P`` (at z = 1) cancels the difference and is divided
    out of the denominator.
    """
    p = _sopdt_plant(drive)
    num, den = _discretise(p.a, p.bu, p.c, period_s, p.delay_s).tf()
    # den = (1 − z⁻¹)·den'; den' by synthetic division (the remainder is rounding)
    den_red = np.cumsum(den)[:-1]
    return _model(num / period_s, den_red, drive.gain, period_s)


def _sampled_loop_model(p: _Plant, period_s: float) -> DiscreteModel:
    """A position loop closed by the CNC at the servo period around the exactly discretised plant.

    ``u = kff·(1 − z⁻¹)/T·r + kerr·(r − q)``, ``q = P u`` →
    ``q/r = P·F/(1 + kerr·P)`` with ``F = kff/T·(1 − z⁻¹) + kerr``.
    """
    pn, pd = _discretise(p.a, p.bu, p.c, period_s, p.delay_s).tf()
    f = np.array([p.kff / period_s + p.kerr, -p.kff / period_s])
    num = np.convolve(pn, f)
    den = _padd(pd, p.kerr * pn)
    return _model(num, den, 1.0, period_s)


def _padd(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Add two polynomials in z⁻¹ (coefficient arrays aligned at z⁰)."""
    out = np.zeros(max(len(x), len(y)))
    out[: len(x)] += x
    out[: len(y)] += y
    return out


# --------------------------------------------------------------------------
# Linear simulation (lfilter)
# --------------------------------------------------------------------------


def _as_reference(ref_mm: np.ndarray) -> np.ndarray:
    r = np.asarray(ref_mm, dtype=float)
    if r.ndim != 1:
        raise ValueError(f"the reference of one axis must have shape (N,), got {r.shape}")
    if r.size and not np.all(np.isfinite(r)):
        raise ValueError("the reference contains NaN or infinite values")
    return r


def _shift(x: np.ndarray, d: int) -> np.ndarray:
    """Delay ``x`` by ``d`` samples (zeros in front)."""
    if d == 0:
        return x
    out = np.zeros_like(x)
    if d < len(x):
        out[d:] = x[: len(x) - d]
    return out


def filter_deviation(model: DiscreteModel, dev: np.ndarray) -> np.ndarray:
    """Apply a discrete model to a signal that starts at 0 (the deviation ``r − r[0]``).

    Parameters
    ----------
    model : DiscreteModel
        The model.
    dev : ndarray, shape (N,)
        Input deviation, ``dev[0] = 0``.

    Returns
    -------
    ndarray, shape (N,)
        ``H(z)·dev`` from rest, computed in the deflated form
        ``g·dev + (1 − z⁻¹)·C/A`` (see the module docstring).
    """
    c, aa, g = _deflated(model)
    step = np.diff(dev, prepend=dev[:1])
    y = g * dev
    if len(c):
        y = y + lfilter(c, aa, step)
    return _shift(y, model.delay_samples)


def _deflated(model: DiscreteModel) -> tuple[np.ndarray, np.ndarray, float]:
    """The deflated form ``g + (1 − z⁻¹)·C/A`` of a model: ``(C, A, g)``, C one coefficient shorter than A."""
    b, a, g = model.b, model.a, model.dc_gain
    n = max(len(b), len(a))
    bb = np.zeros(n)
    bb[: len(b)] = b
    aa = np.zeros(n)
    aa[: len(a)] = a
    return np.cumsum(bb - g * aa)[:-1], aa, g


def _kernel_coefficients(model: DiscreteModel) -> tuple[np.ndarray, np.ndarray, float]:
    """``(b, a, g)`` of the deflated form as the compiled kernels take them: C padded to A's length and both
    divided by ``a[0]``, as ``lfilter`` normalises (empty arrays for a pure gain)."""
    c, aa, g = _deflated(model)
    if not len(c):
        return np.zeros(0), np.zeros(0), float(g)
    bn = np.zeros(len(aa))
    bn[: len(c)] = c
    return bn / aa[0], aa / aa[0], float(g)


def _filter_reference(model: DiscreteModel, ref: np.ndarray, out: np.ndarray) -> None:
    """``out = r[0] + H(z)·(r − r[0])`` of one axis in one compiled pass (:func:`_deflated_kernel`).

    The numbers of :func:`filter_deviation` (``scipy.signal.lfilter``'s recursion, normalised as it
    normalises, operation for operation); ``ref`` and ``out`` may be strided columns. Raises
    ``ValueError`` when the reference is not finite.
    """
    bn, an, g = _kernel_coefficients(model)
    if not _deflated_kernel(ref, out, bn, an, g, int(model.delay_samples)):
        raise ValueError("the reference contains NaN or infinite values")


@njit(cache=True, nogil=True, inline="always")
def _deflated_step(step, bn, an, z):  # pragma: no cover - compiled
    """One sample of the transposed direct form II filter ``C/A`` on ``step`` (the deviation's difference),
    in ``scipy.signal.lfilter``'s order (``y = z0 + b0·x``; ``z[i] = z[i+1] + x·b[i+1] − y·a[i+1]``): the
    recursion :func:`_deflated_kernel` and :func:`_deflated_stream_kernel` share. 0 for a pure gain."""
    nf = an.shape[0]
    if nf <= 1:
        return 0.0
    lf = z[0] + bn[0] * step
    for i in range(nf - 2):
        z[i] = z[i + 1] + step * bn[i + 1] - lf * an[i + 1]
    z[nf - 2] = step * bn[nf - 1] - lf * an[nf - 1]
    return lf


@njit(cache=True, nogil=True)
def _deflated_kernel(r, out, bn, an, g, delay):  # pragma: no cover - compiled; checked against filter_deviation
    """``out[k + d] = r0 + g·dev[k] + C/A·Δdev[k]``, ``out[:d] = r0``, ``dev = r − r0``; False if ``r`` is not finite.

    One pass instead of seven whole-array temporaries (deviation, difference, gain, filter, sum, shift,
    offset) per axis; the filter is the transposed direct form II of ``scipy.signal.lfilter`` with its
    operations in its order (``y = z0 + b0·x``; ``z[i] = z[i+1] + x·b[i+1] − y·a[i+1]``), so the
    numbers are the same. A hand-written loop: a recursion does not vectorise.
    """
    n = r.shape[0]
    nf = an.shape[0]
    z = np.zeros(max(nf - 1, 1))
    finite = True
    r0 = r[0] if n else 0.0
    prev = 0.0
    for k in range(min(delay, n)):
        out[k] = r0 + 0.0
    for k in range(n):
        x = r[k]
        if not math.isfinite(x):
            finite = False
        dev = x - r0
        step = dev - (prev if k > 0 else dev)
        prev = dev
        y = g * dev
        if nf > 1:
            y = y + _deflated_step(step, bn, an, z)
        if k + delay < n:
            out[k + delay] = r0 + y
    return finite


@njit(cache=True, nogil=True)
def _deflated_stream_kernel(r, y, bn, an, g, r0, z, st):  # pragma: no cover - compiled; checked against the whole run
    """:func:`_deflated_kernel` on the next stretch of a reference, before its delay: ``y[k] = r0 + g·dev[k] +
    C/A·Δdev[k]``. The filter state ``z`` and ``st`` (the previous deviation, the samples seen) carry on from
    the stretch before, so the stretches of a run give the numbers of one pass. False if ``r`` is not finite."""
    n = r.shape[0]
    nf = an.shape[0]
    finite = True
    prev = st[0]
    seen = st[1]
    for k in range(n):
        x = r[k]
        if not math.isfinite(x):
            finite = False
        dev = x - r0
        step = dev - (prev if seen + k > 0 else dev)
        prev = dev
        yy = g * dev
        if nf > 1:
            yy = yy + _deflated_step(step, bn, an, z)
        y[k] = r0 + yy
    st[0] = prev
    st[1] = seen + n
    return finite


class _AxisStream:
    """One linear axis run stretch by stretch: the deflated filter's state and the delay line."""

    def __init__(self, model: DiscreteModel, r0: float) -> None:
        self.bn, self.an, self.g = _kernel_coefficients(model)
        self.r0 = float(r0)
        self.z = np.zeros(max(len(self.an) - 1, 1))
        self.st = np.zeros(2)
        # outputs not handed out yet: the model's delay (the first ones are the rest position, r0 + 0.0)
        self.pending = np.full(int(model.delay_samples), self.r0 + 0.0)

    def step(self, ref: np.ndarray, out: np.ndarray) -> None:
        y = np.empty(ref.shape[0])
        if not _deflated_stream_kernel(np.ascontiguousarray(ref), y, self.bn, self.an, self.g, self.r0, self.z,
                                       self.st):
            raise ValueError("the reference contains NaN or infinite values")
        d = self.pending.shape[0]
        if d == 0:
            out[:] = y
            return
        both = np.concatenate([self.pending, y])
        out[:] = both[: y.shape[0]]
        self.pending = both[y.shape[0]:]


class DriveStream:
    """The drives of a profile run on a reference handed over in consecutive stretches.

    :func:`simulate_drives` needs the whole reference (N × 3 floats); a long program's reference is
    planned chunk by chunk (:func:`ilcnc.vcnc.plan.plan_chunks`) and each chunk goes through
    :meth:`step`, which carries every axis's filter state on: the positions are those of
    :func:`simulate_drives` on the whole reference, bit for bit. Linear drive models only (the
    compiled loops of friction, gain schedules and the cross-coupled controller hold their state in
    the loop): :meth:`unsupported` says why a profile cannot stream.

    Parameters
    ----------
    profile : MachineProfile
    r0_mm : ndarray (3,)
        The reference's first sample (the rest position every deviation is taken from), mm.
    """

    def __init__(self, profile: MachineProfile, r0_mm: np.ndarray) -> None:
        why = self.unsupported(profile)
        if why:
            raise ValueError(why)
        period = profile.machine.servo_period_s
        self._axes: list[tuple[int, _AxisStream | None]] = []
        for col, ax in enumerate(AXIS_NAMES[:3]):
            if ax not in profile.axes:
                self._axes.append((col, None))
                continue
            try:
                model = discrete_model(profile.axes[ax].drive, period)
            except DriveModelError as exc:
                raise ProfileError(profile.path, None, f"axes.{ax}.drive: {exc}") from None
            self._axes.append((col, _AxisStream(model, float(r0_mm[col]))))

    @staticmethod
    def unsupported(profile: MachineProfile) -> str | None:
        """Why the profile's drives cannot run stretch by stretch (None: they can)."""
        if profile.controller.type == "cross_coupled":
            return "the cross-coupled controller runs the whole reference at once"
        for ax, axis in profile.axes.items():
            d = axis.drive
            if isinstance(d, PFfFrictionDrive) and max(d.coulomb_n, d.static_n) > 0:
                return f"axes.{ax}.drive has friction (its compiled loop runs the whole reference at once)"
        return None

    def step(self, ref_mm: np.ndarray) -> np.ndarray:
        """Actual positions (n, 3) of the next ``n`` reference samples (n, 3), mm."""
        r = np.asarray(ref_mm, dtype=float)
        out = np.empty_like(r)
        jobs = []
        for col, axis in self._axes:
            if axis is None:
                out[:, col] = r[:, col]
            else:
                jobs.append((axis, col))

        def run(job: tuple[_AxisStream, int]) -> None:
            col = job[1]
            col_out = np.empty(r.shape[0])
            job[0].step(r[:, col], col_out)
            out[:, col] = col_out

        from ilcnc._threads import thread_limit

        nw = min(len(jobs), thread_limit())
        if nw > 1 and r.shape[0] >= _PARALLEL_SAMPLES:
            with ThreadPoolExecutor(max_workers=nw) as ex:
                list(ex.map(run, jobs))
        else:
            for job in jobs:
                run(job)
        return out


# --------------------------------------------------------------------------
# The compiled loop
# --------------------------------------------------------------------------


@njit(cache=True, inline="always")
def friction_steps(x, xn, u, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus):  # pragma: no cover
    """``nsub`` exact sub-steps of one axis with the friction force resolved implicitly (stick-slip).

    Each sub-step first moves the linear part without friction (``xn``). If
    the velocity it reaches is within what the breakaway force can stop
    (``|v| <= bstick·fbreak``) the axis sticks: a moving axis comes to rest
    at the end of the sub-step under the friction force that stops it
    (exact for a force held over the sub-step), an axis at rest takes the
    exact step of the stuck system (``phis``, ``gus``: velocity 0, position
    unchanged, the controller states integrating). Otherwise the kinetic
    friction (Coulomb plus the Stribeck peak at the sub-step's starting
    velocity) opposes the motion, held over the sub-step.
    """
    n = x.shape[0]
    for _ in range(nsub):
        vprev = 0.0
        vfree = 0.0
        for i in range(n):
            vprev += cv[i] * x[i]
        for i in range(n):
            s = guh[i] * u
            for j in range(n):
                s += phih[i, j] * x[j]
            xn[i] = s
            vfree += cv[i] * s
        if abs(vfree) <= bstick * fbreak and vprev == 0.0:  # stays stuck
            for i in range(n):
                s = gus[i] * u
                for j in range(n):
                    s += phis[i, j] * x[j]
                xn[i] = s
            for i in range(n):
                x[i] = xn[i]
        elif abs(vfree) <= bstick * fbreak:  # comes to rest: the friction force that stops it exactly
            force = vfree / bstick
            for i in range(n):
                x[i] = xn[i] - gfh[i] * force
            vrest = 0.0
            for i in range(n):
                vrest += cv[i] * x[i]
            for i in range(n):
                x[i] -= cv[i] * vrest  # exactly 0, not rounding
        else:
            sgn = 1.0 if vfree > 0.0 else -1.0
            if vprev * sgn > 0.0:
                mag = fc
                if vs > 0.0:
                    ratio2 = (vprev / vs) ** 2
                    if ratio2 < 50.0:  # exp(-50) ~ 2e-22: no Stribeck term left
                        mag += (fbreak - fc) * math.exp(-ratio2)
            else:
                mag = fbreak
            force = sgn * mag
            for i in range(n):
                x[i] = xn[i] - gfh[i] * force


@njit(cache=True, inline="always")
def _linear_step(x, xn, u0, u1, phi, g0, g1):  # pragma: no cover - compiled
    """One servo period ``x = Φ x + Γ0 u0 + Γ1 u1``."""
    n = x.shape[0]
    for i in range(n):
        s = g0[i] * u0 + g1[i] * u1
        for j in range(n):
            s += phi[i, j] * x[j]
        xn[i] = s
    for i in range(n):
        x[i] = xn[i]


@njit(cache=True)
def _loop_kernel(
    dr, vref, nrm, cgain, phi, g0, g1, cq, delay, kff, kerr, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus
):  # pragma: no cover - compiled; its Python version is tested through py_func
    """Sampled position loops of ``m`` axes (1 or 2), optionally cross-coupled and with friction.

    Per servo period k and axis a: ``q = cq·x``; ``e = r − q``; with two axes
    and ``cgain != 0``: ``ε = n·e`` and ``e += cgain·ε·n``; ``u = kff·v_ref +
    kerr·e``; then either ``x = Φ x + Γ0 u[k−d] + Γ1 u[k−d−1]`` or, with
    friction (``nsub > 0``, no dead time), ``nsub`` exact sub-steps with the
    friction force resolved implicitly (:func:`friction_steps`).
    """
    npts, m = dr.shape
    n = phi.shape[1]
    out = np.empty((npts, m))
    x = np.zeros((m, n))
    xn = np.zeros(n)
    hlen = 2
    for a in range(m):
        if delay[a] + 2 > hlen:
            hlen = delay[a] + 2
    hist = np.zeros((m, hlen))
    pos = 0  # slot of u[k] in the ring buffer hist
    e = np.zeros(m)
    for k in range(npts):
        for a in range(m):
            q = 0.0
            for i in range(n):
                q += cq[a, i] * x[a, i]
            out[k, a] = q
            e[a] = dr[k, a] - q
        if m == 2 and cgain != 0.0:
            eps = nrm[k, 0] * e[0] + nrm[k, 1] * e[1]
            e[0] += cgain * eps * nrm[k, 0]
            e[1] += cgain * eps * nrm[k, 1]
        for a in range(m):
            u = kff[a] * vref[k, a] + kerr[a] * e[a]
            if nsub[a] > 0:
                friction_steps(
                    x[a], xn, u, nsub[a], phih[a], guh[a], gfh[a], cv[a], bstick[a], fc[a], fbreak[a], vs[a], phis[a], gus[a]
                )
            else:
                d = delay[a]
                hist[a, pos] = u  # the history starts at 0: u before k = 0 is 0
                i0 = pos - d
                if i0 < 0:
                    i0 += hlen
                i1 = i0 - 1 if i0 > 0 else hlen - 1
                u0 = hist[a, i0]
                u1 = hist[a, i1]
                _linear_step(x[a], xn, u0, u1, phi[a], g0[a], g1[a])
        pos = pos + 1 if pos + 1 < hlen else 0
    return out


@njit(cache=True)
def _friction_kernel(
    dr, vref, cq, kff, kerr, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus
):  # pragma: no cover - compiled; its Python version is tested through py_func
    """One axis of :func:`_loop_kernel` with friction, without coupling (the fast common case)."""
    npts = dr.shape[0]
    n = cq.shape[0]
    out = np.empty(npts)
    x = np.zeros(n)
    xn = np.zeros(n)
    for k in range(npts):
        q = 0.0
        for i in range(n):
            q += cq[i] * x[i]
        out[k] = q
        u = kff * vref[k] + kerr * (dr[k] - q)
        friction_steps(x, xn, u, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus)
    return out


#: Per-axis arrays of :func:`_friction_kernel`, in argument order.
_FRICTION_ARGS = ("cq", "kff", "kerr", "nsub", "phih", "guh", "gfh", "cv", "bstick", "fc", "fbreak", "vs", "phis", "gus")

_warned_no_numba = False


def _warn_no_numba() -> None:
    global _warned_no_numba
    if not HAVE_NUMBA and not _warned_no_numba:  # pragma: no cover
        warnings.warn("numba is not installed: the friction and cross-coupled loops run as slow Python", stacklevel=3)
        _warned_no_numba = True


def stuck_system(a: np.ndarray, b: np.ndarray, cv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The system with the velocity state held at 0 (its row and column removed from the dynamics)."""
    iv = int(np.argmax(cv))
    a_s = a.copy()
    a_s[iv, :] = 0.0
    a_s[:, iv] = 0.0
    b_s = b.copy()
    b_s[iv] = 0.0
    return a_s, b_s


def _kernel_arrays(plants: list[_Plant], period_s: float, *, loop: bool = False) -> dict[str, np.ndarray]:
    """Per-axis matrices of the compiled loop, padded to the largest state dimension (``loop``: the
    sub-stepped friction matrices also for an axis without friction, e.g. to run it with a gain schedule)."""
    m = len(plants)
    n = max(p.n for p in plants)
    arr = {
        "phi": np.zeros((m, n, n)),
        "g0": np.zeros((m, n)),
        "g1": np.zeros((m, n)),
        "cq": np.zeros((m, n)),
        "delay": np.zeros(m, dtype=np.int64),
        "kff": np.zeros(m),
        "kerr": np.zeros(m),
        "nsub": np.zeros(m, dtype=np.int64),
        "phih": np.zeros((m, n, n)),
        "guh": np.zeros((m, n)),
        "gfh": np.zeros((m, n)),
        "cv": np.zeros((m, n)),
        "bstick": np.ones(m),
        "fc": np.zeros(m),
        "fbreak": np.zeros(m),
        "vs": np.zeros(m),
        "phis": np.zeros((m, n, n)),
        "gus": np.zeros((m, n)),
    }
    for i, p in enumerate(plants):
        k = p.n
        ss = _discretise(p.a, p.bu, p.c, period_s, p.delay_s)
        arr["phi"][i, :k, :k] = ss.phi
        arr["g0"][i, :k] = ss.g0
        arr["g1"][i, :k] = ss.g1
        arr["cq"][i, :k] = p.c
        arr["delay"][i] = ss.delay
        arr["kff"][i] = p.kff
        arr["kerr"][i] = p.kerr
        if p.nonlinear or (loop and p.bf is not None and p.cv is not None):
            assert p.bf is not None and p.cv is not None and p.delay_s == 0.0
            nsub = max(1, math.ceil(period_s / FRICTION_SUBSTEP_S - 1e-9))
            phih, gh = zoh_discretize(p.a, np.column_stack([p.bu, p.bf]), period_s / nsub)
            arr["nsub"][i] = nsub
            arr["phih"][i, :k, :k] = phih
            arr["guh"][i, :k] = gh[:, 0]
            arr["gfh"][i, :k] = gh[:, 1]
            arr["cv"][i, :k] = p.cv
            arr["bstick"][i] = float(p.cv @ gh[:, 1])
            arr["fc"][i] = p.coulomb_n
            arr["fbreak"][i] = p.breakaway_n
            arr["vs"][i] = p.stribeck_mm_s
            phis, gus = zoh_discretize(*stuck_system(p.a, p.bu, p.cv), period_s / nsub)
            arr["phis"][i, :k, :k] = phis
            arr["gus"][i, :k] = gus
    return arr


def _friction_column(plant: _Plant, ref: np.ndarray, out: np.ndarray, period_s: float,
                     kerr_1_s: np.ndarray | None = None) -> None:
    """``out = r[0] + q`` of one friction axis (what :func:`axis_response` computes) without whole-array temporaries.

    ``kerr_1_s`` (N,): a position gain per servo period, 1/s (a gain schedule) instead of the plant's own.
    """
    if ref.shape[0] and not _all_finite(ref):
        raise ValueError("the reference contains NaN or infinite values")
    _warn_no_numba()
    arr = _kernel_arrays([plant], period_s, loop=kerr_1_s is not None)
    args = [arr[k][0] for k in _FRICTION_ARGS]
    i = _FRICTION_ARGS.index("kerr")
    args[i] = np.array([args[i]]) if kerr_1_s is None else np.ascontiguousarray(kerr_1_s, dtype=np.float64)
    if ref.shape[0] and not _friction_ref_kernel(ref, out, float(period_s), *args):  # pragma: no cover
        raise DriveModelError("the simulated loop diverged (unstable closed loop)")


@njit(cache=True, nogil=True)
def _all_finite(x):  # pragma: no cover - compiled
    """``np.all(np.isfinite(x))`` without a temporary."""
    for k in range(x.shape[0]):
        if not math.isfinite(x[k]):
            return False
    return True


@njit(cache=True, nogil=True)
def _friction_ref_kernel(
    ref, out, period_s, cq, kff, kerr, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus
):  # pragma: no cover - compiled; checked against _friction_kernel
    """:func:`_friction_kernel` fed from the reference itself: the deviation ``r − r0`` and the
    velocity ``(dev[k] − dev[k−1]) / T`` are formed per sample and ``r0 + q`` is written to ``out``
    (same numbers, no whole-array temporaries). ``kerr`` holds one gain, or one per sample (a gain
    schedule). False if the output is not finite."""
    npts = ref.shape[0]
    n = cq.shape[0]
    per_sample = kerr.shape[0] > 1
    x = np.zeros(n)
    xn = np.zeros(n)
    r0 = ref[0]
    prev = 0.0
    ok = True
    for k in range(npts):
        dev = ref[k] - r0
        vref = (dev - (prev if k > 0 else dev)) / period_s
        prev = dev
        q = 0.0
        for i in range(n):
            q += cq[i] * x[i]
        if not math.isfinite(q):
            ok = False
        out[k] = r0 + q
        u = kff * vref + kerr[k if per_sample else 0] * (dev - q)
        friction_steps(x, xn, u, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus)
    return ok


def _run_loop(plants: list[_Plant], dev: np.ndarray, period_s: float, nrm: np.ndarray, gain: float) -> np.ndarray:
    """Run the compiled loop on deviations ``dev`` (N, m); returns position deviations (N, m)."""
    _warn_no_numba()
    arr = _kernel_arrays(plants, period_s)
    vref = np.diff(dev, axis=0, prepend=dev[:1]) / period_s
    if len(plants) == 1 and arr["nsub"][0] > 0:
        args = [arr[k][0] for k in _FRICTION_ARGS]
        out = _friction_kernel(np.ascontiguousarray(dev[:, 0]), np.ascontiguousarray(vref[:, 0]), *args)[:, None]
        if not np.all(np.isfinite(out)):  # pragma: no cover - the implicit friction step cannot diverge
            raise DriveModelError("the simulated loop diverged (unstable closed loop)")
        return out
    out = _loop_kernel(
        np.ascontiguousarray(dev),
        np.ascontiguousarray(vref),
        np.ascontiguousarray(nrm, dtype=float),
        float(gain),
        arr["phi"],
        arr["g0"],
        arr["g1"],
        arr["cq"],
        arr["delay"],
        arr["kff"],
        arr["kerr"],
        arr["nsub"],
        arr["phih"],
        arr["guh"],
        arr["gfh"],
        arr["cv"],
        arr["bstick"],
        arr["fc"],
        arr["fbreak"],
        arr["vs"],
        arr["phis"],
        arr["gus"],
    )
    if not np.all(np.isfinite(out)):
        raise DriveModelError("the simulated loop diverged (unstable closed loop)")
    return out


def path_normals(ref_2d: np.ndarray) -> np.ndarray:
    """Unit normals ``n = (−sin θ, cos θ)`` of a planar reference path, per sample.

    Parameters
    ----------
    ref_2d : ndarray, shape (N, 2)
        Reference of the two coupled axes, mm.

    Returns
    -------
    ndarray, shape (N, 2)
        ``θ`` is the direction of the central difference of the reference
        (forward/backward at the ends); where the reference stands still the
        direction of the nearest earlier motion is held (before the first
        motion: the first motion's; no motion at all: θ = 0).
    """
    r = np.asarray(ref_2d, dtype=float)
    npts = r.shape[0]
    if npts < 2:
        return np.tile([0.0, 1.0], (npts, 1))
    d = np.empty_like(r)
    d[1:-1] = r[2:] - r[:-2]
    d[0] = r[1] - r[0]
    d[-1] = r[-1] - r[-2]
    norm = np.hypot(d[:, 0], d[:, 1])
    valid = norm > _STANDSTILL_MM
    if not np.any(valid):
        return np.tile([0.0, 1.0], (npts, 1))
    idx = np.where(valid, np.arange(npts), -1)
    idx = np.maximum.accumulate(idx)
    idx[idx < 0] = int(np.argmax(valid))
    t = d[idx] / norm[idx, None]
    return np.column_stack([-t[:, 1], t[:, 0]])


# --------------------------------------------------------------------------
# Public simulation functions
# --------------------------------------------------------------------------


def axis_response(drive: DriveModel, ref_mm: np.ndarray, period_s: float) -> np.ndarray:
    """Simulate one axis: actual position for a reference sampled at the servo period.

    Parameters
    ----------
    drive : DriveModel
        The axis's drive model (``profile.axes[name].drive``).
    ref_mm : ndarray, shape (N,)
        Planned reference r[k] at ``t_k = k·period_s``, mm.
    period_s : float
        Servo period T, s.

    Returns
    -------
    ndarray, shape (N,)
        Actual position q[k], mm, starting at rest at ``ref_mm[0]``.

    Raises
    ------
    DriveModelError
        If the model's closed loop is unstable at this period.
    """
    r = _as_reference(ref_mm)
    if r.size == 0:
        return r.copy()
    dev = r - r[0]
    if isinstance(drive, PFfFrictionDrive) and max(drive.coulomb_n, drive.static_n) > 0:
        return r[0] + _run_loop([pff_plant(drive)], dev[:, None], period_s, np.zeros((1, 2)), 0.0)[:, 0]
    return r[0] + filter_deviation(discrete_model(drive, period_s), dev)


def loop_response(drive: DriveModel, ref_mm: np.ndarray, period_s: float) -> np.ndarray:
    """Simulate one axis with a position loop in the compiled sampled loop.

    The loop is the one the friction and cross-coupled simulations use: the
    position error is sampled and held at the servo period. For sopdt with a
    position gain and p_ff_friction it is the model :func:`axis_response`
    uses (equal to rounding without friction); for mass_damper_pid and
    transfer_function (continuous loops) it is their sampled-data version,
    which differs from the continuous closed loop by O(ω·T).

    Parameters
    ----------
    drive : DriveModel
        A drive with a position loop (see :func:`ilcnc.profile.schema.has_position_loop`).
    ref_mm : ndarray, shape (N,)
        Reference, mm.
    period_s : float
        Servo period, s.

    Returns
    -------
    ndarray, shape (N,)
        Actual position, mm.
    """
    r = _as_reference(ref_mm)
    if r.size == 0:
        return r.copy()
    return r[0] + _run_loop([_loop_plant(drive)], (r - r[0])[:, None], period_s, np.zeros((1, 2)), 0.0)[:, 0]


def cross_coupled_response(
    drives: tuple[DriveModel, DriveModel], ref_mm: np.ndarray, period_s: float, gain: float
) -> np.ndarray:
    """Simulate two axes under the cross-coupled contour controller of seed 003.

    Parameters
    ----------
    drives : (DriveModel, DriveModel)
        Drives of the two coupled axes (each with a position loop).
    ref_mm : ndarray, shape (N, 2)
        Reference of the two axes, mm.
    period_s : float
        Servo period, s.
    gain : float
        Cross-coupling gain C (0: the same sampled loops without coupling).

    Returns
    -------
    ndarray, shape (N, 2)
        Actual positions, mm.
    """
    r = np.asarray(ref_mm, dtype=float)
    if r.ndim != 2 or r.shape[1] != 2:
        raise ValueError(f"the reference of two coupled axes must have shape (N, 2), got {r.shape}")
    if r.shape[0] == 0:
        return r.copy()
    if not np.all(np.isfinite(r)):
        raise ValueError("the reference contains NaN or infinite values")
    plants = [_loop_plant(d) for d in drives]
    dev = r - r[0]
    return r[0] + _run_loop(plants, dev, period_s, path_normals(r), gain)


def simulate_drives(
    ref_mm: np.ndarray, profile: MachineProfile, *, gain_schedule: Mapping[str, np.ndarray] | None = None
) -> np.ndarray:
    """Simulate every axis of a machine profile.

    Parameters
    ----------
    ref_mm : ndarray, shape (N, 3) or (N, 2)
        Reference sampled at ``profile.machine.servo_period_s``; columns x, y,
        z (or x, y), mm.
    profile : MachineProfile
        The machine: a drive model per axis and the controller structure.
    gain_schedule : mapping of axis name to ndarray (N,), optional
        Position-loop gain of that axis in each servo period, (m/min)/mm (what
        ``ilcnc tune --method schedule`` writes, seed 001), instead of the
        drive's fixed ``kp_m_min_mm``. Only for ``p_ff_friction`` drives.

    Returns
    -------
    ndarray, same shape as ``ref_mm``
        Actual positions, mm. An axis the profile does not define follows its
        reference exactly; with ``controller.type: cross_coupled`` the two
        coupled axes run under the cross-coupled controller.

    Raises
    ------
    ProfileError
        If a drive model is unstable at the servo period (the message names
        the YAML path of the drive).
    """
    r = np.asarray(ref_mm, dtype=float)
    if r.ndim != 2 or r.shape[1] not in (2, 3):
        raise ValueError(f"the reference must have shape (N, 3) (columns x, y, z) or (N, 2), got {r.shape}")
    period = profile.machine.servo_period_s
    names = AXIS_NAMES[: r.shape[1]]
    out = np.empty_like(r)
    done: set[str] = set()
    ctl = profile.controller
    if ctl.type == "cross_coupled" and all(ax in names for ax in ctl.coupled_axes):
        i, j = (names.index(ax) for ax in ctl.coupled_axes)
        pair = (profile.axes[ctl.coupled_axes[0]].drive, profile.axes[ctl.coupled_axes[1]].drive)
        try:
            out[:, [i, j]] = cross_coupled_response(pair, r[:, [i, j]], period, ctl.cross_coupling_gain)
        except DriveModelError as exc:
            where = f"controller.coupled_axes ({', '.join(ctl.coupled_axes)})"
            raise ProfileError(profile.path, None, f"{where}: {exc}") from None
        done.update(ctl.coupled_axes)
    jobs = []
    for col, ax in enumerate(names):
        if ax in done:
            continue
        if ax not in profile.axes:
            out[:, col] = r[:, col]
            continue
        sched = None
        if gain_schedule is not None and ax in gain_schedule:
            sched = np.asarray(gain_schedule[ax], dtype=np.float64)
            drive = profile.axes[ax].drive
            if not isinstance(drive, PFfFrictionDrive):
                raise ProfileError(profile.path, None, f"axes.{ax}.drive: a gain schedule needs a p_ff_friction drive"
                                                       f" (a P position loop), not {drive.model}")
            if sched.shape != (r.shape[0],) or not np.all(np.isfinite(sched)) or np.any(sched <= 0):
                raise ValueError(f"the gain schedule of axis {ax} must hold one finite gain > 0 per sample"
                                 f" ({r.shape[0]}), got shape {sched.shape}")
        try:
            jobs.append((ax, _axis_job(profile.axes[ax].drive, r[:, col], out[:, col], period, sched)))
        except DriveModelError as exc:
            raise ProfileError(profile.path, None, f"axes.{ax}.drive: {exc}") from None

    def run(job: tuple[str, Callable[[], None]]) -> None:
        try:
            job[1]()
        except DriveModelError as exc:  # pragma: no cover - a stable model does not diverge
            raise ProfileError(profile.path, None, f"axes.{job[0]}.drive: {exc}") from None

    # the compiled loops release the GIL: the axes run side by side
    from ilcnc._threads import thread_limit  # the one place that decides ilcnc's thread counts

    nw = min(len(jobs), thread_limit())
    if nw > 1 and r.shape[0] >= _PARALLEL_SAMPLES:
        with ThreadPoolExecutor(max_workers=nw) as ex:
            list(ex.map(run, jobs))
    else:
        for job in jobs:
            run(job)
    return out


#: References at least this long run their axes in parallel threads.
_PARALLEL_SAMPLES = 100_000


def _axis_job(drive: DriveModel, ref: np.ndarray, out: np.ndarray, period_s: float,
              kp_m_min_mm: np.ndarray | None = None) -> Callable[[], None]:
    """The simulation of one axis into ``out`` (a column of the result), to be run (models are built now,
    so an unstable one raises here). ``kp_m_min_mm``: a gain schedule (the compiled loop runs it)."""
    if isinstance(drive, PFfFrictionDrive) and (max(drive.coulomb_n, drive.static_n) > 0 or kp_m_min_mm is not None):
        plant = pff_plant(drive)
        kerr = None if kp_m_min_mm is None else kp_m_min_mm * (1000.0 / 60.0)

        def run() -> None:
            _friction_column(plant, ref, out, period_s, kerr)

        return run
    model = discrete_model(drive, period_s)
    return lambda: _filter_reference(model, ref, out)

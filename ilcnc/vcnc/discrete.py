"""Discrete models of the drives: each profile drive as the exact sampled transfer function of its closed loop.

:func:`discrete_model` turns a profile drive (:mod:`ilcnc.profile.sections`) into a :class:`DiscreteModel`
at the servo period: the continuous plant of the loops the CNC closes (velocity drive, position loop,
feed-forward, friction-free part of the P-FF drive) discretised exactly (zero-order hold, dead time split
into whole periods and a fraction). The linear simulation (:mod:`ilcnc.vcnc.drives`), the learning gains
(:mod:`ilcnc.learning.time_design`) and the lifted map use the same models.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ilcnc.errors import IlcncError
from ilcnc.profile.sections import (
    DriveModel,
    FirstOrderDelayDrive,
    MassDamperPidDrive,
    PFfFrictionDrive,
    SopdtDrive,
    TransferFunctionDrive,
    has_position_loop,
)
from ilcnc.vcnc.lti import cont2discrete_zoh, ss2tf, tf2ss  # scipy.signal's, without its 1.5 s import

__all__ = ["DELAY_SNAP", "FRICTION_SUBSTEP_S", "STANDSTILL_MM", "DiscreteModel", "DriveModelError", "discrete_model"]

#: Longest sub-step of the friction loop, s (a 1 ms servo period gets 4 sub-steps). The linear
#: part of a sub-step is exact; only the friction force is held over it, so the error is first order
#: in the sub-step: on a 47 µm quadrant glitch (seed 001 profile, 150/200 N friction) 0.25 ms is
#: 0.07 µm off the limit of small sub-steps, one 1 ms step 0.3 µm.
FRICTION_SUBSTEP_S = 2.5e-4

#: A dead time within this many periods of a whole number of periods is taken as whole.
DELAY_SNAP = 1e-9

#: Reference steps shorter than this (mm) do not define a path direction (the axis stands).
STANDSTILL_MM = 1e-9


class DriveModelError(IlcncError, ValueError):
    """A drive model whose discrete closed loop is unstable (or not a valid model): the profile's values.

    Also a :class:`ValueError`, as it was before ilcnc's errors had one root."""




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
    ad, bd = cont2discrete_zoh(a, bb, dt)  # scipy.signal.cont2discrete's A, B (ilcnc.vcnc.lti: start-up)
    return ad, (bd[:, 0] if b.ndim == 1 else bd)


def _split_delay(delay_s: float, period_s: float) -> tuple[int, float]:
    """Whole periods ``d`` and fraction ``f`` of a dead time, ``Td = (d + f)·T``."""
    tau = delay_s / period_s
    d = math.floor(tau + DELAY_SNAP)
    f = tau - d
    return d, (0.0 if f < DELAY_SNAP else f)


def discretise(a: np.ndarray, b: np.ndarray, c: np.ndarray, period_s: float, delay_s: float = 0.0) -> _DiscreteSS:
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
class LoopPlant:
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


def _sopdt_plant(drive: SopdtDrive) -> LoopPlant:
    """Velocity command (mm/s) → position (mm): ``K ω0² e^{−sTd}/(s² + 2ζω0 s + ω0²) · 1/s``."""
    w0, z = drive.omega0_rad_s, drive.zeta
    a = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, -(w0**2), -2.0 * z * w0]])
    b = np.array([0.0, 0.0, drive.gain * w0**2])
    c = np.array([1.0, 0.0, 0.0])
    kv = drive.position_gain_1_s or 0.0
    return LoopPlant(a, b, c, kff=0.0, kerr=kv, delay_s=drive.delay_s)


def pff_plant(drive: PFfFrictionDrive) -> LoopPlant:
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
    return LoopPlant(
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


def loop_plant(drive: DriveModel) -> LoopPlant:
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
    return LoopPlant(a, b, c, kff=0.0, kerr=1.0)


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
        return _sampled_loop_model(loop_plant(drive), period_s)
    num, den = closed_continuous(drive)
    a, b, c = _tf_ss(num, den)
    delay = drive.delay_s if isinstance(drive, FirstOrderDelayDrive) else 0.0
    bn, an = discretise(a, b, c, period_s, delay).tf()
    return _model(bn, an, _dc_gain(num, den), period_s)


def _open_sopdt_model(drive: SopdtDrive, period_s: float) -> DiscreteModel:
    """Seed 004: the velocity drive fed with ``v[k] = (r[k] − r[k−1])/T``, position its integral.

    ``H = P(z)·(1 − z⁻¹)/T`` with ``P`` the exact ZOH model of ``V(s)/s``; the
    integrator pole of ``P`` (at z = 1) cancels the difference and is divided
    out of the denominator.
    """
    p = _sopdt_plant(drive)
    num, den = discretise(p.a, p.bu, p.c, period_s, p.delay_s).tf()
    # den = (1 − z⁻¹)·den'; den' by synthetic division (the remainder is rounding)
    den_red = np.cumsum(den)[:-1]
    return _model(num / period_s, den_red, drive.gain, period_s)


def _sampled_loop_model(p: LoopPlant, period_s: float) -> DiscreteModel:
    """A position loop closed by the CNC at the servo period around the exactly discretised plant.

    ``u = kff·(1 − z⁻¹)/T·r + kerr·(r − q)``, ``q = P u`` →
    ``q/r = P·F/(1 + kerr·P)`` with ``F = kff/T·(1 − z⁻¹) + kerr``.
    """
    pn, pd = discretise(p.a, p.bu, p.c, period_s, p.delay_s).tf()
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



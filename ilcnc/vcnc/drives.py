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
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ilcnc._jit import HAVE_NUMBA, njit, python_kernels
from ilcnc.errors import ProfileError
from ilcnc.profile.sections import (
    DriveModel,
    MachineProfile,
    PFfFrictionDrive,
)
from ilcnc.units import AXIS_NAMES
from ilcnc.vcnc.discrete import DiscreteModel, DriveModelError, discrete_model, loop_plant, pff_plant
from ilcnc.vcnc.drive_loop import direction_normals, friction_column, path_normals, run_loop

__all__ = [
    "HAVE_NUMBA",
    "DriveStream",
    "axis_response",
    "cross_coupled_response",
    "filter_deviation",
    "loop_response",
    "simulate_drives"
]

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
        from scipy.signal import lfilter  # the numpy path only: scipy.signal takes 1.5 s to import

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


def _deflated_stream_python(r, y, bn, an, g, r0, z, st):
    """:func:`_deflated_stream_kernel` for a small job run as Python (:func:`ilcnc._jit.python_kernels`): the
    same operations in the same order on Python floats (IEEE doubles, as numba's without fastmath), on
    lists instead of array elements: CPython indexes a list ~4x faster than an ndarray (star.ngc's three
    axes: 0.09 s as the kernel's own Python). The kernel's loop, with :func:`_deflated_step` inlined."""
    xs, b, a, zz = r.tolist(), bn.tolist(), an.tolist(), z.tolist()
    nf = len(a)
    out = [0.0] * len(xs)
    finite = True
    prev, seen = float(st[0]), float(st[1])
    isfinite = math.isfinite
    for k, x in enumerate(xs):
        if not isfinite(x):
            finite = False
        dev = x - r0
        step = dev - (prev if seen + k > 0 else dev)
        prev = dev
        yy = g * dev
        if nf > 1:
            lf = zz[0] + b[0] * step
            for i in range(nf - 2):
                zz[i] = zz[i + 1] + step * b[i + 1] - lf * a[i + 1]
            zz[nf - 2] = step * b[nf - 1] - lf * a[nf - 1]
            yy = yy + lf
        out[k] = r0 + yy
    y[:] = out
    z[:] = zz
    st[0] = prev
    st[1] = seen + len(xs)
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
        kernel = _deflated_stream_python if python_kernels() else _deflated_stream_kernel
        if not kernel(np.ascontiguousarray(ref), y, self.bn, self.an, self.g, self.r0, self.z, self.st):
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
        if nw > 1 and r.shape[0] >= _PARALLEL_SAMPLES and not python_kernels():  # Python kernels hold the GIL
            with ThreadPoolExecutor(max_workers=nw) as ex:
                list(ex.map(run, jobs))
        else:
            for job in jobs:
                run(job)
        return out


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
        return r[0] + run_loop([pff_plant(drive)], dev[:, None], period_s, np.zeros((1, 2)), 0.0)[:, 0]
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
        A drive with a position loop (see :func:`ilcnc.profile.sections.has_position_loop`).
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
    return r[0] + run_loop([loop_plant(drive)], (r - r[0])[:, None], period_s, np.zeros((1, 2)), 0.0)[:, 0]


def cross_coupled_response(
    drives: tuple[DriveModel, DriveModel], ref_mm: np.ndarray, period_s: float, gain: float,
    direction: np.ndarray | None = None,
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
    direction : ndarray, shape (N, 2), optional
        The contour direction θ of each sample (the desired path's tangent in the plane of the two axes, any
        length; ``controller.theta: desired``). Default: the direction of the reference itself.

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
    plants = [loop_plant(d) for d in drives]
    dev = r - r[0]
    if direction is None:
        normals = path_normals(r)
    else:
        direction = np.asarray(direction, dtype=float)
        if direction.shape != r.shape:
            raise ValueError(f"the contour direction must have the reference's shape {r.shape}, got {direction.shape}")
        normals = direction_normals(direction)
    return r[0] + run_loop(plants, dev, period_s, normals, gain)


def simulate_drives(
    ref_mm: np.ndarray, profile: MachineProfile, *, gain_schedule: Mapping[str, np.ndarray] | None = None,
    contour_direction: np.ndarray | None = None,
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
    contour_direction : ndarray, same shape as ``ref_mm``, optional
        Direction of the desired path at each sample (``controller.theta: desired``,
        :func:`ilcnc.vcnc.simulate.simulate_program` finds it): the cross-coupled controller takes θ from it
        instead of from the reference.

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
            way = None if contour_direction is None else np.asarray(contour_direction, dtype=float)[:, [i, j]]
            out[:, [i, j]] = cross_coupled_response(pair, r[:, [i, j]], period, ctl.cross_coupling_gain, way)
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
    if nw > 1 and r.shape[0] >= _PARALLEL_SAMPLES and not python_kernels():  # Python kernels hold the GIL
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
            friction_column(plant, ref, out, period_s, kerr)

        return run
    model = discrete_model(drive, period_s)
    return lambda: _filter_reference(model, ref, out)

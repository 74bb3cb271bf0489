"""Learning laws on per-command vectors, one class each, registered by the profile's name.

* ``p`` (seeds 002/004): ``U_{i+1} = U_i + Γ E_i``;
* ``pid_ace`` (seed 000): ``U_{i+1} = U_i + K_Pl e + K_Il ∫e dt + K_Dl ė`` of the
  actual contour error, with the integral and the backward-difference
  derivative ``(1 - z⁻¹)/Δt`` taken over the command time stamps and a lead of
  η servo periods;
* ``second_order`` (seed 003, eq. 2): ``U_{i+1} = P1 U_i + P2 U_{i-1} + Q1 Ė_i +
  Q2 Ė_{i-1}``, with the paper's derivative output ``Ŷ = Ẏ`` (eq. 4, so
  ``D = CB``) and its condition (3) checked before learning starts. Under a
  cross-coupled controller the law's input is the paper's ``ilc`` input,
  which enters the axis loops *after* the CCC (seed 003 Fig. 2); ilcnc
  corrects the program, which the CCC sees too, so the update is mapped
  through the inverse of the CCC's error map (:func:`ccc_error_map`).

Time alignment (the drives' ZOH: ``q[s]`` depends on ``r[0..s-1]``): ``E(k)``
is taken at the sample where the reference reaches command k's end, the
sample the correction ``U(k)`` moves, so ``U(k)`` first shows in ``E(k+1)``.
The backward difference of ``pid_ace`` with a lead of ``η = 1`` and the
forward difference of ``second_order`` both learn ``U(k)`` from the error
change ``E(k+1) - E(k)`` it drives (``(1 - z⁻¹)/T·z = (z - 1)/T``).

A new law is one class with :meth:`LearningLaw.next_correction` and one
entry in :data:`LAWS`.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ilcnc.errors import ProfileError
from ilcnc.profile.sections import LearningSection, MachineProfile
from ilcnc.program.model import MOVE_RAPID, Program
from ilcnc.units import AXIS_NAMES

__all__ = [
    "AXES", "LAWS", "LearningLaw", "PLaw", "PidAceLaw", "SecondOrderLaw", "ccc_error_map", "cut_runs",
    "first_markov_per_s", "make_law"
]

AXES = AXIS_NAMES

def cut_runs(program: Program) -> NDArray[np.int64]:
    """Run number of each command: consecutive commands with no rapid between them share a run.

    The Q-filter and the lead never reach across a rapid: the commands of two
    different cuts are unrelated.
    """
    mv = program.moves
    cm = program.command_moves
    if cm.size == 0:
        return np.zeros(0, np.int64)
    rapid_before = np.cumsum(mv.kind == MOVE_RAPID)
    r = rapid_before[cm]
    new = np.concatenate(([True], r[1:] != r[:-1]))
    return np.cumsum(new) - 1



def _gain_matrix(g: ArrayLike, k: int, what: str) -> NDArray[np.float64]:
    """A gain as per-command 3×3 matrices (K, 3, 3), or per-command diagonals (K, 3).

    Accepted: a scalar, a per-axis vector (3,), a per-command vector (K,), a
    per-command per-axis array (K, 3), a 3×3 matrix or (K, 3, 3).
    """
    a = np.asarray(g, dtype=np.float64)
    if a.ndim == 0:
        return np.full((k, 3), float(a))
    if a.shape == (3,) and k != 3:
        return np.broadcast_to(a, (k, 3)).copy()
    if a.shape == (k,):
        return np.repeat(a[:, None], 3, axis=1)
    if a.shape == (k, 3):
        return a.copy()
    if a.shape == (3, 3):
        return np.broadcast_to(a, (k, 3, 3)).copy()
    if a.shape == (k, 3, 3):
        return a.copy()
    raise ValueError(f"gain {what} has shape {a.shape}; expected scalar, (3,), ({k},), ({k}, 3), (3, 3) or ({k}, 3, 3)")


def _apply_gain(g: NDArray[np.float64], e: NDArray[np.float64]) -> NDArray[np.float64]:
    if g.ndim == 3:
        return np.einsum("kij,kj->ki", g, e)
    return g * e


# ---------------------------------------------------------------------------------------------
# The laws
# ---------------------------------------------------------------------------------------------


class LearningLaw:
    """Interface of a learning law on per-command vectors.

    A law turns the history of corrections ``U_0..U_i`` and errors ``E_0..E_i``
    (each (K, 3), mm; ``E`` already shifted by the lead) into ``U_{i+1}``.
    ``scale`` multiplies the error terms (the guard halves it).
    """

    name: ClassVar[str] = ""
    #: Past iterations the law needs (1: only U_i, E_i).
    memory: ClassVar[int] = 1

    def next_correction(
        self,
        u_hist: list[NDArray[np.float64]],
        e_hist: list[NDArray[np.float64]],
        t_hist: list[NDArray[np.float64]],
        *,
        scale: float = 1.0,
    ) -> NDArray[np.float64]:
        """Return ``U_{i+1}`` (K, 3), mm."""
        raise NotImplementedError

    def describe(self) -> dict[str, Any]:
        """Gains as plain numbers (for the state and the report)."""
        raise NotImplementedError

    @classmethod
    def from_profile(cls, profile: MachineProfile, program_commands: int) -> LearningLaw:
        """Build the law from the profile's ``learning`` section."""
        raise NotImplementedError


def _axis_gains(sec: LearningSection, name: str, profile: MachineProfile) -> NDArray[np.float64]:
    """Per-axis vector of a gain; axes the profile does not have get 0 (they are never corrected)."""
    out = np.zeros(3)
    for i, a in enumerate(AXES):
        if a in profile.axes:
            out[i] = sec.gain(name, a)
    return out


class PLaw(LearningLaw):
    """P-type (cascade) law, seeds 002/004: ``U_{i+1}(k) = U_i(k) + Γ(k) E_i(k)``.

    Parameters
    ----------
    gamma : scalar, (3,), (K,), (K, 3), (3, 3) or (K, 3, 3)
        Learning gain Γ: one number, per axis, per command, per command and
        axis, or a matrix (coupling the axes), dimensionless.
    n_commands : int
        K.
    """

    name = "p"

    def __init__(self, gamma: ArrayLike, n_commands: int) -> None:
        self.gamma_input = np.asarray(gamma, dtype=np.float64)
        self.gamma = _gain_matrix(gamma, n_commands, "gamma")

    @classmethod
    def from_profile(cls, profile: MachineProfile, program_commands: int) -> PLaw:
        return cls(_axis_gains(profile.learning, "gamma", profile), program_commands)

    def next_correction(self, u_hist, e_hist, t_hist, *, scale=1.0):
        return u_hist[-1] + scale * _apply_gain(self.gamma, e_hist[-1])

    def describe(self) -> dict[str, Any]:
        return {"gamma": self.gamma_input.tolist()}


def _time_integral(e: NDArray[np.float64], t: NDArray[np.float64], runs: NDArray[np.int64] | None) -> NDArray[np.float64]:
    """Running trapezoidal integral of ``e`` (K, 3) over the time stamps ``t``, restarting at every cut."""
    if e.shape[0] == 0:
        return e.copy()
    dt = np.diff(t, prepend=t[0])[:, None]
    avg = 0.5 * (e + np.vstack([e[:1], e[:-1]]))
    inc = avg * dt
    if runs is not None:
        inc[np.concatenate(([True], runs[1:] != runs[:-1]))] = 0.0
    out = np.cumsum(inc, axis=0)
    if runs is not None and runs.size:
        start = np.concatenate(([0], np.flatnonzero(np.diff(runs)) + 1))
        base = np.repeat(out[start] - inc[start], np.diff(np.concatenate((start, [runs.size]))), axis=0)
        out = out - base
    return out


def _difference(
    e: NDArray[np.float64], t: NDArray[np.float64], runs: NDArray[np.int64] | None, *, forward: bool
) -> NDArray[np.float64]:
    """``(e[k] - e[k-1]) / (t[k] - t[k-1])`` (backward) or the forward difference, 0 across cuts and zero time steps."""
    k = e.shape[0]
    d = np.zeros_like(e)
    if k < 2:
        return d
    de = np.diff(e, axis=0)
    dt = np.diff(t)
    same = np.ones(k - 1, bool) if runs is None else runs[1:] == runs[:-1]
    ok = same & (dt > 1e-12)
    q = np.where(ok[:, None], de / np.where(ok, dt, 1.0)[:, None], 0.0)
    if forward:
        d[:-1] = q
    else:
        d[1:] = q
    return d


class PidAceLaw(LearningLaw):
    """PID-type law on the actual contour error, seed 000 (eq. 20-21).

    ``U_{i+1}(k) = U_i(k) + K_Pl e(t_k + ηT) + K_Il ∫ e dt + K_Dl ė(t_k + ηT)``
    with ``ė`` the backward difference ``(1 - z⁻¹)/Δt`` over the command time
    stamps (the paper's printed operator is its conjugate and reverses the
    lead) and the integral restarting at every cut.

    Parameters
    ----------
    kp, ki, kd : (3,)
        K_Pl (1), K_Il (1/s), K_Dl (s) per axis.
    lead_samples : int
        Lead η in servo periods.
    period_s : float
        Servo period T, s.
    runs : ndarray (K,), optional
        Cut of each command (integral and derivative restart at a cut).
    """

    name = "pid_ace"

    def __init__(self, kp: ArrayLike, ki: ArrayLike, kd: ArrayLike, *, lead_samples: int = 0, period_s: float = 1e-3,
                 runs: NDArray[np.int64] | None = None) -> None:
        self.kp = np.broadcast_to(np.asarray(kp, dtype=np.float64), (3,)).copy()
        self.ki = np.broadcast_to(np.asarray(ki, dtype=np.float64), (3,)).copy()
        self.kd = np.broadcast_to(np.asarray(kd, dtype=np.float64), (3,)).copy()
        self.lead_samples = int(lead_samples)
        self.period_s = float(period_s)
        self.runs = runs

    @classmethod
    def from_profile(cls, profile: MachineProfile, program_commands: int) -> PidAceLaw:
        sec = profile.learning
        return cls(_axis_gains(sec, "kp", profile), _axis_gains(sec, "ki", profile), _axis_gains(sec, "kd", profile),
                   lead_samples=int(sec.gains.get("lead_samples", 0)), period_s=profile.machine.servo_period_s)

    def _shift(self, e: NDArray[np.float64], t: NDArray[np.float64]) -> NDArray[np.float64]:
        if self.lead_samples == 0 or e.shape[0] < 2:
            return e
        tq = t + self.lead_samples * self.period_s
        out = np.empty_like(e)
        tt = np.maximum.accumulate(t)
        for a in range(3):
            out[:, a] = np.interp(tq, tt, e[:, a])
        return out

    def next_correction(self, u_hist, e_hist, t_hist, *, scale=1.0):
        e, t = e_hist[-1], t_hist[-1]
        el = self._shift(e, t)
        du = self.kp * el
        if np.any(self.kd):
            du = du + self.kd * _difference(el, t, self.runs, forward=False)
        if np.any(self.ki):
            du = du + self.ki * _time_integral(el, t, self.runs)
        return u_hist[-1] + scale * du

    def describe(self) -> dict[str, Any]:
        return {"kp": self.kp.tolist(), "ki": self.ki.tolist(), "kd": self.kd.tolist(), "lead_samples": self.lead_samples}


def first_markov_per_s(profile: MachineProfile, axis: str) -> float:
    """``D = CB`` of an axis's closed loop from reference to position, 1/s (0 if its relative degree is not one).

    Seed 003 (eq. 4): with no feed-through, the law learns on the derivative
    output ``Ẏ = CAX + CBU``, so its ``D`` is ``CB = lim s·T(s)`` of the loop
    ``T(s)``: the ratio of the leading coefficients when the denominator's
    degree is one more than the numerator's, 0 otherwise (a drive with dead
    time or relative degree two has no such ``D``).
    """
    from ilcnc.profile.sections import FirstOrderDelayDrive, SopdtDrive
    from ilcnc.vcnc.discrete import closed_continuous

    drive = profile.axes[axis].drive
    if isinstance(drive, (SopdtDrive, FirstOrderDelayDrive)) and getattr(drive, "delay_s", 0.0):
        return 0.0
    try:
        num, den = closed_continuous(drive)
    except Exception:
        return 0.0
    num = np.trim_zeros(np.atleast_1d(np.asarray(num, dtype=np.float64)), "f")
    den = np.trim_zeros(np.atleast_1d(np.asarray(den, dtype=np.float64)), "f")
    if num.size == 0 or den.size - num.size != 1:
        return 0.0
    return float(num[0] / den[0])


class SecondOrderLaw(LearningLaw):
    """Second-order law, seed 003 eq. (2), on the derivative output (eq. 4).

    ``U_{i+1} = P1 U_i + P2 U_{i-1} + Q1 Ė_i + Q2 Ė_{i-1}`` with ``Ė`` the
    forward difference of ``E`` over the command time stamps (the correction
    of a command acts on the following samples: that is the lead of one that
    relative degree one asks for). Condition (3) -- ``P1 + P2 = I`` and
    ``‖P1 - Q1 D‖∞ + ‖P2 - Q2 D‖∞ < 1`` with ``D = CB`` -- is checked by
    :meth:`condition`.

    With ``coupling`` (a cross-coupled controller, :func:`ccc_error_map`) the
    law runs on the paper's input ``Ũ = M U`` -- what the axis loops get
    after the CCC multiplied the program's correction ``U`` by ``M`` -- and
    returns ``U_{i+1} = M⁻¹ Ũ_{i+1}``: the gains and condition (3) are the
    paper's (``D = CB`` of the axes, seed 003 §II.C), not those of the
    stiffer loop ``D·M`` that a correction of the program meets (with
    ``C = 20`` on a 45° line ``‖I - Q1·D·M‖∞ = 20``: the printed law
    applied to the program diverges).

    Parameters
    ----------
    p1, p2, q1, q2 : (3,)
        Diagonals per axis (P dimensionless, Q in s).
    runs : ndarray (K,), optional
        Cut of each command (the difference is 0 across a cut).
    coupling : ndarray (K, 3, 3), optional
        The CCC's error map ``M`` at every command (``None``: independent axes).
    """

    name = "second_order"
    memory = 2

    def __init__(self, p1: ArrayLike, p2: ArrayLike, q1: ArrayLike, q2: ArrayLike, *,
                 runs: NDArray[np.int64] | None = None, coupling: NDArray[np.float64] | None = None) -> None:
        self.p1, self.p2, self.q1, self.q2 = (np.broadcast_to(np.asarray(v, dtype=np.float64), (3,)).copy()
                                              for v in (p1, p2, q1, q2))
        self.runs = runs
        self.coupling = coupling

    @classmethod
    def from_profile(cls, profile: MachineProfile, program_commands: int) -> SecondOrderLaw:
        sec = profile.learning
        p1 = np.array([sec.gain("p1", a) if a in profile.axes else 1.0 for a in AXES])
        p2 = np.array([sec.gain("p2", a) if a in profile.axes else 0.0 for a in AXES])
        return cls(p1, p2, _axis_gains(sec, "q1", profile), _axis_gains(sec, "q2", profile))

    def condition(self, d_per_s: ArrayLike, axes: tuple[str, ...] = AXES) -> tuple[bool, str, float]:
        """Seed 003's condition (3) with ``D = diag(d_per_s)``.

        Returns
        -------
        ok : bool
        reason : str
            Why it fails ("" when it holds).
        value : float
            ``‖P1 - Q1 D‖∞ + ‖P2 - Q2 D‖∞`` over the axes given.
        """
        d = np.asarray(d_per_s, dtype=np.float64)
        idx = [AXES.index(a) for a in axes]
        s = self.p1 + self.p2
        bad = [AXES[i] for i in idx if abs(s[i] - 1.0) > 1e-9]
        if bad:
            return False, f"P1 + P2 must be I (axis {', '.join(bad)}: P1 + P2 = {s[AXES.index(bad[0])]:g})", math.nan
        zero = [AXES[i] for i in idx if d[i] == 0.0]
        if zero:
            return (False, f"the drive of axis {', '.join(zero)} has no D = CB (dead time or relative degree above"
                           " one): the derivative-output law does not apply; use law p", math.nan)
        a = max(abs(self.p1[i] - self.q1[i] * d[i]) for i in idx)
        b = max(abs(self.p2[i] - self.q2[i] * d[i]) for i in idx)
        val = a + b
        if not val < 1.0:
            return False, f"‖P1 - Q1·D‖ + ‖P2 - Q2·D‖ = {a:.4g} + {b:.4g} = {val:.4g} is not < 1 (D = CB = " \
                          + ", ".join(f"{AXES[i]} {d[i]:.4g}/s" for i in idx) + ")", val
        return True, "", val

    def next_correction(self, u_hist, e_hist, t_hist, *, scale=1.0):
        m = self.coupling
        if m is not None:
            u_hist = [np.einsum("kij,kj->ki", m, u) for u in u_hist]
        u1 = u_hist[-1]
        u0 = u_hist[-2] if len(u_hist) > 1 else u_hist[-1]
        de1 = _difference(e_hist[-1], t_hist[-1], self.runs, forward=True)
        out = self.p1 * u1 + self.p2 * u0 + scale * self.q1 * de1
        if len(e_hist) > 1 and np.any(self.q2):
            out = out + scale * self.q2 * _difference(e_hist[-2], t_hist[-2], self.runs, forward=True)
        if m is not None:
            out = np.linalg.solve(m, out[..., None])[..., 0]
        return out

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {"p1": self.p1.tolist(), "p2": self.p2.tolist(), "q1": self.q1.tolist(),
                               "q2": self.q2.tolist()}
        if self.coupling is not None:
            out["ccc_compensated"] = True
        return out


def ccc_error_map(profile: MachineProfile, program: Program) -> NDArray[np.float64] | None:
    """The cross-coupled controller's error map ``M = I + C·n·nᵀ`` at every command, (K, 3, 3).

    Seed 003 §II.B (Fig. 1), as :mod:`ilcnc.vcnc.drives` runs it: with ``n`` the
    unit normal of the path in the plane of the two coupled axes, each axis
    loop is fed ``e' = e + C·(e·n)·n = M·e``. A correction ``U`` of the
    program's reference therefore reaches the axis loops as ``M·U``. ``n`` is
    taken from the programmed path at command k's end (the bisector of the
    command's move and the next one, :func:`ilcnc.vcnc.command_error.command_end_tangents`),
    held from the previous command where the path has no direction in the
    plane (a plunge), like the controller holds it where the reference
    stands still.

    Returns
    -------
    ndarray (K, 3, 3) or None
        ``None`` when the profile's controller is not cross-coupled (or an
        axis it couples is missing).
    """
    ctl = profile.controller
    if ctl.type != "cross_coupled" or not all(a in profile.axes for a in ctl.coupled_axes):
        return None
    from ilcnc.contour.path import PathGeometry
    from ilcnc.vcnc.command_error import command_end_tangents

    i, j = (AXES.index(a) for a in ctl.coupled_axes)
    kk = program.n_commands
    t = command_end_tangents(PathGeometry.from_moves(program.moves)) if kk else np.zeros((0, 3))
    tp = t[:, [i, j]]
    norm = np.hypot(tp[:, 0], tp[:, 1])
    ok = norm > 1e-9
    if ok.any():
        idx = np.where(ok, np.arange(kk), -1)
        idx = np.maximum.accumulate(idx)
        idx[idx < 0] = int(np.argmax(ok))
        tp = tp[idx] / norm[idx, None]
    else:
        tp = np.tile([1.0, 0.0], (kk, 1))
    n = np.zeros((kk, 3))
    n[:, i] = -tp[:, 1]
    n[:, j] = tp[:, 0]
    return np.eye(3) + float(ctl.cross_coupling_gain) * np.einsum("ki,kj->kij", n, n)


#: Registry: profile name → law class.
LAWS: dict[str, type[LearningLaw]] = {c.name: c for c in (PLaw, PidAceLaw, SecondOrderLaw)}


def make_law(profile: MachineProfile, program: Program) -> LearningLaw:
    """The profile's law for a program, checked (seed 003's condition (3) for ``second_order``).

    A ``second_order`` law under a cross-coupled controller gets the CCC's
    error map (:func:`ccc_error_map`) so it learns on the paper's input.

    Parameters
    ----------
    profile : MachineProfile
        The machine profile (its ``learning`` and ``controller`` sections).
    program : Program
        The original program (commands, cuts, path directions).

    Returns
    -------
    LearningLaw

    Raises
    ------
    ProfileError
        The gains break the law's convergence condition (naming the reason).
    """
    sec = profile.learning
    cls = LAWS[sec.law]
    law = cls.from_profile(profile, program.n_commands)
    runs = cut_runs(program)
    if isinstance(law, (PidAceLaw, SecondOrderLaw)):
        law.runs = runs
    if isinstance(law, SecondOrderLaw):
        # the paper's ILC input enters after the CCC: learn on it (condition (3) is then the paper's)
        law.coupling = ccc_error_map(profile, program)
        axes = tuple(a for a in AXES if a in profile.axes)
        d = np.array([first_markov_per_s(profile, a) if a in profile.axes else 0.0 for a in AXES])
        ok, reason, _v = law.condition(d, axes)
        if not ok:
            raise ProfileError(profile.path or "profile", None,
                               f"learning.gains: law second_order refused: condition (3) of seed 003 fails: {reason}")
    return law



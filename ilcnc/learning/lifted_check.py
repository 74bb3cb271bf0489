"""The lifted map of the command-index law (seed 004) and its convergence check.

``lifted`` -- the command-index law ``U_{i+1}(k) = U_i(k) + Γ E_i(k)`` of seed 004 (:func:`check_lifted`)
    The lifted map ``G`` (``E(U) ≈ E_0 − G U`` on the program) is built by
    simulation, column by column, with the planner's time law held fixed: a
    correction of end point k moves the planned reference by the hat of the
    two moves that meet there, the linear drives turn that into an actual
    motion (exact superposition: only the few hundred samples the hat and the
    drive's settling touch are simulated), and the profile's own error
    estimate (:mod:`ilcnc.vcnc.command_error`) turns it into ``E``. With the update
    shaper of :mod:`ilcnc.learning.learner` (lead, zero-phase Q-filter ``Q``) the error
    propagates as ``E_{i+1} = (I − G Q Γ S) E_i``; monotone convergence in the
    2-norm is ``‖I − G Q Γ S‖₂ < 1`` on the errors the estimate can produce
    (normal to the path: a tangential shift of an end point moves no contour
    error, so those directions have eigenvalue 1 and are left out), and
    asymptotic convergence is a spectral radius ≤ 1. Γ and the Q-filter
    cut-off are chosen from candidates.

Nothing here prints; :mod:`ilcnc.learning.tune` is what ``ilcnc tune`` calls.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.jsonout import json_float
from ilcnc.outcomes import LiftedStatus
from ilcnc.profile.sections import MachineProfile, PFfFrictionDrive
from ilcnc.units import AXIS_NAMES

__all__ = [
    "DEFAULT_GAMMAS", "DEFAULT_MAX_COMMANDS", "DEFAULT_Q_FILTERS_HZ", "LiftedCandidate", "LiftedCheck",
    "LiftedModel", "check_lifted", "lifted_model"
]


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
#: Commands next to an end of the window that cuts through a run (the program goes on there) whose modes
#: belong to the cut, not to the program: a mode with more than half its energy on them is a window-edge mode.
EDGE_COMMANDS = 10


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
    from ilcnc.vcnc.discrete import discrete_model
    from ilcnc.vcnc.drives import filter_deviation

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
    from ilcnc.vcnc.command_error import command_end_tangents

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
    from ilcnc.contour.search import ContourError, contour_error
    from ilcnc.learning.learner import Learner
    from ilcnc.vcnc.command_error import (
        error_kind,
        measurement_gate_mm,
        path_weighted_error,
        signal_of_simulation,
    )
    from ilcnc.vcnc.discrete import discrete_model
    from ilcnc.vcnc.drives import filter_deviation, simulate_drives
    from ilcnc.vcnc.lifted import sample_fractions
    from ilcnc.vcnc.simulate import simulate_program

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


@dataclass(frozen=True, kw_only=True)
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
    spectral_radius_inner : float
        ``spectral_radius`` over the modes that do not have more than half their energy
        on the :data:`EDGE_COMMANDS` commands next to an end of the window that cuts
        through a run (the same as ``spectral_radius`` when the window ends where runs
        end). Cutting the lifted map of a non-normal iteration to a window makes modes
        whose eigenvectors pile up at the cut and move with it when the window moves
        (``bench/lifted_modes.py``); the program has no edge there. Reported, not judged:
        ``status`` stays with ``spectral_radius`` (the conservative reading).
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
    status: LiftedStatus
    spectral_radius_inner: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return {"gamma": self.gamma, "q_filter_hz": self.q_filter_hz, "norm": self.norm, "norm_full": self.norm_full,
                "spectral_radius": self.spectral_radius, "spectral_radius_full": self.spectral_radius_full,
                "spectral_radius_inner": self.spectral_radius_inner,
                "predicted_ratio": self.predicted_ratio,
                "predicted_ratio_n": self.predicted_ratio_n, "iterations": self.iterations, "status": self.status}


@dataclass(frozen=True, eq=False, kw_only=True)
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
                        "epsilon": json_float(c.norm), "peak_hz": None, "converges": self.converges,
                        "monotone": self.monotone, "spectral_radius": json_float(c.spectral_radius),
                        "contraction": json_float(self.contraction), "reason": self.reason} for a in axes}
        return {"method": "lifted", "axes": per_axis,
                "lifted": {"window": list(m.window), "coordinates": m.n, "error": m.kind, "linear": m.linear,
                           "simulations": m.simulations, "build_s": m.elapsed_s,
                           "chosen": c.to_json(), "candidates": [x.to_json() for x in self.candidates]}}


def _q_matrix(model: LiftedModel, runs: NDArray[np.int64], correctable: NDArray[np.bool_], q_hz: float | None,
              lead: int, period_s: float) -> NDArray[np.float64]:
    """The shaper's linear map on the window, ``ΔU = Q S E`` (per axis the same), as an (n, n) matrix."""
    from ilcnc.learning.learner import UpdateShaper

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
    from ilcnc.learning.laws import cut_runs
    from ilcnc.learning.learner import correctable_commands

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
    edge = _cut_edge_rows(mdl, runs)
    cands: list[LiftedCandidate] = []
    with _one_blas_thread():
        for q in qs:
            qm = _q_matrix(mdl, runs, corr, q, lead, period)
            gq = mdl.g @ qm
            for gam in gs:
                cands.append(_candidate(eye - gam * gq, b, e0, e0n, gam, q, n_it, edge))
    mono = [c for c in cands if c.status == LiftedStatus.MONOTONE]
    asym = [c for c in cands if c.status == LiftedStatus.ASYMPTOTIC]
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
    if chosen.spectral_radius > 1.0 + RHO_TOL >= chosen.spectral_radius_inner:
        k0, k1 = mdl.window
        reason += (f"; every growing mode sits at an end of the window (commands {k0}..{k1 - 1}) that cuts through"
                   f" the program (ρ away from those ends {chosen.spectral_radius_inner:.6f}): cutting a non-normal"
                   " iteration to a window makes such modes, so this reading is conservative")
    if chosen.spectral_radius_full > 1.0 + RHO_TOL:
        reason = (reason + "; " if reason else "") + (
            f"a tangential mode of the corrections grows (ρ on all coordinates {chosen.spectral_radius_full:.6f}):"
            " it moves no contour error, but the corrections creep along the path")
    return LiftedCheck(model=mdl, candidates=tuple(cands), chosen=chosen,
                       converges=chosen.status != LiftedStatus.DIVERGENT,
                       monotone=chosen.status == LiftedStatus.MONOTONE, contraction=float(contraction), reason=reason,
                       lead_commands=lead)


def _cut_edge_rows(model: LiftedModel, runs: NDArray[np.int64]) -> NDArray[np.bool_]:
    """(n,) rows of the commands within :data:`EDGE_COMMANDS` of an end of the window that cuts through a run."""
    k0, k1 = model.window
    cmd = model.command
    near = np.zeros(cmd.shape[0], dtype=bool)
    if 0 < k0 < runs.shape[0] and runs[k0 - 1] == runs[k0]:
        near |= cmd < k0 + EDGE_COMMANDS
    if 0 < k1 < runs.shape[0] and runs[k1] == runs[k1 - 1]:
        near |= cmd >= k1 - EDGE_COMMANDS
    return near


def _radii(mn: NDArray[np.float64], b: NDArray[np.float64], edge: NDArray[np.bool_]) -> tuple[float, float]:
    """ρ of ``mn = BᵀMB`` over all modes, and over the modes away from the window's cut edges."""
    if not edge.any():
        rho = float(np.max(np.abs(np.linalg.eigvals(mn))))
        return rho, rho
    lam, vec = np.linalg.eig(mn)
    energy = np.abs(b @ vec) ** 2
    at_edge = energy[edge].sum(axis=0) > 0.5 * energy.sum(axis=0)
    mag = np.abs(lam)
    return float(mag.max()), float(mag[~at_edge].max()) if (~at_edge).any() else 0.0


def _candidate(m: NDArray[np.float64], b: NDArray[np.float64], e0: NDArray[np.float64], e0n: float, gamma: float,
               q: float | None, n_it: int, edge: NDArray[np.bool_]) -> LiftedCandidate:
    """Norms, spectral radii and the predicted error ratios of one iteration matrix ``m`` (``edge``: the rows of
    :func:`_cut_edge_rows`)."""
    mb = m @ b
    nb = float(np.linalg.norm(mb, 2)) if b.shape[1] else 0.0
    nf = float(np.linalg.norm(m, 2))
    rho_n, rho_i = _radii(b.T @ mb, b, edge) if b.shape[1] else (0.0, 0.0)
    rho_f = float(np.max(np.abs(np.linalg.eigvals(m))))
    if e0n > 0:
        r1 = float(np.linalg.norm(m @ e0) / e0n)
        e = e0.copy()
        for _ in range(n_it):
            e = m @ e
        rn = float(np.linalg.norm(e) / e0n)
    else:
        r1 = rn = 0.0
    if nb < 1.0:
        status = LiftedStatus.MONOTONE
    else:
        status = LiftedStatus.ASYMPTOTIC if rho_n <= 1.0 + RHO_TOL else LiftedStatus.DIVERGENT
    return LiftedCandidate(gamma=gamma, q_filter_hz=q, norm=nb, norm_full=nf, spectral_radius=rho_n,
                           spectral_radius_full=rho_f, predicted_ratio=r1, predicted_ratio_n=rn, iterations=n_it,
                           status=status, spectral_radius_inner=rho_i)


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



"""The loaded machine profile: one frozen dataclass per section of the YAML file, in mm and s.

:class:`MachineProfile` is what every command receives: per axis the kinematic limits and the drive model
(:class:`SopdtDrive`, :class:`MassDamperPidDrive`, :class:`PFfFrictionDrive`, :class:`FirstOrderDelayDrive`,
:class:`TransferFunctionDrive`), then the machine, controller, planner, learning (with refinement), output,
geometry, tool, cutting and tuning sections. Defaults come from the schema table
(:data:`ilcnc.profile.schema.SPECS`); values are checked before they get here (:mod:`ilcnc.profile.load`).
Lengths are millimetres and times seconds unless the key name says otherwise; :class:`AxisProfile` converts
to mm and s.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar

import yaml

from ilcnc.errors import InputError
from ilcnc.profile.schema import DRIVE_KEY, default_of
from ilcnc.units import LENGTH_UNITS, MM_PER_INCH

__all__ = [
    "DRIVE_MODELS",
    "MODE_KEYS",
    "AxisProfile",
    "ControllerSection",
    "DriveModel",
    "FirstOrderDelayDrive",
    "LearningSection",
    "MachineProfile",
    "MachineSection",
    "MassDamperPidDrive",
    "OutputSection",
    "PFfFrictionDrive",
    "PlannerSection",
    "ProfileDumper",
    "ScheduleTuning",
    "SopdtDrive",
    "TransferFunctionDrive",
    "TuningSection",
    "has_position_loop"
]


class ProfileDumper(yaml.SafeDumper):
    """Safe dumper writing mappings in block style and short lists (``[min, max]``) in flow style."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def _represent_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=True)


ProfileDumper.add_representer(list, _represent_list)



# --------------------------------------------------------------------------
# The profile dataclasses
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class SopdtDrive:
    """Second-order-plus-dead-time velocity drive (seed 004).

    ``v(s) / v_cmd(s) = gain·ω0² e^{-Td s} / (s² + 2ζω0 s + ω0²)``; the axis
    position is the integral of ``v``. Without a position loop the velocity
    command is the reference velocity; with ``position_gain_1_s`` = Kv it is
    ``Kv·(reference − position)``.

    Parameters
    ----------
    omega0_rad_s : float
        Natural frequency ω0, rad/s.
    zeta : float
        Damping ratio ζ, dimensionless.
    gain : float
        Static velocity gain K, dimensionless (normally 1).
    delay_s : float
        Dead time Td, s.
    position_gain_1_s : float or None
        Position loop gain Kv, 1/s; ``None`` for no position loop.
    """

    model: ClassVar[str] = "sopdt"
    omega0_rad_s: float
    zeta: float
    gain: float = default_of(f"{DRIVE_KEY}.gain", "sopdt")
    delay_s: float = default_of(f"{DRIVE_KEY}.delay_s", "sopdt")
    position_gain_1_s: float | None = default_of(f"{DRIVE_KEY}.position_gain_1_s", "sopdt")


@dataclass(frozen=True)
class MassDamperPidDrive:
    """Mass-damper axis under a position PID (seed 000).

    ``m·q̈ + c·q̇ = u`` with ``u = kp·e + ki·∫e dt + kd·ė`` and ``e = r − q``.

    Parameters
    ----------
    mass_v_s2_mm : float
        Mass m, V·s²/mm.
    damping_v_s_mm : float
        Damping c, V·s/mm.
    kp : float
        Proportional gain, V/mm.
    ki : float
        Integral gain, V/(mm·s).
    kd : float
        Derivative gain, V·s/mm.
    """

    model: ClassVar[str] = "mass_damper_pid"
    mass_v_s2_mm: float
    damping_v_s_mm: float
    kp: float
    ki: float
    kd: float


@dataclass(frozen=True)
class PFfFrictionDrive:
    """P position loop with velocity feed-forward and a friction-loaded axis (seed 001).

    The velocity command is ``kff·ṙ + Kv·(r − q)`` with
    ``Kv = kp_m_min_mm`` (m/min)/mm ``= kp_1_s`` 1/s. The velocity loop is a
    proportional controller on the moving mass with force gain
    ``2π·velocity_bandwidth_hz·inertia_kg`` (a first-order velocity loop
    without friction), or a PI controller when ``velocity_integral_time_s``
    is given. Friction opposes the motion with
    ``F(v) = sign(v)·[F_c + (F_s − F_c)·exp(−(v/v_s)²)] + B·v``.

    Parameters
    ----------
    kp_m_min_mm : float
        Position loop gain, (m/min)/mm.
    kff : float
        Velocity feed-forward gain, dimensionless.
    velocity_bandwidth_hz : float
        Velocity loop bandwidth, Hz.
    velocity_integral_time_s : float or None
        Integral time of a PI velocity loop, s (``None``: P velocity loop).
    inertia_kg : float or None
        Moving mass, kg (``None`` when there is no friction).
    coulomb_n : float
        Coulomb friction F_c, N.
    viscous_n_s_mm : float
        Viscous friction B, N·s/mm.
    static_n : float
        Static friction F_s, N (0: no Stribeck peak).
    stribeck_velocity_mm_s : float
        Stribeck velocity v_s, mm/s.
    """

    model: ClassVar[str] = "p_ff_friction"
    kp_m_min_mm: float
    kff: float = default_of(f"{DRIVE_KEY}.kff", "p_ff_friction")
    velocity_bandwidth_hz: float = default_of(f"{DRIVE_KEY}.velocity_bandwidth_hz", "p_ff_friction")
    velocity_integral_time_s: float | None = default_of(f"{DRIVE_KEY}.velocity_integral_time_s", "p_ff_friction")
    inertia_kg: float | None = default_of(f"{DRIVE_KEY}.inertia_kg", "p_ff_friction")
    coulomb_n: float = default_of(f"{DRIVE_KEY}.coulomb_n", "p_ff_friction")
    viscous_n_s_mm: float = default_of(f"{DRIVE_KEY}.viscous_n_s_mm", "p_ff_friction")
    static_n: float = default_of(f"{DRIVE_KEY}.static_n", "p_ff_friction")
    stribeck_velocity_mm_s: float = default_of(f"{DRIVE_KEY}.stribeck_velocity_mm_s", "p_ff_friction")

    @property
    def kp_1_s(self) -> float:
        """Position loop gain in 1/s (``kp_m_min_mm · 1000 / 60``)."""
        return self.kp_m_min_mm * 1000.0 / 60.0

    @property
    def has_friction(self) -> bool:
        """True when any friction term is non-zero."""
        return self.coulomb_n > 0 or self.viscous_n_s_mm > 0 or self.static_n > 0


@dataclass(frozen=True)
class FirstOrderDelayDrive:
    """Closed position loop as a first-order lag with dead time.

    ``q(s) / r(s) = gain·e^{-Td s} / (T s + 1)``.

    Parameters
    ----------
    time_constant_s : float
        Time constant T, s (1/Kv of a P position loop).
    delay_s : float
        Dead time Td, s.
    gain : float
        Static gain, dimensionless.
    """

    model: ClassVar[str] = "first_order_delay"
    time_constant_s: float
    delay_s: float = default_of(f"{DRIVE_KEY}.delay_s", "first_order_delay")
    gain: float = default_of(f"{DRIVE_KEY}.gain", "first_order_delay")


@dataclass(frozen=True)
class TransferFunctionDrive:
    """An axis given as a rational transfer function in s (seed 003).

    With ``feedback = "unity"`` the polynomials are the forward path
    ``L(s) = numerator(s) / denominator(s)`` from position error (mm) to
    position (mm) — position controller times axis, like seed 003's
    ``G1 = (2s + 11.76)/(s² + 12s)`` — and the closed loop is
    ``q/r = L/(1 + L)``. With ``feedback = "none"`` they are the closed loop
    ``q/r`` itself.

    Parameters
    ----------
    numerator : tuple of float
        Coefficients in descending powers of s (units make the ratio mm/mm).
    denominator : tuple of float
        Coefficients in descending powers of s; more of them than the
        numerator (strictly proper).
    feedback : str
        ``"unity"`` or ``"none"``.
    """

    model: ClassVar[str] = "transfer_function"
    numerator: tuple[float, ...]
    denominator: tuple[float, ...]
    feedback: str = default_of(f"{DRIVE_KEY}.feedback", "transfer_function")


#: Any drive model.
DriveModel = SopdtDrive | MassDamperPidDrive | PFfFrictionDrive | FirstOrderDelayDrive | TransferFunctionDrive

#: Drive model name (``axes.<axis>.drive.model``) to its dataclass.
DRIVE_MODELS: dict[str, type[DriveModel]] = {
    cls.model: cls
    for cls in (SopdtDrive, MassDamperPidDrive, PFfFrictionDrive, FirstOrderDelayDrive, TransferFunctionDrive)
}


def _drive_params(drive: DriveModel) -> dict[str, Any]:
    return {f.name: (list(v) if isinstance(v := getattr(drive, f.name), tuple) else v) for f in fields(drive)}


def has_position_loop(drive: DriveModel) -> bool:
    """True when ``drive`` closes a position loop that a cross-coupled controller can act on.

    Parameters
    ----------
    drive : DriveModel
        The drive model.

    Returns
    -------
    bool
        ``True`` for mass_damper_pid, p_ff_friction, sopdt with a position
        gain and transfer_function with unity feedback; ``False`` for
        first_order_delay (a closed loop given as a whole), sopdt without a
        position loop and transfer_function without feedback.
    """
    if isinstance(drive, (MassDamperPidDrive, PFfFrictionDrive)):
        return True
    if isinstance(drive, SopdtDrive):
        return drive.position_gain_1_s is not None
    if isinstance(drive, TransferFunctionDrive):
        return drive.feedback == "unity"
    return False


@dataclass(frozen=True)
class AxisProfile:
    """Kinematic limits and drive model of one axis.

    Parameters
    ----------
    name : str
        Axis name, ``"x"``, ``"y"`` or ``"z"``.
    max_velocity_mm_min : float
        Maximum feed, mm/min.
    max_acceleration_m_s2 : float
        Maximum acceleration, m/s².
    max_jerk_m_s3 : float
        Maximum jerk, m/s³.
    rapid_mm_min : float
        Rapid velocity, mm/min.
    drive : DriveModel
        The drive model.
    """

    name: str
    max_velocity_mm_min: float
    max_acceleration_m_s2: float
    max_jerk_m_s3: float
    rapid_mm_min: float
    drive: DriveModel

    @property
    def max_velocity_mm_s(self) -> float:
        """Maximum feed in mm/s."""
        return self.max_velocity_mm_min / 60.0

    @property
    def rapid_mm_s(self) -> float:
        """Rapid velocity in mm/s."""
        return self.rapid_mm_min / 60.0

    @property
    def max_acceleration_mm_s2(self) -> float:
        """Maximum acceleration in mm/s²."""
        return self.max_acceleration_m_s2 * 1000.0

    @property
    def max_jerk_mm_s3(self) -> float:
        """Maximum jerk in mm/s³."""
        return self.max_jerk_m_s3 * 1000.0


@dataclass(frozen=True)
class MachineSection:
    """The ``machine:`` section.

    Parameters
    ----------
    name : str
        Machine name.
    units : str
        ``"mm"`` or ``"inch"``: program units when a program does not say.
    servo_period_s : float
        Servo period, s.
    resolution_mm : float
        Smallest increment, mm.
    travel_mm : dict of str to (float, float)
        Travel ``(min, max)`` per axis, mm; empty when not given.
    """

    name: str
    units: str = default_of("machine.units")
    servo_period_s: float = default_of("machine.servo_period_s")
    resolution_mm: float = default_of("machine.resolution_mm")
    travel_mm: dict[str, tuple[float, float]] = field(default_factory=dict)


@dataclass(frozen=True)
class ControllerSection:
    """The ``controller:`` section.

    Parameters
    ----------
    type : str
        ``"independent"`` or ``"cross_coupled"``.
    cross_coupling_gain : float
        Cross-coupling gain C, dimensionless.
    coupled_axes : tuple of (str, str)
        The two coupled axes.
    theta : str
        ``"reference"`` or ``"desired"``: the path the controller takes the contour direction θ from.
    """

    type: str = default_of("controller.type")
    cross_coupling_gain: float = default_of("controller.cross_coupling_gain")
    coupled_axes: tuple[str, str] = default_of("controller.coupled_axes")
    theta: str = default_of("controller.theta")


@dataclass(frozen=True)
class PlannerSection:
    """The ``planner:`` section.

    Parameters
    ----------
    profile : str
        ``"seven_phase"``, ``"cubic"``, ``"constant_feed"`` or ``"linuxcnc"``.
    corner_tolerance_mm : float
        Corner tolerance, mm.
    path_control : str
        ``"tolerance"``, ``"g64"``, ``"g61"`` or ``"g61.1"``: the mode of moves the program sets none for.
    in_position_s : float
        Stand-still between rapids and feed moves, s.
    lookahead_blocks : int
        Look-ahead depth in blocks.
    jerk_time_constant_s : float
        Jerk ramp time of the cubic profile, s.
    arc_tolerance_mm : float
        Chord tolerance for arcs, mm.
    """

    profile: str = default_of("planner.profile")
    corner_tolerance_mm: float = default_of("planner.corner_tolerance_mm")
    path_control: str = default_of("planner.path_control")
    in_position_s: float = default_of("planner.in_position_s")
    lookahead_blocks: int = default_of("planner.lookahead_blocks")
    jerk_time_constant_s: float = default_of("planner.jerk_time_constant_s")
    arc_tolerance_mm: float = default_of("planner.arc_tolerance_mm")


@dataclass(frozen=True)
class RefineSection:
    """The ``learning.refine:`` section (:mod:`ilcnc.learning.refine`).

    Parameters
    ----------
    enabled : str
        ``"on"``: refine without ``--refine``.
    corner_angle_deg : float
        Turning angle above which a corner between straight feeds is refined, degrees.
    points_per_side : int
        Most points per side of a corner or after a rapid.
    max_lines : int
        Most inserted lines per program (more is refused).
    min_error_mm : float or None
        Least first-run error of a refined spot, mm (``None``: twice the resolution).
    min_spacing_periods : float
        Least spacing of end points, in servo periods of motion at the feed.
    arcs : str
        ``"on"``: also refine the straight feeds next to arcs.
    feed : str
        ``"on"``: the learning may lower F where the geometry cannot be shaped (:mod:`ilcnc.learning.feed`).
    feed_budget_pct : float
        Most extra cycle time for it, % of the original's.
    feed_min_ratio : float
        Least feed it may program, fraction of the programmed feed.
    settle : str
        ``"on"``: a dwell before the first feed after a rapid where the first run shows the rapid's lag.
    settle_budget_pct : float
        Most cycle time the settles may add, % of the original's.
    tolerance : str
        ``"on"``: a tighter corner tolerance where the first run's error is mostly the planner's rounding.
    tolerance_share : float
        The tighter tolerance, share of half the first run's cutting max (at least twice the resolution).
    tolerance_budget_pct : float
        Most cycle time it may add, % of the original's.
    """

    enabled: str = default_of("learning.refine.enabled")
    corner_angle_deg: float = default_of("learning.refine.corner_angle_deg")
    points_per_side: int = default_of("learning.refine.points_per_side")
    max_lines: int = default_of("learning.refine.max_lines")
    min_error_mm: float | None = default_of("learning.refine.min_error_mm")
    min_spacing_periods: float = default_of("learning.refine.min_spacing_periods")
    arcs: str = default_of("learning.refine.arcs")
    feed: str = default_of("learning.refine.feed")
    feed_budget_pct: float = default_of("learning.refine.feed_budget_pct")
    feed_min_ratio: float = default_of("learning.refine.feed_min_ratio")
    settle: str = default_of("learning.refine.settle")
    settle_budget_pct: float = default_of("learning.refine.settle_budget_pct")
    tolerance: str = default_of("learning.refine.tolerance")
    tolerance_share: float = default_of("learning.refine.tolerance_share")
    tolerance_budget_pct: float = default_of("learning.refine.tolerance_budget_pct")

    def to_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in vars(self).items() if v is not None}
        return out


@dataclass(frozen=True)
class LearningSection:
    """The ``learning:`` section.

    Parameters
    ----------
    law : str
        ``"p"``, ``"pid_ace"`` or ``"second_order"``.
    gains : dict
        Gains of the law with defaults filled; a gain is a number for all
        axes or a dict axis → number (see :meth:`gain`).
    iterations : int
        Largest number of iterations.
    correction_bound_mm : float
        Largest correction per coordinate, mm.
    arc_start_radial_mm : float
        How far an arc's start (the end point of the command before it) may move off the arc's circle, mm
        (the arc becomes a spiral); 0: along the circle only.
    cycle_budget_pct : float
        Most extra cycle time the corrections may cost, % of the original's (:mod:`ilcnc.learning.cycle_hold`).
    stop_tolerance_mm : float
        Stop tolerance on the largest contour error, mm.
    q_filter_hz : float or None
        Q-filter cut-off, Hz; ``None`` for no filter.
    lead_commands : int
        Lead of the update in commands.
    model_steps : int
        Virtual-CNC steps after each measured step (0: none).
    error : str
        Error estimate the law learns from (``"auto"`` picks the law's own).
    air_moves : str
        ``"keep"``: G01 commands in the air are not corrected; ``"correct"``: they are.
    refine : RefineSection
        Settings of the refinement (``learn --refine``).
    """

    law: str = default_of("learning.law")
    gains: dict[str, Any] = field(default_factory=lambda: {"gamma": default_of("learning.gains.gamma", "p")})
    iterations: int = default_of("learning.iterations")
    correction_bound_mm: float = default_of("learning.correction_bound_mm")
    arc_start_radial_mm: float = default_of("learning.arc_start_radial_mm")
    cycle_budget_pct: float = default_of("learning.cycle_budget_pct")
    stop_tolerance_mm: float = default_of("learning.stop_tolerance_mm")
    q_filter_hz: float | None = default_of("learning.q_filter_hz")
    lead_commands: int = default_of("learning.lead_commands")
    error: str = default_of("learning.error")
    model_steps: int = default_of("learning.model_steps")
    air_moves: str = default_of("learning.air_moves")
    refine: RefineSection = field(default_factory=RefineSection)

    def gain(self, name: str, axis: str) -> float:
        """Return gain ``name`` for ``axis`` (resolving per-axis mappings).

        Parameters
        ----------
        name : str
            Gain name, e.g. ``"gamma"``.
        axis : str
            Axis name.

        Returns
        -------
        float
            The gain.
        """
        g = self.gains[name]
        return float(g[axis]) if isinstance(g, Mapping) else float(g)


@dataclass(frozen=True)
class OutputSection:
    """The ``output:`` section.

    Parameters
    ----------
    dialect : str
        ``"auto"``, ``"linuxcnc"``, ``"fanuc"``, ``"grbl"`` or ``"heidenhain"``.
    decimals : int or None
        Least decimals of corrected words; ``None``: from the resolution.
    """

    dialect: str = default_of("output.dialect")
    decimals: int | None = default_of("output.decimals")


MODE_KEYS = ("direction", "natural_frequency_hz", "damping_ratio", "stiffness_n_um")


@dataclass(frozen=True)
class ToolMode:
    """One mode of the tool-tip receptance.

    Parameters
    ----------
    direction : str
        ``"normal"`` (perpendicular to the wall being cut) or ``"feed"``.
    natural_frequency_hz : float
        Natural frequency, Hz.
    damping_ratio : float
        Viscous damping ratio.
    stiffness_n_um : float
        Modal stiffness, N/µm.
    """

    direction: str
    natural_frequency_hz: float
    damping_ratio: float
    stiffness_n_um: float


@dataclass(frozen=True)
class GeometrySection:
    """The ``geometry:`` section.

    Parameters
    ----------
    map : str or None
        Volumetric map file as written in the profile (see :meth:`MachineProfile.resolve`); ``None``: off.
    outside : str
        ``"error"`` or ``"extrapolate"``.
    """

    map: str | None = default_of("geometry.map")
    outside: str = default_of("geometry.outside")


@dataclass(frozen=True)
class ToolSection:
    """The ``tool:`` section.

    Parameters
    ----------
    diameter_mm : float
        Tool diameter, mm.
    teeth : int
        Number of teeth.
    modes : tuple of ToolMode or None
        Modal parameters of the tool tip.
    frf_csv : str or None
        Measured FRF file as written in the profile.
    helix_deg : float
        Helix angle, degrees (0: straight flutes).
    runout_um : float
        Radial runout, total indicator reading, µm.
    runout_angle_deg : float
        Direction of the runout offset from flute 1, degrees.
    """

    diameter_mm: float = default_of("tool.diameter_mm")
    teeth: int = default_of("tool.teeth")
    helix_deg: float = default_of("tool.helix_deg")
    runout_um: float = default_of("tool.runout_um")
    runout_angle_deg: float = default_of("tool.runout_angle_deg")
    modes: tuple[ToolMode, ...] | None = default_of("tool.modes")
    frf_csv: str | None = default_of("tool.frf_csv")


@dataclass(frozen=True)
class CuttingSection:
    """The ``cutting:`` section (the SLE model's cutting conditions).

    Parameters
    ----------
    model : str
        ``"none"`` or ``"mechanistic"``.
    ktc_n_mm2, krc_n_mm2 : float or None
        Tangential and radial cutting coefficients, N/mm².
    kte_n_mm, kre_n_mm : float or None
        Edge coefficients, N/mm.
    axial_depth_mm : float or None
        Axial depth of cut, mm.
    spindle_rpm : float or None
        Spindle speed, rpm.
    milling : str
        ``"up"`` or ``"down"``.
    wall : str
        ``"left"`` or ``"right"`` of the path, looking along the feed.
    stock : str or None
        Stock (OMI) file as written in the profile.
    radial_depth_mm : float or None
        Radial depth of every command when there is no stock file, mm.
    top_z_mm : float or None
        Stock top, mm in program coordinates: feed moves above it are air moves (:mod:`ilcnc.contour.air`).
    """

    model: str = default_of("cutting.model")
    ktc_n_mm2: float | None = None
    krc_n_mm2: float | None = None
    kte_n_mm: float | None = None
    kre_n_mm: float | None = None
    axial_depth_mm: float | None = None
    spindle_rpm: float | None = None
    milling: str = default_of("cutting.milling")
    wall: str = default_of("cutting.wall")
    stock: str | None = default_of("cutting.stock")
    radial_depth_mm: float | None = None
    top_z_mm: float | None = None
    top_z_from: str = "profile"  # "option": given as --cutting-below-z (not a profile key)

    @property
    def enabled(self) -> bool:
        """True when the SLE model is on."""
        return self.model != "none"


@dataclass(frozen=True)
class ScheduleTuning:
    """The ``tuning.schedule:`` section (seed 001's receding-horizon gain schedule).

    Parameters
    ----------
    axis : str or None
        The scheduled axis; ``None``: z if defined, else the last axis (see :meth:`MachineProfile.schedule_axis`).
    horizon_samples : int
        Prediction horizon Np, servo periods.
    lam : float
        λ of ``J = ε̂ᵀε̂ + λ ΔK²`` (ε̂ in µm, ΔK in (m/min)/mm); YAML key ``lambda``.
    dk_candidates : tuple of float
        Gain increments ΔK tried per period, (m/min)/mm (distinct, 0 among them).
    kp_min_m_min_mm, kp_max_m_min_mm : float
        Gain range, (m/min)/mm, min < max.
    kinematics : str
        ``"predicted"``, ``"eq10"`` or ``"none"``.
    baseline_kp_m_min_mm : tuple of float or None
        Fixed gains tried for the comparison run C1 (the best feasible one is C1); ``None``: the drive's gain.
    """

    axis: str | None = default_of("tuning.schedule.axis")
    horizon_samples: int = default_of("tuning.schedule.horizon_samples")
    lam: float = default_of("tuning.schedule.lambda")
    dk_candidates: tuple[float, ...] = default_of("tuning.schedule.dk_candidates")
    kp_min_m_min_mm: float = default_of("tuning.schedule.kp_min_m_min_mm")
    kp_max_m_min_mm: float = default_of("tuning.schedule.kp_max_m_min_mm")
    kinematics: str = default_of("tuning.schedule.kinematics")
    baseline_kp_m_min_mm: tuple[float, ...] | None = default_of("tuning.schedule.baseline_kp_m_min_mm")

    @property
    def kp_range(self) -> tuple[float, float]:
        """``(kp_min_m_min_mm, kp_max_m_min_mm)``."""
        return (self.kp_min_m_min_mm, self.kp_max_m_min_mm)

    def to_dict(self) -> dict[str, Any]:
        """The section as YAML data (key ``lambda`` for :attr:`lam`; ``axis`` only when set)."""
        out: dict[str, Any] = {} if self.axis is None else {"axis": self.axis}
        out.update({"horizon_samples": self.horizon_samples, "lambda": self.lam,
                    "dk_candidates": list(self.dk_candidates), "kp_min_m_min_mm": self.kp_min_m_min_mm,
                    "kp_max_m_min_mm": self.kp_max_m_min_mm, "kinematics": self.kinematics})
        if self.baseline_kp_m_min_mm is not None:
            out["baseline_kp_m_min_mm"] = list(self.baseline_kp_m_min_mm)
        return out


@dataclass(frozen=True)
class TuningSection:
    """The ``tuning:`` section.

    Parameters
    ----------
    schedule : ScheduleTuning
        Settings of ``tune --method schedule``.
    """

    schedule: ScheduleTuning = field(default_factory=ScheduleTuning)


@dataclass(frozen=True)
class MachineProfile:
    """A validated machine profile.

    Parameters
    ----------
    machine : MachineSection
    axes : dict of str to AxisProfile
        The axes in x, y, z order.
    controller : ControllerSection
    planner : PlannerSection
    learning : LearningSection
    output : OutputSection
    geometry : GeometrySection
    tool : ToolSection
    cutting : CuttingSection
    tuning : TuningSection
    path : Path or None
        The file it was read from (not compared).
    source_text : str
        The file's text (not compared); empty when built from a dict.
    """

    machine: MachineSection
    axes: dict[str, AxisProfile]
    controller: ControllerSection = field(default_factory=ControllerSection)
    planner: PlannerSection = field(default_factory=PlannerSection)
    learning: LearningSection = field(default_factory=LearningSection)
    output: OutputSection = field(default_factory=OutputSection)
    geometry: GeometrySection = field(default_factory=GeometrySection)
    tool: ToolSection = field(default_factory=ToolSection)
    cutting: CuttingSection = field(default_factory=CuttingSection)
    tuning: TuningSection = field(default_factory=TuningSection)
    path: Path | None = field(default=None, compare=False)
    source_text: str = field(default="", compare=False, repr=False)

    def resolve(self, name: str) -> Path:
        """Return a file named in the profile as a path: relative names are relative to the profile file.

        Parameters
        ----------
        name : str
            The file as written in the profile.

        Returns
        -------
        Path
            Absolute, or relative to the working directory when the profile was built from a dict.
        """
        p = Path(name).expanduser()
        if p.is_absolute() or self.path is None:
            return p
        return Path(self.path).parent / p

    @property
    def axis_names(self) -> tuple[str, ...]:
        """The defined axis names in x, y, z order."""
        return tuple(self.axes)

    @property
    def schedule_axis(self) -> str:
        """The axis ``tune --method schedule`` schedules: ``tuning.schedule.axis``, else z if defined, else the
        last axis defined."""
        a = self.tuning.schedule.axis
        if a is not None:
            return a
        return "z" if "z" in self.axes else self.axis_names[-1]

    def with_cutting_top(self, top_z_mm: float | None) -> MachineProfile:
        """This profile with the stock top given on the command line (``--cutting-below-z``; ``None``: as is)."""
        if top_z_mm is None:
            return self
        if not math.isfinite(top_z_mm):
            raise InputError(None, None, f"--cutting-below-z must be a finite number of mm, not {top_z_mm}")
        return dataclasses.replace(self, cutting=dataclasses.replace(self.cutting, top_z_mm=float(top_z_mm),
                                                                     top_z_from="option"))

    def min_decimals(self, units: str) -> int:
        """Least number of decimals to write for a corrected coordinate.

        Parameters
        ----------
        units : {"mm", "inch"}
            Units of the program being written.

        Returns
        -------
        int
            ``output.decimals`` when given, else the decimals needed to express
            ``resolution_mm`` in the program's units (inch: resolution/25.4).
        """
        if units not in LENGTH_UNITS:
            raise ValueError(f"units must be 'mm' or 'inch', got {units!r}")
        if self.output.decimals is not None:
            return self.output.decimals
        res = self.machine.resolution_mm / (MM_PER_INCH if units == "inch" else 1.0)
        d = -math.log10(res)
        nearest = round(d)
        return max(0, nearest if abs(d - nearest) < 1e-9 else math.ceil(d))

    def to_dict(self) -> dict[str, Any]:
        """Return the profile as plain data that :func:`profile_from_dict` reads back.

        Every key is written (defaults filled); optional keys that are unset
        (``None``) are left out.
        """
        m = self.machine
        machine: dict[str, Any] = {
            "name": m.name,
            "units": m.units,
            "servo_period_s": m.servo_period_s,
            "resolution_mm": m.resolution_mm,
        }
        if m.travel_mm:
            machine["travel_mm"] = {a: [lo, hi] for a, (lo, hi) in m.travel_mm.items()}
        axes: dict[str, Any] = {}
        for name, ax in self.axes.items():
            drive = {"model": ax.drive.model}
            drive.update({k: v for k, v in _drive_params(ax.drive).items() if v is not None})
            axes[name] = {
                "max_velocity_mm_min": ax.max_velocity_mm_min,
                "max_acceleration_m_s2": ax.max_acceleration_m_s2,
                "max_jerk_m_s3": ax.max_jerk_m_s3,
                "rapid_mm_min": ax.rapid_mm_min,
                "drive": drive,
            }
        c, p, lr, o = self.controller, self.planner, self.learning, self.output
        learning: dict[str, Any] = {
            "law": lr.law,
            "gains": {k: dict(v) if isinstance(v, Mapping) else v for k, v in lr.gains.items()},
            "iterations": lr.iterations,
            "correction_bound_mm": lr.correction_bound_mm,
            "stop_tolerance_mm": lr.stop_tolerance_mm,
            "lead_commands": lr.lead_commands,
            "error": lr.error,
        }
        if lr.model_steps:
            learning["model_steps"] = lr.model_steps
        if lr.arc_start_radial_mm:
            learning["arc_start_radial_mm"] = lr.arc_start_radial_mm
        if lr.cycle_budget_pct != default_of("learning.cycle_budget_pct"):
            learning["cycle_budget_pct"] = lr.cycle_budget_pct
        if lr.air_moves != "keep":
            learning["air_moves"] = lr.air_moves
        if lr.refine != RefineSection():
            learning["refine"] = lr.refine.to_dict()
        if lr.q_filter_hz is not None:
            learning["q_filter_hz"] = lr.q_filter_hz
        output: dict[str, Any] = {"dialect": o.dialect}
        if o.decimals is not None:
            output["decimals"] = o.decimals
        return {
            "machine": machine,
            "axes": axes,
            "controller": {
                "type": c.type,
                "cross_coupling_gain": c.cross_coupling_gain,
                "coupled_axes": list(c.coupled_axes),
                **({"theta": c.theta} if c.theta != "reference" else {}),
            },
            "planner": {
                "profile": p.profile,
                "corner_tolerance_mm": p.corner_tolerance_mm,
                "path_control": p.path_control,
                "in_position_s": p.in_position_s,
                "lookahead_blocks": p.lookahead_blocks,
                "jerk_time_constant_s": p.jerk_time_constant_s,
                "arc_tolerance_mm": p.arc_tolerance_mm,
            },
            "learning": learning,
            "output": output,
            **self._error_model_dict(),
        }

    def _error_model_dict(self) -> dict[str, Any]:
        """The geometry / tool / cutting / tuning sections as plain data (only those that differ from the
        defaults)."""
        out: dict[str, Any] = {}
        g, t, c = self.geometry, self.tool, self.cutting
        if g != GeometrySection():
            out["geometry"] = {k: v for k, v in (("map", g.map), ("outside", g.outside)) if v is not None}
        if t != ToolSection():
            tool: dict[str, Any] = {"diameter_mm": t.diameter_mm, "teeth": t.teeth}
            if t.modes:
                tool["modes"] = [dict(vars(m)) for m in t.modes]
            if t.frf_csv is not None:
                tool["frf_csv"] = t.frf_csv
            out["tool"] = tool
        if c != CuttingSection():
            out["cutting"] = {k: v for k, v in vars(c).items() if v is not None and k != "top_z_from"}
        if self.tuning != TuningSection():
            out["tuning"] = {"schedule": self.tuning.schedule.to_dict()}
        return out

    def to_yaml(self) -> str:
        """Return :meth:`to_dict` as YAML text (comments of the source are not kept)."""
        return yaml.dump(self.to_dict(), Dumper=ProfileDumper, sort_keys=False, allow_unicode=True)



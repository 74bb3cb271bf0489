"""The YAML machine profile: schema, defaults, units, range checks.

A profile describes one machine: its kinematic limits per axis, a model of
each axis drive, the controller structure, the feed planner, the learning law
and how corrected programs are written. It is a YAML file (``configs/*.yaml``)
read with :func:`load_profile`; :func:`default_profile` is the 3-axis mill used
when no profile is given.

The whole schema is the declarative table :data:`SPECS` (one :class:`Spec` per
key: YAML path, type, range or choices, default, unit, description). The
loader, the dataclass defaults and the documentation (``docs/profile.md``, see
:func:`schema_markdown`) are all derived from that one table.

Every value is checked when the profile is loaded (types, ranges, choices,
unknown and missing keys, cross-key rules). A bad profile raises
:class:`ilcnc.errors.ProfileError` whose message is one line naming the file,
the line and the YAML path of the bad key with the allowed range, e.g.::

    mill.yaml:12: axes.x.max_jerk_m_s3: must be > 0 and <= 100000, got -5

Units
-----
Lengths are millimetres and times seconds unless the key name says otherwise
(``max_velocity_mm_min`` is mm/min, ``max_acceleration_m_s2`` is m/s²,
``max_jerk_m_s3`` is m/s³); :class:`AxisProfile` converts to mm and s.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar, NoReturn

import numpy as np
import yaml

from ilcnc.errors import InputError, ProfileError
from ilcnc.fileio import read_bytes

__all__ = [
    "AXIS_NAMES",
    "DRIVE_MODELS",
    "MAX_COEFFS",
    "MAX_DK_CANDIDATES",
    "MM_PER_INCH",
    "SPECS",
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
    "ScheduleTuning",
    "SopdtDrive",
    "Spec",
    "TransferFunctionDrive",
    "TuningSection",
    "default_profile",
    "has_position_loop",
    "load_profile",
    "profile_from_dict",
    "schema_markdown",
]

#: Axis names a profile may define, in this order.
AXIS_NAMES: tuple[str, ...] = ("x", "y", "z")

#: Millimetres per inch (exact).
MM_PER_INCH = 25.4

#: Most coefficients a ``"coeffs"`` key (a polynomial in s) may have.
MAX_COEFFS = 10


class _Required:
    """Sentinel type: the key has no default and must be given."""

    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()


# --------------------------------------------------------------------------
# The schema table
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Spec:
    """One key of the profile schema.

    Parameters
    ----------
    path : str
        Dotted YAML path; ``<axis>`` stands for an axis name (x, y or z).
    kind : str
        ``"section"`` (a mapping of fixed keys), ``"axis_map"`` (a mapping
        keyed by axis name), ``"float"``, ``"int"``, ``"str"``, ``"choice"``,
        ``"axis_float"`` (a number, or a mapping of axis name to number),
        ``"range_pair"`` (a list ``[min, max]`` with min < max),
        ``"axis_pair"`` (a list of two different axis names) or
        ``"coeffs"`` (a list of 1 to :data:`MAX_COEFFS` finite polynomial
        coefficients, the first non-zero) or ``"numbers"`` (a list of 1 to
        :data:`MAX_DK_CANDIDATES` finite numbers within ``lo``/``hi``).
    doc : str
        One-sentence description (goes into ``docs/profile.md``).
    unit : str
        Unit of the value (empty when dimensionless or not a number).
    default : object
        Value used when the key is absent; :data:`REQUIRED` when it must be
        given; ``None`` when it is optional and absence has a meaning.
    lo, hi : float or None
        Bounds of numeric values (``None``: unbounded on that side).
    lo_open, hi_open : bool
        ``True`` when the bound itself is excluded (``> lo`` / ``< hi``).
    choices : tuple of str
        Allowed values of a ``"choice"``.
    when : tuple of (str, str) or None
        ``(selector_path, value)``: the key exists only when the key at
        ``selector_path`` has that value (drive model, learning law).
    default_doc : str
        Text for the default column of the documentation when ``default`` alone
        does not say it (e.g. a default derived from another key).
    """

    path: str
    kind: str
    doc: str
    unit: str = ""
    default: Any = REQUIRED
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple[str, ...] = ()
    when: tuple[str, str] | None = None
    default_doc: str = ""

    @property
    def key(self) -> str:
        """The last component of :attr:`path`."""
        return self.path.rsplit(".", 1)[-1]

    @property
    def parent(self) -> str:
        """The path of the enclosing mapping (``""`` for a top-level section)."""
        return self.path.rsplit(".", 1)[0] if "." in self.path else ""

    @property
    def required(self) -> bool:
        """True when the key has no default and must be given."""
        return self.default is REQUIRED

    def range_text(self) -> str:
        """The allowed range or choices in words, as errors and docs print it."""
        if self.kind == "choice":
            return "one of " + ", ".join(self.choices)
        parts = []
        if self.lo is not None:
            parts.append(f"{'>' if self.lo_open else '>='} {_num(self.lo)}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {_num(self.hi)}")
        return " and ".join(parts)


def _sec(path: str, doc: str, *, required: bool = False) -> Spec:
    return Spec(path, "section", doc, default=REQUIRED if required else {})


def _f(
    path: str,
    doc: str,
    unit: str,
    lo: float | None,
    hi: float | None,
    *,
    default: Any = REQUIRED,
    lo_open: bool = False,
    hi_open: bool = False,
    when: tuple[str, str] | None = None,
    kind: str = "float",
    default_doc: str = "",
) -> Spec:
    return Spec(
        path,
        kind,
        doc,
        unit=unit,
        default=default,
        lo=lo,
        hi=hi,
        lo_open=lo_open,
        hi_open=hi_open,
        when=when,
        default_doc=default_doc,
    )


def _c(path: str, doc: str, choices: tuple[str, ...], *, default: Any = REQUIRED) -> Spec:
    return Spec(path, "choice", doc, default=default, choices=choices)


_DRIVE = "axes.<axis>.drive"
_SOPDT = (f"{_DRIVE}.model", "sopdt")
_MDPID = (f"{_DRIVE}.model", "mass_damper_pid")
_PFF = (f"{_DRIVE}.model", "p_ff_friction")
_FOD = (f"{_DRIVE}.model", "first_order_delay")
_TF = (f"{_DRIVE}.model", "transfer_function")
_LAW_P = ("learning.law", "p")
_LAW_PID = ("learning.law", "pid_ace")
_LAW_SO = ("learning.law", "second_order")
_CUT_M = ("cutting.model", "mechanistic")

#: The profile schema: every key, in file order.
SPECS: tuple[Spec, ...] = (
    # machine ---------------------------------------------------------------
    _sec("machine", "The machine as a whole.", required=True),
    Spec("machine.name", "str", "Name of the machine (free text, shown in reports)."),
    _c(
        "machine.units",
        "Program units assumed when a program has no G20/G21 (Heidenhain programs always say MM or INCH).",
        ("mm", "inch"),
        default="mm",
    ),
    _f(
        "machine.servo_period_s",
        "Servo (interpolation) period: the sample time of the virtual CNC and of the reference.",
        "s",
        1e-5,
        0.1,
        default=0.001,
    ),
    _f(
        "machine.resolution_mm",
        "Smallest increment the control accepts; corrected numbers are written with enough decimals for it.",
        "mm",
        1e-6,
        0.1,
        default=0.001,
    ),
    Spec(
        "machine.travel_mm",
        "axis_map",
        "Optional travel limits per axis (machine coordinates); absent: no travel check.",
        default={},
    ),
    _f(
        "machine.travel_mm.<axis>",
        "Travel of one axis as [min, max], min < max.",
        "mm",
        -1e5,
        1e5,
        kind="range_pair",
        default_doc="—",
    ),
    # axes ------------------------------------------------------------------
    Spec("axes", "axis_map", "The axes, keyed by name (x, y, z; lowercase; at least one)."),
    Spec("axes.<axis>", "section", "One axis: kinematic limits and drive model.", default_doc="—"),
    _f(
        "axes.<axis>.max_velocity_mm_min",
        "Maximum programmable feed of the axis.",
        "mm/min",
        0,
        1e6,
        lo_open=True,
    ),
    _f("axes.<axis>.max_acceleration_m_s2", "Maximum acceleration of the axis.", "m/s²", 0, 1000, lo_open=True),
    _f("axes.<axis>.max_jerk_m_s3", "Maximum jerk of the axis.", "m/s³", 0, 1e5, lo_open=True),
    _f(
        "axes.<axis>.rapid_mm_min",
        "Rapid (G00 / FMAX) velocity of the axis.",
        "mm/min",
        0,
        1e6,
        lo_open=True,
        default=None,
        default_doc="= max_velocity_mm_min",
    ),
    _sec(f"{_DRIVE}", "Model of the axis drive (position command in, actual position out).", required=True),
    _c(
        f"{_DRIVE}.model",
        "Which drive model; each model has its own parameters below.",
        ("sopdt", "mass_damper_pid", "p_ff_friction", "first_order_delay", "transfer_function"),
    ),
    # sopdt (seed 004)
    _f(
        f"{_DRIVE}.gain",
        "Static gain K of the velocity drive (actual / commanded velocity). Seed 004 prints K = 1.09e-4, which no"
        " unit conversion turns into a unity velocity gain; it is normalised to 1.",
        "",
        0,
        100,
        lo_open=True,
        default=1.0,
        when=_SOPDT,
    ),
    _f(
        f"{_DRIVE}.omega0_rad_s",
        "Natural frequency ω0 of the velocity drive.",
        "rad/s",
        0,
        1e5,
        lo_open=True,
        when=_SOPDT,
    ),
    _f(f"{_DRIVE}.zeta", "Damping ratio ζ of the velocity drive.", "", 0, 10, lo_open=True, when=_SOPDT),
    _f(f"{_DRIVE}.delay_s", "Dead time Td of the velocity drive.", "s", 0, 1, default=0.0, when=_SOPDT),
    _f(
        f"{_DRIVE}.position_gain_1_s",
        "Gain Kv of a proportional position loop closed around the velocity drive (velocity command ="
        " Kv·position error). Absent: no position loop; the position is the integral of the drive's velocity,"
        " driven by the reference velocity (seed 004).",
        "1/s",
        0,
        1e4,
        lo_open=True,
        default=None,
        when=_SOPDT,
        default_doc="none (no position loop)",
    ),
    # mass_damper_pid (seed 000)
    _f(
        f"{_DRIVE}.mass_v_s2_mm",
        "Mass m of the axis as seen by the controller output (m·q̈ + c·q̇ = u, u in volts).",
        "V·s²/mm",
        0,
        1e3,
        lo_open=True,
        when=_MDPID,
    ),
    _f(f"{_DRIVE}.damping_v_s_mm", "Viscous damping c of the axis.", "V·s/mm", 0, 1e3, when=_MDPID),
    _f(f"{_DRIVE}.kp", "Proportional gain K_P of the position PID.", "V/mm", 0, 1e6, when=_MDPID),
    _f(f"{_DRIVE}.ki", "Integral gain K_I of the position PID.", "V/(mm·s)", 0, 1e6, when=_MDPID),
    _f(f"{_DRIVE}.kd", "Derivative gain K_D of the position PID.", "V·s/mm", 0, 1e6, when=_MDPID),
    # p_ff_friction (seed 001)
    _f(
        f"{_DRIVE}.kp_m_min_mm",
        "Position loop gain K_v (velocity command per position error); 1 (m/min)/mm = 16.67 1/s.",
        "(m/min)/mm",
        0,
        100,
        lo_open=True,
        when=_PFF,
    ),
    _f(f"{_DRIVE}.kff", "Velocity feed-forward gain (1 = full feed-forward).", "", 0, 1.5, default=1.0, when=_PFF),
    _f(
        f"{_DRIVE}.velocity_bandwidth_hz",
        "Bandwidth of the (first-order) velocity loop; its force gain is 2π·bandwidth·inertia_kg.",
        "Hz",
        0,
        1e4,
        lo_open=True,
        default=100.0,
        when=_PFF,
    ),
    _f(
        f"{_DRIVE}.velocity_integral_time_s",
        "Integral time Ti of a PI velocity loop (force = gain·(e_v + ∫e_v dt / Ti)), as in seed 001's speed PI;"
        " it removes the steady velocity error friction causes and makes the quadrant glitch at a velocity"
        " reversal. Absent: a proportional velocity loop.",
        "s",
        0,
        10,
        lo_open=True,
        default=None,
        when=_PFF,
        default_doc="none (P velocity loop)",
    ),
    _f(
        f"{_DRIVE}.inertia_kg",
        "Moving mass of the axis (table, workpiece and rotor inertia as an equivalent mass); required when any"
        " friction term is non-zero.",
        "kg",
        0,
        1e5,
        lo_open=True,
        default=None,
        when=_PFF,
        default_doc="none (required with friction)",
    ),
    _f(f"{_DRIVE}.coulomb_n", "Coulomb friction force F_c.", "N", 0, 1e5, default=0.0, when=_PFF),
    _f(
        f"{_DRIVE}.viscous_n_s_mm",
        "Viscous friction coefficient B (force per velocity).",
        "N·s/mm",
        0,
        1e4,
        default=0.0,
        when=_PFF,
    ),
    _f(
        f"{_DRIVE}.static_n",
        "Static (breakaway) friction force F_s; 0 means no Stribeck peak (F_s = F_c), otherwise F_s >= F_c.",
        "N",
        0,
        1e5,
        default=0.0,
        when=_PFF,
    ),
    _f(
        f"{_DRIVE}.stribeck_velocity_mm_s",
        "Stribeck velocity v_s over which friction falls from F_s to F_c; must be > 0 when static_n > coulomb_n.",
        "mm/s",
        0,
        1e4,
        default=0.0,
        when=_PFF,
    ),
    # first_order_delay
    _f(
        f"{_DRIVE}.time_constant_s",
        "Time constant T of the closed position loop (T = 1/K_v of a P position loop).",
        "s",
        0,
        10,
        lo_open=True,
        when=_FOD,
    ),
    _f(f"{_DRIVE}.delay_s", "Dead time Td of the closed position loop.", "s", 0, 1, default=0.0, when=_FOD),
    _f(
        f"{_DRIVE}.gain",
        "Static gain of the closed position loop (1 = no steady-state error).",
        "",
        0,
        100,
        lo_open=True,
        default=1.0,
        when=_FOD,
    ),
    # transfer_function (seed 003)
    Spec(
        f"{_DRIVE}.numerator",
        "coeffs",
        "Numerator of the axis transfer function, coefficients in descending powers of s (first non-zero);"
        " it must have fewer coefficients than the denominator (strictly proper).",
        when=_TF,
    ),
    Spec(
        f"{_DRIVE}.denominator",
        "coeffs",
        "Denominator of the axis transfer function, coefficients in descending powers of s (first non-zero).",
        when=_TF,
    ),
    Spec(
        f"{_DRIVE}.feedback",
        "choice",
        "unity: numerator/denominator is the forward path L(s) from position error to position (position"
        " controller × axis, as G1, G2 of seed 003), closed with unity feedback; none: it is already the closed"
        " loop from reference to position.",
        default="unity",
        choices=("unity", "none"),
        when=_TF,
    ),
    # controller ------------------------------------------------------------
    _sec("controller", "Controller structure around the axis drives."),
    _c(
        "controller.type",
        "independent: each axis on its own; cross_coupled: a cross-coupled contour controller (seed 003) on two axes,"
        " which both need a position loop (mass_damper_pid, p_ff_friction, sopdt with position_gain_1_s or"
        " transfer_function with unity feedback).",
        ("independent", "cross_coupled"),
        default="independent",
    ),
    _f(
        "controller.cross_coupling_gain",
        "Gain C of the cross-coupled controller (contour-error gains C_x = sin θ, C_y = cos θ); must be > 0 when"
        " type is cross_coupled.",
        "",
        0,
        1e4,
        default=0.0,
    ),
    Spec(
        "controller.coupled_axes",
        "axis_pair",
        "The two axes the cross-coupled controller couples (both must be defined under axes).",
        default=("x", "y"),
    ),
    # planner ---------------------------------------------------------------
    _sec("planner", "Feed planning of the reference (virtual CNC)."),
    _c(
        "planner.profile",
        "seven_phase: constant-jerk 7-phase S-curve; cubic: jerk-continuous (cubic acceleration, seed 004);"
        " constant_feed: programmed feed, no ramps; linuxcnc: LinuxCNC 2.9's planner (trapezoidal, blend arcs"
        " at corners, no jerk limit or in-position wait; ilcnc/vcnc/plan_tp.py).",
        ("seven_phase", "cubic", "constant_feed", "linuxcnc"),
        default="seven_phase",
    ),
    _f(
        "planner.corner_tolerance_mm",
        "Largest deviation from the programmed corner the planner may use to keep the feed up (0 = exact stop).",
        "mm",
        0,
        10,
        default=0.01,
    ),
    _c(
        "planner.path_control",
        "Path control of moves whose program sets none: tolerance (blend within corner_tolerance_mm), g64 (blend"
        " without a bound, LinuxCNC's start-up mode; LinuxCNC still keeps a blend within a quarter of the shorter"
        " move), g61 (exact path: stop at corners), g61.1 (exact stop at every block end).",
        ("tolerance", "g64", "g61", "g61.1"),
        default="tolerance",
    ),
    _f(
        "planner.in_position_s",
        "Stand-still between a group of rapids and a group of feed moves (the in-position check many CNCs make"
        " after G0, so the drives settle before the cut); 0: the feed move starts as the rapid ends (LinuxCNC).",
        "s",
        0,
        10,
        default=0.1,
    ),
    _f(
        "planner.lookahead_blocks",
        "Number of blocks the look-ahead plans ahead.",
        "",
        1,
        100000,
        default=200,
        kind="int",
    ),
    _f(
        "planner.jerk_time_constant_s",
        "Jerk ramp time of the cubic profile.",
        "s",
        0,
        1,
        lo_open=True,
        default=0.01,
    ),
    _f(
        "planner.arc_tolerance_mm",
        "Chord error allowed when arcs are sampled into the reference.",
        "mm",
        0,
        1,
        lo_open=True,
        default=0.001,
    ),
    # learning --------------------------------------------------------------
    _sec("learning", "The learning law and the iteration."),
    _c(
        "learning.law",
        "p: P-type (cascade, seeds 002/004); pid_ace: PID-type on the actual contour error (seed 000);"
        " second_order: second-order law (seed 003).",
        ("p", "pid_ace", "second_order"),
        default="p",
    ),
    _sec(
        "learning.gains",
        "Gains of the law; the keys depend on learning.law. Each gain marked 'number or"
        " per-axis' is one number for all axes or a mapping giving every axis, e.g. {x: 0.5, y: 0.4}.",
    ),
    _f(
        "learning.gains.gamma",
        "Learning gain Γ: U_{i+1} = U_i + Γ·E_i (on a drive with unity static gain Γ above 2 diverges: the guard"
        " catches it).",
        "",
        0,
        10,
        lo_open=True,
        default=0.5,
        when=_LAW_P,
        kind="axis_float",
    ),
    _f("learning.gains.kp", "Proportional learning gain K_Pl.", "", 0, 1e6, when=_LAW_PID, kind="axis_float"),
    _f(
        "learning.gains.ki",
        "Integral learning gain K_Il (0 keeps the convergence factor bounded at low frequency).",
        "1/s",
        0,
        1e6,
        default=0.0,
        when=_LAW_PID,
        kind="axis_float",
    ),
    _f("learning.gains.kd", "Derivative learning gain K_Dl.", "s", 0, 1e6, when=_LAW_PID, kind="axis_float"),
    _f(
        "learning.gains.lead_samples",
        "Lead η of the learning update in servo periods.",
        "",
        0,
        1000,
        default=0,
        when=_LAW_PID,
        kind="int",
    ),
    _f(
        "learning.gains.p1", "Weight P1 of the last command.", "", -10, 10, default=1.0, when=_LAW_SO, kind="axis_float"
    ),
    _f(
        "learning.gains.p2",
        "Weight P2 of the command before last.",
        "",
        -10,
        10,
        default=0.0,
        when=_LAW_SO,
        kind="axis_float",
    ),
    _f("learning.gains.q1", "Weight Q1 of the last error.", "", -10, 10, when=_LAW_SO, kind="axis_float"),
    _f(
        "learning.gains.q2",
        "Weight Q2 of the error before last.",
        "",
        -10,
        10,
        default=0.0,
        when=_LAW_SO,
        kind="axis_float",
    ),
    _c(
        "learning.error",
        "Error E(k) the law learns from. path: hat-weighted mean contour error of the two moves that meet"
        " at the end point of command k (least squares over the whole path); crossing: end point of command k"
        " minus the actual position where the machine passes closest to it (seed 004's point error); contour:"
        " exact contour error vector when the reference reaches the end of command k (seed 000's ACE);"
        " tangent: seed 000's Frenet-frame estimate at that instant; tracking: end point minus actual at that"
        " instant (seed 003); lifted: the end-point moves that, through the drive models, best cancel the"
        " sampled contour error (damped least squares; sees corners; docs/learning.md); auto: path for p (lifted"
        " when the program is refined: learn --refine), contour for pid_ace, tracking for second_order.",
        ("auto", "path", "crossing", "contour", "tangent", "tracking", "lifted"),
        default="auto",
    ),
    _f("learning.iterations", "Largest number of learning iterations.", "", 1, 1000, default=5, kind="int"),
    _f(
        "learning.correction_bound_mm",
        "Largest correction of one coordinate; larger ones are clipped and reported.",
        "mm",
        0,
        10,
        lo_open=True,
        default=0.5,
    ),
    _f(
        "learning.stop_tolerance_mm",
        "Stop when the largest contour error is below this.",
        "mm",
        0,
        10,
        default=0.001,
    ),
    _f(
        "learning.q_filter_hz",
        "Cut-off of the robustness (Q) low-pass filter on the update.",
        "Hz",
        0,
        1e4,
        lo_open=True,
        default=None,
        default_doc="none (no filter)",
    ),
    _f(
        "learning.lead_commands",
        "Lead of the update in G01 commands (the error of command k+lead corrects command k).",
        "",
        0,
        1000,
        default=0,
        kind="int",
    ),
    _f(
        "learning.model_steps",
        "With a measured log or points (learn --log/--points): virtual-CNC steps made after each measured one,"
        " each on the measured error plus the change the virtual CNC predicts for the new correction"
        " (model-assisted learning; 0: the measured step alone; the p law only).",
        "",
        0,
        20,
        default=0,
        kind="int",
    ),
    _c(
        "learning.air_moves",
        "G01 commands in the air (above cutting.top_z_mm, or above work Z0 where the program cuts below it:"
        " docs/learning.md): keep them as programmed (their error shapes no surface) or correct them like cuts.",
        ("keep", "correct"),
        default="keep",
    ),
    _sec(
        "learning.refine",
        "Refinement (learn --refine): straight-feed points inserted on the original path where the first run shows"
        " error the program's own end points cannot shape (corners, the first feed move after a rapid); they learn"
        " like any other command (docs/learning.md).",
    ),
    _c("learning.refine.enabled", "Refine without --refine on the command line (off: only with --refine).", ("off", "on"),
       default="off"),
    _f("learning.refine.corner_angle_deg", "A corner is refined when the path turns by more than this between two"
       " straight feeds.", "deg", 1, 179, default=15.0),
    _f("learning.refine.points_per_side", "Most points inserted on each side of a corner (and after a rapid), at"
       " distances halving from the end of the disturbed stretch towards the corner.", "", 1, 20, default=6,
       kind="int"),
    _f("learning.refine.max_lines", "Most lines the refinement may insert into one program; a refinement that needs"
       " more is refused (raise it or refine less).", "", 1, 10_000_000, default=200_000, kind="int"),
    _f("learning.refine.min_error_mm", "Least contour error of the first run at a corner or rapid for it to be"
       " refined. Absent: twice the machine's resolution (below it the error is at the physical floor).", "mm", 0, 10,
       default=None, default_doc="2 × machine.resolution_mm"),
    _c("learning.refine.arcs", "Also refine the straight feeds next to arcs (their end points are an arc's only"
       " handles). Off by default: on Gates_combined_R12 (0.5 mm fillets) it inserted 28,282 lines and the"
       " corrections near the arcs cost +14.6 % cycle time for -33 % RMS (docs/learning.md).", ("off", "on"),
       default="off"),
    _c("learning.refine.feed", "Let the learning lower F on the moves where the geometry cannot be shaped (arcs,"
       " corners the planner runs at its tolerance), the largest errors first, within feed_budget_pct of cycle time;"
       " every slowed move is reported (docs/learning.md). Off by default; with or without refinement.",
       ("off", "on"), default="off"),
    _f("learning.refine.feed_budget_pct", "Most extra cycle time the feed learning may spend, % of the original"
       " program's cycle time (an iteration whose cycle time leaves it is refused).", "%", 0, 50, default=2.0),
    _f("learning.refine.feed_min_ratio", "Least feed the feed learning may program, as a fraction of the programmed"
       " feed.", "", 0.05, 1, default=0.25),
    _f("learning.refine.min_spacing_periods", "Least distance of an inserted point from another end point, in servo"
       " periods of motion at the move's feed (a controller runs at most one block per period).", "", 1, 1000,
       default=3.0),
    # output ----------------------------------------------------------------
    _sec("output", "How corrected programs are written."),
    _c(
        "output.dialect",
        "Dialect of written programs; auto: the dialect of the input program.",
        ("auto", "linuxcnc", "fanuc", "grbl", "heidenhain"),
        default="auto",
    ),
    _f(
        "output.decimals",
        "Least number of decimals written in corrected coordinate words.",
        "",
        0,
        8,
        default=None,
        kind="int",
        default_doc="from resolution_mm",
    ),
    # geometry, tool, cutting (issue 8) ----------------------------------------
    _sec("geometry", "Geometric (volumetric) errors of the machine added to the actual tool position (seed 002)."),
    Spec(
        "geometry.map",
        "str",
        "Volumetric error map: a grid CSV x,y,z,dx,dy,dz or per-axis error tables (docs/errors.md); a path"
        " relative to the profile file. Absent: no geometric error.",
        default=None,
    ),
    _c(
        "geometry.outside",
        "A point outside the map: error (refuse the run) or extrapolate (linear, from the map's edge).",
        ("error", "extrapolate"),
        default="error",
    ),
    _sec("tool", "The cutting tool: size and its frequency response at the tool tip (seed 004's SLE model)."),
    _f("tool.diameter_mm", "Tool diameter.", "mm", 0, 200, lo_open=True, default=12.0),
    _f("tool.teeth", "Number of teeth (flutes), straight flutes.", "", 1, 20, default=2, kind="int"),
    Spec(
        "tool.modes",
        "modes",
        "Modes of the tool-tip receptance: a list of {direction: feed|normal, natural_frequency_hz,"
        " damping_ratio, stiffness_n_um}; normal is perpendicular to the wall being cut.",
        default=None,
    ),
    Spec(
        "tool.frf_csv",
        "str",
        "Measured tool-tip FRF normal to the wall from an impact test instead of modes: CSV f_hz,re,im (m/N unless"
        " the header says [um/N]); a path relative to the profile file.",
        default=None,
    ),
    _sec("cutting", "Cutting conditions of the surface location error (SLE) model; model none switches it off."),
    _c(
        "cutting.model",
        "none: no cutting error; mechanistic: straight-flute milling forces on the tool's FRF give the SLE.",
        ("none", "mechanistic"),
        default="none",
    ),
    _f("cutting.ktc_n_mm2", "Tangential cutting coefficient K_tc.", "N/mm²", 0, 1e5, lo_open=True, when=_CUT_M),
    _f("cutting.krc_n_mm2", "Radial cutting coefficient K_rc.", "N/mm²", 0, 1e5, when=_CUT_M),
    _f("cutting.kte_n_mm", "Tangential edge coefficient K_te.", "N/mm", 0, 1e4, default=0.0, when=_CUT_M),
    _f("cutting.kre_n_mm", "Radial edge coefficient K_re.", "N/mm", 0, 1e4, default=0.0, when=_CUT_M),
    _f("cutting.axial_depth_mm", "Axial depth of cut.", "mm", 0, 500, lo_open=True, when=_CUT_M),
    _f("cutting.spindle_rpm", "Spindle speed.", "rpm", 0, 2e5, lo_open=True, when=_CUT_M),
    _c("cutting.milling", "Up (conventional) or down (climb) milling.", ("up", "down"), default="up"),
    _c(
        "cutting.wall",
        "Side of the programmed path, looking along the feed, where the finished wall is.",
        ("left", "right"),
        default="left",
    ),
    Spec(
        "cutting.stock",
        "str",
        "On-machine inspection of the stock: CSV x,y,z of the stock face or k,stock_mm (radial depth per"
        " command); a path relative to the profile file. Absent: cutting.radial_depth_mm for every command.",
        default=None,
    ),
    _f(
        "cutting.radial_depth_mm",
        "Radial depth of cut of every G01 command when no stock file is given.",
        "mm",
        0,
        200,
        lo_open=True,
        default=None,
        when=_CUT_M,
        default_doc="none (needs cutting.stock)",
    ),
    _f(
        "cutting.top_z_mm",
        "Stock top in the program's coordinates: a feed move whose lowest point lies above it is an air move"
        " (figures apart, not corrected; --cutting-below-z overrides it). Absent: work Z0 where some feed move"
        " reaches Z <= 0 (CAM programs put the work zero on the stock top), else every feed move cuts.",
        "mm",
        -1e5,
        1e5,
        default=None,
        default_doc="work Z0 (see the description)",
    ),
    # tuning (issue 7) ----------------------------------------------------------
    _sec("tuning", "Settings of `ilcnc tune` that belong to the machine rather than to one run."),
    _sec(
        "tuning.schedule",
        "The receding-horizon gain schedule of `tune --method schedule` (seed 001): a per-servo-period position"
        " gain K_p of one p_ff_friction axis, chosen at every period among K_{k-1} + ΔK by"
        " J = ε̂ᵀε̂ + λ·ΔK² over Np samples (eqs. 3-5).",
    ),
    Spec(
        "tuning.schedule.axis",
        "choice",
        "The scheduled axis (it must be defined under axes and have a p_ff_friction drive when the schedule runs);"
        " absent: z if defined, else the last axis defined.",
        default=None,
        choices=AXIS_NAMES,
        default_doc="z (else the last axis)",
    ),
    _f(
        "tuning.schedule.horizon_samples",
        "Prediction horizon Np in servo periods: each candidate gain is held over Np periods of the nonlinear"
        " axis model and the predicted contour errors are summed squared (seed 001: Np = 50).",
        "",
        1,
        10000,
        default=50,
        kind="int",
    ),
    _f(
        "tuning.schedule.lambda",
        "Weight λ of the gain increment in J = ε̂ᵀε̂ + λ·ΔK², with ε̂ in mm and ΔK in (m/min)/mm (seed 001:"
        " λ = 0.01; the paper gives no units); 0: no penalty.",
        "mm²/((m/min)/mm)²",
        0,
        1e6,
        default=0.01,
    ),
    Spec(
        "tuning.schedule.dk_candidates",
        "numbers",
        "The gain increments ΔK tried at every period (seed 001: -0.05 to 0.05 in steps of 0.01); distinct,"
        " and 0 must be one of them (holding the gain is always a candidate, so a gain inside the range always"
        " has a choice that stays inside it).",
        unit="(m/min)/mm",
        default=(-0.05, -0.04, -0.03, -0.02, -0.01, 0.0, 0.01, 0.02, 0.03, 0.04, 0.05),
        lo=-10,
        hi=10,
    ),
    _f(
        "tuning.schedule.kp_min_m_min_mm",
        "Lower end of the gain range (eq. 6: the stable range, phase margin > 70°, gain margin > 10 dB; seed"
        " 001's C2: 1); must be < kp_max_m_min_mm.",
        "(m/min)/mm",
        0,
        100,
        lo_open=True,
        default=1.0,
    ),
    _f(
        "tuning.schedule.kp_max_m_min_mm",
        "Upper end of the gain range (seed 001's C2: 2.7 inside the stable [1, 3]).",
        "(m/min)/mm",
        0,
        100,
        lo_open=True,
        default=2.7,
    ),
    _c(
        "tuning.schedule.kinematics",
        "How the axis's V, A, J limits restrict ΔK (eqs. 8-10): predicted (the next displacement the model"
        " predicts for the candidate), eq10 (the paper's bound with the velocity loop taken as 1, its division by"
        " E_Z guarded) or none.",
        ("predicted", "eq10", "none"),
        default="predicted",
    ),
)

#: Most candidates ``tuning.schedule.dk_candidates`` may list.
MAX_DK_CANDIDATES = 101

_TOP_SECTIONS: tuple[str, ...] = tuple(s.path for s in SPECS if not s.parent)
_SELECTORS: frozenset[str] = frozenset(s.when[0] for s in SPECS if s.when)


def _spec(path: str, when_value: str | None = None) -> Spec:
    for s in SPECS:
        if s.path == path and (when_value is None or (s.when is not None and s.when[1] == when_value)):
            return s
    raise KeyError(path)


def _default(path: str, when_value: str | None = None) -> Any:
    """The schema default of ``path`` (for the dataclass defaults below)."""
    d = _spec(path, when_value).default
    if d is REQUIRED:  # pragma: no cover - programming error
        raise ValueError(f"{path} has no default")
    return d


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
    gain: float = _default(f"{_DRIVE}.gain", "sopdt")
    delay_s: float = _default(f"{_DRIVE}.delay_s", "sopdt")
    position_gain_1_s: float | None = _default(f"{_DRIVE}.position_gain_1_s", "sopdt")


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
    kff: float = _default(f"{_DRIVE}.kff", "p_ff_friction")
    velocity_bandwidth_hz: float = _default(f"{_DRIVE}.velocity_bandwidth_hz", "p_ff_friction")
    velocity_integral_time_s: float | None = _default(f"{_DRIVE}.velocity_integral_time_s", "p_ff_friction")
    inertia_kg: float | None = _default(f"{_DRIVE}.inertia_kg", "p_ff_friction")
    coulomb_n: float = _default(f"{_DRIVE}.coulomb_n", "p_ff_friction")
    viscous_n_s_mm: float = _default(f"{_DRIVE}.viscous_n_s_mm", "p_ff_friction")
    static_n: float = _default(f"{_DRIVE}.static_n", "p_ff_friction")
    stribeck_velocity_mm_s: float = _default(f"{_DRIVE}.stribeck_velocity_mm_s", "p_ff_friction")

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
    delay_s: float = _default(f"{_DRIVE}.delay_s", "first_order_delay")
    gain: float = _default(f"{_DRIVE}.gain", "first_order_delay")


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
    feedback: str = _default(f"{_DRIVE}.feedback", "transfer_function")


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
    units: str = _default("machine.units")
    servo_period_s: float = _default("machine.servo_period_s")
    resolution_mm: float = _default("machine.resolution_mm")
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
    """

    type: str = _default("controller.type")
    cross_coupling_gain: float = _default("controller.cross_coupling_gain")
    coupled_axes: tuple[str, str] = _default("controller.coupled_axes")


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

    profile: str = _default("planner.profile")
    corner_tolerance_mm: float = _default("planner.corner_tolerance_mm")
    path_control: str = _default("planner.path_control")
    in_position_s: float = _default("planner.in_position_s")
    lookahead_blocks: int = _default("planner.lookahead_blocks")
    jerk_time_constant_s: float = _default("planner.jerk_time_constant_s")
    arc_tolerance_mm: float = _default("planner.arc_tolerance_mm")


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
    """

    enabled: str = _default("learning.refine.enabled")
    corner_angle_deg: float = _default("learning.refine.corner_angle_deg")
    points_per_side: int = _default("learning.refine.points_per_side")
    max_lines: int = _default("learning.refine.max_lines")
    min_error_mm: float | None = _default("learning.refine.min_error_mm")
    min_spacing_periods: float = _default("learning.refine.min_spacing_periods")
    arcs: str = _default("learning.refine.arcs")
    feed: str = _default("learning.refine.feed")
    feed_budget_pct: float = _default("learning.refine.feed_budget_pct")
    feed_min_ratio: float = _default("learning.refine.feed_min_ratio")

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

    law: str = _default("learning.law")
    gains: dict[str, Any] = field(default_factory=lambda: {"gamma": _default("learning.gains.gamma", "p")})
    iterations: int = _default("learning.iterations")
    correction_bound_mm: float = _default("learning.correction_bound_mm")
    stop_tolerance_mm: float = _default("learning.stop_tolerance_mm")
    q_filter_hz: float | None = _default("learning.q_filter_hz")
    lead_commands: int = _default("learning.lead_commands")
    error: str = _default("learning.error")
    model_steps: int = _default("learning.model_steps")
    air_moves: str = _default("learning.air_moves")
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

    dialect: str = _default("output.dialect")
    decimals: int | None = _default("output.decimals")


_MODE_KEYS = ("direction", "natural_frequency_hz", "damping_ratio", "stiffness_n_um")


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

    map: str | None = _default("geometry.map")
    outside: str = _default("geometry.outside")


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
    """

    diameter_mm: float = _default("tool.diameter_mm")
    teeth: int = _default("tool.teeth")
    modes: tuple[ToolMode, ...] | None = _default("tool.modes")
    frf_csv: str | None = _default("tool.frf_csv")


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

    model: str = _default("cutting.model")
    ktc_n_mm2: float | None = None
    krc_n_mm2: float | None = None
    kte_n_mm: float | None = None
    kre_n_mm: float | None = None
    axial_depth_mm: float | None = None
    spindle_rpm: float | None = None
    milling: str = _default("cutting.milling")
    wall: str = _default("cutting.wall")
    stock: str | None = _default("cutting.stock")
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
        λ of ``J = ε̂ᵀε̂ + λ ΔK²`` (ε̂ in mm, ΔK in (m/min)/mm); YAML key ``lambda``.
    dk_candidates : tuple of float
        Gain increments ΔK tried per period, (m/min)/mm (distinct, 0 among them).
    kp_min_m_min_mm, kp_max_m_min_mm : float
        Gain range, (m/min)/mm, min < max.
    kinematics : str
        ``"predicted"``, ``"eq10"`` or ``"none"``.
    """

    axis: str | None = _default("tuning.schedule.axis")
    horizon_samples: int = _default("tuning.schedule.horizon_samples")
    lam: float = _default("tuning.schedule.lambda")
    dk_candidates: tuple[float, ...] = _default("tuning.schedule.dk_candidates")
    kp_min_m_min_mm: float = _default("tuning.schedule.kp_min_m_min_mm")
    kp_max_m_min_mm: float = _default("tuning.schedule.kp_max_m_min_mm")
    kinematics: str = _default("tuning.schedule.kinematics")

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
        if units not in ("mm", "inch"):
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
        return yaml.dump(self.to_dict(), Dumper=_Dumper, sort_keys=False, allow_unicode=True)


# --------------------------------------------------------------------------
# YAML reading with line numbers
# --------------------------------------------------------------------------


class _Loader(yaml.SafeLoader):
    """Safe loader that also reads ``1e-5`` (no dot) as a float, as YAML 1.2 does."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def _key_lines(
    node: yaml.Node,
    prefix: tuple[str, ...],
    out: dict[tuple[str, ...], int],
    fail: _Fail,
    visited: set[int] | None = None,
) -> None:
    """Record the 1-based line of every mapping key under ``node`` by its path.

    A node reached again through an alias is not walked again (its keys keep
    the lines of the anchored definition through the fallback of
    :meth:`_Fail.line`), which also stops recursive aliases.
    """
    if visited is None:
        visited = set()
    if id(node) in visited:
        return
    visited.add(id(node))
    if isinstance(node, yaml.MappingNode):
        seen: dict[str, int] = {}
        for knode, vnode in node.value:
            if not isinstance(knode, yaml.ScalarNode) or knode.tag == "tag:yaml.org,2002:merge":
                continue
            key = str(knode.value)
            line = knode.start_mark.line + 1
            if key in seen:
                fail.at_line(line, f"{'.'.join((*prefix, key))}: duplicate key (first given on line {seen[key]})")
            seen[key] = line
            path = (*prefix, key)
            out[path] = line
            _key_lines(vnode, path, out, fail, visited)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            out.setdefault((*prefix, str(i)), item.start_mark.line + 1)
            _key_lines(item, (*prefix, str(i)), out, fail, visited)


def _parse_yaml(text: str, fail: _Fail) -> tuple[Any, int | None]:
    """Parse ``text``; return the data and the line of the top-level node."""
    try:
        node = yaml.compose(text, Loader=_Loader)
        data = yaml.load(text, Loader=_Loader)  # _Loader is a SafeLoader
        if node is not None:
            _key_lines(node, (), fail.lines, fail)
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, exc.position) + 1
        ch = exc.character if isinstance(exc.character, int) else ord(str(exc.character)[:1] or "\0")
        fail.at_line(line, f"invalid YAML: control character U+{ch:04X} is not allowed")
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        problem = exc.problem or exc.context or "syntax error"
        if exc.context and exc.problem:
            problem = f"{problem} ({exc.context})"
        fail.at_line(mark.line + 1 if mark is not None else None, f"invalid YAML: {problem}")
    except yaml.YAMLError as exc:
        fail.at_line(None, f"invalid YAML: {exc}")
    except RecursionError:
        fail.at_line(None, "invalid YAML: nested too deeply")
    if node is None:
        return None, None
    return data, node.start_mark.line + 1


class _Dumper(yaml.SafeDumper):
    """Safe dumper writing mappings in block style and short lists (``[min, max]``) in flow style."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def _represent_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=True)


_Dumper.add_representer(list, _represent_list)


# --------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------


class _Fail:
    """Raises :class:`ProfileError` with the file and the line of a key path."""

    def __init__(self, file: Path | None) -> None:
        self.file = file
        self.lines: dict[tuple[str, ...], int] = {}
        self.root_line: int | None = None

    def line(self, path: tuple[str, ...]) -> int | None:
        for n in range(len(path), 0, -1):
            if path[:n] in self.lines:
                return self.lines[path[:n]]
        return self.root_line

    def at_line(self, line: int | None, problem: str) -> NoReturn:
        raise ProfileError(self.file, line, problem)

    def __call__(self, path: tuple[str, ...], problem: str, *, line_path: tuple[str, ...] | None = None) -> NoReturn:
        where = ".".join(path)
        raise ProfileError(self.file, self.line(path if line_path is None else line_path), f"{where}: {problem}")


def _num(x: float) -> str:
    """Format a number for a message: integers plainly, others by repr."""
    if isinstance(x, bool):
        return str(x).lower()
    if isinstance(x, int) or (isinstance(x, float) and x.is_integer() and abs(x) < 1e7):
        return str(int(x))
    return repr(float(x))


def _got(v: Any) -> str:
    if v is None:
        return "nothing (empty value)"
    if isinstance(v, bool):
        return f"{str(v).lower()} (a boolean)"
    if isinstance(v, str):
        return repr(v)
    if isinstance(v, (int, float)):
        return _num(v) if not isinstance(v, float) else repr(v)
    if isinstance(v, Mapping):
        return "a mapping"
    if isinstance(v, (list, tuple)):
        return "a list"
    return type(v).__name__


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _children(pattern: str) -> list[Spec]:
    return [s for s in SPECS if s.parent == pattern]


def _resolve(selector: str, concrete: tuple[str, ...]) -> tuple[str, ...]:
    """Concrete path of a selector pattern, taking ``<axis>`` from ``concrete``."""
    parts = selector.split(".")
    return tuple(concrete[i] if p == "<axis>" and i < len(concrete) else p for i, p in enumerate(parts))


class _Validator:
    """Walks the data against :data:`SPECS`; remembers validated values by concrete path (for ``when``)."""

    def __init__(self, fail: _Fail) -> None:
        self.fail = fail
        self.values: dict[tuple[str, ...], Any] = {}

    def active(self, spec: Spec, concrete: tuple[str, ...]) -> bool:
        if spec.when is None:
            return True
        return self.values.get(_resolve(spec.when[0], concrete)) == spec.when[1]

    def section(self, spec_path: str, path: tuple[str, ...], value: Any) -> dict[str, Any]:
        """Validate a mapping of fixed keys; return it with defaults filled."""
        if value is None:
            value = {}
        if not isinstance(value, Mapping):
            allowed = ", ".join(s.key for s in _children(spec_path) if s.when is None)
            self.fail(path, f"must be a mapping with keys {allowed}, got {_got(value)}")
        children = _children(spec_path)
        out: dict[str, Any] = {}
        # Selectors first: the keys allowed here may depend on them.
        for s in children:
            if s.path in _SELECTORS:
                out[s.key] = self.entry(s, path, value)
        active = [s for s in children if self.active(s, path)]
        names = [s.key for s in active]
        for key in value:
            if not isinstance(key, str) or key not in names:
                extra = ""
                sel = next((s.when for s in children if s.when and s.key == key), None)
                if sel is not None:
                    cur = self.values.get(_resolve(sel[0], path))
                    extra = f" for {sel[0].rsplit('.', 1)[-1]} {cur}"
                elif path == () and isinstance(key, str) and key in AXIS_NAMES:
                    extra = " (axes go under 'axes:')"
                self.fail((*path, str(key)), f"unknown key{extra}; allowed: {', '.join(names)}")
        for s in active:
            if s.key not in out:
                out[s.key] = self.entry(s, path, value)
        return out

    def entry(self, spec: Spec, parent: tuple[str, ...], mapping: Mapping[str, Any]) -> Any:
        path = (*parent, spec.key)
        if spec.key not in mapping or (mapping[spec.key] is None and spec.default is None):
            if spec.required:
                what = "section" if spec.kind in ("section", "axis_map") else "key"
                rng = spec.range_text()
                extra = f" ({spec.unit + ', ' if spec.unit else ''}{rng})" if rng else ""
                self.fail(path, f"missing required {what}{extra}", line_path=parent)
            if spec.kind == "section":
                return self.section(spec.path, path, {})
            if spec.kind == "axis_map":
                return {}
            self.values[path] = spec.default
            return spec.default
        v = self.value(spec, path, mapping[spec.key])
        self.values[path] = v
        return v

    def value(self, spec: Spec, path: tuple[str, ...], v: Any) -> Any:
        kind = spec.kind
        if kind == "section":
            return self.section(spec.path, path, v)
        if kind == "axis_map":
            return self.axis_map(spec, path, v)
        if kind == "str":
            if not isinstance(v, str) or not v.strip():
                self.fail(path, f"must be a non-empty text (quote it if needed), got {_got(v)}")
            return v
        if kind == "choice":
            if not isinstance(v, str) or v not in spec.choices:
                self.fail(path, f"must be {spec.range_text()}, got {_got(v)}")
            return v
        if kind in ("float", "int"):
            return self.number(spec, path, v)
        if kind == "axis_float":
            if isinstance(v, Mapping):
                out: dict[str, float] = {}
                for ax, g in v.items():
                    if ax not in AXIS_NAMES:
                        self.fail(
                            (*path, str(ax)), f"unknown axis; a per-axis gain is keyed by {', '.join(AXIS_NAMES)}"
                        )
                    out[ax] = self.number(spec, (*path, ax), g)
                if not out:
                    self.fail(path, "empty per-axis mapping; give a number or one per axis")
                return {ax: out[ax] for ax in AXIS_NAMES if ax in out}
            return self.number(spec, path, v, per_axis=True)
        if kind == "range_pair":
            ok = isinstance(v, (list, tuple)) and len(v) == 2 and all(_is_number(e) for e in v)
            want = f"must be a list [min, max] of two numbers {spec.range_text()} with min < max"
            if not ok:
                self.fail(path, f"{want}, got {_got(v)}")
            lo, hi = float(v[0]), float(v[1])
            if not (math.isfinite(lo) and math.isfinite(hi)) or not (
                self.in_range(spec, lo) and self.in_range(spec, hi)
            ):
                self.fail(path, f"{want}, got [{_num(v[0])}, {_num(v[1])}]")
            if not lo < hi:
                self.fail(path, f"{want}, got min {_num(v[0])} >= max {_num(v[1])}")
            return (lo, hi)
        if kind == "axis_pair":
            want = f"must be a list of two different axis names from {', '.join(AXIS_NAMES)}"
            ok = (
                isinstance(v, (list, tuple))
                and len(v) == 2
                and all(isinstance(e, str) and e in AXIS_NAMES for e in v)
                and v[0] != v[1]
            )
            if not ok:
                shown = f"[{', '.join(str(e) for e in v)}]" if isinstance(v, (list, tuple)) else _got(v)
                self.fail(path, f"{want}, got {shown}")
            return (v[0], v[1])
        if kind == "coeffs":
            return self.coeffs(spec, path, v)
        if kind == "numbers":
            return self.numbers(spec, path, v)
        if kind == "modes":
            return self.modes(path, v)
        raise AssertionError(kind)  # pragma: no cover

    def coeffs(self, spec: Spec, path: tuple[str, ...], v: Any) -> tuple[float, ...]:
        """Validate a list of polynomial coefficients (descending powers of s)."""
        want = (
            f"must be a list of 1 to {MAX_COEFFS} finite numbers (coefficients in descending powers of s,"
            " the first non-zero)"
        )
        if not isinstance(v, (list, tuple)) or not 1 <= len(v) <= MAX_COEFFS:
            self.fail(path, f"{want}, got {_got(v) if not isinstance(v, (list, tuple)) else f'{len(v)} items'}")
        for i, e in enumerate(v):
            if not _is_number(e) or not math.isfinite(e) or not self.in_range(spec, e):
                self.fail((*path, str(i)), f"{want}, got {_got(e)}", line_path=path)
        if v[0] == 0:
            self.fail(path, f"{want}, got a leading 0")
        return tuple(float(e) for e in v)

    def numbers(self, spec: Spec, path: tuple[str, ...], v: Any) -> tuple[float, ...]:
        """Validate a list of finite numbers within the spec's range."""
        want = f"must be a list of 1 to {MAX_DK_CANDIDATES} finite numbers {spec.range_text()}"
        if not isinstance(v, (list, tuple)) or not 1 <= len(v) <= MAX_DK_CANDIDATES:
            self.fail(path, f"{want}, got {_got(v) if not isinstance(v, (list, tuple)) else f'{len(v)} items'}")
        for i, e in enumerate(v):
            if not _is_number(e) or not math.isfinite(e) or not self.in_range(spec, e):
                self.fail(path, f"{want}, got {_got(e)} (item {i})")
        return tuple(float(e) for e in v)

    def modes(self, path: tuple[str, ...], v: Any) -> tuple[ToolMode, ...]:
        """Validate a list of tool modes (``tool.modes``)."""
        want = "must be a list of 1 to 10 modes {direction, natural_frequency_hz, damping_ratio, stiffness_n_um}"
        if not isinstance(v, (list, tuple)) or not 1 <= len(v) <= 10:
            self.fail(path, f"{want}, got {_got(v) if not isinstance(v, (list, tuple)) else f'{len(v)} items'}")
        out = []
        for i, m in enumerate(v):
            p = (*path, str(i))
            if not isinstance(m, Mapping):
                self.fail(p, f"{want}; item {i} is {_got(m)}", line_path=path)
            extra = sorted(set(map(str, m)) - set(_MODE_KEYS))
            if extra:
                self.fail((*p, extra[0]), f"unknown key; allowed: {', '.join(_MODE_KEYS)}", line_path=p)
            for key in _MODE_KEYS:
                if key not in m:
                    self.fail(p, f"mode {i} misses {key}", line_path=path)
            if m["direction"] not in ("feed", "normal"):
                self.fail((*p, "direction"), f"must be feed or normal, got {_got(m['direction'])}", line_path=p)
            vals = {}
            for key, lo, hi, unit in (("natural_frequency_hz", 0.0, 1e5, "Hz"), ("damping_ratio", 0.0, 1.0, ""),
                                      ("stiffness_n_um", 0.0, 1e6, "N/µm")):
                x = m[key]
                if not _is_number(x) or not math.isfinite(x) or not lo < x < hi:
                    self.fail((*p, key), f"must be a number > {_num(lo)} and < {_num(hi)}{' ' + unit if unit else ''},"
                                         f" got {_got(x)}", line_path=p)
                vals[key] = float(x)
            out.append(ToolMode(direction=m["direction"], **vals))
        return tuple(out)

    @staticmethod
    def in_range(spec: Spec, x: float) -> bool:
        if spec.lo is not None and (x <= spec.lo if spec.lo_open else x < spec.lo):
            return False
        return not (spec.hi is not None and (x >= spec.hi if spec.hi_open else x > spec.hi))

    def number(self, spec: Spec, path: tuple[str, ...], v: Any, *, per_axis: bool = False) -> Any:
        rng = spec.range_text()
        if spec.kind == "int":
            if not isinstance(v, int) or isinstance(v, bool):
                if isinstance(v, float) and v.is_integer():
                    v = int(v)
                else:
                    self.fail(path, f"must be an integer {rng}, got {_got(v)}")
            if not self.in_range(spec, v):
                self.fail(path, f"must be {rng}, got {_got(v)}")
            return v
        if not _is_number(v):
            what = "a number or a per-axis mapping of numbers" if per_axis else "a number"
            self.fail(path, f"must be {what} {rng}, got {_got(v)}")
        if not math.isfinite(v):
            self.fail(path, f"must be a finite number {rng}, got {v!r}")
        if not self.in_range(spec, v):
            self.fail(path, f"must be {rng}, got {_got(v)}")
        return float(v)

    def axis_map(self, spec: Spec, path: tuple[str, ...], v: Any) -> dict[str, Any]:
        child = next(s for s in SPECS if s.parent == spec.path)
        if v is None:
            v = {}
        if not isinstance(v, Mapping):
            self.fail(path, f"must be a mapping keyed by axis name ({', '.join(AXIS_NAMES)}), got {_got(v)}")
        out: dict[str, Any] = {}
        for key in v:
            if key not in AXIS_NAMES:
                hint = " (axis names are lowercase)" if isinstance(key, str) and key.lower() in AXIS_NAMES else ""
                self.fail((*path, str(key)), f"unknown axis{hint}; allowed: {', '.join(AXIS_NAMES)}")
        for key in AXIS_NAMES:  # canonical order
            if key in v:
                out[key] = self.value(child, (*path, key), v[key])
                self.values[(*path, key)] = out[key]
        if spec.required and not out:
            self.fail(path, f"at least one axis is required; allowed: {', '.join(AXIS_NAMES)}")
        return out


def _cross_checks(d: dict[str, Any], fail: _Fail) -> None:
    """Rules that involve more than one key."""
    cut, tool = d["cutting"], d["tool"]
    if cut["model"] != "none":
        if cut["stock"] is None and cut["radial_depth_mm"] is None:
            fail(("cutting", "model"), f"cutting.model {cut['model']} needs cutting.stock (an OMI file) or"
                                       " cutting.radial_depth_mm")
        if not tool["modes"] and tool["frf_csv"] is None:
            fail(("cutting", "model"), f"cutting.model {cut['model']} needs the tool's frequency response:"
                                       " tool.modes or tool.frf_csv")
        if cut["radial_depth_mm"] is not None and cut["radial_depth_mm"] > tool["diameter_mm"]:
            fail(("cutting", "radial_depth_mm"), f"must be <= tool.diameter_mm ({_num(tool['diameter_mm'])} mm),"
                                                 f" got {_num(cut['radial_depth_mm'])}")
    axes = d["axes"]
    names = ", ".join(axes)
    for ax in d["machine"]["travel_mm"]:
        if ax not in axes:
            fail(("machine", "travel_mm", ax), f"axis {ax} is not defined under axes (defined: {names})")
    ctl = d["controller"]
    if ctl["type"] == "cross_coupled":
        gain_spec = _spec("controller.cross_coupling_gain")
        if ctl["cross_coupling_gain"] <= 0:
            fail(
                ("controller", "cross_coupling_gain"),
                f"must be > 0 and {gain_spec.range_text().split(' and ')[-1]} when controller.type is"
                f" cross_coupled, got {_num(ctl['cross_coupling_gain'])}",
                line_path=("controller", "type") if ("controller", "cross_coupling_gain") not in fail.lines else None,
            )
        for ax in ctl["coupled_axes"]:
            if ax not in axes:
                fail(
                    ("controller", "coupled_axes"),
                    f"axis {ax} is not defined under axes (defined: {names}); cross-coupling needs two defined axes",
                )
        for ax in ctl["coupled_axes"]:
            drv = dict(axes[ax]["drive"])
            if not has_position_loop(DRIVE_MODELS[drv.pop("model")](**drv)):
                fail(
                    ("controller", "coupled_axes"),
                    f"axis {ax} has no position loop for the cross-coupled controller to act on (axes.{ax}.drive"
                    " must be mass_damper_pid, p_ff_friction, sopdt with position_gain_1_s or transfer_function"
                    " with feedback unity)",
                )
    for name, g in d["learning"]["gains"].items():
        if isinstance(g, dict):
            for ax in g:
                if ax not in axes:
                    fail(("learning", "gains", name, ax), f"axis {ax} is not defined under axes (defined: {names})")
            for ax in axes:
                if ax not in g:
                    fail(
                        ("learning", "gains", name, ax),
                        f"missing; a per-axis gain must give every axis ({names}) or be one number",
                        line_path=("learning", "gains", name),
                    )
    _schedule_checks(d["tuning"]["schedule"], names, axes, fail)
    for ax, a in axes.items():
        drv = a["drive"]
        p = ("axes", ax, "drive")
        if drv["model"] == "transfer_function":
            _transfer_function_checks(drv, p, fail)
        if drv["model"] != "p_ff_friction":
            continue
        friction = drv["coulomb_n"] > 0 or drv["viscous_n_s_mm"] > 0 or drv["static_n"] > 0
        if friction and drv["inertia_kg"] is None:
            rng = _spec(f"{_DRIVE}.inertia_kg").range_text()
            fail((*p, "inertia_kg"), f"missing; required ({rng}, kg) when a friction term is non-zero", line_path=p)
        if drv["static_n"] > 0 and drv["static_n"] < drv["coulomb_n"]:
            fail(
                (*p, "static_n"),
                f"must be 0 or >= coulomb_n ({_num(drv['coulomb_n'])}), got {_num(drv['static_n'])}",
            )
        if drv["static_n"] > drv["coulomb_n"] and drv["stribeck_velocity_mm_s"] <= 0:
            rng = _spec(f"{_DRIVE}.stribeck_velocity_mm_s").range_text()
            fail(
                (*p, "stribeck_velocity_mm_s"),
                f"must be > 0 ({rng}) when static_n > coulomb_n, got {_num(drv['stribeck_velocity_mm_s'])}",
                line_path=p if (*p, "stribeck_velocity_mm_s") not in fail.lines else None,
            )


def _schedule_checks(sch: dict[str, Any], names: str, axes: dict[str, Any], fail: _Fail) -> None:
    """``tuning.schedule``: a defined axis, kp_min < kp_max, distinct ΔK candidates that include 0."""
    p = ("tuning", "schedule")
    if sch["axis"] is not None and sch["axis"] not in axes:
        fail((*p, "axis"), f"axis {sch['axis']} is not defined under axes (defined: {names})")
    if not sch["kp_min_m_min_mm"] < sch["kp_max_m_min_mm"]:
        fail(
            (*p, "kp_min_m_min_mm"),
            f"must be < kp_max_m_min_mm ({_num(sch['kp_max_m_min_mm'])}), got {_num(sch['kp_min_m_min_mm'])}",
            line_path=(*p, "kp_min_m_min_mm") if (*p, "kp_min_m_min_mm") in fail.lines else (*p, "kp_max_m_min_mm"),
        )
    dk = sch["dk_candidates"]
    shown = "[" + ", ".join(_num(x) for x in dk) + "]"
    if 0.0 not in dk:
        fail((*p, "dk_candidates"), f"must include 0 (holding the gain is always a candidate), got {shown}")
    if len(set(dk)) != len(dk):
        dup = next(x for i, x in enumerate(dk) if x in dk[:i])
        fail((*p, "dk_candidates"), f"must be distinct, got {_num(dup)} twice in {shown}")


def _transfer_function_checks(drv: dict[str, Any], p: tuple[str, ...], fail: _Fail) -> None:
    """A transfer_function drive must be strictly proper and its closed loop stable."""
    num, den = drv["numerator"], drv["denominator"]
    if len(num) >= len(den):
        fail(
            (*p, "numerator"),
            f"must have fewer coefficients than denominator ({len(den)}): the axis transfer function must be"
            f" strictly proper, got {len(num)}",
        )
    char = list(den)
    if drv["feedback"] == "unity":
        char = [c + n for c, n in zip(char, [0.0] * (len(den) - len(num)) + list(num), strict=True)]
    if char[0] == 0:
        fail((*p, "denominator"), "the closed-loop characteristic polynomial (denominator + numerator) has a leading 0")
    poles = np.roots(char)
    bad = [z for z in poles if z.real >= 0]
    if bad:
        what = "1 + L(s)" if drv["feedback"] == "unity" else "the closed loop"
        shown = ", ".join(f"{z.real:.4g}{z.imag:+.4g}j" if abs(z.imag) > 0 else f"{z.real:.4g}" for z in bad)
        fail((*p, "denominator"), f"{what} is unstable: pole(s) with real part >= 0: {shown}")


def _build(d: dict[str, Any], path: Path | None, text: str) -> MachineProfile:
    m = d["machine"]
    axes: dict[str, AxisProfile] = {}
    for name, a in d["axes"].items():
        drv = dict(a["drive"])
        cls = DRIVE_MODELS[drv.pop("model")]
        axes[name] = AxisProfile(
            name=name,
            max_velocity_mm_min=a["max_velocity_mm_min"],
            max_acceleration_m_s2=a["max_acceleration_m_s2"],
            max_jerk_m_s3=a["max_jerk_m_s3"],
            rapid_mm_min=a["rapid_mm_min"] if a["rapid_mm_min"] is not None else a["max_velocity_mm_min"],
            drive=cls(**drv),
        )
    return MachineProfile(
        machine=MachineSection(**m),
        axes=axes,
        controller=ControllerSection(**d["controller"]),
        planner=PlannerSection(**d["planner"]),
        learning=LearningSection(**{**d["learning"], "refine": RefineSection(**d["learning"]["refine"])}),
        output=OutputSection(**d["output"]),
        geometry=GeometrySection(**d["geometry"]),
        tool=ToolSection(**d["tool"]),
        cutting=CuttingSection(**d["cutting"]),
        tuning=TuningSection(schedule=ScheduleTuning(**{("lam" if k == "lambda" else k): v
                                                          for k, v in d["tuning"]["schedule"].items()})),
        path=path,
        source_text=text,
    )


def _validate(data: Any, fail: _Fail, path: Path | None, text: str) -> MachineProfile:
    sections = ", ".join(_TOP_SECTIONS)
    if data is None:
        fail.at_line(1, f"empty profile; expected a mapping with the sections {sections}")
    if not isinstance(data, Mapping):
        fail.at_line(fail.root_line, f"the profile must be a mapping with the sections {sections}, got {_got(data)}")
    v = _Validator(fail)
    d = v.section("", (), data)
    _cross_checks(d, fail)
    return _build(d, path, text)


# --------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------


def load_profile(path: str | Path) -> MachineProfile:
    """Read, check and return the machine profile in a YAML file.

    Parameters
    ----------
    path : str or Path
        The YAML file.

    Returns
    -------
    MachineProfile
        The profile with every default filled.

    Raises
    ------
    ProfileError
        When the file cannot be read, is not valid YAML, or a key is unknown,
        missing, of the wrong type or out of range. The message is one line:
        ``file:line: yaml.path: problem``.
    """
    p = Path(path)
    try:
        raw = read_bytes(p)
    except InputError as exc:
        raise ProfileError(exc.file, exc.line, exc.problem) from None
    fail = _Fail(p)
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        fail.at_line(raw.count(b"\n", 0, exc.start) + 1, "not UTF-8 text; save the profile as UTF-8")
    data, root_line = _parse_yaml(text, fail)
    fail.root_line = root_line
    return _validate(data, fail, p, text)


def profile_from_dict(data: Mapping[str, Any], *, path: str | Path | None = None) -> MachineProfile:
    """Check and return a machine profile given as plain data.

    Parameters
    ----------
    data : mapping
        The profile as :func:`yaml.safe_load` or :meth:`MachineProfile.to_dict`
        gives it.
    path : str or Path, optional
        File name used in error messages.

    Returns
    -------
    MachineProfile

    Raises
    ------
    ProfileError
        As :func:`load_profile` (without line numbers).
    """
    p = Path(path) if path is not None else None
    return _validate(data, _Fail(p), p, "")


_DEFAULT_DRIVE: dict[str, Any] = {"model": "sopdt", "gain": 1.0, "omega0_rad_s": 95.6, "zeta": 1.0, "delay_s": 0.0066}

_DEFAULT_PROFILE: dict[str, Any] = {
    "machine": {"name": "generic 3-axis VMC", "units": "mm", "servo_period_s": 0.001, "resolution_mm": 0.001},
    "axes": {
        "x": {
            "max_velocity_mm_min": 30000.0,
            "max_acceleration_m_s2": 3.0,
            "max_jerk_m_s3": 50.0,
            "rapid_mm_min": 36000.0,
            "drive": _DEFAULT_DRIVE,
        },
        "y": {
            "max_velocity_mm_min": 30000.0,
            "max_acceleration_m_s2": 3.0,
            "max_jerk_m_s3": 50.0,
            "rapid_mm_min": 36000.0,
            "drive": _DEFAULT_DRIVE,
        },
        "z": {
            "max_velocity_mm_min": 24000.0,
            "max_acceleration_m_s2": 2.5,
            "max_jerk_m_s3": 40.0,
            "rapid_mm_min": 30000.0,
            "drive": _DEFAULT_DRIVE,
        },
    },
}


def default_profile() -> MachineProfile:
    """Return the profile used when none is given: a generic 3-axis mill.

    It is the same machine as ``configs/example-mill.yaml``: 30 m/min,
    3 m/s², 50 m/s³ on X/Y (24 m/min, 2.5 m/s², 40 m/s³ on Z), SOPDT velocity
    drives with the seed-004 fit (ω0 = 95.6 rad/s, ζ = 1, Td = 6.6 ms, unity
    gain), independent axes, a 7-phase planner and a P-type law with Γ = 0.5.
    """
    return profile_from_dict(_DEFAULT_PROFILE)


# --------------------------------------------------------------------------
# Documentation from the schema
# --------------------------------------------------------------------------


def _iter_doc_rows(section: str) -> Iterator[Spec]:
    for s in SPECS:
        if s.path == section or s.path.startswith(section + "."):
            yield s


def _doc_default(s: Spec) -> str:
    if s.default_doc:
        return s.default_doc
    if s.required:
        return "**required**"
    if s.kind in ("section", "axis_map"):
        return "all defaults" if s.kind == "section" else "none"
    if s.default is None:
        return "none"
    if isinstance(s.default, tuple):
        return "[" + ", ".join(str(x) for x in s.default) + "]"
    if isinstance(s.default, str):
        return f"`{s.default}`"
    return _num(s.default)


def _doc_type(s: Spec) -> str:
    return {
        "section": "mapping",
        "axis_map": "mapping by axis",
        "float": "number",
        "int": "integer",
        "str": "text",
        "choice": "choice",
        "axis_float": "number or per-axis",
        "range_pair": "[min, max]",
        "axis_pair": "[axis, axis]",
        "coeffs": "[number, ...]",
        "numbers": "[number, ...]",
        "modes": "list of modes",
    }[s.kind]


def schema_markdown() -> str:
    """Return the reference tables of ``docs/profile.md``, generated from :data:`SPECS`.

    Returns
    -------
    str
        Markdown: one table per section, conditional keys (drive models,
        learning laws) in tables of their own.
    """
    lines: list[str] = []
    header = ["| key | type | unit | allowed | default | description |", "|---|---|---|---|---|---|"]
    for top in _TOP_SECTIONS:
        groups: dict[tuple[str, str] | None, list[Spec]] = {}
        for s in _iter_doc_rows(top):
            groups.setdefault(s.when, []).append(s)
        for when, specs in groups.items():
            title = f"`{top}`" if when is None else f"`{top}` — `{when[0]}: {when[1]}`"
            lines += [f"### {title}", "", *header]
            for s in specs:
                desc = s.doc.replace("|", "\\|")
                rng = s.range_text() if s.kind not in ("section", "axis_map", "str", "axis_pair", "coeffs", "modes") else ""
                if s.kind == "coeffs":
                    rng = f"1 to {MAX_COEFFS} finite numbers, the first non-zero"
                if s.kind == "axis_pair":
                    rng = "two different of " + ", ".join(AXIS_NAMES)
                if s.kind == "numbers":
                    rng = f"1 to {MAX_DK_CANDIDATES} numbers {s.range_text()}"
                lines.append(
                    f"| `{s.path}` | {_doc_type(s)} | {s.unit or '—'} | {rng or '—'} | {_doc_default(s)} | {desc} |"
                )
            lines.append("")
    return "\n".join(lines).rstrip() + "\n"


if __name__ == "__main__":  # pragma: no cover
    print(schema_markdown(), end="")

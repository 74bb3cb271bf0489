"""The machine profile's schema: one declarative table of every key.

A profile describes one machine: its kinematic limits per axis, a model of
each axis drive, the controller structure, the feed planner, the learning law
and how corrected programs are written. It is a YAML file (``configs/*.yaml``)
read with :func:`ilcnc.profile.load.load_profile`.

The whole schema is the declarative table :data:`SPECS` (one :class:`Spec` per
key: YAML path, type, range or choices, default, unit, description). The
loader (:mod:`ilcnc.profile.load`), the dataclass defaults
(:mod:`ilcnc.profile.sections`) and the documentation (``docs/profile.md``,
:mod:`ilcnc.profile.docs`) are all derived from that one table.

Units
-----
Lengths are millimetres and times seconds unless the key name says otherwise
(``max_velocity_mm_min`` is mm/min, ``max_acceleration_m_s2`` is m/s²,
``max_jerk_m_s3`` is m/s³).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ilcnc.units import AXIS_NAMES, LENGTH_UNITS, MM_PER_INCH

__all__ = [
    "AXIS_NAMES",
    "DEFAULT_ERROR",
    "DRIVE_KEY",
    "ERROR_KINDS",
    "HISTORY_LAWS",
    "MAX_COEFFS",
    "MAX_DK_CANDIDATES",
    "MM_PER_INCH",
    "PREDICTED_ERRORS",
    "SELECTORS",
    "SPECS",
    "TOP_SECTIONS",
    "Spec",
    "default_of",
    "format_number",
    "spec_of"
]


def format_number(x: float) -> str:
    """Format a number for a message: integers plainly, others by repr."""
    if isinstance(x, bool):
        return str(x).lower()
    if isinstance(x, int) or (isinstance(x, float) and x.is_integer() and abs(x) < 1e7):
        return str(int(x))
    return repr(float(x))


#: Axis names a profile may define, in this order.

#: Millimetres per inch (exact).

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
            parts.append(f"{'>' if self.lo_open else '>='} {format_number(self.lo)}")
        if self.hi is not None:
            parts.append(f"{'<' if self.hi_open else '<='} {format_number(self.hi)}")
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


DRIVE_KEY = "axes.<axis>.drive"
_SOPDT = (f"{DRIVE_KEY}.model", "sopdt")
_MDPID = (f"{DRIVE_KEY}.model", "mass_damper_pid")
_PFF = (f"{DRIVE_KEY}.model", "p_ff_friction")
_FOD = (f"{DRIVE_KEY}.model", "first_order_delay")
_TF = (f"{DRIVE_KEY}.model", "transfer_function")
_LAW_P = ("learning.law", "p")
_LAW_PID = ("learning.law", "pid_ace")
_LAW_SO = ("learning.law", "second_order")
_CUT_M = ("cutting.model", "mechanistic")

#: Default error estimate of each law (``learning.error: auto``).
DEFAULT_ERROR = {"p": "path", "pid_ace": "contour", "second_order": "tracking"}
#: The estimates (profile key ``learning.error``, ``auto`` aside).
ERROR_KINDS = ("path", "crossing", "contour", "tangent", "tracking", "lifted", "surface")
#: The estimates the virtual CNC predicts from a run (``learning.model_steps`` needs one of them).
PREDICTED_ERRORS = ("path", "crossing", "lifted")
#: Laws whose update keeps a history of more than the last run (they take no model-assisted step).
HISTORY_LAWS = ("second_order",)


#: The profile schema: every key, in file order.
SPECS: tuple[Spec, ...] = (
    # machine ---------------------------------------------------------------
    _sec("machine", "The machine as a whole.", required=True),
    Spec("machine.name", "str", "Name of the machine (free text, shown in reports)."),
    _c(
        "machine.units",
        "Program units assumed when a program has no G20/G21 (Heidenhain programs always say MM or INCH).",
        LENGTH_UNITS,
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
        "Maximum programmable feed of the axis (at least 1 mm/min: slower, a run takes longer than any machine does).",
        "mm/min",
        1,
        1e6,
    ),
    _f("axes.<axis>.max_acceleration_m_s2", "Maximum acceleration of the axis (at least 1 mm/s²).", "m/s²", 0.001, 1000),
    _f("axes.<axis>.max_jerk_m_s3", "Maximum jerk of the axis (at least 1 mm/s³).", "m/s³", 0.001, 1e5),
    _f(
        "axes.<axis>.rapid_mm_min",
        "Rapid (G00 / FMAX) velocity of the axis.",
        "mm/min",
        1,
        1e6,
        default=None,
        default_doc="= max_velocity_mm_min",
    ),
    _sec(f"{DRIVE_KEY}", "Model of the axis drive (position command in, actual position out).", required=True),
    _c(
        f"{DRIVE_KEY}.model",
        "Which drive model; each model has its own parameters below.",
        ("sopdt", "mass_damper_pid", "p_ff_friction", "first_order_delay", "transfer_function"),
    ),
    # sopdt (seed 004)
    _f(
        f"{DRIVE_KEY}.gain",
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
        f"{DRIVE_KEY}.omega0_rad_s",
        "Natural frequency ω0 of the velocity drive.",
        "rad/s",
        0,
        1e5,
        lo_open=True,
        when=_SOPDT,
    ),
    _f(f"{DRIVE_KEY}.zeta", "Damping ratio ζ of the velocity drive.", "", 0, 10, lo_open=True, when=_SOPDT),
    _f(f"{DRIVE_KEY}.delay_s", "Dead time Td of the velocity drive.", "s", 0, 1, default=0.0, when=_SOPDT),
    _f(
        f"{DRIVE_KEY}.position_gain_1_s",
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
        f"{DRIVE_KEY}.mass_v_s2_mm",
        "Mass m of the axis as seen by the controller output (m·q̈ + c·q̇ = u, u in volts).",
        "V·s²/mm",
        0,
        1e3,
        lo_open=True,
        when=_MDPID,
    ),
    _f(f"{DRIVE_KEY}.damping_v_s_mm", "Viscous damping c of the axis.", "V·s/mm", 0, 1e3, when=_MDPID),
    _f(f"{DRIVE_KEY}.kp", "Proportional gain K_P of the position PID.", "V/mm", 0, 1e6, when=_MDPID),
    _f(f"{DRIVE_KEY}.ki", "Integral gain K_I of the position PID.", "V/(mm·s)", 0, 1e6, when=_MDPID),
    _f(f"{DRIVE_KEY}.kd", "Derivative gain K_D of the position PID.", "V·s/mm", 0, 1e6, when=_MDPID),
    # p_ff_friction (seed 001)
    _f(
        f"{DRIVE_KEY}.kp_m_min_mm",
        "Position loop gain K_v (velocity command per position error); 1 (m/min)/mm = 16.67 1/s.",
        "(m/min)/mm",
        0,
        100,
        lo_open=True,
        when=_PFF,
    ),
    _f(f"{DRIVE_KEY}.kff", "Velocity feed-forward gain (1 = full feed-forward).", "", 0, 1.5, default=1.0, when=_PFF),
    _f(
        f"{DRIVE_KEY}.velocity_bandwidth_hz",
        "Bandwidth of the (first-order) velocity loop; its force gain is 2π·bandwidth·inertia_kg.",
        "Hz",
        0,
        1e4,
        lo_open=True,
        default=100.0,
        when=_PFF,
    ),
    _f(
        f"{DRIVE_KEY}.velocity_integral_time_s",
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
        f"{DRIVE_KEY}.inertia_kg",
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
    _f(f"{DRIVE_KEY}.coulomb_n", "Coulomb friction force F_c.", "N", 0, 1e5, default=0.0, when=_PFF),
    _f(
        f"{DRIVE_KEY}.viscous_n_s_mm",
        "Viscous friction coefficient B (force per velocity).",
        "N·s/mm",
        0,
        1e4,
        default=0.0,
        when=_PFF,
    ),
    _f(
        f"{DRIVE_KEY}.static_n",
        "Static (breakaway) friction force F_s; 0 means no Stribeck peak (F_s = F_c), otherwise F_s >= F_c.",
        "N",
        0,
        1e5,
        default=0.0,
        when=_PFF,
    ),
    _f(
        f"{DRIVE_KEY}.stribeck_velocity_mm_s",
        "Stribeck velocity v_s over which friction falls from F_s to F_c; must be > 0 when static_n > coulomb_n.",
        "mm/s",
        0,
        1e4,
        default=0.0,
        when=_PFF,
    ),
    # first_order_delay
    _f(
        f"{DRIVE_KEY}.time_constant_s",
        "Time constant T of the closed position loop (T = 1/K_v of a P position loop).",
        "s",
        0,
        10,
        lo_open=True,
        when=_FOD,
    ),
    _f(f"{DRIVE_KEY}.delay_s", "Dead time Td of the closed position loop.", "s", 0, 1, default=0.0, when=_FOD),
    _f(
        f"{DRIVE_KEY}.gain",
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
        f"{DRIVE_KEY}.numerator",
        "coeffs",
        "Numerator of the axis transfer function, coefficients in descending powers of s (first non-zero);"
        " it must have fewer coefficients than the denominator (strictly proper).",
        when=_TF,
    ),
    Spec(
        f"{DRIVE_KEY}.denominator",
        "coeffs",
        "Denominator of the axis transfer function, coefficients in descending powers of s (first non-zero).",
        when=_TF,
    ),
    Spec(
        f"{DRIVE_KEY}.feedback",
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
    _c(
        "controller.theta",
        "Where the cross-coupled controller takes the contour direction θ of C_x = sin θ, C_y = cos θ from."
        " reference: the reference it runs (what a real control knows; a corrected program's reference carries the"
        " corrections, which tilt the direction of short blocks); desired: the drawing, the original program's path"
        " at the point nearest the reference (an offline tool knows it; seed 003's Fig. 2, where the CCC sees the"
        " desired x_r, y_r and the learning input is added after it).",
        ("reference", "desired"),
        default="reference",
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
        " minus the actual position where the machine passes closest to it (seed 004's point error); surface: the"
        " wall the tool leaves per command, seed 004's eq. (4) with its sign corrected, E(k) = (SLE(k) − u(k)·n)·n"
        " with n the normal toward the wall (needs cutting.model mechanistic); contour:"
        " exact contour error vector when the reference reaches the end of command k (seed 000's ACE);"
        " tangent: seed 000's Frenet-frame estimate at that instant; tracking: end point minus actual at that"
        " instant (seed 003); lifted: the end-point moves that, through the drive models, best cancel the"
        " sampled contour error (damped least squares; sees corners; docs/learning.md); auto: path for p (lifted"
        " when the program is refined: learn --refine), contour for pid_ace, tracking for second_order.",
        ("auto", *ERROR_KINDS),
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
        "learning.arc_start_radial_mm",
        "How far the end point before an arc may move off the arc's circle: the arc, whose centre and end stay,"
        " becomes a spiral whose start radius differs from its end radius by at most this (LinuxCNC runs such"
        " spirals and accepts up to 0.02·√2 = 0.0283 mm; other controls have their own limit: set yours). 0: the point"
        " moves only along the circle (docs/learning.md).",
        "mm",
        0,
        0.028,
        default=0.0,
    ),
    _f(
        "learning.cycle_budget_pct",
        "Most extra cycle time the learned corrections may cost, % of the original program's (planned) cycle time:"
        " a correction that bends a corner the planner runs at its tolerance makes it slow down there; such"
        " corrections are held back, each held coordinate reported as a clip 'cycle time' (docs/learning.md).",
        "%",
        0,
        100,
        default=5.0,
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
    _c("learning.refine.settle", "A dwell (G-code G4, Klartext cycle 9) before the first feed after a rapid where the"
       " first run shows the axes still lagging the rapid (the feed would start while they catch up): as long as the"
       " slowest axis's drive model takes to settle from that lag to min_error_mm, rounded up to the servo period"
       " (docs/learning.md). Only with refinement.", ("off", "on"), default="on"),
    _f("learning.refine.settle_budget_pct", "Most cycle time the settles may add, % of the original program's"
       " planned cycle time; where they would need more, the largest lags are settled first and the rest reported.",
       "%", 0, 10, default=0.5),
    _c("learning.refine.tolerance", "A tighter corner tolerance (G-code G64 P, Klartext cycle 32; the program's own"
       " path control after each range) on the moves that end at the corners where the first run's error is mostly"
       " the planner's rounding within the tolerance the program allows and would stay above about half the first"
       " run's cutting max after learning (no corrected end point takes that rounding away): the largest first,"
       " within tolerance_budget_pct of cycle time (docs/learning.md). Only with refinement, on the virtual CNC;"
       " LinuxCNC G-code and Klartext only.", ("off", "on"), default="off"),
    _f("learning.refine.tolerance_share", "The tighter tolerance as a share of the target, half the first run's cutting"
       " max (the rest of the target is left for the lag that learning leaves), never below twice"
       " machine.resolution_mm.", "", 0, 1, lo_open=True, default=0.5),
    _f("learning.refine.tolerance_budget_pct", "Most cycle time the tighter tolerance may add, % of the original"
       " program's planned cycle time (planned before learning); the corners beyond it are reported.", "%", 0, 10,
       default=2.0),
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
    _f("tool.teeth", "Number of teeth (flutes), evenly spaced.", "", 1, 20, default=2, kind="int"),
    _f("tool.helix_deg", "Helix angle of the flutes (right-hand helix); 0: straight flutes. A helix or runout"
       " switches the SLE to the helical model (ilcnc/vcnc/helix_sle.py).", "°", 0, 80, hi_open=True, default=0.0),
    _f("tool.runout_um", "Radial runout of the tool as a dial indicator reads it on the flutes (total indicator"
       " reading); the flutes cut at radii R ± TIR/2.", "µm", 0, 1000, default=0.0),
    _f("tool.runout_angle_deg", "Direction of the runout offset from flute 1 (0: flute 1 cuts at the largest"
       " radius).", "°", -360, 360, default=0.0),
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
        "Weight λ of the gain increment in J = ε̂ᵀε̂ + λ·ΔK², with ε̂ in µm and ΔK in (m/min)/mm (seed 001:"
        " λ = 0.01; the paper gives no units, but only with ε̂ in µm is its λ = 0.01 \"the same MSE\" as λ = 0);"
        " 0: no penalty.",
        "µm²/((m/min)/mm)²",
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
    Spec(
        "tuning.schedule.baseline_kp_m_min_mm",
        "numbers",
        "The fixed gains of the scheduled axis tried for the comparison run C1 (seed 001 §4: the best fixed gain,"
        " the smallest contour-error MSE, among the stable gains whose actual motion keeps every axis within its"
        " V, A, J limits; the paper tries steps of 0.1); C2 starts from that gain. Absent: C1 is the drive's"
        " kp_m_min_mm.",
        unit="(m/min)/mm",
        default=None,
        lo=0,
        hi=100,
        lo_open=True,
        default_doc="the drive's kp_m_min_mm",
    ),
    _c(
        "tuning.schedule.kinematics",
        "How the axis's V, A, J limits restrict ΔK (eqs. 8-10): predicted (the next displacement the model"
        " predicts for the candidate), eq10 (the paper's bound with the velocity loop taken as 1: eq. 8's stored"
        " displacements are the commanded ones, its division by E_Z guarded) or none.",
        ("predicted", "eq10", "none"),
        default="predicted",
    ),
)

#: Most candidates ``tuning.schedule.dk_candidates`` may list.
MAX_DK_CANDIDATES = 101

TOP_SECTIONS: tuple[str, ...] = tuple(s.path for s in SPECS if not s.parent)
SELECTORS: frozenset[str] = frozenset(s.when[0] for s in SPECS if s.when)


def spec_of(path: str, when_value: str | None = None) -> Spec:
    for s in SPECS:
        if s.path == path and (when_value is None or (s.when is not None and s.when[1] == when_value)):
            return s
    raise KeyError(path)


def default_of(path: str, when_value: str | None = None) -> Any:
    """The schema default of ``path`` (for the dataclass defaults below)."""
    d = spec_of(path, when_value).default
    if d is REQUIRED:  # pragma: no cover - programming error
        raise ValueError(f"{path} has no default")
    return d



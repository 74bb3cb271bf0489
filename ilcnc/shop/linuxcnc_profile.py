"""A machine profile written from a LinuxCNC configuration (``ilcnc linuxcnc profile INI``).

The INI gives the units (``[TRAJ] LINEAR_UNITS``), the axes and their limits (``[AXIS_L]``, the joints that
carry them, ``[TRAJ] MAX_LINEAR_*``), the servo period (``[EMCMOT] SERVO_PERIOD``) and the path control the
control starts in (``[RS274NGC] RS274NGC_STARTUP_CODE``); the HAL files it loads say what drives each joint
(a ``pid`` loop and its gains, a step generator, or the command looped back as in LinuxCNC's simulations).
Every value written carries a YAML comment naming its INI key or HAL line. What a configuration cannot say
(the velocity loop of a servo amplifier, a jerk limit LinuxCNC 2.9 does not have) is written as ilcnc's
documented default with a comment saying so and what to measure (``ilcnc identify``).

The planner is ``planner.profile: linuxcnc`` (:mod:`ilcnc.vcnc.plan_tp`, LinuxCNC 2.9's trajectory planner),
as in ``configs/linuxcnc-sim.yaml``; ``[TRAJ] ARC_BLEND_*`` settings other than those it models are named in
the notes.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ilcnc.errors import InputError, UsageError
from ilcnc.fileio import write_atomic
from ilcnc.outcomes import DriveSource
from ilcnc.profile.schema import DRIVE_KEY, default_of, spec_of
from ilcnc.shop.linuxcnc_config import IniFile, IniValue, read_ini_file
from ilcnc.shop.linuxcnc_hal import HalConfig, read_hal
from ilcnc.units import AXIS_NAMES, MM_PER_INCH
from ilcnc.vcnc.plan_tp import GAP_CYCLES, LOOKAHEAD_SEGMENTS

__all__ = ["LINEAR_UNITS", "NO_JERK_M_S3", "RESOLUTION_MM", "AxisFromIni", "IniProfile", "joints_of_axes",
           "profile_from_ini", "startup_path_control", "write_ini_profile"]

#: ``[TRAJ] LINEAR_UNITS`` names LinuxCNC accepts, and the profile unit each means.
LINEAR_UNITS: dict[str, str] = {"mm": "mm", "metric": "mm", "in": "inch", "inch": "inch", "imperial": "inch"}
#: trivkins' joint order when its ``coordinates=`` is not given.
_TRIVKINS_ORDER = "XYZABCUVW"
#: LinuxCNC 2.9's ``[TRAJ] ARC_BLEND_*`` defaults, and what ilcnc's planner model assumes of each.
_ARC_BLEND = {"ARC_BLEND_ENABLE": 1.0, "ARC_BLEND_FALLBACK_ENABLE": 0.0,
              "ARC_BLEND_OPTIMIZATION_DEPTH": float(LOOKAHEAD_SEGMENTS), "ARC_BLEND_GAP_CYCLES": float(GAP_CYCLES)}
#: A jerk limit for the profile: LinuxCNC 2.9 plans without one (``planner.profile: linuxcnc`` ignores it).
NO_JERK_M_S3 = 10000.0
#: Corrections are written to 0.1 µm: LinuxCNC reads any number of decimals (as configs/linuxcnc-sim.yaml).
RESOLUTION_MM = 0.0001
#: Time constant standing for "reaches the command within the period" (a step generator, a loop-back).
_INSTANT_S = 1e-6
#: Placeholder position-loop time constant where the HAL shows no drive ilcnc recognises (Kv = 33 1/s).
_UNKNOWN_T_S = 0.03
_MEASURE = "measure it: ilcnc identify (docs/linuxcnc.md 3.1)"
_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass(frozen=True, kw_only=True)
class AxisFromIni:
    """One axis as the configuration gives it (machine units converted to mm)."""

    name: str
    joints: tuple[int, ...]
    max_velocity_mm_s: float
    max_acceleration_mm_s2: float
    travel_mm: tuple[float, float] | None
    drive: DriveSource
    drive_yaml: tuple[tuple[str, str, str], ...]  # (key, value, comment)

    def to_json(self) -> dict[str, Any]:
        return {"joints": list(self.joints), "max_velocity_mm_min": self.max_velocity_mm_s * 60.0,
                "max_acceleration_m_s2": self.max_acceleration_mm_s2 / 1000.0,
                "travel_mm": list(self.travel_mm) if self.travel_mm else None, "drive": str(self.drive),
                "drive_keys": {k: v for k, v, _c in self.drive_yaml}}


@dataclass(frozen=True, kw_only=True)
class IniProfile:
    """The profile text written from an INI, and what went into it.

    Attributes
    ----------
    text : str
        The profile YAML (loads with :func:`ilcnc.profile.load.load_profile`).
    defaults : list of str
        Profile keys written as ilcnc defaults, not from the configuration (each line says what to measure).
    notes : list of str
        What the reader passed over or could not model (a Tcl HAL file, an ARC_BLEND setting, a clipped value).
    """

    ini: Path
    machine: str
    units: str
    servo_period_s: float
    axes: tuple[AxisFromIni, ...]
    path_control: str
    corner_tolerance_mm: float
    hal_files: tuple[Path, ...]
    text: str
    defaults: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {"ini": str(self.ini), "machine": self.machine, "units": self.units,
                "servo_period_s": self.servo_period_s, "path_control": self.path_control,
                "corner_tolerance_mm": self.corner_tolerance_mm, "hal_files": [str(p) for p in self.hal_files],
                "axes": {a.name: a.to_json() for a in self.axes}, "defaults": self.defaults, "notes": self.notes}


def _g(v: float) -> str:
    """A number for the YAML: up to 10 significant digits, integers without a dot (``1.0e-06``: YAML 1.1 reads
    ``1e-06`` as a string)."""
    s = f"{v:.10g}"
    if "e" in s and "." not in s.split("e")[0]:
        s = s.replace("e", ".0e", 1)
    return s


def _units(ini: IniFile) -> tuple[str, float]:
    """The machine's length unit for the profile, and mm per machine unit."""
    iv = ini.get("TRAJ", "LINEAR_UNITS")
    if iv is None:
        raise ini.missing("TRAJ", "LINEAR_UNITS", "the machine's length unit (mm or inch) is needed")
    name = iv.value.strip().lower()
    if name in LINEAR_UNITS:
        unit = LINEAR_UNITS[name]
        return unit, (MM_PER_INCH if unit == "inch" else 1.0)
    try:
        per_mm = float(name)  # LinuxCNC also takes a number: machine units per mm
    except ValueError:
        per_mm = math.nan
    for unit, mm in (("mm", 1.0), ("inch", MM_PER_INCH)):
        if math.isfinite(per_mm) and abs(per_mm * mm - 1.0) < 1e-6:
            return unit, mm
    raise InputError(iv.file, iv.line, f"[TRAJ] LINEAR_UNITS {iv.value!r}: ilcnc knows mm and inch machines"
                                       f" ({', '.join(LINEAR_UNITS)}, or 1 / 0.03937 units per mm)")


def joints_of_axes(ini: IniFile) -> tuple[dict[str, tuple[int, ...]], str]:
    """The joints that carry X, Y and Z, from trivkins' ``coordinates=`` (or ``[TRAJ] COORDINATES``).

    Returns the mapping (lower-case axis name to joint numbers; only axes present) and the kinematics
    module's name. Other kinematics map joints to axes in their own way: the axes come from
    ``[TRAJ] COORDINATES`` with no joints.
    """
    kins = ini.get("KINS", "KINEMATICS")
    words = kins.value.split() if kins else []
    module = words[0] if words else "trivkins"
    coords = next((w.split("=", 1)[1] for w in words[1:] if w.lower().startswith("coordinates=")), None)
    traj = ini.get("TRAJ", "COORDINATES")
    # trivkins without coordinates=: joint n is the n-th letter of XYZABCUVW
    order = (coords or _TRIVKINS_ORDER).replace(" ", "").upper()
    present = (coords or (traj.value if traj else "")).replace(" ", "").upper()
    out: dict[str, tuple[int, ...]] = {}
    for name in AXIS_NAMES:
        if name.upper() not in present and not (not present and ini.has_section(f"AXIS_{name.upper()}")):
            continue
        out[name] = tuple(i for i, c in enumerate(order) if c == name.upper()) if module == "trivkins" else ()
    return out, module


def _smallest(cands: list[tuple[float, IniValue]]) -> tuple[float, IniValue]:
    return min(cands, key=lambda c: c[0])


def _limit(ini: IniFile, axis: str, joints: tuple[int, ...], key: str,
           traj_keys: tuple[str, ...]) -> tuple[float, IniValue, str]:
    """The smallest of ``[AXIS_L] key``, the joints' and ``[TRAJ]``'s, with a comment naming them."""
    sec = f"AXIS_{axis.upper()}"
    cands: list[tuple[float, IniValue]] = []
    for s, k in [(sec, key), *((f"JOINT_{j}", key) for j in joints), *(("TRAJ", t) for t in traj_keys)]:
        iv = ini.get(s, k)
        if iv is not None:
            v = iv.number()
            if v <= 0:
                raise InputError(iv.file, iv.line, f"{iv.where} {iv.value}: must be > 0")
            cands.append((v, iv))
    if not any(iv.section in (sec, *(f"JOINT_{j}" for j in joints)) for _v, iv in cands):
        raise ini.missing(sec, key, f"the {axis.upper()} axis has no {key} (nor its joints)")
    v, iv = _smallest(cands)
    others = [c.where for _x, c in cands if c is not iv]
    tail = f"; the smallest of it and {', '.join(others)}" if others else ""
    return v, iv, tail


def _travel(ini: IniFile, axis: str, mm: float) -> tuple[tuple[float, float] | None, str]:
    sec = f"AXIS_{axis.upper()}"
    lo, hi = ini.get(sec, "MIN_LIMIT"), ini.get(sec, "MAX_LIMIT")
    if lo is None or hi is None:
        return None, ""
    a, b = lo.number() * mm, hi.number() * mm
    if not a < b:
        raise InputError(hi.file, hi.line, f"[{sec}] MAX_LIMIT {hi.value} is not above MIN_LIMIT {lo.value}")
    return (a, b), f"[{sec}] MIN_LIMIT = {lo.value}, MAX_LIMIT = {hi.value}"


def _gain(hal: HalConfig, base: str, name: str, default: float) -> tuple[float, str]:
    s = hal.settings.get(f"{base}.{name}")
    if s is None:
        return default, f"{base}.{name} not set: pid's default {_g(default)}"
    return s.number(), s.source


def _clip(path: str, model: str | None, v: float, notes: list[str], what: str) -> float:
    """``v`` within the schema's range of ``path`` (clipping is noted: a profile must load)."""
    spec = spec_of(path, model)
    lo, hi = spec.lo, spec.hi
    out = v
    if lo is not None and (v < lo or (spec.lo_open and v <= lo)):
        out = lo if not spec.lo_open else lo + abs(lo or 1.0) * 1e-6
    if hi is not None and v > hi:
        out = hi
    if out != v:
        notes.append(f"{what} = {_g(v)} is outside {path}'s range ({spec.range_text()}): written as {_g(out)}")
    return out


def _drive(hal: HalConfig, axis: str, joints: tuple[int, ...], period_s: float,
           notes: list[str], defaults: list[str]) -> tuple[DriveSource, tuple[tuple[str, str, str], ...]]:
    """The drive model of an axis from what its first joint's ``motor-pos-cmd`` is wired to."""
    key = f"axes.{axis}.drive"
    linked = hal.linked(f"joint.{joints[0]}.motor-pos-cmd") if joints else []
    src = f"joint.{joints[0]}.motor-pos-cmd" if joints else ""
    pid = next((p[: -len(".command")] for p in linked if p.endswith(".command")
                and (p.startswith("pid.") or f"{p[: -len('.command')]}.Pgain" in hal.settings)), None)
    step = next((p for p in linked if re.search(r"stepgen\.\d+\.position-cmd$", p)), None)
    kind = DriveSource.UNKNOWN
    if pid is not None:
        kind = DriveSource.SERVO_PID
    elif step is not None:
        kind = DriveSource.STEPGEN
    elif f"joint.{joints[0]}.motor-pos-fb" in linked if joints else False:
        kind = DriveSource.LOOPBACK
    if len(joints) > 1:
        notes.append(f"axis {axis.upper()} is carried by joints {', '.join(map(str, joints))}: the drive is"
                     f" joint {joints[0]}'s")
    if kind is DriveSource.SERVO_PID:
        p, p_src = _gain(hal, pid, "Pgain", 1.0)
        ff1, ff1_src = _gain(hal, pid, "FF1", 0.0)
        if p > 0:
            model = "p_ff_friction"
            kp = _clip(f"{DRIVE_KEY}.kp_m_min_mm", model, p * 0.06, notes, f"{pid}.Pgain x 0.06")
            kff = _clip(f"{DRIVE_KEY}.kff", model, ff1, notes, f"{pid}.FF1")
            bw = float(default_of(f"{DRIVE_KEY}.velocity_bandwidth_hz", model))
            defaults.append(f"{key}.velocity_bandwidth_hz")
            for g in ("Igain", "Dgain", "FF2"):
                gv, gs = _gain(hal, pid, g, 0.0)
                if gv != 0:
                    notes.append(f"axis {axis.upper()}: {gs}: the profile's P position loop leaves it out")
            return kind, (
                ("model", model, f"{src} -> {pid}.command: a PID position loop in HAL, its output taken as"
                                 " the velocity command"),
                ("kp_m_min_mm", _g(kp), f"{p_src}; Pgain {_g(p)} 1/s x 0.06"),
                ("kff", _g(kff), ff1_src),
                ("velocity_bandwidth_hz", _g(bw), f"not from the INI: the amplifier's velocity loop; {_MEASURE}"),
            )
        notes.append(f"axis {axis.upper()}: {p_src}: Pgain {_g(p)} is no position loop: drive left as a default")
        kind = DriveSource.UNKNOWN
    if kind is DriveSource.STEPGEN:
        return kind, (
            ("model", "first_order_delay", f"{src} -> {step}: a step generator in position mode"),
            ("gain", "1", "it steps to the commanded position"),
            ("time_constant_s", _g(_INSTANT_S), "within one servo period: no lag of its own"),
            ("delay_s", _g(period_s), "one servo period ([EMCMOT] SERVO_PERIOD): it reaches the command the"
                                      " period after; pos-fb counts steps, not the table (docs/linuxcnc.md 1)"),
        )
    if kind is DriveSource.LOOPBACK:
        return kind, (
            ("model", "first_order_delay", f"{src} -> joint.{joints[0]}.motor-pos-fb: the command looped back"
                                           " (a simulation)"),
            ("gain", "1", "feedback = command"),
            ("time_constant_s", _g(_INSTANT_S), "in the same servo period"),
            ("delay_s", "0", "no delay"),
        )
    defaults.append(key)
    why = f"{src} goes to {', '.join(linked)}" if linked else (f"{src} is on no HAL signal ilcnc read" if joints
                                                               else "the kinematics map no joint to this axis")
    return DriveSource.UNKNOWN, (
        ("model", "first_order_delay", f"not from the INI: {why}; {_MEASURE}"),
        ("gain", "1", "not from the INI"),
        ("time_constant_s", _g(_UNKNOWN_T_S), "not from the INI: a placeholder (a position loop of Kv = 33 1/s)"),
        ("delay_s", "0", "not from the INI"),
    )


def startup_path_control(ini: IniFile) -> tuple[str, float | None, str]:
    """The path control LinuxCNC starts in (``[RS274NGC] RS274NGC_STARTUP_CODE``).

    Returns ``planner.path_control``'s value (``g64``, ``tolerance``, ``g61``, ``g61.1``), the ``G64 P``
    tolerance in mm (None without one) and the INI line it comes from, for a comment.
    """
    mm = _units(ini)[1]
    iv = ini.get("RS274NGC", "RS274NGC_STARTUP_CODE")
    if iv is None:
        return "g64", None, "[RS274NGC] RS274NGC_STARTUP_CODE not set: LinuxCNC starts in G64 without P"
    words = [(m.group(1).upper(), float(m.group(2))) for m in _WORD.finditer(iv.value.split(";")[0])]
    g = [v for k, v in words if k == "G"]
    unit = MM_PER_INCH if 20.0 in g else (1.0 if 21.0 in g else mm)
    src = f"[RS274NGC] RS274NGC_STARTUP_CODE = {iv.value.strip()}"
    if 61.1 in g:
        return "g61.1", None, src
    if 61.0 in g:
        return "g61", None, src
    if 64.0 in g:
        p = next((v for k, v in words if k == "P"), 0.0)
        if p > 0:
            return "tolerance", p * unit, src
        return "g64", None, src
    return "g64", None, f"{src}: no G61/G64, so LinuxCNC's G64 without P"


def profile_from_ini(path: str | Path) -> IniProfile:
    """Read a LinuxCNC INI (and its HAL files) and write the profile text (see the module docstring).

    Raises
    ------
    InputError
        A malformed INI, naming the file, line and key: no ``[TRAJ] LINEAR_UNITS``, no ``[EMCMOT] SERVO_PERIOD``,
        a non-numeric or non-positive limit, no X/Y/Z axis, a ``HALFILE`` that cannot be found.
    """
    ini = read_ini_file(path)
    notes: list[str] = list(ini.notes)
    defaults: list[str] = []
    unit, mm = _units(ini)
    sp = ini.get("EMCMOT", "SERVO_PERIOD")
    if sp is None:
        raise ini.missing("EMCMOT", "SERVO_PERIOD", "the servo period (ns) is the time step of every log")
    period_ns = sp.number()
    period_s = period_ns * 1e-9
    spec = spec_of("machine.servo_period_s")
    if not (spec.lo <= period_s <= spec.hi):  # type: ignore[operator]
        raise InputError(sp.file, sp.line, f"[EMCMOT] SERVO_PERIOD {sp.value} ns is outside what ilcnc models"
                                           f" (machine.servo_period_s {spec.range_text()} s)")
    hal = read_hal(ini)
    notes += hal.notes
    joints, kins = joints_of_axes(ini)
    if not joints:
        raise InputError(ini.path, None, "the configuration has no X, Y or Z axis ([TRAJ] COORDINATES,"
                                         " [KINS] KINEMATICS coordinates=)")
    if kins != "trivkins":
        notes.append(f"kinematics {kins}: joints are not the X Y Z axes; limits are the [AXIS_L] ones, the drives"
                     " defaults to measure")
    axes: list[AxisFromIni] = []
    lines_axes: list[str] = []
    travel_lines: list[str] = []
    for name, js in joints.items():
        v, v_iv, v_tail = _limit(ini, name, js, "MAX_VELOCITY", ("MAX_LINEAR_VELOCITY", "MAX_VELOCITY"))
        a, a_iv, a_tail = _limit(ini, name, js, "MAX_ACCELERATION", ("MAX_LINEAR_ACCELERATION", "MAX_ACCELERATION"))
        travel, t_src = _travel(ini, name, mm)
        if travel is not None:
            travel_lines.append(f"  #   {name}: [{_g(travel[0])}, {_g(travel[1])}]  # {t_src}")
        kind, drive = _drive(hal, name, js, period_s, notes, defaults)
        ax = AxisFromIni(name=name, joints=js, max_velocity_mm_s=v * mm, max_acceleration_mm_s2=a * mm,
                         travel_mm=travel, drive=kind, drive_yaml=drive)
        axes.append(ax)
        vel = _clip("axes.<axis>.max_velocity_mm_min", None, v * mm * 60, notes, f"axis {name.upper()} velocity")
        acc = _clip("axes.<axis>.max_acceleration_m_s2", None, a * mm / 1000, notes, f"axis {name.upper()} acceleration")
        inch = " x 25.4" if unit == "inch" else ""
        lines_axes += [
            f"  {name}:",
            f"    max_velocity_mm_min: {_g(vel)}  # {v_iv.where} = {v_iv.value} {unit}/s{inch} x 60{v_tail}",
            f"    max_acceleration_m_s2: {_g(acc)}  # {a_iv.where} = {a_iv.value} {unit}/s^2{inch} / 1000{a_tail}",
            f"    max_jerk_m_s3: {_g(NO_JERK_M_S3)}  # not from the INI: LinuxCNC 2.9 plans without a jerk limit"
            " (planner.profile linuxcnc ignores it)",
            f"    rapid_mm_min: {_g(vel)}  # LinuxCNC rapids at the same limit",
            "    drive:",
            *(f"      {k}: {val}  # {c}" for k, val, c in drive),
        ]
    defaults += [f"axes.{a.name}.max_jerk_m_s3" for a in axes]
    mode, tol, mode_src = startup_path_control(ini)
    if tol is None:
        tol = float(default_of("planner.corner_tolerance_mm"))
        tol_c = (f"not from the INI: the P to give the program's G64 P{_g(tol)} Q0 (ilcnc linuxcnc prepare says"
                 " where)")
        defaults.append("planner.corner_tolerance_mm")
    else:
        tol = _clip("planner.corner_tolerance_mm", None, tol, notes, "the start-up G64 P")
        tol_c = mode_src
    for key, assumed in _ARC_BLEND.items():
        iv = ini.get("TRAJ", key)
        if iv is not None and iv.number() != assumed:
            notes.append(f"{iv.file}:{iv.line}: [TRAJ] {key} = {iv.value}: ilcnc's LinuxCNC planner assumes"
                         f" {_g(assumed)} (LinuxCNC's default): check the prediction with ilcnc simulate --compare")
    machine = ini.get("EMC", "MACHINE")
    mname = machine.value.strip() if machine else ini.path.stem
    text = "\n".join([
        f"# ilcnc machine profile written by `ilcnc linuxcnc profile` from {ini.path.name}",
        f"# ({ini.path}). Every value names the INI key or HAL line it comes from; a value marked",
        "# 'not from the INI' is ilcnc's default: measure it as its comment says.",
        *(f"# note: {n}" for n in notes),
        "",
        "machine:",
        f"  name: {_yaml_str(mname)}  # [EMC] MACHINE" if machine else f"  name: {_yaml_str(mname)}  # the INI's name",
        f"  units: {unit}  # [TRAJ] LINEAR_UNITS = {ini.get('TRAJ', 'LINEAR_UNITS').value}",  # type: ignore[union-attr]
        f"  servo_period_s: {_g(period_s)}  # [EMCMOT] SERVO_PERIOD = {sp.value} ns",
        f"  resolution_mm: {_g(RESOLUTION_MM)}  # not from the INI: LinuxCNC reads any number of decimals",
        *(["  # The travel, [AXIS_L] MIN_LIMIT / MAX_LIMIT, is in machine coordinates. ilcnc checks it against the",
           "  # program's coordinates: uncomment it only where the work offsets are zero.",
           "  # travel_mm:", *travel_lines] if travel_lines else []),
        "",
        "axes:",
        *lines_axes,
        "",
        "controller:",
        "  type: independent  # LinuxCNC closes one loop per joint",
        "",
        "planner:",
        "  profile: linuxcnc  # LinuxCNC 2.9's trajectory planner (ilcnc/vcnc/plan_tp.py): trapezoidal, blend arcs",
        f"  corner_tolerance_mm: {_g(tol)}  # {tol_c}",
        f"  path_control: {mode}  # {mode_src}",
        "  in_position_s: 0  # LinuxCNC starts a feed move as the rapid before it ends (no in-position wait)",
        "",
        "output:",
        "  dialect: linuxcnc",
        "",
    ])
    defaults.insert(0, "machine.resolution_mm")
    return IniProfile(ini=ini.path, machine=mname, units=unit, servo_period_s=period_s, axes=tuple(axes),
                      path_control=mode, corner_tolerance_mm=tol, hal_files=tuple(hal.files), text=text,
                      defaults=defaults, notes=notes)


def _yaml_str(s: str) -> str:
    """A YAML double-quoted string (a machine name may hold ``#`` or ``:``)."""
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def write_ini_profile(result: IniProfile, out: str | Path, *, force: bool = False) -> Path:
    """Write the profile atomically; an existing file only with ``force`` (never the INI itself)."""
    dest = Path(out)
    if dest.exists() and not force:
        raise UsageError("--out", f"{dest} exists: choose another file or replace it with --force")
    return write_atomic(dest, result.text, protect=(result.ini, *result.hal_files))

"""What a log run on a LinuxCNC machine needs, said before the run (``ilcnc linuxcnc prepare PROG``).

Three things: the path control the program runs in (``G61``/``G61.1``/``G64 P Q`` per line range; a program
without any runs in the control's start-up mode, LinuxCNC's ``G64`` without P, which rounds corners as far
as the axes allow), and what to change so corners stay within the profile's ``planner.corner_tolerance_mm``
and every G1 shows up in the log (``Q0``: LinuxCNC's naive-CAM tolerance ``Q`` defaults to ``P`` and merges
short collinear G1s into one segment); the HAL lines that record the axes with ``halsampler`` in the column
order ilcnc reads (:func:`sampler_hal`, the file docs/linuxcnc.md section 2 shows); and the commands that
record the run and learn from its log.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ilcnc.axislog.halsampler import HALSAMPLER_COLUMNS
from ilcnc.errors import InputError
from ilcnc.outcomes import PathMode
from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.program.model import MOVE_RAPID, Program
from ilcnc.program.path_control import PathSetting, path_settings
from ilcnc.shop.inspect import corner_rounding_warnings
from ilcnc.shop.linuxcnc_config import read_ini_file
from ilcnc.shop.linuxcnc_profile import joints_of_axes, startup_path_control
from ilcnc.units import AXIS_NAMES, MM_PER_INCH, length_word

__all__ = ["DEFAULT_SAMPLER_DEPTH", "PathEdit", "PathRange", "Preparation", "path_ranges", "prepare_run", "sampler_hal"]

#: Sampler FIFO depth: 100 s at 1 kHz, 6.4 MB of shared memory (docs/linuxcnc.md section 2).
DEFAULT_SAMPLER_DEPTH = 100000
_MODE_TEXT = {
    PathMode.UNSET: "no G61/G64 in the program",
    PathMode.EXACT_STOP: "G61.1: stop at every block end",
    PathMode.EXACT_PATH: "G61: stop at every corner",
    PathMode.BOUNDED: "G64 P: blend within P",
    PathMode.UNBOUNDED: "G64 without P: blend as fast as the axes allow",
}


def sampler_hal(joints: Mapping[str, int], depth: int = DEFAULT_SAMPLER_DEPTH) -> str:
    """The HAL file that records the program line and commanded and actual X Y Z each servo cycle.

    The sampler's pins follow :data:`ilcnc.axislog.halsampler.HALSAMPLER_COLUMNS` (``halsampler -t`` writes the
    sample number first), so ilcnc reads the log without ``--log-columns``. ``joints`` maps an axis name to the
    joint that carries it (``joint.N.pos-cmd``/``pos-fb``: machine coordinates without the homing offset); an
    axis not in it leaves its two pins unconnected (they read 0).
    """
    if not 1 <= depth <= 10_000_000:
        raise ValueError(f"sampler depth {depth} outside 1..10000000")
    cols = HALSAMPLER_COLUMNS[1:]  # after halsampler's sample number
    lines = ["# ilcnc-log.hal: every servo cycle, the program line and the commanded and",
             "# actual X Y Z, in the column order ilcnc reads (halsampler -t adds the sample number first)",
             f"loadrt sampler depth={depth} cfg=s{'f' * (len(cols) - 1)}",
             "addf sampler.0 servo-thread"]
    for pin, col in enumerate(cols):
        if col == "line":
            sig, src = "ilcnc-line", "motion.program-line"
        else:
            axis, what = col.split("_")
            if axis not in joints:
                lines.append(f"# sampler.0.pin.{pin} ({col}) left unconnected: the machine has no {axis.upper()}")
                continue
            kind = "cmd" if what == "ref" else "fb"
            sig, src = f"ilcnc-{axis}-{kind}", f"joint.{joints[axis]}.pos-{kind}"
        lines.append(f"net {sig:<11} {src:<19} => sampler.0.pin.{pin}")
    lines.append("setp sampler.0.enable 0")
    return "\n".join(lines) + "\n"


@dataclass(frozen=True, kw_only=True)
class PathRange:
    """Consecutive feed moves in one path control mode: their source lines and the tolerance (mm)."""

    first_line: int
    last_line: int
    moves: int
    mode: PathMode
    tolerance_mm: float | None

    def to_json(self) -> dict[str, Any]:
        return {"first_line": self.first_line, "last_line": self.last_line, "moves": self.moves,
                "mode": str(self.mode), "tolerance_mm": self.tolerance_mm}

    def text(self, units: str) -> str:
        what = _MODE_TEXT[self.mode]
        if self.mode is PathMode.BOUNDED and self.tolerance_mm is not None:
            what = f"G64 P{length_word(self.tolerance_mm, units)}: blend within {self.tolerance_mm:g} mm"
        return f"lines {self.first_line}-{self.last_line}: {self.moves} feed moves, {what}"


@dataclass(frozen=True, kw_only=True)
class Preparation:
    """What ``ilcnc linuxcnc prepare`` says (see the module docstring); ``ready``: nothing to change."""

    program: Path
    profile: Path
    ini: Path | None
    units: str
    log_units: str
    tolerance_mm: float
    startup: str
    ranges: list[PathRange]
    settings: list[PathSetting]
    edits: list[PathEdit]
    warnings: list[str]
    joints: dict[str, int]
    hal: str
    record: str
    learn: str
    notes: list[str] = field(default_factory=list)
    source: Program = field(repr=False, compare=False)  #: the program as read (prepare --out writes it edited)

    @property
    def changes(self) -> list[str]:
        """The edits as the command says them."""
        return [e.why for e in self.edits]

    @property
    def ready(self) -> bool:
        return not self.edits

    def to_json(self) -> dict[str, Any]:
        return {"program": str(self.program), "profile": str(self.profile),
                "ini": str(self.ini) if self.ini else None, "units": self.units, "log_units": self.log_units,
                "corner_tolerance_mm": self.tolerance_mm, "startup": self.startup, "ready": self.ready,
                "path_control": [r.to_json() for r in self.ranges],
                "settings": [s.to_json() for s in self.settings], "changes": self.changes,
                "edits": [e.to_json() for e in self.edits],
                "warnings": self.warnings, "joints": self.joints, "hal": self.hal, "record": self.record,
                "learn": self.learn, "notes": self.notes}


    def text(self, hal_file: Path | None = None) -> str:
        """What the command prints: the path control, the changes to make, the HAL lines and the commands."""
        out = [f"{self.program.name}: path control (start-up: {self.startup}):"]
        out += [f"  {r.text(self.units)}" for r in self.ranges]
        if self.ready:
            out.append(f"ready: every feed move stays within the corner tolerance {self.tolerance_mm:g} mm")
        else:
            out.append(f"change before the first run (corner tolerance {self.tolerance_mm:g} mm; docs/linuxcnc.md 4):")
            out += [f"  - {c}" for c in self.changes]
        out += [f"note: {n}" for n in self.notes]
        where = f"written to {hal_file}" if hal_file else "save as ilcnc-log.hal"
        out.append(f"HAL ({where}; load it after the machine's HAL files: [HAL] HALFILE = ilcnc-log.hal):")
        return "\n".join(out) + "\n" + self.hal + f"record: {self.record}\nlearn:  {self.learn}\n"


def path_ranges(program: Program) -> list[PathRange]:
    """The feed moves grouped into runs of one path control (mode and tolerance), in program order."""
    mv = program.moves
    idx = np.flatnonzero(mv.kind != MOVE_RAPID)
    out: list[PathRange] = []
    for i in idx:
        tol = float(mv.blend_tol_mm[i])
        mode = PathMode.of_tolerance(tol)
        t = tol if mode is PathMode.BOUNDED else None
        line = int(mv.line[i])
        last = out[-1] if out else None
        if last is not None and last.mode is mode and last.tolerance_mm == t:
            out[-1] = PathRange(first_line=last.first_line, last_line=max(last.last_line, line),
                                moves=last.moves + 1, mode=mode, tolerance_mm=t)
        else:
            out.append(PathRange(first_line=line, last_line=line, moves=1, mode=mode, tolerance_mm=t))
    return out


def _first_move_line(program: Program) -> int | None:
    mv = program.moves
    return int(mv.line[0]) if len(mv.line) else None


def prepare_run(program_path: str | Path, profile_path: str | Path, *, ini_path: str | Path | None = None,
                depth: int = DEFAULT_SAMPLER_DEPTH, run_path: str | Path | None = None) -> Preparation:
    """Say what a log run of ``program_path`` on a LinuxCNC machine needs (see the module docstring).

    ``run_path``: the program that will run instead, ``program_path`` with the edits made (``prepare --out``):
    the command that learns from the log names it.
    """
    prof = load_profile(profile_path)
    program = read_program(program_path, default_units=prof.machine.units)
    if program.dialect not in ("linuxcnc", "grbl", "fanuc"):
        raise InputError(program.path, None, f"a {program.dialect} program: LinuxCNC runs G-code (RS-274NGC)")
    tol = float(prof.planner.corner_tolerance_mm)
    notes: list[str] = []
    default_mode = prof.planner.path_control
    log_units = prof.machine.units
    if ini_path is not None:
        ini = read_ini_file(ini_path)
        js, kins = joints_of_axes(ini)
        joints = {a: j[0] for a, j in js.items() if j}
        if kins != "trivkins":
            notes.append(f"kinematics {kins}: joint positions are not X Y Z; connect the joints that carry them")
        mode, p_mm, startup = startup_path_control(ini)
        default_mode = mode
        sp = ini.get("EMCMOT", "SERVO_PERIOD")
        if sp is not None and abs(sp.number() * 1e-9 - prof.machine.servo_period_s) > 1e-12:
            notes.append(f"{sp.file}:{sp.line}: [EMCMOT] SERVO_PERIOD = {sp.value} ns but the profile's"
                         f" machine.servo_period_s is {prof.machine.servo_period_s:g} s: the log's time step is"
                         " the INI's: set the profile to it")
        lu = ini.get("TRAJ", "LINEAR_UNITS")
        if lu is not None and lu.value.strip().lower() in ("in", "inch", "imperial"):
            log_units = "inch"
        elif lu is not None:
            log_units = "mm"
        if mode == "tolerance" and p_mm is not None:
            startup += f" (blends within {p_mm:g} mm)"
    else:
        joints = {a: i for i, a in enumerate(AXIS_NAMES)}
        startup = (f"the profile's planner.path_control {default_mode}"
                   + (" (LinuxCNC's start-up G64 without P)" if default_mode == "g64" else ""))
        notes.append("no --ini: joints 0 1 2 taken as X Y Z (trivkins), the log's units as the profile's")
    ranges = path_ranges(program)
    settings = path_settings(program)
    warnings = corner_rounding_warnings(program, tol, default_mode)
    edits = _changes(program, ranges, settings, tol, default_mode)
    units = program.units
    runs = Path(run_path) if run_path is not None else program.path
    stem = runs.with_suffix("")
    suffix = runs.suffix or ".ngc"
    hal = sampler_hal(joints, depth)
    record = "./ilcnc-record.sh run0.log    # docs/linuxcnc.md 5.1: halsampler -t run0.log while sampler.0.enable is 1"
    learn = (f"ilcnc learn {run_path if run_path is not None else program_path} --profile {profile_path} --log run0.log"
             f"{' --log-units inch' if log_units == 'inch' else ''} --state {stem}.state --out {stem}.ilc1{suffix}")
    return Preparation(program=program.path, profile=Path(profile_path), ini=Path(ini_path) if ini_path else None,
                       units=units, log_units=log_units, tolerance_mm=tol, startup=startup, ranges=ranges,
                       settings=settings, edits=edits, warnings=warnings, joints=joints, hal=hal,
                       record=record, learn=learn, notes=notes, source=program)


@dataclass(frozen=True, kw_only=True)
class PathEdit:
    """One edit the program needs before its first run (:func:`ilcnc.shop.path_control_edit.apply_path_edits`).

    ``insert``: a new line of ``words`` before source line ``line``; else the path control words (``G64`` and
    its P and Q) of line ``line`` become ``words``. ``why`` is the change as the command says it.
    """

    line: int
    insert: bool
    words: str
    why: str

    def to_json(self) -> dict[str, Any]:
        return {"line": self.line, "action": "insert" if self.insert else "replace", "words": self.words,
                "why": self.why}


def _changes(program: Program, ranges: list[PathRange], settings: list[PathSetting], tol_mm: float,
             default_mode: str) -> list[PathEdit]:
    """The edits the program needs before its first run (empty: run it as it is)."""
    units = program.units
    word = f"G64 P{length_word(tol_mm, units)} Q0"
    out: list[PathEdit] = []
    unset = [r for r in ranges if r.mode is PathMode.UNSET]
    if unset and default_mode in ("g64", "tolerance"):
        first = _first_move_line(program)
        where = f"before line {first} (the first move)" if first else "at the top"
        out.append(PathEdit(line=first or 1, insert=True, words=word,
                            why=f"{sum(r.moves for r in unset)} feed moves (first on line {unset[0].first_line}) run"
                                f" in the control's start-up mode: insert a line `{word}` {where}"))
    for s in settings:
        if s.mode is PathMode.UNBOUNDED:
            out.append(PathEdit(line=s.line, insert=False, words=word,
                                why=f"line {s.line}: G64 without P rounds corners as far as the axes allow: make it"
                                    f" `{word}`"))
        elif s.mode is PathMode.BOUNDED and s.p is not None:
            p_mm = s.p * (MM_PER_INCH if units == "inch" else 1.0)
            if p_mm > tol_mm * (1 + 1e-9):
                out.append(PathEdit(line=s.line, insert=False, words=word,
                                    why=f"line {s.line}: G64 P{s.p:g} rounds corners by up to {p_mm:g} mm, beyond the"
                                        f" profile's corner tolerance {tol_mm:g} mm: make it `{word}` (or raise"
                                        " planner.corner_tolerance_mm)"))
            elif s.q is None or s.q > 0:
                q = "without Q" if s.q is None else f"Q{s.q:g}"
                out.append(PathEdit(line=s.line, insert=False, words=f"G64 P{s.p:g} Q0",
                                    why=f"line {s.line}: G64 P{s.p:g} {q}: LinuxCNC merges short collinear G1s into"
                                        " one segment (Q defaults to P), which the log then cannot tell apart: add"
                                        " Q0"))
    return out

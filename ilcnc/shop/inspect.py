"""``ilcnc inspect``: what a program is and does, at a glance."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ilcnc.fileio import write_atomic
from ilcnc.program import Program, read_program
from ilcnc.program.geometry import extents_mm, feed_time_s, move_lengths_mm
from ilcnc.program.model import MOVE_RAPID, program_frame_mm

__all__ = ["InspectReport", "command_table_csv", "corner_rounding_warnings", "inspect_program", "print_report"]

DEFAULT_RAPID_MM_MIN = 10000.0


@dataclass(slots=True)
class InspectReport:
    """Summary of one program (all lengths in mm, times in s)."""

    program: str
    dialect: str
    units: str
    lines: int
    g01_commands: int
    moves: int
    extents_mm: list[list[float]]
    path_length_mm: float
    feed_length_mm: float
    cycle_time_s: float
    feed_only_time_s: float
    cycle_time_kind: str
    warnings: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` object of DESIGN.md."""
        return {
            "program": self.program,
            "dialect": self.dialect,
            "units": self.units,
            "lines": self.lines,
            "g01_commands": self.g01_commands,
            "moves": self.moves,
            "extents_mm": {"min": self.extents_mm[0], "max": self.extents_mm[1]},
            "path_length_mm": self.path_length_mm,
            "feed_length_mm": self.feed_length_mm,
            "cycle_time_s": self.cycle_time_s,
            "cycle_time_kind": self.cycle_time_kind,
            "feed_only_time_s": self.feed_only_time_s,
            "warnings": self.warnings,
        }


def command_table_csv(program: Program) -> str:
    """The command table ``k,line,x,y,z,f`` (program frame, mm, mm/min)."""
    idx = program.command_moves
    mv = program.moves
    pts = program_frame_mm(mv, mv.end_mm[idx], idx)
    feed = mv.feed_mm_min[idx]
    lines = mv.line[idx]
    out = ["k,line,x,y,z,f"]
    out.extend(
        f"{k},{int(lines[k])},{pts[k, 0]:.6f},{pts[k, 1]:.6f},{pts[k, 2]:.6f},{feed[k]:.4f}"
        for k in range(len(idx))
    )
    return "\n".join(out) + "\n"


def corner_rounding_warnings(program: Program, tolerance_mm: float, default_mode: str) -> list[str]:
    """Warnings for feed moves whose path control lets the control round corners beyond ``tolerance_mm``.

    A program's ``G64`` without P (or ``P0``) blends as fast as the axes allow (LinuxCNC keeps the blend within a
    quarter of the shorter move, a profile's tolerance does not apply); ``G64 P`` / cycle 32 T larger than the
    tolerance rounds by up to that much. Moves without a program setting take the profile's
    ``planner.path_control``: ``g64`` there is the unbounded case (LinuxCNC's start-up mode).
    """
    mv = program.moves
    feed = mv.kind != MOVE_RAPID
    tol = mv.blend_tol_mm
    unset = feed & np.isnan(tol)
    unbounded = feed & np.isinf(tol)
    if default_mode == "g64":
        unbounded = unbounded | unset
    loose = feed & np.isfinite(tol) & (tol > tolerance_mm * (1 + 1e-9))
    out = []
    if unbounded.any():
        i = int(np.flatnonzero(unbounded)[0])
        first = int(mv.line[i])
        how = "in G64 without P" if np.isinf(tol[i]) else ("without a path control setting, in the profile's"
                                                           " planner.path_control g64")
        out.append(f"{int(unbounded.sum())} feed moves run {how} (first on line {first}): the control may round"
                   f" their corners as far as the axes allow (LinuxCNC: up to a quarter of the shorter move), beyond"
                   f" the profile's corner tolerance {tolerance_mm:g} mm; G64 P{tolerance_mm:g} bounds it")
    if loose.any():
        first = int(mv.line[np.flatnonzero(loose)[0]])
        worst = float(tol[loose].max())
        out.append(f"{int(loose.sum())} feed moves blend within up to {worst:g} mm (first on line {first}): corners"
                   f" may be rounded more than the profile's corner tolerance {tolerance_mm:g} mm")
    return out


def inspect_program(path: Path, *, profile_path: Path | None = None, moves_out: Path | None = None) -> InspectReport:
    """Read a program and summarise it; optionally write its command table."""
    rapid = DEFAULT_RAPID_MM_MIN
    default_units = "mm"
    prof = None
    if profile_path is not None:
        from ilcnc.profile.load import load_profile

        prof = load_profile(profile_path)
        default_units = prof.machine.units
        rapids = [ax.rapid_mm_min or ax.max_velocity_mm_min for ax in prof.axes.values()]
        rapid = float(min(rapids)) if rapids else rapid
    program = read_program(path, default_units=default_units)
    program.require_complete()
    mv = program.moves
    length = move_lengths_mm(mv)
    ext = extents_mm(mv)
    if moves_out is not None:
        write_atomic(moves_out, command_table_csv(program), protect=(path,))
    warnings = list(program.warnings)
    if prof is not None:
        warnings += corner_rounding_warnings(program, prof.planner.corner_tolerance_mm, prof.planner.path_control)
        from ilcnc.vcnc.plan import planned_duration_s

        cycle = planned_duration_s(program, prof)
        kind = f"planned ({prof.planner.profile}, axis limits of {prof.machine.name})"
    else:
        cycle = feed_time_s(mv, rapid) + program.trailing_dwell_s
        kind = "feed-only (no acceleration; give --profile for the planned time)"
    return InspectReport(
        program=str(path),
        dialect=program.dialect,
        units=program.units,
        lines=program.n_lines,
        g01_commands=program.n_commands,
        moves=len(mv),
        extents_mm=ext.tolist(),
        path_length_mm=float(length.sum()),
        feed_length_mm=float(length[mv.kind != MOVE_RAPID].sum()),
        cycle_time_s=cycle,
        feed_only_time_s=feed_time_s(mv, rapid) + program.trailing_dwell_s,
        cycle_time_kind=kind,
        warnings=warnings,
    )


def print_report(report: InspectReport, console: Any) -> None:
    """Print the report as a rich table."""
    from rich.markup import escape
    from rich.table import Table

    t = Table(title=report.program, show_header=False)
    t.add_column("what")
    t.add_column("value")
    ext = np.asarray(report.extents_mm)
    t.add_row("dialect", report.dialect)
    t.add_row("units", report.units)
    t.add_row("lines", f"{report.lines}")
    t.add_row("G01 commands", f"{report.g01_commands}")
    t.add_row("moves", f"{report.moves}")
    for a, name in enumerate("XYZ"):
        t.add_row(f"{name} extent (mm)", f"{ext[0, a]:.3f} .. {ext[1, a]:.3f}")
    t.add_row("path length (mm)", f"{report.path_length_mm:.3f}")
    t.add_row("cycle time (s)", f"{report.cycle_time_s:.1f}  ({escape(report.cycle_time_kind)})")
    if report.cycle_time_s != report.feed_only_time_s:
        t.add_row("feed-only estimate (s)", f"{report.feed_only_time_s:.1f}")
    console.print(t)
    for w in report.warnings:
        console.print(f"[yellow]warning:[/yellow] {escape(w)}")

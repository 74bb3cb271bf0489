"""``ilcnc export``: write a program, corrected or converted, never over its input."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes, write_atomic
from ilcnc.program import GCODE_SUFFIXES, HEIDENHAIN_SUFFIXES, Program, read_program
from ilcnc.program.model import FLAG_CUTTER_COMP, FLAG_HOME, FLAG_MACHINE, MOVE_ARC_CW, MOVE_RAPID, STYLE_LITERAL
from ilcnc.program.rewrite import apply_corrections
from ilcnc.shop.corrections import read_corrections

__all__ = ["ExportResult", "export_program", "output_family"]


@dataclass(frozen=True, slots=True)
class ExportResult:
    """What ``export`` wrote."""

    path: Path
    mode: str  # "copy", "rewrite" or "convert"
    changed_commands: int
    edits: int
    note: str = ""  # e.g. a copy of a program the interpreter does not run in full


def output_family(path: Path) -> str:
    """``gcode`` or ``heidenhain`` from the output suffix."""
    suffix = path.suffix.lower()
    if suffix in HEIDENHAIN_SUFFIXES:
        return "heidenhain"
    if suffix in GCODE_SUFFIXES:
        return "gcode"
    raise InputError(path, None, f"unknown output suffix {suffix!r}; use .nc, .ngc, .tap, .gcode or .h")


def _min_decimals(units: str, profile_path: Path | None, override: int | None) -> int:
    if override is not None:
        return override
    if profile_path is not None:
        from ilcnc.profile.load import load_profile

        return int(load_profile(profile_path).min_decimals(units))
    return 4 if units == "inch" else 3


def export_program(
    src: Path,
    out: Path,
    *,
    corrections_path: Path | None = None,
    profile_path: Path | None = None,
    min_decimals: int | None = None,
    data: bytes | None = None,
) -> ExportResult:
    """Write ``src`` to ``out`` in the dialect of ``out``'s suffix, applying corrections.

    ``data``: the program's bytes when they are not read from ``src`` (an iteration kept in a state).

    Raises
    ------
    InputError
        Bad program, bad corrections, unknown suffix, or ``out`` is the input.
    """
    family = output_family(out)
    default_units = "mm"
    if profile_path is not None:
        from ilcnc.profile.load import load_profile

        default_units = load_profile(profile_path).machine.units
    if data is None:
        data = read_bytes(src)
    program = read_program(src, default_units=default_units, data=data)
    same = (program.dialect == "heidenhain") == (family == "heidenhain")
    protect = (src,) + ((corrections_path,) if corrections_path else ())
    corr = None
    if corrections_path is not None:
        program.require_complete()
        corr = read_corrections(corrections_path, program.n_commands)
    if same:
        if corr is None:
            write_atomic(out, program.data, protect=protect)
            note = ""
            if program.unsupported is not None:  # a copy needs no interpretation; say that it had none
                line, problem = program.unsupported
                note = (f"{src}:{line}: the interpreter stops here ({problem}): copied byte for byte without"
                        " interpreting the rest")
            return ExportResult(out, "copy", 0, 0, note)
        dec = _min_decimals(program.units, profile_path, min_decimals)
        text, edits = apply_corrections(program, corr, min_decimals=dec)
        write_atomic(out, text.encode("latin-1"), protect=protect)
        return ExportResult(out, "rewrite", int(np.count_nonzero(np.any(corr != 0, axis=1))), len(edits))
    program.require_complete()
    _refuse_unconvertible(program, family)
    moves = program.moves
    if corr is not None and np.any(corr):
        moves = _corrected_moves(program, corr)
    dec = _conversion_decimals(program, _min_decimals(program.units, profile_path, min_decimals))
    from ilcnc.program.carry import carried_events

    events = carried_events(program)  # tool, spindle, coolant, dwells, stops, comments; or refused with the line
    if family == "heidenhain":
        from ilcnc.program.heidenhain_write import write_klartext

        text = write_klartext(moves, name=_pgm_name(out), units=program.units, decimals=dec, events=events)
    else:
        from ilcnc.program.gcode_write import write_gcode

        try:
            text = write_gcode(moves, units=program.units, decimals=dec, name=program.path.name, events=events)
        except ValueError as exc:  # a construct the target cannot run: nothing is written
            raise InputError(src, None, f"cannot be converted to {out.suffix}: {exc}") from None
    write_atomic(out, text.encode("latin-1", errors="replace"), protect=protect)
    changed = 0 if corr is None else int(np.count_nonzero(np.any(corr != 0, axis=1)))
    return ExportResult(out, "convert", changed, 0)


def _conversion_decimals(program: Program, least: int) -> int:
    """Decimals of a converted program: the most its source wrote in a coordinate (a learned correction is not
    rounded away), at least ``least`` and at most 6; more where fewer would round an arc's end onto its start
    (a full circle the source does not cut)."""
    program.resolve_spans()
    mv = program.moves
    lit = (mv.word_start >= 0) & ((mv.word_style & STYLE_LITERAL) != 0)
    text = program.text
    most = 0
    for a, b in zip(mv.word_start[lit].tolist(), mv.word_end[lit].tolist(), strict=True):
        dot = max(text.rfind(".", a, b), text.rfind(",", a, b))
        if dot >= 0:
            most = max(most, b - dot - 1)
    dec = min(6, max(int(least), most))
    arcs = np.flatnonzero(mv.kind >= MOVE_ARC_CW)
    if arcs.size == 0:
        return dec
    delta = np.abs(mv.end_mm[arcs] - mv.start_mm[arcs]) / mv.unit_mm[arcs, None]
    full = np.all(delta <= 1e-9, axis=1)  # the source's own full circles
    for d in range(dec, 7):
        collapsed = ~full & np.all(delta < 0.5 * 10.0 ** -d, axis=1)
        if not collapsed.any():
            return d
    i = int(arcs[np.flatnonzero(collapsed)[0]])
    raise InputError(program.path, int(mv.line[i]), "an arc whose end lies within 0.5e-6 of its start would be"
                     " written as a full circle: not converted")


def _refuse_unconvertible(program: Program, family: str) -> None:
    """Refuse, with the line, a move the other dialect would run somewhere else (issue 20): cutter radius
    compensation (the writers write the programmed contour), Klartext ``M92``
    (a position the machine builder defines; ``G53`` is machine zero), G-code ``G28``/``G30`` (a home position
    stored in the machine, which Klartext cannot name)."""
    mv = program.moves
    unknown = np.flatnonzero((mv.kind != MOVE_RAPID) & ~(mv.feed_mm_min > 0) & ~np.isfinite(mv.block_time_s))
    if unknown.size:
        raise InputError(program.path, int(mv.line[unknown[0]]), "a feed move without a known feed (no F before it):"
                         " the other dialect would refuse it or run it at another speed: not converted")
    if family == "heidenhain" and len(mv):  # the TNC takes at most 5 digits before the point
        pts = np.concatenate([mv.end_mm - mv.offset_mm, np.nan_to_num(mv.center_mm - mv.offset_mm)])
        big = np.flatnonzero(np.any(np.abs(pts / np.concatenate([mv.unit_mm, mv.unit_mm])[:, None]) > 99999.9999,
                                    axis=1))
        if big.size:
            raise InputError(program.path, int(mv.line[big[0] % len(mv)]), "a coordinate beyond 99999.9999, more than"
                             " a Klartext program holds: not converted")
    turned = np.flatnonzero(mv.rotation_deg != 0.0)
    if turned.size:  # the writers write offsets as shifts (G52, cycle 7), never a rotation
        raise InputError(program.path, int(mv.line[turned[0]]), "a move in a rotated work system (G10 L2 R): the"
                         " writers do not write a rotation: not converted")
    comp = np.flatnonzero(mv.flags & FLAG_CUTTER_COMP)
    if comp.size:
        raise InputError(program.path, int(mv.line[comp[0]]), "cutter radius compensation (G41/G42, RL/RR) is not"
                         " converted: the contour would be cut by the tool centre")
    if family == "gcode":
        for i in np.flatnonzero(mv.flags & FLAG_MACHINE):
            line = int(mv.line[i])
            body = program.line_text(line)[1].split(";", 1)[0].upper()
            if re.search(r"\bM92\b", body):
                raise InputError(program.path, line, "M92 positions are relative to a datum the machine builder"
                                 " sets; G-code has no equivalent (G53 is machine zero): not converted")
    else:
        home = np.flatnonzero(mv.flags & FLAG_HOME)
        if home.size:
            raise InputError(program.path, int(mv.line[home[0]]), "G28/G30 go to a position stored in the machine;"
                             " Klartext has no equivalent (an M91 move to that position would): not converted")


def _pgm_name(out: Path) -> str:
    return "".join(c for c in out.stem if c.isalnum() or c in "_-")[:24] or "ILCNC"


def _corrected_moves(program, corr):
    """A copy of the move table with corrected command end points (and the following starts)."""
    import copy

    mv = copy.copy(program.moves)
    end = mv.end_mm.copy()
    idx = program.command_moves
    end[idx] += corr
    start = mv.start_mm.copy()
    start[1:] = end[:-1]
    mv.end_mm = end
    mv.start_mm = start
    return mv



def export_iteration(src: Path, out: Path, state_dir: Path, *, iteration: int | None = None,
                     profile_path: Path | None = None) -> ExportResult:
    """Write the program of one iteration of a learning state (``export --state``), byte for byte.

    ``src`` must be the state's original program or one of its outputs; ``iteration`` defaults to the one the
    run wrote as its output (else the last). In the program's own dialect the bytes are the state's, checked
    against their recorded hash; in the other dialect the iteration's program is converted.
    """
    from ilcnc.errors import StateError
    from ilcnc.shop.state import LearnState, sha256_bytes

    st = LearnState.load(state_dir)
    sha = sha256_bytes(read_bytes(src))
    if sha != st.part["sha256"] and st.find_program(sha) is None:
        raise StateError(src, None, f"is not the original nor an output of the learning run in {state_dir}"
                         f" ({st.part['name']})")
    if not st.iterations:
        raise StateError(state_dir, None, "holds no iteration yet")
    if iteration is None:
        with_output = [e for e in st.iterations if e.output]
        entry = with_output[-1] if with_output else st.iterations[-1]
    else:
        found = [e for e in st.iterations if e.iteration == iteration]
        if not found:
            have = ", ".join(str(e.iteration) for e in st.iterations)
            raise StateError(state_dir, None, f"has no iteration {iteration} (it has {have})")
        entry = found[0]
    raw = st.read_program_bytes(entry)
    return export_program(st.file(entry.program), out, profile_path=profile_path, data=raw)

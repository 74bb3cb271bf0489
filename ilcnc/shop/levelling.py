"""Level a G-code program on a sender's probe height map (``ilcnc learn PROG --points MAP --out OUT``).

Every move's end point in the probed region gets the surface height there (the map's bilinear height minus
its height at the sender's zero point, docs/probemaps.md), so the tool keeps its programmed depth below a
warped or tilted stock top. What the senders' users miss, kept:

* arcs stay arcs: an arc whose ends get different heights becomes a helix (G2/G3 with Z); one whose helix
  departs from the surface by more than :data:`LEVEL_TOLERANCE_MM` is split into shorter arcs on the same
  circle (:mod:`ilcnc.program.arcsplit`) until each piece's helix stays within it; the largest departure is
  reported;
* a straight feed is split only where the surface bends along it by more than :data:`LEVEL_TOLERANCE_MM`
  (the inserted lines are marked ``ilcnc level`` as refinement marks its own); rapids are never split;
* every other word, comment and M-code stays; numbers keep their spelling and at least their decimals;
  units (a G20 program gets inch numbers) and work offsets (G54.., G92) stay as the source set them;
* the output carries a marker naming the map's hash; a program that carries one is refused, so a map is
  never applied twice.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.axislog.heightmap import HeightMap, read_height_map
from ilcnc.contour.surface import arc_height_error_mm, line_split_fractions, surface_height_mm
from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes, same_file, write_atomic
from ilcnc.program import read_program
from ilcnc.program.arcsplit import split_arcs
from ilcnc.program.comments import comment_first_line
from ilcnc.program.insert import insert_points, required_decimals, reread
from ilcnc.program.model import (
    FLAG_DERIVED,
    FLAG_HOME,
    FLAG_MACHINE,
    FLAG_POLAR,
    FLAG_POSITION_READ,
    FLAG_REPEATED,
    MOVE_ARC_CCW,
    MOVE_ARC_CW,
    MOVE_LINE,
    PLANE_XY,
    Program,
)
from ilcnc.program.rewrite import apply_move_ends

__all__ = ["LEVEL_MARKER", "LEVEL_TOLERANCE_MM", "MAX_ARC_PIECES", "LevelResult", "find_level_stamp", "level_program"]

#: Largest height departure of a straight feed piece from the surface between its levelled ends, mm.
LEVEL_TOLERANCE_MM = 0.001
#: The trailing comment of every line inserted to split a straight feed.
LEVEL_MARKER = "ilcnc level"

_STAMP = re.compile(r"ilcnc: levelled with (?P<name>\S+) sha256:(?P<sha>[0-9a-f]{16})")
# FLAG_POSITION_READ: the next block (G92, G10 L20, a cycle, ...) reads its end point: levelled, every later
# move would shift by its dz
_SKIP_FLAGS = FLAG_MACHINE | FLAG_HOME | FLAG_REPEATED | FLAG_POLAR | FLAG_POSITION_READ


@dataclass(kw_only=True, slots=True)
class LevelResult:
    """What :func:`level_program` did; every figure in mm."""

    program: Path
    output: Path
    map_path: Path
    map_format: str
    grid: tuple[int, int]
    reference_xy_mm: tuple[float, float] | None
    reference_height_mm: float
    tolerance_mm: float
    moves_levelled: int
    moves_kept: int
    ends_outside: int
    outside_max_mm: float
    dz_min_mm: float
    dz_max_mm: float
    lines_split: int
    points_inserted: int
    arcs_split: int = 0
    split_refused: list[tuple[int, str]] = field(default_factory=list)
    line_error_max_mm: float = 0.0
    arcs: int = 0
    arcs_over_tolerance: int = 0
    arc_error_max_mm: float = 0.0
    notes: list[str] = field(default_factory=list)

    def rows(self) -> list[tuple[str, str]]:
        """The summary ``ilcnc learn --points MAP`` prints, as (what, value) rows."""
        ref = "the work Z zero of the probing" if self.reference_xy_mm is None else \
            f"X{self.reference_xy_mm[0]:g} Y{self.reference_xy_mm[1]:g} ({self.reference_height_mm * 1e3:+.1f} µm)"
        return [
            ("map grid (points)", f"{self.grid[1]} x {self.grid[0]}"),
            ("heights relative to", ref),
            ("moves levelled / kept", f"{self.moves_levelled} / {self.moves_kept}"),
            ("dz min / max (µm)", f"{self.dz_min_mm * 1e3:+.1f} / {self.dz_max_mm * 1e3:+.1f}"),
            ("end points outside the map", f"{self.ends_outside} (farthest {self.outside_max_mm:.3f} mm; edge height held)"),
            ("straight feeds / arcs split", f"{self.lines_split} / {self.arcs_split} ({self.points_inserted} lines"
             f" inserted, {len(self.split_refused)} not split)"),
            ("straight feeds: largest departure (µm)", f"{self.line_error_max_mm * 1e3:.2f}"),
            ("arcs kept as arcs / over tolerance", f"{self.arcs} / {self.arcs_over_tolerance}"),
            ("arcs: largest departure (µm)", f"{self.arc_error_max_mm * 1e3:.2f}"),
        ]

    def to_json(self) -> dict[str, Any]:
        """The result as one JSON object (``--json``)."""
        return {
            "mode": "height-map", "program": str(self.program), "output": str(self.output),
            "map": {"path": str(self.map_path), "format": self.map_format, "grid": list(self.grid),
                    "reference_xy_mm": None if self.reference_xy_mm is None else list(self.reference_xy_mm),
                    "reference_height_mm": self.reference_height_mm},
            "tolerance_mm": self.tolerance_mm, "moves_levelled": self.moves_levelled, "moves_kept": self.moves_kept,
            "ends_outside_map": self.ends_outside, "outside_max_mm": self.outside_max_mm,
            "dz_min_mm": self.dz_min_mm, "dz_max_mm": self.dz_max_mm,
            "lines_split": self.lines_split, "arcs_split": self.arcs_split, "points_inserted": self.points_inserted,
            "split_refused": [{"line": ln, "reason": r} for ln, r in self.split_refused],
            "line_error_max_mm": self.line_error_max_mm, "arcs": self.arcs,
            "arcs_over_tolerance": self.arcs_over_tolerance, "arc_error_max_mm": self.arc_error_max_mm,
            "notes": list(self.notes),
        }


def find_level_stamp(text: str) -> dict[str, Any] | None:
    """The height-map marker of a levelled program (first 50 lines), or None."""
    for i, line in enumerate(text.splitlines()[:50], start=1):
        m = _STAMP.search(line)
        if m:
            return {"name": m["name"], "sha": m["sha"], "line": i}
    return None


def _eligible(program: Program) -> NDArray[np.bool_]:
    """Moves whose end point the map moves: X and Y set by the program (not a machine, home, repeated or polar
    move). A move before the program sets X and Y (a first retract) keeps its Z."""
    mv = program.moves
    m = len(mv)
    known = np.zeros(2, dtype=bool)
    out = np.zeros(m, dtype=bool)
    ws = mv.word_start[:, :2] != -1  # SPAN_LAZY (-2): a word whose span is found on demand
    inc = mv.word_incremental[:, :2]
    flags = mv.flags.astype(np.int64)
    for i in range(m):
        known |= ws[i] & ~inc[i]
        out[i] = bool(known.all()) and not int(flags[i]) & _SKIP_FLAGS
    return out


def _sweep(kind: int, a0: float, a1: float, turns: int) -> float:
    two_pi = 2.0 * math.pi
    if kind == MOVE_ARC_CCW:
        s = (a1 - a0) % two_pi
    else:
        s = -((a0 - a1) % two_pi)
    if abs(s) < 1e-12:
        s = two_pi if kind == MOVE_ARC_CCW else -two_pi
    extra = max(int(turns), 1) - 1
    return s + math.copysign(two_pi * extra, s)


def _arc_geometry(program: Program, i: int) -> tuple[NDArray[np.float64], float, float, float]:
    """(centre xy in program coordinates, radius, start angle, signed sweep) of arc move ``i``."""
    mv = program.moves
    c = mv.center_mm[i, :2] - mv.offset_mm[i, :2]
    s = mv.start_mm[i, :2] - mv.offset_mm[i, :2]
    e = mv.end_mm[i, :2] - mv.offset_mm[i, :2]
    a0 = math.atan2(s[1] - c[1], s[0] - c[0])
    a1 = math.atan2(e[1] - c[1], e[0] - c[0])
    return c, math.hypot(*(s - c)), a0, _sweep(int(mv.kind[i]), a0, a1, int(mv.turns[i]))


def _arc_pieces_error(hmap: HeightMap, c: NDArray[np.float64], r: float, a0: float, sweep: float, n: int) -> float:
    """Largest departure of ``n`` equal helix pieces of an arc, each between the surface heights at its ends."""
    ang = a0 + sweep * np.arange(n + 1) / n
    h, _ = surface_height_mm(hmap, c[0] + r * np.cos(ang), c[1] + r * np.sin(ang))
    return max(arc_height_error_mm(hmap, c, r, float(ang[k]), sweep / n, float(h[k]), float(h[k + 1]))
               for k in range(n))


#: Most pieces an arc is split into (a limit to the lines added; an arc that needs more is reported).
MAX_ARC_PIECES = 64


def _plan_arc_splits(program: Program, hmap: HeightMap, ok: NDArray[np.bool_], tol: float
                     ) -> dict[int, list[float]]:
    """Arcs whose helix departs from the surface by more than ``tol``: equal pieces, doubled until each fits."""
    mv = program.moves
    arcs = np.flatnonzero(ok & (mv.kind >= MOVE_ARC_CW) & np.concatenate([[False], ok[:-1]]))
    out: dict[int, list[float]] = {}
    for i in arcs.tolist():
        c, r, a0, sweep = _arc_geometry(program, i)
        if _arc_pieces_error(hmap, c, r, a0, sweep, 1) <= tol:
            continue
        n = 2
        while n < MAX_ARC_PIECES and _arc_pieces_error(hmap, c, r, a0, sweep, n) > tol:
            n *= 2
        out[i] = [k / n for k in range(1, n)]
    return out


def _plan_splits(program: Program, hmap: HeightMap, ok: NDArray[np.bool_], tol: float) -> dict[int, list[float]]:
    """Straight feeds to split, with the fractions where (:func:`line_split_fractions`)."""
    mv = program.moves
    pc_end = mv.end_mm[:, :2] - mv.offset_mm[:, :2]
    pc_start = mv.start_mm[:, :2] - mv.offset_mm[:, :2]
    prev_ok = np.concatenate([[False], ok[:-1]])
    cand = ok & prev_ok & (mv.kind == MOVE_LINE) & (np.hypot(*(pc_end - pc_start).T) > 1e-6)
    idx = np.flatnonzero(cand)
    if idx.size == 0:
        return {}
    s, e = pc_start[idx], pc_end[idx]
    mid = 0.5 * (s + e)
    h0, _ = surface_height_mm(hmap, s[:, 0], s[:, 1])
    h1, _ = surface_height_mm(hmap, e[:, 0], e[:, 1])
    hm, _ = surface_height_mm(hmap, mid[:, 0], mid[:, 1])
    xs, ys = hmap.x_mm, hmap.y_mm

    def cell(v: NDArray[np.float64], grid: NDArray[np.float64]) -> NDArray[np.int64]:
        return np.clip(np.searchsorted(grid, np.clip(v, grid[0], grid[-1]), side="right") - 1, 0, grid.size - 2)

    one_cell = (cell(s[:, 0], xs) == cell(e[:, 0], xs)) & (cell(s[:, 1], ys) == cell(e[:, 1], ys))
    # inside one cell the departure is the midpoint's, exactly (surface module docstring)
    need = ~one_cell | (np.abs(hm - 0.5 * (h0 + h1)) > tol)
    out: dict[int, list[float]] = {}
    for k in np.flatnonzero(need).tolist():
        i = int(idx[k])
        fr, _err = line_split_fractions(hmap, pc_start[i], pc_end[i], tol)
        if fr:
            out[i] = fr
    return out


def _line_errors(program: Program, hmap: HeightMap, ok: NDArray[np.bool_]) -> float:
    """Largest departure of a levelled straight feed from the surface between its ends, mm."""
    mv = program.moves
    prev_ok = np.concatenate([[False], ok[:-1]])
    worst = 0.0
    for i in np.flatnonzero(ok & prev_ok & (mv.kind == MOVE_LINE)).tolist():
        s = mv.start_mm[i, :2] - mv.offset_mm[i, :2]
        e = mv.end_mm[i, :2] - mv.offset_mm[i, :2]
        if math.hypot(*(e - s)) > 1e-6:
            worst = max(worst, line_split_fractions(hmap, s, e, math.inf)[1])
    return worst


def level_program(program_path: str | Path, map_path: str | Path, out: str | Path, *,
                  tolerance_mm: float = LEVEL_TOLERANCE_MM) -> LevelResult:
    """Write ``program_path`` levelled on the height map ``map_path`` to ``out``.

    Raises
    ------
    InputError
        A Klartext program, a program that already carries a height map, an output that is an input, a
        malformed map, an arc in the XZ or YZ plane or a spline among the levelled moves, or a word that cannot
        take its change.
    """
    prog_p, map_p, out_p = Path(program_path), Path(map_path), Path(out)
    for what, p in (("the program", prog_p), ("the height map", map_p)):
        if same_file(out_p, p):
            raise InputError(out_p, None, f"is {what} of this run: choose another output path (--out)")
    data = read_bytes(prog_p)
    program = read_program(prog_p, data=data)
    if program.dialect == "heidenhain":
        raise InputError(prog_p, None, "a probe height map levels G-code programs (the senders' format); a Klartext"
                         " program is levelled on the control (its own probing cycles)")
    program.require_complete()
    hmap = read_height_map(map_p)
    seen = find_level_stamp(program.text)
    if seen is not None:
        same = "this map" if seen["sha"] == hmap.sha256[:16] else f"map {seen['name']}"
        raise InputError(prog_p, seen["line"], f"is levelled already with {same} (sha256:{seen['sha']}): a height map is"
                         " applied once; level the original program")
    unit_mm = 25.4 if program.units == "inch" else 1.0
    min_dec = required_decimals(unit_mm, tolerance_mm / 2)
    ok = _eligible(program)
    mv = program.moves
    bad = np.flatnonzero(ok & (mv.kind >= MOVE_ARC_CW) & (mv.plane != PLANE_XY))
    if bad.size:
        raise InputError(prog_p, int(mv.line[bad[0]]), "an arc in the XZ or YZ plane: a height map cannot move its ends"
                         " along Z without changing its radius; ilcnc levels G17 (XY) arcs only")
    derived = np.flatnonzero(ok & ((mv.flags & FLAG_DERIVED) != 0))
    if derived.size:
        raise InputError(prog_p, int(mv.line[derived[0]]), "a spline (G5, G5.1, G5.2) or another move the reader"
                         " derives: its Z cannot follow the map (LinuxCNC takes no Z word on a spline); have the CAM"
                         " write it as arcs or lines")
    splits = _plan_splits(program, hmap, ok, tolerance_mm)
    refused: list[tuple[int, str]] = []
    n_line_refused = 0
    points_inserted = 0
    notes: list[str] = []
    lev = np.flatnonzero(ok)  # the source's lines, before any insertion
    shift = lev[1:][np.any(mv.offset_mm[lev[1:]] != mv.offset_mm[lev[:-1]], axis=1)] if lev.size > 1 else lev[:0]
    if shift.size:
        notes.append(f"the work offset changes at line {int(mv.line[shift[0]])} ({shift.size} times among the levelled"
                     " moves): the map is read in the coordinates of the work system active at each move, as the"
                     " senders read the program's numbers")
    if splits:
        ins = insert_points(program, splits, min_decimals=min_dec, marker=LEVEL_MARKER)
        refused = [(s.line, s.reason) for s in ins.skipped]
        n_line_refused = len(refused)
        points_inserted = ins.n_inserted
        notes.extend(ins.notes)
        if ins.n_inserted:
            program = reread(program, ins.text)
            program.require_complete()
            ok = _eligible(program)
            mv = program.moves
    arc_splits = _plan_arc_splits(program, hmap, ok, tolerance_mm)
    arcs_split = 0
    if arc_splits:
        asr = split_arcs(program, arc_splits, min_decimals=min_dec, marker=LEVEL_MARKER)
        refused += [(sk.line, sk.reason) for sk in asr.skipped]
        arcs_split = len(arc_splits) - len(asr.skipped)
        points_inserted += asr.n_inserted
        if asr.n_inserted:
            program = reread(program, asr.text)
            program.require_complete()
            ok = _eligible(program)
            mv = program.moves
    pc = mv.end_mm - mv.offset_mm
    h, outside = surface_height_mm(hmap, pc[:, 0], pc[:, 1])
    ref_h = 0.0
    if hmap.reference_xy_mm is not None:
        ref_h = float(surface_height_mm(hmap, np.array([hmap.reference_xy_mm[0]]),
                                        np.array([hmap.reference_xy_mm[1]]))[0][0])
    dz = np.where(ok, h - ref_h, 0.0)
    ends = mv.end_mm.copy()
    # the levelled Z on the grid of the written numbers (min_dec decimals of the program's unit), so that a Z word
    # the rewriter adds gets those decimals and no more
    zq = np.round((ends[:, 2] + dz - mv.offset_mm[:, 2]) / mv.unit_mm, min_dec) * mv.unit_mm + mv.offset_mm[:, 2]
    ends[:, 2] = np.where(ok, zq, ends[:, 2])
    dz = np.where(ok, ends[:, 2] - mv.end_mm[:, 2], 0.0)
    # how far outside: the distance to the probed rectangle, mm
    gx = np.maximum(np.maximum(hmap.x_mm[0] - pc[:, 0], pc[:, 0] - hmap.x_mm[-1]), 0.0)
    gy = np.maximum(np.maximum(hmap.y_mm[0] - pc[:, 1], pc[:, 1] - hmap.y_mm[-1]), 0.0)
    far = np.hypot(gx, gy)[ok & outside]
    # arcs: the helix between the levelled ends against the surface along the arc
    arcs = np.flatnonzero(ok & (mv.kind >= MOVE_ARC_CW) & np.concatenate([[False], ok[:-1]]))
    arc_err = np.zeros(arcs.size)
    for n, i in enumerate(arcs.tolist()):
        c, r, a0, sweep = _arc_geometry(program, i)
        arc_err[n] = arc_height_error_mm(hmap, c, r, a0, sweep, float(dz[i - 1] + ref_h), float(dz[i] + ref_h))
    text, _edits = apply_move_ends(program, ends, min_decimals=min_dec)
    note = f"ilcnc: levelled with {map_p.name.replace(' ', '_')} sha256:{hmap.sha256[:16]}"
    text = comment_first_line(text, note)
    written = write_atomic(out_p, text.encode("latin-1"), protect=(prog_p, map_p))
    over = int(np.count_nonzero(arc_err > tolerance_mm))
    if over:
        notes.append(f"{over} arcs depart from the surface by more than {tolerance_mm * 1e3:g} µm between their"
                     f" levelled ends (largest {arc_err.max() * 1e3:.1f} µm): arcs that could not be split (above) or"
                     f" would need more than {MAX_ARC_PIECES} pieces")
    return LevelResult(
        program=prog_p, output=written, map_path=map_p, map_format=hmap.fmt, grid=hmap.shape,
        reference_xy_mm=hmap.reference_xy_mm, reference_height_mm=ref_h, tolerance_mm=tolerance_mm,
        moves_levelled=int(np.count_nonzero(ok)), moves_kept=int(np.count_nonzero(~ok)),
        ends_outside=int(far.size), outside_max_mm=float(far.max()) if far.size else 0.0,
        dz_min_mm=float(dz[ok].min()) if ok.any() else 0.0, dz_max_mm=float(dz[ok].max()) if ok.any() else 0.0,
        lines_split=len(splits) - n_line_refused, arcs_split=arcs_split, points_inserted=points_inserted, split_refused=refused,
        line_error_max_mm=_line_errors(program, hmap, ok), arcs=int(arcs.size), arcs_over_tolerance=over,
        arc_error_max_mm=float(arc_err.max()) if arc_err.size else 0.0, notes=notes)

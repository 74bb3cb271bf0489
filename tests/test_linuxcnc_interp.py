"""ilcnc's G-code reader against LinuxCNC's own interpreter, sample by sample.

Acceptance: ``inspect --moves`` on the LinuxCNC programs agrees with LinuxCNC's
interpreter. For every G-code sample in ``samples/third_party/{gcode,contour,interp,large}``
LinuxCNC's interpreter is run and every straight feed (end point and source
line) is compared with ours, in the program frame (``program_frame_mm``:
LinuxCNC reports work coordinates, offsets and the work system's XY rotation
(``G10 L2 R``) not applied):

* ``rs274 -g`` (the standalone interpreter) on a copy whose every line is
  prefixed ``N<line>`` so that its output names the source line; it prints 4
  decimals in the program's current units, so the tolerance is half a unit of
  the 4th decimal (0.05 µm in mm programs, 1.27 µm in inch programs);
* the ``gcode`` Python extension (what AXIS uses for its preview), run by
  ``/usr/bin/python3 tests/lcnc_gcode_dump.py``: full doubles and native line
  numbers, tolerance 1e-6 mm. It cannot look tools up without a running
  LinuxCNC (it crashes on any T/H/D word), so for such programs only rs274 is
  used. What each test compared (and why the gcode module was not used) is
  recorded in its ``user_properties`` (``--junitxml`` writes them).

Both tests check both routes: the straight feeds (what ``inspect --moves``
lists), and all motion (rapids, feeds, arcs with their centres, and the end
points with the work / G92 offsets and the rotation applied as LinuxCNC's canon
applies them). rs274 gets a tool table in which
every tool exists with zero length and diameter, so that cutter compensation
leaves the programmed path unchanged.

Zero-length straight moves are dropped on both sides (LinuxCNC emits one for a
``G1 F..`` block without axis words). Where ilcnc stops early
(:attr:`Program.unsupported`), its message must name a real line in a clear
sentence, every move it read must agree with LinuxCNC's first moves (execution
order, so O-word loops and subroutines are fine), and LinuxCNC's next move
must not come from a line between ilcnc's last move and that line. Where
LinuxCNC refuses a program, ilcnc must refuse it too, at that line or
earlier; the few cases where ilcnc knowingly reads more are listed in
``_TOLERATED_REFUSALS`` with the reason, recorded as a test property (after their
moves were compared).
"""

from __future__ import annotations

import functools
import json
import math
import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from ilcnc.errors import ProgramError, UnsupportedError
from ilcnc.program import read_program
from ilcnc.program.model import MOVE_LINE, Program, program_frame_mm, rotate_xy
from ilcnc.units import MM_PER_INCH

from .conftest import sample_files

RS274 = shutil.which("rs274")
if RS274 is None:
    pytest.skip(
        "LinuxCNC's standalone interpreter 'rs274' is not on PATH (Debian 12: apt-get install linuxcnc-uspace); "
        "cannot compare the reader with LinuxCNC",
        allow_module_level=True,
    )

pytestmark = pytest.mark.linuxcnc

SYSTEM_PYTHON = Path("/usr/bin/python3")
DUMP_SCRIPT = Path(__file__).with_name("lcnc_gcode_dump.py")
# the samples, and ilcnc's own program of the constructs the samples use once or not at all: work systems turned by
# G10 L2 R with arcs (I/J, R, G90.1), G91, G92, G10 L20, drilling cycles, G5.1, G53 and polar words in them; and
# G5.2/G5.3 NURBS blocks (orders 3 and 4, weights, in a turned and shifted work system)
SAMPLES = [*sample_files("gcode", "contour", "interp", "large"),
           *(Path(__file__).with_name("data") / name for name in ("rotated_frames.ngc", "nurbs.ngc"))]
TIMEOUT_S = 120

KIND_NAMES = {0: "G0", 1: "G1", 2: "G2", 3: "G3", 9: "other motion"}
RS274_TOL = 0.5e-4 + 1e-9  # program units: rs274 prints %.4f
GCODE_TOL_MM = 1e-6
ZERO_MM = 1e-9

# Programs LinuxCNC refuses but ilcnc reads on purpose. Each entry: a pattern on LinuxCNC's
# message, a test on the refused block's text, and why ilcnc may read it. The moves are compared
# first (all of them that LinuxCNC produced); the reason is recorded as a test property.
_TOLERATED_REFUSALS: list[tuple[str, str, str]] = [
    (
        r"^File ended with no percent sign or program end$",
        r"",
        "LinuxCNC insists on M2/M30 or a closing '%' at the end of a program; ilcnc reads programs that "
        "simply stop (grbl and hobby CAM output often do). Every move up to the end of the file was compared.",
    ),
    (
        r"^Bad character '%' used$",
        r"^\s*%\s*$",
        "the program's last line is a closing '%' without an opening '%' on the first line: LinuxCNC refuses "
        "that '%', ilcnc takes a lone '%' line as a tape delimiter (Fanuc style) and has no move after it. "
        "Every move before it was compared.",
    ),
    (
        r"^Unknown word where unary operation could be$",
        r"^\s*N\d+\s*\$",
        "a grbl system command ('$H' homing) on its own line: LinuxCNC has no '$' words, ilcnc reads grbl files "
        "and ignores these lines with a warning. The moves were compared against LinuxCNC run on a copy in "
        "which the '$' lines are comments.",
    ),
]

# Lines that LinuxCNC cannot read but ilcnc deliberately ignores; the oracle copy gets them as
# comments so that LinuxCNC can check the rest of the program (see the '$' entry above).
_GRBL_SYSTEM_LINE = re.compile(r"^([ \t]*)(\$[^\r\n]*)")


# --------------------------------------------------------------------------------------------
# motion lists


@dataclass
class Motion:
    """A sequence of moves in execution order, program frame, mm."""

    kind: np.ndarray  # int: 0 G0, 1 G1, 2 G2, 3 G3, 9 other
    line: np.ndarray  # int: 1-based source line
    end: np.ndarray  # (M, 3) mm, program frame
    center: np.ndarray  # (M, 3) mm, program frame; NaN where none / normal axis
    tol: np.ndarray  # (M,) mm, comparison tolerance of each move
    zero: np.ndarray  # (M,) bool: a straight move that does not move (consistent frame)
    machine: np.ndarray  # (M, 3) mm, end point with the G92/G52 offsets, the XY rotation and the work offset applied
    mtol: np.ndarray  # (M,) mm, comparison tolerance of ``machine``

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    def take(self, mask: np.ndarray) -> Motion:
        return Motion(
            self.kind[mask],
            self.line[mask],
            self.end[mask],
            self.center[mask],
            self.tol[mask],
            self.zero[mask],
            self.machine[mask],
            self.mtol[mask],
        )


def _zero_length(kind: np.ndarray, machine: np.ndarray, zero_mm: np.ndarray | float = ZERO_MM) -> np.ndarray:
    """Straight moves that do not move (consistent frame; the machine starts at 0, 0, 0)."""
    if not len(kind):
        return np.zeros(0, dtype=bool)
    prev = np.vstack([np.zeros((1, 3)), machine[:-1]])
    step = np.abs(machine - prev).max(axis=1)
    return ((kind == 0) | (kind == 1)) & (step <= zero_mm)


def _motion(kind: list[int], line: list[int], end: list, center: list, machine: list, tol: list[float],
            rotation: list[float] | None = None) -> Motion:
    """A motion list; ``rotation`` (degrees per move) only for rs274's printed numbers, whose rounding the rotation
    carries into the machine point (see below)."""
    k = np.array(kind, dtype=np.int64)
    m = np.array(machine, dtype=np.float64).reshape(-1, 3)
    t = np.array(tol, dtype=np.float64)
    # the machine point adds three printed numbers (program point, G92 and G5x offsets; each within tol per axis):
    # 2 tol as before where nothing turns; turned by the rotation, the first two add up to (|cos|+|sin|) tol each
    mtol = 2 * t
    zero = np.full(len(k), ZERO_MM)
    if rotation is not None and len(k):
        r = np.radians(np.array(rotation, dtype=np.float64))
        turned = r != 0.0
        mtol = np.where(turned, (1.0 + 2.0 * (np.abs(np.cos(r)) + np.abs(np.sin(r)))) * t, mtol)
        # a move between two such points that does not move shows a step of up to twice that rounding
        near = turned | np.concatenate([[False], turned[:-1]])
        zero = np.where(near, 2.0 * mtol, zero)
    return Motion(
        k,
        np.array(line, dtype=np.int64),
        np.array(end, dtype=np.float64).reshape(-1, 3),
        np.array(center, dtype=np.float64).reshape(-1, 3),
        t,
        _zero_length(k, m, zero),
        m,
        mtol,
    )


def _ours_motion(prog: Program) -> Motion:
    mv = prog.moves
    kind = mv.kind.astype(np.int64)
    return Motion(
        kind,
        mv.line.astype(np.int64),
        program_frame_mm(mv, mv.end_mm),
        program_frame_mm(mv, mv.center_mm),
        np.zeros(len(mv)),
        _zero_length(kind, mv.end_mm),
        mv.end_mm,
        np.zeros(len(mv)),
    )


def _drop_zero_length(ours: Motion, theirs: Motion) -> tuple[Motion, Motion]:
    """Both lists without their zero-length straight moves.

    Ours are dropped when they do not move at all. LinuxCNC's list is what its output shows: with
    rs274's 4 printed decimals a real move shorter than the print resolution looks like zero
    length too, so a "zero" LinuxCNC move is kept when it is the counterpart of our next move
    (same line, kind and end point); otherwise it is the zero-length feed of a block without axis
    words (``G1 F100``) or a move to where the tool already is, and is dropped.
    """
    mine = ours.take(~ours.zero)
    keep = ~theirs.zero
    i = 0
    n = len(mine)
    for j in range(len(theirs)):
        if theirs.zero[j]:
            keep[j] = (
                i < n
                and mine.line[i] == theirs.line[j]
                and mine.kind[i] == theirs.kind[j]
                and float(np.abs(mine.end[i] - theirs.end[j]).max()) <= theirs.tol[j]
            )
        if keep[j]:
            i += 1
    return mine, theirs.take(keep)


# --------------------------------------------------------------------------------------------
# LinuxCNC's side


@dataclass
class Oracle:
    name: str
    ok: bool
    error: str  # LinuxCNC's message ("" when ok)
    error_line: int | None  # source line of the refused block
    error_block: str  # the refused block as LinuxCNC printed it
    motion: Motion | None  # None: this interpreter could not be run on the sample
    note: str = ""  # why motion is None


_N_WORD = re.compile(r"([ \t]*/?[ \t]*)(?:[Nn][ \t]*\d+(?:\.\d*)?)?")


def _n_prefixed(text: str) -> str:
    """Every line prefixed with ``N<line>`` (an existing N word replaced), '%' lines untouched."""
    out = []
    lines = text.split("\n")
    if lines[-1] == "":
        lines.pop()
    for i, raw in enumerate(lines, start=1):
        head = raw.lstrip(" \t")[:1]
        if head not in "%/Nn":  # (an empty head is in every string: blank lines take the slow path)
            out.append(f"N{i} {raw}")
        elif head == "%":
            out.append(raw)
        else:
            m = _N_WORD.match(raw)
            assert m is not None
            out.append(f"{m.group(1)}N{i} {raw[m.end() :]}")
    return "\n".join(out) + "\n"


def _adapted(text: str) -> tuple[str, bool]:
    """The program with grbl '$' system lines turned into comments (for LinuxCNC only)."""
    lines = text.split("\n")
    changed = False
    for i, raw in enumerate(lines):
        m = _GRBL_SYSTEM_LINE.match(raw)
        if m is not None:
            body = m.group(2).replace("(", "[").replace(")", "]")
            lines[i] = f"{m.group(1)}({body})"
            changed = True
    return "\n".join(lines), changed


_RS274_LINE = re.compile(r"^[ \t]*\d+[ \t]+N(\d+|\.+)[ \t]*([A-Z_0-9]+)\((.*)\)[ \t]*$", re.MULTILINE)
_PLANES = {"CANON_PLANE_XY": (0, 1, 2), "CANON_PLANE_YZ": (1, 2, 0), "CANON_PLANE_XZ": (2, 0, 1)}
_UNITS = {"CANON_UNITS_MM": 1.0, "CANON_UNITS_INCHES": MM_PER_INCH, "CANON_UNITS_CM": 10.0}
_OTHER_MOTION = {"STRAIGHT_PROBE", "RIGID_TAP", "NURBS_FEED", "SPLINE_FEED"}


def _canon_machine(end: np.ndarray, g5x: list, g92: list, rotation: list) -> np.ndarray:
    """LinuxCNC's canon (emccanon.cc ``rotate_and_offset_pos``) on the interpreter's program-frame points: the G92
    offset added, the XY rotation of the work system (degrees) turned about the work origin, the G5x offset added;
    mm, one offset and rotation per point."""
    e = np.asarray(end, dtype=np.float64).reshape(-1, 3)
    turned = rotate_xy(e + np.array(g92, dtype=np.float64).reshape(-1, 3), np.array(rotation, dtype=np.float64))
    return turned + np.array(g5x, dtype=np.float64).reshape(-1, 3)


def _parse_rs274(stdout: str) -> Motion:
    unit = 1.0
    plane = _PLANES["CANON_PLANE_XY"]
    g5x = (0.0, 0.0, 0.0)
    g92 = (0.0, 0.0, 0.0)
    rot = 0.0
    rots: list[float] = []
    g92s: list[tuple[float, float, float]] = []
    kind: list[int] = []
    line: list[int] = []
    end: list[list[float]] = []
    center: list[list[float]] = []
    offsets: list[tuple[float, float, float]] = []
    tol: list[float] = []
    nan3 = [math.nan] * 3
    for m in _RS274_LINE.finditer(stdout):  # other output ((PRINT,...) lines and the like) does not match
        n, name, args = m.group(1), m.group(2), m.group(3)
        if name in ("STRAIGHT_FEED", "STRAIGHT_TRAVERSE"):
            v = args.split(",", 3)
            p = [float(v[0]) * unit, float(v[1]) * unit, float(v[2]) * unit]
            kind.append(1 if name == "STRAIGHT_FEED" else 0)
            center.append(nan3)
        elif name == "ARC_FEED":
            v = [float(a) for a in args.split(",")]
            a1, a2, nrm = plane
            p = [0.0, 0.0, 0.0]
            c = [math.nan] * 3
            p[a1], p[a2], p[nrm] = v[0] * unit, v[1] * unit, v[5] * unit
            c[a1], c[a2] = v[2] * unit, v[3] * unit
            kind.append(2 if int(v[4]) < 0 else 3)
            center.append(c)
        elif name in _OTHER_MOTION:
            p = end[-1] if end else [0.0, 0.0, 0.0]  # end point not printed; only its line matters
            kind.append(9)
            center.append(nan3)
        else:
            if name == "USE_LENGTH_UNITS":
                unit = _UNITS[args.strip()]
            elif name == "SELECT_PLANE":
                plane = _PLANES[args.strip()]
            elif name == "SET_G5X_OFFSET":
                x, y, z = (float(v) * unit for v in args.split(",")[1:4])
                g5x = (x, y, z)
            elif name == "SET_G92_OFFSET":
                x, y, z = (float(v) * unit for v in args.split(",")[0:3])
                g92 = (x, y, z)
            elif name == "SET_XY_ROTATION":
                rot = float(args)
            continue
        line.append(int(n) if n[0] != "." else 0)
        end.append(p)
        offsets.append(g5x)
        g92s.append(g92)
        rots.append(rot)
        tol.append(RS274_TOL * unit)
    e = np.array(end, dtype=np.float64).reshape(-1, 3)
    return _motion(kind, line, e, center, _canon_machine(e, offsets, g92s, rots), tol, rots)


def _refusal(stderr: str, stdout: str, copy_lines: list[str]) -> tuple[str, int | None, str]:
    """LinuxCNC's message, the refused block's source line and its text (rs274 prints them on stderr)."""
    rows = [r for r in stderr.splitlines() if r.strip() and r.strip() != "executing"]
    if not rows:
        return "", None, ""
    block = rows[-1]
    msg = " ".join(rows[:-1]).strip() if len(rows) > 1 else rows[-1]
    m = re.match(r"\s*/?\s*N(\d+)", block)
    if m is not None:
        return msg, int(m.group(1)), block
    # a block without our N prefix ('%' lines): the first such line after the last N that ran
    seen = [int(n) for n in re.findall(r"^\s*\d+\s+N(\d+)", stdout, re.MULTILINE)]
    for i in range(max(seen, default=0), len(copy_lines)):
        if copy_lines[i].strip() == block.strip():
            return msg, i + 1, block
    return msg, None, block


class LinuxCNC:
    """Runs both interpreters on the samples (once each), in a private temporary directory."""

    def __init__(self, work: Path) -> None:
        self.work = work
        self.tools = work / "tools.tbl"
        # every tool 1..99 exists, zero length and diameter (the samples call T1..T8 and H/D words)
        self.tools.write_text("".join(f"T{i} P{i} Z0 D0 ;\n" for i in range(1, 100)))
        self._gcode_ok: bool | None = None

    @staticmethod
    def _env(d: Path) -> dict[str, str]:
        # rs274 -t maps its tool table into $HOME/.tool.mmap, opened with O_TRUNC: a shared HOME lets
        # concurrent runs (or a running LinuxCNC) truncate each other's map (SIGBUS). Keep it private.
        return {**os.environ, "HOME": str(d)}

    def _dir(self, src: Path, route: str) -> Path:
        d = self.work / route / f"{src.parent.name}__{src.stem.replace(' ', '_')}"
        d.mkdir(parents=True, exist_ok=True)
        return d

    def rs274(self, src: Path, adapt: bool = False) -> Oracle:
        """rs274 -g on the N-prefixed copy (of the adapted program)."""
        return self._rs274(src, bool(adapt))

    def gcode_module(self, src: Path, adapt: bool = False) -> Oracle:
        """The gcode module on the program (on an adapted copy)."""
        return self._gcode_module(src, bool(adapt))

    @functools.cache  # noqa: B019 - one instance per session
    def _rs274(self, src: Path, adapt: bool) -> Oracle:
        d = self._dir(src, "rs274" + ("-adapted" if adapt else ""))
        text = src.read_bytes().decode("latin-1")
        if adapt:
            text, _ = _adapted(text)
        copy = d / "prog.ngc"
        prefixed = _n_prefixed(text)
        copy.write_bytes(prefixed.encode("latin-1"))
        with open(d / "stdout.txt", "wb") as fout, open(d / "stderr.txt", "wb") as ferr:
            proc = subprocess.run(
                [RS274, "-t", str(self.tools), "-g", str(copy)],
                cwd=d,
                env=self._env(d),
                stdout=fout,
                stderr=ferr,
                stdin=subprocess.DEVNULL,
                timeout=TIMEOUT_S,
            )
        out = (d / "stdout.txt").read_bytes().decode("latin-1")
        err = (d / "stderr.txt").read_bytes().decode("latin-1")
        assert proc.returncode in (0, 1), f"rs274 crashed on {src} (exit {proc.returncode}): {err[-2000:]}"
        msg, line, block = _refusal(err, out, prefixed.split("\n")) if proc.returncode == 1 else ("", None, "")
        return Oracle("rs274", proc.returncode == 0, msg, line, block, _parse_rs274(out))

    def gcode_available(self) -> bool:
        if self._gcode_ok is None:
            try:
                r = subprocess.run([str(SYSTEM_PYTHON), "-c", "import gcode"], capture_output=True, timeout=60)
                self._gcode_ok = r.returncode == 0
            except OSError:
                self._gcode_ok = False
        return self._gcode_ok

    @functools.cache  # noqa: B019 - one instance per session
    def _gcode_module(self, src: Path, adapt: bool) -> Oracle:
        d = self._dir(src, "gcode" + ("-adapted" if adapt else ""))
        prog = src
        if adapt:
            prog = d / ("prog" + src.suffix)
            prog.write_bytes(_adapted(src.read_bytes().decode("latin-1"))[0].encode("latin-1"))
        proc = subprocess.run(
            [str(SYSTEM_PYTHON), str(DUMP_SCRIPT), str(prog), str(d / "params.var"), str(d / "moves.json"), "G21"],
            cwd=d,
            env=self._env(d),
            capture_output=True,
            timeout=TIMEOUT_S,
            stdin=subprocess.DEVNULL,
        )
        if proc.returncode != 0:
            note = (
                f"the gcode module died (exit {proc.returncode}) on this program: without a running LinuxCNC it "
                "has no tool table and crashes on T/H/D words; rs274 -t covers this sample"
                if proc.returncode < 0
                else f"the gcode module failed (exit {proc.returncode}): {proc.stderr.decode('latin-1')[-500:]}"
            )
            return Oracle("gcode module", False, "", None, "", None, note)
        data = json.loads((d / "moves.json").read_text())
        kind, line, end, center, offsets, g92s, rots = [], [], [], [], [], [], []
        g5x = g92 = (0.0, 0.0, 0.0)
        rot = 0.0
        for row in data["moves"]:
            k, ln = row[0], row[1]
            if k in (100, 101):  # new G5x / G92 offset
                g5x, g92 = (row[2:5], g92) if k == 100 else (g5x, row[2:5])
                continue
            if k == 102:  # new XY rotation of the work system
                rot = row[2]
                continue
            if row[2] is None:  # other motion (probe, rigid tap): end point not reported
                p = end[-1] if end else [0.0, 0.0, 0.0]
            else:
                p = row[2:5]
            kind.append(k)
            line.append(ln)
            end.append(p)
            center.append([v if v is not None else math.nan for v in row[5:8]])
            offsets.append(g5x)
            g92s.append(g92)
            rots.append(rot)
        e = np.array(end, dtype=np.float64).reshape(-1, 3) * MM_PER_INCH
        m = _canon_machine(e, np.array(offsets, dtype=np.float64) * MM_PER_INCH,
                           np.array(g92s, dtype=np.float64) * MM_PER_INCH, rots)
        c = np.array(center, dtype=np.float64).reshape(-1, 3) * MM_PER_INCH
        mot = _motion(kind, line, e, c, m, [GCODE_TOL_MM] * len(kind))
        ok = data["result"] <= data["min_error"]
        return Oracle("gcode module", ok, data["error"], None if ok else data["last_line"], "", mot)


@pytest.fixture(scope="module")
def lcnc():
    with tempfile.TemporaryDirectory(prefix="ilcnc-lcnc-") as tmp:
        yield LinuxCNC(Path(tmp))


# --------------------------------------------------------------------------------------------
# our side


@functools.cache
def _ours(path: Path) -> Program | ProgramError:
    try:
        return read_program(path)
    except ProgramError as exc:
        return exc


def _check_refusal_is_clear(prog: Program) -> int:
    """ilcnc stopped early: the message names a real line in one clear sentence; returns the line."""
    assert prog.unsupported is not None
    line, problem = prog.unsupported
    src_lines = prog.text.split("\n")
    assert 1 <= line <= prog.n_lines, f"unsupported line {line} is not a line of the file ({prog.n_lines} lines)"
    code = re.sub(r"\([^)]*\)|;.*$", "", src_lines[line - 1].rstrip("\r")).strip()
    assert code, f"unsupported line {line} holds no code: {src_lines[line - 1]!r} ({problem})"
    assert "\n" not in problem and len(problem) >= 12 and " " in problem and problem[0].isalnum(), problem
    with pytest.raises(UnsupportedError) as info:
        prog.require_complete()
    assert str(info.value) == f"{prog.path}:{line}: {problem}"
    return line


# --------------------------------------------------------------------------------------------
# comparison


def _fmt(mot: Motion, i: int, src: list[str]) -> str:
    if i >= len(mot):
        return "(none)"
    ln = int(mot.line[i])
    text = src[ln - 1].rstrip("\r").strip() if 1 <= ln <= len(src) else "?"
    e = mot.end[i]
    s = f"{KIND_NAMES.get(int(mot.kind[i]), '?')} line {ln} end ({e[0]:.6f}, {e[1]:.6f}, {e[2]:.6f}) mm"
    if int(mot.kind[i]) in (2, 3):
        c = mot.center[i]
        s += f" centre ({c[0]:.6f}, {c[1]:.6f}, {c[2]:.6f})"
    o = mot.machine[i] - e
    if np.any(np.abs(o) > 1e-9):
        s += f" offset ({o[0]:.6f}, {o[1]:.6f}, {o[2]:.6f})"
    return f"{s}   <- {text[:90]!r}"


def _compare(ours: Motion, theirs: Motion, oracle: str, src: list[str], what: str, full: bool) -> list[str]:
    """Differences between two motion lists (empty list: they agree).

    Always: kind, source line and end point (program frame) of each move. With ``full`` also the
    arc centres (in-plane) and the end point with the work and G92/G52 offsets added (the offsets
    in force; rs274 prints them with 4 decimals too, hence a wider tolerance, ``Motion.mtol``).
    """
    n = min(len(ours), len(theirs))
    problems: list[str] = []
    line_bad = ours.line[:n] != theirs.line[:n]
    kind_bad = ours.kind[:n] != theirs.kind[:n]
    err = np.abs(ours.end[:n] - theirs.end[:n]).max(axis=1) if n else np.zeros(0)
    pos_bad = ~(err <= theirs.tol[:n])
    bad = line_bad | kind_bad | pos_bad
    if full and n:
        merr = np.abs(ours.machine[:n] - theirs.machine[:n]).max(axis=1)
        bad |= ~(merr <= theirs.mtol[:n])
        arc = (theirs.kind[:n] == 2) | (theirs.kind[:n] == 3)
        cd = np.abs(ours.center[:n] - theirs.center[:n])
        cerr = np.where(np.isnan(theirs.center[:n]), 0.0, cd)
        cerr = np.where(np.isnan(cerr), np.inf, cerr).max(axis=1)
        bad |= arc & ~(cerr <= theirs.tol[:n])
    idx = np.flatnonzero(bad)
    if len(ours) != len(theirs):
        problems.append(f"{what}: ilcnc has {len(ours)}, LinuxCNC ({oracle}) has {len(theirs)}")
    if idx.size:
        i = int(idx[0])
        problems.append(
            f"{what}: {idx.size} of {n} disagree; first at #{i}:\n"
            f"    ilcnc    {_fmt(ours, i, src)}\n    LinuxCNC {_fmt(theirs, i, src)}\n"
            f"    (max |diff| {float(err[i]) if i < len(err) else math.nan:.3g} mm, tolerance {float(theirs.tol[i]):.3g} mm)"
        )
    elif len(ours) != len(theirs):
        i = n
        problems.append(f"    first extra move: ilcnc {_fmt(ours, i, src)}\n    LinuxCNC {_fmt(theirs, i, src)}")
    return problems


def _check(path: Path, lcnc: LinuxCNC, request: pytest.FixtureRequest, *, only_feeds: bool) -> None:
    """Compare ilcnc with every LinuxCNC route that can run on ``path``; fail with all differences."""

    def record_property(name: str, value: str) -> None:
        request.node.user_properties.append((name, value))

    ours = _ours(path)
    if isinstance(ours, ProgramError):
        # ilcnc refuses the whole file: allowed (never read differently), if the message is clear
        assert str(ours).startswith(f"{path}"), str(ours)
        assert ours.problem and "\n" not in ours.problem
        return

    src = ours.text.split("\n")
    refusal = lcnc.rs274(path)  # rs274 names the refused block's line exactly (N prefix)
    if not refusal.ok:
        assert refusal.error_line is not None, f"rs274 refused {path} without naming a block: {refusal.error!r}"
    stop = None
    if ours.unsupported is not None:
        stop = _check_refusal_is_clear(ours)
    tolerated: str | None = None
    adapt = False
    if not refusal.ok and (stop is None or stop > refusal.error_line):
        # LinuxCNC refuses a line that ilcnc reads: only acceptable for the listed, explained cases
        for pat, block_pat, reason in _TOLERATED_REFUSALS:
            if re.search(pat, refusal.error) and re.search(block_pat, refusal.error_block):
                tolerated = reason
                break
        if tolerated is None:
            pytest.fail(
                f"LinuxCNC refuses line {refusal.error_line} ({refusal.error!r}, block {refusal.error_block!r}) "
                f"but ilcnc reads it"
                + (f" and stops later, at line {stop}: {ours.unsupported}" if stop else " (and the whole program)")
            )
        adapt = _adapted(path.read_bytes().decode("latin-1"))[1]
        if not adapt:
            after = ours.moves.line[ours.moves.line > refusal.error_line]
            assert not after.size, (
                f"LinuxCNC stops at line {refusal.error_line} ({refusal.error}) but ilcnc reads {after.size} moves "
                f"after it (first on line {int(after[0]) if after.size else 0}) that LinuxCNC never interprets"
            )

    routes = [lcnc.rs274]
    if lcnc.gcode_available():
        routes.append(lcnc.gcode_module)
    else:
        record_property("gcode_module", f"not used: {SYSTEM_PYTHON} cannot import LinuxCNC's gcode module")
    problems: list[str] = []
    for run in routes:
        oracle = run(path, adapt=adapt)
        if oracle.motion is None:
            # the gcode module cannot look tools up without a running LinuxCNC: rs274 -t covers the sample
            record_property("gcode_module", f"not used: {oracle.note}")
            continue
        if run is lcnc.gcode_module:
            assert oracle.ok == lcnc.rs274(path, adapt=adapt).ok, (
                f"rs274 and the gcode module disagree about refusing {path}: {oracle.error!r}"
            )
        mine, theirs = _drop_zero_length(_ours_motion(ours), oracle.motion)
        mine, theirs, on_curve = _split_splines(ours, mine, theirs, src, oracle.name)
        problems += on_curve
        if only_feeds:
            mine = mine.take(mine.kind == MOVE_LINE)
            theirs = theirs.take(theirs.kind == MOVE_LINE)
            what = "straight feeds (G1)"
        else:
            what = "moves (G0/G1/G2/G3, arc centres, offsets)"
        gap: list[str] = []
        if stop is None:
            scope = "whole program"
        else:
            # ilcnc stopped when execution first reached line `stop`: all it read must be LinuxCNC's
            # first moves, and LinuxCNC's next one must not come from a line ilcnc passed over
            n = len(mine)
            scope = f"the first {n} {what} (ilcnc stops at line {stop})"
            if len(theirs) > n:
                nxt, last = int(theirs.line[n]), int(mine.line[n - 1]) if n else 0
                if last < nxt < stop:
                    gap.append(
                        f"LinuxCNC's next move is on line {nxt}, between ilcnc's last move (line {last}) and "
                        f"the line where ilcnc stops ({stop}): ilcnc passed over it without a move\n"
                        f"    LinuxCNC {_fmt(theirs, n, src)}"
                    )
                theirs = theirs.take(np.arange(len(theirs)) < n)
        record_property(oracle.name, f"{len(theirs)} {what} compared, {scope}")
        found = gap + _compare(mine, theirs, oracle.name, src, what, full=not only_feeds)
        if found:
            problems.append(f"{path.name} vs LinuxCNC {oracle.name} ({scope}):\n" + "\n".join(found))
    assert not problems, "\n".join(problems)
    if tolerated is not None:
        # all checks above were made: record why LinuxCNC's refusal is not ours (visible in the junit report)
        record_property(
            "tolerated_refusal",
            f"LinuxCNC refuses line {refusal.error_line} ({refusal.error}); ilcnc reads it on purpose: {tolerated}",
        )


# the lines whose moves are a curve's chords: G5.1, and G5.3, which ends a NURBS block (LinuxCNC reports the curve there)
_CURVE_LINE = re.compile(r"[Gg]\s*0*5\s*\.\s*[13](?![0-9])")


def _split_splines(prog: Program, mine: Motion, theirs: Motion, src: list[str], oracle: str
                   ) -> tuple[Motion, Motion, list[str]]:
    """Take the moves of G5.1 and G5.3 lines out of the one-to-one comparison and check them apart.

    ilcnc follows a quadratic spline or a NURBS curve through chords within ``SPLINE_CHORD_MM`` of the curve;
    LinuxCNC makes its own pieces (rs274 prints one NURBS_FEED, the gcode module straight feeds on the curve: for a
    NURBS block 15 per control point, on the G5.3 line), so the counts differ.
    Every point LinuxCNC ends a piece at must lie on ilcnc's chords of that line, within the chords' distance
    from the curve plus the 4 decimals rs274 prints (or the last bits of the gcode module's doubles)."""
    from ilcnc.program.gcode import SPLINE_CHORD_MM
    from ilcnc.program.model import FLAG_DERIVED

    mv = prog.moves
    spline_lines = np.unique(mv.line[(mv.flags & FLAG_DERIVED) != 0])
    spline_lines = np.array([ln for ln in spline_lines.tolist() if _CURVE_LINE.search(src[ln - 1])], dtype=np.int64)
    if not spline_lines.size:
        return mine, theirs, []
    problems: list[str] = []
    for ln in spline_lines.tolist():
        ours_sel = np.flatnonzero(mv.line == ln)
        # rs274 prints 4 decimals of the program's unit (RS274_TOL); the gcode module full doubles
        tol = SPLINE_CHORD_MM + (RS274_TOL * float(mv.unit_mm[ours_sel[0]]) if oracle == "rs274" else 1e-9)
        a = program_frame_mm(mv, mv.start_mm[ours_sel], ours_sel)[:, :2]
        b = program_frame_mm(mv, mv.end_mm[ours_sel], ours_sel)[:, :2]
        pts = theirs.end[(theirs.line == ln) & (theirs.kind == 1), :2]
        for p in pts:
            d = b - a
            t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-30), 0.0, 1.0)
            dist = float(np.min(np.hypot(*(a + t[:, None] * d - p).T)))
            if dist > tol:
                problems.append(f"{oracle}: curve on line {ln}: LinuxCNC's point {p.tolist()} is {dist * 1e3:.4f} µm from"
                                f" ilcnc's chords (tolerance {tol * 1e3:.4f} µm)   <- {src[ln - 1].strip()!r}")
                break
    keep_mine = ~np.isin(mine.line, spline_lines)
    keep_theirs = ~np.isin(theirs.line, spline_lines)
    return mine.take(keep_mine), theirs.take(keep_theirs), problems


def _ids(p: Path) -> str:
    return f"{p.parent.name}/{p.name}"


@pytest.mark.parametrize("path", SAMPLES, ids=_ids)
def test_straight_feeds_agree_with_linuxcnc(path: Path, lcnc: LinuxCNC, request: pytest.FixtureRequest) -> None:
    """Every G1 end point and source line (what ``inspect --moves`` lists, and more).

    Against rs274 within its 4 printed decimals (program units) and, where the gcode module can
    run the program, within 1e-6 mm of its doubles.
    """
    _check(path, lcnc, request, only_feeds=True)


@pytest.mark.parametrize("path", SAMPLES, ids=_ids)
def test_all_motion_agrees_with_linuxcnc(path: Path, lcnc: LinuxCNC, request: pytest.FixtureRequest) -> None:
    """Rapids, feeds and arcs: kind, line, end point, arc centre and the offsets in force."""
    _check(path, lcnc, request, only_feeds=False)

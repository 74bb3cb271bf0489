"""Axis logs and measured points.

ilcnc's own axis-log CSV (what ``simulate`` writes and ``learn --log`` reads),
DESIGN.md: optional ``#`` comment lines, then the header
``t_s,k,line,x_ref,y_ref,z_ref,x_act,y_act,z_act`` (seconds, command index,
source line, mm). Extra columns are ignored; missing z columns mean a 2-axis log.

Other recorders are read into the same :class:`AxisLog`: LinuxCNC
``halsampler`` output (:func:`read_halsampler`) and Heidenhain TNCscope CSV
exports (:func:`read_tncscope`); :func:`read_log` tells them apart. Probe /
CMM results (``k,dx,dy,dz`` or ``x,y,z,dx,dy,dz``) are read by :func:`read_points`.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes, write_atomic

__all__ = [
    "AXIS_LOG_HEADER",
    "AxisLog",
    "format_axis_log",
    "moves_from_lines",
    "read_axis_log",
    "write_axis_log",
]

AXIS_LOG_HEADER = ("t_s", "k", "line", "x_ref", "y_ref", "z_ref", "x_act", "y_act", "z_act")


@dataclass(slots=True)
class AxisLog:
    """Sampled reference and actual axis positions.

    Attributes
    ----------
    t_s : ndarray (N,)
        Time, s.
    k : ndarray (N,) int
        Active G01 command index (-1 on other moves).
    line : ndarray (N,) int
        Source line of the active block (0 when none).
    ref_mm, act_mm : ndarray (N, 3)
        Commanded and actual X, Y, Z, mm (Z is NaN in a 2-axis log).
    """

    t_s: NDArray[np.float64]
    k: NDArray[np.int64]
    line: NDArray[np.int64]
    ref_mm: NDArray[np.float64]
    act_mm: NDArray[np.float64]

    @property
    def n_samples(self) -> int:
        return int(self.t_s.shape[0])

    @property
    def has_z(self) -> bool:
        return not bool(np.all(np.isnan(self.act_mm[:, 2])))


def format_axis_log(log: AxisLog, *, decimals: int = 6) -> str:
    """The log as CSV text (one C-level formatting pass: ~10x faster than csv.writer)."""
    n = log.n_samples
    cols = [log.t_s, log.k, log.line]
    z = log.has_z
    axes = (0, 1, 2) if z else (0, 1)
    names = ["t_s", "k", "line"] + [f"{a}_ref" for a in "xyz"[: len(axes)]] + [f"{a}_act" for a in "xyz"[: len(axes)]]
    data = np.empty((n, 3 + 2 * len(axes)))
    data[:, 0] = log.t_s
    data[:, 1] = log.k
    data[:, 2] = log.line
    for i, a in enumerate(axes):
        data[:, 3 + i] = log.ref_mm[:, a]
        data[:, 3 + len(axes) + i] = log.act_mm[:, a]
    row = ",".join(["%.6f", "%d", "%d"] + [f"%.{decimals}f"] * (2 * len(axes))) + "\n"
    del cols
    buf = io.StringIO()
    buf.write(",".join(names) + "\n")
    chunk = 200_000
    for s in range(0, n, chunk):
        block = data[s:s + chunk]
        buf.write((row * block.shape[0]) % tuple(block.ravel().tolist()))
    return buf.getvalue()


def write_axis_log(path: str | Path, log: AxisLog, *, protect: tuple[str | Path, ...] = ()) -> Path:
    """Write the log atomically."""
    return write_atomic(path, format_axis_log(log), protect=protect)


def read_axis_log(path: str | Path, *, max_gap_periods: float = 1.5) -> AxisLog:
    """Read an ilcnc axis-log CSV, checking it thoroughly.

    Parameters
    ----------
    path : str or Path
        The CSV: optional leading comment lines starting with ``#`` (and blank
        lines), then the header ``t_s,k,line,x_ref,y_ref[,z_ref],x_act,y_act[,z_act]``
        (s, command index, source line, mm), then one row per sample.
    max_gap_periods : float
        Largest allowed time step, in median sample periods.

    Returns
    -------
    AxisLog
        The samples (Z is NaN when the log has no z columns).

    Raises
    ------
    InputError
        Missing columns, a bad or non-finite number (with its line), time not
        increasing, or a gap longer than ``max_gap_periods`` sample periods.
        Line numbers count every line of the file, comments included.
    """
    p = Path(path)
    text = read_bytes(p).decode("utf-8", errors="replace").lstrip("\ufeff")
    lines = text.splitlines()
    h = 0  # index of the header line
    while h < len(lines) and (not lines[h].strip() or lines[h].lstrip().startswith("#")):
        h += 1
    if h >= len(lines):
        raise InputError(p, None, "empty axis log")
    header = [c.strip().lower() for c in lines[h].split(",")]
    need = ("t_s", "k", "line", "x_ref", "y_ref", "x_act", "y_act")
    missing = [c for c in need if c not in header]
    if missing:
        raise InputError(p, h + 1, f"axis log header lacks {', '.join(missing)} (expected {','.join(AXIS_LOG_HEADER)})")
    col = {name: i for i, name in enumerate(header)}
    want = [c for c in AXIS_LOG_HEADER if c in col]
    body = lines[h + 1:]
    first = h + 2  # file line number of body[0]
    if not body:
        raise InputError(p, None, "axis log has a header but no samples")
    try:
        arr = np.loadtxt(io.StringIO("\n".join(body)), delimiter=",", usecols=[col[c] for c in want], ndmin=2)
    except ValueError:
        arr = None
    if arr is None or arr.shape[0] != len(body):
        _find_bad_row(p, body, [col[c] for c in want], len(header), first)
        raise InputError(p, None, "axis log could not be read")  # pragma: no cover
    data = {c: arr[:, i] for i, c in enumerate(want)}
    finite = np.isfinite(arr)
    if not finite.all():
        row = int(np.flatnonzero(~finite.all(axis=1))[0])
        bad_col = want[int(np.flatnonzero(~finite[row])[0])]
        raise InputError(p, row + first, f"{bad_col} is not a finite number")
    t = data["t_s"]
    _check_time(p, t, np.arange(first, first + t.shape[0]), max_gap_periods)
    n = t.shape[0]
    nan = np.full(n, math.nan)
    ref = np.column_stack([data["x_ref"], data["y_ref"], data.get("z_ref", nan)])
    act = np.column_stack([data["x_act"], data["y_act"], data.get("z_act", nan)])
    return AxisLog(t, data["k"].astype(np.int64), data["line"].astype(np.int64), ref, act)


def _check_time(p: Path, t: NDArray[np.float64], rowline: NDArray[np.int64], max_gap_periods: float) -> None:
    """Refuse time that does not increase or has a gap (``rowline``: file line of each sample)."""
    dt = np.diff(t)
    if not dt.size:
        return
    if np.any(dt <= 0):
        row = int(np.flatnonzero(dt <= 0)[0])
        raise InputError(p, int(rowline[row + 1]), f"time does not increase ({t[row]:.6f} s then {t[row + 1]:.6f} s)")
    period = float(np.median(dt))
    gap = dt > max_gap_periods * period
    if np.any(gap):
        row = int(np.flatnonzero(gap)[0])
        raise InputError(
            p, int(rowline[row + 1]), f"gap of {dt[row] * 1e3:.3f} ms in the log (sample period {period * 1e3:.3f} ms)"
        )


def _find_bad_row(p: Path, body: list[str], cols: list[int], ncols: int, first: int = 2) -> None:
    """Raise the error for the first malformed row (slow path, only on bad input; ``first``: line of body[0])."""
    for i, row in enumerate(body):
        cells = row.split(",")
        if not row.strip():
            raise InputError(p, i + first, "empty line in the axis log")
        if len(cells) < ncols:
            raise InputError(p, i + first, f"expected {ncols} columns, got {len(cells)} (truncated line?)")
        for c in cols:
            try:
                float(cells[c])
            except ValueError:
                raise InputError(p, i + first, f"{cells[c].strip()!r} is not a number") from None


# ---------------------------------------------------------------------------
# LinuxCNC halsampler logs
# ---------------------------------------------------------------------------

__all__ += ["HALSAMPLER_COLUMNS", "commands_from_lines", "read_halsampler"]

#: Column order of the ilcnc LinuxCNC simulation (configs/linuxcnc-sim/sim.hal,
#: ``halsampler -t``): sample number, ``motion.program-line``, commanded X Y Z
#: (``joint.N.motor-pos-cmd``), actual X Y Z (``joint.N.motor-pos-fb``).
HALSAMPLER_COLUMNS: tuple[str, ...] = ("n", "line", "x_ref", "y_ref", "z_ref", "x_act", "y_act", "z_act")

_HALSAMPLER_NAMES = ("n", "line", "x_ref", "y_ref", "z_ref", "x_act", "y_act", "z_act")


def _halsampler_column_map(path: Path, columns: object) -> dict[str, int]:
    """Normalise ``columns`` (names in file order, or name -> 0-based column) to name -> column."""
    if isinstance(columns, str):
        columns = [c.strip() for c in columns.replace(",", " ").split()]
    if isinstance(columns, dict):
        cmap = {str(k).lower(): int(v) for k, v in columns.items()}
    else:
        try:
            names = list(columns)  # type: ignore[call-overload]
        except TypeError:
            raise InputError(
                None, None, f"halsampler columns must be names in file order or a name -> column map, got {columns!r}"
            ) from None
        cmap = {}
        for i, name in enumerate(names):
            if name is None or str(name).strip() in ("", "-", "_"):
                continue
            key = str(name).strip().lower()
            if key in cmap:
                raise InputError(None, None, f"halsampler column {key!r} given twice")
            cmap[key] = i
    unknown = sorted(set(cmap) - set(_HALSAMPLER_NAMES))
    if unknown:
        known = ", ".join(_HALSAMPLER_NAMES)
        raise InputError(None, None, f"unknown halsampler column name(s) {', '.join(unknown)} (known: {known})")
    missing = [c for c in ("x_ref", "y_ref", "x_act", "y_act") if c not in cmap]
    if missing:
        raise InputError(None, None, f"halsampler column map lacks {', '.join(missing)}")
    if any(v < 0 for v in cmap.values()):
        raise InputError(None, None, "halsampler column indices must be >= 0")
    return cmap


def read_halsampler(
    path: str | Path,
    *,
    columns: object = HALSAMPLER_COLUMNS,
    period_s: float = 1e-3,
    align: bool = True,
    tail_s: float | None = None,
) -> AxisLog:
    """Read a LinuxCNC ``halsampler`` log (whitespace columns, no header) as an axis log.

    Parameters
    ----------
    path : str or Path
        The file ``halsampler [-t] FILE`` wrote: one line per servo cycle,
        ``overrun`` lines where the FIFO overflowed (skipped; a gap in the
        sample numbers is an error).
    columns : sequence of names, or dict name -> 0-based column, or "n line x_ref ..."
        What each column holds. Names: ``n`` (sample number, ``halsampler -t``),
        ``line`` (``motion.program-line``), ``x_ref y_ref z_ref`` (commanded,
        mm), ``x_act y_act z_act`` (actual, mm); ``None``/``"-"`` skips a
        column. ``x_ref y_ref x_act y_act`` are required. Default
        :data:`HALSAMPLER_COLUMNS` (the ilcnc simulation).
    period_s : float
        Servo (sampling) period in s: halsampler has no time stamps, time is
        sample number x period. For a time-scaled simulation pass the
        unscaled period (every cycle is the same, so the log is in real time).
    align : bool
        Start the log at the first sample with a non-zero program line
        (``t_s = 0`` there; the idle samples before the program are dropped).
        Without a ``line`` column: at the first change of the commanded position.
    tail_s : float, optional
        Keep only this long after the last sample with a non-zero program line
        (the settle tail); default: everything.

    Returns
    -------
    AxisLog
        ``k`` is -1 everywhere (map lines to commands with
        :func:`commands_from_lines`); ``line`` after the first program line is
        forward-filled, so the settle tail (``motion.program-line`` drops to 0
        as soon as the *commanded* motion ends, while the axes still lag) and
        any other 0 inside the run belong to the last block that ran.

    Raises
    ------
    InputError
        Empty file, a bad number or too few columns (with its line), lost
        samples (a jump in the sample numbers), or no program line at all.
    """
    p = Path(path)
    if not (period_s > 0 and math.isfinite(period_s)):
        raise InputError(None, None, f"halsampler period must be a positive number of seconds, got {period_s!r}")
    cmap = _halsampler_column_map(p, columns)
    ncols = max(cmap.values()) + 1
    text = read_bytes(p).decode("utf-8", errors="replace")
    raw = text.splitlines()
    rows: list[str] = []
    rowline: list[int] = []
    for i, r in enumerate(raw):
        s = r.strip()
        if not s or s == "overrun":
            continue
        rows.append(s)
        rowline.append(i + 1)
    if not rows:
        raise InputError(p, None, "empty halsampler log (no samples)")
    # halsampler killed in mid-write may leave a short last line: drop it
    if len(rows[-1].split()) < ncols and len(rows) > 1:
        rows.pop()
        rowline.pop()
    want = sorted(cmap.items(), key=lambda kv: kv[1])
    usecols = [c for _, c in want]
    try:
        arr = np.loadtxt(io.StringIO("\n".join(rows)), usecols=usecols, ndmin=2, dtype=np.float64)
    except (ValueError, IndexError):
        arr = None
    if arr is None or arr.shape[0] != len(rows):
        for r, ln in zip(rows, rowline, strict=True):
            cells = r.split()
            if len(cells) < ncols:
                raise InputError(p, ln, f"expected at least {ncols} columns, got {len(cells)}")
            for c in usecols:
                try:
                    float(cells[c])
                except ValueError:
                    raise InputError(p, ln, f"{cells[c]!r} is not a number") from None
        raise InputError(p, None, "halsampler log could not be read")  # pragma: no cover
    data = {name: arr[:, j] for j, (name, _) in enumerate(want)}
    finite = np.isfinite(arr)
    if not finite.all():
        r = int(np.flatnonzero(~finite.all(axis=1))[0])
        raise InputError(p, rowline[r], "not a finite number")
    n_rows = arr.shape[0]
    if "n" in data:
        num = data["n"].astype(np.int64)
        step = np.diff(num)
        bad = np.flatnonzero(step != 1)
        if bad.size:
            r = int(bad[0])
            if step[r] > 1:
                problem = f"{int(step[r]) - 1} samples lost (sample number jumps from {num[r]} to {num[r + 1]}: FIFO overrun)"
            else:
                problem = f"sample numbers do not increase ({num[r]} then {num[r + 1]})"
            raise InputError(p, rowline[r + 1], problem)
    else:
        num = np.arange(n_rows, dtype=np.int64)
    if "line" in data:
        line = data["line"].astype(np.int64)
        active = np.flatnonzero(line != 0)
        if active.size == 0:
            raise InputError(p, None, "no sample has a non-zero program line: the program did not run (or wrong line column)")
        first, last = int(active[0]), int(active[-1])
    else:
        line = np.zeros(n_rows, dtype=np.int64)
        ref_xy = np.column_stack([data["x_ref"], data["y_ref"], data.get("z_ref", np.zeros(n_rows))])
        moved = np.flatnonzero(np.any(ref_xy != ref_xy[0], axis=1))
        if moved.size == 0:
            raise InputError(p, None, "the commanded position never changes: nothing ran")
        first = int(moved[0])
        moving = np.flatnonzero(np.any(np.diff(ref_xy, axis=0) != 0, axis=1))
        last = int(moving[-1]) + 1
    start = first if align else 0
    stop = n_rows
    if tail_s is not None:
        stop = min(n_rows, last + 1 + max(0, round(tail_s / period_s)))
    sl = slice(start, stop)
    if "line" in data:
        seg = line[sl].copy()
        nz = seg != 0
        idx = np.where(nz, np.arange(seg.shape[0]), -1)
        np.maximum.accumulate(idx, out=idx)
        seg = np.where(idx >= 0, seg[np.maximum(idx, 0)], 0)
        line = seg
    else:
        line = line[sl]
    t = (num[sl] - num[first if align else 0]).astype(np.float64) * period_s
    n = t.shape[0]
    nan = np.full(n, math.nan)
    ref = np.column_stack([data["x_ref"][sl], data["y_ref"][sl], data["z_ref"][sl] if "z_ref" in data else nan])
    act = np.column_stack([data["x_act"][sl], data["y_act"][sl], data["z_act"][sl] if "z_act" in data else nan])
    return AxisLog(t, np.full(n, -1, dtype=np.int64), line.astype(np.int64), ref, act)


def commands_from_lines(line: NDArray[np.int64], program: object) -> NDArray[np.int64]:
    """Command index k for each sample's source line (-1 where the block is not a G01 command).

    See :func:`moves_from_lines` for how samples are matched to moves.
    """
    m = moves_from_lines(line, program)
    mcmd = np.asarray(program.moves.command, dtype=np.int64)  # type: ignore[attr-defined]
    return np.where(m >= 0, mcmd[np.maximum(m, 0)], -1)


def moves_from_lines(line: NDArray[np.int64], program: object) -> NDArray[np.int64]:
    """Move index for each sample's source line (-1 where no move is on that line).

    Parameters
    ----------
    line : int array (N,)
        Source line per sample (e.g. :attr:`AxisLog.line` of :func:`read_halsampler`).
    program : ilcnc.program.model.Program
        The program that ran; its ``moves.line`` / ``moves.command`` give the
        line of every move and its command index.

    Notes
    -----
    The samples are walked in order and each run of equal lines is matched
    to the next move (in execution order) on that line, so a line executed
    several times (loops, subprograms) gets the command index of each pass.
    A line that is not found further on (a block without motion, a sample
    order the table does not have) maps to its first move on that line, or -1.
    Blocks that never show up in the log (short blocks blended away) are simply
    skipped.
    """
    ln = np.asarray(line, dtype=np.int64)
    moves = program.moves  # type: ignore[attr-defined]
    mline = np.asarray(moves.line, dtype=np.int64)
    out = np.full(ln.shape[0], -1, dtype=np.int64)
    if ln.size == 0 or mline.size == 0:
        return out
    order = np.argsort(mline, kind="stable")  # moves grouped by line, execution order inside a group
    sorted_lines = mline[order]
    change = np.flatnonzero(np.diff(ln)) + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [ln.shape[0]]))
    pos = -1  # index (in execution order) of the move matched last
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        value = int(ln[s])
        if value <= 0:
            continue
        lo = int(np.searchsorted(sorted_lines, value, side="left"))
        hi = int(np.searchsorted(sorted_lines, value, side="right"))
        if lo == hi:
            continue
        cand = order[lo:hi]  # move indices on this line, increasing
        j = int(np.searchsorted(cand, pos, side="right"))
        if j < cand.shape[0]:
            m = int(cand[j])
            pos = m
        else:
            m = int(cand[0])
        out[s:e] = m
    return out


# ---------------------------------------------------------------------------
# Heidenhain TNCscope CSV exports
# ---------------------------------------------------------------------------

__all__ += ["TNCSCOPE_COLUMNS", "read_tncscope"]

#: Signals :func:`read_tncscope` looks for (the keys its ``columns`` argument accepts):
#: time, NC block number, nominal X Y Z, actual X Y Z.
TNCSCOPE_COLUMNS: tuple[str, ...] = ("t_s", "line", "x_ref", "y_ref", "z_ref", "x_act", "y_act", "z_act")

_TIME_UNITS = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "msec": 1e-3, "µs": 1e-6, "us": 1e-6}
_LENGTH_UNITS = {"mm": 1.0, "µm": 1e-3, "um": 1e-3, "nm": 1e-6, "m": 1e3, "inch": 25.4, "in": 25.4, '"': 25.4}
_RATE_UNITS = {"hz": 1.0, "khz": 1e3}
_REQUIRED = ("x_ref", "y_ref", "x_act", "y_act")
_HEADER_SCAN_LINES = 500  # the header must be within the first lines of the file
_NOM_WORDS = ("nominal", "nom", "soll", "cmd", "command", "ref", "setpoint", "target", "demand")
_ACT_WORDS = ("actual", "act", "ist", "pos", "feedback", "fb", "meas", "real")
_NOT_POSITION = frozenset(
    "v a i j f vel velocity speed feed acc accel acceleration jerk ruck current strom error fehler diff differenz "
    "abweichung following lag torque moment dev deviation temp temperature temperatur power leistung load".split()
)
_NOT_POSITION_PREFIX = ("schlepp", "geschw", "beschl", "vorschub", "veloc", "accel")
_TOKEN_RE = re.compile(r"[a-z0-9äöüßµ]+")
_KIND_WORDS = "nominal|nom|soll|ist|actual|act|ref|cmd|pos"
_AXIS_WORD_RE = re.compile(rf"([xyz])({_KIND_WORDS})|({_KIND_WORDS})([xyz])")
_BRACKET_UNIT_RE = re.compile(r"^(?P<name>.*?)\s*[\[(](?P<unit>[^\])]*)[\])]\s*$")
_SUFFIX_UNIT_RE = re.compile(r"^(?P<name>.*?)(?:_|/|\s+in\s+)(?P<unit>[a-zµμ\"]+)$", re.IGNORECASE)
_SAMPLING_RE = re.compile(
    r"(?:sampling|sample|abtast)[\s_-]*(?P<kind>time|period|interval|intervall|zeit|periode|rate|frequency|frequenz)?",
    re.IGNORECASE,
)
_NUMBER_RE = re.compile(r"[-+]?(?:\d+(?:[.,]\d+)?|[.,]\d+)(?:[eE][-+]?\d+)?")
_BLOCK_RE = re.compile(r"^[Nn]?\s*([-+]?\d+)(?:\.0*)?$")
_END_MARKERS = frozenset({"eof", "end", "ende", "end of data"})


def _decode_text(raw: bytes) -> str:
    """Text of an exported file: UTF-16 (BOM or NUL bytes), UTF-8 (BOM stripped), else Windows-1252."""
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16", errors="replace")
    if len(raw) >= 4 and raw[1::2].count(0) > len(raw) // 4:
        return raw.decode("utf-16-le", errors="replace")
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("cp1252", errors="replace")


def _norm_unit(unit: str) -> str:
    """Lower-case unit without spaces; Greek mu and a mangled micro sign become ``µ``."""
    u = unit.strip().lower().replace("μ", "µ").replace(" ", "")
    if len(u) == 2 and u[0] in "\ufffd?" and u[1] in "ms":
        u = "µ" + u[1]
    return u


def _split_unit(cell: str) -> tuple[str, str | None]:
    """``"Time [ms]"`` -> ``("Time", "ms")``; also ``(ms)``, ``_ms``, ``/ms`` and `` in ms``."""
    cell = cell.strip().strip('"').strip()
    m = _BRACKET_UNIT_RE.match(cell)
    if m:
        unit = _norm_unit(m["unit"])
        known = unit in _TIME_UNITS or unit in _LENGTH_UNITS or unit in _RATE_UNITS
        if cell.endswith("]") or known or "/" in unit or len(unit) <= 3:  # "(interpolator)" is no unit
            return m["name"].strip(), unit
    m = _SUFFIX_UNIT_RE.match(cell)
    if m and _norm_unit(m["unit"]) in (_TIME_UNITS.keys() | _LENGTH_UNITS.keys()):
        return m["name"].strip(), _norm_unit(m["unit"])
    return cell, None


def _norm_text(text: str) -> str:
    return " ".join(text.strip().strip('"').split()).casefold()


def _classify_cell(cell: str) -> tuple[str, int] | None:
    """The signal a header cell names, as (role, rank): rank orders block-number candidates (lower first)."""
    name, unit = _split_unit(cell)
    raw_tokens = _TOKEN_RE.findall(name.lower())
    if not raw_tokens:
        return None
    tokens: list[str] = []
    for tok in raw_tokens:  # split compounds such as "xsoll" / "istx"
        m = _AXIS_WORD_RE.fullmatch(tok)
        tokens.extend([g for g in m.groups() if g] if m else [tok])
    axes = {t for t in tokens if t in ("x", "y", "z")}
    words = [t for t in tokens if t not in ("x", "y", "z")]
    is_length = unit is None or unit in _LENGTH_UNITS
    joined = " ".join(tokens)
    if not axes and (unit is None or unit in ("", "-")):
        if re.search(r"\b(block|satz|zeile|line|lines)|programline|programmzeile", joined) or joined in ("n", "nr"):
            numbered = re.search(r"\b(number|nummer|nr|no)\b|satznummer|satznr|zeilennummer|blocknumber|^n$", joined)
            return "line", 0 if numbered else 1
    if not axes and any(t in ("t", "time", "zeit", "timestamp", "zeitstempel", "zeitachse") for t in tokens):
        return "t_s", 0  # an unknown unit is refused later, rather than the column ignored
    if len(axes) != 1 or not is_length:
        return None
    if any(t in _NOT_POSITION or t.startswith(_NOT_POSITION_PREFIX) for t in words):
        return None
    axis = next(iter(axes))
    if any(t.startswith(_NOM_WORDS) or "soll" in t for t in words):
        return f"{axis}_ref", 0
    if any(t.startswith(_ACT_WORDS) or "istwert" in t or "istpos" in t or t.startswith("lageist") for t in words):
        return f"{axis}_act", 0
    return None


def _is_number(cell: str) -> bool:
    try:
        float(cell.strip().replace(",", "."))
    except ValueError:
        return False
    return True


def _sampling_period(line: str) -> float | None:
    """Sampling period in s from a metadata line such as ``Sampling time: 0.6 ms`` / ``Abtastzeit;0,6;ms``."""
    m = _SAMPLING_RE.search(line)
    if not m:
        return None
    rest = line[m.end():]
    num = _NUMBER_RE.search(rest)
    if not num:
        return None
    value = float(num.group().replace(",", "."))
    before = re.search(r"[\[(]([^\])]*)[\])]", rest[: num.start()])
    after = re.match(r"\s*[;,:\t=]?\s*[\[(]?\s*([a-zA-Zµμ]+)", rest[num.end():])
    unit = _norm_unit(after.group(1)) if after else (_norm_unit(before.group(1)) if before else None)
    kind = (m["kind"] or "").lower()
    if unit in _RATE_UNITS or (unit is None and kind in ("rate", "frequency", "frequenz")):
        f = value * _RATE_UNITS.get(unit or "hz", 1.0)
        return 1.0 / f if f > 0 else None
    period = value * _TIME_UNITS.get(unit, 1e-3) if unit in _TIME_UNITS or unit is None else None
    return period if period is not None and period > 0 and math.isfinite(period) else None


def _tncscope_overrides(columns: object) -> dict[str, str | int | None]:
    """Validate the ``columns`` argument of :func:`read_tncscope`."""
    if columns is None:
        return {}
    if not isinstance(columns, Mapping):
        raise InputError(None, None, f"TNCscope columns must map names to header texts or 0-based indices, got {columns!r}")
    out: dict[str, str | int | None] = {}
    for key, value in columns.items():
        name = str(key).strip().lower()
        if name not in TNCSCOPE_COLUMNS:
            raise InputError(None, None, f"unknown TNCscope column name {key!r} (known: {', '.join(TNCSCOPE_COLUMNS)})")
        if value is None or isinstance(value, str):
            out[name] = value
        elif isinstance(value, int) and not isinstance(value, bool) and value >= 0:
            out[name] = int(value)
        else:
            raise InputError(None, None, f"TNCscope column {name}: expected a header text or a 0-based index, got {value!r}")
    if (out.get("z_ref") is None) != (out.get("z_act") is None):
        raise InputError(None, None, "TNCscope columns must give both z_ref and z_act, or neither")
    return out


def _header_columns(cells: list[str], overrides: dict[str, str | int | None]) -> tuple[dict[str, int], list[int], list[str]]:
    """Roles found in a header row: (role -> column, block-number candidates in order, override texts not found)."""
    cols: dict[str, int] = {}
    line_cands: list[tuple[int, int]] = []
    for i, cell in enumerate(cells):
        found = _classify_cell(cell)
        if found is None:
            continue
        role, rank = found
        if role == "line":
            line_cands.append((rank, i))
        elif role not in cols:
            cols[role] = i
    lines = [i for _, i in sorted(line_cands)]
    not_found: list[str] = []
    normed = [_norm_text(c) for c in cells]
    bare = [_norm_text(_split_unit(c)[0]) for c in cells]
    for role, value in overrides.items():
        if role == "line":
            lines = []
        if value is None:
            cols.pop(role, None)
            continue
        if isinstance(value, int):
            idx: int | None = value
        else:
            want = _norm_text(value)
            idx = normed.index(want) if want in normed else (bare.index(want) if want in bare else None)
        if idx is None:
            not_found.append(str(value))
            cols.pop(role, None)
        else:
            cols[role] = idx
    if ("z_ref" in cols) != ("z_act" in cols):
        cols.pop("z_ref", None)
        cols.pop("z_act", None)
    return cols, lines, not_found


def _describe(cells: list[str], cols: dict[str, int]) -> str:
    return ", ".join(f"{r}={cells[i].strip()!r}" if i < len(cells) else f"{r}=column {i}" for r, i in cols.items()) or "nothing"


def _tncscope_slow(
    p: Path,
    lines: list[str],
    rows: list[list[str]],
    rowline: list[int],
    sep: str,
    cols: dict[str, int],
    num_roles: list[str],
    header_name: dict[str, str],
    width: int | None,
) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.int64]]:
    """Numbers and block numbers of the data rows, cell by cell, naming the line and column of the first bad one."""

    def as_written(j: int, c: int) -> str:
        """Cell c of data row j as written in the file."""
        return next(csv.reader([lines[rowline[j] - 1]], delimiter=sep, skipinitialspace=True))[c].strip()

    ncols = max(cols.values()) + 1
    for cells_, ln in zip(rows, rowline, strict=True):
        if len(cells_) < ncols:
            raise InputError(p, ln, f"expected at least {ncols} columns, got {len(cells_)} (truncated line?)")
        if width is not None and len(cells_) > width and any(c.strip() for c in cells_[width:]):
            raise InputError(p, ln, f"{len(cells_)} columns but the header has {width} (a stray separator?)")
    data: dict[str, NDArray[np.float64]] = {}
    for r in num_roles:
        c = cols[r]
        raw = [row[c] for row in rows]
        try:
            data[r] = np.array(raw, dtype=np.float64)
        except ValueError:
            for j, v in enumerate(raw):
                try:
                    float(v)
                except ValueError:
                    what = "is empty" if not v.strip() else f"value {as_written(j, c)!r} is not a number"
                    raise InputError(p, rowline[j], f"{header_name[r]} {what}") from None
            raise  # pragma: no cover
    bad_rows = [(int(np.flatnonzero(~np.isfinite(a))[0]), r) for r, a in data.items() if not np.isfinite(a).all()]
    if bad_rows:
        j, r = min(bad_rows, key=lambda x: (x[0], cols[x[1]]))
        raise InputError(p, rowline[j], f"{header_name[r]} is not a finite number ({as_written(j, cols[r])!r})")
    block = np.zeros(len(rows), dtype=np.int64)
    if "line" in cols:
        c = cols["line"]
        for j, row in enumerate(rows):
            v = row[c].strip()
            if not v:
                continue  # no block: 0
            m = _BLOCK_RE.match(v)
            if not m:
                raise InputError(p, rowline[j], f"{header_name['line']}: block number {as_written(j, c)!r} is not an integer")
            block[j] = int(m.group(1))
    return data, block


def read_tncscope(
    path: str | Path,
    *,
    columns: Mapping[str, str | int | None] | None = None,
    max_gap_periods: float = 1.5,
    length_unit: str | None = None,
) -> AxisLog:
    """Read a Heidenhain TNCscope CSV export (or a similar scope export) as an axis log.

    Parameters
    ----------
    path : str or Path
        The export: any metadata lines (e.g. ``Sampling time: 0.6 ms`` /
        ``Abtastzeit;0,6;ms``), a header row naming the signals, optionally a
        row of units, then one row per sample. Separator ``;``, tab or ``,``
        (the one with which a header row is found); with ``;`` or tab a
        decimal comma is accepted. UTF-8, UTF-16 and Windows-1252 text.
    columns : mapping, optional
        Overrides the detection: keys from :data:`TNCSCOPE_COLUMNS` (``t_s``,
        ``line``, ``x_ref`` ... ``z_act``), values a header text (compared
        case-insensitively, with or without its unit) or a 0-based column
        index, or ``None`` for "not in the file". With indices for all
        needed columns the file may have no header row at all.
    max_gap_periods : float
        Largest allowed time step, in median sample periods.
    length_unit : {None, "mm", "inch", "µm", ...}, optional
        Unit of position columns whose header names none (default mm). A
        header that names a different unit is an error.

    Returns
    -------
    AxisLog
        ``t_s`` in s (as recorded: not shifted to start at 0; built from the
        sampling time when there is no time column); ``ref_mm`` / ``act_mm``
        in mm (Z NaN without both Z signals); ``line`` the NC block number
        (0 without such a column or where a cell is empty); ``k`` is -1
        everywhere (map lines to commands with :func:`commands_from_lines`).

    Notes
    -----
    Header detection (case-insensitive, English and German): time
    ``Time``/``t``/``Zeit``; nominal position: an axis letter X/Y/Z and one of
    nominal, nom, soll, cmd, ref, setpoint; actual position: an axis letter
    and one of actual, act, ist, pos, feedback. Velocity, acceleration,
    current and following-error signals (``v act X``, ``X following error``,
    ``Schleppfehler X``, a unit such as ``mm/min``) are not positions. Units
    come from brackets (``Time [ms]``, ``Pos.Soll X [µm]``) or a unit row:
    time s, ms, µs/us (none: ms, or whichever matches the sampling time);
    length mm, µm/um, nm, m, inch/in.

    Raises
    ------
    InputError
        No header row with the needed signals (the message lists what the
        best candidate row has), no time column and no sampling-time line, an
        unknown unit, a short row, a bad or non-finite number (naming the line
        and the column), time not increasing, or a gap longer than
        ``max_gap_periods`` sample periods. Line numbers are 1-based file lines.
    """
    p = Path(path)
    overrides = _tncscope_overrides(columns)
    if length_unit is not None and _norm_unit(length_unit) not in _LENGTH_UNITS:
        raise InputError(None, None, f"unknown length unit {length_unit!r} (known: {', '.join(_LENGTH_UNITS)})")
    default_len = _norm_unit(length_unit) if length_unit is not None else None
    text = _decode_text(read_bytes(p))
    lines = text.splitlines()
    if not any(ln.strip() for ln in lines):
        raise InputError(p, None, "empty TNCscope export")
    head = lines[:_HEADER_SCAN_LINES]
    index_only = all(isinstance(overrides.get(r), int) for r in _REQUIRED) and (
        isinstance(overrides.get("t_s"), int) or ("t_s" in overrides and overrides["t_s"] is None)
    )
    best: tuple[int, int, list[str], dict[str, int], list[str]] | None = None  # score, line index, cells, roles, lacking
    found: tuple[str, int, list[str], dict[str, int], list[int], float | None, bool] | None = None
    for sep in (";", "\t", ","):
        period: float | None = None
        scan = csv.reader(head, delimiter=sep, skipinitialspace=True)
        for cells in scan:
            idx = scan.line_num - 1
            if not any(c.strip() for c in cells):
                continue
            cols, line_cands, not_found = _header_columns(cells, overrides)
            used = list(cols.values())
            numeric_row = bool(used) and all(i < len(cells) and _is_number(cells[i]) for i in used)
            if numeric_row and not index_only:
                continue  # a data row before any header (wrong separator, or no header)
            missing = [r for r in _REQUIRED if r not in cols] + [f"column {t!r}" for t in not_found]
            if any(i >= len(cells) for i in used):
                missing.append(f"column {max(used) + 1} (the line has {len(cells)})")
            if not missing and ("t_s" in cols or period is not None):
                found = (sep, idx, cells, cols, line_cands, period, numeric_row)
                break
            if not missing:
                missing = ["time (no time column and no sampling-time line before the header)"]
            if best is None or len(cols) > best[0]:
                best = (len(cols), idx, cells, cols, missing)
            if period is None:
                period = _sampling_period(head[idx])
        if found is not None:
            break
    if found is None:
        need = "time (or a sampling-time line), X/Y nominal and X/Y actual position columns"
        if best is None or best[0] == 0:
            raise InputError(p, None, f"no TNCscope header row found: need {need}; no line names any of them")
        _, idx, cells, cols, missing = best
        has = _describe(cells, cols)
        raise InputError(p, idx + 1, f"no TNCscope header row with {need}: this line has {has}; lacks {', '.join(missing)}")
    sep, h, cells, cols, line_cands, period, headerless = found
    units: dict[str, str | None] = {r: None if headerless else _split_unit(cells[i])[1] for r, i in cols.items()}
    first_line = h + 1 if headerless else h + 2
    body = lines[first_line - 1:]
    if sep != ",":  # decimal comma (the original text is quoted in error messages)
        body = [ln.replace(",", ".") for ln in body]
    quoted = any('"' in ln for ln in body)
    texts: list[str] = []  # the non-blank data lines (unquoted files only)
    rows: list[list[str]] = []
    rowline: list[int] = []
    if quoted:
        reader = csv.reader(body, delimiter=sep, skipinitialspace=True)
        for cells_ in reader:
            if any(c.strip() for c in cells_):
                rows.append(cells_)
                rowline.append(first_line + reader.line_num - 1)
    else:
        blank = sep + " \t'"
        for j, ln in enumerate(body):
            if ln.strip(blank):
                texts.append(ln)
                rowline.append(first_line + j)

    def row(j: int) -> list[str]:
        return rows[j] if quoted else texts[j].split(sep)

    def drop(j: int) -> None:
        (rows if quoted else texts).pop(j)
        rowline.pop(j)

    while rowline and len([c for c in row(-1) if c.strip()]) == 1 and _norm_text(row(-1)[0]) in _END_MARKERS:
        drop(-1)
    # an optional row of units right under the header
    if rowline and not headerless and not any(i < len(row(0)) and _is_number(row(0)[i]) for i in cols.values()):
        top = row(0)
        unit_cells = {r: _norm_unit(top[i].strip().strip("[]()")) if i < len(top) else "" for r, i in cols.items()}
        if all(u == "" or u in _TIME_UNITS or u in _LENGTH_UNITS or u == "-" for u in unit_cells.values()):
            for r, u in unit_cells.items():
                if units.get(r) is None and u not in ("", "-"):
                    units[r] = u
            drop(0)
    if not rowline:
        raise InputError(p, None, "TNCscope export has a header but no samples")
    # the block-number column: the first candidate that holds numbers
    if "line" not in cols and line_cands:
        top = row(0)
        for i in line_cands:
            first = top[i].strip() if i < len(top) else ""
            if not first or _BLOCK_RE.match(first):
                cols["line"] = i
                break
    header_name = {r: f"column {i + 1}" if headerless else f"column {i + 1} ({cells[i].strip()!r})" for r, i in cols.items()}
    num_roles = [r for r in ("t_s", "x_ref", "y_ref", "z_ref", "x_act", "y_act", "z_act") if r in cols]
    n = len(rowline)
    width = len(cells)  # cells beyond the header's width shift the columns (a stray separator): refuse them
    data: dict[str, NDArray[np.float64]] = {}
    block = np.zeros(n, dtype=np.int64)
    fast = None
    if not quoted and (headerless or max(t.count(sep) for t in texts) < width):
        roles = [*num_roles, "line"] if "line" in cols else num_roles
        try:
            fast = np.loadtxt(io.StringIO("\n".join(texts)), delimiter=sep, usecols=[cols[r] for r in roles], ndmin=2)
        except (ValueError, IndexError):
            fast = None
        if fast is not None and (fast.shape[0] != n or not np.isfinite(fast).all()):
            fast = None
        if fast is not None and "line" in cols and not np.all(fast[:, -1] == np.round(fast[:, -1])):
            fast = None
    if fast is not None:
        data = {r: fast[:, j] for j, r in enumerate(num_roles)}
        if "line" in cols:
            block = fast[:, -1].astype(np.int64)
    else:
        data, block = _tncscope_slow(p, lines, [row(j) for j in range(n)], rowline, sep, cols, num_roles, header_name,
                                     width=None if headerless else width)
    # time in s
    if "t_s" in data:
        u = units.get("t_s")
        if u is None:
            scale = 1e-3
            if period is not None and n > 1:
                step = float(np.median(np.diff(data["t_s"])))
                if step > 0:
                    scale = min((1.0, 1e-3, 1e-6), key=lambda s: abs(math.log(step * s / period)))
        elif u in _TIME_UNITS:
            scale = _TIME_UNITS[u]
        else:
            raise InputError(p, h + 1, f"{header_name['t_s']}: unknown time unit {u!r} (known: {', '.join(_TIME_UNITS)})")
        t = data["t_s"] * scale
    else:
        assert period is not None
        t = np.arange(n, dtype=np.float64) * period
    _check_time(p, t, np.asarray(rowline, dtype=np.int64), max_gap_periods)
    pos: dict[str, NDArray[np.float64]] = {}
    for r in ("x_ref", "y_ref", "z_ref", "x_act", "y_act", "z_act"):
        if r not in data:
            continue
        u = units.get(r)
        if u is not None and u not in _LENGTH_UNITS:
            raise InputError(p, h + 1, f"{header_name[r]}: unknown length unit {u!r} (known: {', '.join(_LENGTH_UNITS)})")
        if u is not None and default_len is not None and _LENGTH_UNITS[u] != _LENGTH_UNITS[default_len]:
            raise InputError(p, h + 1, f"{header_name[r]} is in {u}, but the positions were said to be in {default_len}")
        pos[r] = data[r] * _LENGTH_UNITS[u or default_len or "mm"]
    nan = np.full(n, math.nan)
    ref = np.column_stack([pos["x_ref"], pos["y_ref"], pos.get("z_ref", nan)])
    act = np.column_stack([pos["x_act"], pos["y_act"], pos.get("z_act", nan)])
    return AxisLog(t, np.full(n, -1, dtype=np.int64), block, ref, act)


# ---------------------------------------------------------------------------
# Measured points (probe / CMM results)
# ---------------------------------------------------------------------------

__all__ += ["MeasuredPoints", "read_points"]


@dataclass(slots=True)
class MeasuredPoints:
    """Measured deviations at commanded end points or at nominal positions.

    Attributes
    ----------
    k : ndarray (N,) int64 or None
        G01 command index of each point (``k,dx,dy,dz`` layout), else None.
    xyz_mm : ndarray (N, 3) or None
        Nominal position of each point, mm (``x,y,z,dx,dy,dz`` layout; Z NaN
        without a z column), else None.
    dev_mm : ndarray (N, 3)
        Deviation measured minus nominal, mm (dz 0 without a dz column).
    line : ndarray (N,) int64
        1-based file line of each point.
    """

    k: NDArray[np.int64] | None
    xyz_mm: NDArray[np.float64] | None
    dev_mm: NDArray[np.float64]
    line: NDArray[np.int64]

    @property
    def n_points(self) -> int:
        return int(self.dev_mm.shape[0])


def read_points(path: str | Path) -> MeasuredPoints:
    """Read a probe / measured-points CSV (DESIGN.md).

    Parameters
    ----------
    path : str or Path
        CSV with the header ``k,dx,dy,dz`` (deviation at the end point of G01
        command k) or ``x,y,z,dx,dy,dz`` (deviation at a nominal position),
        all mm; ``dz`` and ``z`` are optional (2-axis). Deviation is measured
        minus nominal, as a CMM reports it. Blank lines and lines starting
        with ``#`` are skipped; extra columns are ignored; names are
        case-insensitive and may carry a unit in brackets (``dx [µm]``:
        mm, µm/um, inch). Separator ``,`` (or ``;`` / tab when the header
        uses it; then a decimal comma is accepted).

    Returns
    -------
    MeasuredPoints

    Raises
    ------
    InputError
        Empty file or no points, a header without ``dx``/``dy`` or without
        ``k`` or ``x``/``y``, a short row, a bad or non-finite number, a
        negative or non-integer ``k``, or a ``k`` given twice (naming both
        lines). Line numbers are 1-based file lines.
    """
    p = Path(path)
    lines = _decode_text(read_bytes(p)).splitlines()
    content = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    if not content:
        raise InputError(p, None, "empty points file")
    hline, htext = content[0]
    sep = ";" if ";" in htext else ("\t" if "\t" in htext else ",")
    header = next(csv.reader([htext], delimiter=sep, skipinitialspace=True))
    col: dict[str, int] = {}
    scale: dict[str, float] = {}
    for i, cell in enumerate(header):
        name, unit = _split_unit(cell)
        name = name.lower()
        if name in ("k", "x", "y", "z", "dx", "dy", "dz") and name not in col:
            if unit is not None and unit not in _LENGTH_UNITS:
                raise InputError(p, hline, f"column {name}: unknown unit {unit!r} (known: {', '.join(_LENGTH_UNITS)})")
            col[name] = i
            scale[name] = _LENGTH_UNITS[unit or "mm"]
    missing = [c for c in ("dx", "dy") if c not in col]
    if "k" not in col:
        missing += [c for c in ("x", "y") if c not in col]
    if missing:
        found = ", ".join(col) or "none of them"
        raise InputError(
            p, hline, f"points header lacks {', '.join(missing)} (expected k,dx,dy,dz or x,y,z,dx,dy,dz; found {found})"
        )
    if not ("x" in col and "y" in col):
        col.pop("x", None)
        col.pop("y", None)
        col.pop("z", None)
    body = content[1:]
    if not body:
        raise InputError(p, None, "points file has a header but no points")
    ncols = max(col.values()) + 1
    n = len(body)
    vals = {c: np.empty(n) for c in col}
    rowline = np.array([ln for ln, _ in body], dtype=np.int64)
    for j, (ln, text) in enumerate(body):
        cells = next(csv.reader([text], delimiter=sep, skipinitialspace=True))
        if len(cells) < ncols:
            raise InputError(p, ln, f"expected {ncols} columns, got {len(cells)} (truncated line?)")
        for c, i in col.items():
            v = cells[i].strip()
            if sep != ",":
                v = v.replace(",", ".")
            try:
                x = float(v)
            except ValueError:
                raise InputError(p, ln, f"{c}: {'empty value' if not v else repr(v) + ' is not a number'}") from None
            if not math.isfinite(x):
                raise InputError(p, ln, f"{c} is not a finite number ({v!r})")
            vals[c][j] = x
    k = None
    if "k" in col:
        kf = vals["k"]
        bad = np.flatnonzero((kf < 0) | (kf != np.round(kf)))
        if bad.size:
            j = int(bad[0])
            raise InputError(p, int(rowline[j]), f"k must be a command index (integer >= 0), got {kf[j]:g}")
        k = kf.astype(np.int64)
        seen: dict[int, int] = {}
        for kk, ln in zip(k.tolist(), rowline.tolist(), strict=True):
            if kk in seen:
                raise InputError(p, ln, f"duplicate k={kk} (first on line {seen[kk]})")
            seen[kk] = ln
    dz = vals["dz"] * scale["dz"] if "dz" in col else np.zeros(n)
    dev = np.column_stack([vals["dx"] * scale["dx"], vals["dy"] * scale["dy"], dz])
    xyz = None
    if "x" in col:
        z = vals["z"] * scale["z"] if "z" in col else np.full(n, math.nan)
        xyz = np.column_stack([vals["x"] * scale["x"], vals["y"] * scale["y"], z])
    return MeasuredPoints(k, xyz, dev, rowline)


# ---------------------------------------------------------------------------
# One entry point for every log format
# ---------------------------------------------------------------------------

__all__ += ["LOG_FORMATS", "detect_log_format", "read_log"]

#: Values of the ``fmt`` argument of :func:`read_log`.
LOG_FORMATS: tuple[str, ...] = ("auto", "ilcnc", "halsampler", "tncscope")
_LOG_UNITS = ("mm", "inch")


def _head_lines(p: Path, size: int = 65536) -> list[str]:
    """The first lines of a file (its first ``size`` bytes), decoded like an export."""
    try:
        with p.open("rb") as fh:
            raw = fh.read(size)
    except OSError:
        read_bytes(p)  # raises the one-line InputError
        raise
    return _decode_text(raw).splitlines()


def detect_log_format(path: str | Path) -> str:
    """Which reader a log needs: ``"ilcnc"``, ``"halsampler"`` or ``"tncscope"``.

    Parameters
    ----------
    path : str or Path
        The log.

    Returns
    -------
    str
        ``"ilcnc"`` when the first line that is neither blank nor a ``#``
        comment starts with ``t_s``; ``"halsampler"`` when the first non-empty
        line is whitespace-separated numbers (or ``overrun``); else
        ``"tncscope"``.

    Raises
    ------
    InputError
        The file cannot be read or is empty.
    """
    p = Path(path)
    lines = [ln for ln in _head_lines(p) if ln.strip()]
    if not lines:
        raise InputError(p, None, "empty log file")
    for ln in lines:
        if ln.lstrip().startswith("#"):
            continue
        if ln.split(",")[0].strip().strip('"').lower().startswith("t_s"):
            return "ilcnc"
        break
    first = lines[0].split()
    if first == ["overrun"] or all(_is_plain_number(c) for c in first):
        return "halsampler"
    return "tncscope"


def _is_plain_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def read_log(
    path: str | Path,
    *,
    fmt: str = "auto",
    period_s: float = 1e-3,
    columns: object = None,
    units: str = "mm",
    offset: tuple[float, float, float] | None = None,
) -> AxisLog:
    """Read an axis log of any supported format.

    Parameters
    ----------
    path : str or Path
        The log.
    fmt : {"auto", "ilcnc", "halsampler", "tncscope"}
        Its format; ``"auto"`` uses :func:`detect_log_format`.
    period_s : float
        Sampling period in s for halsampler logs (they have no time stamps);
        not used by the other formats (ilcnc logs have ``t_s``, TNCscope
        exports a time column or a sampling-time line).
    columns : optional
        Column map for halsampler (see :func:`read_halsampler`; default
        :data:`HALSAMPLER_COLUMNS`) or TNCscope (see :func:`read_tncscope`)
        logs; an ilcnc log has fixed column names and refuses one.
    units : {"mm", "inch"}
        Unit the positions were recorded in; ``"inch"`` multiplies reference
        and actual positions by 25.4. For a TNCscope export it is the unit of
        position columns whose header names none (header units always apply).
    offset : (x, y, z), optional
        Work offset to subtract from the commanded and actual positions, in
        ``units``: a log of machine coordinates (LinuxCNC's joint pins) brought
        into the program's coordinates (active G5x + G92 + tool length offset).

    Returns
    -------
    AxisLog
        Positions in mm, time in s.

    Raises
    ------
    ValueError
        Unknown ``fmt`` or ``units``.
    InputError
        Whatever the format's reader refuses, or ``columns`` for an ilcnc log.
    """
    if fmt not in LOG_FORMATS:
        raise ValueError(f"unknown log format {fmt!r} (known: {', '.join(LOG_FORMATS)})")
    if units not in _LOG_UNITS:
        raise ValueError(f"unknown log units {units!r} (known: {', '.join(_LOG_UNITS)})")
    p = Path(path)
    log = _read_any_log(p, fmt, period_s, columns, units)
    if offset is not None:
        off = np.asarray(offset, dtype=np.float64) * (25.4 if units == "inch" else 1.0)
        if off.shape != (3,) or not np.all(np.isfinite(off)):
            raise InputError(p, None, f"the work offset must be three finite numbers x, y, z, got {offset!r}")
        log.ref_mm = log.ref_mm - off
        log.act_mm = log.act_mm - off
    return log


def _read_any_log(p: Path, fmt: str, period_s: float, columns: object, units: str) -> AxisLog:
    """:func:`read_log` without the work offset."""
    kind = detect_log_format(p) if fmt == "auto" else fmt
    if kind == "tncscope":
        if isinstance(columns, str):
            raise InputError(p, None, "a TNCscope export names its signals in its header: the column names in file"
                                      " order apply only to halsampler logs")
        return read_tncscope(p, columns=columns, length_unit=None if units == "mm" else units)  # type: ignore[arg-type]
    if kind == "halsampler":
        log = read_halsampler(p, columns=HALSAMPLER_COLUMNS if columns is None else columns, period_s=period_s)
    else:
        if columns is not None:
            raise InputError(
                p, None, "an ilcnc axis log has fixed column names; a column map applies only to halsampler and TNCscope logs"
            )
        log = read_axis_log(p)
    if units == "inch":
        log.ref_mm = log.ref_mm * 25.4
        log.act_mm = log.act_mm * 25.4
    return log

"""Axis logs: ilcnc's own CSV (what ``simulate`` writes and ``learn --log`` reads).

Format (DESIGN.md): header ``t_s,k,line,x_ref,y_ref,z_ref,x_act,y_act,z_act``
(seconds, command index, source line, mm). Extra columns are ignored;
missing z columns mean a 2-axis log.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes, write_atomic

__all__ = ["AXIS_LOG_HEADER", "AxisLog", "format_axis_log", "read_axis_log", "write_axis_log"]

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

    Raises
    ------
    InputError
        Missing columns, a bad or non-finite number (with its line), time not
        increasing, or a gap longer than ``max_gap_periods`` sample periods.
    """
    p = Path(path)
    text = read_bytes(p).decode("utf-8", errors="replace")
    lines = text.splitlines()
    if not lines:
        raise InputError(p, None, "empty axis log")
    header = [h.strip().lower() for h in lines[0].split(",")]
    need = ("t_s", "k", "line", "x_ref", "y_ref", "x_act", "y_act")
    missing = [c for c in need if c not in header]
    if missing:
        raise InputError(p, 1, f"axis log header lacks {', '.join(missing)} (expected {','.join(AXIS_LOG_HEADER)})")
    col = {name: i for i, name in enumerate(header)}
    want = [c for c in AXIS_LOG_HEADER if c in col]
    body = lines[1:]
    if not body:
        raise InputError(p, None, "axis log has a header but no samples")
    try:
        arr = np.loadtxt(io.StringIO("\n".join(body)), delimiter=",", usecols=[col[c] for c in want], ndmin=2)
    except ValueError:
        arr = None
    if arr is None or arr.shape[0] != len(body):
        _find_bad_row(p, body, [col[c] for c in want], len(header))
        raise InputError(p, None, "axis log could not be read")  # pragma: no cover
    data = {c: arr[:, i] for i, c in enumerate(want)}
    finite = np.isfinite(arr)
    if not finite.all():
        row = int(np.flatnonzero(~finite.all(axis=1))[0])
        bad_col = want[int(np.flatnonzero(~finite[row])[0])]
        raise InputError(p, row + 2, f"{bad_col} is not a finite number")
    t = data["t_s"]
    dt = np.diff(t)
    if dt.size:
        if np.any(dt <= 0):
            row = int(np.flatnonzero(dt <= 0)[0])
            raise InputError(p, row + 3, f"time does not increase ({t[row]:.6f} s then {t[row + 1]:.6f} s)")
        period = float(np.median(dt))
        gap = dt > max_gap_periods * period
        if np.any(gap):
            row = int(np.flatnonzero(gap)[0])
            raise InputError(p, row + 3, f"gap of {dt[row] * 1e3:.3f} ms in the log (sample period {period * 1e3:.3f} ms)")
    n = t.shape[0]
    nan = np.full(n, math.nan)
    ref = np.column_stack([data["x_ref"], data["y_ref"], data.get("z_ref", nan)])
    act = np.column_stack([data["x_act"], data["y_act"], data.get("z_act", nan)])
    return AxisLog(t, data["k"].astype(np.int64), data["line"].astype(np.int64), ref, act)


def _find_bad_row(p: Path, body: list[str], cols: list[int], ncols: int) -> None:
    """Raise the error for the first malformed row (slow path, only on bad input)."""
    for i, row in enumerate(body):
        cells = row.split(",")
        if not row.strip():
            raise InputError(p, i + 2, "empty line in the axis log")
        if len(cells) < ncols:
            raise InputError(p, i + 2, f"expected {ncols} columns, got {len(cells)} (truncated line?)")
        for c in cols:
            try:
                float(cells[c])
            except ValueError:
                raise InputError(p, i + 2, f"{cells[c].strip()!r} is not a number") from None


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
    mcmd = np.asarray(moves.command, dtype=np.int64)
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
        out[s:e] = mcmd[m]
    return out

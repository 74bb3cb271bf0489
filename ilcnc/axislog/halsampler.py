"""LinuxCNC ``halsampler`` logs, and the program lines a log's samples ran.

``halsampler`` writes one whitespace-separated row per servo period with no
time column; :func:`read_halsampler` numbers the rows by the period and reads
the columns in :data:`HALSAMPLER_COLUMNS` order (or the user's). The
``motion.program-line`` column maps each sample to the program's commands and
moves (:func:`commands_from_lines`, :func:`moves_from_lines`).
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ilcnc.axislog.log import AxisLog
from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes

__all__ = ["HALSAMPLER_COLUMNS", "commands_from_lines", "halsampler_column_map", "moves_from_lines", "read_halsampler"]


# ---------------------------------------------------------------------------
# LinuxCNC halsampler logs
# ---------------------------------------------------------------------------


#: Column order of the ilcnc LinuxCNC simulation (configs/linuxcnc-sim/sim.hal,
#: ``halsampler -t``): sample number, ``motion.program-line``, commanded X Y Z
#: (``joint.N.motor-pos-cmd``), actual X Y Z (``joint.N.motor-pos-fb``).
HALSAMPLER_COLUMNS: tuple[str, ...] = ("n", "line", "x_ref", "y_ref", "z_ref", "x_act", "y_act", "z_act")

_HALSAMPLER_NAMES = ("n", "line", "x_ref", "y_ref", "z_ref", "x_act", "y_act", "z_act")


def halsampler_column_map(path: Path | None, columns: object) -> dict[str, int]:
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
    cmap = halsampler_column_map(p, columns)
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



"""The axis log: what a machine did, sample by sample, and ilcnc's own CSV of it.

:class:`AxisLog` holds a run's samples (time, command, source line, commanded
and actual X Y Z in mm) whatever recorded it. ilcnc's own axis-log CSV (what
``simulate`` writes and ``learn --log`` reads), DESIGN.md: optional ``#``
comment lines, then the header ``t_s,k,line,x_ref,y_ref,z_ref,x_act,y_act,z_act``
(seconds, command index, source line, mm). Extra columns are ignored; missing
z columns mean a 2-axis log. Other recorders are read into the same
:class:`AxisLog`: :mod:`ilcnc.axislog.halsampler` (LinuxCNC),
:mod:`ilcnc.axislog.tncscope` (Heidenhain); :func:`ilcnc.axislog.detect.read_log`
tells them apart. Exported text is decoded by :func:`decode_text`.
"""

from __future__ import annotations

import io
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import InputError
from ilcnc.fileio import open_input, write_atomic

__all__ = [
    "AXIS_LOG_HEADER", "AxisLog", "check_sample_times", "decode_text", "format_axis_log", "norm_unit",
    "read_axis_log", "write_axis_log"
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
    line_is_block_number : bool
        ``line`` holds the NC block numbers a control reports (a TNCscope export), not file lines: a Klartext
        program's block ``n`` is on the line :func:`ilcnc.program.heidenhain_lexer.block_number_lines` says.
    """

    t_s: NDArray[np.float64]
    k: NDArray[np.int64]
    line: NDArray[np.int64]
    ref_mm: NDArray[np.float64]
    act_mm: NDArray[np.float64]
    line_is_block_number: bool = False

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
    with open_input(p) as fh:
        # comments and blank lines, then the header
        h = 0  # file line number of the header
        header_text = None
        for raw in fh:
            h += 1
            line = raw.decode("utf-8", errors="replace")
            if h == 1:
                line = line.lstrip("\ufeff")
            if line.strip() and not line.lstrip().startswith("#"):
                header_text = line
                break
        if header_text is None:
            raise InputError(p, None, "empty axis log")
        header = [c.strip().lower() for c in header_text.split(",")]
        need = ("t_s", "k", "line", "x_ref", "y_ref", "x_act", "y_act")
        missing = [c for c in need if c not in header]
        if missing:
            raise InputError(p, h, f"axis log header lacks {', '.join(missing)} (expected {','.join(AXIS_LOG_HEADER)})")
        col = {name: i for i, name in enumerate(header)}
        want = [c for c in AXIS_LOG_HEADER if c in col]
        arr = _read_rows(p, fh, [col[c] for c in want], len(header), h + 1)
    first = h + 1  # file line number of the first sample
    data = {c: arr[:, i] for i, c in enumerate(want)}
    finite = np.isfinite(arr)
    if not finite.all():
        row = int(np.flatnonzero(~finite.all(axis=1))[0])
        bad_col = want[int(np.flatnonzero(~finite[row])[0])]
        raise InputError(p, row + first, f"{bad_col} is not a finite number")
    t = data["t_s"]
    check_sample_times(p, t, np.arange(first, first + t.shape[0]), max_gap_periods)
    n = t.shape[0]
    nan = np.full(n, math.nan)
    ref = np.column_stack([data["x_ref"], data["y_ref"], data.get("z_ref", nan)])
    act = np.column_stack([data["x_act"], data["y_act"], data.get("z_act", nan)])
    return AxisLog(t, data["k"].astype(np.int64), data["line"].astype(np.int64), ref, act)


#: Rows parsed at once: the text of one block is held, never the whole file's (a 10 M-row log is ~0.7 GB of text).
ROWS_PER_BLOCK = 1 << 18


def _read_rows(p: Path, fh: BinaryIO, cols: list[int], ncols: int, first: int) -> NDArray[np.float64]:
    """The sample rows after the header, block by block (``first``: file line number of the first row)."""
    blocks: list[NDArray[np.float64]] = []
    blank_at: int | None = None  # file line of a blank line after which only blank lines may follow
    line_no = first
    while True:
        chunk = list(itertools.islice(fh, ROWS_PER_BLOCK))
        if not chunk:
            break
        rows = [r.decode("utf-8", errors="replace") for r in chunk]
        end = len(rows)
        while end and not rows[end - 1].strip():  # blank lines after the last sample (an editor's) end nothing
            end -= 1
        if end and blank_at is not None:
            raise InputError(p, blank_at, "empty line in the axis log")
        if end < len(rows) and blank_at is None:
            blank_at = line_no + end
        body = rows[:end]
        if body:
            try:
                arr = np.loadtxt(io.StringIO("".join(body)), delimiter=",", usecols=cols, ndmin=2)
            except ValueError:
                arr = None
            if arr is None or arr.shape[0] != len(body):
                _find_bad_row(p, [r.rstrip("\r\n") for r in body], cols, ncols, line_no)
                raise InputError(p, None, "axis log could not be read")  # pragma: no cover
            blocks.append(arr)
        line_no += len(rows)
    if not blocks:
        raise InputError(p, None, "axis log has a header but no samples")
    return blocks[0] if len(blocks) == 1 else np.concatenate(blocks)


def check_sample_times(p: Path, t: NDArray[np.float64], rowline: NDArray[np.int64], max_gap_periods: float) -> None:
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


def decode_text(raw: bytes) -> str:
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


def norm_unit(unit: str) -> str:
    """Lower-case unit without spaces; Greek mu and a mangled micro sign become ``µ``."""
    u = unit.strip().lower().replace("μ", "µ").replace(" ", "")
    if len(u) == 2 and u[0] in "\ufffd?" and u[1] in "ms":
        u = "µ" + u[1]
    return u



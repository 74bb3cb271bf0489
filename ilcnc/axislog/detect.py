"""One entry point for every axis-log format: :func:`read_log` tells ilcnc CSV, halsampler and TNCscope apart."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ilcnc.axislog.halsampler import HALSAMPLER_COLUMNS, read_halsampler
from ilcnc.axislog.log import AxisLog, decode_text, read_axis_log
from ilcnc.axislog.tncscope import read_tncscope
from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes
from ilcnc.units import LENGTH_UNITS

__all__ = ["LOG_FORMATS", "detect_log_format", "estimate_log_samples", "read_log"]


# ---------------------------------------------------------------------------
# One entry point for every log format
# ---------------------------------------------------------------------------


#: Values of the ``fmt`` argument of :func:`read_log`.
LOG_FORMATS: tuple[str, ...] = ("auto", "ilcnc", "halsampler", "tncscope")


def _head_lines(p: Path, size: int = 65536) -> list[str]:
    """The first lines of a file (its first ``size`` bytes), decoded like an export."""
    try:
        with p.open("rb") as fh:
            raw = fh.read(size)
    except OSError:
        read_bytes(p)  # raises the one-line InputError
        raise
    return decode_text(raw).splitlines()


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


def estimate_log_samples(path: str | Path, *, window_bytes: int = 65536) -> int:
    """About how many samples a log holds, from its size and the lines of three windows (start, middle, end) of
    it, without reading it whole; >= 0.

    Data lines are told from comments and headers by starting with a number (or a sign or a dot).
    """
    p = Path(path)
    try:
        size = p.stat().st_size
        pieces = []
        with p.open("rb") as fh:
            for at in sorted({0, max(0, size // 2 - window_bytes // 2), max(0, size - window_bytes)}):
                fh.seek(at)
                lines = fh.read(window_bytes).split(b"\n")
                if at > 0:
                    lines = lines[1:]  # a partial line
                pieces += lines[:-1] if at + window_bytes < size else lines
    except OSError:
        return 0
    data = [ln for ln in pieces if ln.strip()[:1] in b"0123456789-+." and ln.strip()]
    if not data:
        return 0
    per_line = sum(len(ln) + 1 for ln in data) / len(data)
    return int(size / per_line)


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
    if units not in LENGTH_UNITS:
        raise ValueError(f"unknown log units {units!r} (known: {', '.join(LENGTH_UNITS)})")
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

"""Step responses from files: ``t_s,u,y`` CSV or an axis log (ilcnc, halsampler, TNCscope), fitted per axis.

:func:`read_step_csv` reads the plain step format; :func:`identify_file` reads either kind, picks the axis's
commanded and actual signal, and fits the drive model with :func:`ilcnc.learning.identify.identify_step`.
"""

from __future__ import annotations

import csv
import hashlib
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes
from ilcnc.learning.identification import MODEL_ALIASES, Identification
from ilcnc.learning.identify import identify_step
from ilcnc.profile.load import load_profile
from ilcnc.profile.sections import MachineProfile
from ilcnc.units import AXIS_NAMES, LENGTH_UNITS

__all__ = ["identify_file", "read_step_csv"]


# --------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------


def read_step_csv(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, NDArray[np.float64]]:
    """Read a step-response CSV ``t_s,u,y`` (``u`` optional).

    Parameters
    ----------
    path : str or Path
        The file: optional ``#`` comment lines and blank lines, a header
        naming the columns (``t_s``, ``y`` and optionally ``u``; extra columns
        are ignored; any order), then one row per sample.

    Returns
    -------
    t_s, u, y : ndarray
        ``u`` is None when the file has no ``u`` column.

    Raises
    ------
    InputError
        Missing columns, a bad number (with its line), time not increasing.
    """
    p = Path(path)
    text = read_bytes(p).decode("utf-8", errors="replace").lstrip("\ufeff")
    lines = text.splitlines()
    h = 0
    while h < len(lines) and (not lines[h].strip() or lines[h].lstrip().startswith("#")):
        h += 1
    if h >= len(lines):
        raise InputError(p, None, "empty step-response file (expected the header t_s,u,y)")
    header = [c.strip().strip('"').lower() for c in next(csv.reader([lines[h]]))]
    missing = [c for c in ("t_s", "y") if c not in header]
    if missing:
        raise InputError(p, h + 1, f"step-response header lacks {', '.join(missing)} (expected t_s,u,y)")
    want = [c for c in ("t_s", "u", "y") if c in header]
    idx = [header.index(c) for c in want]
    rows: list[list[float]] = []
    for i in range(h + 1, len(lines)):
        line = lines[i]
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        cells = line.split(",")
        if len(cells) < len(header):
            raise InputError(p, i + 1, f"expected {len(header)} columns, got {len(cells)} (truncated line?)")
        try:
            row = [float(cells[j]) for j in idx]
        except ValueError:
            bad = next(cells[j].strip() for j in idx if not _is_float(cells[j]))
            raise InputError(p, i + 1, f"{bad!r} is not a number") from None
        if not all(math.isfinite(v) for v in row):
            raise InputError(p, i + 1, "not a finite number")
        if rows and row[0] <= rows[-1][0]:
            raise InputError(p, i + 1, f"time does not increase ({rows[-1][0]:.6g} s then {row[0]:.6g} s)")
        rows.append(row)
    if not rows:
        raise InputError(p, None, "step-response file has a header but no samples")
    arr = np.asarray(rows, dtype=float)
    col = {c: arr[:, i] for i, c in enumerate(want)}
    return col["t_s"], col.get("u"), col["y"]


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _is_step_csv(p: Path) -> bool:
    """True when the first header line names the t_s,u,y columns of a step-response CSV."""
    from ilcnc.axislog.detect import detect_log_format

    if detect_log_format(p) != "ilcnc":
        return False
    with p.open("rb") as fh:
        head = fh.read(65536).decode("utf-8", errors="replace").lstrip("\ufeff")
    for line in head.splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        cells = [c.strip().strip('"').lower() for c in line.split(",")]
        return "y" in cells and "x_act" not in cells
    return False  # pragma: no cover


def identify_file(
    path: str | Path,
    *,
    axis: str | None = None,
    model: str = "sopdt",
    signal: str | None = None,
    step: float | None = None,
    fmt: str = "auto",
    units: str = "mm",
    profile: MachineProfile | str | Path | None = None,
    period_s: float | None = None,
    step_time_s: float | None = None,
) -> Identification:
    """Fit a drive model to a step response stored in a file.

    Parameters
    ----------
    path : str or Path
        A step-response CSV ``t_s,u,y`` (``u`` optional when ``step`` is
        given) or an axis log :func:`ilcnc.axislog.detect.read_log` reads (ilcnc CSV,
        LinuxCNC halsampler, TNCscope export); for a log ``<axis>_ref`` is the
        command and ``<axis>_act`` the response (positions).
    axis : str, optional
        The axis (required for a log; recorded in the result and used to find
        the profile's PID / position loop).
    model : {"sopdt", "mass_damper", "first_order_delay"}
        The drive model.
    signal : {"velocity", "position"}, optional
        What ``u`` and ``y`` are. Default: position for a log and for
        mass_damper / first_order_delay, velocity for a sopdt step CSV.
        A log holds positions: ``"velocity"`` is refused.
    step : float, optional
        Step size instead of a ``u`` column (a ``u`` column is then ignored,
        with a warning); see :func:`identify_step`. Not for logs.
    fmt : {"auto", "step", "ilcnc", "halsampler", "tncscope"}
        File format; ``"auto"``: a CSV whose header has ``t_s`` and ``y`` is a
        step CSV, anything else goes to :func:`ilcnc.axislog.detect.read_log`.
    units : {"mm", "inch"}
        Length unit of the file (inch values are converted to mm).
    profile : MachineProfile or path, optional
        The machine profile (PID for mass_damper, servo period, position loop).
    period_s : float, optional
        Sample period, s: needed for halsampler logs (no time stamps; default
        the profile's servo period, else 1 ms); overrides the time column
        otherwise.
    step_time_s : float, optional
        Time of the step given by ``step`` (default t = 0 or the first sample).

    Returns
    -------
    Identification
        With :attr:`Identification.source` and its SHA-256 set.

    Raises
    ------
    InputError
        Unreadable file, missing columns or axis, ``no step in the data``
        (naming the file), a log with ``signal="velocity"`` or ``step``.
    ProfileError
        ``profile`` is a path to a bad profile.
    ValueError
        Unknown model, signal, format or units.
    """
    p = Path(path)
    prof: MachineProfile | None
    if profile is None or isinstance(profile, MachineProfile):
        prof = profile
    else:
        prof = load_profile(profile)
    if units not in LENGTH_UNITS:
        raise ValueError(f"unknown units {units!r} (known: mm, inch)")
    if fmt not in ("auto", "step", "ilcnc", "halsampler", "tncscope"):
        raise ValueError(f"unknown format {fmt!r} (known: auto, step, ilcnc, halsampler, tncscope)")
    if axis is not None and axis not in AXIS_NAMES:
        raise InputError(None, None, f"unknown axis {axis!r} (known: {', '.join(AXIS_NAMES)})")
    raw = read_bytes(p)
    digest = hashlib.sha256(raw).hexdigest()
    canon = MODEL_ALIASES.get(model, model)
    scale = 25.4 if units == "inch" else 1.0
    extra: list[str] = []
    kind = fmt
    if fmt == "auto":
        kind = "step" if _is_step_csv(p) else "log"
    if kind == "step":
        t, u_col, y = read_step_csv(p)
        sig = signal or ("velocity" if canon == "sopdt" else "position")
        u: NDArray[np.float64] | float
        if step is not None:
            if u_col is not None:
                extra.append("input: the file's u column is ignored; the step size given is used")
            u = float(step) * scale
        elif u_col is None:
            raise InputError(p, None, "the step-response file has no u column: give the step size")
        else:
            u = u_col * scale
        ident = identify_step(
            t, u, y * scale, model=canon, signal=sig, profile=prof, axis=axis, period_s=period_s,
            step_time_s=step_time_s, source=p,
        )
    else:
        from ilcnc.axislog.detect import read_log

        if axis is None:
            raise InputError(p, None, "an axis log has several axes: say which one to identify (axis)")
        if signal == "velocity":
            raise InputError(p, None, f"an axis log holds positions ({axis}_ref, {axis}_act): use the position signal")
        if step is not None:
            raise InputError(p, None, f"an axis log has its own command ({axis}_ref): a step size applies to t_s,u,y files")
        per = period_s if period_s is not None else (prof.machine.servo_period_s if prof is not None else 1e-3)
        log = read_log(p, fmt="auto" if kind == "log" else kind, period_s=per, units=units)
        i = AXIS_NAMES.index(axis)
        u_arr, y_arr = log.ref_mm[:, i], log.act_mm[:, i]
        if np.all(np.isnan(y_arr)) or np.all(np.isnan(u_arr)):
            raise InputError(p, None, f"the log has no {axis} axis")
        ident = identify_step(
            log.t_s, u_arr, y_arr, model=canon, signal="position", profile=prof, axis=axis,
            period_s=period_s, source=p, u_name=f"{axis}_ref", y_name=f"{axis}_act",
        )
    warn = tuple(extra) + ident.warnings
    return _replace(ident, source_sha256=digest, warnings=warn)


def _replace(ident: Identification, **kw: Any) -> Identification:
    from dataclasses import replace

    return replace(ident, **kw)

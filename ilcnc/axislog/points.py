"""Measured points: probe or CMM results per command (``k,dx,dy,dz``) or at positions (``x,y,z,dx,dy,dz``)."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ilcnc.axislog.log import decode_text
from ilcnc.axislog.tncscope import LENGTH_UNITS_MM, split_unit
from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes

__all__ = ["MeasuredPoints", "read_points"]


# ---------------------------------------------------------------------------
# Measured points (probe / CMM results)
# ---------------------------------------------------------------------------



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
    lines = decode_text(read_bytes(p)).splitlines()
    content = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    if not content:
        raise InputError(p, None, "empty points file")
    hline, htext = content[0]
    sep = ";" if ";" in htext else ("\t" if "\t" in htext else ",")
    header = next(csv.reader([htext], delimiter=sep, skipinitialspace=True))
    col: dict[str, int] = {}
    scale: dict[str, float] = {}
    for i, cell in enumerate(header):
        name, unit = split_unit(cell)
        name = name.lower()
        if name in ("k", "x", "y", "z", "dx", "dy", "dz") and name not in col:
            if unit is not None and unit not in LENGTH_UNITS_MM:
                raise InputError(p, hline, f"column {name}: unknown unit {unit!r} (known: {', '.join(LENGTH_UNITS_MM)})")
            col[name] = i
            scale[name] = LENGTH_UNITS_MM[unit or "mm"]
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



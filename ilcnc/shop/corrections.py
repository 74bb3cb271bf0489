"""Corrections CSV: ``k,dx,dy,dz`` (mm, added to the end point of G01 command k)."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import CorrectionError
from ilcnc.fileio import read_bytes

__all__ = ["read_corrections", "write_corrections"]


def read_corrections(path: str | Path, n_commands: int) -> NDArray[np.float64]:
    """Read a corrections CSV into an (N, 3) array (zeros where a command is not listed).

    Raises
    ------
    CorrectionError
        Missing columns, a bad number, a k that does not exist, a repeated k.
    """
    p = Path(path)
    data = read_bytes(p)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise CorrectionError(p, None, "not a UTF-8 text file") from None
    reader = csv.reader(io.StringIO(text))
    out = np.zeros((n_commands, 3))
    header: list[str] | None = None
    seen: set[int] = set()
    for lineno, row in enumerate(reader, start=1):
        if not row or all(not c.strip() for c in row) or row[0].lstrip().startswith("#"):
            continue
        cells = [c.strip() for c in row]
        if header is None:
            header = [c.lower() for c in cells]
            if "k" not in header or not any(a in header for a in ("dx", "dy", "dz")):
                raise CorrectionError(p, lineno, "header must be k,dx,dy,dz")
            continue
        if len(cells) != len(header):
            raise CorrectionError(p, lineno, f"expected {len(header)} columns, got {len(cells)}")
        rec = dict(zip(header, cells, strict=True))
        try:
            kf = float(rec["k"])
        except ValueError:
            raise CorrectionError(p, lineno, f"k {rec['k']!r} is not a number") from None
        if not kf.is_integer():
            raise CorrectionError(p, lineno, f"k {rec['k']!r} is not an integer")
        k = int(kf)
        if k < 0 or k >= n_commands:
            raise CorrectionError(p, lineno, f"command k={k} does not exist (program has k = 0..{n_commands - 1})")
        if k in seen:
            raise CorrectionError(p, lineno, f"command k={k} listed twice")
        seen.add(k)
        for a, col in enumerate(("dx", "dy", "dz")):
            if col not in rec or rec[col] == "":
                continue
            try:
                v = float(rec[col])
            except ValueError:
                raise CorrectionError(p, lineno, f"{col} {rec[col]!r} is not a number") from None
            if not math.isfinite(v):
                raise CorrectionError(p, lineno, f"{col} is not finite")
            out[k, a] = v
    if header is None:
        raise CorrectionError(p, None, "empty corrections file")
    return out


def write_corrections(corrections_mm: NDArray[np.float64], *, only_nonzero: bool = True) -> str:
    """Format an (N, 3) correction array as CSV text."""
    lines = ["k,dx,dy,dz"]
    for k, (dx, dy, dz) in enumerate(np.asarray(corrections_mm)):
        if only_nonzero and dx == 0 and dy == 0 and dz == 0:
            continue
        lines.append(f"{k},{dx:.6f},{dy:.6f},{dz:.6f}")
    return "\n".join(lines) + "\n"

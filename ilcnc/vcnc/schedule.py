"""A gain schedule: its file and the gain it holds in each servo period.

Seed 001 (receding-horizon gain scheduling) changes an axis's position gain
during a run. :func:`ilcnc.learning.gain_schedule.schedule_gains` designs the schedule
and writes it as a ``t_s,kp`` CSV; this module reads that file back
(:func:`read_schedule`) and turns it into one gain per servo period
(:func:`schedule_on_samples`), which the virtual CNC's drives take
(:func:`ilcnc.vcnc.simulate.simulate_program`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ilcnc.axislog.log import decode_text
from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes

__all__ = ["read_schedule", "schedule_on_samples"]


def read_schedule(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Read a gain-schedule CSV ``t_s,kp`` (what :meth:`ScheduleResult.write_csv` writes).

    Returns
    -------
    t_s : ndarray (N,)
        Start of each period, s (increasing).
    kp : ndarray (N,)
        Position gain from that instant on, (m/min)/mm.

    Raises
    ------
    InputError
        No ``t_s,kp`` header, a bad or non-finite number, a gain <= 0, times
        that do not increase (``file:line: problem``).
    """
    p = Path(path)
    lines = decode_text(read_bytes(p)).splitlines()
    rows = [(i + 1, ln.strip()) for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    if not rows or [c.strip().lower() for c in rows[0][1].split(",")][:2] != ["t_s", "kp"]:
        raise InputError(p, rows[0][0] if rows else 1, "a gain schedule starts with the header t_s,kp")
    t, k = [], []
    for no, ln in rows[1:]:
        cells = ln.split(",")
        try:
            ti, ki = float(cells[0]), float(cells[1])
        except (ValueError, IndexError):
            raise InputError(p, no, f"expected two numbers t_s,kp, got {ln!r}") from None
        if not (math.isfinite(ti) and math.isfinite(ki)) or ki <= 0:
            raise InputError(p, no, f"kp must be a finite gain > 0 at a finite time, got {ln!r}")
        if t and ti <= t[-1]:
            raise InputError(p, no, f"t_s {ti:g} does not increase (previous {t[-1]:g})")
        t.append(ti)
        k.append(ki)
    if not t:
        raise InputError(p, rows[0][0], "the gain schedule has no rows")
    return np.array(t), np.array(k)


def schedule_on_samples(t_s: NDArray[np.float64], kp: NDArray[np.float64], n: int, period_s: float
                        ) -> NDArray[np.float64]:
    """The gain in each of ``n`` servo periods (sample k at k·period_s): the last row at or before it (held);
    before the first row, the first gain."""
    tk = np.arange(n) * period_s
    i = np.searchsorted(np.asarray(t_s), tk + 1e-9 * period_s, side="right") - 1
    return np.asarray(kp, dtype=np.float64)[np.clip(i, 0, len(kp) - 1)]

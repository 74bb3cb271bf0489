"""Fidelity: how far the virtual CNC's prediction of a machine can be trusted.

The learning loop can run on the virtual CNC (``ilcnc learn`` without
``--log``) only as far as the virtual CNC predicts the machine. This module
compares the two on the same program: the per-command error ``E(k)`` that
``learn`` learns from, predicted by :func:`ilcnc.vcnc.simulate.simulate_program`
with the profile, against the same estimate measured from a log of the
machine (:func:`ilcnc.shop.measure.measure_log`), over the commands both measured:

* the correlation of ``|E(k)|`` (does the prediction put the error on the
  right commands?), and of each axis component;
* the RMS of the vector difference ``E_measured(k) − E_predicted(k)``, also as
  a share of the measured RMS ``|E(k)|`` (how much of the error would a
  virtual-only step get wrong?);
* the sample contour error (RMS, max) of both runs.

Targets of issue 9 (LinuxCNC as the measured machine): correlation at least
0.9 and a difference of at most 20 % of the measured error
(:data:`TARGET_CORRELATION`, :data:`TARGET_DIFFERENCE`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.axislog.log import AxisLog
from ilcnc.errors import LogError
from ilcnc.profile.sections import MachineProfile
from ilcnc.program.model import Program
from ilcnc.units import AXIS_NAMES
from ilcnc.vcnc.command_error import CommandSignal, error_kind

__all__ = ["TARGET_CORRELATION", "TARGET_DIFFERENCE", "Fidelity", "compare_signals", "fidelity_of_log"]

#: Least correlation of measured and predicted ``|E(k)|`` for a virtual CNC to be trusted.
TARGET_CORRELATION = 0.9
#: Largest RMS of the difference, as a share of the measured RMS ``|E(k)|``.
TARGET_DIFFERENCE = 0.2
#: Commands listed as the worst disagreements.
N_WORST = 8


def _rms(a: NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(a * a))) if a.size else 0.0


def _corr(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """Pearson correlation; NaN when either side does not vary (nothing to correlate)."""
    if a.size < 2 or np.ptp(a) == 0.0 or np.ptp(b) == 0.0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


@dataclass(slots=True, eq=False)
class Fidelity:
    """Predicted against measured per-command error of one program.

    Attributes
    ----------
    commands : int
        Commands measured by both runs (the comparison is over these).
    correlation : float
        Correlation of ``|E(k)|`` measured and predicted (NaN if either is constant).
    axis_correlation : dict of str to float
        Correlation of each axis component of ``E(k)`` (NaN where an axis does not vary).
    rms_measured_mm, rms_predicted_mm : float
        RMS ``|E(k)|`` of each, mm.
    rms_difference_mm : float
        RMS of ``|E_measured(k) − E_predicted(k)|``, mm.
    contour_measured_mm, contour_predicted_mm : dict of str to float
        Sample contour error of each run (``rms``, ``max``, ``mean``), mm.
    worst : list of dict
        The commands where the two differ most: ``k``, ``line``, ``measured_um``, ``predicted_um`` (vectors).
    """

    commands: int
    correlation: float
    axis_correlation: dict[str, float]
    rms_measured_mm: float
    rms_predicted_mm: float
    rms_difference_mm: float
    contour_measured_mm: dict[str, float] = field(default_factory=dict)
    contour_predicted_mm: dict[str, float] = field(default_factory=dict)
    worst: list[dict[str, Any]] = field(default_factory=list)

    @property
    def relative_difference(self) -> float:
        """``rms_difference_mm / rms_measured_mm`` (inf when nothing was measured)."""
        return self.rms_difference_mm / self.rms_measured_mm if self.rms_measured_mm > 0 else float("inf")

    @property
    def trusted(self) -> bool:
        """Both targets met: correlation ≥ :data:`TARGET_CORRELATION`, difference ≤ :data:`TARGET_DIFFERENCE`."""
        return bool(self.correlation >= TARGET_CORRELATION and self.relative_difference <= TARGET_DIFFERENCE)

    def to_json(self) -> dict[str, Any]:
        def num(x: float) -> float | None:
            return None if not np.isfinite(x) else float(x)

        return {
            "commands": self.commands,
            "correlation": num(self.correlation),
            "axis_correlation": {a: num(c) for a, c in self.axis_correlation.items()},
            "rms_measured_mm": self.rms_measured_mm,
            "rms_predicted_mm": self.rms_predicted_mm,
            "rms_difference_mm": self.rms_difference_mm,
            "relative_difference": num(self.relative_difference),
            "targets": {"correlation": TARGET_CORRELATION, "relative_difference": TARGET_DIFFERENCE},
            "trusted": self.trusted,
            "contour_measured_mm": self.contour_measured_mm,
            "contour_predicted_mm": self.contour_predicted_mm,
            "worst": self.worst,
        }


def compare_signals(measured: CommandSignal, predicted: CommandSignal, *, axes: tuple[str, ...] = AXIS_NAMES,
                    command_line: NDArray[np.int64] | None = None) -> Fidelity:
    """Compare two per-command error signals of the same program.

    Parameters
    ----------
    measured, predicted : CommandSignal
        ``E(k)`` of the machine's run and of the virtual CNC's, same commands (K, 3), mm.
    axes : tuple of str
        Names of the three components.
    command_line : ndarray (K,), optional
        Source line of every command (for the list of worst disagreements).

    Raises
    ------
    ValueError
        The signals are of different programs (command counts differ).
    """
    if measured.e_mm.shape != predicted.e_mm.shape:
        raise ValueError(f"the signals have {measured.e_mm.shape[0]} and {predicted.e_mm.shape[0]} commands")
    both = measured.valid & predicted.valid
    m, p = measured.e_mm[both], predicted.e_mm[both]
    nm, npr = np.linalg.norm(m, axis=1), np.linalg.norm(p, axis=1)
    diff = np.linalg.norm(m - p, axis=1)
    ks = np.flatnonzero(both)
    order = np.argsort(diff, kind="stable")[::-1][:N_WORST]
    worst = [{"k": int(ks[i]), "line": int(command_line[ks[i]]) if command_line is not None else None,
              "measured_um": [round(float(v) * 1e3, 3) for v in m[i]],
              "predicted_um": [round(float(v) * 1e3, 3) for v in p[i]]} for i in order]
    return Fidelity(
        commands=int(both.sum()),
        correlation=_corr(nm, npr),
        axis_correlation={a: _corr(m[:, j], p[:, j]) for j, a in enumerate(axes)},
        rms_measured_mm=_rms(nm),
        rms_predicted_mm=_rms(npr),
        rms_difference_mm=_rms(diff),
        worst=worst,
    )


def fidelity_of_log(program: Program, log: AxisLog, profile: MachineProfile, *, source: str | Path,
                    units: str = "mm") -> Fidelity:
    """Predict ``program`` on the virtual CNC of ``profile`` and compare it with a log of the machine running it.

    Parameters
    ----------
    program : Program
        The program the log is a run of (it is also the drawing the errors are measured against).
    log : AxisLog
        The machine's run (:func:`ilcnc.axislog.detect.read_log`).
    profile : MachineProfile
        The virtual CNC to judge (planner, drives) and the error estimate (``learning.error``).
    source : str or Path
        The log's file, for messages.
    units : str
        Unit of the log's positions (``mm`` or ``inch``).

    Raises
    ------
    LogError
        The log is not a run of the program (:func:`ilcnc.shop.measure.measure_log`), or no command was
        measured by both runs.
    """
    from ilcnc.learning.learner import virtual_run
    from ilcnc.shop.measure import measure_log

    kind = error_kind(profile)
    meas = measure_log(log, program, program, profile, kind, source=source, units=units)
    # the prediction learn would learn from on the virtual CNC (chunk by chunk where the profile allows)
    sim, pred = virtual_run(program, None, profile, kind)
    fid = compare_signals(meas.signal, pred, command_line=np.asarray(program.command_line))
    if fid.commands == 0:
        raise LogError(source, None, "no command was measured by both the log and the virtual CNC: nothing to compare")
    fid.contour_measured_mm = dict(meas.stats)
    fid.contour_predicted_mm = {k: float(sim.stats[k]) for k in ("rms", "max", "mean")}
    return fid

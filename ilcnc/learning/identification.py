"""What a drive-model fit found: parameters, uncertainty, fit quality, warnings, and the profile keys to store.

:class:`Identification` is returned by :func:`ilcnc.learning.identify.identify_step` and
:func:`ilcnc.learning.step_files.identify_file`; :meth:`Identification.profile_updates` gives the keys
:func:`ilcnc.profile.edit.update_profile` writes.
"""

from __future__ import annotations

import datetime as _dt
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import InputError
from ilcnc.fileio import same_file, write_atomic
from ilcnc.jsonout import json_float

__all__ = [
    "GAIN_TOLERANCE",
    "MODELS",
    "MODEL_ALIASES",
    "PARAMETERS",
    "PROFILE_MODEL",
    "SIGNALS",
    "UNITS",
    "Identification"
]

#: Model names accepted by :func:`identify_step` (``mass_damper_pid`` is accepted for ``mass_damper``).
MODELS: tuple[str, ...] = ("sopdt", "mass_damper", "first_order_delay")

#: Signal kinds: what ``u`` and ``y`` are.
SIGNALS: tuple[str, ...] = ("velocity", "position")

#: Reported parameters of each model, named as the profile keys of the drive.
PARAMETERS: dict[str, tuple[str, ...]] = {
    "sopdt": ("gain", "omega0_rad_s", "zeta", "delay_s"),
    "mass_damper": ("mass_v_s2_mm", "damping_v_s_mm"),
    "first_order_delay": ("gain", "time_constant_s", "delay_s"),
}

#: Unit of each parameter (empty: dimensionless).
UNITS: dict[str, str] = {
    "gain": "",
    "omega0_rad_s": "rad/s",
    "zeta": "",
    "delay_s": "s",
    "time_constant_s": "s",
    "mass_v_s2_mm": "V·s²/mm",
    "damping_v_s_mm": "V·s/mm",
}

#: A fitted gain this close to 1 is written to the profile as 1 (see the module docstring).
GAIN_TOLERANCE = 0.05

#: The profile's drive model of each fitted model.
PROFILE_MODEL = {"sopdt": "sopdt", "mass_damper": "mass_damper_pid", "first_order_delay": "first_order_delay"}
#: Other names accepted for the models.
MODEL_ALIASES = {"mass_damper_pid": "mass_damper", "fod": "first_order_delay"}


# --------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Identification:
    """A fitted drive model with its uncertainty and fit quality.

    Attributes
    ----------
    axis : str or None
        Axis name (``"x"``…), when known.
    model : str
        ``"sopdt"``, ``"mass_damper"`` or ``"first_order_delay"``.
    signal : str
        ``"velocity"`` or ``"position"``.
    parameters : dict of str to float
        Fitted values, keyed by profile key (see :data:`PARAMETERS`, :data:`UNITS`).
    stderr : dict of str to float
        Standard errors (NaN when the data do not determine the parameter).
    ci95 : dict of str to (float, float)
        95 % confidence intervals.
    fixed : dict of str to float
        Known parameters used in the fit (PID gains, position loop gain).
    fit_rms : float
        RMS of the residual ``y − ŷ``, units of ``y``.
    r2 : float
        Coefficient of determination ``1 − SSR/SST``.
    noise_rms : float
        Noise level estimated from the data (MAD of second differences), units of ``y``.
    dynamic_amplitude : float
        Largest difference between the fitted response and a static gain
        (the part of the response the dynamics explain), units of ``y``.
    warnings : tuple of str
        One-line warnings (see the module docstring).
    period_s : float
        Sample period used, s.
    step_time_s : float
        Time of the first change of the command, s.
    time_constant_s : float
        Dominant time constant of the fitted model, s (for the "too short" check).
    offset : float
        Fitted constant offset of ``y`` (initial level), units of ``y``.
    evaluations : int
        Number of model evaluations the fit used.
    fit_time_s : float
        Wall time of the fit, s.
    source : str or None
        The file the data came from.
    source_sha256 : str or None
        SHA-256 of that file.
    t_s, u, y, y_fit : ndarray
        Time, command, measurement and fitted response (for plots).
    """

    axis: str | None
    model: str
    signal: str
    parameters: dict[str, float]
    stderr: dict[str, float]
    ci95: dict[str, tuple[float, float]]
    fixed: dict[str, float]
    fit_rms: float
    r2: float
    noise_rms: float
    dynamic_amplitude: float
    warnings: tuple[str, ...]
    period_s: float
    step_time_s: float
    time_constant_s: float
    offset: float
    evaluations: int
    fit_time_s: float
    t_s: NDArray[np.float64] = field(repr=False)
    u: NDArray[np.float64] = field(repr=False)
    y: NDArray[np.float64] = field(repr=False)
    y_fit: NDArray[np.float64] = field(repr=False)
    source: str | None = None
    source_sha256: str | None = None

    @property
    def y_unit(self) -> str:
        """Unit of ``u`` and ``y``: ``"mm/s"`` or ``"mm"``."""
        return "mm/s" if self.signal == "velocity" else "mm"

    @property
    def written_gain(self) -> float | None:
        """The gain :meth:`profile_updates` writes (1.0 when within :data:`GAIN_TOLERANCE` of 1), or None."""
        k = self.parameters.get("gain")
        if k is None:
            return None
        return 1.0 if abs(k - 1.0) <= GAIN_TOLERANCE else _round(k)

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` object of DESIGN.md.

        Returns
        -------
        dict
            ``{"axis", "model", "parameters": {name: value}, "stderr": {name: value},
            "fit_rms", "r2", "warnings": [...]}``; NaN becomes ``None``.
        """
        return {
            "axis": self.axis,
            "model": self.model,
            "parameters": {k: json_float(v) for k, v in self.parameters.items()},
            "stderr": {k: json_float(v) for k, v in self.stderr.items()},
            "fit_rms": json_float(self.fit_rms),
            "r2": json_float(self.r2),
            "warnings": list(self.warnings),
        }

    def to_dict(self) -> dict[str, Any]:
        """Everything :meth:`to_json` has plus the intervals, fixed parameters and fit details."""
        d = self.to_json()
        d.update(
            {
                "signal": self.signal,
                "units": {k: UNITS[k] for k in self.parameters},
                "ci95": {k: [json_float(a), json_float(b)] for k, (a, b) in self.ci95.items()},
                "fixed": dict(self.fixed),
                "noise_rms": json_float(self.noise_rms),
                "dynamic_amplitude": json_float(self.dynamic_amplitude),
                "samples": int(self.t_s.shape[0]),
                "period_s": self.period_s,
                "step_time_s": self.step_time_s,
                "time_constant_s": json_float(self.time_constant_s),
                "offset": json_float(self.offset),
                "evaluations": self.evaluations,
                "fit_time_s": self.fit_time_s,
                "written_gain": self.written_gain,
                "source": self.source,
                "source_sha256": self.source_sha256,
            }
        )
        return d

    def parameter_rows(self) -> list[dict[str, Any]]:
        """One row per parameter for a table.

        Returns
        -------
        list of dict
            ``{"name", "value", "stderr", "ci_low", "ci_high", "unit"}``.
        """
        return [
            {
                "name": k,
                "value": v,
                "stderr": self.stderr[k],
                "ci_low": self.ci95[k][0],
                "ci_high": self.ci95[k][1],
                "unit": UNITS[k],
            }
            for k, v in self.parameters.items()
        ]

    def profile_updates(self, axis: str | None = None) -> dict[str, object]:
        """The profile keys to store, for :func:`ilcnc.profile.edit.update_profile`.

        Parameters
        ----------
        axis : str, optional
            Axis to write (default: :attr:`axis`).

        Returns
        -------
        dict
            ``{"axes.<axis>.drive": {"model": ..., <parameters>}}``: the whole
            drive mapping (the model may change). Values are rounded to 5
            significant digits; the gain is 1.0 when within
            :data:`GAIN_TOLERANCE` of 1 (:attr:`written_gain`); known
            parameters (PID gains, ``position_gain_1_s``) are included.

        Raises
        ------
        ValueError
            No axis given or known.
        """
        ax = axis or self.axis
        if ax is None:
            raise ValueError("profile_updates needs the axis name")
        drive: dict[str, object] = {"model": PROFILE_MODEL[self.model]}
        for k, v in self.parameters.items():
            drive[k] = self.written_gain if k == "gain" else _round(max(v, 0.0) if k == "damping_v_s_mm" else v)
        for k, v in self.fixed.items():
            drive[k] = v
        return {f"axes.{ax}.drive": drive}

    def profile_note(self, date: str | None = None) -> str:
        """One-line note for the profile: how, when and from what the values were identified.

        Parameters
        ----------
        date : str, optional
            ISO date (default: today).
        """
        when = date or _dt.date.today().isoformat()
        src = f" from {Path(self.source).name}" if self.source else ""
        digest = f" (sha256 {self.source_sha256[:12]})" if self.source_sha256 else ""
        gain = ""
        k = self.parameters.get("gain")
        if k is not None and self.written_gain == 1.0 and round(k, 4) != 1.0:
            gain = f", fitted gain {k:.4f} written as 1"
        return (
            f"identified {when} by ilcnc identify{src}{digest}: {self.model}, {self.signal} signal,"
            f" R² {self.r2:.6f}, fit RMS {self.fit_rms:.3g} {self.y_unit}{gain}"
        )

    def write_profile(
        self,
        profile_path: str | Path,
        *,
        axis: str | None = None,
        out: str | Path | None = None,
        protect: Sequence[str | Path] = (),
        date: str | None = None,
    ) -> Path:
        """Store the fitted drive in a profile with a note (keeping its comments; see :mod:`ilcnc.profile.edit`).

        Parameters
        ----------
        profile_path : str or Path
            The profile YAML.
        axis : str, optional
            Axis to write (default: :attr:`axis`).
        out : str or Path, optional
            Write here instead of in place.
        protect : sequence of paths
            Further inputs never to be written over (the data file is always protected).
        date : str, optional
            Date for the note (default: today).

        Returns
        -------
        Path
            The file written.
        """
        from ilcnc.profile.edit import update_profile

        inputs = tuple(protect) + ((self.source,) if self.source else ())
        return update_profile(profile_path, self.profile_updates(axis), out=out, note=self.profile_note(date), protect=inputs)

    def plot(self, path: str | Path, *, protect: Sequence[str | Path] = ()) -> Path:
        """Write a figure of the measurement against the fit and the residual.

        Parameters
        ----------
        path : str or Path
            Image file; its suffix picks the format (``.png``, ``.svg``, ``.pdf``).
        protect : sequence of paths
            Inputs never to be written over (the data file is always protected).

        Returns
        -------
        Path
            The file written (atomically).
        """
        dest = Path(path)
        inputs = tuple(protect) + ((self.source,) if self.source else ())
        for src in inputs:  # before drawing: the same refusal write_atomic makes
            if same_file(dest, src):
                raise InputError(dest, None, "refusing to write over an input file; choose another output path")
        fmt = dest.suffix.lstrip(".").lower() or "png"
        if fmt not in ("png", "svg", "pdf", "jpg", "jpeg", "webp", "eps", "ps", "tif", "tiff"):
            raise InputError(dest, None, f"unknown image format .{fmt} (use .png, .svg or .pdf)")
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        fig = Figure(figsize=(9.0, 6.0), dpi=110, layout="constrained")
        FigureCanvasAgg(fig)
        ax1, ax2 = fig.subplots(2, 1, sharex=True, height_ratios=(3, 1))
        t = self.t_s
        ax1.plot(t, self.y, ".", ms=2.0, color="0.45", label="measured")
        ax1.plot(t, self.y_fit, "-", lw=1.4, color="C0", label="fit")
        gain = self.parameters.get("gain", 1.0) if not (self.model == "sopdt" and "position_gain_1_s" in self.fixed) else 1.0
        ax1.plot(t, self.offset + gain * (self.u - self.u[0]), "--", lw=0.9, color="C1", label="command (× K)")
        ax1.set_ylabel(f"{self.signal} [{self.y_unit}]")
        pars = ", ".join(f"{k} = {_fmt(v)}" for k, v in self.parameters.items())
        where = f"axis {self.axis}: " if self.axis else ""
        ax1.set_title(f"{where}{self.model} ({pars}); R² = {self.r2:.4f}", fontsize=9)
        ax1.legend(loc="best", fontsize=8)
        ax1.grid(True, lw=0.3)
        ax2.plot(t, self.y - self.y_fit, "-", lw=0.6, color="C3")
        ax2.axhline(0.0, color="0.3", lw=0.5)
        ax2.set_ylabel(f"residual [{self.y_unit}]")
        ax2.set_xlabel("t [s]")
        ax2.grid(True, lw=0.3)
        buf = io.BytesIO()
        fig.savefig(buf, format=fmt)
        return write_atomic(dest, buf.getvalue(), protect=inputs)


def _round(v: float, digits: int = 5) -> float:
    return float(f"{v:.{digits}g}") if v != 0 and math.isfinite(v) else float(v)


def _fmt(v: float) -> str:
    return f"{v:.4g}"



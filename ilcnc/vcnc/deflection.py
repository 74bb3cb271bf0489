"""Tool deflection in peripheral milling: forces, tool FRF and surface location error (SLE).

Seed 004 (Ward, Ozkirimli, Jones 2021) feeds a frequency-response SLE model with
the radial depth of every G01 command, taken from on-machine inspection (OMI) of
the stock. This module is that model:

* a mechanistic force model for straight-fluted end mills (no helix), up- and
  down-milling (:func:`tooth_force_n`, :func:`milling_force_n`);
* the tool-point receptance, from modal parameters (:class:`ModalFRF`) or from a
  measured impact-test FRF (:class:`MeasuredFRF`, :func:`read_frf`);
* the SLE by the frequency-domain method of Schmitz & Smith (*Machining
  Dynamics*, Springer 2008/2019, ch. 5; T. L. Schmitz, B. P. Mann, "Closed-form
  solutions for surface location error in milling", Int. J. Mach. Tools Manuf.
  46 (2006) 1369-1377) (:func:`sle_frequency_domain_mm`), checked against a
  time-domain simulation of the same model (:func:`sle_time_domain_mm`);
* the per-command SLE, vectorised (:func:`sle_per_command_mm`);
* the radial depth of each command from an OMI stock file (:func:`read_stock`).

Frame and conventions
---------------------
The cut is described in its own frame, seen from above (+Z), spindle turning
clockwise (M3): ``x`` is the feed direction, ``y`` points to the right of it.
The tooth angle φ is measured clockwise from the tool's left side: a tooth at
φ sits at ``R·(sin φ, −cos φ)`` from the tool axis (φ = 0 left, π/2 front,
π right). The chip thickness is ``h = c·sin φ`` (``c`` feed per tooth).

* Up-milling (conventional): the material is on the left; the tooth enters at
  ``φ_st = 0`` with no chip and leaves at ``φ_ex = arccos(1 − 2·a_e/D)``. The
  finished wall is generated at **entry, φ = 0** (Schmitz & Smith; the tooth
  touches the final surface where the chip is zero).
* Down-milling (climb): the material is on the right; ``φ_st = π − arccos(1 −
  2·a_e/D)``, ``φ_ex = π``; the wall is generated at **exit, φ = π**.

The force of the workpiece on the tool, per engaged tooth, is
``F_t = Ktc·a·h + Kte·a`` against the tooth's motion and ``F_r = Krc·a·h +
Kre·a`` towards the tool axis, so (N, in the cut frame)::

    F_x = −F_t·cos φ − F_r·sin φ,      F_y = −F_t·sin φ + F_r·cos φ.

**SLE sign**: the displacement of the tool along the wall's outward normal
(from the wall towards the tool axis) at the instant a tooth generates the
wall. SLE > 0: the tool deflects away from the wall, material is left
(undercut); SLE < 0: overcut. For up-milling the outward normal is +y
(SLE = y); for down-milling it is −y (SLE = −y). With a stiff tool the classic
static result follows: up-milling overcuts, down-milling undercuts.

The model is linear, has a rigid feed and no regeneration (the chip is the
nominal ``c·sin φ``), no runout and no helix, as in the frequency-domain
method. Only the receptance in y (``Tool.frf_normal``) enters the SLE.

The displacement is continuous, so the force jump when a tooth enters
(edge forces; the chip at a down-milling entry) does not move the tool at
that instant. With few straight flutes in up-milling no other tooth cuts
when one generates the wall (two flutes: the other is at π, outside
[0, φ_ex]); the SLE is then only the free vibration left from the previous
tooth's cut, zero for a quasi-static tool and oscillating with the exit
angle (its phase) for a real one. A helix, which this model lacks, puts
other parts of the flutes in the cut at that instant.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ilcnc.axislog.log import decode_text, norm_unit  # the readers of every CSV ilcnc takes
from ilcnc.errors import MapError
from ilcnc.fileio import read_bytes
from ilcnc.program.model import Program

__all__ = [
    "MILLING_MODES",
    "SEED004_CUTTING_REFERENCE",
    "SEED004_MODES_REFERENCE",
    "Cutting",
    "MeasuredFRF",
    "ModalFRF",
    "Mode",
    "Tool",
    "engagement_angles",
    "feed_per_tooth_mm",
    "milling_force_n",
    "read_frf",
    "read_stock",
    "seed004_cutting",
    "seed004_tool",
    "sle_frequency_domain_mm",
    "sle_per_command_mm",
    "sle_time_domain_mm",
    "tool_displacement_mm",
    "tooth_force_n",
]

#: Values of :attr:`Cutting.mode`.
MILLING_MODES: tuple[str, ...] = ("up", "down")

_DEFAULT_SAMPLES = 4096  # samples per tooth period in the frequency-domain method
_CHUNK_CELLS = 4_000_000  # rows x samples per block of force evaluation (~32 MB per float array)


# ---------------------------------------------------------------------------
# Tool FRF
# ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Mode:
    """One vibration mode of the tool point in one direction.

    Attributes
    ----------
    frequency_hz : float
        Undamped natural frequency, Hz.
    damping_ratio : float
        Viscous damping ratio ζ, dimensionless, 0 < ζ < 1.
    stiffness_n_um : float
        Modal stiffness k, N/µm (the mode's receptance is ``1/(k·(1 − r² + 2iζr))``, r = f/f_n).
    """

    frequency_hz: float
    damping_ratio: float
    stiffness_n_um: float

    def validate(self, name: str = "mode") -> None:
        """Raise ``ValueError`` naming the option (``name.field``) when a value is out of range."""
        _positive(f"{name}.frequency_hz", self.frequency_hz)
        _positive(f"{name}.stiffness_n_um", self.stiffness_n_um)
        z = self.damping_ratio
        if not (math.isfinite(z) and 0.0 < z < 1.0):
            raise ValueError(f"{name}.damping_ratio must be in (0, 1), got {z:g}")


@dataclass(frozen=True, slots=True)
class ModalFRF:
    """Receptance of the tool point as a sum of single-degree-of-freedom modes.

    Attributes
    ----------
    modes : tuple of Mode
        The modes (at least one).
    """

    modes: tuple[Mode, ...]

    def __call__(self, f_hz: ArrayLike) -> NDArray[np.complex128]:
        """Receptance at ``f_hz`` (Hz, ≥ 0), m/N: ``Σ 1/(k_i·(1 − r_i² + 2iζ_i r_i))``."""
        f = np.asarray(f_hz, dtype=np.float64)
        h = np.zeros(f.shape, dtype=np.complex128)
        for m in self.modes:
            r = f / m.frequency_hz
            h += 1.0 / (m.stiffness_n_um * 1e6 * (1.0 - r * r + 2j * m.damping_ratio * r))
        return h

    @property
    def static_compliance_m_n(self) -> float:
        """Receptance at 0 Hz, m/N (``Σ 1/k_i``)."""
        return float(sum(1.0 / (m.stiffness_n_um * 1e6) for m in self.modes))

    def validate(self, name: str = "frf") -> None:
        """Raise ``ValueError`` naming the option when there is no mode or a mode is out of range."""
        if not self.modes:
            raise ValueError(f"{name}.modes must hold at least one mode")
        for i, m in enumerate(self.modes):
            m.validate(f"{name}.modes[{i}]")

    def state_space(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Continuous state space (A, B, C) from force (N) to displacement (m), states [x_i, v_i] per mode."""
        n = len(self.modes)
        a = np.zeros((2 * n, 2 * n))
        b = np.zeros((2 * n, 1))
        c = np.zeros((1, 2 * n))
        for i, m in enumerate(self.modes):
            w = 2.0 * math.pi * m.frequency_hz
            k = m.stiffness_n_um * 1e6
            mass = k / (w * w)
            a[2 * i, 2 * i + 1] = 1.0
            a[2 * i + 1, 2 * i] = -w * w
            a[2 * i + 1, 2 * i + 1] = -2.0 * m.damping_ratio * w
            b[2 * i + 1, 0] = 1.0 / mass
            c[0, 2 * i] = 1.0
        return a, b, c


@dataclass(frozen=True, slots=True)
class MeasuredFRF:
    """A measured tool-point receptance (impact test), interpolated between its lines.

    Attributes
    ----------
    f_hz : ndarray (L,)
        Frequencies, Hz, strictly increasing, ≥ 0.
    h_m_n : ndarray (L,) complex
        Receptance, m/N.
    source : str
        Where it was read from (for messages).

    Notes
    -----
    Between lines the real and imaginary parts are interpolated linearly. Below
    the first line the receptance is held at the first line's real part (an
    impact test is stiffness-controlled well below the first mode, which is
    where its first line must be; this is also the static compliance used for
    the mean force). Above the last line it follows the mass line
    ``H(f_max)·(f_max/f)²``.
    """

    f_hz: NDArray[np.float64]
    h_m_n: NDArray[np.complex128]
    source: str = ""

    def __call__(self, f_hz: ArrayLike) -> NDArray[np.complex128]:
        """Receptance at ``f_hz`` (Hz, ≥ 0), m/N."""
        f = np.asarray(f_hz, dtype=np.float64)
        fx, hx = self.f_hz, self.h_m_n
        h = np.interp(f, fx, hx.real) + 1j * np.interp(f, fx, hx.imag)
        low = f < fx[0]
        h = np.where(low, hx[0].real + 0j, h)
        high = f > fx[-1]
        if np.any(high):
            h = np.where(high, hx[-1] * (fx[-1] / np.where(high, f, 1.0)) ** 2, h)
        return np.asarray(h, dtype=np.complex128)

    @property
    def static_compliance_m_n(self) -> float:
        """Receptance used at 0 Hz, m/N (the first line's real part)."""
        return float(self.h_m_n[0].real)

    def validate(self, name: str = "frf") -> None:
        """Raise ``ValueError`` naming the option for too few lines, bad frequencies or non-finite values."""
        f, h = self.f_hz, self.h_m_n
        if f.ndim != 1 or f.shape != h.shape or f.size < 2:
            raise ValueError(f"{name} must have at least 2 lines of equal-length f_hz and h_m_n, got {f.size}")
        if not (np.all(np.isfinite(f)) and np.all(np.isfinite(h))):
            raise ValueError(f"{name} has non-finite values")
        if f[0] < 0 or np.any(np.diff(f) <= 0):
            raise ValueError(f"{name}.f_hz must be >= 0 and strictly increasing")


FRF = ModalFRF | MeasuredFRF


# ---------------------------------------------------------------------------
# Tool and cutting conditions
# ---------------------------------------------------------------------------


@dataclass(slots=True)
class Tool:
    """A straight-fluted end mill and its tool-point receptance.

    Attributes
    ----------
    diameter_mm : float
        Tool diameter D, mm.
    teeth : int
        Number of teeth (flutes) N, evenly spaced.
    frf_normal : ModalFRF or MeasuredFRF
        Direct receptance normal to the wall (the cut frame's y), m/N.
    frf_feed : ModalFRF or MeasuredFRF or None
        Direct receptance in the feed direction (x), m/N; ``None``: same as
        ``frf_normal`` (a symmetric tool). It does not enter the SLE.
    helix_deg : float
        Helix angle, degrees, 0 ≤ β < 80 (0: straight flutes, this module's model).
    runout_um : float
        Radial runout as a dial indicator reads it (total indicator reading), µm, ≥ 0.
    runout_angle_deg : float
        Direction of the runout offset from flute 0, degrees.

    A helix or runout needs :mod:`ilcnc.vcnc.helix_sle`; :func:`sle_per_command_mm` refuses them.
    """

    diameter_mm: float
    teeth: int
    frf_normal: FRF
    frf_feed: FRF | None = None
    helix_deg: float = 0.0
    runout_um: float = 0.0
    runout_angle_deg: float = 0.0

    @property
    def radius_mm(self) -> float:
        """Tool radius R = D/2, mm."""
        return 0.5 * self.diameter_mm

    def validate(self) -> None:
        """Raise ``ValueError`` naming the option (``tool.diameter_mm must be > 0, got -3``)."""
        _positive("tool.diameter_mm", self.diameter_mm)
        if not (isinstance(self.teeth, (int, np.integer)) and self.teeth >= 1):
            raise ValueError(f"tool.teeth must be an integer >= 1, got {self.teeth!r}")
        self.frf_normal.validate("tool.frf_normal")
        h = self.helix_deg
        if not (isinstance(h, (int, float, np.floating, np.integer)) and math.isfinite(h) and 0.0 <= h < 80.0):
            raise ValueError(f"tool.helix_deg must be in [0, 80), got {h!r}")
        _nonnegative("tool.runout_um", self.runout_um)
        a = self.runout_angle_deg
        if not (isinstance(a, (int, float, np.floating, np.integer)) and math.isfinite(a)):
            raise ValueError(f"tool.runout_angle_deg must be a finite number, got {a!r}")
        if self.frf_feed is not None:
            self.frf_feed.validate("tool.frf_feed")


@dataclass(slots=True)
class Cutting:
    """Workpiece material coefficients and the cutting conditions that do not change per command.

    Attributes
    ----------
    ktc_n_mm2, krc_n_mm2 : float
        Tangential and radial cutting coefficients, N/mm² (force per chip area).
    axial_depth_mm : float
        Axial depth of cut a, mm.
    spindle_rpm : float
        Spindle speed, rev/min.
    kte_n_mm, kre_n_mm : float
        Tangential and radial edge coefficients, N/mm (force per axial length), ≥ 0.
    mode : {"up", "down"}
        Up-milling (conventional) or down-milling (climb).
    """

    ktc_n_mm2: float
    krc_n_mm2: float
    axial_depth_mm: float
    spindle_rpm: float
    kte_n_mm: float = 0.0
    kre_n_mm: float = 0.0
    mode: str = "up"

    def validate(self) -> None:
        """Raise ``ValueError`` naming the option (``cutting.axial_depth_mm must be > 0, got 0``)."""
        _positive("cutting.ktc_n_mm2", self.ktc_n_mm2)
        _nonnegative("cutting.krc_n_mm2", self.krc_n_mm2)
        _positive("cutting.axial_depth_mm", self.axial_depth_mm)
        _positive("cutting.spindle_rpm", self.spindle_rpm)
        _nonnegative("cutting.kte_n_mm", self.kte_n_mm)
        _nonnegative("cutting.kre_n_mm", self.kre_n_mm)
        if self.mode not in MILLING_MODES:
            raise ValueError(f"cutting.mode must be one of {', '.join(MILLING_MODES)}, got {self.mode!r}")


def _positive(name: str, value: float) -> None:
    if not (isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be > 0, got {value:g}" if isinstance(value, (int, float)) else f"{name} must be > 0")


def _nonnegative(name: str, value: float) -> None:
    if not (isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be >= 0, got {value:g}" if isinstance(value, (int, float)) else f"{name} must be >= 0")


def feed_per_tooth_mm(feed_mm_min: ArrayLike, spindle_rpm: float, teeth: int) -> NDArray[np.float64]:
    """Feed per tooth c = F / (n·N), mm.

    Parameters
    ----------
    feed_mm_min : array_like
        Programmed feed, mm/min (e.g. ``Program.command_feed_mm_min``).
    spindle_rpm : float
        Spindle speed, rev/min.
    teeth : int
        Number of teeth.
    """
    return np.asarray(feed_mm_min, dtype=np.float64) / (float(spindle_rpm) * int(teeth))


# ---------------------------------------------------------------------------
# Seed 004: literature values
# ---------------------------------------------------------------------------

#: Cutting coefficients used by :func:`seed004_cutting` (Al 7075-T6, uncoated carbide, dry):
#: Ktc 767.01 N/mm², Krc 168.8 N/mm², Kte 27.7 N/mm, Kre 26.6 N/mm, from Table 5 (its reference [190])
#: of Z. Duan et al., "Milling force model for aviation aluminum alloy: academic insight and
#: perspective analysis", Chinese Journal of Mechanical Engineering 34 (2021), doi:10.1186/s10033-021-00536-9.
SEED004_CUTTING_REFERENCE: dict[str, float] = {"ktc_n_mm2": 767.01, "krc_n_mm2": 168.8, "kte_n_mm": 27.7, "kre_n_mm": 26.6}

#: Tool-point modes used by :func:`seed004_tool` (both directions; ASSUMED, see there): (frequency Hz, damping
#: ratio, stiffness N/µm).
SEED004_MODES_REFERENCE: tuple[tuple[float, float, float], ...] = ((900.0, 0.04, 40.0), (2400.0, 0.025, 15.0))


def seed004_tool() -> Tool:
    """The 12 mm two-flute solid-carbide end mill of seed 004, with assumed tool-point modes.

    Seed 004 (Ward, Ozkirimli, Jones, Procedia CIRP 2021, sec. 3) used a Sandvik
    2P170-1200-NA H10F end mill (D = 12 mm, 2 flutes) in an HSK-63A holder on a
    DMG DMU eVo 40, with an impact-tested FRF it does not publish. The modes
    here (:data:`SEED004_MODES_REFERENCE`) are assumptions, not the paper's:

    * a tool mode at 2400 Hz, k = 15 N/µm, ζ = 0.025. Only the stiffness has an
      estimate behind it, a scaling, not a measurement: a carbide cantilever of
      fluted diameter ≈ 0.8·D = 9.6 mm (I ≈ 417 mm⁴, E ≈ 600 GPa) and stick-out
      ≈ 3·D = 36 mm has 3EI/L³ ≈ 16 N/µm. Frequency and damping are assumed;
    * a holder/spindle mode at 900 Hz, k = 40 N/µm, ζ = 0.04: assumed, no source.

    No published tool-point FRF of a comparable tool could be read and cited
    (docs/papers.md, seed 004, lists what was searched).

    Static tool-point stiffness 1/(1/40 + 1/15) ≈ 10.9 N/µm. The tool is
    symmetric (``frf_feed`` = ``frf_normal``). Replace them with the measured FRF
    (:func:`read_frf`) of the actual tool.
    """
    modes = tuple(Mode(f, z, k) for f, z, k in SEED004_MODES_REFERENCE)
    return Tool(diameter_mm=12.0, teeth=2, frf_normal=ModalFRF(modes))


def seed004_cutting() -> Cutting:
    """Seed 004's cutting conditions with literature coefficients for Al 7075-T6.

    Conditions from the paper (sec. 3.2): up-milling, axial depth 8 mm, cutting
    speed 76.01 m/min on a 12 mm tool → 2016 rev/min; feed 403.4 mm/min →
    0.100 mm/tooth with two flutes (pass it per command to :func:`sle_per_command_mm`).

    The paper does not give cutting coefficients. The values
    (:data:`SEED004_CUTTING_REFERENCE`) are the mechanistic coefficients for
    Al 7075-T6 with cemented carbide, dry, tabulated by Duan et al. (Chin. J.
    Mech. Eng. 34, 2021, Table 5, their ref. [190]): Ktc = 767.01 N/mm²,
    Krc = 168.8 N/mm², Kte = 27.7 N/mm, Kre = 26.6 N/mm. The often quoted
    Schmitz & Smith aluminium values (Kt ≈ 796, Kn ≈ 168 N/mm²) are within 4 %
    of these; that source could not be checked here, so the tabulated set with
    edge coefficients is used.
    """
    c = SEED004_CUTTING_REFERENCE
    return Cutting(
        ktc_n_mm2=c["ktc_n_mm2"], krc_n_mm2=c["krc_n_mm2"], kte_n_mm=c["kte_n_mm"], kre_n_mm=c["kre_n_mm"],
        axial_depth_mm=8.0, spindle_rpm=2016.0, mode="up",
    )


# ---------------------------------------------------------------------------
# Force model
# ---------------------------------------------------------------------------


def engagement_angles(
    radial_depth_mm: ArrayLike, diameter_mm: float, mode: str
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Entry and exit angles (rad) of a radial depth of cut.

    Parameters
    ----------
    radial_depth_mm : array_like
        Radial depth a_e, mm, 0 < a_e ≤ D.
    diameter_mm : float
        Tool diameter D, mm.
    mode : {"up", "down"}
        Up-milling: φ_st = 0, φ_ex = arccos(1 − 2a_e/D); down-milling:
        φ_st = π − arccos(1 − 2a_e/D), φ_ex = π.

    Raises
    ------
    ValueError
        A radial depth ≤ 0, larger than the diameter or not finite (naming the first one).
    """
    ae = np.asarray(radial_depth_mm, dtype=np.float64)
    _check_radial_depth(ae, diameter_mm)
    sweep = np.arccos(np.clip(1.0 - 2.0 * ae / diameter_mm, -1.0, 1.0))
    if mode == "up":
        return np.zeros_like(sweep), sweep
    if mode == "down":
        return math.pi - sweep, np.full_like(sweep, math.pi)
    raise ValueError(f"cutting.mode must be one of {', '.join(MILLING_MODES)}, got {mode!r}")


def _check_radial_depth(ae: NDArray[np.float64], diameter_mm: float, *, allow_nan: bool = False) -> None:
    """Raise ``ValueError`` for the first radial depth out of (0, D], naming its command index k."""
    flat = ae.ravel()
    bad = ~((flat > 0) & (flat <= diameter_mm))
    if allow_nan:
        bad &= ~np.isnan(flat)
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        v = float(flat[k])
        where = f"command k={k}: " if flat.size > 1 else ""
        if not math.isfinite(v):
            raise ValueError(f"{where}radial depth is not a finite number ({v})")
        if v <= 0:
            raise ValueError(f"{where}radial depth {v:g} mm must be > 0 (the tool does not cut)")
        raise ValueError(f"{where}radial depth {v:g} mm is larger than the tool diameter {diameter_mm:g} mm")


def tooth_force_n(
    phi_rad: ArrayLike, radial_depth_mm: float, feed_per_tooth_mm: float, tool: Tool, cutting: Cutting
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Tangential and radial force on one tooth at angle φ, N (0 outside the engagement).

    Parameters
    ----------
    phi_rad : array_like
        Tooth angle φ, rad (any value: taken modulo 2π).
    radial_depth_mm : float
        Radial depth a_e, mm.
    feed_per_tooth_mm : float
        Feed per tooth c, mm.
    tool, cutting : Tool, Cutting

    Returns
    -------
    f_t, f_r : ndarray
        ``F_t = Ktc·a·h + Kte·a`` and ``F_r = Krc·a·h + Kre·a`` with ``h = c·sin φ``
        where φ_st ≤ φ ≤ φ_ex (boundaries included), else 0; N.
    """
    return _tooth_force(np.asarray(phi_rad, dtype=np.float64), radial_depth_mm, feed_per_tooth_mm, tool, cutting, 0.0)


def _tooth_force(
    phi: NDArray[np.float64], radial_depth_mm: float, c: float, tool: Tool, cutting: Cutting, step: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`tooth_force_n` with the engagement weighted by :func:`_engaged` over cells of ``step`` rad."""
    st, ex = engagement_angles(radial_depth_mm, tool.diameter_mm, cutting.mode)
    w, ang = _engaged(phi, st, ex, step)
    a = cutting.axial_depth_mm
    h = c * np.sin(ang)
    return w * (cutting.ktc_n_mm2 * a * h + cutting.kte_n_mm * a), w * (cutting.krc_n_mm2 * a * h + cutting.kre_n_mm * a)


def _engaged(
    phi: NDArray[np.float64], st: NDArray[np.float64], ex: NDArray[np.float64], step: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Engagement weight of a tooth at φ and φ itself, unwrapped to lie at or just before the entry angle.

    ``step = 0``: 1 for φ_st ≤ φ ≤ φ_ex (boundaries included, 1e-12 rad), else 0.
    ``step > 0`` (a sampled signal with that angular spacing): the fraction of the
    cell [φ − step/2, φ + step/2] inside [φ_st, φ_ex], so a force jump is
    represented by its cell average (0.5 on a boundary) and the result is
    continuous in the angles. ``st``, ``ex`` broadcast against ``phi``.
    """
    margin = max(step, 1e-12)
    psi = np.mod(phi - st + margin, 2.0 * math.pi) - margin  # angle past entry, in [−margin, 2π − margin)
    width = ex - st
    if step > 0:
        w = np.clip(psi / step + 0.5, 0.0, 1.0) * np.clip((width - psi) / step + 0.5, 0.0, 1.0)
    else:
        w = ((psi >= -1e-12) & (psi <= width + 1e-12)).astype(np.float64)
    return w, st + psi


def milling_force_n(
    phi_rad: ArrayLike, radial_depth_mm: float, feed_per_tooth_mm: float, tool: Tool, cutting: Cutting
) -> NDArray[np.float64]:
    """Total force of the workpiece on the tool, summed over all teeth, in the cut frame, N.

    Parameters
    ----------
    phi_rad : array_like, shape (...)
        Angle of tooth 0, rad; tooth j is at ``φ + 2πj/N``.
    radial_depth_mm, feed_per_tooth_mm : float
        a_e and c, mm.
    tool, cutting : Tool, Cutting

    Returns
    -------
    ndarray, shape (..., 2)
        ``(F_x, F_y)``: feed direction and its right-hand normal (module docstring), N.
    """
    return _milling_force(np.asarray(phi_rad, dtype=np.float64), radial_depth_mm, feed_per_tooth_mm, tool, cutting, 0.0)


def _milling_force(
    phi0: NDArray[np.float64], radial_depth_mm: float, c: float, tool: Tool, cutting: Cutting, step: float
) -> NDArray[np.float64]:
    out = np.zeros((*phi0.shape, 2))
    for j in range(tool.teeth):
        phi = phi0 + 2.0 * math.pi * j / tool.teeth
        ft, fr = _tooth_force(phi, radial_depth_mm, c, tool, cutting, step)
        s, co = np.sin(phi), np.cos(phi)
        out[..., 0] += -ft * co - fr * s
        out[..., 1] += -ft * s + fr * co
    return out


def _generation_angle(mode: str) -> float:
    """Tooth angle at which the finished wall is generated: 0 (up-milling entry) or π (down-milling exit)."""
    return 0.0 if mode == "up" else math.pi


def _sle_sign(mode: str) -> float:
    """SLE = sign · y: the wall's outward normal is +y for up-milling, −y for down-milling."""
    return 1.0 if mode == "up" else -1.0


def _normal_force_rows(
    ae: NDArray[np.float64], tool: Tool, cutting: Cutting, samples: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """F_y over one tooth period for each radial depth, split into its cutting and edge parts.

    Returns ``(fy_cut, fy_edge)`` of shape (len(ae), samples): ``fy_cut`` per mm of
    feed per tooth (N/mm), ``fy_edge`` in N. Sample s is at ``t = s·T/samples``
    with tooth 0 at the generation angle at s = 0. Each tooth's engagement is
    weighted by the fraction of its sample cell inside [φ_st, φ_ex] (0.5 on a
    boundary), so the result is continuous in a_e and a force jump is
    represented by its cell average.
    """
    n_teeth = tool.teeth
    st, ex = engagement_angles(ae, tool.diameter_mm, cutting.mode)
    step = 2.0 * math.pi / (n_teeth * samples)
    base = _generation_angle(cutting.mode) + step * np.arange(samples)
    a = cutting.axial_depth_mm
    fy_cut = np.zeros((ae.shape[0], samples))
    fy_edge = np.zeros((ae.shape[0], samples))
    for j in range(n_teeth):
        phi = base + 2.0 * math.pi * j / n_teeth
        w, ang = _engaged(phi[None, :], st[:, None], ex[:, None], step)  # (U, samples)
        s, c = np.sin(ang), np.cos(ang)
        # F_y = −F_t sin φ + F_r cos φ with F_t = a(Ktc c sin φ + Kte), F_r = a(Krc c sin φ + Kre)
        fy_cut += w * (a * s * (-cutting.ktc_n_mm2 * s + cutting.krc_n_mm2 * c))
        fy_edge += w * (a * (-cutting.kte_n_mm * s + cutting.kre_n_mm * c))
    return fy_cut, fy_edge


def _harmonic_receptance(frf: FRF, tool: Tool, cutting: Cutting, samples: int) -> NDArray[np.complex128]:
    """FRF at the tooth-passing harmonics 0 .. samples/2 (m/N), Nyquist bin set to 0."""
    f_tooth = cutting.spindle_rpm * tool.teeth / 60.0
    h = frf(f_tooth * np.arange(samples // 2 + 1))
    h[-1] = 0.0  # the Nyquist bin of an even-length period cannot carry a complex gain
    return h


def tool_displacement_mm(
    radial_depth_mm: float, feed_per_tooth_mm: float, tool: Tool, cutting: Cutting, *, samples: int = _DEFAULT_SAMPLES
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Steady-state tool displacement normal to the wall over one tooth period (frequency-domain method).

    The summed normal force over one tooth period is sampled, transformed by
    FFT into its tooth-passing harmonics, multiplied by ``tool.frf_normal`` at
    each harmonic and transformed back.

    Parameters
    ----------
    radial_depth_mm, feed_per_tooth_mm : float
        a_e and c, mm.
    tool, cutting : Tool, Cutting
    samples : int
        Samples per tooth period (even); harmonics up to ``samples/2 − 1``.

    Returns
    -------
    t_s : ndarray (samples,)
        Time from the instant tooth 0 generates the wall, s.
    y_mm : ndarray (samples,)
        Displacement along the cut frame's y, mm (the SLE is ``y_mm[0]`` for
        up-milling, ``−y_mm[0]`` for down-milling).
    """
    samples = _even_samples(samples)
    ae = np.array([float(radial_depth_mm)])
    fc, fe = _normal_force_rows(ae, tool, cutting, samples)
    fy = feed_per_tooth_mm * fc[0] + fe[0]
    h = _harmonic_receptance(tool.frf_normal, tool, cutting, samples)
    y_m = np.fft.irfft(np.fft.rfft(fy) * h, n=samples)
    period = 60.0 / (cutting.spindle_rpm * tool.teeth)
    return period * np.arange(samples) / samples, y_m * 1e3


def sle_frequency_domain_mm(
    radial_depth_mm: float, feed_per_tooth_mm: float, tool: Tool, cutting: Cutting, *, samples: int = _DEFAULT_SAMPLES
) -> float:
    """Surface location error of one cut by the frequency-domain method, mm (> 0: undercut).

    Parameters
    ----------
    radial_depth_mm, feed_per_tooth_mm : float
        a_e and c, mm.
    tool, cutting : Tool, Cutting
    samples : int
        Samples per tooth period of the FFT.

    Returns
    -------
    float
        Tool displacement along the wall's outward normal at the instant a
        tooth generates the wall (φ = 0 up-milling, φ = π down-milling), mm.
    """
    _, y = tool_displacement_mm(radial_depth_mm, feed_per_tooth_mm, tool, cutting, samples=samples)
    return float(_sle_sign(cutting.mode) * y[0])


def sle_time_domain_mm(
    radial_depth_mm: float,
    feed_per_tooth_mm: float,
    tool: Tool,
    cutting: Cutting,
    *,
    samples: int = 8192,
    settle: float = 1e-9,
    max_periods: int = 5000,
) -> float:
    """Surface location error by time-domain simulation of the modal model, mm (> 0: undercut).

    The tool-point modes of ``tool.frf_normal`` (a :class:`ModalFRF`) are
    integrated from rest under the summed normal force (:func:`milling_force_n`
    evaluated at every time step, the step that holds an entry or exit weighted
    by the fraction of it the tooth is engaged), each mode discretised exactly
    for a force linear between steps (``scipy.signal.cont2discrete``, first-order
    hold) and run by ``lfilter``, over whole tooth periods until the slowest mode's
    free response has decayed by ``settle``; the displacement at the last
    generation instant is the steady-state SLE. Rigid feed, no regeneration:
    the same model as :func:`sle_frequency_domain_mm`, by another route.

    Parameters
    ----------
    radial_depth_mm, feed_per_tooth_mm : float
        a_e and c, mm.
    tool, cutting : Tool, Cutting
    samples : int
        Time steps per tooth period.
    settle : float
        Remaining fraction of the slowest decay, exp(−ζω t) ≤ settle.
    max_periods : int
        Upper bound on the simulated tooth periods.

    Raises
    ------
    ValueError
        The tool's normal FRF is not modal.
    """
    from scipy.signal import cont2discrete, lfilter

    frf = tool.frf_normal
    if not isinstance(frf, ModalFRF):
        raise ValueError("tool.frf_normal must be a ModalFRF for the time-domain simulation")
    period = 60.0 / (cutting.spindle_rpm * tool.teeth)
    dt = period / samples
    decay = min(m.damping_ratio * 2.0 * math.pi * m.frequency_hz for m in frf.modes)
    periods = int(min(max_periods, max(2, math.ceil(-math.log(settle) / (decay * period)) + 1)))
    omega = 2.0 * math.pi * cutting.spindle_rpm / 60.0
    phi0 = _generation_angle(cutting.mode) + omega * dt * np.arange(samples)
    fy_period = _milling_force(phi0, radial_depth_mm, feed_per_tooth_mm, tool, cutting, omega * dt)[:, 1]
    fy = np.concatenate([np.tile(fy_period, periods), fy_period[:1]])  # the summed force repeats every tooth period
    y = np.zeros_like(fy)
    for mode in frf.modes:  # each mode exactly discretised for a force linear between steps
        a, b, c = ModalFRF((mode,)).state_space()
        ad, bd, cd, dd, _ = cont2discrete((a, b, c, np.zeros((1, 1))), dt, method="foh")
        # x[k+1] = Ad x[k] + Bd u[k], y = Cd x + Dd u; run in Ad's eigenbasis (two complex first-order
        # recursions in lfilter: a transfer-function polynomial with poles this close to 1 loses ~1e-4)
        p, v = np.linalg.eig(ad)
        gain = np.linalg.solve(v, bd[:, 0])
        out = (cd @ v)[0]
        for i in range(2):
            y += (out[i] * lfilter([0.0, gain[i]], [1.0, -p[i]], fy.astype(np.complex128))).real
        y += dd[0, 0] * fy
    return float(_sle_sign(cutting.mode) * y[-1] * 1e3)


def _even_samples(samples: int) -> int:
    if samples < 8:
        raise ValueError(f"samples must be >= 8, got {samples}")
    return samples + (samples % 2)


def _sle_kernel(tool: Tool, cutting: Cutting, samples: int) -> NDArray[np.float64]:
    """g (m/N) with y(t_gen) = Σ_s F_y[s]·g[s]: the frequency-domain method's value at s = 0 as a dot product."""
    h = np.fft.irfft(_harmonic_receptance(tool.frf_normal, tool, cutting, samples), n=samples)
    return np.roll(h[::-1], 1)  # g[s] = h[(−s) mod samples]: y = F ⊛ h evaluated at 0


def _sle_parts(
    ae: NDArray[np.float64], tool: Tool, cutting: Cutting, samples: int
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """y(t_gen) per mm of feed per tooth (m/mm) and from the edge forces (m) for each a_e, in O(1) per value.

    With the angle grid of one revolution φ_m = φ_gen + m·δ (δ = 2π/(N·samples);
    tooth j at sample s is m = s + j·samples) the frequency-domain value is
    ``Σ_m w_m(a_e)·f(φ_m)·g[m mod samples]``: ``f`` does not depend on a_e and the
    engagement weight ``w_m`` (:func:`_engaged`) is 1 inside [φ_st, φ_ex], 0
    outside and fractional only in the two cells holding φ_st and φ_ex. So the
    sum is a difference of prefix sums plus those two cells: the same number
    as :func:`_normal_force_rows` · kernel, to rounding.
    """
    n_teeth = tool.teeth
    period = n_teeth * samples
    step = 2.0 * math.pi / period
    st, ex = engagement_angles(ae, tool.diameter_mm, cutting.mode)
    phi_gen = _generation_angle(cutting.mode)
    lo_a, hi_b = (st - phi_gen) / step, (ex - phi_gen) / step  # boundaries in cells, within [-period/2, period/2]
    half = period // 2 + 3
    m = np.arange(-half, half + 1)
    phi = phi_gen + m * step
    g = _sle_kernel(tool, cutting, samples)[np.mod(m, samples)]
    s, c = np.sin(phi), np.cos(phi)
    a = cutting.axial_depth_mm
    v_cut = g * a * s * (-cutting.ktc_n_mm2 * s + cutting.krc_n_mm2 * c)
    v_edge = g * a * (-cutting.kte_n_mm * s + cutting.kre_n_mm * c)
    out = []
    i_lo = np.ceil(lo_a + 0.5).astype(np.int64)  # first cell wholly inside
    i_hi = np.floor(hi_b - 0.5).astype(np.int64)  # last cell wholly inside
    m_a, m_b = i_lo - 1, i_hi + 1  # the cells holding the boundaries

    def weight(cell: NDArray[np.int64]) -> NDArray[np.float64]:
        return np.clip(cell - lo_a + 0.5, 0.0, 1.0) * np.clip(hi_b - cell + 0.5, 0.0, 1.0)

    for v in (v_cut, v_edge):
        csum = np.concatenate([[0.0], np.cumsum(v)])  # csum[i + half + 1] = Σ v over m ≤ i
        full = np.where(i_hi >= i_lo, csum[i_hi + half + 1] - csum[i_lo + half], 0.0)
        edge_a = weight(m_a) * v[m_a + half]
        edge_b = np.where(m_b != m_a, weight(m_b) * v[m_b + half], 0.0)
        out.append(full + edge_a + edge_b)
    return out[0], out[1]


def sle_per_command_mm(
    radial_depth_mm: ArrayLike,
    feed_per_tooth_mm: ArrayLike,
    tool: Tool,
    cutting: Cutting,
    *,
    samples: int = _DEFAULT_SAMPLES,
) -> NDArray[np.float64]:
    """SLE of every command from its radial depth and feed per tooth, mm (> 0: undercut).

    The same number as :func:`sle_frequency_domain_mm` for each command, for
    any number of commands in O(N·samples + K) work. The model is linear in
    the force and the force is ``c·F_cut(a_e) + F_edge(a_e)``, so ``SLE =
    c·S_cut(a_e) + S_edge(a_e)``. Only the displacement at the generation
    instant is needed, so the FFT, the product with the FRF at the
    tooth-passing harmonics and the inverse FFT reduce to one dot product of
    the sampled force with a kernel computed once from the FRF; and since the
    radial depth only moves the entry and exit angles of the engagement, that
    dot product is a difference of two prefix sums over the angle grid plus the
    two cells holding the entry and exit (:func:`_sle_parts`). No table and no
    interpolation: every distinct radial depth is computed exactly.

    Parameters
    ----------
    radial_depth_mm : array_like (K,)
        Radial depth a_e of each command, mm; NaN (no stock information) gives NaN.
    feed_per_tooth_mm : array_like (K,) or float
        Feed per tooth c of each command, mm (:func:`feed_per_tooth_mm`).
    tool, cutting : Tool, Cutting
        Validated here.
    samples : int
        Samples per tooth period of the frequency-domain method.

    Returns
    -------
    ndarray (K,)
        SLE, mm.

    Raises
    ------
    ValueError
        A bad tool or cutting option (naming it), a radial depth ≤ 0 or larger
        than the tool diameter, or a bad feed per tooth (naming the command k).
    """
    tool.validate()
    cutting.validate()
    if tool.helix_deg != 0.0 or tool.runout_um != 0.0:
        raise ValueError("the tool has a helix or runout: use ilcnc.vcnc.helix_sle.sle_helical_per_command_mm")
    samples = _even_samples(samples)
    ae = np.atleast_1d(np.asarray(radial_depth_mm, dtype=np.float64))
    if ae.ndim != 1:
        raise ValueError(f"radial_depth_mm must be one-dimensional, got shape {ae.shape}")
    _check_radial_depth(ae, tool.diameter_mm, allow_nan=True)
    c = np.broadcast_to(np.asarray(feed_per_tooth_mm, dtype=np.float64), ae.shape)
    bad_c = ~(np.isfinite(c) & (c >= 0))
    if np.any(bad_c):
        k = int(np.flatnonzero(bad_c)[0])
        raise ValueError(f"command k={k}: feed per tooth must be a finite number >= 0, got {c[k]:g}")
    out = np.full(ae.shape, np.nan)
    known = ~np.isnan(ae)
    if np.any(known):
        s_cut, s_edge = _sle_parts(ae[known], tool, cutting, samples)
        out[known] = _sle_sign(cutting.mode) * (c[known] * s_cut + s_edge) * 1e3
    return out


# ---------------------------------------------------------------------------
# File readers: measured FRF, stock (OMI)
# ---------------------------------------------------------------------------

_HEADER_UNIT_RE = re.compile(r"^\s*(?P<name>[^\[\(]*?)\s*[\[\(]\s*(?P<unit>[^\]\)]*)\s*[\]\)]\s*$")
_FRF_UNITS = {"m/n": 1.0, "mm/n": 1e-3, "µm/n": 1e-6, "um/n": 1e-6, "nm/n": 1e-9}
_LENGTH_UNITS = {"mm": 1.0, "µm": 1e-3, "um": 1e-3, "m": 1e3, "inch": 25.4, "in": 25.4}


def _split_header(cell: str) -> tuple[str, str | None]:
    """``"re [µm/N]"`` -> ``("re", "µm/n")``; ``"f_hz"`` -> ``("f_hz", None)``."""
    cell = cell.strip().strip('"').strip()
    m = _HEADER_UNIT_RE.match(cell)
    if m:
        return m["name"].strip().lower(), norm_unit(m["unit"])
    return cell.lower(), None


@dataclass(slots=True)
class _Table:
    """Rows of a small numeric CSV: header names, values by column, file line of each row."""

    path: Path
    header_line: int
    names: list[str]
    units: list[str | None]
    rows: list[tuple[int, list[str]]] = field(default_factory=list)


def _read_table(p: Path, what: str) -> _Table:
    """Split a CSV into header and rows, skipping blank and ``#`` lines (MapError when empty)."""
    lines = decode_text(read_bytes(p)).splitlines()
    content = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    if not content:
        raise MapError(p, None, f"empty {what} file")
    hline, htext = content[0]
    cells = next(csv.reader([htext], skipinitialspace=True))
    names, units = zip(*(_split_header(c) for c in cells), strict=True)
    table = _Table(p, hline, list(names), list(units))
    for ln, text in content[1:]:
        table.rows.append((ln, next(csv.reader([text], skipinitialspace=True))))
    if not table.rows:
        raise MapError(p, None, f"{what} file has a header but no rows")
    return table


def _column_values(table: _Table, cols: dict[str, int]) -> dict[str, NDArray[np.float64]]:
    """Parse the named columns of every row as finite floats (MapError naming file and line)."""
    ncols = max(cols.values()) + 1
    n = len(table.rows)
    vals = {c: np.empty(n) for c in cols}
    for j, (ln, cells) in enumerate(table.rows):
        if len(cells) < ncols:
            raise MapError(table.path, ln, f"expected {ncols} columns, got {len(cells)} (truncated line?)")
        for name, i in cols.items():
            v = cells[i].strip()
            try:
                x = float(v)
            except ValueError:
                raise MapError(table.path, ln, f"{name}: {'empty value' if not v else repr(v) + ' is not a number'}") from None
            if not math.isfinite(x):
                raise MapError(table.path, ln, f"{name} is not a finite number ({v!r})")
            vals[name][j] = x
    return vals


def read_frf(path: str | Path) -> MeasuredFRF:
    """Read a measured tool-point FRF (impact test) from a CSV.

    Parameters
    ----------
    path : str or Path
        CSV with the header ``f_hz,re,im`` (frequency, real and imaginary part
        of the direct receptance); ``f [Hz]`` is accepted for ``f_hz``. The
        receptance unit may be given in brackets on ``re``/``im``: ``[m/N]``
        (the default), ``[mm/N]``, ``[µm/N]`` (``um/N``), ``[nm/N]``. Blank
        lines and lines starting with ``#`` are skipped; extra columns are
        ignored; names are case-insensitive.

    Returns
    -------
    MeasuredFRF
        Receptance in m/N (interpolation and extrapolation: :class:`MeasuredFRF`).

    Raises
    ------
    MapError
        Empty file, missing columns, an unknown unit, a short row, a bad or
        non-finite number, a negative frequency, frequencies that do not
        increase, or fewer than 2 lines, naming the file and line.
    """
    p = Path(path)
    t = _read_table(p, "FRF")
    cols: dict[str, int] = {}
    scale = {"re": 1.0, "im": 1.0}
    for i, (name, unit) in enumerate(zip(t.names, t.units, strict=True)):
        if name in ("f_hz", "f", "freq", "frequency") and "f" not in cols:
            if name != "f_hz" and unit not in ("hz", None):
                raise MapError(p, t.header_line, f"column {name}: unknown unit {unit!r} (expected Hz)")
            cols["f"] = i
        elif name in ("re", "im") and name not in cols:
            if unit is not None:
                if unit not in _FRF_UNITS:
                    raise MapError(p, t.header_line, f"column {name}: unknown unit {unit!r} (known: m/N, mm/N, µm/N, nm/N)")
                scale[name] = _FRF_UNITS[unit]
            cols[name] = i
    missing = [c for c, k in (("f_hz", "f"), ("re", "re"), ("im", "im")) if k not in cols]
    if missing:
        raise MapError(p, t.header_line, f"FRF header lacks {', '.join(missing)} (expected f_hz,re,im)")
    v = _column_values(t, cols)
    lines = [ln for ln, _ in t.rows]
    f = v["f"]
    if f[0] < 0:
        raise MapError(p, lines[0], f"frequency must be >= 0 Hz, got {f[0]:g}")
    d = np.diff(f)
    if np.any(d <= 0):
        j = int(np.flatnonzero(d <= 0)[0])
        raise MapError(p, lines[j + 1], f"frequency does not increase ({f[j]:g} Hz then {f[j + 1]:g} Hz)")
    if f.size < 2:
        raise MapError(p, None, "an FRF needs at least 2 lines")
    return MeasuredFRF(f, v["re"] * scale["re"] + 1j * v["im"] * scale["im"], str(p))


def read_stock(
    path: str | Path, program: Program, tool: Tool, *, wall: Literal["left", "right"] = "left"
) -> NDArray[np.float64]:
    """Radial depth of cut of every command from an on-machine inspection (OMI) stock file.

    Two formats (blank and ``#`` lines skipped, names case-insensitive, a length
    unit in brackets allowed: ``[mm]`` default, ``[µm]``, ``[inch]``):

    ``x,y,z`` (``z`` optional, read but not used)
        Points probed on the stock face before the cut, mm, in the program's
        frame. Assumed geometry: a vertical wall cut by the side of a
        straight-fluted tool whose programmed path is its axis (R0); the
        finished wall lies on the ``wall`` side of the travel direction, at
        distance R from the path. Each point is projected in XY onto the
        commands' segments; it belongs to the segment it projects onto (ends
        included; the nearest one laterally, the earlier command on a tie),
        and its radial depth is the distance from the tool's wall-side edge to
        the point along the segment's normal: ``a_e = (p − P)·n + R``, n the
        unit normal pointing from the wall to the path. The radial depth of
        command k is interpolated linearly, along the path length of the
        commands, at its end point (the points must lie along one continuous
        cut, e.g. a straight cut along Y with the wall parallel to it).
    ``k,stock_mm`` (or ``k,stock [unit]``)
        The radial depth of command k given directly.

    Parameters
    ----------
    path : str or Path
        The CSV.
    program : Program
        The program the commands belong to.
    tool : Tool
        Its diameter bounds the radial depth; its radius places the wall.
    wall : {"left", "right"}
        Side of the travel direction the finished wall (the material) is on:
        ``left`` for up-milling with a clockwise (M3) spindle, ``right`` for
        down-milling.

    Returns
    -------
    ndarray (K,)
        Radial depth of each command, mm; NaN where the file says nothing
        about a command (outside the probed stretch, or not listed).

    Raises
    ------
    MapError
        Naming the file and line: an empty file, a header that is neither
        format, a short row or bad number, a k that is not a command index or
        appears twice, a point matching no command (it projects onto no
        command or lies behind the finished wall: radial depth ≤ 0), or a
        radial depth larger than the tool diameter.
    """
    p = Path(path)
    if wall not in ("left", "right"):
        raise ValueError(f"wall must be 'left' or 'right', got {wall!r}")
    tool.validate()
    t = _read_table(p, "stock")
    col: dict[str, int] = {}
    scale: dict[str, float] = {}
    for i, (name, unit) in enumerate(zip(t.names, t.units, strict=True)):
        base = name
        if name == "stock_mm":
            base, unit = "stock", unit or "mm"
        if base in ("k", "x", "y", "z", "stock") and base not in col:
            if base != "k" and unit is not None and unit not in _LENGTH_UNITS:
                raise MapError(p, t.header_line, f"column {name}: unknown unit {unit!r} (known: {', '.join(_LENGTH_UNITS)})")
            col[base] = i
            scale[base] = _LENGTH_UNITS.get(unit or "mm", 1.0)
    lines = np.array([ln for ln, _ in t.rows], dtype=np.int64)
    k_cmd = program.n_commands
    d_max = tool.diameter_mm
    out = np.full(k_cmd, np.nan)
    if "k" in col and "stock" in col:
        v = _column_values(t, {"k": col["k"], "stock": col["stock"]})
        kf, ae = v["k"], v["stock"] * scale["stock"]
        seen: dict[int, int] = {}
        for j, (kk, a) in enumerate(zip(kf.tolist(), ae.tolist(), strict=True)):
            ln = int(lines[j])
            if kk < 0 or kk != round(kk):
                raise MapError(p, ln, f"k must be a command index (integer >= 0), got {kk:g}")
            kk = int(kk)
            if kk >= k_cmd:
                raise MapError(p, ln, f"k={kk} matches no command (the program has {k_cmd} commands)")
            if kk in seen:
                raise MapError(p, ln, f"duplicate k={kk} (first on line {seen[kk]})")
            seen[kk] = ln
            _check_point_depth(p, ln, a, d_max, f"command k={kk}")
            out[kk] = a
        return out
    if not ("x" in col and "y" in col):
        found = ", ".join(t.names)
        raise MapError(p, t.header_line, f"stock header must be x,y,z or k,stock_mm (found {found})")
    v = _column_values(t, {c: col[c] for c in ("x", "y", "z") if c in col})
    pts = np.column_stack([v["x"] * scale["x"], v["y"] * scale["y"]])
    idx = program.command_moves
    start = program.moves.start_mm[idx, :2]
    end = program.moves.end_mm[idx, :2]
    seg = end - start
    length = np.hypot(seg[:, 0], seg[:, 1])
    use = length > 1e-9
    if not np.any(use):
        raise MapError(p, None, f"{program.path.name} has no command that moves in XY: stock points match no command")
    tang = np.zeros_like(seg)
    tang[use] = seg[use] / length[use, None]
    left = np.column_stack([-tang[:, 1], tang[:, 0]])
    normal = -left if wall == "left" else left  # from the wall towards the path
    path_at = np.concatenate([[0.0], np.cumsum(np.where(use, length, 0.0))])  # path length at each command start
    tol = 1e-6
    pos = np.empty(pts.shape[0])
    depth = np.empty(pts.shape[0])
    cand = np.flatnonzero(use)
    block = max(1, _CHUNK_CELLS // max(1, cand.size))
    radius = tool.radius_mm
    for lo in range(0, pts.shape[0], block):
        rel = pts[lo:lo + block, None, :] - start[None, cand, :]  # (P, C, 2)
        s = np.einsum("pcj,cj->pc", rel, tang[cand])
        d = np.einsum("pcj,cj->pc", rel, normal[cand])
        inside = (s >= -tol) & (s <= length[cand][None, :] + tol)
        score = np.where(inside, np.abs(d), np.inf)
        best = np.argmin(score, axis=1)
        rows = np.arange(best.size)
        none = ~np.isfinite(score[rows, best])
        if np.any(none):
            j = lo + int(np.flatnonzero(none)[0])
            x, y = pts[j]
            problem = f"stock point ({x:g}, {y:g}) matches no command: it is beside no XY segment of the path"
            raise MapError(p, int(lines[j]), problem)
        ci = cand[best]
        pos[lo:lo + block] = path_at[ci] + np.clip(s[rows, best], 0.0, length[ci])
        depth[lo:lo + block] = d[rows, best] + radius
        dep = depth[lo:lo + block]
        bad = np.flatnonzero((dep <= 0) | (dep > d_max))
        if bad.size:
            j = lo + int(bad[0])
            where = f"stock point ({pts[j, 0]:g}, {pts[j, 1]:g})"
            _check_point_depth(p, int(lines[j]), float(depth[j]), d_max, where, command=int(ci[j - lo]))
    order = np.argsort(pos, kind="stable")
    pos, depth = pos[order], depth[order]
    at_end = path_at[1:]
    covered = use & (at_end >= pos[0] - tol) & (at_end <= pos[-1] + tol)
    out[covered] = np.interp(at_end[covered], pos, depth)
    return out


def _check_point_depth(p: Path, line: int, ae: float, d_max: float, where: str, *, command: int | None = None) -> None:
    """MapError for a radial depth ≤ 0 (matches no cut) or larger than the tool diameter."""
    on = f" (command k={command})" if command is not None else ""
    if ae <= 0:
        behind = "(the stock face lies behind the finished wall)"
        raise MapError(p, line, f"{where}{on} matches no command: radial depth {ae:.4g} mm <= 0 {behind}")
    if ae > d_max:
        raise MapError(p, line, f"{where}{on}: radial depth {ae:.4g} mm is larger than the tool diameter {d_max:g} mm")

"""Surface location error of a helical end mill with runout (seed 004's cut as it was machined).

:mod:`ilcnc.vcnc.deflection` models straight flutes: in up-milling with two
flutes no edge cuts while one generates the wall, so its SLE is only left-over
vibration. A real end mill has a helix and runout:

* **Helix** (angle β): the flute point at height z above the tool tip lags the
  tip by ``z·tan β / R`` rad (right-hand helix, M3 spindle), so while the flute
  generates the wall at height z, the part of it below is still in the chip
  and pushes the tool away from the wall. The tool is cut into ``slices`` disks
  along the axial depth a_p; each disk of each flute takes the force of
  :mod:`ilcnc.vcnc.deflection` (same coefficients, frame and signs) per mm of
  height.
* **Runout** (total indicator reading TIR, µm): the tool axis is offset
  ``e = TIR/2`` from the spindle axis towards angle λ from flute 0, so flute j
  cuts at radius ``R + r_j``, ``r_j = e·cos(2πj/N − λ)``. Its chip is
  ``h_j = c·sin φ + r_j − r_{j−1}`` (the flute before it left the surface
  ``r_{j−1}`` out), ≥ 0: a flute whose chip would be negative does not cut.
  Runout repeats once per revolution, so the force and the displacement are
  periodic in the revolution, not the tooth period.

The displacement normal to the wall is the tool-point receptance times the
force at the spindle harmonics (the frequency-domain method, over one
revolution), evaluated exactly (a Fourier sum) at the instant each flute
passes the generation angle at each disk's height. Flute j leaves the wall at
``SLE_j(z) = s·y(t_j(z)) − r_j`` (s = +1 up-, −1 down-milling; > 0 undercut);
the wall is what the deepest flute left: ``SLE(z) = min_j SLE_j(z)``. The SLE
of a cut is the value of largest magnitude along the axial depth (seed 004
§3.1 takes "the maximum SLE" along the axial depth as its reference).

Same limits as :mod:`ilcnc.vcnc.deflection`: linear, rigid feed, no
regeneration (the chip is the nominal one), only the receptance normal to the
wall. With β = 0 and no runout the result is the straight-flute model's
(``tests/test_helix_sle.py`` checks it).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ilcnc.vcnc.deflection import Cutting, Tool, engagement_angles

__all__ = ["flute_radius_offsets_mm", "sle_helical_per_command_mm", "sle_helical_profile_mm"]

_SAMPLES = 1024  # samples per revolution of the force
_SLICES = 48  # disks along the axial depth


def flute_radius_offsets_mm(tool: Tool) -> NDArray[np.float64]:
    """Radius of each flute minus R from the tool's runout, mm: ``r_j = (TIR/2)·cos(2πj/N − λ)``."""
    e = 0.5 * tool.runout_um * 1e-3
    j = np.arange(tool.teeth)
    return e * np.cos(2.0 * math.pi * j / tool.teeth - math.radians(tool.runout_angle_deg))


def _gen_angle(mode: str) -> float:
    return 0.0 if mode == "up" else math.pi


def _normal_force_per_rev(ae: float, c: float, tool: Tool, cutting: Cutting, samples: int, slices: int
                          ) -> NDArray[np.float64]:
    """F_y (N) over one revolution at ``samples`` instants; sample m has flute 0's tip at φ_gen + 2πm/samples."""
    st, ex = engagement_angles(ae, tool.diameter_mm, cutting.mode)
    st, ex = float(st), float(ex)
    r = flute_radius_offsets_mm(tool)
    dz = cutting.axial_depth_mm / slices
    z = (np.arange(slices) + 0.5) * dz
    lag = z * math.tan(math.radians(tool.helix_deg)) / tool.radius_mm  # (L,)
    step = 2.0 * math.pi / samples
    theta = _gen_angle(cutting.mode) + step * np.arange(samples)  # (M,)
    fy = np.zeros(samples)
    for j in range(tool.teeth):
        phi = theta[:, None] + 2.0 * math.pi * j / tool.teeth - lag[None, :]  # (M, L)
        # the fraction of the sample's cell [φ − step/2, φ + step/2] inside [φ_st, φ_ex], as deflection does:
        # a force jump at entry or exit counts by its cell average, so the result is continuous in a_e
        psi = np.mod(phi - st + step, 2.0 * math.pi) - step
        w = np.clip(psi / step + 0.5, 0.0, 1.0) * np.clip((ex - st - psi) / step + 0.5, 0.0, 1.0)
        ang = st + psi
        h = c * np.sin(ang) + (r[j] - r[j - 1])
        w = np.where(h > 0.0, w, 0.0)  # a flute whose chip would be negative does not cut
        s, co = np.sin(ang), np.cos(ang)
        ft = cutting.ktc_n_mm2 * h + cutting.kte_n_mm
        fr = cutting.krc_n_mm2 * h + cutting.kre_n_mm
        fy += np.sum(w * (-ft * s + fr * co), axis=1) * dz
    return fy


def sle_helical_profile_mm(radial_depth_mm: float, feed_per_tooth_mm: float, tool: Tool, cutting: Cutting, *,
                           samples: int = _SAMPLES, slices: int = _SLICES
                           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """SLE along the axial depth of one cut, mm (> 0: undercut).

    Parameters
    ----------
    radial_depth_mm, feed_per_tooth_mm : float
        a_e (0 < a_e ≤ D) and c, mm.
    tool, cutting : Tool, Cutting
        ``tool.helix_deg``, ``tool.runout_um`` and ``tool.runout_angle_deg`` are used; validated here.
    samples : int
        Force samples per revolution (even, ≥ 8).
    slices : int
        Disks along the axial depth (≥ 1).

    Returns
    -------
    z_mm : ndarray (slices,)
        Height of each disk's middle above the tool tip, mm.
    sle_mm : ndarray (slices,)
        SLE of the wall at that height: the deepest flute's, mm.
    """
    tool.validate()
    cutting.validate()
    if samples < 8 or samples % 2:
        raise ValueError(f"samples must be even and >= 8, got {samples}")
    if slices < 1:
        raise ValueError(f"slices must be >= 1, got {slices}")
    fy = _normal_force_per_rev(float(radial_depth_mm), float(feed_per_tooth_mm), tool, cutting, samples, slices)
    f_rev = cutting.spindle_rpm / 60.0
    n = np.arange(samples // 2 + 1)
    coef = np.fft.rfft(fy) / samples * tool.frf_normal(f_rev * n)  # displacement harmonics, m
    coef[1:] *= 2.0
    coef[-1] = 0.0  # the Nyquist bin carries no complex gain
    dz = cutting.axial_depth_mm / slices
    z = (np.arange(slices) + 0.5) * dz
    lag = z * math.tan(math.radians(tool.helix_deg)) / tool.radius_mm
    r = flute_radius_offsets_mm(tool)
    sign = 1.0 if cutting.mode == "up" else -1.0
    sle = np.full(slices, np.inf)
    for j in range(tool.teeth):
        # flute j at height z is at φ_gen when flute 0's tip has turned lag(z) − 2πj/N past φ_gen
        theta = lag - 2.0 * math.pi * j / tool.teeth
        y_m = np.real(np.exp(1j * np.outer(theta, n)) @ coef)
        sle = np.minimum(sle, sign * y_m * 1e3 - r[j])
    return z, sle


def sle_helical_per_command_mm(radial_depth_mm: ArrayLike, feed_per_tooth_mm: ArrayLike, tool: Tool,
                               cutting: Cutting, *, samples: int = _SAMPLES, slices: int = _SLICES
                               ) -> NDArray[np.float64]:
    """SLE of every command, mm: the value of largest magnitude along the axial depth (> 0: undercut).

    Parameters
    ----------
    radial_depth_mm : array_like (K,)
        Radial depth of each command, mm; NaN gives NaN.
    feed_per_tooth_mm : array_like (K,) or float
        Feed per tooth of each command, mm (≥ 0).
    tool, cutting : Tool, Cutting
    samples, slices : int
        As :func:`sle_helical_profile_mm`.

    Returns
    -------
    ndarray (K,)
        SLE, mm. Each distinct (a_e, c) pair is computed once.

    Raises
    ------
    ValueError
        A radial depth ≤ 0 or above the diameter, or a bad feed per tooth, naming the command k.
    """
    ae = np.atleast_1d(np.asarray(radial_depth_mm, dtype=np.float64))
    c = np.broadcast_to(np.asarray(feed_per_tooth_mm, dtype=np.float64), ae.shape)
    out = np.full(ae.shape, np.nan)
    known = ~np.isnan(ae)
    bad = known & ~((ae > 0) & (ae <= tool.diameter_mm))
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        raise ValueError(f"command k={k}: radial depth {ae[k]:g} mm must be in (0, {tool.diameter_mm:g}] mm")
    bad_c = known & ~(np.isfinite(c) & (c >= 0))
    if np.any(bad_c):
        k = int(np.flatnonzero(bad_c)[0])
        raise ValueError(f"command k={k}: feed per tooth must be a finite number >= 0, got {c[k]:g}")
    if not np.any(known):
        return out
    pairs, inverse = np.unique(np.column_stack([ae[known], c[known]]), axis=0, return_inverse=True)
    values = np.empty(pairs.shape[0])
    for i, (a, cc) in enumerate(pairs):
        _z, s = sle_helical_profile_mm(float(a), float(cc), tool, cutting, samples=samples, slices=slices)
        values[i] = s[int(np.argmax(np.abs(s)))]
    out[known] = values[np.asarray(inverse).ravel()]
    return out

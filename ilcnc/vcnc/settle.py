"""How long the axes take to settle after a stop: the tail of the drive models' step response.

A control that stops at the end of a rapid stops its *command*; the axes still lag it by what the drive
leaves at the stop (on a type-1 position loop about ``a·τ²`` after a deceleration ``a``, plus what the
planner's last samples add) and close that lag along their step response. A feed that starts at once
(LinuxCNC: no in-position wait) starts while they catch up, and its first millimetres are cut off the path
by the rest of the lag. A dwell (``G4 P``) of :func:`settle_time_s` lets the lag fall from ``lag_mm`` to
``target_mm`` first.

The tail is taken from the profile's own drive models (:func:`ilcnc.vcnc.drives.axis_response` of a unit
step, sampled at the servo period), so it holds for every model the profile may name: a first-order lag
with a dead time settles in ``delay + τ·ln(lag/target)``, a drive that overshoots settles when its ringing
stays inside the band. The slowest axis decides (the lag is in the rapid's direction, which may use any).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from ilcnc.profile.sections import MachineProfile

__all__ = ["MAX_SETTLE_S", "settle_time_s"]

#: Longest settle computed, s: a drive that has not settled by then is reported at this bound (a dwell longer
#: than this after a rapid would be a slow machine, not a lag).
MAX_SETTLE_S = 2.0


def _step_tails(profile: MachineProfile) -> tuple[NDArray[np.float64], float]:
    """For the slowest axis at each sample: the largest ``|y(t') - y(∞)|`` for ``t' ≥ t`` of a unit step, and the
    period, s."""
    from ilcnc.vcnc.drives import axis_response

    period = float(profile.machine.servo_period_s)
    n = max(math.ceil(MAX_SETTLE_S / period), 2)
    ref = np.ones(n + 1)
    ref[0] = 0.0
    worst = np.zeros(n + 1)
    for axis in profile.axes.values():
        y = axis_response(axis.drive, ref, period)
        dev = np.abs(y - y[-1])
        tail = np.maximum.accumulate(dev[::-1])[::-1]  # the largest deviation from here on
        np.maximum(worst, tail, out=worst)
    return worst, period


def settle_time_s(profile: MachineProfile, lag_mm: NDArray[np.float64] | float,
                  target_mm: float) -> NDArray[np.float64]:
    """Dwell after a stop that lets the axes' lag fall from ``lag_mm`` to ``target_mm``, s.

    Parameters
    ----------
    profile : MachineProfile
        The machine: every axis's drive model and the servo period.
    lag_mm : float or ndarray
        Lag left at the stop, mm (e.g. a first run's contour error where the feed after a rapid starts).
    target_mm : float
        Lag to settle to, mm (> 0).

    Returns
    -------
    ndarray
        Settle time per lag, s, a whole number of servo periods (0 where ``lag_mm <= target_mm``; at most
        :data:`MAX_SETTLE_S`).
    """
    lag = np.atleast_1d(np.asarray(lag_mm, dtype=np.float64))
    if target_mm <= 0.0:
        raise ValueError("target_mm must be > 0")
    tail, period = _step_tails(profile)
    ratio = np.where(lag > target_mm, target_mm / np.where(lag > 0, lag, 1.0), np.inf)
    # first sample from which the step stays inside the band ratio (the tail is non-increasing)
    rev = tail[::-1]
    k = tail.size - np.searchsorted(rev, ratio, side="right")
    k = np.where(np.isfinite(ratio), k, 0)
    return np.minimum(k * period, MAX_SETTLE_S)

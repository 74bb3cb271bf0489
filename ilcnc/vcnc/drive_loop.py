"""The drives' compiled loop: axes with friction (and cross-coupled axes) simulated period by period.

Where a drive is not linear (the P-FF drive's Coulomb/Stribeck friction with stiction) or two axes are coupled
by a contour controller, the loop is run sample by sample in numba kernels with sub-steps inside each servo
period; :func:`friction_steps` is the exact step of the stuck and sliding system. The linear drives take the
filter path of :mod:`ilcnc.vcnc.drives` instead.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ilcnc._jit import HAVE_NUMBA, njit
from ilcnc.vcnc.discrete import FRICTION_SUBSTEP_S, STANDSTILL_MM, DriveModelError, LoopPlant, discretise, zoh_discretize

__all__ = ["direction_normals", "path_normals"]


# --------------------------------------------------------------------------
# The compiled loop
# --------------------------------------------------------------------------


@njit(cache=True, inline="always")
def friction_steps(x, xn, u, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus):  # pragma: no cover
    """``nsub`` exact sub-steps of one axis with the friction force resolved implicitly (stick-slip).

    Each sub-step first moves the linear part without friction (``xn``). If
    the velocity it reaches is within what the breakaway force can stop
    (``|v| <= bstick·fbreak``) the axis sticks: a moving axis comes to rest
    at the end of the sub-step under the friction force that stops it
    (exact for a force held over the sub-step), an axis at rest takes the
    exact step of the stuck system (``phis``, ``gus``: velocity 0, position
    unchanged, the controller states integrating). Otherwise the kinetic
    friction (Coulomb plus the Stribeck peak at the sub-step's starting
    velocity) opposes the motion, held over the sub-step.
    """
    n = x.shape[0]
    for _ in range(nsub):
        vprev = 0.0
        vfree = 0.0
        for i in range(n):
            vprev += cv[i] * x[i]
        for i in range(n):
            s = guh[i] * u
            for j in range(n):
                s += phih[i, j] * x[j]
            xn[i] = s
            vfree += cv[i] * s
        if abs(vfree) <= bstick * fbreak and vprev == 0.0:  # stays stuck
            for i in range(n):
                s = gus[i] * u
                for j in range(n):
                    s += phis[i, j] * x[j]
                xn[i] = s
            for i in range(n):
                x[i] = xn[i]
        elif abs(vfree) <= bstick * fbreak:  # comes to rest: the friction force that stops it exactly
            force = vfree / bstick
            for i in range(n):
                x[i] = xn[i] - gfh[i] * force
            vrest = 0.0
            for i in range(n):
                vrest += cv[i] * x[i]
            for i in range(n):
                x[i] -= cv[i] * vrest  # exactly 0, not rounding
        else:
            sgn = 1.0 if vfree > 0.0 else -1.0
            if vprev * sgn > 0.0:
                mag = fc
                if vs > 0.0:
                    ratio2 = (vprev / vs) ** 2
                    if ratio2 < 50.0:  # exp(-50) ~ 2e-22: no Stribeck term left
                        mag += (fbreak - fc) * math.exp(-ratio2)
            else:
                mag = fbreak
            force = sgn * mag
            for i in range(n):
                x[i] = xn[i] - gfh[i] * force


@njit(cache=True, inline="always")
def _linear_step(x, xn, u0, u1, phi, g0, g1):  # pragma: no cover - compiled
    """One servo period ``x = Φ x + Γ0 u0 + Γ1 u1``."""
    n = x.shape[0]
    for i in range(n):
        s = g0[i] * u0 + g1[i] * u1
        for j in range(n):
            s += phi[i, j] * x[j]
        xn[i] = s
    for i in range(n):
        x[i] = xn[i]


@njit(cache=True)
def _loop_kernel(
    dr, vref, nrm, cgain, phi, g0, g1, cq, delay, kff, kerr, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus
):  # pragma: no cover - compiled; its Python version is tested through py_func
    """Sampled position loops of ``m`` axes (1 or 2), optionally cross-coupled and with friction.

    Per servo period k and axis a: ``q = cq·x``; ``e = r − q``; with two axes
    and ``cgain != 0``: ``ε = n·e`` and ``e += cgain·ε·n``; ``u = kff·v_ref +
    kerr·e``; then either ``x = Φ x + Γ0 u[k−d] + Γ1 u[k−d−1]`` or, with
    friction (``nsub > 0``, no dead time), ``nsub`` exact sub-steps with the
    friction force resolved implicitly (:func:`friction_steps`).
    """
    npts, m = dr.shape
    n = phi.shape[1]
    out = np.empty((npts, m))
    x = np.zeros((m, n))
    xn = np.zeros(n)
    hlen = 2
    for a in range(m):
        if delay[a] + 2 > hlen:
            hlen = delay[a] + 2
    hist = np.zeros((m, hlen))
    pos = 0  # slot of u[k] in the ring buffer hist
    e = np.zeros(m)
    for k in range(npts):
        for a in range(m):
            q = 0.0
            for i in range(n):
                q += cq[a, i] * x[a, i]
            out[k, a] = q
            e[a] = dr[k, a] - q
        if m == 2 and cgain != 0.0:
            eps = nrm[k, 0] * e[0] + nrm[k, 1] * e[1]
            e[0] += cgain * eps * nrm[k, 0]
            e[1] += cgain * eps * nrm[k, 1]
        for a in range(m):
            u = kff[a] * vref[k, a] + kerr[a] * e[a]
            if nsub[a] > 0:
                friction_steps(
                    x[a], xn, u, nsub[a], phih[a], guh[a], gfh[a], cv[a], bstick[a], fc[a], fbreak[a], vs[a], phis[a], gus[a]
                )
            else:
                d = delay[a]
                hist[a, pos] = u  # the history starts at 0: u before k = 0 is 0
                i0 = pos - d
                if i0 < 0:
                    i0 += hlen
                i1 = i0 - 1 if i0 > 0 else hlen - 1
                u0 = hist[a, i0]
                u1 = hist[a, i1]
                _linear_step(x[a], xn, u0, u1, phi[a], g0[a], g1[a])
        pos = pos + 1 if pos + 1 < hlen else 0
    return out


@njit(cache=True)
def _friction_kernel(
    dr, vref, cq, kff, kerr, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus
):  # pragma: no cover - compiled; its Python version is tested through py_func
    """One axis of :func:`_loop_kernel` with friction, without coupling (the fast common case)."""
    npts = dr.shape[0]
    n = cq.shape[0]
    out = np.empty(npts)
    x = np.zeros(n)
    xn = np.zeros(n)
    for k in range(npts):
        q = 0.0
        for i in range(n):
            q += cq[i] * x[i]
        out[k] = q
        u = kff * vref[k] + kerr * (dr[k] - q)
        friction_steps(x, xn, u, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus)
    return out


#: Per-axis arrays of :func:`_friction_kernel`, in argument order.
_FRICTION_ARGS = ("cq", "kff", "kerr", "nsub", "phih", "guh", "gfh", "cv", "bstick", "fc", "fbreak", "vs", "phis", "gus")

_warned_no_numba = False


def _warn_no_numba() -> None:
    global _warned_no_numba
    if not HAVE_NUMBA and not _warned_no_numba:  # pragma: no cover
        warnings.warn("numba is not installed: the friction and cross-coupled loops run as slow Python", stacklevel=3)
        _warned_no_numba = True


def stuck_system(a: np.ndarray, b: np.ndarray, cv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The system with the velocity state held at 0 (its row and column removed from the dynamics)."""
    iv = int(np.argmax(cv))
    a_s = a.copy()
    a_s[iv, :] = 0.0
    a_s[:, iv] = 0.0
    b_s = b.copy()
    b_s[iv] = 0.0
    return a_s, b_s


def _kernel_arrays(plants: list[LoopPlant], period_s: float, *, loop: bool = False) -> dict[str, np.ndarray]:
    """Per-axis matrices of the compiled loop, padded to the largest state dimension (``loop``: the
    sub-stepped friction matrices also for an axis without friction, e.g. to run it with a gain schedule)."""
    m = len(plants)
    n = max(p.n for p in plants)
    arr = {
        "phi": np.zeros((m, n, n)),
        "g0": np.zeros((m, n)),
        "g1": np.zeros((m, n)),
        "cq": np.zeros((m, n)),
        "delay": np.zeros(m, dtype=np.int64),
        "kff": np.zeros(m),
        "kerr": np.zeros(m),
        "nsub": np.zeros(m, dtype=np.int64),
        "phih": np.zeros((m, n, n)),
        "guh": np.zeros((m, n)),
        "gfh": np.zeros((m, n)),
        "cv": np.zeros((m, n)),
        "bstick": np.ones(m),
        "fc": np.zeros(m),
        "fbreak": np.zeros(m),
        "vs": np.zeros(m),
        "phis": np.zeros((m, n, n)),
        "gus": np.zeros((m, n)),
    }
    for i, p in enumerate(plants):
        k = p.n
        ss = discretise(p.a, p.bu, p.c, period_s, p.delay_s)
        arr["phi"][i, :k, :k] = ss.phi
        arr["g0"][i, :k] = ss.g0
        arr["g1"][i, :k] = ss.g1
        arr["cq"][i, :k] = p.c
        arr["delay"][i] = ss.delay
        arr["kff"][i] = p.kff
        arr["kerr"][i] = p.kerr
        if p.nonlinear or (loop and p.bf is not None and p.cv is not None):
            assert p.bf is not None and p.cv is not None and p.delay_s == 0.0
            nsub = max(1, math.ceil(period_s / FRICTION_SUBSTEP_S - 1e-9))
            phih, gh = zoh_discretize(p.a, np.column_stack([p.bu, p.bf]), period_s / nsub)
            arr["nsub"][i] = nsub
            arr["phih"][i, :k, :k] = phih
            arr["guh"][i, :k] = gh[:, 0]
            arr["gfh"][i, :k] = gh[:, 1]
            arr["cv"][i, :k] = p.cv
            arr["bstick"][i] = float(p.cv @ gh[:, 1])
            arr["fc"][i] = p.coulomb_n
            arr["fbreak"][i] = p.breakaway_n
            arr["vs"][i] = p.stribeck_mm_s
            phis, gus = zoh_discretize(*stuck_system(p.a, p.bu, p.cv), period_s / nsub)
            arr["phis"][i, :k, :k] = phis
            arr["gus"][i, :k] = gus
    return arr


def friction_column(plant: LoopPlant, ref: np.ndarray, out: np.ndarray, period_s: float,
                     kerr_1_s: np.ndarray | None = None) -> None:
    """``out = r[0] + q`` of one friction axis (what :func:`axis_response` computes) without whole-array temporaries.

    ``kerr_1_s`` (N,): a position gain per servo period, 1/s (a gain schedule) instead of the plant's own.
    """
    if ref.shape[0] and not _all_finite(ref):
        raise ValueError("the reference contains NaN or infinite values")
    _warn_no_numba()
    arr = _kernel_arrays([plant], period_s, loop=kerr_1_s is not None)
    args = [arr[k][0] for k in _FRICTION_ARGS]
    i = _FRICTION_ARGS.index("kerr")
    args[i] = np.array([args[i]]) if kerr_1_s is None else np.ascontiguousarray(kerr_1_s, dtype=np.float64)
    if ref.shape[0] and not _friction_ref_kernel(ref, out, float(period_s), *args):  # pragma: no cover
        raise DriveModelError("the simulated loop diverged (unstable closed loop)")


@njit(cache=True, nogil=True)
def _all_finite(x):  # pragma: no cover - compiled
    """``np.all(np.isfinite(x))`` without a temporary."""
    for k in range(x.shape[0]):
        if not math.isfinite(x[k]):
            return False
    return True


@njit(cache=True, nogil=True)
def _friction_ref_kernel(
    ref, out, period_s, cq, kff, kerr, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus
):  # pragma: no cover - compiled; checked against _friction_kernel
    """:func:`_friction_kernel` fed from the reference itself: the deviation ``r − r0`` and the
    velocity ``(dev[k] − dev[k−1]) / T`` are formed per sample and ``r0 + q`` is written to ``out``
    (same numbers, no whole-array temporaries). ``kerr`` holds one gain, or one per sample (a gain
    schedule). False if the output is not finite."""
    npts = ref.shape[0]
    n = cq.shape[0]
    per_sample = kerr.shape[0] > 1
    x = np.zeros(n)
    xn = np.zeros(n)
    r0 = ref[0]
    prev = 0.0
    ok = True
    for k in range(npts):
        dev = ref[k] - r0
        vref = (dev - (prev if k > 0 else dev)) / period_s
        prev = dev
        q = 0.0
        for i in range(n):
            q += cq[i] * x[i]
        if not math.isfinite(q):
            ok = False
        out[k] = r0 + q
        u = kff * vref + kerr[k if per_sample else 0] * (dev - q)
        friction_steps(x, xn, u, nsub, phih, guh, gfh, cv, bstick, fc, fbreak, vs, phis, gus)
    return ok


def run_loop(plants: list[LoopPlant], dev: np.ndarray, period_s: float, nrm: np.ndarray, gain: float) -> np.ndarray:
    """Run the compiled loop on deviations ``dev`` (N, m); returns position deviations (N, m)."""
    _warn_no_numba()
    arr = _kernel_arrays(plants, period_s)
    vref = np.diff(dev, axis=0, prepend=dev[:1]) / period_s
    if len(plants) == 1 and arr["nsub"][0] > 0:
        args = [arr[k][0] for k in _FRICTION_ARGS]
        out = _friction_kernel(np.ascontiguousarray(dev[:, 0]), np.ascontiguousarray(vref[:, 0]), *args)[:, None]
        if not np.all(np.isfinite(out)):  # pragma: no cover - the implicit friction step cannot diverge
            raise DriveModelError("the simulated loop diverged (unstable closed loop)")
        return out
    out = _loop_kernel(
        np.ascontiguousarray(dev),
        np.ascontiguousarray(vref),
        np.ascontiguousarray(nrm, dtype=float),
        float(gain),
        arr["phi"],
        arr["g0"],
        arr["g1"],
        arr["cq"],
        arr["delay"],
        arr["kff"],
        arr["kerr"],
        arr["nsub"],
        arr["phih"],
        arr["guh"],
        arr["gfh"],
        arr["cv"],
        arr["bstick"],
        arr["fc"],
        arr["fbreak"],
        arr["vs"],
        arr["phis"],
        arr["gus"],
    )
    if not np.all(np.isfinite(out)):
        raise DriveModelError("the simulated loop diverged (unstable closed loop)")
    return out


def path_normals(ref_2d: np.ndarray) -> np.ndarray:
    """Unit normals ``n = (−sin θ, cos θ)`` of a planar reference path, per sample.

    Parameters
    ----------
    ref_2d : ndarray, shape (N, 2)
        Reference of the two coupled axes, mm.

    Returns
    -------
    ndarray, shape (N, 2)
        ``θ`` is the direction of the central difference of the reference
        (forward/backward at the ends); where the reference stands still the
        direction of the nearest earlier motion is held (before the first
        motion: the first motion's; no motion at all: θ = 0).
    """
    r = np.asarray(ref_2d, dtype=float)
    npts = r.shape[0]
    if npts < 2:
        return np.tile([0.0, 1.0], (npts, 1))
    d = np.empty_like(r)
    d[1:-1] = r[2:] - r[:-2]
    d[0] = r[1] - r[0]
    d[-1] = r[-1] - r[-2]
    return direction_normals(d, STANDSTILL_MM)


def direction_normals(dir_2d: np.ndarray, min_norm: float = 1e-6) -> np.ndarray:
    """Unit normals ``n = (−sin θ, cos θ)`` of per-sample path directions.

    Parameters
    ----------
    dir_2d : ndarray, shape (N, 2)
        Direction of the path at each sample in the plane of the two coupled axes: any length (the in-plane part
        of a unit tangent, a difference of positions in mm).
    min_norm : float
        A direction shorter than this is none (a stand-still, a move square to the plane): the
        nearest earlier valid direction is held (before the first: the first one's; none at all: θ = 0).

    Returns
    -------
    ndarray, shape (N, 2)
    """
    d = np.asarray(dir_2d, dtype=float)
    npts = d.shape[0]
    norm = np.hypot(d[:, 0], d[:, 1])
    valid = norm > min_norm
    if not np.any(valid):
        return np.tile([0.0, 1.0], (npts, 1))
    idx = np.where(valid, np.arange(npts), -1)
    idx = np.maximum.accumulate(idx)
    idx[idx < 0] = int(np.argmax(valid))
    t = d[idx] / norm[idx, None]
    return np.column_stack([-t[:, 1], t[:, 0]])



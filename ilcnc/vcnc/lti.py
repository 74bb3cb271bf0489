"""The three linear-system conversions the drive models need, without importing :mod:`scipy.signal`.

``import scipy.signal`` takes 1.4-1.7 s under SciPy 1.17 (it builds its array-API wrappers and parses
docstrings at import), ten times what a small simulation costs in all (issue 24). The discretisation of
the drive models uses three of its functions, for single-input single-output systems only; they are
written out here with SciPy's own operations, in SciPy's order, on the same NumPy and SciPy routines
(``numpy.poly``, ``scipy.linalg.expm``), so the results are the same bit for bit
(``tests/test_startup.py`` compares them with :mod:`scipy.signal` on every shipped profile's drives and
on random systems):

- :func:`tf2ss`: ``scipy.signal.tf2ss`` (controller canonical form, after ``scipy.signal.normalize``);
- :func:`ss2tf`: ``scipy.signal.ss2tf`` for one input;
- :func:`cont2discrete_zoh`: the ``A, B`` of ``scipy.signal.cont2discrete(..., method="zoh")``: the
  exponential of the block matrix ``[[A, B], [0, 0]]·dt``.

The exponentials are kept in a small cache on disk (:func:`expm_cached`): a later run with the same drives
reads SciPy's result back instead of importing :mod:`scipy.linalg` (0.1-0.2 s, a third of a small
program's whole command once numba is not imported either: issue 24).

Adapted from SciPy (``scipy/signal/_lti_conversion.py``, ``_filter_design.normalize``), BSD-3-Clause,
Copyright (c) 2001-2002 Enthought, Inc. 2003, SciPy Developers.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import warnings
from pathlib import Path

import numpy as np

from ilcnc.errors import IlcncError

__all__ = ["EXPM_CACHE_MAX", "BadCoefficients", "cont2discrete_zoh", "expm_cache_dir", "expm_cached", "ss2tf",
           "tf2ss"]

#: Most exponentials kept on disk: a profile's drives need ~10; a tuning or identification loop asks for
#: thousands of different ones, which are not written once the folder holds this many.
EXPM_CACHE_MAX = 256


class BadCoefficients(UserWarning):
    """The numerator's leading coefficients are (nearly) zero (``scipy.signal.BadCoefficients``)."""


def _trim_leading_zeros(x: np.ndarray) -> np.ndarray:
    first = 0
    for v in x:
        if v != 0.0:
            break
        first += 1
    return x[first:]


def _normalize(b: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal.normalize`` for one numerator: leading zeros of ``a`` dropped, both divided by ``a[0]``."""
    den = np.atleast_1d(np.asarray(a))
    num = np.atleast_2d(np.asarray(b))
    if den.ndim != 1:
        raise ValueError("Denominator polynomial must be rank-1 array.")
    if num.ndim > 2:
        raise ValueError("Numerator polynomial must be rank-1 or rank-2 array.")
    if np.all(den == 0):
        raise ValueError("Denominator must have at least on nonzero element.")
    den = _trim_leading_zeros(den)
    num, den = num / den[0], den / den[0]
    leading_zeros = 0
    for j in range(num.shape[-1]):
        if np.all(np.abs(num[:, j]) <= 1e-14):
            leading_zeros += 1
        else:
            break
    if leading_zeros > 0:
        warnings.warn("Badly conditioned filter coefficients (numerator): the results may be meaningless",
                      BadCoefficients, stacklevel=3)
        if leading_zeros == num.shape[1]:
            leading_zeros -= 1
        num = num[:, leading_zeros:]
    if num.shape[0] == 1:
        num = num[0, :]
    return num, den


def tf2ss(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``scipy.signal.tf2ss(num, den)``: ``A, B, C, D`` in controller canonical form."""
    num, den = _normalize(num, den)
    if num.ndim == 1:
        num = np.asarray([num], num.dtype)
    m = num.shape[1]
    k = len(den)
    if m > k:
        raise ValueError("Improper transfer function. `num` is longer than `den`.")
    if m == 0 or k == 0:
        return np.array([], float), np.array([], float), np.array([], float), np.array([], float)
    num = np.hstack((np.zeros((num.shape[0], k - m), dtype=num.dtype), num))
    d = np.atleast_2d(num[:, 0]) if num.shape[-1] > 0 else np.array([[0]], float)
    if k == 1:
        d = d.reshape(num.shape)
        return np.zeros((1, 1)), np.zeros((1, d.shape[1])), np.zeros((d.shape[0], 1)), d
    frow = -np.array([den[1:]])
    a = np.r_[frow, np.eye(k - 2, k - 1)]
    b = np.eye(k - 1, 1)
    c = num[:, 1:] - np.outer(num[:, 0], den[1:])
    d = d.reshape((c.shape[0], b.shape[1]))
    return a, b, c, d


def ss2tf(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal.ss2tf(A, B, C, D)`` of the first input: ``num`` (one row per output) and ``den``."""
    a, b, c, d = (np.atleast_2d(np.asarray(x)) for x in (a, b, c, d))
    n = a.shape[0]
    if not (a.shape == (n, n) and b.shape[0] == n and c.shape[1] == n and d.shape == (c.shape[0], b.shape[1])
            and n > 0):
        raise ValueError(f"ss2tf: incompatible shapes A {a.shape}, B {b.shape}, C {c.shape}, D {d.shape}")
    nout = d.shape[0]
    b = b[:, 0:1]
    d = d[:, 0:1]
    den = np.poly(a)
    type_test = a[:, 0] + b[:, 0] + c[0, :] + d + 0.0
    num = np.empty((nout, n + 1), type_test.dtype)
    for k in range(nout):
        ck = np.atleast_2d(c[k, :])
        num[k] = np.poly(a - np.dot(b, ck)) + (d[k] - 1) * den
    return num, den


def cont2discrete_zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``ad, bd`` of ``scipy.signal.cont2discrete((A, B, C, D), dt, method="zoh")`` (``b`` is (n, m))."""
    em_upper = np.hstack((a, b))
    em_lower = np.hstack((np.zeros((b.shape[1], a.shape[0])), np.zeros((b.shape[1], b.shape[1]))))
    em = np.vstack((em_upper, em_lower))
    ms = expm_cached(dt * em)
    ms = ms[: a.shape[0], :]
    return ms[:, 0 : a.shape[1]], ms[:, a.shape[1] :]


def _expm(m: np.ndarray) -> np.ndarray:
    from ilcnc._lazy import defer_numpy_extras
    from ilcnc._threads import one_blas_thread

    defer_numpy_extras()  # before scipy.linalg's import (issue 24: start-up)
    from scipy.linalg import expm  # ~0.1-0.25 s, and only when a drive model is discretised

    with one_blas_thread():  # a 4x4 exponential: OpenBLAS's thread pool only makes it 300x slower (issue 24)
        return expm(m)


def expm_cache_dir() -> Path | None:
    """Where :func:`expm_cached` keeps its files: ``$NUMBA_CACHE_DIR/ilcnc-expm`` when that is set (where numba
    keeps its kernels), else ``__pycache__/expm`` beside this module (as numba does); None when neither can be
    made (then nothing is cached)."""
    base = os.environ.get("NUMBA_CACHE_DIR")
    d = Path(base) / "ilcnc-expm" if base else Path(__file__).resolve().parent / "__pycache__" / "expm"
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return d if os.access(d, os.W_OK) else None


def _scipy_stamp() -> bytes:
    """What names the SciPy that computed an entry: its ``version.py`` (version and git revision)."""
    spec = importlib.util.find_spec("scipy")
    if spec is None or spec.origin is None:
        return b""
    try:
        return (Path(spec.origin).parent / "version.py").read_bytes()
    except OSError:
        return b""


def expm_cached(m: np.ndarray) -> np.ndarray:
    """``scipy.linalg.expm(m)`` of a float64 matrix, read from the cache when this SciPy computed it before.

    Why a cache of our own: a drive model's discretisation needs the exponential of a 3x3-6x6 matrix, and
    ``import scipy.linalg`` alone costs 0.1-0.2 s. The key is the matrix's bytes and SciPy's version file, the
    value is SciPy's result as it was, so a hit gives the same numbers bit for bit; each file carries a
    SHA-256 of its content, a file that does not match is computed again. Writes are atomic
    (:func:`ilcnc.fileio.write_atomic`) and best effort: a folder that cannot be written caches nothing.
    """
    a = np.ascontiguousarray(m, dtype=np.float64)
    d = expm_cache_dir() if a.ndim == 2 else None
    if d is None:
        return _expm(a)
    key = hashlib.sha256(repr(a.shape).encode() + a.tobytes() + _scipy_stamp()).hexdigest()[:40]
    path = d / f"{key}.f64"
    try:
        data = path.read_bytes()
    except OSError:
        data = b""
    body, digest = data[:-32], data[-32:]
    if len(body) == a.nbytes and hashlib.sha256(body).digest() == digest:
        return np.frombuffer(body, dtype=np.float64).reshape(a.shape).copy()
    out = _expm(a)
    try:
        if len(os.listdir(d)) < EXPM_CACHE_MAX:
            from ilcnc.fileio import unsynced_writes, write_atomic

            body = np.ascontiguousarray(out, dtype=np.float64).tobytes()
            with unsynced_writes():  # a torn file fails its SHA-256 and is computed again
                write_atomic(path, body + hashlib.sha256(body).digest())
    except (OSError, IlcncError):
        pass
    return out

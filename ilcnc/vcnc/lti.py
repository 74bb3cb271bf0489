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

Adapted from SciPy (``scipy/signal/_lti_conversion.py``, ``_filter_design.normalize``), BSD-3-Clause,
Copyright (c) 2001-2002 Enthought, Inc. 2003, SciPy Developers.
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["BadCoefficients", "cont2discrete_zoh", "ss2tf", "tf2ss"]


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
    from ilcnc._lazy import defer_numpy_extras
    from ilcnc._threads import one_blas_thread

    defer_numpy_extras()  # before scipy.linalg's import (issue 24: start-up)
    from scipy.linalg import expm  # ~0.25 s, and only when a drive model is discretised

    em_upper = np.hstack((a, b))
    em_lower = np.hstack((np.zeros((b.shape[1], a.shape[0])), np.zeros((b.shape[1], b.shape[1]))))
    em = np.vstack((em_upper, em_lower))
    with one_blas_thread():  # a 4x4 exponential: OpenBLAS's thread pool only makes it 300x slower (issue 24)
        ms = expm(dt * em)
    ms = ms[: a.shape[0], :]
    return ms[:, 0 : a.shape[1]], ms[:, a.shape[1] :]

"""Compiled scanner for plain CAM blocks (large programs).

The G-code reader classifies every line as a *plain block*
``[N..] [G0-3] [X] [Y] [Z] [I] [J] [K] [R] [F]`` (in this order but for X, Y
and Z, which may come in any order, each once; literal numbers) or *other*.
For small files one regular expression does it; for large ones this numba
loop over the bytes does the same in one pass and parses the numbers on the
way (measured on the 169,220-line sample: ~0.05 s against ~0.55 s for the
regular expression plus numpy's string parsing, which is why the project
carries its own scanner here).

It accepts exactly what ``gcode_plain.FAST_LINE`` accepts, and is checked against
it line by line on every sample (``tests/test_gcode.py``). A number is parsed
as ``mantissa / 10**decimals`` with both exact in binary (at most 15
significant digits, at most 22 decimals), which is the correctly rounded value,
the same as ``float(text)``; anything longer is left to the general lexer.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ilcnc._jit import HAVE_NUMBA, njit

__all__ = ["AVAILABLE", "plain_block_spans", "scan_plain_blocks"]

AVAILABLE = HAVE_NUMBA

_POW10 = np.array([10.0**i for i in range(23)])

# expected letters in order after the optional G word: X Y Z (any order) I J K R F (upper, lower)
_ORDER_UPPER = np.array([ord(c) for c in "XYZIJKRF"], dtype=np.uint8)


def _scan_impl(buf, starts, ends, pow10, order, out, slow, spans, want_spans):  # pragma: no cover - compiled
    n = starts.shape[0]
    for li in range(n):
        p = starts[li]
        e = ends[li]
        if want_spans:
            for c in range(9):
                spans[li, c, 0] = -1
                spans[li, c, 1] = -1
        if e > p and buf[e - 1] == 13:
            e -= 1
        for c in range(9):
            out[li, c] = np.nan
        ok = True
        while p < e and (buf[p] == 32 or buf[p] == 9):
            p += 1
        # N word
        if p < e and (buf[p] == 78 or buf[p] == 110):
            q = p + 1
            while q < e and 48 <= buf[q] <= 57:
                q += 1
            if q == p + 1:
                ok = False
            p = q
            while p < e and (buf[p] == 32 or buf[p] == 9):
                p += 1
        # G0..G3 (0* then one digit 0-3, not followed by a digit or '.')
        if ok and p < e and (buf[p] == 71 or buf[p] == 103):
            q = p + 1
            start = q
            while q < e and 48 <= buf[q] <= 57:
                q += 1
            if q == start:
                ok = False
            else:
                last = buf[q - 1]
                for r in range(start, q - 1):
                    if buf[r] != 48:
                        ok = False
                if last > 51:
                    ok = False
                if q < e and buf[q] == 46:
                    ok = False
                if ok:
                    out[li, 0] = float(last - 48)
                    if want_spans:
                        spans[li, 0, 0] = q - 1
                        spans[li, 0, 1] = q
            p = q
            while p < e and (buf[p] == 32 or buf[p] == 9):
                p += 1
        k = 0
        axes_seen = 0
        while ok and p < e:
            ch = buf[p]
            if ch >= 97:
                ch -= 32
            if k <= 3 and 88 <= ch <= 90:  # X Y Z in any order, each once, before the others
                col = ch - 88
                if axes_seen & (1 << col):
                    ok = False
                    break
                axes_seen |= 1 << col
                k = max(k, col)
            else:
                while k < 8 and order[k] != ch:
                    k += 1
                if k == 8:
                    ok = False
                    break
                col = k
            p += 1
            while p < e and (buf[p] == 32 or buf[p] == 9):
                p += 1
            num_at = p
            neg = False
            if p < e and (buf[p] == 43 or buf[p] == 45):
                if col == 7:  # F takes no sign
                    ok = False
                    break
                neg = buf[p] == 45
                p += 1
            mant = 0
            nd = 0
            ndec = 0
            seen_dot = False
            while p < e:
                b = buf[p]
                if 48 <= b <= 57:
                    mant = mant * 10 + (b - 48)
                    nd += 1
                    if seen_dot:
                        ndec += 1
                    if mant >= 1_000_000_000_000_000:  # beyond 15 significant digits: general lexer
                        ok = False
                        break
                    p += 1
                elif b == 46 and not seen_dot:
                    seen_dot = True
                    p += 1
                else:
                    break
            if nd == 0 or ndec > 22 or not ok:
                ok = False
                break
            v = mant / pow10[ndec]
            if v > 1e12:
                ok = False
                break
            out[li, col + 1] = -v if neg else v
            if want_spans:
                spans[li, col + 1, 0] = num_at
                spans[li, col + 1, 1] = p
            k = max(k, col + 1)
            while p < e and (buf[p] == 32 or buf[p] == 9):
                p += 1
        if not ok:
            for c in range(9):
                out[li, c] = np.nan
        slow[li] = not ok


_scan_compiled = njit(cache=True, nogil=True)(_scan_impl) if AVAILABLE else None


def scan_plain_blocks(data: bytes, line_start: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Classify and parse every line of a program.

    Parameters
    ----------
    data : bytes
        The program (latin-1 text as bytes).
    line_start : ndarray (n,)
        Offset of each line.

    Returns
    -------
    table : ndarray (n, 9)
        G motion digit (0-3) and the X Y Z I J K R F numbers of plain blocks, NaN where absent.
    slow : ndarray (n,) bool
        True for lines that are not plain blocks (the general lexer reads them).
    """
    if _scan_compiled is None:  # pragma: no cover
        raise RuntimeError("numba is not installed")
    buf = np.frombuffer(data, dtype=np.uint8)
    n = line_start.shape[0]
    ends = np.empty(n, dtype=np.int64)
    ends[:-1] = line_start[1:] - 1
    ends[-1] = len(data)
    out = np.empty((n, 9))
    slow = np.empty(n, dtype=np.bool_)
    _scan_compiled(buf, line_start.astype(np.int64), ends, _POW10, _ORDER_UPPER, out, slow, _NO_SPANS, False)
    return out, slow


_NO_SPANS = np.empty((1, 9, 2), dtype=np.int64)


def plain_block_spans(data: NDArray[np.uint8], line_start: NDArray[np.int64], line_end: NDArray[np.int64]) -> tuple[
        NDArray[np.int64], NDArray[np.bool_]]:
    """Where the words of some plain blocks are: the spans of the groups of ``gcode_plain.FAST_LINE``.

    Parameters
    ----------
    data : ndarray of uint8
        The program's bytes.
    line_start, line_end : ndarray (n,)
        Offsets of the lines' first byte and of their end (the ``\\n`` or the end of the data).

    Returns
    -------
    spans : ndarray (n, 9, 2) of int64
        Start and end offset in ``data`` of the G digit and the X Y Z I J K R F numbers (sign included),
        -1 where absent: what the regular expression's groups 1-9 span.
    slow : ndarray (n,) bool
        Lines the scanner does not read as plain blocks (their spans are not set).
    """
    if _scan_compiled is None:  # pragma: no cover
        raise RuntimeError("numba is not installed")
    n = line_start.shape[0]
    out = np.empty((n, 9))
    slow = np.empty(n, dtype=np.bool_)
    spans = np.empty((n, 9, 2), dtype=np.int64)
    _scan_compiled(data, line_start.astype(np.int64), line_end.astype(np.int64), _POW10, _ORDER_UPPER, out, slow,
                   spans, True)
    return spans, slow

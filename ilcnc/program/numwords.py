"""Number words of a program's bytes, many at a time: read them, spell new numbers, splice them in.

The lossless rewrite changes one or more numbers on most lines of a big CAM
program (stellabee1: 250,000 numbers in 169,000 lines). Done word by word in
Python that cost 15 µs a number, 27x what reading the whole program costs.
Here the same arithmetic runs on numpy arrays:

* :func:`parse_plain` reads words written plainly (``-12.345``, ``+12.``,
  ``.5``: digits, one dot, a leading sign) to the float ``float(word)`` gives,
  with their decimals and ``STYLE_*`` bits (as :func:`ilcnc.program.rewrite.spelling`);
* :func:`spell` writes numbers with given decimals and styles, byte for byte
  what :func:`ilcnc.program.rewrite.format_number` writes, and the value the
  written text reads back as;
* :func:`splice` makes sorted, non-overlapping replacements in the bytes.

Words and numbers outside the exact range of the arithmetic (see each
function) are flagged, and the caller spells them one by one: the results
are the same either way.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ilcnc._jit import HAVE_NUMBA, njit, numba_loaded
from ilcnc.program.model import STYLE_COMMA, STYLE_LITERAL, STYLE_NO_LEADING_ZERO, STYLE_PLUS, STYLE_TRAILING_DOT

__all__ = ["parse_plain", "spell", "splice"]

#: Exact powers of ten: 10**k is an integer below 2**53 for k <= 15, so float(10**k) is exact.
_POW10_F = np.array([float(10**k) for k in range(16)])
_POW10_I = np.array([10**k for k in range(19)], dtype=np.int64)
#: Longest word :func:`parse_plain` reads (longer ones are flagged).
_MAX_WORD = 17
#: Most digits of a plainly read word: below 2**53, so the mantissa is an exact float.
_MAX_DIGITS = 15
#: Largest |value| * 10**decimals :func:`spell` rounds itself. Below 2**36 the product's rounding error is
#: below 2**36 * 2**-53 = 7.6e-6 (half an ulp), so with the fraction farther than _HALF_GUARD from 0.5 the
#: rounding of the exact binary value (what Python's format does) is the rounding of the product.
_MAX_SCALED = float(2**36)
_HALF_GUARD = 1e-4
_MAX_DECIMALS = 15

_DIGIT0, _DOT, _COMMA, _MINUS, _PLUS = 48, 46, 44, 45, 43


def parse_plain(data: NDArray[np.uint8], start: NDArray[np.int64], end: NDArray[np.int64]) -> tuple[
        NDArray[np.bool_], NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """Read the number words ``data[start:end]`` written plainly: ``[+-]digits[.digits]``.

    Parameters
    ----------
    data : ndarray of uint8
        The program's bytes.
    start, end : ndarray of int64, shape (N,)
        Byte spans of the words (the number only, without its letter).

    Returns
    -------
    ok : ndarray of bool, shape (N,)
        The word is plain (only digits, at most one dot, a sign in front; 1 to 15 digits, at most
        17 characters); the other outputs are only meaningful here.
    value : ndarray of float64
        The number in program units: the mantissa (an exact float) divided by an exact power of ten, one
        correctly rounded division, so the float ``float(word)`` reads.
    decimals : ndarray of int64
        Digits after the dot.
    style : ndarray of int64
        ``STYLE_LITERAL``, with ``STYLE_PLUS`` (``+5``), ``STYLE_NO_LEADING_ZERO`` (``.5``, ``-.5``) and
        ``STYLE_TRAILING_DOT`` (``12.``) as written.
    """
    if start.size >= _COMPILED_MIN and numba_loaded():
        return _parse_plain_loop(data, start, end)
    return _parse_plain_arrays(data, start, end)


def _parse_plain_loop(data: NDArray[np.uint8], start: NDArray[np.int64], end: NDArray[np.int64]) -> tuple[
        NDArray[np.bool_], NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """:func:`parse_plain` by the compiled loop."""
    n = start.size
    ok = np.empty(n, dtype=np.bool_)
    value = np.empty(n)
    decimals = np.empty(n, dtype=np.int64)
    style = np.empty(n, dtype=np.int64)
    _parse_compiled(data, start.astype(np.int64), end.astype(np.int64), _POW10_F, ok, value, decimals, style)
    return ok, value, decimals, style


def _parse_plain_arrays(data: NDArray[np.uint8], start: NDArray[np.int64], end: NDArray[np.int64]) -> tuple[
        NDArray[np.bool_], NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """:func:`parse_plain` with numpy only: every word padded to the longest (the compiled loop is ~10x faster on
    the 228,000 words of a learned stellabee1; this is the path for small rewrites, without numba, and the reference
    in the tests)."""
    n = start.size
    length = end - start
    width = int(min(max(int(length.max()), 1), _MAX_WORD)) if n else 1
    cols = np.arange(width)
    inside = cols < length[:, None]
    ch = data[np.minimum(start[:, None] + cols, data.size - 1)]
    ch = np.where(inside, ch, 0)
    digit = (ch >= _DIGIT0) & (ch <= _DIGIT0 + 9)
    dot = ch == _DOT
    minus = (ch == _MINUS) & (cols == 0)
    plus = (ch == _PLUS) & (cols == 0)
    n_dig = digit.sum(axis=1)
    n_dot = dot.sum(axis=1)
    ok = (length >= 1) & (length <= _MAX_WORD) & np.all(~inside | digit | dot | minus | plus, axis=1)
    ok &= (n_dot <= 1) & (n_dig >= 1) & (n_dig <= _MAX_DIGITS)
    dot_at = np.where(n_dot == 1, np.argmax(dot, axis=1), length)
    decimals = np.where(n_dot == 1, length - dot_at - 1, 0).astype(np.int64)
    # mantissa: each digit times ten to the number of digits after it
    after = np.cumsum(digit[:, ::-1], axis=1)[:, ::-1] - digit
    d_val = np.where(digit, ch.astype(np.int64) - _DIGIT0, 0)
    mant = (d_val * _POW10_I[np.minimum(after, 18)]).sum(axis=1)
    dec_ok = np.minimum(decimals, _MAX_DECIMALS)
    value = mant.astype(np.float64) / _POW10_F[dec_ok]
    neg = minus[:, 0]
    signed = neg | plus[:, 0]
    value = np.where(neg, -value, value)
    first = np.where(signed, ch[:, min(1, width - 1)], ch[:, 0])
    style = np.full(n, STYLE_LITERAL, dtype=np.int64)
    style |= np.where(plus[:, 0], STYLE_PLUS, 0)
    style |= np.where(first == _DOT, STYLE_NO_LEADING_ZERO, 0)
    style |= np.where((n_dot == 1) & (decimals == 0), STYLE_TRAILING_DOT, 0)
    return ok, value, decimals, style


def _parse_impl(data, start, end, pow10, ok, value, decimals, style):  # pragma: no cover - compiled
    """The loop of :func:`parse_plain`: the same tests and the same arithmetic as :func:`_parse_plain_arrays`
    (the mantissa an exact integer, one division by an exact power of ten)."""
    for i in range(start.shape[0]):
        a = start[i]
        length = end[i] - a
        good = 1 <= length <= 17
        neg = False
        plus = False
        n_dig = 0
        n_dot = 0
        dot_at = length
        mant = 0
        first = 0
        if good:
            for c in range(length):
                b = data[a + c]
                if 48 <= b <= 57:
                    if n_dig < 15:
                        mant = mant * 10 + (b - 48)
                    n_dig += 1
                elif b == 46:
                    if n_dot == 0:
                        dot_at = c
                    n_dot += 1
                elif c == 0 and b == 45:
                    neg = True
                elif c == 0 and b == 43:
                    plus = True
                else:
                    good = False
                    break
            first = data[a + 1] if (neg or plus) and length > 1 else data[a]
        good = good and n_dot <= 1 and 1 <= n_dig <= 15
        dec = length - dot_at - 1 if n_dot == 1 else 0
        ok[i] = good
        decimals[i] = dec
        v = mant / pow10[min(dec, 15)] if good else 0.0
        value[i] = -v if neg else v
        st = 16  # STYLE_LITERAL
        if plus:
            st |= 1  # STYLE_PLUS
        if first == 46:
            st |= 4  # STYLE_NO_LEADING_ZERO
        if n_dot == 1 and dec == 0:
            st |= 8  # STYLE_TRAILING_DOT
        style[i] = st


_parse_compiled = njit(cache=True, nogil=True)(_parse_impl) if HAVE_NUMBA else None
#: The compiled loops read and spell from this many numbers on, and only in a process that has imported numba
#: already (a learning run, a program read by the scanner): importing it costs more (~0.3 s) than the numpy path
#: saves on a mid-size program (a few ms).
_COMPILED_MIN = 2_000


def spell(value: NDArray[np.float64], decimals: NDArray[np.int64], style: NDArray[np.int64], *,
          klartext: bool = False) -> tuple[NDArray[np.bool_], NDArray[np.uint8], NDArray[np.int64],
                                           NDArray[np.float64]]:
    """Spell numbers as :func:`ilcnc.program.rewrite.format_number` does, all at once.

    Parameters
    ----------
    value : ndarray of float64, shape (N,)
        The numbers (program units).
    decimals : ndarray of int64, shape (N,)
        Decimal places of each.
    style : ndarray of int64, shape (N,)
        ``STYLE_*`` bits of the word each replaces.
    klartext : bool
        Heidenhain: an explicit sign on every number.

    Returns
    -------
    ok : ndarray of bool, shape (N,)
        Spelled here: finite, 0..15 decimals, ``|value| * 10**decimals`` below 2**36 and its fraction
        farther than 1e-4 from one half (where rounding the float product might round another way than
        rounding the exact binary value). The caller spells the others with ``format_number``.
    text : ndarray of uint8
        The spelled numbers (only those ``ok``), one after the other.
    length : ndarray of int64, shape (N,)
        Bytes of each in ``text`` (0 where not ``ok``).
    written : ndarray of float64, shape (N,)
        The value each written number reads back as (``float(text)``: the rounded integer divided by
        an exact power of ten, one correctly rounded division).
    """
    v = np.asarray(value, dtype=np.float64)
    d = np.asarray(decimals, dtype=np.int64)
    st = np.asarray(style, dtype=np.int64)
    if v.size >= _COMPILED_MIN and numba_loaded():
        return _spell_loop(v, d, st, klartext)
    return _spell_arrays(v, d, st, klartext)


def _spell_loop(v: NDArray[np.float64], d: NDArray[np.int64], st: NDArray[np.int64], klartext: bool) -> tuple[
        NDArray[np.bool_], NDArray[np.uint8], NDArray[np.int64], NDArray[np.float64]]:
    """:func:`spell` by the compiled loops: measure every number, then write them."""
    n = v.size
    ok = np.empty(n, dtype=np.bool_)
    length = np.empty(n, dtype=np.int64)
    written = np.empty(n)
    rounded = np.empty(n, dtype=np.int64)
    _spell_measure_compiled(v, d, st, bool(klartext), _POW10_F, _POW10_I, ok, length, written, rounded)
    text = np.empty(int(length.sum()), dtype=np.uint8)
    _spell_write_compiled(v, d, st, bool(klartext), _POW10_I, ok, length, rounded, text)
    return ok, text, length, written


def _spell_arrays(v: NDArray[np.float64], d: NDArray[np.int64], st: NDArray[np.int64], klartext: bool) -> tuple[
        NDArray[np.bool_], NDArray[np.uint8], NDArray[np.int64], NDArray[np.float64]]:
    """:func:`spell` with numpy only (the path without numba and for few numbers; the reference in the tests)."""
    n = v.size
    ok = np.isfinite(v) & (d >= 0) & (d <= _MAX_DECIMALS)
    dd = np.where(ok, d, 0)
    scaled = np.abs(np.where(ok, v, 0.0)) * _POW10_F[dd]
    ok &= scaled < _MAX_SCALED
    scaled = np.where(ok, scaled, 0.0)
    floor = np.floor(scaled)
    frac = scaled - floor
    ok &= np.abs(frac - 0.5) > _HALF_GUARD
    rounded = floor.astype(np.int64) + (frac > 0.5)
    rounded = np.where(ok, rounded, 0)
    negative = (v < 0) & (rounded != 0)
    written = rounded.astype(np.float64) / _POW10_F[dd]
    written = np.where(negative, -written, written)
    ip = rounded // _POW10_I[dd]
    fp = rounded - ip * _POW10_I[dd]
    n_int = 1 + (ip[:, None] >= _POW10_I[1:12]).sum(axis=1)
    n_int = np.where((ip == 0) & (dd > 0) & ((st & STYLE_NO_LEADING_ZERO) != 0), 0, n_int)
    has_sign = negative | (~negative & (klartext | ((st & STYLE_PLUS) != 0)))
    has_sep = (dd > 0) | ((st & STYLE_TRAILING_DOT) != 0)
    wi = int(n_int[ok].max()) if ok.any() else 1
    wf = int(dd[ok].max()) if ok.any() else 0
    # one row per number: sign, wi integer digits (right-aligned), separator, wf decimals (left-aligned)
    width = 2 + wi + wf
    chars = np.zeros((n, width), dtype=np.uint8)
    used = np.zeros((n, width), dtype=bool)
    chars[:, 0] = np.where(negative, _MINUS, _PLUS)
    used[:, 0] = has_sign
    for c in range(wi):
        power = wi - 1 - c
        chars[:, 1 + c] = _DIGIT0 + (ip // _POW10_I[power]) % 10
        used[:, 1 + c] = power < n_int
    chars[:, 1 + wi] = np.where((st & STYLE_COMMA) != 0, _COMMA, _DOT)
    used[:, 1 + wi] = has_sep
    for c in range(wf):
        power = np.maximum(dd - 1 - c, 0)
        chars[:, 2 + wi + c] = _DIGIT0 + (fp // _POW10_I[power]) % 10
        used[:, 2 + wi + c] = c < dd
    used &= ok[:, None]
    return ok, chars[used], used.sum(axis=1).astype(np.int64), written


def _spell_measure_impl(v, d, st, klartext, pow10f, pow10i, ok, length, written, rounded):  # pragma: no cover
    """First loop of :func:`spell`: which numbers it spells, their rounded integer (value x 10**decimals), their
    byte count and the value they read back as: the arithmetic of :func:`_spell_arrays`, number by number."""
    for i in range(v.shape[0]):
        x = v[i]
        dd = d[i]
        good = np.isfinite(x) and 0 <= dd <= 15
        r = 0
        if good:
            scaled = abs(x) * pow10f[dd]
            good = scaled < 68719476736.0  # 2**36
            if good:
                fl = np.floor(scaled)
                frac = scaled - fl
                good = abs(frac - 0.5) > 1e-4
                r = np.int64(fl) + (1 if frac > 0.5 else 0)
        ok[i] = good
        if not good:
            length[i] = 0
            written[i] = 0.0
            rounded[i] = 0
            continue
        rounded[i] = r
        negative = x < 0 and r != 0
        w = r / pow10f[dd]
        written[i] = -w if negative else w
        s = st[i]
        ip = r // pow10i[dd]
        n_int = 1
        for k in range(1, 12):
            if ip >= pow10i[k]:
                n_int += 1
        if ip == 0 and dd > 0 and (s & 4) != 0:  # STYLE_NO_LEADING_ZERO
            n_int = 0
        has_sign = negative or klartext or (s & 1) != 0  # STYLE_PLUS
        has_sep = dd > 0 or (s & 8) != 0  # STYLE_TRAILING_DOT
        length[i] = (1 if has_sign else 0) + n_int + (1 if has_sep else 0) + dd


def _spell_write_impl(v, d, st, klartext, pow10i, ok, length, rounded, text):  # pragma: no cover - compiled
    """Second loop of :func:`spell`: the bytes of the numbers the first one measured, one after the other."""
    at = 0
    for i in range(v.shape[0]):
        if not ok[i]:
            continue
        r = rounded[i]
        dd = d[i]
        s = st[i]
        negative = v[i] < 0 and r != 0
        ip = r // pow10i[dd]
        fp = r - ip * pow10i[dd]
        end = at + length[i]
        # from the right: decimals, separator, integer digits, sign
        p = end
        for _c in range(dd):
            p -= 1
            text[p] = 48 + fp % 10
            fp //= 10
        if dd > 0 or (s & 8) != 0:
            p -= 1
            text[p] = 44 if (s & 2) != 0 else 46  # STYLE_COMMA
        has_sign = negative or klartext or (s & 1) != 0
        stop = at + (1 if has_sign else 0)
        while p > stop:
            p -= 1
            text[p] = 48 + ip % 10
            ip //= 10
        if has_sign:
            text[at] = 45 if negative else 43
        at = end


_spell_measure_compiled = njit(cache=True, nogil=True)(_spell_measure_impl) if HAVE_NUMBA else None
_spell_write_compiled = njit(cache=True, nogil=True)(_spell_write_impl) if HAVE_NUMBA else None


def splice(data: NDArray[np.uint8], start: NDArray[np.int64], end: NDArray[np.int64], new: NDArray[np.uint8],
           new_start: NDArray[np.int64], new_length: NDArray[np.int64]) -> NDArray[np.uint8]:
    """The bytes with ``data[start[i]:end[i]]`` replaced by ``new[new_start[i]:new_start[i] + new_length[i]]``.

    Parameters
    ----------
    data : ndarray of uint8
        The source bytes.
    start, end : ndarray of int64, shape (E,)
        Spans to replace, sorted and not overlapping (``end[i] <= start[i + 1]``; ``start == end`` inserts).
    new : ndarray of uint8
        The replacement bytes of all edits, in any order.
    new_start, new_length : ndarray of int64, shape (E,)
        Where each edit's replacement is in ``new``.

    Returns
    -------
    ndarray of uint8
        The new bytes: one gather from ``data`` followed by ``new``, index by index.
    """
    n = data.size
    both = np.concatenate((data, new))
    k = start.size
    seg_from = np.empty(2 * k + 1, dtype=np.int64)
    seg_len = np.empty(2 * k + 1, dtype=np.int64)
    seg_from[0::2] = np.concatenate(([0], end))
    seg_len[0::2] = np.concatenate((start, [n])) - seg_from[0::2]
    seg_from[1::2] = n + new_start
    seg_len[1::2] = new_length
    out_at = np.cumsum(seg_len) - seg_len
    total = int(seg_len.sum())
    # one index per output byte: int32 while it fits (half the memory traffic of int64 on a 20 MB program)
    itype = np.int32 if max(total, both.size) < 2**31 else np.int64
    index = np.arange(total, dtype=itype)
    index += np.repeat((seg_from - out_at).astype(itype), seg_len)
    return both[index]

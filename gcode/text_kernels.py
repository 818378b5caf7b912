"""G-code text compiled: what the compiled writers (:mod:`printability.postprocess._rewrite_kernel`,
:mod:`printability.generate._emit_kernel`) write and read, to Python's bytes.

What they must reproduce exactly:

* Numbers: :func:`gcode.writer.format_number` (printf's correctly rounded
  digits, round half to even on the binary value). :func:`fixed_digits`
  rounds v·10^d exactly: the product is split into its rounded value and its
  error (Dekker's product with Veltkamp's split, exact in binary64 without
  FMA, which numba does not contract without ``fastmath``), so the side of
  the half-way point is decided on the exact product. It declines values with
  |v|·10^d ≥ 4·10^15, where the fraction is no longer exact.
* Reading numbers: ``float()`` of a slicer's word. :func:`parse_number` reads
  at most 15 significant digits and 22 decimals, where mantissa / 10^k is
  one correctly rounded division; it declines longer words.
* Lines: :data:`gcode.edit.SIMPLE_MOVE` (the common slicer shape), by
  :func:`simple_span`; the regular expression cannot backtrack into a match
  there (a word ends at a blank, ``;`` or the end), so one greedy pass agrees
  with it.
* The rotary coordinate: :func:`gcode.rotary.nearest_equivalent` (:func:`nearest`).
* Lengths: ``math.hypot`` (:func:`hypot`, CPython's algorithm, not the C library's).

What a function declines it reports (``ok`` False, or -1 for an end), and the caller
hands the work to the Python it replaces. Output goes to ``uint8`` buffers at an offset
``n``, returning the new end; numba does not check bounds, so callers make room first
(:func:`reserve`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["coordinate", "copy", "copy_with_feed", "eol_span", "fixed_digits", "hypot", "nearest",
           "parse_number", "put", "put_eol", "put_feed", "put_fixed", "put_move",
           "put_rotation", "reserve", "simple_span", "strip_span", "word_span"]

_P10 = np.array([10.0 ** k for k in range(23)])
_SPLIT = 134217729.0  # 2^27 + 1: Veltkamp's splitter for binary64
_LIMIT = 4.0e15  # below 2^52: p - floor(p) and that less 1/2 are exact


@numba.njit(cache=True, nogil=True)
def fixed_digits(v, d):  # pragma: no cover
    """(ok, m): v·10^d rounded half to even on its exact value, as an integer."""
    s = _P10[d]
    if not abs(v) * s < _LIMIT:  # also NaN and infinities
        return False, 0
    p = v * s
    c = _SPLIT * v
    vh = c - (c - v)
    vl = v - vh
    c = _SPLIT * s
    sh = c - (c - s)
    sl = s - sh
    err = ((vh * sh - p) + vh * sl + vl * sh) + vl * sl  # v·s = p + err exactly
    f = math.floor(p)
    t = ((p - f) - 0.5) + err  # the sign of a rounded sum is exact
    m = np.int64(f)
    if t > 0.0 or (t == 0.0 and m % 2 != 0):
        m += 1
    return True, m


@numba.njit(cache=True, nogil=True)
def put_fixed(buf, n, v, d):  # pragma: no cover
    """Write ``format_number(v, d)`` at ``buf[n:]``; the new end, or -1 when declined.

    ``buf`` must have 40 bytes free at ``n``.
    """
    ok, m = fixed_digits(v, d)
    if not ok:
        return -1
    if m == 0:
        buf[n] = 48
        return n + 1
    if m < 0:
        buf[n] = 45
        n += 1
        m = -m
    k = d
    while k > 0 and m % 10 == 0:
        m //= 10
        k -= 1
    # the digits of m, at least k + 1 of them ("0.05"), the point before the last k,
    # written from the end (no scratch array: an allocation per number cost the
    # compiled writers a tenth of their time)
    nd = 1
    t = m // 10
    while t > 0:
        nd += 1
        t //= 10
    nd = max(nd, k + 1)
    end = n + nd + (1 if k > 0 else 0)
    j = end
    for i in range(nd):
        j -= 1
        buf[j] = 48 + m % 10
        m //= 10
        if i == k - 1:
            j -= 1
            buf[j] = 46
    return end


@numba.njit(cache=True, nogil=True)
def parse_number(data, a, b):  # pragma: no cover
    """(ok, value) of the text ``data[a:b]`` (sign, digits, one point), as ``float()`` reads it."""
    i = a
    neg = False
    if i < b and (data[i] == 45 or data[i] == 43):
        neg = data[i] == 45
        i += 1
    mant = np.int64(0)
    sig = 0
    frac = 0
    seen_point = False
    any_digit = False
    while i < b:
        ch = data[i]
        if ch == 46 and not seen_point:
            seen_point = True
        elif 48 <= ch <= 57:
            any_digit = True
            if mant > 0 or ch != 48:
                sig += 1
            if sig > 15:
                return False, 0.0
            mant = mant * 10 + (ch - 48)
            if seen_point:
                frac += 1
        else:
            return False, 0.0
        i += 1
    if not any_digit or frac > 22:
        return False, 0.0
    value = np.float64(mant) / _P10[frac]
    return True, -value if neg else value


@numba.njit(cache=True, nogil=True)
def _is_upper(ch):  # pragma: no cover
    return 65 <= ch <= 90


@numba.njit(cache=True, nogil=True)
def _is_digit(ch):  # pragma: no cover
    return 48 <= ch <= 57


@numba.njit(cache=True, nogil=True)
def simple_span(data, a, b):  # pragma: no cover
    """The span of the words of the line ``data[a:b]`` when it has the common slicer shape
    (``_SIMPLE_MOVE``'s group 1), else (-1, -1)."""
    if b - a < 2 or data[a] != 71 or not _is_digit(data[a + 1]):
        return -1, -1
    i = a + 1
    while i < b and _is_digit(data[i]):
        i += 1
    ga = i
    gb = i
    while True:
        j = gb
        while j < b and data[j] == 32:
            j += 1
        if j == gb or j >= b or not _is_upper(data[j]):
            break
        j += 1
        if j < b and (data[j] == 45 or data[j] == 43):
            j += 1
        if j < b and _is_digit(data[j]):
            while j < b and _is_digit(data[j]):
                j += 1
            if j + 1 < b and data[j] == 46 and _is_digit(data[j + 1]):
                j += 1
                while j < b and _is_digit(data[j]):
                    j += 1
        elif j + 1 < b and data[j] == 46 and _is_digit(data[j + 1]):
            j += 1
            while j < b and _is_digit(data[j]):
                j += 1
        else:
            return -1, -1  # a letter with no number: the expression cannot match
        gb = j
    # the tail: blanks, a comment, one line ending, the end
    j = gb
    while j < b and (data[j] == 32 or data[j] == 9):
        j += 1
    if j < b and data[j] == 59:
        while j < b and data[j] != 13 and data[j] != 10:
            j += 1
    if j < b and data[j] == 13:
        j += 1
        if j < b and data[j] == 10:
            j += 1
    elif j < b and data[j] == 10:
        j += 1
    if j != b:
        return -1, -1
    return ga, gb


@numba.njit(cache=True, nogil=True)
def word_span(data, ga, gb, letter):  # pragma: no cover
    """The first word of ``data[ga:gb]`` (a simple line's words) with that letter: (start,
    end), or (-1, -1). Inside the words a letter only ever starts one."""
    for i in range(ga, gb):
        if data[i] == letter:
            j = i + 1
            while j < gb and data[j] != 32:
                j += 1
            return i, j
    return -1, -1


@numba.njit(cache=True, nogil=True)
def reserve(buf, n, need):  # pragma: no cover
    if n + need <= len(buf):
        return buf
    grown = np.empty(max(2 * len(buf), n + need), np.uint8)
    grown[:n] = buf[:n]
    return grown


@numba.njit(cache=True, nogil=True)
def copy(buf, n, src, a, b):  # pragma: no cover
    buf[n:n + b - a] = src[a:b]
    return n + b - a


@numba.njit(cache=True, nogil=True)
def put(buf, n, text):  # pragma: no cover
    for i in range(len(text)):
        buf[n + i] = text[i]
    return n + len(text)


@numba.njit(cache=True, nogil=True)
def put_move(buf, n, x, y, with_z, z, xd):  # pragma: no cover
    """Write ``G1 X… Y…`` (`` Z…`` too when ``with_z``) at ``buf[n:]``; the new end, or -1
    when a number is declined. ``buf`` must have 120 bytes free at ``n``."""
    for ch in (71, 49, 32, 88):  # "G1 X"
        buf[n] = ch
        n += 1
    n = put_fixed(buf, n, x, xd)
    if n < 0:
        return -1
    buf[n] = 32
    buf[n + 1] = 89
    n = put_fixed(buf, n + 2, y, xd)
    if n < 0 or not with_z:
        return n
    buf[n] = 32
    buf[n + 1] = 90
    return put_fixed(buf, n + 2, z, xd)


_G1 = np.array([71, 49, 32], np.uint8)  # "G1 "


@numba.njit(cache=True, nogil=True)
def put_rotation(buf, n, letter, c, d_ang, rot_feed):  # pragma: no cover
    """A rotation-only move, ``G1 <letter><c>`` and `` F<rot_feed>`` (degrees per minute)
    when ``rot_feed`` is positive, at ``buf[n:]`` (``letter``: its byte): the new end, or
    -1 when declined."""
    n = put(buf, n, _G1)
    buf[n] = letter
    n = put_fixed(buf, n + 1, c, d_ang)
    if n < 0 or rot_feed <= 0:
        return n
    return put_feed(buf, n, rot_feed)


@numba.njit(cache=True, nogil=True)
def put_feed(buf, n, f):  # pragma: no cover
    """`` F`` and ``format_number(f, 3)`` at ``buf[n:]`` (40 bytes free)."""
    buf[n] = 32
    buf[n + 1] = 70
    return put_fixed(buf, n + 2, f, 3)


@numba.njit(cache=True, nogil=True)
def copy_with_feed(buf, n, data, a, gb, b, f):  # pragma: no cover
    """The line ``data[a:b]`` with `` F<f>`` put at ``gb`` (the end of its words): the
    feed a rotation-only move before it would otherwise leave in force; -1 when declined."""
    n = copy(buf, n, data, a, gb)
    n = put_feed(buf, n, f)
    if n < 0:
        return n
    return copy(buf, n, data, gb, b)


@numba.njit(cache=True, nogil=True)
def eol_span(data, a, b):  # pragma: no cover
    """(start, end) of the line ending of ``data[a:b]`` as
    :func:`printability.postprocess.rewrite.eol_of` gives it; (-1, -1) stands for an added
    ``\\n``."""
    if b - a >= 2 and data[b - 2] == 13 and data[b - 1] == 10:
        return b - 2, b
    if b > a and (data[b - 1] == 10 or data[b - 1] == 13):
        return b - 1, b
    return -1, -1


@numba.njit(cache=True, nogil=True)
def put_eol(buf, n, data, e0, e1):  # pragma: no cover
    if e0 < 0:
        buf[n] = 10
        return n + 1
    return copy(buf, n, data, e0, e1)


@numba.njit(cache=True, nogil=True)
def nearest(target, previous, period, lo, hi, unbounded):  # pragma: no cover
    """(ok, c): :func:`gcode.rotary.nearest_equivalent`, the same operations in the same
    order (the unbounded branch as the reference inlines it)."""
    k = np.rint((previous - target) / period)  # round half to even, as round()
    if unbounded:
        best = target + (k - 1.0) * period
        bd = abs(best - previous)
        cand = target + k * period
        if abs(cand - previous) < bd - 1e-12:
            best = cand
            bd = abs(cand - previous)
        cand = target + (k + 1.0) * period
        if abs(cand - previous) < bd - 1e-12:
            best = cand
        return True, best
    found = False
    best = 0.0
    for dk in range(-1, 2):
        cand = target + (k + dk) * period
        if lo - 1e-9 <= cand <= hi + 1e-9 and (
                not found or abs(cand - previous) < abs(best - previous) - 1e-12):
            best = cand
            found = True
    if not found and math.isfinite(lo) and math.isfinite(hi):
        k0 = math.ceil((lo - target) / period - 1e-12)
        for kk in range(k0, k0 + int((hi - lo) / period) + 2):
            cand = target + kk * period
            if lo - 1e-9 <= cand <= hi + 1e-9:
                # min() keeps the first of equal keys
                if not found or abs(cand - previous) < abs(best - previous):
                    best = cand
                    found = True
    return found, best


@numba.njit(cache=True, nogil=True)
def coordinate(phi, previous, period, lo, hi, unbounded, d):  # pragma: no cover
    """(ok, c, m): the axis coordinate for orientation ``phi`` (:func:`nearest`) and its
    text as digits (:func:`fixed_digits`: equal texts, equal integers)."""
    ok, c = nearest(phi, previous, period, lo, hi, unbounded)
    if not ok:
        return False, c, np.int64(0)
    ok, m = fixed_digits(c, d)
    return ok, c, m


@numba.njit(cache=True, nogil=True)
def strip_span(data, a, b):  # pragma: no cover
    """``bytes.strip()`` of ``data[a:b]``: ASCII blanks off both ends."""
    while a < b and (data[a] == 32 or 9 <= data[a] <= 13):
        a += 1
    while b > a and (data[b - 1] == 32 or 9 <= data[b - 1] <= 13):
        b -= 1
    return a, b


@numba.njit(cache=True, nogil=True)
def _two_product(x, y):  # pragma: no cover
    """x·y as an unevaluated sum hi + lo, exactly (Dekker's product, Veltkamp's split)."""
    c = 134217729.0 * x
    hx = c - (c - x)
    tx = x - hx
    c = 134217729.0 * y
    hy = c - (c - y)
    ty = y - hy
    p = x * y
    return p, ((hx * hy - p) + hx * ty + tx * hy) + tx * ty


@numba.njit(cache=True, nogil=True)
def hypot(a, b):  # pragma: no cover
    """``math.hypot(a, b)`` to the bit, CPython 3.11's algorithm (``vector_norm``).

    Not the C library's ``hypot`` (numba's): the two differ in the last bit for about
    one pair in 170, and the emitter's lengths (E, the travel thresholds) are Python's.
    """
    a = abs(a)
    b = abs(b)
    mx = max(a, b)
    if math.isinf(mx):
        return mx
    if math.isnan(a) or math.isnan(b):
        return math.nan
    if mx == 0.0:
        return mx
    tiny = 1.0
    _, e = math.frexp(mx)
    if e < -1023:  # as CPython: scaled by DBL_MIN first
        tiny = 2.2250738585072014e-308
        a /= tiny
        b /= tiny
        _, e = math.frexp(mx / tiny)
    scale = math.ldexp(1.0, -e)
    csum = 1.0
    f1 = 0.0
    f2 = 0.0
    for k in range(2):
        x = (a if k == 0 else b) * scale
        ph, pl = _two_product(x, x)
        sh = csum + ph
        f2 += ph - (sh - csum)
        csum = sh
        f1 += pl
    h = math.sqrt(csum - 1.0 + (f1 + f2))
    ph, pl = _two_product(-h, h)
    sh = csum + ph
    f2 += ph - (sh - csum)
    csum = sh
    f1 += pl
    h += (csum - 1.0 + (f1 + f2)) / (2.0 * h)
    return tiny * (h / scale)

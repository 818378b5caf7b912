"""The rewrite pass compiled: the same bytes as :func:`printability.rewrite.rewrite_reference`.

The reference walks the moves that may change in Python, about 20 µs each (a
rotary word, an E edit, new lines for split moves); on Benchy that was a
third of the post-processor's time. This kernel does the same walk over the
file's bytes. What it must reproduce exactly:

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
* Lines: :data:`gcode.writer._SIMPLE_MOVE` (the common slicer shape), by
  :func:`simple_span`; the regular expression cannot backtrack into a match
  there (a word ends at a blank, ``;`` or the end), so one greedy pass agrees
  with it.

Whatever the kernel declines (a number out of that range, a line to edit that
is not of the common shape, a bounded axis with no reachable representative)
ends it with a status, and the caller runs the reference instead: the output
is the reference's in every case.

Complexity: linear in the file's bytes plus the new lines.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["fixed_digits", "parse_number", "put_fixed", "rewrite_kernel", "simple_span"]

OK = 0
DECLINED = 1

_P10 = np.array([10.0 ** k for k in range(23)])
_SPLIT = 134217729.0  # 2^27 + 1: Veltkamp's splitter for binary64
_LIMIT = 4.0e15  # below 2^52: p - floor(p) and that less 1/2 are exact

_TRAVEL, _RESET, _WORK, _UNRETRACT = 1, 2, 3, 4  # event codes of printability.rewrite


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
    # digits of m, least significant first, at least k + 1 of them ("0.05")
    tmp = np.empty(24, np.uint8)
    nd = 0
    while m > 0 or nd <= k:
        tmp[nd] = 48 + m % 10
        m //= 10
        nd += 1
    for i in range(nd - 1, -1, -1):
        if i == k - 1:
            buf[n] = 46
            n += 1
        buf[n] = tmp[i]
        n += 1
    return n


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
def _word(data, ga, gb, letter):  # pragma: no cover
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
def _reserve(buf, n, need):  # pragma: no cover
    if n + need <= len(buf):
        return buf
    grown = np.empty(max(2 * len(buf), n + need), np.uint8)
    grown[:n] = buf[:n]
    return grown


@numba.njit(cache=True, nogil=True)
def _copy(buf, n, src, a, b):  # pragma: no cover
    buf[n:n + b - a] = src[a:b]
    return n + b - a


@numba.njit(cache=True, nogil=True)
def _put(buf, n, text):  # pragma: no cover
    for i in range(len(text)):
        buf[n + i] = text[i]
    return n + len(text)


@numba.njit(cache=True, nogil=True)
def _put_move(buf, n, x, y, with_z, z, xd):  # pragma: no cover
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
def _put_rotation(buf, n, letter, c, d_ang, rot_feed):  # pragma: no cover
    """A rotation-only move, ``G1 <letter><c>`` and `` F<rot_feed>`` (degrees per minute)
    when ``rot_feed`` is positive, at ``buf[n:]``: the new end, or -1 when declined."""
    n = _put(buf, n, _G1)
    n = _put(buf, n, letter)
    n = put_fixed(buf, n, c, d_ang)
    if n < 0 or rot_feed <= 0:
        return n
    return _put_feed(buf, n, rot_feed)


@numba.njit(cache=True, nogil=True)
def _put_feed(buf, n, f):  # pragma: no cover
    """`` F`` and ``format_number(f, 3)`` at ``buf[n:]`` (40 bytes free)."""
    buf[n] = 32
    buf[n + 1] = 70
    return put_fixed(buf, n + 2, f, 3)


@numba.njit(cache=True, nogil=True)
def _copy_with_feed(buf, n, data, a, gb, b, f):  # pragma: no cover
    """The line ``data[a:b]`` with `` F<f>`` put at ``gb`` (the end of its words): the
    feed a rotation-only move before it would otherwise leave in force; -1 when declined."""
    n = _copy(buf, n, data, a, gb)
    n = _put_feed(buf, n, f)
    if n < 0:
        return n
    return _copy(buf, n, data, gb, b)


@numba.njit(cache=True, nogil=True)
def _eol(data, a, b):  # pragma: no cover
    """(start, end) of the line ending of ``data[a:b]`` as :func:`printability.rewrite.eol_of`
    gives it; (-1, -1) stands for an added ``\\n``."""
    if b - a >= 2 and data[b - 2] == 13 and data[b - 1] == 10:
        return b - 2, b
    if b > a and (data[b - 1] == 10 or data[b - 1] == 13):
        return b - 1, b
    return -1, -1


@numba.njit(cache=True, nogil=True)
def _put_eol(buf, n, data, e0, e1):  # pragma: no cover
    if e0 < 0:
        buf[n] = 10
        return n + 1
    return _copy(buf, n, data, e0, e1)


@numba.njit(cache=True, nogil=True)
def _nearest(target, previous, period, lo, hi, unbounded):  # pragma: no cover
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
def _coordinate(phi, previous, period, lo, hi, unbounded, d):  # pragma: no cover
    """(ok, c, m): the axis coordinate for orientation ``phi`` (:func:`_nearest`) and its
    text as digits (:func:`fixed_digits`: equal texts, equal integers)."""
    ok, c = _nearest(phi, previous, period, lo, hi, unbounded)
    if not ok:
        return False, c, np.int64(0)
    ok, m = fixed_digits(c, d)
    return ok, c, m


@numba.njit(cache=True, nogil=True)
def _strip_span(data, a, b):  # pragma: no cover
    """``bytes.strip()`` of ``data[a:b]``: ASCII blanks off both ends."""
    while a < b and (data[a] == 32 or 9 <= data[a] <= 13):
        a += 1
    while b > a and (data[b - 1] == 32 or 9 <= data[b - 1] <= 13):
        b -= 1
    return a, b


@numba.njit(cache=True, nogil=True)
def rewrite_kernel(data, starts, pos0, ev_line, ev_move, ev_code,
                   m_e, m_kind, m_flags, m_layer, m_x0, m_y0, m_x1, m_y1, m_z0, m_z1,
                   mv_a0, mv_a1,
                   s_x0, s_y0, s_x1, s_y1, s_e, s_angle, s_fold, s_turn, s_scale,
                   s_in_pieces, s_p0, s_p1, s_len,
                   p_t0, p_t1, p_angle, p_scale, p_fold, p_turn,
                   letter, d_ang, xd, ed, period, lo, hi, unbounded, fold, unwind, turns,
                   n_layers, m_feed, rot_feed):  # pragma: no cover
    """The reference's walk over the events, writing the file from ``pos0`` on.

    ``p_fold``, ``p_turn`` are per piece what ``s_fold``, ``s_turn`` are per chord: the
    turn into it made while moving, and its planned size.

    A rotation-only line carries ``F<rot_feed>`` (degrees per minute) when ``rot_feed``
    is positive and the feed in force after it is known, and the next motion line then
    restores that feed (``m_feed``, mm/min) unless it has an F of its own.

    Returns (status, buffer, length, changed, inserted, rotary words, rotary words per
    layer + 1, the line declined or -1).
    """
    buf = np.empty(len(data) - pos0 + 65536, np.uint8)
    n = 0
    scratch = np.empty(4096, np.uint8)  # the move's new text, before the travel is written
    turned = np.zeros(n_layers + 2, np.int64)
    changed = 0
    inserted = 0
    rotary = 0
    cur = 0.0
    cur_m = np.int64(0)  # format_number(cur) as digits: equal texts, equal integers
    pos = pos0
    pending = -1
    unret = -1  # an un-retract since the last travel, where a turn goes before it
    unret_mv = -1
    g92 = np.array([71, 57, 50, 32, 69], np.uint8)  # "G92 E"
    note = np.array([32, 59, 32, 112, 114, 105, 110, 116, 97, 98, 105, 108, 105, 116, 121,
                     58, 32, 119, 97, 115, 32], np.uint8)  # " ; printability: was "
    for q in range(len(ev_line)):
        li = ev_line[q]
        mi = ev_move[q]
        code = ev_code[q]
        if code == _TRAVEL:
            pending = li
            unret = -1
            continue
        if code == _UNRETRACT:
            unret = li
            unret_mv = ev_move[q]
            continue
        if code == _RESET:
            pending = -1
            unret = -1
            continue
        travel = pending  # the travel a turn may be folded into, or -1
        pending = -1
        ur = unret  # the un-retract a turn goes before when it cannot be folded, or -1
        ur_mv = unret_mv
        unret = -1
        u_line = -1  # the un-retract a turn was put before, and its coordinate
        u_c = 0.0
        need_f = False  # a rotation line set F: the next motion line restores the feed
        feed = m_feed[mi]
        a = starts[li]
        b = starts[li + 1]
        layer = m_layer[mi]
        a0 = mv_a0[mi]
        a1 = mv_a1[mi]
        e0, e1 = _eol(data, a, b)
        e_rel = (m_flags[mi] & 1) != 0
        e_move = m_e[mi]
        t_line = -1  # the travel a turn was folded into, the end of its words (from its
        t_gb = 0  # start) and the coordinate it turns to
        t_word_c = 0.0
        ns = 0  # bytes of this move's new text in scratch
        # room for the new text: a line is at most its own bytes (the copied words: an F
        # word may be long), numbers of at most 24 bytes and the rotary letter twice, so
        # every write below stays inside the buffer (numba does not check bounds)
        extra = 400 + 2 * len(letter) + (b - a)
        scratch = _reserve(scratch, 0, (b - a) + extra + 4096)
        if a1 - a0 == 1 and s_in_pieces[a0] == 0 and m_kind[mi] <= 1:
            # ---- a simple move: a rotary word, an E edit, or both
            phi = s_angle[a0]
            add = False
            add_c = 0.0
            if turns and math.isfinite(phi):
                ok, c, cm = _coordinate(phi, cur, period, lo, hi, unbounded, d_ang)
                if not ok:
                    return DECLINED, buf, n, changed, inserted, rotary, turned, li
                if s_fold[a0] and abs(c - cur) <= s_turn[a0] + 1e-6:
                    if cm != cur_m:
                        add = True
                        add_c = c
                        rotary += 1
                        turned[layer + 1] += 1
                        cur = c
                        cur_m = cm
                elif cm != cur_m:
                    # turn_to: folded into the travel before, else a line of its own
                    if fold and travel >= 0:
                        if unwind:
                            ok, c, cm = _coordinate(phi, 0.0, period, lo, hi, unbounded,
                                                    d_ang)
                            if not ok:
                                return DECLINED, buf, n, changed, inserted, rotary, turned, li
                        ta, tb = simple_span(data, starts[travel], starts[travel + 1])
                        if ta < 0:
                            return DECLINED, buf, n, changed, inserted, rotary, turned, travel
                        t_line = travel
                        t_gb = tb - starts[travel]
                        t_word_c = c
                    elif ur >= 0:
                        u_line = ur
                        u_c = c
                        inserted += 1
                    else:
                        need_f = rot_feed > 0 and math.isfinite(feed)
                        ns = _put_rotation(scratch, ns, letter, c, d_ang,
                                           rot_feed if need_f else 0.0)
                        if ns < 0:
                            return DECLINED, buf, n, changed, inserted, rotary, turned, li
                        ns = _put_eol(scratch, ns, data, e0, e1)
                        inserted += 1
                    rotary += 1
                    turned[layer + 1] += 1
                    cur = c
                    cur_m = cm
            scale = s_scale[a0]
            ga, gb = simple_span(data, a, b)
            if need_f:
                if ga < 0:
                    return DECLINED, buf, n, changed, inserted, rotary, turned, li
                fa, fb = _word(data, ga, gb, 70)
                need_f = fa < 0
            if scale != 1.0:
                if ga < 0:
                    return DECLINED, buf, n, changed, inserted, rotary, turned, li
                wa, wb = _word(data, ga, gb, 69)
                if wa >= 0:
                    ok, v = parse_number(data, wa + 1, wb)
                    if not ok:
                        return DECLINED, buf, n, changed, inserted, rotary, turned, li
                    new_e = e_move * scale if e_rel else (v - e_move) + e_move * scale
                    ns = _copy(scratch, ns, data, a, wa + 1)
                    ns = put_fixed(scratch, ns, new_e, ed)
                    if ns < 0:
                        return DECLINED, buf, n, changed, inserted, rotary, turned, li
                    ns = _copy(scratch, ns, data, wb, gb)
                    if add:
                        scratch[ns] = 32
                        ns = _put(scratch, ns + 1, letter)
                        ns = put_fixed(scratch, ns, add_c, d_ang)
                    if need_f:
                        ns = _put_feed(scratch, ns, feed)
                        if ns < 0:
                            return DECLINED, buf, n, changed, inserted, rotary, turned, li
                    ns = _copy(scratch, ns, data, gb, b)
                    changed += 1
                    if not e_rel:
                        ns = _put(scratch, ns, g92)
                        ns = put_fixed(scratch, ns, v, ed)
                        if ns < 0:
                            return DECLINED, buf, n, changed, inserted, rotary, turned, li
                        ns = _put_eol(scratch, ns, data, e0, e1)
                        inserted += 1
                    add = False
                    ga = -2  # written
            if ga != -2:
                if add:
                    if ga < 0:
                        return DECLINED, buf, n, changed, inserted, rotary, turned, li
                    ns = _copy(scratch, ns, data, a, gb)
                    scratch[ns] = 32
                    ns = _put(scratch, ns + 1, letter)
                    ns = put_fixed(scratch, ns, add_c, d_ang)
                    ns = _copy(scratch, ns, data, gb, b)
                    changed += 1
                elif need_f:
                    ns = _copy_with_feed(scratch, ns, data, a, gb, b, feed)
                    if ns < 0:
                        return DECLINED, buf, n, changed, inserted, rotary, turned, li
                    changed += 1
                else:
                    ns = _copy(scratch, ns, data, a, b)
        else:
            # ---- the general case: chords and pieces, written as new G1 lines
            ga, gb = simple_span(data, a, b)
            if ga < 0:
                return DECLINED, buf, n, changed, inserted, rotary, turned, li
            fa, fb = _word(data, ga, gb, 70)
            wa, wb = _word(data, ga, gb, 69)
            has_e = wa >= 0
            e_start = 0.0
            if not e_rel:
                if not has_e:
                    return DECLINED, buf, n, changed, inserted, rotary, turned, li
                ok, e_end = parse_number(data, wa + 1, wb)
                if not ok:
                    return DECLINED, buf, n, changed, inserted, rotary, turned, li
                e_start = e_end - e_move
            changed += 1
            e_acc = 0.0
            first = True
            px = m_x0[mi]
            py = m_y0[mi]
            z0 = m_z0[mi]
            z1 = m_z1[mi]
            ramp = z1 != z0 and math.isfinite(z0) and math.isfinite(z1)
            total = 0.0
            if ramp:
                for s in range(a0, a1):
                    total += s_len[s]
            tot = total if total > 0 else 1.0
            acc = 0.0  # path length before chord s
            n_new = 0
            first_end = -1  # where the first new line ends in scratch (the note goes there)
            for s in range(a0, a1):
                sx0 = s_x0[s]
                sy0 = s_y0[s]
                sx1 = s_x1[s]
                sy1 = s_y1[s]
                in_p = s_in_pieces[s] != 0
                r0 = s_p0[s] if in_p else 0
                r1 = s_p1[s] if in_p else 1
                scratch = _reserve(scratch, ns, (r1 - r0 + 1) * extra)
                for r in range(r0, r1):
                    if in_p:
                        t0 = p_t0[r]
                        t1 = p_t1[r]
                        phi = p_angle[r]
                        scale = p_scale[r]
                    else:
                        t0 = 0.0
                        t1 = 1.0
                        phi = s_angle[s]
                        scale = s_scale[s]
                    qx0 = sx0 + t0 * (sx1 - sx0)
                    qy0 = sy0 + t0 * (sy1 - sy0)
                    qx1 = sx0 + t1 * (sx1 - sx0)
                    qy1 = sy0 + t1 * (sy1 - sy0)
                    gap_end = -1  # the end of the words of a line to the piece's start
                    if math.hypot(qx0 - px, qy0 - py) > 1e-9:
                        z = z0 + (z1 - z0) * min(1.0, (acc + t0 * s_len[s]) / tot) if ramp \
                            else 0.0
                        ns = _put_move(scratch, ns, qx0, qy0, ramp, z, xd)
                        if ns < 0:
                            return DECLINED, buf, n, changed, inserted, rotary, turned, li
                        gap_end = ns
                        if first_end < 0:
                            first_end = ns
                        ns = _put_eol(scratch, ns, data, e0, e1)
                        n_new += 1
                        px = qx0
                        py = qy0
                    c_word = False
                    c_val = 0.0
                    if turns and math.isfinite(phi):
                        ok, c, cm = _coordinate(phi, cur, period, lo, hi, unbounded, d_ang)
                        if not ok:
                            return DECLINED, buf, n, changed, inserted, rotary, turned, li
                        if cm != cur_m:
                            c_word = True
                            c_val = c
                            if in_p:
                                moving = p_fold[r] != 0 and abs(c - cur) <= p_turn[r] + 1e-6
                            else:
                                moving = s_fold[s] != 0 and abs(c - cur) <= s_turn[s] + 1e-6
                            if not moving:
                                c_word = False
                                if fold and travel >= 0 and ns == 0 and t_line < 0:
                                    # the first thing this move does: folded into the travel
                                    if unwind:
                                        ok, c, cm = _coordinate(phi, 0.0, period, lo, hi,
                                                                unbounded, d_ang)
                                        if not ok:
                                            return (DECLINED, buf, n, changed, inserted,
                                                    rotary, turned, li)
                                    ta, tb = simple_span(data, starts[travel],
                                                         starts[travel + 1])
                                    if ta < 0:
                                        return (DECLINED, buf, n, changed, inserted, rotary,
                                                turned, travel)
                                    t_line = travel
                                    t_gb = tb - starts[travel]
                                    t_word_c = c
                                elif ur >= 0 and ns == 0 and u_line < 0:
                                    # the first thing this move does: before the un-retract
                                    u_line = ur
                                    u_c = c
                                    inserted += 1
                                elif fold and gap_end >= 0:
                                    # made on the way to the piece's start (nothing
                                    # deposited): the word goes before that line's ending
                                    ns = gap_end
                                    scratch[ns] = 32
                                    ns = _put(scratch, ns + 1, letter)
                                    ns = put_fixed(scratch, ns, c, d_ang)
                                    if first_end == gap_end:
                                        first_end = ns
                                    ns = _put_eol(scratch, ns, data, e0, e1)
                                else:
                                    need_f = rot_feed > 0 and math.isfinite(feed)
                                    ns = _put_rotation(scratch, ns, letter, c, d_ang,
                                                       rot_feed if need_f else 0.0)
                                    if ns < 0:
                                        return (DECLINED, buf, n, changed, inserted,
                                                rotary, turned, li)
                                    if first_end < 0:
                                        first_end = ns
                                    ns = _put_eol(scratch, ns, data, e0, e1)
                                    n_new += 1
                            rotary += 1
                            turned[layer + 1] += 1
                            cur = c
                            cur_m = cm
                    de = s_e[s] * (t1 - t0) * scale
                    e_acc += de
                    z = z0 + (z1 - z0) * min(1.0, (acc + t1 * s_len[s]) / tot) if ramp else 0.0
                    ns = _put_move(scratch, ns, qx1, qy1, ramp, z, xd)
                    if ns < 0:
                        return DECLINED, buf, n, changed, inserted, rotary, turned, li
                    scratch[ns] = 32
                    scratch[ns + 1] = 69
                    ns = put_fixed(scratch, ns + 2, de if e_rel else e_start + e_acc, ed)
                    if ns < 0:
                        return DECLINED, buf, n, changed, inserted, rotary, turned, li
                    if c_word:
                        scratch[ns] = 32
                        ns = _put(scratch, ns + 1, letter)
                        ns = put_fixed(scratch, ns, c_val, d_ang)
                    if first and fa >= 0:
                        scratch[ns] = 32
                        ns = _copy(scratch, ns + 1, data, fa, fb)
                    elif need_f:
                        ns = _put_feed(scratch, ns, feed)
                        if ns < 0:
                            return DECLINED, buf, n, changed, inserted, rotary, turned, li
                    need_f = False
                    first = False
                    if first_end < 0:
                        first_end = ns
                    ns = _put_eol(scratch, ns, data, e0, e1)
                    n_new += 1
                    px = qx1
                    py = qy1
                if ramp:
                    acc += s_len[s]
            scratch = _reserve(scratch, ns, 2 * extra)
            ex = m_x1[mi]
            ey = m_y1[mi]
            if math.hypot(ex - px, ey - py) > 1e-9 or n_new == 0:
                # chord a1 - 1 at t = 1: the path length before it plus its own, which is
                # acc (summed in the same order)
                z = z0 + (z1 - z0) * min(1.0, acc / tot) if ramp else 0.0
                ns = _put_move(scratch, ns, ex, ey, ramp, z, xd)
                if ns < 0:
                    return DECLINED, buf, n, changed, inserted, rotary, turned, li
                if first and fa >= 0:
                    scratch[ns] = 32
                    ns = _copy(scratch, ns + 1, data, fa, fb)
                if first_end < 0:
                    first_end = ns
                ns = _put_eol(scratch, ns, data, e0, e1)
                n_new += 1
            if z1 != z0 and math.isfinite(z1) and not ramp:
                ns = _put(scratch, ns, np.array([71, 49, 32, 90], np.uint8))
                ns = put_fixed(scratch, ns, z1, xd)
                if ns < 0:
                    return DECLINED, buf, n, changed, inserted, rotary, turned, li
                ns = _put_eol(scratch, ns, data, e0, e1)
                n_new += 1
            if not e_rel and abs(e_acc - e_move) > 1e-05:
                ns = _put(scratch, ns, g92)
                ns = put_fixed(scratch, ns, e_end, ed)
                if ns < 0:
                    return DECLINED, buf, n, changed, inserted, rotary, turned, li
                ns = _put_eol(scratch, ns, data, e0, e1)
                n_new += 1
            # the note on the first new line: " ; printability: was " + the line, stripped
            ca, cb = _strip_span(data, a, b)
            cb = min(cb, ca + 60)
            k = len(note) + cb - ca
            scratch = _reserve(scratch, ns, k)
            scratch[first_end + k:ns + k] = scratch[first_end:ns].copy()
            w = _put(scratch, first_end, note)
            _copy(scratch, w, data, ca, cb)
            ns += k
            inserted += n_new - 1
        # ---- flush: the run, the travel (with the folded turn), the lines between, the move
        buf = _reserve(buf, n, (b - pos) + ns + 64 + len(letter))
        if t_line >= 0:
            ta = starts[t_line]
            n = _copy(buf, n, data, pos, ta + t_gb)
            buf[n] = 32
            n = _put(buf, n + 1, letter)
            n = put_fixed(buf, n, t_word_c, d_ang)
            pos = ta + t_gb
        if u_line >= 0:
            # the turn before the un-retract: nothing is deposited at the old orientation
            ua = starts[u_line]
            ub = starts[u_line + 1]
            ga, gb = simple_span(data, ua, ub)
            if ga < 0:
                return DECLINED, buf, n, changed, inserted, rotary, turned, u_line
            fa, fb = _word(data, ga, gb, 70)
            u_feed = m_feed[ur_mv]
            with_f = rot_feed > 0 and math.isfinite(u_feed)
            buf = _reserve(buf, n, (ub - pos) + 200 + len(letter))
            n = _copy(buf, n, data, pos, ua)
            n = _put_rotation(buf, n, letter, u_c, d_ang, rot_feed if with_f else 0.0)
            if n < 0:
                return DECLINED, buf, n, changed, inserted, rotary, turned, u_line
            ue0, ue1 = _eol(data, ua, ub)
            n = _put_eol(buf, n, data, ue0, ue1)
            if with_f and fa < 0:
                n = _copy_with_feed(buf, n, data, ua, gb, ub, u_feed)
                if n < 0:
                    return DECLINED, buf, n, changed, inserted, rotary, turned, u_line
                changed += 1
            else:
                n = _copy(buf, n, data, ua, ub)
            pos = ub
        n = _copy(buf, n, data, pos, a)
        n = _copy(buf, n, scratch, 0, ns)
        pos = b
    buf = _reserve(buf, n, len(data) - pos)
    n = _copy(buf, n, data, pos, len(data))
    return OK, buf, n, changed, inserted, rotary, turned, -1

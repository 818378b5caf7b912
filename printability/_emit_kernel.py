"""The generator's moves compiled: the same bytes as :class:`gcode.writer.Emitter`.

:func:`printability.generate.generate_gcode` writes every piece of every move
through the emitter's methods, about 20 µs each in Python: on a part of half
a million lines that was most of the run. :func:`emit_pieces` writes one
group's pieces (each a travel when it does not start where the nozzle is,
then a turn and the extrusion) in one pass, with the emitter's arithmetic in
the same order:

* numbers are :func:`gcode.writer.format_number`'s text
  (:func:`printability._rewrite_kernel.put_fixed`); two numbers are written
  the same exactly when their :func:`~printability._rewrite_kernel.fixed_digits`
  are equal, which is how the emitter's text comparisons are made here;
* ``round(v, d)`` is that integer over 10^d: Python rounds the exact binary
  value half to even, as :func:`~printability._rewrite_kernel.fixed_digits`
  does, and returns the double nearest the decimal, as one division of two
  exact doubles does; ``float(text)`` likewise;
* the rotary coordinate is :func:`gcode.rotary.nearest_equivalent`'s
  (:func:`~printability._rewrite_kernel._nearest`).

Whatever it declines (a number out of :func:`fixed_digits`' range, an
orientation the axis cannot reach, the inverse-time feed policy) it reports
without changing the state, and the caller writes that group with the emitter
itself: the output is the emitter's in every case (and its error, for an
unreachable orientation).

State (``fs``, ``ks``): ``fs = [x, y, z, angle, e, e_written]`` and ``ks =
[x known, y known, z known, F written, F digits, rotations, first move]``,
the emitter's fields (``F written`` 0 for its ``None``).

Complexity: linear in the pieces.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from gcode.writer import format_number
from printability._rewrite_kernel import _nearest, _reserve, fixed_digits, put_fixed
from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["DECLINED", "OK", "emit", "emit_pieces", "group_pieces", "hypot"]

OK = 0
DECLINED = 1

# policies (gcode.writer._FEED_POLICIES order): only xy and euclidean are compiled
_XY, _EUCLIDEAN = 0, 1

_X, _Y, _Z, _ANGLE, _E, _EW = range(6)
_XK, _YK, _ZK, _FK, _FM, _ROT, _FIRST = range(7)


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


@numba.njit(cache=True, nogil=True)
def _word(buf, n, letter, v, d):  # pragma: no cover
    """`` <letter><format_number(v, d)>`` at ``buf[n:]``; the new end, -1 when declined."""
    if n < 0:
        return -1
    buf[n] = 32
    buf[n + 1] = letter
    return put_fixed(buf, n + 2, v, d)


@numba.njit(cache=True, nogil=True)
def _e_word(buf, n, fs, delta, relative, ed, p10):  # pragma: no cover
    """``Emitter._e_word``: `` E…`` feeding ``delta`` more; the new end, -1 when declined."""
    fs[_E] += delta
    if relative:
        # the rounding error is carried, as the emitter carries it
        ok, mt = fixed_digits(fs[_E], ed)
        if not ok:
            return -1
        diff = mt / p10 - fs[_EW]
        ok, m = fixed_digits(diff, ed)
        if not ok:
            return -1
        ok, mw = fixed_digits(fs[_EW] + m / p10, ed)
        if not ok:
            return -1
        fs[_EW] = mw / p10
        return _word(buf, n, 69, diff, ed)
    ok, mw = fixed_digits(fs[_E], ed)
    if not ok:
        return -1
    fs[_EW] = mw / p10
    return _word(buf, n, 69, fs[_EW], ed)


@numba.njit(cache=True, nogil=True)
def _length(fs, ks, has_x, x, has_y, y):  # pragma: no cover
    """``Emitter._length``: XY length of a move, NaN from an unknown place."""
    if not has_x and not has_y:
        return 0.0
    if ks[_XK] == 0 or ks[_YK] == 0:
        return math.nan
    return hypot((x if has_x else fs[_X]) - fs[_X], (y if has_y else fs[_Y]) - fs[_Y])


@numba.njit(cache=True, nogil=True)
def _feed(buf, n, ks, feed, length, rotation, oi, of):  # pragma: no cover
    """``Emitter._feed_word`` (and :func:`gcode.rotary.feed_for_move`): `` F…`` when its
    text changes; the new end, -1 when declined."""
    if math.isnan(length):
        f = feed
    else:
        dphi = abs(rotation if oi[7] else 0.0)
        if length <= 1e-12:
            f = of[3]
        elif oi[4] == _XY:
            f = feed
        elif dphi * feed > of[3] * length:  # the turn is the slower part
            f = of[3] * hypot(length, dphi) / dphi
        else:
            f = feed * hypot(length, dphi) / length
    ok, m = fixed_digits(f, oi[3])
    if not ok:
        return -1
    if ks[_FK] == 0 or m != ks[_FM]:
        ks[_FK] = 1
        ks[_FM] = m
        return _word(buf, n, 70, f, oi[3])
    return n


@numba.njit(cache=True, nogil=True)
def _reach(orientation, previous, oi, of):  # pragma: no cover
    """(found, c): ``WriterOptions.coordinate`` of ``orientation`` near ``previous``."""
    return _nearest(orientation, previous, of[0], of[1], of[2], oi[10] != 0)


@numba.njit(cache=True, nogil=True)
def _turn(fs, orientation, unwind, oi, of, target):  # pragma: no cover
    """``Emitter._rotary`` without writing: (ok, a word to write, step), to the axis
    coordinate ``target`` when known (else NaN). The angle becomes the new coordinate when
    there is a word."""
    if math.isnan(orientation) or not oi[7]:
        return True, False, 0.0
    if math.isnan(target):
        found, target = _reach(orientation, 0.0 if unwind else fs[_ANGLE], oi, of)
        if not found:
            return False, False, 0.0
    ok, mt = fixed_digits(target, oi[2])
    ok2, ma = fixed_digits(fs[_ANGLE], oi[2])
    if not (ok and ok2):
        return False, False, 0.0
    if mt == ma:
        return True, False, 0.0
    step = target - fs[_ANGLE]
    fs[_ANGLE] = target
    return True, True, step


@numba.njit(cache=True, nogil=True)
def _xy(buf, n, fs, ks, has_x, x, has_y, y, has_z, z, xd):  # pragma: no cover
    """``Emitter._xy_words``: the coordinates whose text changes; the new end, -1."""
    for k in range(3):
        has = has_x if k == 0 else (has_y if k == 1 else has_z)
        if not has:
            continue
        v = x if k == 0 else (y if k == 1 else z)
        ok, m = fixed_digits(v, xd)
        if not ok:
            return -1
        if ks[_XK + k] != 0:
            ok, mo = fixed_digits(fs[_X + k], xd)
            if not ok:
                return -1
            if m == mo:
                continue
        n = _word(buf, n, 88 + k, v, xd)  # X, Y, Z
        if n < 0:
            return -1
    return n


@numba.njit(cache=True, nogil=True)
def _travel_move(buf, n, fs, ks, has_xy, x, y, has_z, z, feed, orientation, oi,
                 of):  # pragma: no cover
    """``Emitter.travel``: one line (or none); the new end, -1 when declined."""
    length = _length(fs, ks, has_xy, x, has_xy, y)
    ok, word, step = _turn(fs, orientation, oi[8] != 0, oi, of, math.nan)
    if not ok:
        return -1
    if step != 0.0:
        ks[_ROT] += 1
    start = n
    if n > 0:
        buf[n] = 10
        n += 1
    line = n
    buf[n] = 71  # G0, or G1 when it turns
    buf[n + 1] = 49 if word else 48
    n += 2
    n = _xy(buf, n, fs, ks, has_xy, x, has_xy, y, has_z, z, oi[0])
    if word:
        n = _word(buf, n, oi[9], fs[_ANGLE], oi[2])
    if n < 0:
        return -1
    n = _feed(buf, n, ks, feed, length, step, oi, of)
    if n < 0:
        return -1
    if n == line + 2:  # nothing to say: no line, and the position stays
        return start
    if has_xy:
        fs[_X] = x
        fs[_Y] = y
        ks[_XK] = 1
        ks[_YK] = 1
    if has_z:
        fs[_Z] = z
        ks[_ZK] = 1
    return n


@numba.njit(cache=True, nogil=True)
def _filament(buf, n, fs, ks, length, feed, oi, of, p10):  # pragma: no cover
    """``Emitter.retract`` (``length`` < 0) and ``unretract`` (> 0): ``G1 E… F…``."""
    if n > 0:
        buf[n] = 10
        n += 1
    buf[n] = 71
    buf[n + 1] = 49
    n = _e_word(buf, n + 2, fs, length, oi[5] != 0, oi[1], p10)
    ks[_FK] = 0  # a retraction feed must not become the XY feed
    return _word(buf, n, 70, feed, oi[3])


@numba.njit(cache=True, nogil=True)
def emit_pieces(ax, ay, bx, by, phi, width, fold, z, height, feed, trav, oi, of, fs,
                ks, buf):  # pragma: no cover
    """Write pieces ``a → b`` as :func:`printability.generate.generate_gcode` writes them.

    Piece ``q`` is extruded at orientation ``phi[q]`` (NaN: none) laying
    ``width[q]`` at ``height``, turning while it moves by up to ``fold[q]``
    degrees (NaN: it turns standing still), at ``feed``; a travel
    (``_travel``'s: retract, lift, move, lower, unretract, with
    ``trav = [travel feed, retraction length, its feed, shortest travel that
    retracts, lift]``) comes first where the nozzle is not at ``a`` (or on the
    layer's first move). ``oi = [xy, e, angle and F decimals, policy, relative E,
    rounded bead, rotary, unwind, letter, axis without limits]`` and ``of = [period, angle min, max,
    rotation-only feed, filament area, 1 − π/4, 10^e decimals]`` are the writer's
    options. ``fs``, ``ks`` (the module's state) are updated in place.

    Returns
    -------
    (status, end, buf)
        :data:`OK`, the end of the lines written and the buffer holding them (``buf``
        or a larger copy; lines joined by ``\\n``, none after the last), or
        :data:`DECLINED` (the state is then partial).
    """
    n = 0
    p10 = of[6]
    r_len = trav[1]
    lift = trav[4]
    for q in range(len(ax)):
        buf = _reserve(buf, n, 1536)  # a piece writes at most seven lines of ~200 bytes
        x0 = ax[q]
        y0 = ay[q]
        if ks[_XK] == 0 or hypot(x0 - fs[_X], y0 - fs[_Y]) > 1e-6 or ks[_FIRST] != 0:
            # generate._travel
            far = ks[_XK] == 0 or hypot(x0 - fs[_X], y0 - fs[_Y]) >= trav[3]
            if far:
                if r_len > 0:
                    n = _filament(buf, n, fs, ks, -r_len, trav[2], oi, of, p10)
                    if n < 0:
                        return DECLINED, 0, buf
                if lift > 0 and ks[_ZK] != 0:
                    n = _travel_move(buf, n, fs, ks, False, 0.0, 0.0, True, z + lift,
                                     trav[0], math.nan, oi, of)
                    if n < 0:
                        return DECLINED, 0, buf
            n = _travel_move(buf, n, fs, ks, True, x0, y0, not (far and lift > 0), z, trav[0],
                             phi[q], oi, of)
            if n < 0:
                return DECLINED, 0, buf
            if far:
                if lift > 0:
                    n = _travel_move(buf, n, fs, ks, False, 0.0, 0.0, True, z, trav[0],
                                     math.nan, oi, of)
                    if n < 0:
                        return DECLINED, 0, buf
                if r_len > 0:
                    n = _filament(buf, n, fs, ks, r_len, trav[2], oi, of, p10)
                    if n < 0:
                        return DECLINED, 0, buf
            ks[_FIRST] = 0
        # Emitter.extrude
        x1 = bx[q]
        y1 = by[q]
        length = _length(fs, ks, True, x1, True, y1)
        w = width[q]
        if oi[6]:
            area = max(w, height) * height - height * height * of[5]
        else:
            area = w * height
        e = length * (area / of[4])
        step = 0.0
        word = False
        if not math.isnan(phi[q]):
            turned = False
            target = math.nan  # the axis coordinate, once per piece
            if not math.isnan(fold[q]) and oi[7]:
                found, target = _reach(phi[q], fs[_ANGLE], oi, of)
                if not found:
                    return DECLINED, 0, buf
                if abs(target - fs[_ANGLE]) <= fold[q] + 1e-6:
                    turned = True
                    ok, word, step = _turn(fs, phi[q], False, oi, of, target)
                    if not ok:
                        return DECLINED, 0, buf
                    if step != 0.0:
                        ks[_ROT] += 1
            if not turned:
                # Emitter.rotate: a rotation-only line first
                ok, rword, rstep = _turn(fs, phi[q], False, oi, of, target)
                if not ok:
                    return DECLINED, 0, buf
                if rword:
                    ks[_ROT] += 1
                    if n > 0:
                        buf[n] = 10
                        n += 1
                    buf[n] = 71
                    buf[n + 1] = 49
                    n = _word(buf, n + 2, oi[9], fs[_ANGLE], oi[2])
                    n = _feed(buf, n, ks, 0.0, 0.0, rstep, oi, of) if n >= 0 else -1
                    if n < 0:
                        return DECLINED, 0, buf
        if n > 0:
            buf[n] = 10
            n += 1
        buf[n] = 71
        buf[n + 1] = 49
        n = _xy(buf, n + 2, fs, ks, True, x1, True, y1, False, 0.0, oi[0])
        if word:
            n = _word(buf, n, oi[9], fs[_ANGLE], oi[2])
        if n < 0:
            return DECLINED, 0, buf
        n = _e_word(buf, n, fs, e, oi[5] != 0, oi[1], p10)
        if n < 0:
            return DECLINED, 0, buf
        n = _feed(buf, n, ks, feed, length, step, oi, of)
        if n < 0:
            return DECLINED, 0, buf
        fs[_X] = x1
        fs[_Y] = y1
    return OK, n, buf



@numba.njit(cache=True, nogil=True)
def _bead_width(direction, angle, mount, fk, fa, fb, fcx, fcy, frot):  # pragma: no cover
    """:meth:`printability.nozzle.Nozzle.bead_width` of circles, ellipses (``fk`` 0) and
    rectangles (1): the same operations (numba's trigonometry is the C library's, as
    :mod:`math`'s)."""
    theta = math.radians(direction)
    nx = -math.sin(theta)
    ny = math.cos(theta)
    lo = math.inf
    hi = -math.inf
    for j in range(len(fk)):
        phi = math.radians(mount + angle + frot[j])
        c = math.cos(phi)
        s = math.sin(phi)
        cx = c * fcx[j] - s * fcy[j]
        cy = s * fcx[j] + c * fcy[j]
        mid = cx * nx + cy * ny
        ux = c * nx + s * ny
        uy = -s * nx + c * ny
        if fk[j] == 0:
            half = hypot(fa[j] * ux, fb[j] * uy)
        else:
            half = abs(fa[j] * ux) + abs(fb[j] * uy)
        lo = min(lo, mid - half)
        hi = max(hi, mid + half)
    return hi - lo


@numba.njit(cache=True, nogil=True)
def group_pieces(p0, p1, seg_len, angle, fold, split, lo, hi, rt0, rt1, rphi, turns, width,
                 mount, fk, fa, fb, fcx, fcy, frot, acc):  # pragma: no cover
    """The pieces the generator writes for one group of moves, and its running sums.

    Move ``i`` (``p0[i] → p1[i]``, of length ``seg_len[i]``) is one piece at
    ``angle[i]`` (turning while it moves when ``fold[i]``), or, where ``split[i]``, the
    planner's pieces ``lo[i] … hi[i] - 1`` of ``rt0``, ``rt1``, ``rphi``. Each piece's
    bead width is the nozzle's across its direction (:func:`_bead_width`; ``width``
    when it does not turn). ``acc = [extruded, layer length, layer dropped, last angle]``
    is updated in the generator's order.

    Returns
    -------
    ax, ay, bx, by, phi, w, fold : ndarray
        Per piece, as :func:`emit_pieces` takes them.
    """
    n = len(p0)
    m = 0
    for i in range(n):
        m += hi[i] - lo[i] if split[i] else 1
    ax = np.empty(m)
    ay = np.empty(m)
    bx = np.empty(m)
    by = np.empty(m)
    phi = np.empty(m)
    w = np.empty(m)
    fo = np.empty(m)
    q = 0
    for i in range(n):
        x0 = p0[i, 0]
        y0 = p0[i, 1]
        dx = p1[i, 0] - x0
        dy = p1[i, 1] - y0
        acc[1] += seg_len[i]
        if split[i]:
            kept = 0.0
            for r in range(lo[i], hi[i]):
                kept += rt1[r] - rt0[r]
            acc[2] += seg_len[i] * (1 - kept)
            r0 = lo[i]
            r1 = hi[i]
        else:
            r0 = 0
            r1 = 1
        for r in range(r0, r1):
            if split[i]:
                t0 = rt0[r]
                t1 = rt1[r]
                a = rphi[r]
            else:
                t0 = 0.0
                t1 = 1.0
                a = angle[i]
            ax[q] = x0 + t0 * dx
            ay[q] = y0 + t0 * dy
            bx[q] = x0 + t1 * dx
            by[q] = y0 + t1 * dy
            direction = math.degrees(math.atan2(by[q] - ay[q], bx[q] - ax[q]))
            if turns:
                w[q] = _bead_width(direction, a, mount, fk, fa, fb, fcx, fcy, frot)
                phi[q] = a
                acc[3] = a
            else:
                w[q] = width
                phi[q] = math.nan
            fo[q] = abs(angle[i] - angle[i - 1]) if not split[i] and fold[i] else math.nan
            acc[0] += hypot(bx[q] - ax[q], by[q] - ay[q])
            q += 1
    return ax, ay, bx, by, phi, w, fo


_POLICIES = {"xy": _XY, "euclidean": _EUCLIDEAN}


def emit(em, ax, ay, bx, by, phi, width, fold, *, z: float, height: float, feed: float,
         travel: tuple[float, float, float, float, float], first_move: bool) -> bool | None:
    """Write pieces through :func:`emit_pieces` onto the emitter ``em`` (its lines and state,
    private fields included: this is its compiled twin), as the generator's loop of
    ``_travel`` and ``Emitter.extrude`` would.

    Parameters are :func:`emit_pieces`' (sequences of floats; ``phi``, ``fold``: NaN for
    None). Returns the first-move flag after the pieces, or None when the kernel declines:
    then ``em`` is unchanged and the caller writes the pieces with the emitter.
    """
    o = em.options
    decimals = (o.xy_decimals, o.e_decimals, o.angle_decimals, o.feed_decimals)
    if o.feed_policy not in _POLICIES or not all(0 <= d <= 17 for d in decimals):
        return None
    fw = em._feed_written
    fm = 0
    if fw is not None:
        whole, _, frac = fw.partition(".")
        if len(frac) > o.feed_decimals:
            return None
        fm = int(whole + frac.ljust(o.feed_decimals, "0"))
    fs = np.array([em.x or 0.0, em.y or 0.0, em.z or 0.0, em.angle, em.e, em._e_written])
    ks = np.array([em.x is not None, em.y is not None, em.z is not None, fw is not None, fm,
                   em.rotations, first_move], dtype=np.int64)
    lo, hi = o.angle_min, o.angle_max
    unbounded = math.isinf(lo) and math.isinf(hi) and lo < 0 < hi
    oi = np.array([*decimals, _POLICIES[o.feed_policy], o.relative_e,
                   o.bead_model == "rounded", o.rotary, o.unwind, ord(o.letter), unbounded],
                  dtype=np.int64)
    of = np.array([o.period or 360.0, o.angle_min, o.angle_max, o.rotary_feed,
                   math.pi * o.filament_diameter**2 / 4.0, 1.0 - math.pi / 4.0,
                   10.0 ** o.e_decimals])
    arrays = [np.asarray(v, dtype=float) for v in (ax, ay, bx, by, phi, width, fold)]
    status, n, buf = emit_pieces(*arrays, float(z), float(height), float(feed),
                                 np.asarray(travel, dtype=float), oi, of, fs, ks,
                                 np.empty(256 * len(arrays[0]) + 2048, np.uint8))
    if status != OK:
        return None
    if n:
        em.lines.extend(buf[:n].tobytes().decode("ascii").split("\n"))
    em.x = float(fs[0]) if ks[0] else None
    em.y = float(fs[1]) if ks[1] else None
    em.z = float(fs[2]) if ks[2] else None
    em.angle, em.e, em._e_written = float(fs[3]), float(fs[4]), float(fs[5])
    em._feed_written = format_number(ks[4] / 10.0 ** o.feed_decimals, o.feed_decimals) \
        if ks[3] else None
    em.rotations = int(ks[5])
    return bool(ks[6])

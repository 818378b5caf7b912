"""The generator's moves compiled: the same bytes as :class:`gcode.writer.Emitter`.

:func:`printability.generate.generate_gcode` writes every piece of every move
through the emitter's methods, about 20 µs each in Python: on a part of half
a million lines that was most of the run. :func:`emit_pieces` writes one
group's pieces (each a travel when it does not start where the nozzle is,
then a turn and the extrusion) in one pass, with the emitter's arithmetic in
the same order:

* numbers are :func:`gcode.writer.format_number`'s text
  (:func:`gcode.text_kernels.put_fixed`); two numbers are written
  the same exactly when their :func:`~gcode.text_kernels.fixed_digits`
  are equal, which is how the emitter's text comparisons are made here;
* ``round(v, d)`` is that integer over 10^d: Python rounds the exact binary
  value half to even, as :func:`~gcode.text_kernels.fixed_digits`
  does, and returns the double nearest the decimal, as one division of two
  exact doubles does; ``float(text)`` likewise;
* the rotary coordinate is :func:`gcode.rotary.nearest_equivalent`'s
  (:func:`~gcode.text_kernels.nearest`).

Whatever it declines (a number out of :func:`fixed_digits`' range, an
orientation the axis cannot reach, the inverse-time feed policy) it reports
without changing the state, and the caller writes that group with the emitter
itself: the output is the emitter's in every case (and its error, for an
unreachable orientation).

Records: the pieces (:class:`Pieces`, columns: :func:`printability.generate._group_kernel.pieces_of`
makes them), the writer's options (:data:`EMIT_OPTIONS`), the generator's travels
(:data:`TRAVEL`), the emitter's state (:data:`EMIT_STATE`: its fields, updated in place).

Complexity: linear in the pieces.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from gcode.text_kernels import fixed_digits, hypot, nearest, put_fixed, reserve
from gcode.writer import format_number
from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

# hypot: the tests import it from here
__all__ = ["DECLINED", "EMIT_OPTIONS", "EMIT_STATE", "OK", "TRAVEL", "Pieces", "emit",
           "emit_pieces", "hypot"]

OK = 0
DECLINED = 1

# policies (gcode.writer._FEED_POLICIES order): only xy and euclidean are compiled
_XY, _EUCLIDEAN = 0, 1

_i8, _f8, _b1 = np.int64, np.float64, np.bool_

EMIT_OPTIONS = np.dtype([
    ("xy_decimals", _i8), ("e_decimals", _i8), ("angle_decimals", _i8), ("feed_decimals", _i8),
    ("policy", _i8),  # _XY or _EUCLIDEAN
    ("relative_e", _b1), ("rounded", _b1),  # bead model "rounded"
    ("rotary", _b1), ("unwind", _b1),
    ("letter", _i8),  # the rotary axis's, its byte
    ("unbounded", _b1),  # the axis has no limits
    ("period", _f8), ("angle_min", _f8), ("angle_max", _f8),
    ("rotary_feed", _f8),  # degrees per minute of a rotation-only move
    ("filament_area", _f8),  # mm²
    ("corner", _f8),  # 1 − π/4: what a rounded bead lacks of its rectangle, per height²
    ("e_unit", _f8),  # 10^e_decimals
])
"""The writer's options (:class:`gcode.writer.WriterOptions`), as the kernel reads them."""

TRAVEL = np.dtype([
    ("feed", _f8),  # mm/min
    ("retract", _f8), ("retract_feed", _f8),  # retraction length (0: none), its feed
    ("retract_min", _f8),  # the shortest travel that retracts
    ("lift", _f8),  # Z lift (0: none)
])
"""How the generator travels between pieces (``generate._travel``)."""

EMIT_STATE = np.dtype([
    ("x", _f8), ("y", _f8), ("z", _f8), ("angle", _f8), ("e", _f8), ("e_written", _f8),
    ("x_known", _b1), ("y_known", _b1), ("z_known", _b1),
    ("f_known", _b1), ("f_digits", _i8),  # the F written (its digits), if any
    ("rotations", _i8), ("first", _b1),  # the layer's first move is still to come
])
"""The emitter's state: its fields (``None`` for an unknown place or F as ``known``
False)."""

class Pieces(NamedTuple):
    """Pieces ``a → b`` as columns: ends, orientation (NaN: none), width laid, and the
    turn made while moving into it (NaN: it turns standing still)."""

    ax: np.ndarray
    ay: np.ndarray
    bx: np.ndarray
    by: np.ndarray
    phi: np.ndarray
    width: np.ndarray
    fold: np.ndarray


@numba.njit(cache=True, nogil=True)
def _word(buf, n, letter, v, d):  # pragma: no cover
    """`` <letter><format_number(v, d)>`` at ``buf[n:]``; the new end, -1 when declined."""
    if n < 0:
        return -1
    buf[n] = 32
    buf[n + 1] = letter
    return put_fixed(buf, n + 2, v, d)


@numba.njit(cache=True, nogil=True)
def _e_word(buf, n, st, delta, o):  # pragma: no cover
    """``Emitter._e_word``: `` E…`` feeding ``delta`` more; the new end, -1 when declined."""
    ed = o.e_decimals
    p10 = o.e_unit
    st.e += delta
    if o.relative_e:
        # the rounding error is carried, as the emitter carries it
        ok, mt = fixed_digits(st.e, ed)
        if not ok:
            return -1
        diff = mt / p10 - st.e_written
        ok, m = fixed_digits(diff, ed)
        if not ok:
            return -1
        ok, mw = fixed_digits(st.e_written + m / p10, ed)
        if not ok:
            return -1
        st.e_written = mw / p10
        return _word(buf, n, 69, diff, ed)
    ok, mw = fixed_digits(st.e, ed)
    if not ok:
        return -1
    st.e_written = mw / p10
    return _word(buf, n, 69, st.e_written, ed)


@numba.njit(cache=True, nogil=True)
def _length(st, has_x, x, has_y, y):  # pragma: no cover
    """``Emitter._length``: XY length of a move, NaN from an unknown place."""
    if not has_x and not has_y:
        return 0.0
    if not st.x_known or not st.y_known:
        return math.nan
    return hypot((x if has_x else st.x) - st.x, (y if has_y else st.y) - st.y)


@numba.njit(cache=True, nogil=True)
def _feed(buf, n, st, feed, length, rotation, o):  # pragma: no cover
    """``Emitter._feed_word`` (and :func:`gcode.rotary.feed_for_move`): `` F…`` when its
    text changes; the new end, -1 when declined."""
    if math.isnan(length):
        f = feed
    else:
        dphi = abs(rotation if o.rotary else 0.0)
        if length <= 1e-12:
            f = o.rotary_feed
        elif o.policy == _XY:
            f = feed
        elif dphi * feed > o.rotary_feed * length:  # the turn is the slower part
            f = o.rotary_feed * hypot(length, dphi) / dphi
        else:
            f = feed * hypot(length, dphi) / length
    ok, m = fixed_digits(f, o.feed_decimals)
    if not ok:
        return -1
    if not st.f_known or m != st.f_digits:
        st.f_known = True
        st.f_digits = m
        return _word(buf, n, 70, f, o.feed_decimals)
    return n


@numba.njit(cache=True, nogil=True)
def _reach(orientation, previous, o):  # pragma: no cover
    """(found, c): ``WriterOptions.coordinate`` of ``orientation`` near ``previous``."""
    return nearest(orientation, previous, o.period, o.angle_min, o.angle_max, o.unbounded)


@numba.njit(cache=True, nogil=True)
def _turn(st, orientation, unwind, o, target):  # pragma: no cover
    """``Emitter._rotary`` without writing: (ok, a word to write, step), to the axis
    coordinate ``target`` when known (else NaN). The angle becomes the new coordinate when
    there is a word."""
    if math.isnan(orientation) or not o.rotary:
        return True, False, 0.0
    if math.isnan(target):
        found, target = _reach(orientation, 0.0 if unwind else st.angle, o)
        if not found:
            return False, False, 0.0
    ok, mt = fixed_digits(target, o.angle_decimals)
    ok2, ma = fixed_digits(st.angle, o.angle_decimals)
    if not (ok and ok2):
        return False, False, 0.0
    if mt == ma:
        return True, False, 0.0
    step = target - st.angle
    st.angle = target
    return True, True, step


@numba.njit(cache=True, nogil=True)
def _xy(buf, n, st, has_x, x, has_y, y, has_z, z, xd):  # pragma: no cover
    """``Emitter._xy_words``: the coordinates whose text changes; the new end, -1."""
    for k in range(3):
        has = has_x if k == 0 else (has_y if k == 1 else has_z)
        if not has:
            continue
        v = x if k == 0 else (y if k == 1 else z)
        ok, m = fixed_digits(v, xd)
        if not ok:
            return -1
        if st.x_known if k == 0 else (st.y_known if k == 1 else st.z_known):
            ok, mo = fixed_digits(st.x if k == 0 else (st.y if k == 1 else st.z), xd)
            if not ok:
                return -1
            if m == mo:
                continue
        n = _word(buf, n, 88 + k, v, xd)  # X, Y, Z
        if n < 0:
            return -1
    return n


@numba.njit(cache=True, nogil=True)
def _travel_move(buf, n, st, o, has_xy, x, y, has_z, z, feed,
                 orientation):  # pragma: no cover
    """``Emitter.travel``: one line (or none); the new end, -1 when declined."""
    length = _length(st, has_xy, x, has_xy, y)
    ok, word, step = _turn(st, orientation, o.unwind, o, math.nan)
    if not ok:
        return -1
    if step != 0.0:
        st.rotations += 1
    start = n
    if n > 0:
        buf[n] = 10
        n += 1
    line = n
    buf[n] = 71  # G0, or G1 when it turns
    buf[n + 1] = 49 if word else 48
    n += 2
    n = _xy(buf, n, st, has_xy, x, has_xy, y, has_z, z, o.xy_decimals)
    if word:
        n = _word(buf, n, o.letter, st.angle, o.angle_decimals)
    if n < 0:
        return -1
    n = _feed(buf, n, st, feed, length, step, o)
    if n < 0:
        return -1
    if n == line + 2:  # nothing to say: no line, and the position stays
        return start
    if has_xy:
        st.x = x
        st.y = y
        st.x_known = True
        st.y_known = True
    if has_z:
        st.z = z
        st.z_known = True
    return n


@numba.njit(cache=True, nogil=True)
def _filament(buf, n, st, length, feed, o):  # pragma: no cover
    """``Emitter.retract`` (``length`` < 0) and ``unretract`` (> 0): ``G1 E… F…``."""
    if n > 0:
        buf[n] = 10
        n += 1
    buf[n] = 71
    buf[n + 1] = 49
    n = _e_word(buf, n + 2, st, length, o)
    st.f_known = False  # a retraction feed must not become the XY feed
    return _word(buf, n, 70, feed, o.feed_decimals)


@numba.njit(cache=True, nogil=True)
def _travel_to(buf, n, st, o, tr, x, y, z, orientation):  # pragma: no cover
    """``generate._travel`` to ``(x, y)`` at height ``z``, turning to ``orientation``:
    retract, lift, move, lower, unretract (the retraction and lift where the travel is long,
    or from an unknown place); the new end, -1 when declined."""
    far = not st.x_known or hypot(x - st.x, y - st.y) >= tr.retract_min
    if far:
        if tr.retract > 0:
            n = _filament(buf, n, st, -tr.retract, tr.retract_feed, o)
            if n < 0:
                return -1
        if tr.lift > 0 and st.z_known:
            n = _travel_move(buf, n, st, o, False, 0.0, 0.0, True, z + tr.lift, tr.feed,
                             math.nan)
            if n < 0:
                return -1
    n = _travel_move(buf, n, st, o, True, x, y, not (far and tr.lift > 0), z, tr.feed,
                     orientation)
    if n < 0:
        return -1
    if far:
        if tr.lift > 0:
            n = _travel_move(buf, n, st, o, False, 0.0, 0.0, True, z, tr.feed, math.nan)
            if n < 0:
                return -1
        if tr.retract > 0:
            n = _filament(buf, n, st, tr.retract, tr.retract_feed, o)
    return n


@numba.njit(cache=True, nogil=True)
def _extrude(buf, n, st, o, x, y, phi, w, fold, height, feed):  # pragma: no cover
    """``Emitter.extrude`` to ``(x, y)`` at orientation ``phi`` (NaN: none) laying ``w`` at
    ``height``, turning while it moves by up to ``fold`` degrees (NaN: a rotation-only line
    first), at ``feed``; the new end, -1 when declined."""
    length = _length(st, True, x, True, y)
    if o.rounded:
        area = max(w, height) * height - height * height * o.corner
    else:
        area = w * height
    e = length * (area / o.filament_area)
    step = 0.0
    word = False
    if not math.isnan(phi):
        turned = False
        target = math.nan  # the axis coordinate, once per piece
        if not math.isnan(fold) and o.rotary:
            found, target = _reach(phi, st.angle, o)
            if not found:
                return -1
            if abs(target - st.angle) <= fold + 1e-6:
                turned = True
                ok, word, step = _turn(st, phi, False, o, target)
                if not ok:
                    return -1
                if step != 0.0:
                    st.rotations += 1
        if not turned:
            # Emitter.rotate: a rotation-only line first
            ok, rword, rstep = _turn(st, phi, False, o, target)
            if not ok:
                return -1
            if rword:
                st.rotations += 1
                if n > 0:
                    buf[n] = 10
                    n += 1
                buf[n] = 71
                buf[n + 1] = 49
                n = _word(buf, n + 2, o.letter, st.angle, o.angle_decimals)
                n = _feed(buf, n, st, 0.0, 0.0, rstep, o) if n >= 0 else -1
                if n < 0:
                    return -1
    if n > 0:
        buf[n] = 10
        n += 1
    buf[n] = 71
    buf[n + 1] = 49
    n = _xy(buf, n + 2, st, True, x, True, y, False, 0.0, o.xy_decimals)
    if word:
        n = _word(buf, n, o.letter, st.angle, o.angle_decimals)
    if n < 0:
        return -1
    n = _e_word(buf, n, st, e, o)
    if n < 0:
        return -1
    n = _feed(buf, n, st, feed, length, step, o)
    if n < 0:
        return -1
    st.x = x
    st.y = y
    return n


@numba.njit(cache=True, nogil=True)
def emit_pieces(pieces, z, height, feed, travel, opts, state, buf):  # pragma: no cover
    """Write pieces as :func:`printability.generate.generate_gcode` writes them.

    ``pieces`` (:class:`Pieces`' columns, a tuple) are extruded at ``height`` and ``feed``,
    each after a travel (``generate._travel``'s, as ``travel[0]`` says: :data:`TRAVEL`)
    where the nozzle is not at its start (or on the layer's first move), at height ``z``.
    ``opts[0]``: the writer's options (:data:`EMIT_OPTIONS`); ``state[0]``: the emitter's
    (:data:`EMIT_STATE`), updated in place.

    Returns
    -------
    (status, end, buf)
        :data:`OK`, the end of the lines written and the buffer holding them (``buf``
        or a larger copy; lines joined by ``\\n``, none after the last), or
        :data:`DECLINED` (the state is then partial).
    """
    ax, ay, bx, by, phi, width, fold = pieces
    st = state[0]
    o = opts[0]
    tr = travel[0]
    n = 0
    for q in range(len(ax)):
        buf = reserve(buf, n, 1536)  # a piece writes at most seven lines of ~200 bytes
        x0 = ax[q]
        y0 = ay[q]
        if not st.x_known or hypot(x0 - st.x, y0 - st.y) > 1e-6 or st.first:
            n = _travel_to(buf, n, st, o, tr, x0, y0, z, phi[q])
            if n < 0:
                return DECLINED, 0, buf
            st.first = False
        n = _extrude(buf, n, st, o, bx[q], by[q], phi[q], width[q], fold[q], height, feed)
        if n < 0:
            return DECLINED, 0, buf
    return OK, n, buf


_POLICIES = {"xy": _XY, "euclidean": _EUCLIDEAN}
_last_options: tuple = (None, None)


def _options(o) -> np.ndarray:
    """The :data:`EMIT_OPTIONS` record of ``o`` (frozen: the last one's is kept, the
    generator calls :func:`emit` for every group with the same)."""
    global _last_options
    last, rec = _last_options
    if last is o:
        return rec
    lo, hi = o.angle_min, o.angle_max
    rec = np.array([(o.xy_decimals, o.e_decimals, o.angle_decimals, o.feed_decimals,
                     _POLICIES[o.feed_policy], o.relative_e, o.bead_model == "rounded",
                     o.rotary, o.unwind, ord(o.letter),
                     math.isinf(lo) and math.isinf(hi) and lo < 0 < hi, o.period or 360.0, lo,
                     hi, o.rotary_feed, math.pi * o.filament_diameter**2 / 4.0,
                     1.0 - math.pi / 4.0, 10.0 ** o.e_decimals)], dtype=EMIT_OPTIONS)
    _last_options = (o, rec)
    return rec


def emit(em, *columns, z: float, height: float, feed: float,
         travel: tuple[float, float, float, float, float], first_move: bool) -> bool | None:
    """Write pieces through :func:`emit_pieces` onto the emitter ``em`` (its lines and state,
    private fields included: this is its compiled twin), as the generator's loop of
    ``_travel`` and ``Emitter.extrude`` would.

    ``columns``: the pieces' (:class:`Pieces`' fields in order, sequences of floats;
    ``phi``, ``fold``: NaN for None); ``travel``: :data:`TRAVEL`'s fields in order. Returns
    the first-move flag after the pieces, or None when the kernel declines: then ``em`` is
    unchanged and the caller writes the pieces with the emitter.
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
    state = np.array([(em.x or 0.0, em.y or 0.0, em.z or 0.0, em.angle, em.e, em._e_written,
                       em.x is not None, em.y is not None, em.z is not None, fw is not None, fm,
                       em.rotations, first_move)], dtype=EMIT_STATE)
    # a plain tuple: a named one costs numba's dispatch 2 µs a call
    pieces = tuple(np.asarray(v, dtype=float) for v in columns)
    status, n, buf = emit_pieces(pieces, float(z), float(height), float(feed),
                                 np.array([tuple(travel)], dtype=TRAVEL), _options(o), state,
                                 np.empty(256 * len(pieces[0]) + 2048, np.uint8))
    if status != OK:
        return None
    if n:
        em.lines.extend(buf[:n].tobytes().decode("ascii").split("\n"))
    s = state[0].item()
    x, y, z_, angle, e, e_written, xk, yk, zk, fk, fm, rotations, first = s
    em.x = x if xk else None
    em.y = y if yk else None
    em.z = z_ if zk else None
    em.angle, em.e, em._e_written = angle, e, e_written
    em._feed_written = format_number(fm / 10.0 ** o.feed_decimals, o.feed_decimals) \
        if fk else None
    em.rotations = rotations
    return first

"""The moves of the compiled rewrite pass (:mod:`printability.postprocess._rewrite_kernel`):
each writes the new text of one move into a scratch buffer, as the reference
(:mod:`printability.postprocess._rewrite_reference`) does.

* :func:`simple_move`: a whole chord (a rotary word, an E edit, or both; a turn that cannot
  be made while moving goes before the move: folded into the travel before it, else
  before the un-retract, else on a line of its own);
* :func:`split_move`: arcs and split moves, written as new ``G1`` lines, the first
  carrying the old line as a note.

Each takes the file's bytes ``data``, the move's and its chords' rows (the parser's move
record, :data:`~printability.postprocess._rewrite_kernel.CHORD_ROW`; a split move's pieces, of
:data:`~printability.postprocess._rewrite_kernel.PIECE_ROW`), the writer's options ``cfg``
(:class:`~printability.postprocess._rewrite_kernel.RewriteConfig`), the pass's state ``st``
and the move's ``mv`` (records of :data:`~printability.postprocess._rewrite_kernel.PASS_STATE`
and :data:`~printability.postprocess._rewrite_kernel.MOVE_STATE`, updated in place), and
returns the line it declines (the caller then runs the reference) or -1, with the end of its
text; the rotary words it writes are counted in ``st`` and ``mv.turns``. A coordinate of NaN
stands for no rotary word. (Rows, not named tuples of columns, and as few arrays passed as can
be: numba counts a reference to an array at each call it is passed to and at each use of
one taken from a tuple, which made the pass take twice its time.)

Complexity: linear in the move's bytes and new lines.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from gcode.text_kernels import (
    coordinate,
    copy,
    copy_with_feed,
    parse_number,
    put,
    put_eol,
    put_feed,
    put_fixed,
    put_move,
    put_rotation,
    reserve,
    simple_span,
    strip_span,
    word_span,
)
from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["simple_move", "split_move"]

_G92 = np.array([71, 57, 50, 32, 69], np.uint8)  # "G92 E"
_G1Z = np.array([71, 49, 32, 90], np.uint8)  # "G1 Z"
_NOTE = np.array([32, 59, 32, 112, 114, 105, 110, 116, 97, 98, 105, 108, 105, 116, 121,
                  58, 32, 119, 97, 115, 32], np.uint8)  # " ; printability: was "


@numba.njit(cache=True, nogil=True, inline="always")
def _put_word(buf, n, cfg, c):  # pragma: no cover
    """`` <letter><c>`` at ``buf[n:]``: the new end."""
    buf[n] = 32
    buf[n + 1] = cfg.letter
    return put_fixed(buf, n + 2, c, cfg.angle_decimals)


@numba.njit(cache=True, nogil=True, inline="always")
def _coordinate(cfg, phi, previous):  # pragma: no cover
    """(ok, c, digits of c): the axis coordinate for ``phi`` nearest ``previous``."""
    return coordinate(phi, previous, cfg.period, cfg.angle_min, cfg.angle_max, cfg.unbounded,
                      cfg.angle_decimals)


@numba.njit(cache=True, nogil=True, inline="always")
def _count_turn(st, mv, c, cm):  # pragma: no cover
    """A rotary word in the move: the axis is now at ``c`` (digits ``cm``)."""
    st.rotary += 1
    mv.turns += 1
    st.cur = c
    st.cur_m = cm


@numba.njit(cache=True, nogil=True, inline="always")
def _fold_into_travel(data, cfg, mv, phi, c, cm):  # pragma: no cover
    """The turn to ``c`` folded into the travel before the move (from 0 when the writer
    unwinds): (line declined or -1, the coordinate, its digits)."""
    if cfg.unwind:
        ok, c, cm = _coordinate(cfg, phi, 0.0)
        if not ok:
            return mv.line, c, cm
    ta, tb = simple_span(data, mv.travel_a, mv.travel_b)
    if ta < 0:
        return mv.travel, c, cm
    mv.t_line = mv.travel
    mv.t_end = tb
    mv.t_c = c
    return -1, c, cm


@numba.njit(cache=True, nogil=True, inline="always")
def _rotation_line(cfg, mv, scratch, ns, c):  # pragma: no cover
    """``G1 <letter><c>`` at ``scratch[ns:]`` (no line ending), with the rotation feed when
    the feed to restore after it is known (the move's next line restores it): the new end,
    -1 when declined."""
    mv.need_f = cfg.rotary_feed > 0 and math.isfinite(mv.feed)
    return put_rotation(scratch, ns, cfg.letter, c, cfg.angle_decimals,
                        cfg.rotary_feed if mv.need_f else 0.0)


@numba.njit(cache=True, nogil=True, inline="always")
def _simple_turn(data, chord, cfg, st, mv, scratch):  # pragma: no cover
    """The turn into a whole chord: (line declined or -1, end of a rotation line written
    before the move or 0, the rotary word the move carries or NaN)."""
    phi = chord.angle
    if not (cfg.turns and math.isfinite(phi)):
        return -1, 0, math.nan
    ok, c, cm = _coordinate(cfg, phi, st.cur)
    if not ok:
        return mv.line, 0, math.nan
    if chord.fold != 0 and abs(c - st.cur) <= chord.turn + 1e-6:
        # the turn checked by the planner, made while moving
        if cm == st.cur_m:
            return -1, 0, math.nan
        _count_turn(st, mv, c, cm)
        return -1, 0, c
    if cm == st.cur_m:
        return -1, 0, math.nan
    ns = 0
    if cfg.fold and mv.travel >= 0:
        bad, c, cm = _fold_into_travel(data, cfg, mv, phi, c, cm)
        if bad >= 0:
            return bad, 0, math.nan
    elif mv.ur >= 0:
        mv.u_line = mv.ur
        mv.u_c = c
        st.inserted += 1
    else:
        ns = _rotation_line(cfg, mv, scratch, 0, c)
        if ns < 0:
            return mv.line, 0, math.nan
        ns = put_eol(scratch, ns, data, mv.e0, mv.e1)
        st.inserted += 1
    _count_turn(st, mv, c, cm)
    return -1, ns, math.nan


@numba.njit(cache=True, nogil=True, inline="always")
def _edit_e(data, cfg, st, mv, scratch, ns, gb, wa, wb, scale, add_c):  # pragma: no cover
    """The move's line with its E word (``data[wa:wb]``; the words end at ``gb``) scaled,
    the rotary word ``add_c`` and the feed to restore added, and ``G92 E`` after it in
    absolute-E files: (line declined or -1, the new end)."""
    ok, v = parse_number(data, wa + 1, wb)
    if not ok:
        return mv.line, ns
    e_move = mv.e_move
    new_e = e_move * scale if mv.e_rel else (v - e_move) + e_move * scale
    ns = copy(scratch, ns, data, mv.a, wa + 1)
    ns = put_fixed(scratch, ns, new_e, cfg.e_decimals)
    if ns < 0:
        return mv.line, ns
    ns = copy(scratch, ns, data, wb, gb)
    if not math.isnan(add_c):
        ns = _put_word(scratch, ns, cfg, add_c)
    if mv.need_f:
        ns = put_feed(scratch, ns, mv.feed)
        if ns < 0:
            return mv.line, ns
    ns = copy(scratch, ns, data, gb, mv.b)
    st.changed += 1
    if not mv.e_rel:
        ns = put(scratch, ns, _G92)
        ns = put_fixed(scratch, ns, v, cfg.e_decimals)
        if ns < 0:
            return mv.line, ns
        ns = put_eol(scratch, ns, data, mv.e0, mv.e1)
        st.inserted += 1
    return -1, ns


@numba.njit(cache=True, nogil=True, inline="always")
def simple_move(data, chord, cfg, st, mv, scratch):  # pragma: no cover
    """A move of one whole chord: a rotary word, an E edit, or both, at ``scratch[0:]``
    (a rotation line first when the turn goes just before it; ``chord``: its row). Returns
    (line declined or -1, the end of its text)."""
    bad, ns, add_c = _simple_turn(data, chord, cfg, st, mv, scratch)
    if bad >= 0:
        return bad, ns
    ga, gb = simple_span(data, mv.a, mv.b)
    if mv.need_f:
        if ga < 0:
            return mv.line, ns
        fa, _ = word_span(data, ga, gb, 70)
        mv.need_f = fa < 0
    scale = chord.scale
    if scale != 1.0:
        if ga < 0:
            return mv.line, ns
        wa, wb = word_span(data, ga, gb, 69)
        if wa >= 0:
            return _edit_e(data, cfg, st, mv, scratch, ns, gb, wa, wb, scale, add_c)
    if not math.isnan(add_c):
        if ga < 0:
            return mv.line, ns
        ns = copy(scratch, ns, data, mv.a, gb)
        ns = _put_word(scratch, ns, cfg, add_c)
        ns = copy(scratch, ns, data, gb, mv.b)
        st.changed += 1
    elif mv.need_f:
        ns = copy_with_feed(scratch, ns, data, mv.a, gb, mv.b, mv.feed)
        if ns < 0:
            return mv.line, ns
        st.changed += 1
    else:
        ns = copy(scratch, ns, data, mv.a, mv.b)
    return -1, ns


@numba.njit(cache=True, nogil=True, inline="always")
def _split_begin(data, m, chords, st, mv):  # pragma: no cover
    """Read the move's F and E words and set up its new lines (E so far, the nozzle's
    place, Z along a climb): the line declined or -1."""
    ga, gb = simple_span(data, mv.a, mv.b)
    if ga < 0:
        return mv.line
    fa, fb = word_span(data, ga, gb, 70)
    wa, wb = word_span(data, ga, gb, 69)
    mv.fa = fa
    mv.fb = fb
    mv.e_start = 0.0
    if not mv.e_rel:
        if wa < 0:
            return mv.line
        ok, e_end = parse_number(data, wa + 1, wb)
        if not ok:
            return mv.line
        mv.e_end = e_end
        mv.e_start = e_end - mv.e_move
    st.changed += 1
    mv.e_acc = 0.0
    mv.first = True
    mv.px = m.x0
    mv.py = m.y0
    z0 = m.z0
    z1 = m.z1
    mv.z0 = z0
    mv.z1 = z1
    mv.ramp = z1 != z0 and math.isfinite(z0) and math.isfinite(z1)
    total = 0.0
    if mv.ramp:
        for s in range(mv.a0, mv.a1):
            total += chords[s].length
    mv.tot = total if total > 0 else 1.0
    mv.acc = 0.0  # path length before the chord being written
    mv.n_new = 0
    mv.first_end = -1  # where the first new line ends in scratch (the note goes there)
    return -1


@numba.njit(cache=True, nogil=True, inline="always")
def _z_at(mv, length, t):  # pragma: no cover
    """Z at fraction ``t`` of the chord being written (of ``length``) along a climb; 0
    when the move does not climb."""
    if not mv.ramp:
        return 0.0
    return mv.z0 + (mv.z1 - mv.z0) * min(1.0, (mv.acc + t * length) / mv.tot)


@numba.njit(cache=True, nogil=True, inline="always")
def _piece_turn(data, cfg, st, mv, scratch, ns, phi, moving, turn, gap_end):  # pragma: no cover
    """The turn into a chord or piece at ``phi``: the rotary word its line carries when the
    planner made it while moving (``moving``, a turn of at most ``turn``), else put before
    (folded into the travel, before the un-retract, on the line to the piece's start ending
    at ``gap_end``, or on a line of its own). Returns (line declined or -1, the new end,
    the word's coordinate or NaN)."""
    ok, c, cm = _coordinate(cfg, phi, st.cur)
    if not ok:
        return mv.line, ns, math.nan
    if cm == st.cur_m:
        return -1, ns, math.nan
    c_val = c
    if not (moving and abs(c - st.cur) <= turn + 1e-6):
        c_val = math.nan
        if cfg.fold and mv.travel >= 0 and ns == 0 and mv.t_line < 0:
            # the first thing this move does: folded into the travel
            bad, c, cm = _fold_into_travel(data, cfg, mv, phi, c, cm)
            if bad >= 0:
                return bad, ns, math.nan
        elif mv.ur >= 0 and ns == 0 and mv.u_line < 0:
            # the first thing this move does: before the un-retract
            mv.u_line = mv.ur
            mv.u_c = c
            st.inserted += 1
        elif cfg.fold and gap_end >= 0:
            # made on the way to the piece's start (nothing deposited): the word goes
            # before that line's ending
            ns = _put_word(scratch, gap_end, cfg, c)
            if mv.first_end == gap_end:
                mv.first_end = ns
            ns = put_eol(scratch, ns, data, mv.e0, mv.e1)
        else:
            ns = _rotation_line(cfg, mv, scratch, ns, c)
            if ns < 0:
                return mv.line, ns, math.nan
            if mv.first_end < 0:
                mv.first_end = ns
            ns = put_eol(scratch, ns, data, mv.e0, mv.e1)
            mv.n_new += 1
    _count_turn(st, mv, c, cm)
    return -1, ns, c_val


@numba.njit(cache=True, nogil=True, inline="always")
def _chord_lines(data, chord, pieces, cfg, st, mv, scratch, ns):  # pragma: no cover
    """The new lines of a chord: the whole chord, or each of its pieces (a line to the
    piece's start first where the nozzle is not there). Returns (line declined or -1, the
    new end)."""
    xd = cfg.xy_decimals
    sx0 = chord.x0
    sy0 = chord.y0
    sx1 = chord.x1
    sy1 = chord.y1
    length = chord.length
    in_p = chord.split != 0
    r0 = chord.p0 if in_p else 0
    r1 = chord.p1 if in_p else 1
    for r in range(r0, r1):
        if in_p:
            piece = pieces[r]
            t0 = piece.t0
            t1 = piece.t1
            phi = piece.angle
            scale = piece.scale
        else:
            t0 = 0.0
            t1 = 1.0
            phi = chord.angle
            scale = chord.scale
        qx0 = sx0 + t0 * (sx1 - sx0)
        qy0 = sy0 + t0 * (sy1 - sy0)
        qx1 = sx0 + t1 * (sx1 - sx0)
        qy1 = sy0 + t1 * (sy1 - sy0)
        gap_end = -1  # the end of the words of a line to the piece's start
        if math.hypot(qx0 - mv.px, qy0 - mv.py) > 1e-9:
            ns = put_move(scratch, ns, qx0, qy0, mv.ramp, _z_at(mv, length, t0), xd)
            if ns < 0:
                return mv.line, ns
            gap_end = ns
            if mv.first_end < 0:
                mv.first_end = ns
            ns = put_eol(scratch, ns, data, mv.e0, mv.e1)
            mv.n_new += 1
            mv.px = qx0
            mv.py = qy0
        c_val = math.nan
        if cfg.turns and math.isfinite(phi):
            if in_p:
                moving = pieces[r].fold != 0
                turn = pieces[r].turn
            else:
                moving = chord.fold != 0
                turn = chord.turn
            bad, ns, c_val = _piece_turn(data, cfg, st, mv, scratch, ns, phi, moving, turn,
                                         gap_end)
            if bad >= 0:
                return bad, ns
        de = chord.e * (t1 - t0) * scale
        mv.e_acc += de
        ns = put_move(scratch, ns, qx1, qy1, mv.ramp, _z_at(mv, length, t1), xd)
        if ns < 0:
            return mv.line, ns
        scratch[ns] = 32
        scratch[ns + 1] = 69
        ns = put_fixed(scratch, ns + 2, de if mv.e_rel else mv.e_start + mv.e_acc,
                       cfg.e_decimals)
        if ns < 0:
            return mv.line, ns
        if not math.isnan(c_val):
            ns = _put_word(scratch, ns, cfg, c_val)
        if mv.first and mv.fa >= 0:
            scratch[ns] = 32
            ns = copy(scratch, ns + 1, data, mv.fa, mv.fb)
        elif mv.need_f:
            ns = put_feed(scratch, ns, mv.feed)
            if ns < 0:
                return mv.line, ns
        mv.need_f = False
        mv.first = False
        if mv.first_end < 0:
            mv.first_end = ns
        ns = put_eol(scratch, ns, data, mv.e0, mv.e1)
        mv.n_new += 1
        mv.px = qx1
        mv.py = qy1
    return -1, ns


@numba.njit(cache=True, nogil=True, inline="always")
def _split_end(data, m, cfg, st, mv, scratch, ns):  # pragma: no cover
    """The move's last lines (to its end, a Z step, ``G92 E``) and the note on its first
    line: (line declined or -1, the scratch buffer, the new end)."""
    xd = cfg.xy_decimals
    ex = m.x1
    ey = m.y1
    if math.hypot(ex - mv.px, ey - mv.py) > 1e-9 or mv.n_new == 0:
        # the last chord at t = 1: the path length before it plus its own, which is acc
        # (summed in the same order)
        z = mv.z0 + (mv.z1 - mv.z0) * min(1.0, mv.acc / mv.tot) if mv.ramp else 0.0
        ns = put_move(scratch, ns, ex, ey, mv.ramp, z, xd)
        if ns < 0:
            return mv.line, scratch, ns
        if mv.first and mv.fa >= 0:
            scratch[ns] = 32
            ns = copy(scratch, ns + 1, data, mv.fa, mv.fb)
        if mv.first_end < 0:
            mv.first_end = ns
        ns = put_eol(scratch, ns, data, mv.e0, mv.e1)
        mv.n_new += 1
    if mv.z1 != mv.z0 and math.isfinite(mv.z1) and not mv.ramp:
        ns = put(scratch, ns, _G1Z)
        ns = put_fixed(scratch, ns, mv.z1, xd)
        if ns < 0:
            return mv.line, scratch, ns
        ns = put_eol(scratch, ns, data, mv.e0, mv.e1)
        mv.n_new += 1
    if not mv.e_rel and abs(mv.e_acc - mv.e_move) > 1e-05:
        ns = put(scratch, ns, _G92)
        ns = put_fixed(scratch, ns, mv.e_end, cfg.e_decimals)
        if ns < 0:
            return mv.line, scratch, ns
        ns = put_eol(scratch, ns, data, mv.e0, mv.e1)
        mv.n_new += 1
    # the note on the first new line: " ; printability: was " + the line, stripped
    ca, cb = strip_span(data, mv.a, mv.b)
    cb = min(cb, ca + 60)
    k = len(_NOTE) + cb - ca
    scratch = reserve(scratch, ns, k)
    first_end = mv.first_end
    scratch[first_end + k:ns + k] = scratch[first_end:ns].copy()
    w = put(scratch, first_end, _NOTE)
    copy(scratch, w, data, ca, cb)
    st.inserted += mv.n_new - 1
    return -1, scratch, ns + k


@numba.njit(cache=True, nogil=True, inline="always")
def split_move(data, m, chords, pieces, cfg, st, mv, scratch):  # pragma: no cover
    """An arc or a split move: chords and pieces written as new ``G1`` lines at
    ``scratch[0:]`` (``m``: the move's row, ``chords``, ``pieces``: the tables). Returns
    (line declined or -1, the scratch buffer (``scratch`` or a larger copy), the end of its
    text)."""
    bad = _split_begin(data, m, chords, st, mv)
    if bad >= 0:
        return bad, scratch, 0
    ns = 0
    for s in range(mv.a0, mv.a1):
        chord = chords[s]
        n_pieces = chord.p1 - chord.p0 if chord.split != 0 else 1
        scratch = reserve(scratch, ns, (n_pieces + 1) * mv.extra)
        bad, ns = _chord_lines(data, chord, pieces, cfg, st, mv, scratch, ns)
        if bad >= 0:
            return bad, scratch, ns
        if mv.ramp:
            mv.acc += chord.length
    scratch = reserve(scratch, ns, 2 * mv.extra)
    return _split_end(data, m, cfg, st, mv, scratch, ns)

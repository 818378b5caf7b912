"""The rewrite pass compiled: the same bytes as
:func:`printability.postprocess.rewrite.rewrite_reference`.

The reference walks the moves that may change in Python, about 20 µs each (a
rotary word, an E edit, new lines for split moves); on Benchy that was a
third of the post-processor's time. :func:`rewrite_kernel` does the same walk over the
file's bytes: it copies the runs between the moves to rewrite, and each move's new text
(:mod:`printability.postprocess._rewrite_moves`) with the turns put before it (folded into
the travel before it, or a rotation line before its un-retract). Numbers and lines are written and
read as Python does (:mod:`gcode.text_kernels`).

Whatever the kernel declines (a number out of that range, a line to edit that
is not of the common shape, a bounded axis with no reachable representative)
ends it with a status, and :func:`rewrite_compiled` returns None: the caller runs the
reference instead, so the output is the reference's in every case.

The kernel takes the walk's inputs as tables of records: the parser's moves (its own
records), and one row per event, chord and piece (:data:`EVENT_ROW`, :data:`CHORD_ROW`,
:data:`PIECE_ROW`); the writer's options as :class:`RewriteConfig`; and keeps its state in
records of :data:`PASS_STATE` (the walk, and its tallies: returned through the caller's
array) and :data:`MOVE_STATE` (the move being written). Records, not named tuples of
arrays: numba counts a reference at every use of an array taken from a tuple, and with the
moves, chords and pieces passed as named tuples of columns the pass took twice its time.
The walk's steps (here and in :mod:`printability.postprocess._rewrite_moves`) are inlined
(``inline="always"``): called once or more per move, as calls they cost a fifth more.

Complexity: linear in the file's bytes plus the new lines.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from gcode.text_kernels import (
    copy,
    copy_with_feed,
    eol_span,
    put_eol,
    put_fixed,
    put_rotation,
    reserve,
    simple_span,
    word_span,
)
from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.postprocess._rewrite_events import (
    RESET,
    TRAVEL,
    UNRETRACT,
    ChordPlan,
    Events,
    RewriteOutput,
    SlicerFile,
    WriteSettings,
    first_command_line,
)
from printability.postprocess._rewrite_moves import simple_move, split_move

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["CHORD_ROW", "DECLINED", "EVENT_ROW", "MOVE_STATE", "OK", "PASS_STATE",
           "PIECE_ROW", "RewriteConfig", "rewrite_compiled", "rewrite_kernel"]

OK = 0
DECLINED = 1

_i8, _f8, _u1, _b1 = np.int64, np.float64, np.uint8, np.bool_

EVENT_ROW = np.dtype([("line", _i8), ("move", _i8), ("code", _i8), ("a0", _i8), ("a1", _i8)],
                     align=True)
"""A move the walk visits, in file order: its line, the move, what it does
(:data:`~printability.postprocess._rewrite_events.TRAVEL` …), and its chords ``a0:a1``."""

CHORD_ROW = np.dtype([
    ("x0", _f8), ("y0", _f8), ("x1", _f8), ("y1", _f8), ("e", _f8),
    ("length", _f8),  # of a climbing move's chord (spiral vase), else 0
    ("angle", _f8),  # orientation, NaN: none
    ("turn", _f8),  # the turn into it the planner checked, -1: none
    ("scale", _f8),  # E factor
    ("p0", _i8), ("p1", _i8),  # a split chord's pieces p0:p1
    ("fold", _u1),  # the turn into it is made while moving
    ("split", _u1),  # split (or dropped: no pieces)
], align=True)
"""A chord of the plan."""

PIECE_ROW = np.dtype([
    ("t0", _f8), ("t1", _f8),  # its span of the chord
    ("angle", _f8), ("scale", _f8), ("turn", _f8), ("fold", _u1),  # as a chord's
], align=True)
"""A piece of a split chord."""


class RewriteConfig(NamedTuple):
    """The writer's options: the axis letter (its byte), decimals, the axis (period,
    limits, and whether it has none), whether turns are folded into moves (feed policy
    ``xy``), unwound and made at all, and the rotation-only lines' feed (degrees per
    minute, 0: none)."""

    letter: int
    angle_decimals: int
    xy_decimals: int
    e_decimals: int
    period: float
    angle_min: float
    angle_max: float
    unbounded: bool
    fold: bool
    unwind: bool
    turns: bool
    rotary_feed: float


PASS_STATE = np.dtype([
    ("n", _i8), ("pos", _i8),  # bytes written; the file's bytes before pos are copied
    ("changed", _i8), ("inserted", _i8), ("rotary", _i8),  # lines changed, added; words
    ("cur", _f8), ("cur_m", _i8),  # the axis coordinate, and its text as digits
    ("pending", _i8),  # the travel since the last rewritten move, -1
    ("unret", _i8), ("unret_move", _i8),  # an un-retract since then (line, move), -1
])
"""The walk's state: a record, one per call, the caller's (it reads the tallies)."""

MOVE_STATE = np.dtype([
    # the move: its line and bytes a:b (line ending e0:e1, -1: none), chords, E, feed,
    # and the room a line of it may need
    ("line", _i8), ("move", _i8), ("layer", _i8), ("a", _i8), ("b", _i8), ("e0", _i8),
    ("e1", _i8), ("a0", _i8), ("a1", _i8), ("e_rel", _b1), ("e_move", _f8), ("feed", _f8),
    ("extra", _i8),
    # before it: the travel a turn may be folded into (line, bytes), the un-retract a turn
    # goes before (line, bytes, the feed it restores); -1: none
    ("travel", _i8), ("travel_a", _i8), ("travel_b", _i8), ("ur", _i8), ("ur_a", _i8),
    ("ur_b", _i8), ("ur_feed", _f8),
    # the turns put there: into the travel (-1: none; the end of its words, the
    # coordinate), before the un-retract; the move's first line restores the feed
    ("t_line", _i8), ("t_end", _i8), ("t_c", _f8), ("u_line", _i8), ("u_c", _f8),
    ("need_f", _b1), ("turns", _i8),  # rotary words in it
    # a split move's new lines: its F word, E (at the start, the end, so far), the
    # nozzle's place, Z along a climb, lines written and where the first ends
    ("fa", _i8), ("fb", _i8), ("e_start", _f8), ("e_end", _f8), ("e_acc", _f8),
    ("first", _b1), ("px", _f8), ("py", _f8), ("z0", _f8), ("z1", _f8), ("ramp", _b1),
    ("tot", _f8), ("acc", _f8), ("n_new", _i8), ("first_end", _i8),
])
"""The move being written (:mod:`printability.postprocess._rewrite_moves`)."""


@numba.njit(cache=True, nogil=True, inline="always")
def _begin_move(data, starts, moves, st, mv, ev):  # pragma: no cover
    """Set ``mv`` to the move of the event ``ev``; the travel and un-retract before it pass
    from the walk to the move."""
    li = ev.line
    mi = ev.move
    m = moves[mi]
    mv.turns = 0
    mv.line = li
    mv.move = mi
    mv.travel = st.pending  # the travel a turn may be folded into, or -1
    if st.pending >= 0:
        mv.travel_a = starts[st.pending]
        mv.travel_b = starts[st.pending + 1]
    st.pending = -1
    mv.ur = st.unret  # the un-retract a turn goes before when it cannot be folded, or -1
    if st.unret >= 0:
        mv.ur_a = starts[st.unret]
        mv.ur_b = starts[st.unret + 1]
        mv.ur_feed = moves[st.unret_move].feed
    st.unret = -1
    mv.u_line = -1
    mv.u_c = 0.0
    mv.need_f = False  # a rotation line set F: the next motion line restores the feed
    mv.feed = m.feed
    a = starts[li]
    b = starts[li + 1]
    mv.a = a
    mv.b = b
    mv.layer = m.layer
    mv.a0 = ev.a0
    mv.a1 = ev.a1
    e0, e1 = eol_span(data, a, b)
    mv.e0 = e0
    mv.e1 = e1
    mv.e_rel = (m.flags & 1) != 0
    mv.e_move = m.e
    mv.t_line = -1
    mv.t_end = 0
    mv.t_c = 0.0
    # room for the new text: a line is at most its own bytes (the copied words: an F
    # word may be long), numbers of at most 24 bytes and the rotary letter twice (400 + 2),
    # so every write stays inside the buffer (numba does not check bounds)
    mv.extra = 402 + (b - a)


@numba.njit(cache=True, nogil=True, inline="always")
def _before_unretract(data, cfg, st, mv, buf):  # pragma: no cover
    """Write the file up to the un-retract ``mv.u_line`` and it, after a rotation line to
    ``mv.u_c`` (nothing is deposited at the old orientation); the un-retract restores the
    feed. Returns (line declined or -1, the buffer)."""
    ua = mv.ur_a
    ub = mv.ur_b
    ga, gb = simple_span(data, ua, ub)
    if ga < 0:
        return mv.u_line, buf
    fa, _ = word_span(data, ga, gb, 70)
    u_feed = mv.ur_feed
    with_f = cfg.rotary_feed > 0 and math.isfinite(u_feed)
    buf = reserve(buf, st.n, (ub - st.pos) + 201)
    n = copy(buf, st.n, data, st.pos, ua)
    n = put_rotation(buf, n, cfg.letter, mv.u_c, cfg.angle_decimals,
                     cfg.rotary_feed if with_f else 0.0)
    if n < 0:
        return mv.u_line, buf
    ue0, ue1 = eol_span(data, ua, ub)
    n = put_eol(buf, n, data, ue0, ue1)
    if with_f and fa < 0:
        n = copy_with_feed(buf, n, data, ua, gb, ub, u_feed)
        if n < 0:
            return mv.u_line, buf
        st.changed += 1
    else:
        n = copy(buf, n, data, ua, ub)
    st.n = n
    st.pos = ub
    return -1, buf


@numba.njit(cache=True, nogil=True, inline="always")
def _flush(data, cfg, st, mv, scratch, ns, buf):  # pragma: no cover
    """Write the run before the move, the travel (with the folded turn), the lines between,
    the move's text ``scratch[:ns]``. Returns (line declined or -1, the buffer)."""
    buf = reserve(buf, st.n, (mv.b - st.pos) + ns + 65)
    if mv.t_line >= 0:
        n = copy(buf, st.n, data, st.pos, mv.t_end)
        buf[n] = 32
        buf[n + 1] = cfg.letter
        st.n = put_fixed(buf, n + 2, mv.t_c, cfg.angle_decimals)
        st.pos = mv.t_end
    if mv.u_line >= 0:
        bad, buf = _before_unretract(data, cfg, st, mv, buf)
        if bad >= 0:
            return bad, buf
    n = copy(buf, st.n, data, st.pos, mv.a)
    st.n = copy(buf, n, scratch, 0, ns)
    st.pos = mv.b
    return -1, buf


@numba.njit(cache=True, nogil=True)
def rewrite_kernel(data, starts, events, moves, chords, pieces, cfg, state, move,
                   turned):  # pragma: no cover
    """The reference's walk over the events, writing the file (``data``, its lines
    starting at ``starts``, one more item: the length) from ``state[0].pos`` on.

    A rotation-only line carries ``F<rotary_feed>`` (degrees per minute) when that is
    positive and the feed in force after it is known, and the next motion line then
    restores that feed (the move's ``feed``, mm/min) unless it has an F of its own.

    ``moves``: the parser's move records (``e kind flags layer x0 y0 x1 y1 z0 z1 feed``);
    ``events``, ``chords``, ``pieces``: tables of :data:`EVENT_ROW`, :data:`CHORD_ROW`,
    :data:`PIECE_ROW`; ``state``: one record of :data:`PASS_STATE` (``pos`` set,
    ``pending`` and ``unret`` -1), updated; ``move``: one of :data:`MOVE_STATE`, the
    kernel's (an array the caller holds: a record taken from an array made here would
    outlive its memory); ``turned``: rotary words per layer + 1, counted.

    Returns (status, buffer, the line declined or -1); the buffer's first ``state[0].n``
    bytes are the output.
    """
    st = state[0]
    mv = move[0]
    buf = np.empty(len(data) - st.pos + 65536, np.uint8)
    scratch = np.empty(4096, np.uint8)  # the move's new text, before the travel is written
    for q in range(len(events)):
        ev = events[q]
        if ev.code == TRAVEL:
            st.pending = ev.line
            st.unret = -1
            continue
        if ev.code == UNRETRACT:
            st.unret = ev.line
            st.unret_move = ev.move
            continue
        if ev.code == RESET:
            st.pending = -1
            st.unret = -1
            continue
        _begin_move(data, starts, moves, st, mv, ev)
        scratch = reserve(scratch, 0, (mv.b - mv.a) + mv.extra + 4096)
        m = moves[mv.move]
        if mv.a1 - mv.a0 == 1 and chords[mv.a0].split == 0 and m.kind <= 1:
            bad, ns = simple_move(data, chords[mv.a0], cfg, st, mv, scratch)
        else:
            bad, scratch, ns = split_move(data, m, chords, pieces, cfg, st, mv, scratch)
        if bad < 0:
            bad, buf = _flush(data, cfg, st, mv, scratch, ns, buf)
        if bad >= 0:
            return DECLINED, buf, bad
        turned[mv.layer + 1] += mv.turns
    buf = reserve(buf, st.n, len(data) - st.pos)
    st.n = copy(buf, st.n, data, st.pos, len(data))
    return OK, buf, -1


def _table(dtype: np.dtype, n: int, **columns) -> np.ndarray:
    """A table of ``n`` records of ``dtype``, its fields from ``columns`` (the others 0)."""
    out = np.zeros(n, dtype)
    for k, v in columns.items():
        out[k] = v
    return out


@numba.njit(cache=True, nogil=True)
def _chord_table(seg, angle, fold, turn, scale, length, split, p_seg):  # pragma: no cover
    """The :data:`CHORD_ROW` table of the chords ``seg`` and their columns; a chord's
    pieces are the rows of ``p_seg`` (sorted) that name it. (Compiled: filled field by
    field in Python, the table cost Bambu's arcs 2.5 ms, more than the kernel saved.)"""
    out = np.empty(len(seg), CHORD_ROW)
    r = 0
    for s in range(len(seg)):
        g = seg[s]
        c = out[s]
        c.x0 = g.x0
        c.y0 = g.y0
        c.x1 = g.x1
        c.y1 = g.y1
        c.e = g.e
        c.length = length[s]
        c.angle = angle[s]
        c.turn = turn[s]
        c.scale = scale[s]
        c.fold = fold[s]
        c.split = split[s]
        while r < len(p_seg) and p_seg[r] < s:
            r += 1
        c.p0 = r
        q = r
        while q < len(p_seg) and p_seg[q] == s:
            q += 1
        c.p1 = q
    return out


def _chord_rows(plan: ChordPlan, moves: np.ndarray, ev: Events) -> np.ndarray:
    seg = plan.seg
    n_seg = len(seg)
    split = np.zeros(n_seg, np.uint8)  # split, or dropped (no pieces)
    split[np.fromiter(plan.pieces, dtype=np.int64, count=len(plan.pieces))] = 1
    # chord lengths of climbing moves (spiral vase), as the reference measures them
    s_len = np.zeros(n_seg)
    if n_seg:
        # (two fields gathered, not whole rows of the wide move records: 1.5 ms on the cube)
        z0, z1 = moves["z0"][plan.move], moves["z1"][plan.move]
        climbs = np.flatnonzero((z1 != z0) & np.isfinite(z0) & np.isfinite(z1))
        x0, y0 = seg["x0"][climbs].tolist(), seg["y0"][climbs].tolist()
        x1, y1 = seg["x1"][climbs].tolist(), seg["y1"][climbs].tolist()
        s_len[climbs] = [math.hypot(c - a, d - b) for a, b, c, d in zip(x0, y0, x1, y1,
                                                                          strict=True)]
    return _chord_table(seg, np.ascontiguousarray(plan.angle, float),
                        np.ascontiguousarray(plan.fold, np.uint8), ev.s_turn, ev.s_scale, s_len,
                        split, ev.piece_rows[0])


def _piece_rows(ev: Events) -> np.ndarray:
    _, t0, t1, angle = ev.piece_rows
    return _table(PIECE_ROW, len(t0), t0=t0, t1=t1, angle=angle, scale=ev.piece_scale_flat,
                  turn=ev.p_turn, fold=ev.p_fold)


def _config(settings: WriteSettings) -> RewriteConfig:
    wopts = settings.wopts
    lo, hi = float(wopts.angle_min), float(wopts.angle_max)
    return RewriteConfig(
        ord(wopts.letter), int(wopts.angle_decimals), int(wopts.xy_decimals), 5,
        float(wopts.period or 360.0), lo, hi,
        bool(math.isinf(lo) and math.isinf(hi) and lo < 0 < hi), wopts.feed_policy == "xy",
        bool(wopts.unwind), bool(settings.turns), float(wopts.rotary_feed))


def rewrite_compiled(src: SlicerFile, plan: ChordPlan, settings: WriteSettings,
                     ev: Events) -> tuple[RewriteOutput, dict[int, int]] | None:
    """:func:`~printability.postprocess.rewrite.rewrite_reference`'s output and rotary words per
    layer, written by :func:`rewrite_kernel`; None when it declines. ``ev`` must have events."""
    g, data = src.g, src.data
    n_lines = len(g.lines)
    starts = np.empty(n_lines + 1, np.int64)
    starts[:n_lines] = g.lines["start"]
    starts[n_lines] = len(data)
    first_cmd = min(first_command_line(g.lines), int(ev.ev_line[0]))
    state = np.zeros(1, PASS_STATE)
    state["pos"] = starts[first_cmd]
    state["pending"] = state["unret"] = state["unret_move"] = -1
    turned_arr = np.zeros(len(g.layers) + 2, np.int64)
    status, buf, _ = rewrite_kernel(
        np.frombuffer(data, np.uint8), starts,
        _table(EVENT_ROW, len(ev.ev_line), line=ev.ev_line, move=ev.ev_move, code=ev.ev_code,
               a0=ev.mv_a0[ev.ev_move], a1=ev.mv_a1[ev.ev_move]),
        src.moves, _chord_rows(plan, src.moves, ev), _piece_rows(ev), _config(settings), state,
        np.zeros(1, MOVE_STATE), turned_arr)
    if status != OK:
        return None
    st = state[0]
    out = RewriteOutput(changed=int(st["changed"]), inserted=int(st["inserted"]),
                        rotary_words=int(st["rotary"]))
    out.chunks.extend(data[starts[li]:starts[li + 1]] for li in range(first_cmd))
    out.chunks.append(buf[:st["n"]].tobytes())
    turned = {int(k) - 1: int(turned_arr[k]) for k in np.flatnonzero(turned_arr)}
    return out, turned

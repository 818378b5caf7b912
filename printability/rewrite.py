"""The rewrite pass of the post-processor: copy the slicer's file, editing the planned moves.

Given the plan (an orientation per chord, the printable pieces of split moves, the
width laid), :func:`rewrite` copies the G-code: runs of lines that need no change
are copied as slices of the input, byte for byte; a move that only turns gains a
rotary word (or a rotation-only line before it); a move whose E changes is edited
in place (with ``G92 E…`` after it in absolute-E files); arcs and split moves
become new ``G1`` lines, a turn into a piece riding on the piece's line where the plan
made it while moving (``Plan.piece_fold``), else on the line to the piece's start when
there is one (nothing is deposited there), else on a line of its own. See
:mod:`printability.postprocess` for what each change means to the print.

Two passes write the same bytes: :func:`rewrite_reference`, in Python, and the
compiled one of :mod:`printability._rewrite_kernel` that :func:`rewrite` runs
(about 6× faster on the calibration cube and 7× on Benchy), which hands what it
cannot write exactly to the reference.
"""

from __future__ import annotations

import bisect
import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from gcode.rotary import nearest_equivalent
from gcode.writer import WriterOptions, format_number
from printability._arrays import take_rows
from printability.errors import InputError
from printability.motion.orientation import piece_rows_of
from printability.nozzle import Nozzle

__all__ = ["RewriteOutput", "e_scale", "e_scales", "eol_of", "first_command_line",
           "planned_turns", "rewrite", "rewrite_reference"]


@dataclass
class RewriteOutput:
    """Output chunks plus the bookkeeping of what changed."""

    chunks: list[bytes] = field(default_factory=list)
    changed: int = 0
    inserted: int = 0
    rotary_words: int = 0


def eol_of(line: bytes) -> bytes:
    if line.endswith(b"\r\n"):
        return b"\r\n"
    if line.endswith((b"\n", b"\r")):
        return line[-1:]
    return b"\n"



@dataclass(frozen=True)
class _ZRamp:
    """Z along a climbing move's chords (spiral vase), by path length."""

    z0: float
    z1: float
    first: int  # index of the move's first chord
    length: list[float]
    start: list[float]  # path length before each chord; the last item is the total
    decimals: int

    def word(self, s: int, t: float) -> bytes:
        """`` Z…`` at fraction ``t`` of chord ``s``."""
        total = self.start[-1] if self.start[-1] > 0 else 1.0
        k = s - self.first
        z = self.z0 + (self.z1 - self.z0) * min(1.0, (self.start[k] + t * self.length[k]) / total)
        return b" Z" + format_number(z, self.decimals).encode()


def _no_z_word(s: int, t: float) -> bytes:
    return b""


def first_command_line(lines: np.ndarray) -> int:
    from gcode._lexer import KIND_BLANK, KIND_COMMENT

    idx = np.flatnonzero((lines["kind"] != KIND_COMMENT) & (lines["kind"] != KIND_BLANK))
    return int(idx[0]) if idx.size else len(lines)


def rewrite(g, data, moves, seg, seg_move, seg_angle, seg_fold, seg_width_laid, seg_pieces,
            widths, heights, wopts: WriterOptions, turns: bool, e_policy: str,
            nozzle: Nozzle, *, piece_rows: tuple | None = None,
            piece_fold: np.ndarray | None = None) -> tuple[RewriteOutput, dict[int, int]]:
    """Copy the file, rewriting the part extrusions that need it.

    The compiled pass of :mod:`printability._rewrite_kernel` writes the bytes
    :func:`rewrite_reference` writes; what it declines (numbers or lines outside
    the range where it is exact, see there) goes to the reference. ``piece_rows`` are the
    pieces of ``seg_pieces`` as arrays ``(chord, t0, t1, angle)`` by chord, when known;
    ``piece_fold`` per such row True where the turn into the piece is made during it
    (:attr:`~printability.motion.orientation.Plan.piece_fold`, in the rows' order).
    """
    from printability._rewrite_kernel import OK, rewrite_kernel

    ev = _events(g, moves, seg, seg_move, seg_angle, seg_width_laid, seg_pieces, widths,
                 heights, wopts, turns, e_policy, nozzle, piece_rows=piece_rows,
                 piece_fold=piece_fold)
    if not ev.ev_line.size:
        return rewrite_reference(g, data, moves, seg, seg_move, seg_angle, seg_fold,
                                 seg_width_laid, seg_pieces, widths, heights, wopts, turns,
                                 e_policy, nozzle, events=ev)
    n_lines = len(g.lines)
    starts = np.empty(n_lines + 1, np.int64)
    starts[:n_lines] = g.lines["start"]
    starts[n_lines] = len(data)
    first_cmd = min(first_command_line(g.lines), int(ev.ev_line[0]))
    n_seg = len(seg)
    # the pieces of split chords, flat: chord s has pieces p_lo[s]:p_hi[s]
    in_pieces = np.zeros(n_seg, np.uint8)
    keys = np.fromiter(seg_pieces, dtype=np.int64, count=len(seg_pieces))
    in_pieces[keys] = 1  # split or dropped (no pieces)
    p_seg, p_t0, p_t1, p_angle = ev.piece_rows
    all_seg = np.arange(n_seg)
    p_lo = np.searchsorted(p_seg, all_seg, "left").astype(np.int64)
    p_hi = np.searchsorted(p_seg, all_seg, "right").astype(np.int64)
    p_scale = ev.piece_scale_flat
    # chord lengths of climbing moves (spiral vase), as the reference measures them
    s_len = np.zeros(n_seg)
    if n_seg:
        # (two fields gathered, not whole rows of the wide move records: 1.5 ms on the cube)
        z0, z1 = moves["z0"][seg_move], moves["z1"][seg_move]
        climbs = np.flatnonzero((z1 != z0) & np.isfinite(z0) & np.isfinite(z1))
        x0, y0 = seg["x0"][climbs].tolist(), seg["y0"][climbs].tolist()
        x1, y1 = seg["x1"][climbs].tolist(), seg["y1"][climbs].tolist()
        s_len[climbs] = [math.hypot(c - a, d - b) for a, b, c, d in zip(x0, y0, x1, y1,
                                                                          strict=True)]
    lo, hi = wopts.angle_min, wopts.angle_max
    period = wopts.period or 360.0
    status, buf, n, changed, inserted, rotary, turned_arr, _ = rewrite_kernel(
        np.frombuffer(data, np.uint8), starts, int(starts[first_cmd]),
        ev.ev_line, ev.ev_move, ev.ev_code,
        np.ascontiguousarray(moves["e"], float), np.ascontiguousarray(moves["kind"], np.int64),
        np.ascontiguousarray(moves["flags"], np.int64),
        np.ascontiguousarray(moves["layer"], np.int64),
        *(np.ascontiguousarray(moves[k], float) for k in ("x0", "y0", "x1", "y1", "z0", "z1")),
        ev.mv_a0, ev.mv_a1,
        *(np.ascontiguousarray(seg[k], float) for k in ("x0", "y0", "x1", "y1", "e")),
        np.ascontiguousarray(seg_angle, float), np.ascontiguousarray(seg_fold, np.uint8),
        ev.s_turn, ev.s_scale, in_pieces, p_lo, p_hi, s_len,
        p_t0, p_t1, p_angle, p_scale, ev.p_fold, ev.p_turn,
        np.frombuffer(wopts.letter.encode("ascii"), np.uint8), int(wopts.angle_decimals),
        int(wopts.xy_decimals), 5, float(period), float(lo), float(hi),
        bool(math.isinf(lo) and math.isinf(hi) and lo < 0 < hi),
        wopts.feed_policy == "xy", bool(wopts.unwind), bool(turns), len(g.layers),
        np.ascontiguousarray(moves["feed"], float), float(wopts.rotary_feed))
    if status != OK:
        return rewrite_reference(g, data, moves, seg, seg_move, seg_angle, seg_fold,
                                 seg_width_laid, seg_pieces, widths, heights, wopts, turns,
                                 e_policy, nozzle, events=ev)
    out = RewriteOutput(changed=int(changed), inserted=int(inserted),
                        rotary_words=int(rotary))
    out.chunks.extend(data[starts[li]:starts[li + 1]] for li in range(first_cmd))
    out.chunks.append(buf[:n].tobytes())
    turned = {int(k) - 1: int(turned_arr[k]) for k in np.flatnonzero(turned_arr)}
    return out, turned


@dataclass(frozen=True)
class _Events:
    """What both passes walk: the lines of the moves that matter, in order, with what each
    does (travel, reset, work), and the per-chord columns they read."""

    ev_line: np.ndarray
    ev_move: np.ndarray
    ev_code: np.ndarray
    mv_a0: np.ndarray
    mv_a1: np.ndarray
    s_turn: np.ndarray
    s_scale: np.ndarray
    piece_rows: tuple
    piece_scale_flat: np.ndarray
    p_fold: np.ndarray
    p_turn: np.ndarray

    @property
    def piece_scale(self) -> dict[int, list[float]]:
        """Per split chord, the E factor of each of its pieces, in order."""
        p_seg = self.piece_rows[0]
        flat = self.piece_scale_flat.tolist()
        cut = (np.flatnonzero(np.diff(p_seg)) + 1).tolist()
        out: dict[int, list[float]] = {}
        lo = 0
        for hi in [*cut, len(flat)]:
            if hi > lo:
                out[int(p_seg[lo])] = flat[lo:hi]
            lo = hi
        return out


_NONE, _TRAVEL, _RESET, _WORK, _UNRETRACT = 0, 1, 2, 3, 4


def _events(g, moves, seg, seg_move, seg_angle, seg_width_laid, seg_pieces, widths, heights,
            wopts: WriterOptions, turns: bool, e_policy: str, nozzle: Nozzle, *,
            piece_rows: tuple | None = None, piece_fold: np.ndarray | None = None) -> _Events:
    from gcode.rotary import bead_area

    n_lines = len(g.lines)
    n_moves = len(moves)
    # chords of each move: mv_a0[m]:mv_a1[m] (a later run of chords of the same move wins)
    has_seg = np.zeros(n_moves, dtype=bool)
    with_pieces = np.zeros(n_moves, dtype=bool)
    mv_a0 = np.full(n_moves, -1, np.int64)
    mv_a1 = np.full(n_moves, -1, np.int64)
    if len(seg):
        change = np.flatnonzero(np.diff(seg_move)) + 1
        b = np.concatenate([[0], change, [len(seg_move)]])
        run_move = np.asarray(seg_move[b[:-1]], dtype=np.int64)
        keys, last_rev = np.unique(run_move[::-1], return_index=True)
        last = len(run_move) - 1 - last_rev  # the last run of each move
        ranges = np.column_stack([b[:-1][last], b[1:][last]]).astype(np.int64)
        has_seg[keys] = True
        mv_a0[keys] = ranges[:, 0]
        mv_a1[keys] = ranges[:, 1]
        piece_flag = np.zeros(len(seg) + 1, dtype=np.int64)
        if seg_pieces:
            piece_flag[np.fromiter(seg_pieces, dtype=np.int64, count=len(seg_pieces)) + 1] = 1
        csum = np.cumsum(piece_flag)
        with_pieces[keys] = csum[ranges[:, 1]] > csum[ranges[:, 0]]

    # the move of each line: the last move listed on it
    mv_line = moves["line"].astype(np.int64)
    lines_u, last_rev = np.unique(mv_line[::-1], return_index=True)
    move_u = n_moves - 1 - last_rev
    keep = (lines_u >= 0) & (lines_u < n_lines)
    lines_u, move_u = lines_u[keep], move_u[keep]

    fold = wopts.feed_policy == "xy"
    # what each move line does to the travel a turn may be folded into (see the reference)
    work = has_seg & (with_pieces | turns)
    with np.errstate(invalid="ignore"):
        is_travel = ((moves["e"] <= 0) & (moves["kind"] <= 1)
                     & ((moves["x1"] != moves["x0"]) | (moves["y1"] != moves["y0"])))
        extruding = moves["e"] > 0
        # E alone, forwards: the un-retract before a path, which a turn must precede
        unretract = (extruding & (moves["kind"] <= 1) & (moves["x1"] == moves["x0"])
                     & (moves["y1"] == moves["y0"]) & ~(moves["z1"] != moves["z0"]))
    effect = np.full(n_moves, _NONE, dtype=np.int8)
    effect[extruding] = _RESET
    if turns:
        effect[unretract & ~has_seg] = _UNRETRACT
        effect[has_seg] = _RESET
        if fold:
            effect[is_travel] = _TRAVEL
    effect[work] = _WORK
    ev = effect[move_u] != _NONE

    s_turn = planned_turns(np.asarray(seg_angle, dtype=float))
    h_seg = None
    if len(seg):
        layer_of_seg = moves["layer"][seg_move]
        h_seg = np.where(layer_of_seg >= 0,
                         np.asarray(heights, dtype=float)[np.maximum(layer_of_seg, 0)]
                         if len(heights) else 0.2, 0.2)
        s_scale = e_scales(np.asarray(seg_width_laid, dtype=float),
                           np.asarray(widths, dtype=float), h_seg, e_policy, nozzle,
                           bead_area)
    else:
        s_scale = np.zeros(0)
    rows = piece_rows if piece_rows is not None else piece_rows_of(seg_pieces)
    rows = (np.asarray(rows[0], np.int64), *(np.asarray(r, float) for r in rows[1:]))
    scale = _piece_scales(seg, rows[0], rows[3], widths, h_seg, turns, e_policy, nozzle,
                          bead_area)
    p_fold = np.zeros(len(rows[0]), np.uint8)
    if piece_fold is not None and fold and turns:
        p_fold[:] = np.asarray(piece_fold, bool)
    s_turn, p_turn = _piece_turns(s_turn, np.asarray(seg_angle, dtype=float), rows,
                                  wopts.period or 360.0)
    return _Events(lines_u[ev].astype(np.int64), move_u[ev].astype(np.int64),
                   effect[move_u[ev]].astype(np.int64), mv_a0, mv_a1, s_turn,
                   s_scale, rows, scale, p_fold, p_turn)


def _piece_turns(s_turn: np.ndarray, seg_angle: np.ndarray, rows: tuple, period: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The planned turns around split chords: into each piece (from the piece before it on
    its chord, else from the chord before: its orientation or its last piece's), and into a
    whole chord after a split one (``s_turn`` there, a copy), each the nearest way round,
    degrees; -1 where there is none."""
    p_seg, p_angle = rows[0], rows[3]
    npc = len(p_seg)
    p_turn = np.full(npc, -1.0)
    if npc == 0:
        return s_turn, p_turn
    n_seg = len(seg_angle)
    first = np.ones(npc, bool)
    first[1:] = p_seg[1:] != p_seg[:-1]
    last = np.append(p_seg[1:] != p_seg[:-1], True)
    end = seg_angle.copy()  # each chord's last orientation
    end[p_seg[last]] = p_angle[last]
    prev = np.full(npc, np.nan)
    prev[1:] = p_angle[:-1]
    fs = p_seg[first]
    prev[first] = np.where(fs > 0, end[np.maximum(fs - 1, 0)], np.nan)

    def dist(a, b):
        return np.abs((a - b + 0.5 * period) % period - 0.5 * period)

    ok = np.isfinite(prev) & np.isfinite(p_angle)
    p_turn[ok] = dist(p_angle[ok], prev[ok])
    # whole chords right after a split one
    after = p_seg[last] + 1
    after = after[after < n_seg]
    after = after[np.isfinite(seg_angle[after]) & np.isfinite(end[after - 1])]
    if after.size:
        s_turn = s_turn.copy()
        s_turn[after] = dist(seg_angle[after], end[after - 1])
    return s_turn, p_turn


def rewrite_reference(g, data, moves, seg, seg_move, seg_angle, seg_fold, seg_width_laid,
                      seg_pieces, widths, heights, wopts: WriterOptions, turns: bool,
                      e_policy: str, nozzle: Nozzle, *, events: _Events | None = None,
                      piece_rows: tuple | None = None, piece_fold: np.ndarray | None = None
                      ) -> tuple[RewriteOutput, dict[int, int]]:
    """Copy the file, rewriting the part extrusions that need it (the reference, in Python).

    Only the lines of moves that may change are looked at one by one; the runs of
    lines between them are copied as single slices of ``data``. The chunks of the
    result are one per line up to the first command line (the header goes there),
    then runs and rewritten lines. ``events`` and ``piece_rows`` are what :func:`rewrite`
    already computed, when it did.
    """
    from gcode.line import parse_line
    from gcode.writer import edit_e, edit_line, simple_move_words

    ev = events if events is not None else _events(
        g, moves, seg, seg_move, seg_angle, seg_width_laid, seg_pieces, widths, heights, wopts,
        turns, e_policy, nozzle, piece_rows=piece_rows, piece_fold=piece_fold)
    out = RewriteOutput()
    n_lines = len(g.lines)
    starts = [*g.lines["start"].tolist(), len(data)]
    mv_a0, mv_a1 = ev.mv_a0.tolist(), ev.mv_a1.tolist()
    fold = wopts.feed_policy == "xy"
    ev_line = ev.ev_line.tolist()
    ev_move = ev.ev_move.tolist()
    ev_code = ev.ev_code.tolist()

    # per-move and per-chord columns as Python objects: the loop below reads them one by one
    m_e = moves["e"].tolist()
    m_kind = moves["kind"].tolist()
    m_flags = moves["flags"].tolist()
    m_layer = moves["layer"].tolist()
    m_x0, m_y0 = moves["x0"].tolist(), moves["y0"].tolist()
    m_x1, m_y1 = moves["x1"].tolist(), moves["y1"].tolist()
    m_z0, m_z1 = moves["z0"].tolist(), moves["z1"].tolist()
    s_x0, s_y0 = seg["x0"].tolist(), seg["y0"].tolist()
    s_x1, s_y1 = seg["x1"].tolist(), seg["y1"].tolist()
    s_e = seg["e"].tolist()
    s_angle = np.asarray(seg_angle, dtype=float).tolist()
    s_fold = np.asarray(seg_fold, dtype=bool).tolist()
    s_turn = ev.s_turn.tolist()
    s_scale = ev.s_scale.tolist()
    piece_scale = ev.piece_scale
    p_seg_list = ev.piece_rows[0].tolist()
    p_fold = ev.p_fold.astype(bool).tolist()
    p_turn = ev.p_turn.tolist()

    cur = 0.0  # rotary coordinate
    letter = wopts.letter
    d_ang = wopts.angle_decimals
    cur_text = format_number(cur, d_ang)
    last_travel_chunk: int | None = None  # chunk index of a travel we may fold C into
    xd = wopts.xy_decimals
    ed = 5
    turned: dict[int, int] = {}
    period = wopts.period or 360.0
    lo, hi = wopts.angle_min, wopts.angle_max
    chunks = out.chunks

    unbounded = math.isinf(lo) and math.isinf(hi) and lo < 0 < hi

    def coord_for(phi: float, *, unwind: bool = False) -> float:
        prev = 0.0 if unwind else cur
        if unbounded:
            # nearest_equivalent without limits, inlined (the same operations, so the
            # same bits): it runs once per rewritten move
            k = round((prev - phi) / period)
            best = phi + (k - 1) * period
            bd = abs(best - prev)
            cand = phi + k * period
            if abs(cand - prev) < bd - 1e-12:
                best, bd = cand, abs(cand - prev)
            cand = phi + (k + 1) * period
            if abs(cand - prev) < bd - 1e-12:
                best = cand
            return best
        c = nearest_equivalent(phi, prev, period=period, lo=lo, hi=hi)
        if c is None:  # cannot happen: candidates were filtered to reachable ones
            raise InputError(f"orientation {phi:.3f}° is outside the rotary axis limits")
        return c

    angle_texts: dict[float, str] = {}

    def angle_text(c: float) -> str:
        # rotary coordinates repeat along straight runs and curves: format each once
        t = angle_texts.get(c)
        if t is None:
            t = angle_texts[c] = format_number(c, d_ang)
        return t

    rot_feed = float(wopts.rotary_feed)
    rot_f = ("F" + format_number(rot_feed, 3)).encode() if rot_feed > 0 else b""

    def before_unretract(word: str) -> None:
        # the rotation-only move before the un-retract: nothing is deposited at the old
        # orientation; the un-retract restores the feed it had
        nonlocal u_slot
        u_raw = chunks[u_slot + 1]
        with_f = bool(rot_f) and math.isfinite(m_feed[u_move])
        chunks[u_slot] = (b"G1 " + word.encode() + (b" " + rot_f if with_f else b"")
                          + eol_of(u_raw))
        if with_f and not _has_feed(u_raw):
            chunks[u_slot + 1] = edit_line(u_raw, add=[f_word(m_feed[u_move])])
            out.changed += 1
        out.inserted += 1
        u_slot = None

    def turn_to(phi: float, c: float, c_text: str, eol: bytes, layer: int,
                feed: float) -> bool:
        # A turn before the move: folded into the travel before it, else a move of its own
        # before the un-retract before it, else one just before the move. A rotation-only
        # move carries its own F (degrees/min; it would inherit the XY feed), when the feed
        # to restore after it is known; True when the move must restore its feed.
        nonlocal cur, cur_text, last_travel_chunk, u_slot
        if c_text == cur_text:
            return False
        word = letter + c_text
        need_f = False
        if fold and last_travel_chunk is not None:
            if wopts.unwind:
                c = coord_for(phi, unwind=True)
                c_text = format_number(c, d_ang)
                word = letter + c_text
            chunks[last_travel_chunk] = edit_line(chunks[last_travel_chunk], add=[word])
        elif u_slot is not None:
            before_unretract(word)
        else:
            with_f = bool(rot_f) and math.isfinite(feed)
            chunks.append(b"G1 " + word.encode() + (b" " + rot_f if with_f else b"") + eol)
            need_f = with_f
            out.inserted += 1
        u_slot = None
        out.rotary_words += 1
        turned[layer] = turned.get(layer, 0) + 1
        cur = c
        cur_text = c_text
        last_travel_chunk = None
        return need_f

    def words(raw: bytes, e_rel: bool, e_move: float):
        # read only where a word is needed: most moves only gain a rotary word
        ws = simple_move_words(raw)
        if ws is not None:
            f_text = e_text = None
            for w in ws:
                if f_text is None and w[:1] == b"F":
                    f_text = w.decode("ascii")
                elif e_text is None and w[:1] == b"E":
                    e_text = w
            has_e = e_text is not None
            e_value = float(e_text[1:]) if has_e else None
        else:
            parsed = parse_line(raw)
            fword = parsed.word("F")
            f_text = fword.text.decode("ascii", "replace") if fword is not None else None
            eword = parsed.word("E")
            has_e = eword is not None
            e_value = eword.value if has_e else None
        e_end_abs = e_value if (has_e and not e_rel) else None
        e_start_abs = (e_end_abs - e_move) if e_end_abs is not None else None
        return f_text, has_e, e_end_abs, e_start_abs

    # the lines before the first command are chunks of their own: the header goes among them
    first_cmd = min(first_command_line(g.lines), ev_line[0] if ev_line else n_lines)
    for li in range(first_cmd):
        chunks.append(data[starts[li]:starts[li + 1]])
    pos = starts[first_cmd]  # data before pos is in the chunks
    pending: int | None = None  # the last travel line since the last rewritten move
    unret: tuple[int, int] | None = None  # (line, move) of an un-retract since that travel
    u_slot: int | None = None  # the chunk before the un-retract's, where a turn may go
    u_move = -1
    m_feed = moves["feed"].tolist() if rot_f else []

    for li, mi, code in zip(ev_line, ev_move, ev_code, strict=True):
        # A turn may be folded into the last travel before the move when no extrusion
        # came in between; every rewritten move ends that chance.
        if code == _TRAVEL:
            pending = li
            unret = None
            continue
        if code == _UNRETRACT:
            unret = (li, mi)
            continue
        if code == _RESET:
            pending = None
            unret = None
            continue
        u_slot = None
        if pending is not None:
            chunks.append(data[pos:starts[pending]])
            chunks.append(data[starts[pending]:starts[pending + 1]])
            last_travel_chunk = len(chunks) - 1
            pos = starts[pending + 1]
            pending = None
        else:
            last_travel_chunk = None
            if unret is not None:
                u_line, u_move = unret
                chunks.append(data[pos:starts[u_line]])
                u_slot = len(chunks)
                chunks.append(b"")  # a turn goes here, before the un-retract
                chunks.append(data[starts[u_line]:starts[u_line + 1]])
                pos = starts[u_line + 1]
        unret = None
        chunks.append(data[pos:starts[li]])
        pos = starts[li + 1]
        raw = data[starts[li]:pos]

        # ---- this move is rewritten
        layer = m_layer[mi]
        a0, a1 = mv_a0[mi], mv_a1[mi]
        eol = eol_of(raw)
        e_rel = bool(m_flags[mi] & 1)
        e_move = m_e[mi]
        simple = (a1 - a0 == 1 and a0 not in seg_pieces and m_kind[mi] <= 1)
        feed = m_feed[mi] if rot_f else math.nan
        if simple:
            phi = s_angle[a0]
            add: list[str] = []
            need_f = False
            if turns and math.isfinite(phi):
                c = coord_for(phi)
                c_text = angle_text(c)
                if s_fold[a0] and abs(c - cur) <= s_turn[a0] + 1e-6:
                    # the turn checked by the planner, made while moving
                    if c_text != cur_text:
                        add = [letter + c_text]
                        out.rotary_words += 1
                        turned[layer] = turned.get(layer, 0) + 1
                        cur = c
                        cur_text = c_text
                else:
                    need_f = turn_to(phi, c, c_text, eol, layer, feed)
            if need_f and not _has_feed(raw):
                add.append(f_word(feed))
            scale = s_scale[a0]
            replace = {}
            if scale != 1.0:
                # the common shape: E read and replaced in one pass over the line
                edited = edit_e(raw, lambda v, m=e_move, k=scale, rel=e_rel: format_number(
                    m * k if rel else (v - m) + m * k, ed), add=add)
                if edited is not None:
                    line, e_end = edited
                    chunks.append(line)
                    out.changed += 1
                    if not e_rel:
                        chunks.append(f"G92 E{format_number(e_end, ed)}".encode() + eol)
                        out.inserted += 1
                    last_travel_chunk = None
                    continue
                # another shape, or no E word: read and edit through the tokeniser
                _, has_e, e_end_abs, e_start_abs = words(raw, e_rel, e_move)
                if has_e:
                    if e_rel:
                        replace = {"E": "E" + format_number(e_move * scale, ed)}
                    else:
                        replace = {"E": "E" + format_number(e_start_abs + e_move * scale, ed)}
            if replace or add:
                chunks.append(edit_line(raw, replace=replace, add=add))
                out.changed += 1
                if replace and not e_rel:
                    chunks.append(f"G92 E{format_number(e_end_abs, ed)}".encode() + eol)
                    out.inserted += 1
            else:
                chunks.append(raw)
            last_travel_chunk = None
            continue
        # ---- general case: chords and pieces, written as new G1 lines
        f_text, _, e_end_abs, e_start_abs = words(raw, e_rel, e_move)
        out.changed += 1
        e_acc = 0.0
        first = True
        px, py = m_x0[mi], m_y0[mi]
        comment = b" ; printability: was " + raw.rstrip(b"\r\n").strip()[:60]
        lines_new: list[bytes] = []
        need_f = False
        # A move that also climbs (spiral vase) climbs along its new lines too, by path
        # length, instead of stepping Z at the end.
        z0, z1 = m_z0[mi], m_z1[mi]
        ramp = None
        if z1 != z0 and math.isfinite(z0) and math.isfinite(z1):
            c_len = [math.hypot(s_x1[s] - s_x0[s], s_y1[s] - s_y0[s]) for s in range(a0, a1)]
            ramp = _ZRamp(z0, z1, a0, c_len, list(itertools.accumulate(c_len, initial=0.0)),
                          xd)
        z_word = ramp.word if ramp is not None else _no_z_word
        for s in range(a0, a1):
            sx0, sy0, sx1, sy1 = s_x0[s], s_y0[s], s_x1[s], s_y1[s]
            se = s_e[s]
            in_pieces = s in seg_pieces
            if in_pieces:
                r0 = bisect.bisect_left(p_seg_list, s)
                plist = [(p.t0, p.t1, p.angle, sc, p_fold[r0 + k], p_turn[r0 + k])
                         for k, (p, sc) in enumerate(zip(seg_pieces[s], piece_scale.get(s, ()),
                                                         strict=True))]
            else:
                plist = [(0.0, 1.0, s_angle[s], s_scale[s], s_fold[s], s_turn[s])]
            for t0, t1, phi, scale, moving, turn in plist:
                qx0, qy0 = sx0 + t0 * (sx1 - sx0), sy0 + t0 * (sy1 - sy0)
                qx1, qy1 = sx0 + t1 * (sx1 - sx0), sy0 + t1 * (sy1 - sy0)
                gap = False  # a line to the piece's start, not extruding, just written
                if math.hypot(qx0 - px, qy0 - py) > 1e-9:
                    lines_new.append(b"G1 X" + format_number(qx0, xd).encode() + b" Y"
                                     + format_number(qy0, xd).encode() + z_word(s, t0))
                    px, py = qx0, qy0
                    gap = True
                c_word = b""
                if turns and math.isfinite(phi):
                    c = coord_for(phi)
                    c_text = angle_text(c)
                    if c_text != cur_text:
                        c_word = (letter + c_text).encode()
                        # the turn checked by the planner, made while moving (a whole chord's
                        # or a piece's), else a turn of its own before
                        if not (moving and abs(c - cur) <= turn + 1e-6):
                            if fold and last_travel_chunk is not None and not lines_new:
                                # the first thing this move does: folded into the travel
                                if wopts.unwind:
                                    c = coord_for(phi, unwind=True)
                                    c_text = format_number(c, d_ang)
                                    c_word = (letter + c_text).encode()
                                chunks[last_travel_chunk] = edit_line(
                                    chunks[last_travel_chunk], add=[c_word.decode()])
                                last_travel_chunk = None
                            elif u_slot is not None and not lines_new:
                                # the first thing this move does: before the un-retract
                                before_unretract(c_word.decode())
                            elif fold and gap:
                                # made on the way to the piece's start (nothing deposited)
                                lines_new[-1] = lines_new[-1] + b" " + c_word
                            else:
                                with_f = bool(rot_f) and math.isfinite(feed)
                                lines_new.append(b"G1 " + c_word
                                                 + (b" " + rot_f if with_f else b""))
                                need_f = with_f
                            c_word = b""
                        out.rotary_words += 1
                        turned[layer] = turned.get(layer, 0) + 1
                        cur = c
                        cur_text = c_text
                de = se * (t1 - t0) * scale
                e_acc += de
                if e_rel:
                    e_word = b"E" + format_number(de, ed).encode()
                else:
                    e_word = b"E" + format_number(e_start_abs + e_acc, ed).encode()
                ws = [b"G1", b"X" + format_number(qx1, xd).encode(),
                      b"Y" + format_number(qy1, xd).encode() + z_word(s, t1), e_word]
                if c_word:
                    ws.append(c_word)
                if first and f_text is not None:
                    ws.append(f_text.encode())
                elif need_f:
                    ws.append(f_word(feed).encode())
                need_f = False
                first = False
                lines_new.append(b" ".join(ws))
                px, py = qx1, qy1
        ex, ey = m_x1[mi], m_y1[mi]
        if math.hypot(ex - px, ey - py) > 1e-9 or not lines_new:
            ws = [b"G1", b"X" + format_number(ex, xd).encode(),
                  b"Y" + format_number(ey, xd).encode() + z_word(a1 - 1, 1.0)]
            if first and f_text is not None:
                ws.append(f_text.encode())
            lines_new.append(b" ".join(ws))
        if z1 != z0 and math.isfinite(z1) and ramp is None:
            lines_new.append(b"G1 Z" + format_number(z1, xd).encode())
        if not e_rel and e_end_abs is not None and abs(e_acc - e_move) > 10 ** -ed:
            lines_new.append(b"G92 E" + format_number(e_end_abs, ed).encode())
        lines_new[0] = lines_new[0] + comment
        chunks.extend(ln + eol for ln in lines_new)
        out.inserted += len(lines_new) - 1
        last_travel_chunk = None
    chunks.append(data[pos:])
    return out, turned


def f_word(feed: float) -> str:
    """The F word restoring ``feed`` (mm/min) after a rotation-only move."""
    return "F" + format_number(feed, 3)


def _has_feed(raw: bytes) -> bool:
    """True when the line has an F word."""
    from gcode.line import parse_line
    from gcode.writer import simple_move_words

    ws = simple_move_words(raw)
    if ws is not None:
        return any(w[:1] == b"F" for w in ws)
    return parse_line(raw).word("F") is not None


def _piece_scales(seg, p_seg, phi, widths, h_seg, turns: bool, e_policy: str, nozzle: Nozzle,
                  bead_area) -> np.ndarray:
    """The E factor of every piece of the split chords (chord ``p_seg``, orientation ``phi``):
    :func:`e_scale` of the width the piece lays at its orientation, all at once."""
    scale = np.ones(len(p_seg))
    live = np.isfinite(phi)
    if turns and live.any():
        sg = take_rows(seg, p_seg[live])
        rel = np.degrees(np.arctan2(sg["y1"] - sg["y0"], sg["x1"] - sg["x0"]))
        w_laid = nozzle.bead_widths(rel, phi[live])
        scale[live] = e_scales(w_laid, np.asarray(widths, dtype=float)[p_seg[live]],
                               h_seg[p_seg[live]], e_policy, nozzle, bead_area)
    return scale


def planned_turns(seg_angle: np.ndarray) -> np.ndarray:
    """Per chord, the turn into it the planner checked (from the chord before), degrees.

    A turn folded into an extruding move must be that one: near an axis limit the
    coordinate may have to go the long way round, which was never checked. -1 where
    there is none (first chord, or an orientation that is not finite).
    """
    out = np.full(len(seg_angle), -1.0)
    if len(seg_angle) > 1:
        a, b = seg_angle[1:], seg_angle[:-1]
        ok = np.isfinite(a) & np.isfinite(b)
        out[1:][ok] = np.abs(a[ok] - b[ok])
    return out


def e_scales(w_laid: np.ndarray, w_plan: np.ndarray, h: np.ndarray, e_policy: str,
              nozzle: Nozzle, bead_area) -> np.ndarray:
    """:func:`e_scale` of every chord at once (the same operations, so the same bits)."""
    scale = np.ones(len(w_laid))
    if e_policy != "width" or nozzle.is_round:
        return scale
    with np.errstate(invalid="ignore", divide="ignore"):
        a_plan = bead_area(w_plan, h)
        a_laid = bead_area(w_laid, h)
        ok = (np.isfinite(w_laid) & np.isfinite(w_plan)
              & ~(np.abs(w_laid - w_plan) <= 0.01 * w_plan) & (a_plan > 0))
    scale[ok] = a_laid[ok] / a_plan[ok]
    return scale


def e_scale(w_laid: float, w_plan: float, h: float, e_policy: str, nozzle: Nozzle,
             bead_area) -> float:
    """Factor applied to the slicer's E for a bead laid ``w_laid`` wide instead of ``w_plan``."""
    if e_policy != "width" or nozzle.is_round or not (math.isfinite(w_laid)
                                                       and math.isfinite(w_plan)):
        return 1.0
    if abs(w_laid - w_plan) <= 0.01 * w_plan:
        return 1.0
    a_plan = float(bead_area(w_plan, h))
    return float(bead_area(w_laid, h)) / a_plan if a_plan > 0 else 1.0

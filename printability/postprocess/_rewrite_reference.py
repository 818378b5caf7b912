"""The rewrite pass in Python: the reference whose bytes the compiled pass
(:mod:`printability.postprocess._rewrite_kernel`) writes, and the fallback for what it declines.

Only the lines of moves that may change are looked at one by one (the events of
:func:`printability.postprocess._rewrite_events.scan_events`); the runs of lines between them are
copied as single slices of the file. A move that only turns gains a rotary word, or a
turn before it (folded into the travel before it, else a rotation-only line before the
un-retract before it, else one just before the move); a move whose E changes is edited in
place (``G92 E…`` after it in absolute-E files); arcs and split moves become new ``G1``
lines.

Complexity: linear in the file's lines plus the new lines.
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from gcode.rotary import nearest_equivalent
from gcode.writer import format_number
from printability.errors import InputError
from printability.postprocess._rewrite_events import (
    RESET,
    TRAVEL,
    UNRETRACT,
    ChordPlan,
    Events,
    RewriteOutput,
    SlicerFile,
    WriteSettings,
    eol_of,
    first_command_line,
    scan_events,
)

__all__ = ["f_word", "rewrite_reference"]


def rewrite_reference(src: SlicerFile, plan: ChordPlan, settings: WriteSettings, *,
                      events: Events | None = None) -> tuple[RewriteOutput, dict[int, int]]:
    """Copy the file, rewriting the part extrusions that need it (the reference, in Python).

    The chunks of the result are one per line up to the first command line (the header
    goes there), then runs and rewritten lines. ``events``: what
    :func:`~printability.postprocess._rewrite_events.scan_events` gives, when already computed.
    Returns the output and the rotary words per layer.
    """
    ev = events if events is not None else scan_events(src, plan, settings)
    return _Reference(src, plan, settings, ev).run(src, ev)


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


class _Move(NamedTuple):
    """The move being rewritten: its line (``raw``, ending ``eol``), move and layer, its
    chords ``a0:a1``, its E (relative or not) and the feed in force after it."""

    raw: bytes
    eol: bytes
    mi: int
    layer: int
    a0: int
    a1: int
    e_rel: bool
    e_move: float
    feed: float


@dataclass
class _NewLines:
    """The lines a split or curved move becomes, as they are written: the move's F word
    (carried by the first), its absolute E at the start (absolute-E files), Z along a climb,
    E so far, the nozzle's place, and whether the next line restores the feed."""

    f_text: str | None
    e_start: float | None
    z_word: Callable[[int, float], bytes]
    px: float
    py: float
    lines: list[bytes] = field(default_factory=list)
    e_acc: float = 0.0
    first: bool = True
    need_f: bool = False


def _columns(table: np.ndarray, names: tuple[str, ...]) -> list[list]:
    return [table[k].tolist() for k in names]


class _Reference:
    """One walk over the events: the output, the rotary axis's coordinate (and its text),
    and the travel and un-retract a turn may still go into."""

    def __init__(self, src: SlicerFile, plan: ChordPlan, settings: WriteSettings,
                 ev: Events) -> None:
        wopts = settings.wopts
        self.data = src.data
        self.starts = [*src.g.lines["start"].tolist(), len(src.data)]
        self.turns = settings.turns
        self.pieces = plan.pieces
        self.out = RewriteOutput()
        self.chunks = self.out.chunks
        self.turned: dict[int, int] = {}
        self.mv_a0, self.mv_a1 = ev.mv_a0.tolist(), ev.mv_a1.tolist()
        # per-move and per-chord columns as Python objects: the walk reads them one by one
        moves = src.moves
        (self.m_e, self.m_kind, self.m_flags, self.m_layer, self.m_x0, self.m_y0, self.m_x1,
         self.m_y1, self.m_z0, self.m_z1) = _columns(
            moves, ("e", "kind", "flags", "layer", "x0", "y0", "x1", "y1", "z0", "z1"))
        self.s_x0, self.s_y0, self.s_x1, self.s_y1, self.s_e = _columns(
            plan.seg, ("x0", "y0", "x1", "y1", "e"))
        self.s_angle = np.asarray(plan.angle, dtype=float).tolist()
        self.s_fold = np.asarray(plan.fold, dtype=bool).tolist()
        self.s_turn = ev.s_turn.tolist()
        self.s_scale = ev.s_scale.tolist()
        self.piece_scale = ev.piece_scale
        self.p_seg = ev.piece_rows[0].tolist()
        self.p_fold = ev.p_fold.astype(bool).tolist()
        self.p_turn = ev.p_turn.tolist()
        # the writer
        self.letter = wopts.letter
        self.d_ang = wopts.angle_decimals
        self.xd = wopts.xy_decimals
        self.ed = 5
        self.fold = wopts.feed_policy == "xy"
        self.unwind = wopts.unwind
        self.period = wopts.period or 360.0
        self.lo, self.hi = wopts.angle_min, wopts.angle_max
        self.unbounded = math.isinf(self.lo) and math.isinf(self.hi) and self.lo < 0 < self.hi
        rot_feed = float(wopts.rotary_feed)
        self.rot_f = ("F" + format_number(rot_feed, 3)).encode() if rot_feed > 0 else b""
        self.m_feed = moves["feed"].tolist() if self.rot_f else []
        # the walk
        self.cur = 0.0  # rotary coordinate
        self.cur_text = format_number(self.cur, self.d_ang)
        self.angle_texts: dict[float, str] = {}
        self.last_travel_chunk: int | None = None  # chunk index of a travel we may fold C into
        self.u_slot: int | None = None  # the chunk before the un-retract's, where a turn may go
        self.u_move = -1
        self.pos = 0  # data before pos is in the chunks

    def run(self, src: SlicerFile, ev: Events) -> tuple[RewriteOutput, dict[int, int]]:
        data, starts, chunks = self.data, self.starts, self.chunks
        ev_line = ev.ev_line.tolist()
        # the lines before the first command are chunks of their own: the header goes among
        # them
        first_cmd = min(first_command_line(src.g.lines),
                        ev_line[0] if ev_line else len(starts) - 1)
        for li in range(first_cmd):
            chunks.append(data[starts[li]:starts[li + 1]])
        self.pos = starts[first_cmd]
        pending: int | None = None  # the last travel line since the last rewritten move
        unret: tuple[int, int] | None = None  # (line, move) of an un-retract since that travel
        for li, mi, code in zip(ev_line, ev.ev_move.tolist(), ev.ev_code.tolist(), strict=True):
            # A turn may be folded into the last travel before the move when no extrusion
            # came in between; every rewritten move ends that chance.
            if code == TRAVEL:
                pending = li
                unret = None
                continue
            if code == UNRETRACT:
                unret = (li, mi)
                continue
            if code == RESET:
                pending = None
                unret = None
                continue
            self._before_move(pending, unret)
            pending = None
            unret = None
            self._move(li, mi)
            self.last_travel_chunk = None
        chunks.append(data[self.pos:])
        return self.out, self.turned

    def _before_move(self, pending: int | None, unret: tuple[int, int] | None) -> None:
        """The lines up to a move to rewrite: the travel before it as a chunk of its own (a
        turn may be folded into it), else the un-retract's, with an empty chunk before it
        (a turn may go there)."""
        data, starts, chunks = self.data, self.starts, self.chunks
        self.u_slot = None
        if pending is not None:
            chunks.append(data[self.pos:starts[pending]])
            chunks.append(data[starts[pending]:starts[pending + 1]])
            self.last_travel_chunk = len(chunks) - 1
            self.pos = starts[pending + 1]
        else:
            self.last_travel_chunk = None
            if unret is not None:
                u_line, self.u_move = unret
                chunks.append(data[self.pos:starts[u_line]])
                self.u_slot = len(chunks)
                chunks.append(b"")  # a turn goes here, before the un-retract
                chunks.append(data[starts[u_line]:starts[u_line + 1]])
                self.pos = starts[u_line + 1]

    def _move(self, li: int, mi: int) -> None:
        """Rewrite the move ``mi`` of line ``li``."""
        starts = self.starts
        self.chunks.append(self.data[self.pos:starts[li]])
        self.pos = starts[li + 1]
        raw = self.data[starts[li]:self.pos]
        a0, a1 = self.mv_a0[mi], self.mv_a1[mi]
        mv = _Move(raw, eol_of(raw), mi, self.m_layer[mi], a0, a1, bool(self.m_flags[mi] & 1),
                   self.m_e[mi], self.m_feed[mi] if self.rot_f else math.nan)
        if a1 - a0 == 1 and a0 not in self.pieces and self.m_kind[mi] <= 1:
            self._simple_move(mv)
        else:
            self._split_move(mv)

    def coord_for(self, phi: float, *, unwind: bool = False) -> float:
        prev = 0.0 if unwind else self.cur
        period = self.period
        if self.unbounded:
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
        c = nearest_equivalent(phi, prev, period=period, lo=self.lo, hi=self.hi)
        if c is None:  # cannot happen: candidates were filtered to reachable ones
            raise InputError(f"orientation {phi:.3f}° is outside the rotary axis limits")
        return c

    def angle_text(self, c: float) -> str:
        # rotary coordinates repeat along straight runs and curves: format each once
        t = self.angle_texts.get(c)
        if t is None:
            t = self.angle_texts[c] = format_number(c, self.d_ang)
        return t

    def _turned(self, layer: int, c: float, c_text: str) -> None:
        """Count a rotary word on ``layer``, the axis now at ``c``."""
        self.out.rotary_words += 1
        self.turned[layer] = self.turned.get(layer, 0) + 1
        self.cur = c
        self.cur_text = c_text

    def before_unretract(self, word: str) -> None:
        # the rotation-only move before the un-retract: nothing is deposited at the old
        # orientation; the un-retract restores the feed it had
        from gcode.writer import edit_line

        chunks, u_slot, rot_f = self.chunks, self.u_slot, self.rot_f
        u_raw = chunks[u_slot + 1]
        feed = self.m_feed[self.u_move] if rot_f else math.nan
        with_f = bool(rot_f) and math.isfinite(feed)
        chunks[u_slot] = (b"G1 " + word.encode() + (b" " + rot_f if with_f else b"")
                          + eol_of(u_raw))
        if with_f and not _has_feed(u_raw):
            chunks[u_slot + 1] = edit_line(u_raw, add=[f_word(feed)])
            self.out.changed += 1
        self.out.inserted += 1
        self.u_slot = None

    def turn_to(self, phi: float, c: float, c_text: str, mv: _Move) -> bool:
        # A turn before the move: folded into the travel before it, else a move of its own
        # before the un-retract before it, else one just before the move. A rotation-only
        # move carries its own F (degrees/min; it would inherit the XY feed), when the feed
        # to restore after it is known; True when the move must restore its feed.
        from gcode.writer import edit_line

        if c_text == self.cur_text:
            return False
        word = self.letter + c_text
        need_f = False
        if self.fold and self.last_travel_chunk is not None:
            if self.unwind:
                c = self.coord_for(phi, unwind=True)
                c_text = format_number(c, self.d_ang)
                word = self.letter + c_text
            k = self.last_travel_chunk
            self.chunks[k] = edit_line(self.chunks[k], add=[word])
        elif self.u_slot is not None:
            self.before_unretract(word)
        else:
            rot_f = self.rot_f
            with_f = bool(rot_f) and math.isfinite(mv.feed)
            self.chunks.append(b"G1 " + word.encode() + (b" " + rot_f if with_f else b"")
                               + mv.eol)
            need_f = with_f
            self.out.inserted += 1
        self.u_slot = None
        self._turned(mv.layer, c, c_text)
        self.last_travel_chunk = None
        return need_f

    def _simple_move(self, mv: _Move) -> None:
        """One chord, whole: a rotary word, an E edit, or both."""
        from gcode.writer import edit_e, edit_line

        raw, eol, a0, e_rel, e_move = mv.raw, mv.eol, mv.a0, mv.e_rel, mv.e_move
        chunks, out, ed = self.chunks, self.out, self.ed
        phi = self.s_angle[a0]
        add: list[str] = []
        need_f = False
        if self.turns and math.isfinite(phi):
            c = self.coord_for(phi)
            c_text = self.angle_text(c)
            if self.s_fold[a0] and abs(c - self.cur) <= self.s_turn[a0] + 1e-6:
                # the turn checked by the planner, made while moving
                if c_text != self.cur_text:
                    add = [self.letter + c_text]
                    self._turned(mv.layer, c, c_text)
            else:
                need_f = self.turn_to(phi, c, c_text, mv)
        if need_f and not _has_feed(raw):
            add.append(f_word(mv.feed))
        scale = self.s_scale[a0]
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
                return
            # another shape, or no E word: read and edit through the tokeniser
            _, has_e, e_end_abs, e_start_abs = _words(raw, e_rel, e_move)
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

    def _split_move(self, mv: _Move) -> None:
        """Chords and pieces, written as new ``G1`` lines; the first carries the old line
        as a note."""
        raw, mi, a0, a1, xd, ed = mv.raw, mv.mi, mv.a0, mv.a1, self.xd, self.ed
        f_text, _, e_end_abs, e_start_abs = _words(raw, mv.e_rel, mv.e_move)
        self.out.changed += 1
        comment = b" ; printability: was " + raw.rstrip(b"\r\n").strip()[:60]
        # A move that also climbs (spiral vase) climbs along its new lines too, by path
        # length, instead of stepping Z at the end.
        z0, z1 = self.m_z0[mi], self.m_z1[mi]
        ramp = None
        if z1 != z0 and math.isfinite(z0) and math.isfinite(z1):
            s_x0, s_y0, s_x1, s_y1 = self.s_x0, self.s_y0, self.s_x1, self.s_y1
            c_len = [math.hypot(s_x1[s] - s_x0[s], s_y1[s] - s_y0[s]) for s in range(a0, a1)]
            ramp = _ZRamp(z0, z1, a0, c_len, list(itertools.accumulate(c_len, initial=0.0)),
                          xd)
        z_word = ramp.word if ramp is not None else _no_z_word
        nl = _NewLines(f_text, e_start_abs, z_word, self.m_x0[mi], self.m_y0[mi])
        for s in range(a0, a1):
            self._chord_lines(mv, nl, s)
        lines_new = nl.lines
        ex, ey = self.m_x1[mi], self.m_y1[mi]
        if math.hypot(ex - nl.px, ey - nl.py) > 1e-9 or not lines_new:
            ws = [b"G1", b"X" + format_number(ex, xd).encode(),
                  b"Y" + format_number(ey, xd).encode() + z_word(a1 - 1, 1.0)]
            if nl.first and f_text is not None:
                ws.append(f_text.encode())
            lines_new.append(b" ".join(ws))
        if z1 != z0 and math.isfinite(z1) and ramp is None:
            lines_new.append(b"G1 Z" + format_number(z1, xd).encode())
        if not mv.e_rel and e_end_abs is not None and abs(nl.e_acc - mv.e_move) > 10 ** -ed:
            lines_new.append(b"G92 E" + format_number(e_end_abs, ed).encode())
        lines_new[0] = lines_new[0] + comment
        self.chunks.extend(ln + mv.eol for ln in lines_new)
        self.out.inserted += len(lines_new) - 1

    def _chord_lines(self, mv: _Move, nl: _NewLines, s: int) -> None:
        """The new lines of chord ``s``: the whole chord, or each of its pieces (a line to
        the piece's start first where the nozzle is not there)."""
        xd = self.xd
        sx0, sy0, sx1, sy1 = self.s_x0[s], self.s_y0[s], self.s_x1[s], self.s_y1[s]
        se = self.s_e[s]
        if s in self.pieces:
            r0 = bisect.bisect_left(self.p_seg, s)
            plist = [(p.t0, p.t1, p.angle, sc, self.p_fold[r0 + k], self.p_turn[r0 + k])
                     for k, (p, sc) in enumerate(zip(self.pieces[s], self.piece_scale.get(s, ()),
                                                     strict=True))]
        else:
            plist = [(0.0, 1.0, self.s_angle[s], self.s_scale[s], self.s_fold[s],
                      self.s_turn[s])]
        lines_new, z_word = nl.lines, nl.z_word
        for t0, t1, phi, scale, moving, turn in plist:
            qx0, qy0 = sx0 + t0 * (sx1 - sx0), sy0 + t0 * (sy1 - sy0)
            qx1, qy1 = sx0 + t1 * (sx1 - sx0), sy0 + t1 * (sy1 - sy0)
            gap = False  # a line to the piece's start, not extruding, just written
            if math.hypot(qx0 - nl.px, qy0 - nl.py) > 1e-9:
                lines_new.append(b"G1 X" + format_number(qx0, xd).encode() + b" Y"
                                 + format_number(qy0, xd).encode() + z_word(s, t0))
                nl.px, nl.py = qx0, qy0
                gap = True
            c_word = b""
            if self.turns and math.isfinite(phi):
                c_word = self._piece_turn(mv, nl, phi, moving, turn, gap)
            de = se * (t1 - t0) * scale
            nl.e_acc += de
            if mv.e_rel:
                e_word = b"E" + format_number(de, self.ed).encode()
            else:
                e_word = b"E" + format_number(nl.e_start + nl.e_acc, self.ed).encode()
            ws = [b"G1", b"X" + format_number(qx1, xd).encode(),
                  b"Y" + format_number(qy1, xd).encode() + z_word(s, t1), e_word]
            if c_word:
                ws.append(c_word)
            if nl.first and nl.f_text is not None:
                ws.append(nl.f_text.encode())
            elif nl.need_f:
                ws.append(f_word(mv.feed).encode())
            nl.need_f = False
            nl.first = False
            lines_new.append(b" ".join(ws))
            nl.px, nl.py = qx1, qy1

    def _piece_turn(self, mv: _Move, nl: _NewLines, phi: float, moving: bool, turn: float,
                    gap: bool) -> bytes:
        """The turn into a chord or piece at ``phi``: the rotary word its line carries when
        the planner made the turn while moving (``moving``, a turn of at most ``turn``),
        else put before it (folded into the travel, before the un-retract, on the line to
        the piece's start, or on a line of its own) and ``b""``."""
        from gcode.writer import edit_line

        c = self.coord_for(phi)
        c_text = self.angle_text(c)
        if c_text == self.cur_text:
            return b""
        c_word = (self.letter + c_text).encode()
        # the turn checked by the planner, made while moving (a whole chord's or a
        # piece's), else a turn of its own before
        if not (moving and abs(c - self.cur) <= turn + 1e-6):
            if self.fold and self.last_travel_chunk is not None and not nl.lines:
                # the first thing this move does: folded into the travel
                if self.unwind:
                    c = self.coord_for(phi, unwind=True)
                    c_text = format_number(c, self.d_ang)
                    c_word = (self.letter + c_text).encode()
                k = self.last_travel_chunk
                self.chunks[k] = edit_line(self.chunks[k], add=[c_word.decode()])
                self.last_travel_chunk = None
            elif self.u_slot is not None and not nl.lines:
                # the first thing this move does: before the un-retract
                self.before_unretract(c_word.decode())
            elif self.fold and gap:
                # made on the way to the piece's start (nothing deposited)
                nl.lines[-1] = nl.lines[-1] + b" " + c_word
            else:
                with_f = bool(self.rot_f) and math.isfinite(mv.feed)
                nl.lines.append(b"G1 " + c_word + (b" " + self.rot_f if with_f else b""))
                nl.need_f = with_f
            c_word = b""
        self._turned(mv.layer, c, c_text)
        return c_word


def _words(raw: bytes, e_rel: bool, e_move: float):
    """(F word's text, whether it has an E, absolute E at its end and start (absolute-E
    files; else None)) of a move's line."""
    from gcode.line import parse_line
    from gcode.writer import simple_move_words

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

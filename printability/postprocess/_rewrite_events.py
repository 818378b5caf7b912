"""What both rewrite passes share: their inputs as records, the moves they walk, their output.

:func:`printability.postprocess.rewrite.rewrite` groups its arguments into three records
(:class:`SlicerFile`, :class:`ChordPlan`, :class:`WriteSettings`); :func:`scan_events`
finds in them the lines of the moves that matter (:class:`Events`: travels, resets, moves
to rewrite, un-retracts, in file order) with the per-chord and per-piece columns both
passes read (E factors, planned turns). The compiled pass
(:mod:`printability.postprocess._rewrite_kernel`) and the reference
(:mod:`printability.postprocess._rewrite_reference`) then write the same :class:`RewriteOutput`.

Complexity: O(moves + chords + pieces), vectorised.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from gcode.writer import WriterOptions
from printability.base.arrays import take_rows
from printability.model.nozzle import Nozzle
from printability.planning.orientation import piece_rows_of

if TYPE_CHECKING:
    from gcode.reader import GCodeFile

__all__ = ["RESET", "TRAVEL", "UNRETRACT", "WORK", "ChordPlan", "Events", "RewriteOutput",
           "SlicerFile", "WriteSettings", "e_scale", "e_scales", "eol_of", "first_command_line",
           "planned_turns", "scan_events"]

# what a move's line does, for the walk (the compiled pass reads the same codes)
NONE, TRAVEL, RESET, WORK, UNRETRACT = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class SlicerFile:
    """The slicer's file: its bytes, their parse (``g``: lines and layers) and its moves
    (``g``'s move records: ``e kind flags layer line feed x0 y0 x1 y1 z0 z1``)."""

    data: bytes
    g: GCodeFile
    moves: np.ndarray


@dataclass(frozen=True)
class ChordPlan:
    """The plan of the file's extruding chords (its moves cut at their arcs), per chord.

    ``seg`` the chords (``x0 y0 x1 y1 e``), ``move`` the move of each; ``angle`` the
    orientation (NaN: none), ``fold`` True where the turn into the chord is made while
    moving, ``width_laid`` the width it lays there (E follows it), ``widths`` the width
    the slicer planned; ``pieces`` split chord → its printable pieces (empty: dropped),
    as arrays ``piece_rows = (chord, t0, t1, angle)`` by chord when known, ``piece_fold``
    per such row True where the turn into the piece is made during it; ``heights`` per
    layer, its height.
    """

    seg: np.ndarray
    move: np.ndarray
    angle: np.ndarray
    fold: np.ndarray
    width_laid: np.ndarray
    widths: np.ndarray
    pieces: Mapping[int, list]
    heights: np.ndarray
    piece_rows: tuple | None = None
    piece_fold: np.ndarray | None = None


@dataclass(frozen=True)
class WriteSettings:
    """How the moves are written: the writer's options, whether the axis turns at all, the
    E policy (``"width"``: E follows the width laid) and the nozzle (for the widths)."""

    wopts: WriterOptions
    turns: bool
    e_policy: str
    nozzle: Nozzle


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


def first_command_line(lines: np.ndarray) -> int:
    from gcode import KIND_BLANK, KIND_COMMENT

    idx = np.flatnonzero((lines["kind"] != KIND_COMMENT) & (lines["kind"] != KIND_BLANK))
    return int(idx[0]) if idx.size else len(lines)


@dataclass(frozen=True)
class Events:
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


def _chord_ranges(plan: ChordPlan, n_moves: int) -> tuple[np.ndarray, ...]:
    """Per move: whether it has chords, whether any is split, and its chords
    ``mv_a0[m]:mv_a1[m]`` (-1: none; a later run of chords of the same move wins)."""
    seg_move = plan.move
    has_seg = np.zeros(n_moves, dtype=bool)
    with_pieces = np.zeros(n_moves, dtype=bool)
    mv_a0 = np.full(n_moves, -1, np.int64)
    mv_a1 = np.full(n_moves, -1, np.int64)
    if len(plan.seg):
        change = np.flatnonzero(np.diff(seg_move)) + 1
        b = np.concatenate([[0], change, [len(seg_move)]])
        run_move = np.asarray(seg_move[b[:-1]], dtype=np.int64)
        keys, last_rev = np.unique(run_move[::-1], return_index=True)
        last = len(run_move) - 1 - last_rev  # the last run of each move
        ranges = np.column_stack([b[:-1][last], b[1:][last]]).astype(np.int64)
        has_seg[keys] = True
        mv_a0[keys] = ranges[:, 0]
        mv_a1[keys] = ranges[:, 1]
        piece_flag = np.zeros(len(plan.seg) + 1, dtype=np.int64)
        if plan.pieces:
            piece_flag[np.fromiter(plan.pieces, dtype=np.int64, count=len(plan.pieces)) + 1] = 1
        csum = np.cumsum(piece_flag)
        with_pieces[keys] = csum[ranges[:, 1]] > csum[ranges[:, 0]]
    return has_seg, with_pieces, mv_a0, mv_a1


def _move_effects(moves: np.ndarray, has_seg: np.ndarray, with_pieces: np.ndarray,
                  settings: WriteSettings) -> np.ndarray:
    """What each move's line does to the travel a turn may be folded into (see the
    reference): one of the codes above."""
    turns = settings.turns
    work = has_seg & (with_pieces | turns)
    with np.errstate(invalid="ignore"):
        is_travel = ((moves["e"] <= 0) & (moves["kind"] <= 1)
                     & ((moves["x1"] != moves["x0"]) | (moves["y1"] != moves["y0"])))
        extruding = moves["e"] > 0
        # E alone, forwards: the un-retract before a path, which a turn must precede
        unretract = (extruding & (moves["kind"] <= 1) & (moves["x1"] == moves["x0"])
                     & (moves["y1"] == moves["y0"]) & ~(moves["z1"] != moves["z0"]))
    effect = np.full(len(moves), NONE, dtype=np.int8)
    effect[extruding] = RESET
    if turns:
        effect[unretract & ~has_seg] = UNRETRACT
        effect[has_seg] = RESET
        if settings.wopts.feed_policy == "xy":
            effect[is_travel] = TRAVEL
    effect[work] = WORK
    return effect


def scan_events(src: SlicerFile, plan: ChordPlan, settings: WriteSettings) -> Events:
    """The moves both passes walk, and the columns they read (:class:`Events`)."""
    from gcode.rotary import bead_area

    moves = src.moves
    n_lines = len(src.g.lines)
    n_moves = len(moves)
    has_seg, with_pieces, mv_a0, mv_a1 = _chord_ranges(plan, n_moves)

    # the move of each line: the last move listed on it
    mv_line = moves["line"].astype(np.int64)
    lines_u, last_rev = np.unique(mv_line[::-1], return_index=True)
    move_u = n_moves - 1 - last_rev
    keep = (lines_u >= 0) & (lines_u < n_lines)
    lines_u, move_u = lines_u[keep], move_u[keep]
    effect = _move_effects(moves, has_seg, with_pieces, settings)
    ev = effect[move_u] != NONE

    seg_angle = np.asarray(plan.angle, dtype=float)
    s_turn = planned_turns(seg_angle)
    h_seg = None
    if len(plan.seg):
        layer_of_seg = moves["layer"][plan.move]
        heights = plan.heights
        h_seg = np.where(layer_of_seg >= 0,
                         np.asarray(heights, dtype=float)[np.maximum(layer_of_seg, 0)]
                         if len(heights) else 0.2, 0.2)
        s_scale = e_scales(np.asarray(plan.width_laid, dtype=float),
                           np.asarray(plan.widths, dtype=float), h_seg, settings.e_policy,
                           settings.nozzle, bead_area)
    else:
        s_scale = np.zeros(0)
    rows = plan.piece_rows if plan.piece_rows is not None else piece_rows_of(plan.pieces)
    rows = (np.asarray(rows[0], np.int64), *(np.asarray(r, float) for r in rows[1:]))
    scale = _piece_scales(plan, rows, h_seg, settings, bead_area)
    p_fold = np.zeros(len(rows[0]), np.uint8)
    if plan.piece_fold is not None and settings.wopts.feed_policy == "xy" and settings.turns:
        p_fold[:] = np.asarray(plan.piece_fold, bool)
    s_turn, p_turn = _piece_turns(s_turn, seg_angle, rows, settings.wopts.period or 360.0)
    return Events(lines_u[ev].astype(np.int64), move_u[ev].astype(np.int64),
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


def _piece_scales(plan: ChordPlan, rows: tuple, h_seg: np.ndarray | None,
                  settings: WriteSettings, bead_area) -> np.ndarray:
    """The E factor of every piece of the split chords (``rows``: chord, t0, t1,
    orientation): :func:`e_scale` of the width the piece lays at its orientation, all at
    once."""
    p_seg, phi = rows[0], rows[3]
    scale = np.ones(len(p_seg))
    live = np.isfinite(phi)
    if settings.turns and live.any():
        sg = take_rows(plan.seg, p_seg[live])
        rel = np.degrees(np.arctan2(sg["y1"] - sg["y0"], sg["x1"] - sg["x0"]))
        w_laid = settings.nozzle.bead_widths(rel, phi[live])
        scale[live] = e_scales(w_laid, np.asarray(plan.widths, dtype=float)[p_seg[live]],
                               h_seg[p_seg[live]], settings.e_policy, settings.nozzle,
                               bead_area)
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

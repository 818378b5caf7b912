"""The orientation planner's passes after the search (:mod:`printability.planning.orientation`):
re-chaining the orientations the search replaced (:func:`smooth`), aligning the pieces of a
split move with its longest (:func:`align_pieces`), leaving out the short side pieces that
need a turn of their own (:func:`drop_side_pieces`), and deciding which turns are made
while moving (:func:`fold_flags`); and the axis' reach (:func:`reachable`,
:func:`other_solution`).

Each reads the layer from a :class:`~printability.planning.plan.PlanContext`. Angles in
degrees, positions along a move as fractions of it.
"""

from __future__ import annotations

import numpy as np

from printability.base.arrays import take_rows
from printability.model.machine import Machine
from printability.planning import footprints as fp
from printability.planning._plan_kernels import merge_pieces, smooth_chain
from printability.planning.plan import PlanContext
from printability.planning.turns import turning_fits

__all__ = ["align_pieces", "drop_side_pieces", "fold_flags", "other_solution", "reachable",
           "smooth"]


def reachable(phi: np.ndarray, machine: Machine, period: float) -> np.ndarray:
    """Whether some equivalent of each orientation lies within the axis limits."""
    if not machine.has_rotary:
        return np.isclose(np.mod(phi + 1e-9, period or 360.0), 1e-9, atol=1e-6)
    lo, hi = machine.angle_min, machine.angle_max
    if hi - lo >= period - 1e-9:
        return np.ones(phi.shape, dtype=bool)
    k = np.ceil((lo - phi) / period - 1e-12)
    return phi + k * period <= hi + 1e-9



def fold_flags(ctx: PlanContext, angle: np.ndarray, rows: tuple, chained: np.ndarray, *,
               fold_pieces: bool) -> tuple[np.ndarray, np.ndarray]:
    """Which turns are made while moving: ``Plan.fold`` (per move) and ``Plan.piece_fold``
    (per piece row).

    A turn of at most ``fold_max`` into a whole move chained to the previous one (whose
    orientation is its own, or its last piece's when it is split) is made during the move
    where the footprint turning along it fits; the same for a piece of a split move, from
    the previous piece of the move or, for its first piece, from the previous move (when
    chained; ``fold_pieces`` False: never, as where F would not be the XY feed). The test
    is :func:`~printability.planning.turns.turning_fits`, on the piece's own stretch of the
    move: what it deposits while turning stays inside the grown target, as every other
    footprint.
    """
    p0, p1, per, options = ctx.p0, ctx.p1, ctx.per, ctx.options
    n = len(angle)
    pm, pt0, pt1, pa = rows
    pm = np.asarray(pm, np.int64)
    npc = pm.size
    # each move's last orientation (NaN: dropped)
    end = np.asarray(angle, float).copy()
    first = np.zeros(0, bool)
    if npc:
        first = np.ones(npc, bool)
        first[1:] = pm[1:] != pm[:-1]
        last = np.append(pm[1:] != pm[:-1], True)
        end[pm[last]] = pa[last]
    fold = np.zeros(n, dtype=bool)
    piece_fold = np.zeros(npc, dtype=bool)
    whole = np.isfinite(angle)
    # whole moves: from the previous move's end (the raw difference after a whole move, as
    # the chain unwrapped them; the nearest equivalent after a split one)
    prev_a = np.concatenate([[np.nan], end[:-1]])
    after_whole = np.concatenate([[False], whole[:-1]])
    a_end = np.where(after_whole, angle, angle + per * np.round((prev_a - angle) / per))
    with np.errstate(invalid="ignore"):
        step = np.abs(a_end - prev_a)
        cand = np.flatnonzero(chained & whole & np.isfinite(step) & (step > 1e-9)
                              & (step <= options.fold_max))
    # pieces: from the previous piece of the move, or the previous move's end
    q_prev = np.full(npc, np.nan)
    q_ok = np.zeros(npc, bool)
    if npc and fold_pieces:
        q_prev[~first] = pa[:-1][~first[1:]]
        q_ok[~first] = True
        fm = pm[first]
        has_prev = fm > 0
        q_prev[np.flatnonzero(first)[has_prev]] = end[fm[has_prev] - 1]
        q_ok[np.flatnonzero(first)[has_prev]] = chained[fm[has_prev]]
    q_end = pa + per * np.round((q_prev - pa) / per) if npc else pa
    with np.errstate(invalid="ignore"):
        q_step = np.abs(q_end - q_prev)
        q_cand = np.flatnonzero(q_ok & np.isfinite(q_step) & (q_step > 1e-9)
                                & (q_step <= options.fold_max))
    m = q_cand.size
    if cand.size + m == 0:
        return fold, piece_fold
    mv = pm[q_cand]
    d = take_rows(p1, mv) - take_rows(p0, mv)
    a0 = take_rows(p0, mv) + pt0[q_cand][:, None] * d
    a1 = take_rows(p0, mv) + pt1[q_cand][:, None] * d
    ok = turning_fits(ctx.target, ctx.pieces, np.concatenate([take_rows(p0, cand), a0]),
                      np.concatenate([take_rows(p1, cand), a1]),
                      np.concatenate([prev_a[cand], q_prev[q_cand]]),
                      np.concatenate([a_end[cand], q_end[q_cand]]), workers=ctx.workers)
    fold[cand] = ok[:cand.size]
    piece_fold[q_cand] = ok[cand.size:]
    return fold, piece_fold


def _longest_piece(pm: np.ndarray, span: np.ndarray) -> np.ndarray:
    """Per piece row (rows sorted by move ``pm``), the row of its move's longest piece
    (the first of equals). O(rows)."""
    npc = len(pm)
    lo = np.flatnonzero(np.concatenate([[True], pm[1:] != pm[:-1]]))
    best = lo + np.array([int(np.argmax(span[a:b])) for a, b in
                          zip(lo.tolist(), [*lo[1:].tolist(), npc], strict=True)], np.int64)
    return np.repeat(best, np.diff(np.append(lo, npc)))


def align_pieces(ctx: PlanContext, rows: tuple) -> tuple:
    """The pieces of each split move next to its longest one take that one's orientation
    where it fits there and lays a width no further from the plan (``width_slack``) than
    their own: no turn between them then (and contiguous ones are joined into one).

    The split searches each stretch on its own, cheapest first, and the short pieces next
    to a corner end up at a grid orientation a few degrees from the long piece's.
    """
    p0, p1, direction, widths, per = ctx.p0, ctx.p1, ctx.direction, ctx.widths, ctx.per
    pm, t0, t1, pa = rows
    npc = len(pm)
    if npc < 2:
        return rows
    anchor = _longest_piece(pm, t1 - t0)
    r = np.arange(npc)
    near = (np.abs(r - anchor) == 1)
    target_a = pa[anchor]
    diff = np.abs((pa - target_a + per / 2) % per - per / 2)
    cand = np.flatnonzero(near & (diff > 1e-9))
    if cand.size == 0:
        return rows
    table_b = np.append(ctx.beta, 360.0)
    table_w = np.append(ctx.wtab, ctx.wtab[0])
    m = pm[cand]
    w_plan = widths[m]

    def werr(phi):
        w = np.interp(np.mod(phi - direction[m], 360.0), table_b, table_w)
        return np.where(np.isnan(w_plan), 0.0, np.abs(w - np.nan_to_num(w_plan)))

    ok_w = werr(target_a[cand]) <= werr(pa[cand]) + ctx.options.width_slack
    cand = cand[ok_w]
    if cand.size == 0:
        return rows
    m = pm[cand]
    d = p1[m] - p0[m]
    a = p0[m] + t0[cand][:, None] * d
    b = p0[m] + t1[cand][:, None] * d
    ok = fp.fits(ctx.target, ctx.pieces, a, b, target_a[cand], workers=ctx.workers)
    if not ok.any():
        return rows
    pa = pa.copy()
    pa[cand[ok]] = target_a[cand[ok]]
    return merge_pieces(pm, t0, t1, pa)


def drop_side_pieces(ctx: PlanContext, rows: tuple) -> tuple:
    """Leave out the short pieces of split moves that need a turn of their own.

    At a convex corner of an outer wall an elongated orifice laying the planned width
    pokes out of the part for a few tenths of a millimetre on either side; the split then
    finds, for those ends, other orientations (narrower, along the motion) that still fit,
    and the nozzle turns there and back: two or three turns per corner, each a full stop
    of the XY motion on real firmware, for a fleck of material (the calibration cube on a
    360 °/s axis: 0.6 s per corner, 40 % more print time). A piece other than its move's
    longest, at another orientation than that one, and at most
    ``options.side_piece_widths`` planned bead widths long is dropped (its length is
    reported as lost, like every dropped length); 0 keeps them all.
    """
    p0, p1, per = ctx.p0, ctx.p1, ctx.per
    k = ctx.options.side_piece_widths
    pm, t0, t1, pa = rows
    npc = len(pm)
    if k <= 0 or npc < 2:
        return rows
    span = t1 - t0
    anchor = _longest_piece(pm, span)
    length = span * np.hypot(*(p1[pm] - p0[pm]).T)
    w = np.asarray(ctx.widths, dtype=float)[pm]
    limit = k * np.where(np.isfinite(w), w, 0.0)
    turned = np.abs((pa - pa[anchor] + per / 2) % per - per / 2) > 1e-6
    keep = ~(turned & (length <= limit) & (np.arange(npc) != anchor))
    if keep.all():
        return rows
    return (pm[keep], t0[keep], t1[keep], pa[keep])


def smooth(ctx: PlanContext, angle: np.ndarray, searched: np.ndarray, c1: np.ndarray,
           c2: np.ndarray, *, previous: float, machine: Machine) -> np.ndarray:
    """Second pass: turn least given the orientations the search replaced.

    The preferred orientations were chained assuming every move fits; where
    the search replaced one, the next moves may now be nearer to the other
    solution of the same width. Proposals are re-tested together and kept
    only where they fit; an equivalent orientation (a multiple of the period
    away) needs no test.
    """
    per, scale = ctx.per, ctx.scale
    n = len(angle)
    is_searched = np.zeros(n, dtype=bool)
    is_searched[np.asarray(searched, dtype=np.int64)] = True
    reach = machine.has_rotary and not machine.covers_period(per)
    prop = smooth_chain(np.asarray(angle, dtype=float), np.asarray(c1, dtype=float),
                        np.asarray(c2, dtype=float), is_searched, bool(reach), float(per),
                        float(previous))
    diff = np.abs((prop - angle + per / 2) % per - per / 2)
    test = np.flatnonzero(np.isfinite(prop) & (diff > 1e-6))
    out = np.where(np.isfinite(prop), prop, angle)
    if test.size:
        ok = fp.fits(ctx.target, ctx.pieces, take_rows(ctx.p0, test), take_rows(ctx.p1, test),
                     prop[test], scale=None if scale is None else scale[test],
                     workers=ctx.workers)
        keep = test[~ok]
        # a rejected proposal keeps its old orientation, unwrapped near its neighbour
        out[keep] = angle[keep]
    return out


def other_solution(pick: np.ndarray, c1: np.ndarray, c2: np.ndarray, per: float,
                   machine: Machine) -> np.ndarray:
    """Per move, the orientation laying the planned width that the chain did not pick
    (``c1`` or ``c2``, unwrapped near ``pick``); ``pick`` itself where there is one only
    or the other is out of the axis' reach."""
    d1 = np.abs(np.mod(pick - c1 + per / 2, per) - per / 2)
    d2 = np.abs(np.mod(pick - c2 + per / 2, per) - per / 2)
    raw = np.where(d1 <= d2, c2, c1)
    alt = raw + per * np.round((pick - raw) / per)
    same = np.minimum(d1, d2) > 1e-9  # the pick is neither (out of reach: clipped)
    same |= np.abs(np.mod(alt - pick + per / 2, per) - per / 2) < 1e-9
    if machine.has_rotary and not machine.covers_period(per):
        same |= ~reachable(alt, machine, per)
    return np.where(same, pick, alt)

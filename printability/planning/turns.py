"""Turning the nozzle while it moves: the fit test of a turning footprint and the
least-turning pass of the orientation planner.

A turn standing still is a full stop of the XY motion on real firmware (Klipper plans a
move with no XYZ motion as its own, with zero junction speeds around it), so the planner
(:func:`printability.planning.orientation.plan_orientations`) picks, per path, the admissible
orientations that turn least (:func:`least_turning`, a Viterbi pass over candidates), and
makes a turn during a move where the footprint turning along it still fits
(:func:`turning_fits`: the MMC promise is the same test as for every orientation).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from printability.base.arrays import take_rows
from printability.planning import footprints as fp
from printability.planning._plan_kernels import chain_viterbi, distinct_candidates, fold_pairs

if TYPE_CHECKING:
    from printability.planning.plan import PlanContext

__all__ = ["TURN_STEP", "least_turning", "turning_fits"]


#: the largest turn (degrees) :func:`turning_fits` tests in one step
TURN_STEP = 5.0


def turning_fits(target, pieces, a, b, phi0, phi1, *, workers=1):
    """Whether the nozzle moving from ``a`` to ``b`` while turning from ``phi0`` to ``phi1``
    (both linear in time) deposits inside ``target``.

    :func:`fits` bounds a turning footprint by the hull of its two ends grown by
    1/cos(turn/2) (1.5 % for 20°: more than the tolerance on a 0.8 mm orifice, so a turn
    next to the target's edge never fitted). Here a turn of more than :data:`TURN_STEP`
    is cut into equal steps of the move and the turn, each tested so: the steps cover
    the motion, and each bound contains its step's footprints, so the test stays an
    outer one, only tighter (1/cos(2.5°): 0.1 %).
    """
    n = len(a)
    if n == 0:
        return np.ones(0, dtype=bool)
    turn = np.abs(np.asarray(phi1, float) - np.asarray(phi0, float))
    m = np.maximum(1, np.ceil(turn / TURN_STEP - 1e-9)).astype(np.int64)
    if np.all(m == 1):
        return fp.fits(target, pieces, a, b, phi0, angle_end=phi1, workers=workers)
    row = np.repeat(np.arange(n), m)
    lo = np.repeat(np.cumsum(m) - m, m)
    k = np.arange(row.size) - lo  # step within its row
    mr = m[row].astype(float)
    t0 = k / mr
    t1 = (k + 1) / mr
    d = b - a
    s0 = a[row] + t0[:, None] * d[row]
    s1 = np.where((k + 1 == m[row])[:, None], b[row], a[row] + t1[:, None] * d[row])
    f0 = phi0[row] + t0 * (phi1 - phi0)[row]
    f1 = np.where(k + 1 == m[row], phi1[row], phi0[row] + t1 * (phi1 - phi0)[row])
    ok = fp.fits(target, pieces, s0, s1, f0, angle_end=f1, workers=workers)
    return np.logical_and.reduceat(ok, np.cumsum(m) - m)


#: a width error (mm) below which :func:`least_turning` counts an orientation as laying
#: the planned width
_EXACT = 2e-3
#: moves no longer than this (mm: arc chords, the links of a zigzag) may lay a width up to
#: _SHORT_SLACK (mm) from the plan in :func:`least_turning` (E follows the width laid)
_SHORT = 1.0
_SHORT_SLACK = 0.1
#: moves no longer than this fraction of their planned width may lay any width (see
#: :func:`least_turning`), their width error weighed by their own length
_TINY = 0.5
#: what :func:`least_turning` counts a turn made standing still (a full stop of the XY
#: motion on real firmware) and a reversal of the turning sense along a path as, in
#: degrees of turn
_STOP = 60.0
_REVERSE = 20.0
#: orientations relative to the motion among :func:`least_turning`'s candidates, degrees
_RELATIVE = np.arange(-90.0, 90.0, 5.0)
#: rounds of :func:`least_turning`'s Viterbi pass testing the turns its path makes while moving
_FOLD_ROUNDS = 12


def least_turning(angle: np.ndarray, rows: tuple, c1: np.ndarray, c2: np.ndarray,
                  ctx: PlanContext, previous: float, chained: np.ndarray | None, *,
                  interior: np.ndarray | None = None) -> np.ndarray:
    """Third pass: the admissible orientations that turn least along each path.

    The chain and the search pick move by move, each near the previous pick: along a
    path they alternate between the two orientations laying the planned width (±θ to
    the motion) and between grid orientations on either side of the motion, and every
    turn they cannot make during a move is made standing still, rocking the axis (the
    shared PrusaSlicer screw: 22 637 rotation-only lines, 16 746 reversals). Here every
    whole move gets candidates: its orientation, the two laying the planned width, the
    search's grid (``search_step``) and orientations at fixed angles to the motion
    (:data:`_RELATIVE`), kept where they lay a width no further from the plan than its
    own orientation or ``width_slack`` (a move laying the planned width: only those
    laying it; a short move, :data:`_SHORT`: up to :data:`_SHORT_SLACK`) and where they
    fit (the same test as every orientation: the MMC promise is unchanged); a split
    move keeps its pieces. A Viterbi pass (:func:`chain_viterbi`) then picks per path
    the candidates costing least: a turn between chained moves costs its size, plus
    :data:`_STOP` unless it can be made during the move or, into a split move, its
    first piece (the test ``Plan.fold`` is made with, on the pairs of candidates at most
    ``fold_max`` apart that the pass's path takes, in rounds), plus
    :data:`_REVERSE` where it turns back; across a travel a quarter of its size; a
    width error as 10° of turn per ``width_slack`` and mm of move (at least 1 mm).
    An ``interior`` move (inner walls, infill) counts only a bead narrower than planned
    as an error: it may lie wider wherever that fits, which lets a zigzag of infill keep
    one orientation through its 90° and 180° changes of direction.
    Only for an axis that reaches every orientation.
    """
    whole = np.isfinite(angle)
    if not whole.any():
        return angle
    cols, keep, err, weight = _candidates(angle, c1, c2, ctx, interior)
    cand_in = np.where(keep, cols, np.nan)
    cand_out = cand_in.copy()
    # a split move: its pieces, fixed (first and last)
    pm, _, _, pa = rows
    first = np.zeros(0, bool)
    if pm.size:
        first = np.searchsorted(pm, pm, "left") == np.arange(pm.size)
        last = np.append(pm[1:] != pm[:-1], True)
        cand_in[pm[first], 0] = pa[first]
        cand_out[pm[last], 0] = pa[last]
    cost = np.where(keep, 10.0 * weight[:, None] * err / max(ctx.options.width_slack, 1e-9),
                    0.0)
    folds = _fold_table(cand_in, cand_out, chained, ctx.per, ctx.options)
    # where the turn into each move is made: along the move, or its first piece
    ta, tb = ctx.p0, ctx.p1
    if pm.size:
        ta, tb = ctx.p0.copy(), ctx.p1.copy()
        fm = pm[first]
        d = ctx.p1[fm] - ctx.p0[fm]
        ta[fm] = ctx.p0[fm] + rows[1][first][:, None] * d
        tb[fm] = ctx.p0[fm] + rows[2][first][:, None] * d
    cand_in = np.ascontiguousarray(cand_in)
    cand_out = np.ascontiguousarray(cand_out)
    pick = _cheapest_path(cand_in, cand_out, np.ascontiguousarray(cost), folds, ctx, (ta, tb))
    out = angle.copy()
    prev = previous
    per = ctx.per
    for i in range(len(angle)):
        c = pick[i]
        if c < 0:
            continue
        if whole[i]:
            a = cols[i, c]
            out[i] = a + per * round((prev - a) / per)
            prev = out[i]
        else:
            prev = cand_out[i, 0]
    return out


def _candidates(angle, c1, c2, ctx, interior):
    """Per whole move, the orientations :func:`least_turning` may pick, leftmost (its own
    first), in as few columns as hold them: ``(cols, keep, err, weight)``, the
    orientations, which are kept (they lay a width allowed and fit), their width errors,
    and the weight of a width error per move."""
    direction, widths, per, options = ctx.direction, ctx.widths, ctx.per, ctx.options
    n = len(angle)
    whole = np.isfinite(angle)
    grid = np.arange(0.0, per, options.search_step)
    cols = np.column_stack([angle, c1, c2, direction[:, None] + _RELATIVE[None, :],
                            np.broadcast_to(grid, (n, grid.size))])
    table_b = np.append(ctx.beta, 360.0)
    table_w = np.append(ctx.wtab, ctx.wtab[0])

    def werr(phi):
        w = np.interp(np.mod(phi - direction[:, None], 360.0), table_b, table_w)
        short = np.nan_to_num(widths)[:, None] - w  # > 0: narrower than planned
        # an interior bead may lie wider than planned: only narrower is an error
        off = np.where(interior[:, None], np.maximum(short, 0.0), np.abs(short)) \
            if interior is not None else np.abs(short)
        return np.where(np.isnan(widths)[:, None], 0.0, off)

    err = werr(cols)
    own = err[:, 0]
    # a move laying the planned width keeps to the orientations laying it (to within the
    # table's interpolation); another one to those no further from the plan than its own
    # orientation or ``width_slack``
    length = np.hypot(*(ctx.p1 - ctx.p0).T)
    allowed = np.where(length <= _SHORT, np.maximum(own, _SHORT_SLACK),
                       np.where(own <= _EXACT, _EXACT, np.maximum(own, options.width_slack)))
    # a move no longer than half its planned width is mostly the footprint's own cap: the
    # width it lays along its length means nothing, any orientation that fits will do (on
    # the calibration cube, links of 20-50 µm at the ends of infill lines each cost a 36°
    # turn standing still)
    tiny = length <= _TINY * np.nan_to_num(widths, nan=0.0)
    allowed = np.where(tiny, np.inf, allowed)
    keep = whole[:, None] & (err <= allowed[:, None] + 1e-9)
    # the same orientation twice (modulo the period) is tested once
    distinct_candidates(np.ascontiguousarray(np.mod(cols, per)), keep, float(per))
    test = keep.copy()
    test[:, 0] = False  # the move's own orientation fits already
    mv, col = np.nonzero(test)
    if mv.size:
        ok = fp.fits(ctx.target, ctx.pieces, take_rows(ctx.p0, mv), take_rows(ctx.p1, mv),
                     cols[mv, col], scale=None if ctx.scale is None else ctx.scale[mv],
                     workers=ctx.workers)
        keep[mv[~ok], col[~ok]] = False
    # the candidates kept, leftmost (the move's own first), in as few columns as hold them
    order = np.argsort(~keep, axis=1, kind="stable")[:, :max(1, int(keep.sum(axis=1).max()))]
    weight = np.where(tiny, length, np.maximum(length, 1.0))
    return (np.take_along_axis(cols, order, axis=1), np.take_along_axis(keep, order, axis=1),
            np.take_along_axis(err, order, axis=1), weight)


def _cheapest_path(cand_in, cand_out, cost, folds, ctx, ends):
    """:func:`chain_viterbi`'s pick per move, the turns during a move on its path tested
    (``folds`` updated), the turn into each move made from ``ends`` (its start and end, or
    its first piece's)."""
    ta, tb = ends
    per, target, pieces, workers = ctx.per, ctx.target, ctx.pieces, ctx.workers
    params = np.array([per, _STOP, 0.25, _REVERSE])
    # The turns during a move are tested where the path takes them only: the pass counts
    # an untested one as made while moving (it can cost no less), so once every turn of
    # the cheapest path has been tested, that path is the cheapest with every turn tested
    # (each round tests a path's worth, a few thousand; testing every pair, millions, cost
    # the shared screw sample 2 s). With the moves whose turn failed tested whole, the
    # screw takes 4 rounds per batch; after _FOLD_ROUNDS a turn still untested on the path
    # would only be mis-priced: ``Plan.fold`` is tested on its own (``fold_flags``).
    for r in range(_FOLD_ROUNDS + 1):
        pick = chain_viterbi(cand_in, cand_out, cost, folds, params)
        i = np.flatnonzero((pick[1:] >= 0) & (pick[:-1] >= 0)) + 1
        i = i[folds[i, pick[i - 1], pick[i]] == 3]
        if i.size == 0 or r == _FOLD_ROUNDS:
            break
        _test_folds(folds, cand_in, cand_out, per, target, pieces, ta, tb, workers,
                    at=(i, pick[i - 1], pick[i]))
        # where the path's turn cannot be made while moving, the others of that move are
        # likely not to either: all tested at once, rather than a round for each
        bad = i[folds[i, pick[i - 1], pick[i]] == 1]
        if bad.size:
            b_i, b_j, b_c = np.nonzero(folds[bad] == 3)
            _test_folds(folds, cand_in, cand_out, per, target, pieces, ta, tb, workers,
                        at=(bad[b_i], b_j, b_c))
    return pick


def _fold_table(cand_in, cand_out, chained, per, options):
    """Per move and pair of candidates (previous move's j, its c), as
    :func:`chain_viterbi` reads them: 0 after a travel, 1 chained, 3 where the turn from
    j to c (at most ``fold_max``; into a whole move or a split one's first piece) may be
    made during the move: not tested yet (:func:`_test_folds` makes it 2 where it can, 1
    where it cannot)."""
    if chained is None:
        return np.zeros((*cand_in.shape, cand_in.shape[1]), np.uint8)
    # a split move's candidates are its pieces (NaN where it has none: no pair)
    return fold_pairs(np.ascontiguousarray(cand_in, dtype=float),
                      np.ascontiguousarray(cand_out, dtype=float),
                      np.ascontiguousarray(chained, dtype=bool), float(per),
                      float(options.fold_max))


def _test_folds(folds, cand_in, cand_out, per, target, pieces, p0, p1, workers, *, at=None):
    """Test the turns during a move that ``folds`` marks untested (3), or those at ``at``
    (moves, previous candidates, candidates): the test :func:`plan_orientations` makes for
    ``Plan.fold`` (:func:`turning_fits`); 2 where it can be made, else 1."""
    i, j, c = np.nonzero(folds == 3) if at is None else at
    if i.size:
        x = cand_out[i - 1, j]
        y = cand_in[i, c]
        ok = turning_fits(target, pieces, take_rows(p0, i), take_rows(p1, i), x,
                           y + per * np.round((x - y) / per), workers=workers)
        folds[i, j, c] = np.where(ok, 2, 1)

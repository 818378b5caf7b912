"""The orientation searches of :mod:`printability.planning.orientation`: grid orientations in
order of cost, and the split of the moves that fit whole at none.

:func:`search_ordered` tries each move's candidates (a grid of orientations, unwrapped
near the previous move's) cheapest first (:func:`cost_order`: the width error over the
slack plus the turn over 30°); :func:`split_many` keeps what fits of the moves that
fit nowhere: the longest middle at the exact-width orientations or the grid's two
cheapest (:func:`_first_intervals`), then the rest searched whole and in pieces. Both
decide every footprint with :mod:`printability.planning.footprints`; their shortcuts
change no answer (monotonicity: a footprint holds the footprint of any part of its
move).

Angles in degrees; parameters along a move as fractions of it.
"""

from __future__ import annotations

import numpy as np

from printability.base.arrays import take_rows
from printability.planning import footprints as fp
from printability.planning._plan_kernels import merge_pieces, points_along, split_intervals
from printability.planning.plan import PlanContext

__all__ = ["cost_order", "search_ordered", "split_many", "tried_counts"]


def _cost_terms(direction, widths, prev, cands, beta, wtab, per):
    phis = direction[:, None] * 0 + cands[None, :]
    rel = np.mod(phis - direction[:, None], 360.0)
    w = np.interp(rel, np.append(beta, 360.0), np.append(wtab, wtab[0]))
    werr = np.where(np.isnan(widths)[:, None], 0.0,
                    np.abs(w - np.where(np.isnan(widths), 0.0, widths)[:, None]))
    near = phis + per * np.round((prev[:, None] - phis) / per)
    turn = np.abs(near - prev[:, None])
    return near, werr, turn


def cost_order(direction, widths, prev, cands, beta, wtab, per, options):
    """Per move, its candidates unwrapped near ``prev`` and their order of cost: the width
    error over ``width_slack`` plus the turn from ``prev`` over 30° (a 30° turn weighs as
    much as a width error of ``width_slack``)."""
    near, werr, turn = _cost_terms(direction, widths, prev, cands, beta, wtab, per)
    key = werr / max(options.width_slack, 1e-9) + turn / 30.0
    return near, np.argsort(key, axis=1, kind="stable")


def search_ordered(target, pieces, p0, p1, near, order, scale=None, limit=None, fast=True, *,
                   workers=1):
    """Per move, the first of its candidates ``near`` that fits, in their ``order`` of cost
    (at most ``limit`` per move, in rounds of 4, 4 and the rest: :func:`tried_counts`).

    Returns
    -------
    found : bool array
    best : orientation per move (NaN where none fits)
    """
    k = len(p0)
    found = np.zeros(k, dtype=bool)
    best = np.full(k, np.nan)
    if k == 0:
        return found, best
    ncand = near.shape[1]
    count = tried_counts(np.full(k, ncand) if limit is None else np.asarray(limit), ncand)
    if fast and fp._fused(pieces):
        # the rounds only bounded the wasted tests: the first candidate that fits, in
        # order, is the one they find, and the kernel stops there
        phis = np.take_along_axis(near, order, axis=1)[np.arange(ncand)[None, :]
                                                       < count[:, None]]
        gend = np.cumsum(count)
        first = fp._first_fit(target, pieces, (p0, p1, scale), np.repeat(np.arange(k), count),
                              phis, gend - count, gend, workers=workers)
        found = first >= 0
        best[found] = phis[first[found]]
        return found, best
    for start, stop in ((0, min(4, ncand)), (min(4, ncand), min(8, ncand)), (min(8, ncand), ncand)):
        todo = np.flatnonzero(~found & (count > start))
        if todo.size == 0 or stop <= start:
            continue
        cols = order[todo, start:stop]  # (t, s)
        rows = np.repeat(todo, cols.shape[1])
        phis = near[rows, cols.ravel()]
        ok = fp.fits(target, pieces, p0[rows], p1[rows], phis,
                  scale=None if scale is None else scale[rows], fast=fast).reshape(cols.shape)
        hit = ok.any(axis=1)
        first = np.argmax(ok, axis=1)
        sel = todo[hit]
        best[sel] = near[sel, cols[hit, first[hit]]]
        found[sel] = True
    return found, best


def tried_counts(limit: np.ndarray, ncand: int) -> np.ndarray:
    """How many candidates :func:`search_ordered` tries per move under ``limit``: the
    cheapest first, in rounds of 4, 4 and the rest, a move taking part in the rounds that
    start below its limit (a move it finds nothing for was refused at all of them)."""
    count = np.zeros(len(limit), dtype=np.int64)
    for start, stop in ((0, min(4, ncand)), (min(4, ncand), min(8, ncand)),
                        (min(8, ncand), ncand)):
        if stop > start:
            count = np.where(limit > start, stop, count)
    return count


def _first_intervals(target, pieces, q0, q1, sc_iv, iv_mv, ivpos, tops, fast, *, workers=1):
    """Per move with intervals (:func:`split_intervals`: intervals ``q0 → q1`` of moves
    ``iv_mv``, CSR ``ivpos``), the interval to keep and its orientation: the first set
    of orientations of ``tops`` ((n, 2) each, in order) at which some interval fits,
    and in that set the longest interval that fits (intervals by decreasing span, then
    generation order, each at the set's orientations in turn). Returns the interval
    per move (-1: none fits) and its orientation.

    A move's last interval, trimmed most at both ends, lies inside every other one, and a
    footprint holds the footprint of any part of its move: where that interval fits at
    none of a set's orientations, no interval does. It is tried first, at every
    orientation of every set in one pass; a set is then searched only for the moves
    whose first fit there is in it, up to that interval (then the answer if nothing
    longer fits).
    """
    nm = len(ivpos) - 1
    ncol = sum(t.shape[1] for t in tops)
    allcols = np.ascontiguousarray(np.column_stack(tops), dtype=float)
    col_set = np.repeat(np.arange(len(tops)), [t.shape[1] for t in tops])
    cand_iv = np.repeat(np.arange(iv_mv.size), ncol)
    phis = take_rows(allcols, iv_mv).reshape(-1)
    gpos = ivpos[:-1] * ncol
    gend = ivpos[1:] * ncol
    best_iv = np.full(nm, -1, np.int64)
    best_phi = np.full(nm, np.nan)
    if not (fast and fp._fused(pieces)):
        # the reference: every set in turn over every interval of the moves still without
        # one, each candidate through shapely
        lo = 0
        for t in tops:
            hi = lo + t.shape[1]
            mv = np.flatnonzero(best_iv < 0)
            cand, ends = _set_candidates(ivpos, mv, 0, lo, hi, ncol)
            first = fp._first_fit_reference(target, pieces, q0, q1, sc_iv, cand_iv[cand],
                                            phis[cand], ends - np.diff(ends, prepend=0), ends,
                                            fast=fast)
            ok = first >= 0
            best_iv[mv[ok]] = cand_iv[cand[first[ok]]]
            best_phi[mv[ok]] = phis[cand[first[ok]]]
            lo = hi
        return best_iv, best_phi
    # cos/sin of each move's orientations, once, gathered per candidate
    rad = np.deg2rad(allcols)
    trig = (take_rows(np.cos(rad), iv_mv).reshape(-1), take_rows(np.sin(rad), iv_mv).reshape(-1))
    inner = gend - ncol
    probe = fp._first_fit(target, pieces, (q0, q1, sc_iv), cand_iv, phis, inner, gend,
                          trig=trig, workers=workers)
    lo = 0
    for k, t in enumerate(tops):
        hi = lo + t.shape[1]
        mv = np.flatnonzero((probe >= 0) & (col_set[(probe - inner) % ncol] == k))
        first = probe[mv]
        # the set's orientations over the longer intervals, the groups holding those
        # candidates only: candidate c of interval v is v·ncol + c
        rows = np.flatnonzero(inner[mv] > gpos[mv])
        if rows.size:
            cand, ends = _set_candidates(ivpos, mv[rows], 1, lo, hi, ncol)
            outer = fp._first_fit(target, pieces, (q0, q1, sc_iv), cand_iv[cand], phis[cand],
                                  ends - np.diff(ends, prepend=0), ends,
                                  trig=(trig[0][cand], trig[1][cand]), workers=workers)
            first[rows] = np.where(outer >= 0, cand[np.maximum(outer, 0)], first[rows])
        best_iv[mv] = cand_iv[first]
        best_phi[mv] = phis[first]
        lo = hi
    return best_iv, best_phi


def _set_candidates(ivpos, mv, drop_last, lo, hi, ncol):
    """The candidates (interval v at column c: v·ncol + c) of moves ``mv``: their intervals
    (all but the last ``drop_last``) at columns ``lo … hi - 1``, by move, then interval,
    then column; and where each move's run ends (CSR ends)."""
    n_iv = np.maximum(ivpos[mv + 1] - ivpos[mv] - drop_last, 0)
    iv_of = np.repeat(ivpos[mv], n_iv) + (np.arange(n_iv.sum())
                                          - np.repeat(np.cumsum(n_iv) - n_iv, n_iv))
    cand = (iv_of[:, None] * ncol + np.arange(lo, hi)[None, :]).ravel()
    return cand, np.cumsum(n_iv * (hi - lo))


def split_many(ctx: PlanContext, prev: np.ndarray, cands: np.ndarray, *, fast: bool = True,
               ordered: tuple | None = None, tried: np.ndarray | None = None,
               exact: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Keep the parts of the moves of ``ctx`` that fit somewhere; drop the rest (all moves
    at once).

    A move usually fails because one end pokes out at a corner: first the
    longest sub-interval that fits at one of the two orientations laying the planned
    width (``exact``), or else at one of the grid's two cheapest, is
    found among intervals trimmed at the start, the end or both by
    geometrically growing lengths; each trimmed-off part is then searched
    whole at every orientation and, where nothing fits, cut into pieces of
    twice ``ctx.step`` searched again, and what still fits nowhere halved once
    more (pieces down to ``ctx.step``). A few vectorised searches in all,
    whatever the number of moves. ``ordered`` is :func:`cost_order`'s answer for these
    moves when already known (only where ``prev`` has no NaN: here a NaN counts as 0), and
    ``tried`` (with it) how many of each move's first candidates in that order the whole
    move was already refused at: a move nothing is kept of starts its search after them.

    Returns the pieces as arrays ``(move, t0, t1, angle)`` by move (:attr:`Plan.piece_rows`;
    a move with no row is dropped).
    """
    target, pieces, a, b, scale = ctx.target, ctx.pieces, ctx.p0, ctx.p1, ctx.scale
    workers = ctx.workers
    n = len(a)
    step = ctx.step
    ba = b - a
    length = np.hypot(*ba.T)
    if ordered is None or np.isnan(prev).any():
        prev = np.where(np.isnan(prev), 0.0, prev)
        near, order_all = cost_order(ctx.direction, ctx.widths, prev, cands, ctx.beta,
                                     ctx.wtab, ctx.per, ctx.options)
        tried = None  # another order: what was refused is not its first candidates
    else:
        near, order_all = ordered
    # the kept middle interval of every move (none: t1 <= t0)
    keep_t0 = np.zeros(n)
    keep_t1 = np.zeros(n)
    keep_phi = np.full(n, np.nan)
    # candidate intervals per move: trimmed by d = step/length, 2d, 4d… (d < 1/2) at the
    # start, the end or both; each at a few orientations: the two laying the planned
    # width (``exact``, (n, 2)) first, then, where no interval fits at them, the two
    # cheapest of the grid
    iv_mv, iv_t0, iv_t1, moves, ivpos = split_intervals(length, float(step))
    if iv_mv.size:
        q0 = points_along(a, ba, iv_mv, iv_t0)
        q1 = points_along(a, ba, iv_mv, iv_t1)
        sc_iv = None if scale is None else scale[iv_mv]
        grid_top = np.take_along_axis(near, order_all[:, :2], axis=1)
        iv, phi = _first_intervals(target, pieces, q0, q1, sc_iv, iv_mv, ivpos,
                                   ([] if exact is None else [exact]) + [grid_top], fast,
                                   workers=workers)
        hit = iv >= 0
        keep_t0[moves[hit]] = iv_t0[iv[hit]]
        keep_t1[moves[hit]] = iv_t1[iv[hit]]
        keep_phi[moves[hit]] = phi[hit]
    kept = keep_t1 > keep_t0
    # the pieces found, as arrays (move, t0, t1, angle) in the order found, until merged
    found_l = [(np.flatnonzero(kept), keep_t0[kept], keep_t1[kept], keep_phi[kept])]
    # what is left of every move: each part searched whole at every orientation; a part
    # that fits nowhere is cut (down to `step`) and searched again. A part's candidates
    # and their order are its move's (they depend on the direction, width and previous
    # orientation only). Parts by move, then position: the whole move where nothing was
    # kept, else the parts before and after the kept interval.
    ra_all = np.stack([np.zeros(n), np.where(kept, keep_t1, 2.0)], axis=1)
    rb_all = np.stack([np.where(kept, keep_t0, 1.0), np.where(kept, 1.0, 2.0)], axis=1)
    part = (rb_all - ra_all > 1e-12) & (ra_all < 2.0)
    ncand = near.shape[1]
    # every candidate of every move, in order, with its cos/sin: the parts index them
    near_ord = np.take_along_axis(near, order_all, axis=1).ravel()
    rad = np.deg2rad(near_ord)
    trig = (np.cos(rad), np.sin(rad))
    idx = np.repeat(np.arange(n), 2).reshape(n, 2)[part]
    ta = ra_all[part]
    tb = rb_all[part]
    # a whole move (nothing kept) skips the candidates it was refused at already
    skip = np.zeros(idx.size, np.int64) if tried is None else \
        np.where(kept[idx], 0, np.minimum(np.asarray(tried, np.int64)[idx], ncand))
    while idx.size:
        q0 = points_along(a, ba, idx, ta)
        q1 = points_along(a, ba, idx, tb)
        if fast and fp._fused(pieces) and ncand:
            # no limit: a part tries all its move's candidates, in order
            first = fp._first_fit(target, pieces,
                                  (q0, q1, None if scale is None else scale[idx]), None,
                                  near_ord, idx * ncand + skip, idx * ncand + ncand,
                                  gseg=np.arange(idx.size), trig=trig, workers=workers)
            found = first >= 0
            best = np.where(found, near_ord[first], np.nan)
        else:
            found, best = search_ordered(target, pieces, q0, q1, near[idx], order_all[idx],
                                         None if scale is None else scale[idx], fast=fast,
                                         workers=workers)
        found_l.append((idx[found], ta[found], tb[found], best[found]))
        # the rest, straight to pieces of 2·`step` (smaller pieces fit more easily), cut as
        # np.linspace(ra, rb, m + 1) cuts them; a part or piece of at most 2·`step` that
        # fits nowhere is halved once more, down to `step` (an end at a corner, a short
        # move: on the sample parts a fifth to a third less length is dropped)
        span = length[idx] * (tb - ta)
        rest = ~found & (span > step * 1.000001)
        i_r, ra, rb = idx[rest], ta[rest], tb[rest]
        span = span[rest]
        m = np.where(span > 2 * step * 1.000001, np.ceil(span / (2 * step)), 2).astype(np.int64)
        delta = (rb - ra) / m
        which = np.repeat(np.arange(m.size), m)
        q = (np.arange(which.size) - np.repeat(np.cumsum(m) - m, m)).astype(float)
        idx = i_r[which]
        ta = q * delta[which] + ra[which]
        tb = (q + 1.0) * delta[which] + ra[which]
        last = np.cumsum(m) - 1
        tb[last] = rb
        skip = np.zeros(idx.size, np.int64)
    # sorted by start and joined where adjacent at the same orientation (compiled: a
    # Python loop per piece cost more than the searches)
    pm, pa, pb, pp = merge_pieces(*(np.concatenate([f[c] for f in found_l]).astype(t)
                                    for c, t in enumerate((np.int64, float, float, float))))
    return pm, pa, pb, pp



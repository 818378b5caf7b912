"""Compiled steps of the orientation planner (:mod:`printability.planning.orientation`)
that are not footprint tests: chaining the preferred orientations, picking each planned
width's relative orientations, listing a split's candidate intervals and merging the
pieces found.

Angles in degrees; fractions ``t`` of a move in [0, 1]. The footprint tests themselves
are in :mod:`printability.planning.fastfit`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["chain_nearest", "chain_viterbi", "distinct_candidates", "fold_pairs", "merge_pieces",
           "piece_losses", "points_along", "smooth_chain", "split_intervals", "width_picks"]


@numba.njit(cache=True)
def chain_nearest(c1, c2, per, previous):  # pragma: no cover
    """Per move, of ``c1``, ``c2``, ``c1 + 180``, ``c2 + 180`` the equivalent nearest the last pick.

    The sequential loop of
    :func:`printability.planning.orientation.preferred_orientations` for an
    unlimited axis, compiled (a Python loop per move cost more than the rest
    of the planning); ``np.rint`` rounds half to even like Python's ``round``,
    so the picks are the same.
    """
    n = len(c1)
    out = np.empty(n)
    prev = previous
    for i in range(n):
        best = 0.0
        first = True
        for q in range(4):
            c = c1[i] if q == 0 else c2[i] if q == 1 else c1[i] + 180.0 if q == 2 \
                else c2[i] + 180.0
            near = c + per * np.rint((prev - c) / per)
            if first or abs(near - prev) < abs(best - prev):
                best = near
                first = False
        out[i] = best
        prev = best
    return out


@numba.njit(cache=True)
def smooth_chain(angle, c1, c2, searched, reach, per, previous):  # pragma: no cover
    """The proposals of :func:`printability.planning._passes.smooth`, compiled.

    Per move (NaN moves skipped and kept): a searched move's orientation (or any, on
    a limited axis) unwrapped nearest the last pick; otherwise, of ``c1`` and ``c2``,
    the equivalent nearest it. ``np.rint`` rounds half to even like Python's
    ``round``, so the picks are those of the Python loop.
    """
    n = len(angle)
    prop = angle.copy()
    prev = previous
    for i in range(n):
        a = angle[i]
        if a != a:  # NaN: split or dropped move
            continue
        if searched[i] or reach:
            best = a + per * np.rint((prev - a) / per)
        else:
            best = c1[i] + per * np.rint((prev - c1[i]) / per)
            near = c2[i] + per * np.rint((prev - c2[i]) / per)
            if abs(near - prev) < abs(best - prev):
                best = near
        prop[i] = best
        prev = best
    return prop


@numba.njit(cache=True)
def width_picks(w, wtab, beta, dist):  # pragma: no cover
    """Per planned width, the picks of
    :func:`printability.planning.orientation.preferred_orientations`, compiled.

    ``b1``: the relative orientation ``beta`` whose width ``wtab`` is nearest ``w`` (the
    first among equals, as ``np.argmin``); ``b2``: the nearest one more than 2° away from
    it modulo 180° (``dist``, row per orientation) when at most 1e-4 mm worse, else ``b1``.
    The same elementwise operations as the numpy rows (``|wtab - w|``, first minimum), so
    the same picks; no (widths × orientations) array is made.
    """
    n = len(w)
    m = len(wtab)
    b1 = np.empty(n)
    b2 = np.empty(n)
    for i in range(n):
        j1 = 0
        e1 = abs(wtab[0] - w[i])
        for j in range(1, m):
            e = abs(wtab[j] - w[i])
            if e < e1:
                e1 = e
                j1 = j
        j2 = 0
        e2 = abs(wtab[0] - w[i]) if dist[j1, 0] > 2.0 else np.inf
        for j in range(1, m):
            e = abs(wtab[j] - w[i]) if dist[j1, j] > 2.0 else np.inf
            if e < e2:
                e2 = e
                j2 = j
        b1[i] = beta[j1]
        b2[i] = beta[j2] if e2 <= e1 + 1e-4 else beta[j1]
    return b1, b2


@numba.njit(cache=True)
def split_intervals(length, step):  # pragma: no cover
    """The candidate intervals of :func:`printability.planning._search.split_many`.

    A move longer than ``2·step`` is trimmed by d = step/length, 2d, 4d… (while d < 1/2)
    at the start (``[d, 1]``), the end (``[0, 1 - d]``) or both (``[d, 1 - d]``), in that
    order per d; its intervals are listed by decreasing span, then in that order (the
    order a stable sort by span over the generated intervals gives). Returns per interval
    its move, start and end, then the moves that have intervals (ascending) and where
    each one's intervals start (CSR, one more entry than moves).
    """
    n = len(length)
    levels = np.zeros(n, np.int64)
    total = 0
    for i in range(n):
        if length[i] > 2 * step:
            d = step / length[i]
            while d < 0.5:
                levels[i] += 1
                d = d * 2.0
            total += 3 * levels[i]
    iv_mv = np.empty(total, np.int64)
    iv_t0 = np.empty(total)
    iv_t1 = np.empty(total)
    span = np.empty(total)
    moves = np.empty(n, np.int64)
    ivpos = np.zeros(n + 1, np.int64)
    k = 0
    nm = 0
    for i in range(n):
        if levels[i] == 0:
            continue
        lo = k
        d = step / length[i]
        for _ in range(levels[i]):
            for kind in range(3):
                t0 = 0.0 if kind == 1 else d
                t1 = 1.0 if kind == 0 else 1.0 - d
                s = t1 - t0
                # insertion, after every interval at least as long (stable)
                j = k
                while j > lo and span[j - 1] < s:
                    iv_t0[j] = iv_t0[j - 1]
                    iv_t1[j] = iv_t1[j - 1]
                    span[j] = span[j - 1]
                    j -= 1
                iv_t0[j] = t0
                iv_t1[j] = t1
                span[j] = s
                iv_mv[k] = i
                k += 1
            d = d * 2.0
        moves[nm] = i
        nm += 1
        ivpos[nm] = k
    return iv_mv, iv_t0, iv_t1, moves[:nm], ivpos[:nm + 1]


@numba.njit(cache=True)
def _isclose(a, b):  # pragma: no cover
    """``math.isclose(a, b)`` (relative tolerance 1e-9, no absolute one), as CPython decides it."""
    if a == b:
        return True
    if math.isinf(a) or math.isinf(b):
        return False
    diff = abs(b - a)
    return diff <= abs(1e-9 * b) or diff <= abs(1e-9 * a)


@numba.njit(cache=True)
def merge_pieces(move, t0, t1, angle):  # pragma: no cover
    """Pieces sorted by move, then start (the order given among equals), adjacent ones joined.

    Two pieces of a move are joined when the second starts where the first (as
    joined so far) ends and has its orientation, both up to ``math.isclose``:
    the loop :func:`printability.planning._search.split_many` ran per move
    on lists of tuples, compiled. Returns the joined pieces' move, start, end
    and orientation.
    """
    n = len(move)
    order = np.argsort(move, kind="mergesort")  # stable
    # then by start within each move (stable insertion: a move has few pieces)
    lo = 0
    for r in range(1, n + 1):
        if r < n and move[order[r]] == move[order[lo]]:
            continue
        for x in range(lo + 1, r):
            i = order[x]
            j = x
            while j > lo and t0[order[j - 1]] > t0[i]:
                order[j] = order[j - 1]
                j -= 1
            order[j] = i
        lo = r
    om = np.empty(n, np.int64)
    oa = np.empty(n)
    ob = np.empty(n)
    op = np.empty(n)
    k = 0
    for r in range(n):
        i = order[r]
        if k > 0 and om[k - 1] == move[i] and _isclose(ob[k - 1], t0[i]) \
                and _isclose(op[k - 1], angle[i]):
            ob[k - 1] = t1[i]
        else:
            om[k] = move[i]
            oa[k] = t0[i]
            ob[k] = t1[i]
            op[k] = angle[i]
            k += 1
    return om[:k], oa[:k], ob[:k], op[:k]


@numba.njit(cache=True, nogil=True)
def piece_losses(keys, lo, hi, row_t0, row_t1, lay_of, length, width, n_layers):  # pragma: no cover
    """What the split and dropped moves of a plan leave out, per layer.

    ``keys`` are the split or dropped moves in order, with pieces ``lo[q]:hi[q]`` of the
    rows ``row_t0``, ``row_t1``
    (:attr:`~printability.planning.orientation.Plan.piece_rows`), ``lay_of`` each move's
    layer, ``length`` and ``width`` (mm) each key's. Returns per layer the split moves,
    the dropped moves, the length not printed (mm) and that times the width (mm²), summed
    in the order a Python loop over the plan's pieces sums them (the same bits).
    """
    split = np.zeros(n_layers, np.int64)
    dropped = np.zeros(n_layers, np.int64)
    d_len = np.zeros(n_layers)
    d_area = np.zeros(n_layers)
    for q in range(len(keys)):
        kept = 0.0
        for r in range(lo[q], hi[q]):
            kept += row_t1[r] - row_t0[r]
        j = lay_of[keys[q]]
        if hi[q] > lo[q]:
            split[j] += 1
        else:
            dropped[j] += 1
        rest = 1.0 - kept
        gone = length[q] * (rest if rest > 0.0 else 0.0)
        d_len[j] += gone
        d_area[j] += gone * width[q]
    return split, dropped, d_len, d_area


@numba.njit(cache=True)
def points_along(a, ba, idx, t):  # pragma: no cover
    """``a[idx] + t[:, None] * ba[idx]``: the points at fractions ``t`` along moves ``idx``
    (rows of ``a``, ``ba`` = end − start), (n, 2) mm; the same two operations per
    coordinate as numpy's, without its gathered temporaries."""
    out = np.empty((len(idx), 2))
    for i in range(len(idx)):
        m = idx[i]
        out[i, 0] = a[m, 0] + t[i] * ba[m, 0]
        out[i, 1] = a[m, 1] + t[i] * ba[m, 1]
    return out


@numba.njit(cache=True)
def chain_viterbi(cand_in, cand_out, node_cost, folds, params):  # pragma: no cover
    """Per move, the candidate orientation of the path turning least (a Viterbi pass).

    ``cand_in``, ``cand_out`` (n, k): each move's admissible candidates (NaN: none),
    the orientation it starts and ends at (the same but for a split move, whose
    pieces are fixed); ``node_cost`` (n, k) what laying each costs (its width error,
    in degrees of turn); ``folds`` (n, k, k) per move 0 where it does not start where
    the previous ended (a travel between), else 1, or 2 where the turn from the
    previous move's candidate j to its candidate c can be made during the move (3:
    may be, not tested yet; counted as 2).
    ``params`` = (period, stop, travel, reverse): a turn between chained moves costs
    its size (modulo the period), plus ``stop`` unless it is made during the move (the
    nozzle then turns standing still: a full stop of the XY motion), plus ``reverse``
    when it turns the other way than the last turn of the path; across a travel it
    costs ``travel`` times its size. A state is a candidate and the sense of the last
    turn (0: clockwise or none yet, 1: counter-clockwise). A move without candidates
    (dropped) breaks the path. Returns the chosen column per move (-1: none), the first
    of equals.
    """
    per = params[0]
    stop = params[1]
    travel = params[2]
    reverse = params[3]
    n, k = cand_in.shape
    acc = np.full((n, k, 2), np.inf)
    back = np.full((n, k, 2), -1, np.int64)
    # each row's candidates (not NaN), in column order: rows hold a few of the k columns
    cols = np.empty((2, k), np.int64)
    m_prev = 0
    prev_ok = False
    for i in range(n):
        cur = i % 2
        m = 0
        for c in range(k):
            if cand_in[i, c] == cand_in[i, c]:
                cols[cur, m] = c
                m += 1
        any_ok = m > 0
        for q in range(m):
            c = cols[cur, q]
            y = cand_in[i, c]
            if not prev_ok:
                acc[i, c, 0] = node_cost[i, c]
                acc[i, c, 1] = node_cost[i, c]
                continue
            for qj in range(m_prev):
                j = cols[1 - cur, qj]
                if acc[i - 1, j, 0] == np.inf and acc[i - 1, j, 1] == np.inf:
                    continue
                # the turn from j to c, the same for both states of j
                d = (y - cand_out[i - 1, j] + 0.5 * per) % per - 0.5 * per
                ad = abs(d)
                f = folds[i, j, c]
                for s in range(2):
                    a = acc[i - 1, j, s]
                    if a == np.inf:
                        continue
                    s2 = s if ad <= 1e-9 else (1 if d > 0.0 else 0)
                    if f:
                        t = ad + (stop if ad > 1e-9 and f == 1 else 0.0)
                        if s2 != s:
                            t += reverse
                    else:
                        t = travel * ad
                    v = a + t + node_cost[i, c]
                    if v < acc[i, c, s2]:
                        acc[i, c, s2] = v
                        back[i, c, s2] = j * 2 + s
        prev_ok = any_ok
        m_prev = m
    out = np.full(n, -1, np.int64)
    i = n - 1
    nxt = -1
    while i >= 0:
        if nxt < 0:
            # the end of a path (or a move without candidates): its cheapest state
            best = np.inf
            for c in range(k):
                for s in range(2):
                    if acc[i, c, s] < best:
                        best = acc[i, c, s]
                        nxt = c * 2 + s
        if nxt >= 0:
            out[i] = nxt // 2
            nxt = back[i, nxt // 2, nxt % 2]
        i -= 1
    return out


@numba.njit(cache=True)
def distinct_candidates(red, keep, per):  # pragma: no cover
    """Clear ``keep[i, c]`` where an earlier kept column of row ``i`` holds the same
    orientation modulo ``per`` (to 1e-9), in place: the numpy loop over the columns of
    :func:`printability.planning.turns.least_turning`, the same operations per pair
    (``(a - b + per/2) % per - per/2``), without its (rows × columns) temporaries."""
    n, k = red.shape
    half = 0.5 * per
    for i in range(n):
        for c in range(1, k):
            if not keep[i, c]:
                continue
            b = red[i, c]
            for j in range(c):
                if keep[i, j] and abs((red[i, j] - b + half) % per - half) < 1e-9:
                    keep[i, c] = False
                    break


@numba.njit(cache=True)
def fold_pairs(cand_in, cand_out, chained, per, fold_max):  # pragma: no cover
    """The table of :func:`printability.planning.turns._fold_table`, compiled: per move
    and pair (previous move's candidate j, its c) 0 after a travel, 1 chained, 3 where the
    turn (nearest way round, ``np.round`` as ``np.rint``: the same bits) is more than
    1e-9 and at most ``fold_max``. No (moves × k × k) temporaries."""
    n, k = cand_in.shape
    folds = np.zeros((n, k, k), np.uint8)
    for i in range(n):
        if not chained[i]:
            continue
        for j in range(k):
            for c in range(k):
                folds[i, j, c] = 1
        if i == 0:
            continue
        for j in range(k):
            x = cand_out[i - 1, j]
            if x != x:
                continue
            for c in range(k):
                y = cand_in[i, c]
                if y != y:
                    continue
                step = abs(y + per * np.rint((x - y) / per) - x)
                if step > 1e-9 and step <= fold_max:
                    folds[i, j, c] = 3
    return folds

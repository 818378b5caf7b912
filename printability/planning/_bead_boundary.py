"""The pieces of the bead polygons' edges that make ∂G' (:mod:`printability.planning.beadunion`).

An edge of polygon C_i is clipped against each overlapping C_j (Liang–Barsky, :func:`_clip`)
and the covered intervals are removed, under the tie rule of the beadunion module's docs
(C_j with j < i removes what it holds grown by ε, with j > i what it holds shrunk by ε, each
half-plane moved out a further ε(1 − cos φ)).

Each clip evaluates only C_j's two sides and the cap planes that face the edge's ends
(:func:`_window`, :func:`_clip_windows`): a plane that holds both ends by a margin cannot
move the interval, so the result is the full loop's to the bit, at about a tenth of the
planes. An edge starts where the last one ended, so :func:`boundary_pieces` keeps each
neighbour's window of that corner (a third of the windows are found so), and the two
ends' windows are evaluated as one arc where they overlap (:func:`_clip_windows`).
:func:`green_area` gives the area the pieces enclose.

Coordinates and lengths in mm; the polygons' layout is
:mod:`printability.planning._bead_polygons`'s.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.planning._kernels import cell_of as _cell
from printability.planning._kernels import clip_step as _clip_step
from printability.planning._kernels import point_segment2 as _point_segment2
from printability.planning._kernels import segment_offset as _segment_offset
from printability.planning._kernels import segments2 as _segments2

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["_clip", "_clip_windows", "_corner_cosines", "_window", "boundary_pieces", "green_area"]


@numba.njit(cache=True, nogil=True, _nrt=False)
def _clip(edge, planes, a, b, slack):  # pragma: no cover
    """The parameter interval of the edge ``(px, py, qx, qy)`` inside the half-planes ``a:b``
    of ``planes`` (a :class:`~printability.planning.records.HalfPlanes`), each moved out by
    ``slack = (margin, turn, nx, ny)``: ``margin`` plus ``turn`` × (1 − cos) of its angle to
    the edge's normal (nx, ny) (Liang–Barsky); empty when t1 <= t0."""
    px, py, qx, qy = edge
    t0 = 0.0
    t1 = 1.0
    d = (qx - px, qy - py)
    for j in range(a, b):
        t0, t1 = _bound(planes, j, (px, py), d, slack, t0, t1)
        if t1 <= t0:
            return 1.0, 0.0
    return t0, t1


@numba.njit(cache=True, nogil=True, inline="always")
def _bound(planes, j, p, d, slack, t0, t1):  # pragma: no cover
    """One Liang–Barsky step of :func:`_clip`: [t0, t1] cut by half-plane ``j`` (an empty
    interval, t1 <= t0, when the edge from ``p`` along ``d`` runs parallel outside it)."""
    ux = planes.ux
    uy = planes.uy
    margin, turn, nx, ny = slack
    return _clip_step(ux[j] * d[0] + uy[j] * d[1],
                      planes.h[j] + margin + turn * (1.0 - (ux[j] * nx + uy[j] * ny))
                      - (ux[j] * p[0] + uy[j] * p[1]), t0, t1)


_SAFE = 1e-8
"""Margin (mm) by which a half-plane :func:`_clip_windows` skips must hold both ends of the
edge: far above the rounding of the offsets (about 1e-13 mm), far below the bead sizes."""


@numba.njit(cache=True, nogil=True, _nrt=False)
def _window(x, y, beads, polys, j, eps, vck):  # pragma: no cover
    """The cap planes of C_j (bead j of ``beads``, polygon j of ``polys``: segment [a, b],
    left normal ``l`` its first plane's, k edges per half turn, cap planes ``phase``
    clockwise of l, side offset ``rho``) that may not hold the point x by :data:`_SAFE`:
    ``(r*, w)``, the cap planes ``r* - w … r* + w`` (mod 2k, counted clockwise from the one
    just past l: :func:`_cap_plane`); ``w = -1`` none, ``w >= k // 2`` all (no window saves).
    ``vck`` is :func:`_corner_cosines`'s row of k.

    With s the point of [a, b] nearest x and d = x − s, every plane l of C_j holds
    ``u_l·s ≤ h_l − ρ``, so ``u_l·x ≤ h_l − ρ + |d| cos Δ_l`` with Δ_l its angle to d:
    when ``|d| cos Δ_l ≤ ρ − ε − _SAFE`` it holds x with room to spare, whatever
    :func:`_clip`'s margins (at least −ε). Cap plane r* is the nearest to d's direction, so
    the one m steps from it is at least (m − ½)·π/k from d, and ``vck[m - 1]`` =
    cos((m − ½)·π/k) bounds its cos Δ. (The two sides are always clipped.)
    """
    first = polys.planes.off[j]
    lx = polys.planes.ux[first]
    ly = polys.planes.uy[first]
    k = polys.k[j]
    ex, ey = _segment_offset(x, y, beads.ax[j], beads.ay[j], beads.bx[j], beads.by[j])
    d2 = ex * ex + ey * ey
    lim = beads.rho[j] - eps - _SAFE
    if d2 <= lim * lim:
        return 0, -1
    c = lim / math.sqrt(d2) - 1e-12  # (the slack covers the rounding of the angle)
    w = 0
    while w < k and vck[w] > c:
        w += 1
    if w >= k // 2:
        return 0, k
    # the angle of d from l towards the segment's direction t = (ly, -lx) (clockwise)
    phi = math.atan2(ex * ly - ey * lx, ex * lx + ey * ly)
    return math.floor((phi - polys.phase[j]) * k / math.pi + 0.5), w


@numba.njit(cache=True, nogil=True, inline="always")
def _cap_plane(r, k):  # pragma: no cover
    """The index in its polygon of cap plane r (mod 2k, clockwise from the one just past the
    left side): the k planes of the cap at b follow the left side, the cap at a's the right
    side."""
    r = r % (2 * k)
    return 1 + r if r < k else 2 + r


@numba.njit(cache=True, nogil=True, _nrt=False)
def _clip_windows(edge, planes, a, b, slack, win1, win2):  # pragma: no cover
    """:func:`_clip`'s interval over the half-planes ``a:b`` of C_j: its two sides and the
    cap planes in the two ends' windows ``(r, w)`` (:func:`_window`; all of them when
    either is ``w >= k // 2``).

    A plane outside both windows holds both ends strictly, so its Liang–Barsky parameter
    lies beyond [0, 1] on the side it bounds: it moves neither t0 nor t1, and the
    interval (hence the boundary) is the full loop's to the bit. Most edges of a cap face
    a few planes of a neighbour (about 6 of 48 at τ = 1e-3 mm); the full loop runs where
    the ends are too far out for a window to save (w ≥ k/2).

    Any superset of the planes the windows keep gives the same bits (min and max do not
    depend on the order), so windows that overlap or nearly touch are evaluated as the one
    arc that spans both, each plane once: the two ends of a short edge mostly face the
    same few planes.
    """
    j1, w1 = win1
    j2, w2 = win2
    k = (b - a - 2) // 2
    if w1 >= k // 2 or w2 >= k // 2:
        return _clip(edge, planes, a, b, slack)
    px, py, qx, qy = edge
    p = (px, py)
    d = (qx - px, qy - py)
    t0 = 0.0
    t1 = 1.0
    for j in (a, a + k + 1):  # the sides
        t0, t1 = _bound(planes, j, p, d, slack, t0, t1)
        if t1 <= t0:
            return 1.0, 0.0
    if w1 >= 0 and w2 >= 0:
        # window 2 seen from window 1's centre, the shorter way round
        delta = (j2 - j1 + k) % (2 * k) - k
        lo = min(-w1, delta - w2)
        hi = max(w1, delta + w2)
        if hi - lo <= 2 * (w1 + w2) + 1:
            for m in range(lo, hi + 1):
                j = a + _cap_plane(j1 + m, k)
                t0, t1 = _bound(planes, j, p, d, slack, t0, t1)
                if t1 <= t0:
                    return 1.0, 0.0
            return t0, t1
    for end in range(2):
        js = j1 if end == 0 else j2
        w = w1 if end == 0 else w2
        for mm in range(2 * w + 1):  # the nearest plane first, then ±1, ±2…
            m = (mm + 1) // 2 if mm % 2 else -(mm // 2)
            j = a + _cap_plane(js + m, k)
            t0, t1 = _bound(planes, j, p, d, slack, t0, t1)
            if t1 <= t0:
                return 1.0, 0.0
    return t0, t1


@numba.njit(cache=True, nogil=True)
def _corner_cosines(k):  # pragma: no cover
    """cos((w + ½)·π/k) for w < k, per edge count k (per half turn) of the polygons."""
    kmax = 2
    for i in range(len(k)):
        kmax = max(kmax, k[i])
    vc = np.ones((kmax + 1, kmax))
    for i in range(len(k)):
        kk = k[i]
        if vc[kk, 0] == 1.0:
            for w in range(kk):
                vc[kk, w] = math.cos((w + 0.5) * math.pi / kk)
    return vc


class _Memo(NamedTuple):
    """The working arrays of :func:`boundary_pieces`: polygon i's neighbours (``near``, ``mark[j]
    == i`` once j is listed), per slot of ``near`` the corner whose window against that
    neighbour is kept (``w_at``, an index into the corners) and the window (``w_j``,
    ``w_w``), and an edge's covered intervals (``t_lo``, ``t_hi``, by start)."""

    mark: np.ndarray
    near: np.ndarray
    w_at: np.ndarray
    w_j: np.ndarray
    w_w: np.ndarray
    t_lo: np.ndarray
    t_hi: np.ndarray


@numba.njit(cache=True, nogil=True)
def boundary_pieces(beads, polys, cells, eps, lo, hi):  # pragma: no cover
    """The uncovered pieces of the edges of polygons ``lo … hi - 1`` (the tie rule of the
    module docs), in order: what each polygon keeps depends on the polygons only. Rows
    (x0, y0, x1, y1, how far the piece's line stands beyond ρ from its bead's path).

    ``beads`` the :class:`~printability.planning.records.Beads`, ``polys`` their
    :class:`~printability.planning.records.BeadPolygons`, ``cells`` the
    :class:`~printability.planning.records.CellGrid` listing the polygons.
    """
    n = len(beads.ax)
    memo = _Memo(np.full(n, -1, np.int64), np.empty(n, np.int64), np.full(n, -1, np.int64),
                 np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n + 2),
                 np.empty(n + 2))
    cap = max(1024, 8 * (hi - lo))
    out = np.empty((cap, 5))
    vc = _corner_cosines(polys.k)
    off = polys.planes.off
    n_out = 0
    for i in range(lo, hi):
        m = _neighbours(i, beads, polys.box, cells, memo)
        both = 0 < i < n - 1  # near[0] = i - 1, near[1] = i + 1
        for e in range(off[i + 1] - off[i]):
            # the cap at b (edges 1 … k) is mostly inside the next chord's polygon
            ahead = both and 0 < e <= polys.k[i]
            n_iv = _covered(i, e, ahead, m, beads, polys, vc, eps, memo)
            if n_iv >= 0:
                if n_out + n_iv + 1 > len(out):  # room for every piece the edge may leave
                    grown = np.empty((2 * len(out) + n_iv + 1, 5))
                    grown[:n_out] = out[:n_out]
                    out = grown
                n_out = _emit(out, n_out, _edge_row(i, e, beads, polys), memo, n_iv)
    return out[:n_out]


@numba.njit(cache=True, nogil=True, _nrt=False)
def _neighbours(i, beads, box, cells, memo):  # pragma: no cover
    """The polygons that may overlap polygon i, into ``memo.near``, and their count: the
    neighbours along the path first (they cover most of a cap, ending the scans early),
    then those listed in the cells of i's box whose capsules come near i's."""
    ax, ay, bx, by, _ = beads
    start, items, x0, y0, cell, nx, ny = cells
    mark = memo.mark
    near = memo.near
    n = len(ax)
    m = 0
    big_i = (box[i, 2] - box[i, 0] - abs(bx[i] - ax[i])) * 0.5
    for j in range(i - 1, i + 2, 2):
        if 0 <= j < n:
            mark[j] = i
            near[m] = j
            m += 1
    for iy in range(_cell(box[i, 1], y0, cell, ny), _cell(box[i, 3], y0, cell, ny) + 1):
        for ix in range(_cell(box[i, 0], x0, cell, nx), _cell(box[i, 2], x0, cell, nx) + 1):
            c = iy * nx + ix
            for q in range(start[c], start[c + 1]):
                j = items[q]
                if j == i or mark[j] == i:
                    continue
                mark[j] = i
                if box[j, 0] > box[i, 2] or box[j, 2] < box[i, 0] \
                        or box[j, 1] > box[i, 3] or box[j, 3] < box[i, 1]:
                    continue
                big_j = (box[j, 2] - box[j, 0] - abs(bx[j] - ax[j])) * 0.5
                if _segments2(ax[i], ay[i], bx[i], by[i], ax[j], ay[j], bx[j],
                              by[j]) >= (big_i + big_j) ** 2:
                    continue
                near[m] = j
                m += 1
    return m


@numba.njit(cache=True, nogil=True, _nrt=False)
def _edge_row(i, e, beads, polys):  # pragma: no cover
    """Edge e of polygon i as ``(px, py, qx, qy, beyond)``: from corner e - 1 to corner e,
    and how far its line stands beyond rho from the path (0 on the caps, the sides touch
    Q's extreme corners)."""
    first = polys.planes.off[i]
    d = polys.planes.off[i + 1] - first
    q1 = first + e
    q0 = first + (e - 1 if e > 0 else d - 1)
    beyond = 0.0
    if e == 0 or e == polys.k[i] + 1:
        ux = polys.planes.ux
        uy = polys.planes.uy
        beyond = polys.planes.h[q1] - max(ux[q1] * beads.ax[i] + uy[q1] * beads.ay[i],
                                          ux[q1] * beads.bx[i] + uy[q1] * beads.by[i]) \
            - beads.rho[i]
    return polys.vx[q0], polys.vy[q0], polys.vx[q1], polys.vy[q1], beyond


@numba.njit(cache=True, nogil=True, _nrt=False)
def _covered(i, e, ahead, m, beads, polys, vc, eps, memo):  # pragma: no cover
    """The intervals of edge e of polygon i that its ``m`` neighbours cover, sorted by start
    into ``memo.t_lo``, ``memo.t_hi``: their count, or -1 when the edge is covered whole.
    ``ahead``: the next chord's polygon (slot 1) is tried first."""
    ax, ay, bx, by, rho = beads
    box = polys.box
    off = polys.planes.off
    near = memo.near
    t_lo = memo.t_lo
    t_hi = memo.t_hi
    first = off[i]
    q1 = first + e
    q0 = first + (e - 1 if e > 0 else off[i + 1] - first - 1)
    px = polys.vx[q0]
    py = polys.vy[q0]
    qx = polys.vx[q1]
    qy = polys.vy[q1]
    lo_x = min(px, qx)
    hi_x = max(px, qx)
    lo_y = min(py, qy)
    hi_y = max(py, qy)
    half = 0.5 * math.sqrt((qx - px) ** 2 + (qy - py) ** 2)  # (libm hypot: 3 % of all)
    mx = 0.5 * (px + qx)
    my = 0.5 * (py + qy)
    n_iv = 0
    for mm in range(m):
        sl = 1 - mm if ahead and mm < 2 else mm
        j = near[sl]
        if box[j, 0] > hi_x or box[j, 2] < lo_x or box[j, 1] > hi_y or box[j, 3] < lo_y:
            continue
        d2 = _point_segment2(mx, my, ax[j], ay[j], bx[j], by[j])
        big_j = (box[j, 2] - box[j, 0] - abs(bx[j] - ax[j])) * 0.5
        if d2 > (big_j + half) ** 2:
            continue  # the edge stays outside the circumscribed capsule
        if half < rho[j] - eps and d2 < (rho[j] - eps - half) ** 2:
            return -1  # inside the inscribed capsule, deeper than eps
        # the ends' windows; an edge's start is the last edge's end, whose
        # window against this neighbour is kept from its clip
        vck = vc[polys.k[j]]
        if memo.w_at[sl] == q0:
            win1 = (memo.w_j[sl], memo.w_w[sl])
        else:
            win1 = _window(px, py, beads, polys, j, eps, vck)
        win2 = _window(qx, qy, beads, polys, j, eps, vck)
        memo.w_at[sl] = q1
        memo.w_j[sl] = win2[0]
        memo.w_w[sl] = win2[1]
        t0, t1 = _clip_windows((px, py, qx, qy), polys.planes, off[j], off[j + 1],
                               (eps if j < i else -eps, eps, polys.planes.ux[q1],
                                polys.planes.uy[q1]), win1, win2)
        if t1 > t0:
            if t0 <= 0.0 and t1 >= 1.0:
                return -1
            s = n_iv  # insertion by start: the lists are short
            while s > 0 and t_lo[s - 1] > t0:
                t_lo[s] = t_lo[s - 1]
                t_hi[s] = t_hi[s - 1]
                s -= 1
            t_lo[s] = t0
            t_hi[s] = t1
            n_iv += 1
    return n_iv


@numba.njit(cache=True, nogil=True, _nrt=False)
def _emit(out, n_out, row, memo, n_iv):  # pragma: no cover
    """Write into ``out`` from row ``n_out`` on (room for ``n_iv + 1`` rows) the pieces of
    the edge ``row`` (:func:`_edge_row`) between its ``n_iv`` covered intervals; the new
    count of rows."""
    px, py, qx, qy, beyond = row
    t_lo = memo.t_lo
    t_hi = memo.t_hi
    t = 0.0
    for s in range(n_iv + 1):
        s0 = t_lo[s] if s < n_iv else 1.0
        s1 = t_hi[s] if s < n_iv else 1.0
        if s0 > t:
            e1 = min(s0, 1.0)
            out[n_out, 0] = px + t * (qx - px)
            out[n_out, 1] = py + t * (qy - py)
            out[n_out, 2] = px + e1 * (qx - px)
            out[n_out, 3] = py + e1 * (qy - py)
            out[n_out, 4] = beyond
            n_out += 1
        if s1 > t:
            t = s1
        if t >= 1.0:
            break
    return n_out


@numba.njit(cache=True, nogil=True)
def green_area(edges, x0, y0):  # pragma: no cover
    """The signed area the edges enclose (Green's theorem, about ``(x0, y0)``), summed in
    their order."""
    area = 0.0
    for q in range(edges.shape[0]):
        area += 0.5 * ((edges[q, 0] - x0) * (edges[q, 3] - y0)
                       - (edges[q, 2] - x0) * (edges[q, 1] - y0))
    return area

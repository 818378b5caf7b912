"""The lower bound's convex chain model (:func:`printability.mmc._band.settle_band`).

A leaf that no certified piece covers may be *proved lost*: when the edges near it form one
convex chain, every footprint that could cover it has its position in the chain's inner
half-planes eroded by the footprint's least support over an angle cell; a leaf whose image
misses every cell's eroded polygon ⊕ footprint is lost at every angle. The proof is in
:func:`printability.mmc._band.settle_band`'s notes; the records are those of
:mod:`printability.mmc._band_records`.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.mmc._band_geometry import clip_left, dist_seg_box, poly_dist, polygon_area

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["MAX_CHAIN", "chain_lost", "chain_of", "min_support"]

#: Longest chain of edges the lower bound's convex model takes (more: no model).
MAX_CHAIN = 48


@nb.njit(cache=True)
def chain_of(rings, nlist, box, reach, chain):  # pragma: no cover - numba
    """The convex chain model of a box: its length n (0: none), the edges in ``chain``.

    The edges of ``nlist`` within ``reach`` of the box ``(x0, y0, x1, y1)`` must be
    consecutive edges of one ring (or the whole ring), turning left at every joint (a
    convex chain): then G ∩ B lies in the intersection of their inner half-planes
    (:func:`printability.mmc._band.settle_band`).
    """
    edges, prev_, next_ = rings.edges, rings.prev_, rings.next_
    x0, y0, x1, y1 = box
    n = 0
    for t in range(nlist.shape[0]):
        e = nlist[t]
        if dist_seg_box(edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3],
                        x0, y0, x1, y1) <= reach:
            if n >= chain.shape[0]:
                return 0
            chain[n] = e
            n += 1
    if n == 0:
        return 0
    # the first edge: the one whose predecessor is not in the set (none: a whole ring)
    first = -1
    for t in range(n):
        pe = prev_[chain[t]]
        found = False
        for q in range(n):
            if chain[q] == pe:
                found = True
                break
        if not found:
            if first >= 0:
                return 0  # two chains
            first = chain[t]
    closed = first < 0
    if closed:
        first = chain[0]
    # walk along the ring: every edge of the set, in order, contiguous
    e = first
    for t in range(n):
        found = False
        for q in range(t, n):
            if chain[q] == e:
                chain[q] = chain[t]
                chain[t] = e
                found = True
                break
        if not found:
            return 0
        e = next_[e]
    if closed and e != first:
        return 0
    if not closed:
        for q in range(n):
            if chain[q] == e:
                return 0  # the walk went on inside the set: not one chain
    last = n if closed else n - 1
    for t in range(last):
        e1 = chain[t]
        e2 = chain[(t + 1) % n]
        d1x = edges[e1, 2] - edges[e1, 0]
        d1y = edges[e1, 3] - edges[e1, 1]
        d2x = edges[e2, 2] - edges[e2, 0]
        d2y = edges[e2, 3] - edges[e2, 1]
        cr = d1x * d2y - d1y * d2x
        if cr < 0.0 or (cr == 0.0 and d1x * d2x + d1y * d2y <= 0.0):
            return 0  # a right turn or a spike: not convex
    return n


@nb.njit(cache=True, inline="always")
def min_support(alpha, theta, hw, a, b):  # pragma: no cover - numba
    """min over |θ' − θ| ≤ hw of the support of R(θ')·diag(a, b)·D in direction alpha."""
    lo = alpha - theta - hw
    hi = alpha - theta + hw
    if hi - lo >= math.pi:
        c2 = 0.0
    else:
        j = math.ceil((lo - 0.5 * math.pi) / math.pi)
        if 0.5 * math.pi + j * math.pi <= hi:
            c2 = 0.0
        else:
            c2 = min(math.cos(lo) ** 2, math.cos(hi) ** 2)
    return math.sqrt(b * b + (a * a - b * b) * c2) * (1.0 - 1e-12)


@nb.njit(cache=True, inline="always")
def _positions(edges, chain, n, box, model, k, clip):  # pragma: no cover - numba
    """The positions that could put a footprint of cell k over the box: within a of it,
    clipped to the chain's half-planes eroded by the cell's least support. The polygon is
    left in ``clip.wx, clip.wy``; returns its vertex count (< 3: none)."""
    x0, y0, x1, y1 = box
    wx, wy, vx, vy = clip.wx, clip.wy, clip.vx, clip.vy
    a, b = model.a, model.b
    theta, hw = model.cells[k, 4], model.cells[k, 5]
    reach = a * (1.0 + 1e-9)
    wx[0], wy[0] = x0 - reach, y0 - reach
    wx[1], wy[1] = x1 + reach, y0 - reach
    wx[2], wy[2] = x1 + reach, y1 + reach
    wx[3], wy[3] = x0 - reach, y1 + reach
    m = 4
    for t in range(n):
        e = chain[t]
        dx = edges[e, 2] - edges[e, 0]
        dy = edges[e, 3] - edges[e, 1]
        ln = math.sqrt(dx * dx + dy * dy)
        if ln == 0.0:
            continue
        nx_ = -dy / ln
        ny_ = dx / ln
        ms = min_support(math.atan2(ny_, nx_), theta, hw, a, b)
        # the half-plane n·(t − A) ≥ ms, as "left of" the shifted edge line
        ax_ = edges[e, 0] + ms * nx_
        ay_ = edges[e, 1] + ms * ny_
        m = clip_left(wx, wy, m, ax_, ay_, ax_ + dx, ay_ + dy, vx, vy)
        for q in range(m):
            wx[q] = vx[q]
            wy[q] = vy[q]
        if m < 3:
            break
    return m


@nb.njit(cache=True, inline="always")
def _cell_may_cover(box, model, k, m, clip, qx, qy):  # pragma: no cover - numba
    """Whether the box grown by δ comes within the footprint of cell k of a position of the
    polygon ``clip.wx, clip.wy`` (m vertices): in the cell's unit-disk frame, the two
    convex images are at most 1 apart. ``qx, qy``: work arrays of 4."""
    x0, y0, x1, y1 = box
    delta = model.delta
    wx, wy, vx, vy = clip.wx, clip.wy, clip.vx, clip.vy
    cells = model.cells
    m00, m01, m10, m11 = cells[k, 0], cells[k, 1], cells[k, 2], cells[k, 3]
    for c in range(4):
        px = x0 - delta if c == 0 or c == 3 else x1 + delta
        py = y0 - delta if c < 2 else y1 + delta
        qx[c] = m00 * px + m01 * py
        qy[c] = m10 * px + m11 * py
    for q in range(m):
        px, py = wx[q], wy[q]
        vx[q] = m00 * px + m01 * py
        vy[q] = m10 * px + m11 * py
    return poly_dist(qx, qy, 4, vx, vy, m) <= 1.0 + 1e-9


@nb.njit(cache=True)
def chain_lost(edges, chain, n, box, model, start, clip):  # pragma: no cover - numba
    """(lost, k): whether no footprint at any angle of any cell covers a point of the box
    ``(x0, y0, x1, y1)`` (the convex chain model, for the ``n`` edges of ``chain``), and the
    first cell that may cover it (−1 when lost).

    Cells are tried from ``start`` on (the cell that covered a neighbouring leaf usually
    covers this one too). ``model`` is a :class:`~printability.mmc._band_records.ChainModel`,
    ``clip`` a :class:`~printability.mmc._band_records.ClipBuffers` of at least ``n + 8``
    entries.
    """
    nc = model.cells.shape[0]
    qx = np.empty(4)
    qy = np.empty(4)
    for kk in range(nc):
        k = (start + kk) % nc
        m = _positions(edges, chain, n, box, model, k, clip)
        if m < 3 or polygon_area(clip.wx, clip.wy, m) <= 0.0:
            continue  # no position at all: nothing covers the box at these angles
        if _cell_may_cover(box, model, k, m, clip, qx, qy):
            return False, k
    return True, -1

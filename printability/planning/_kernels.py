"""Small compiled predicates shared by :mod:`printability.planning.fastfit` and
:mod:`printability.planning.beadunion` (one copy, so the two grids and distance tests agree).

Coordinates in mm; "squared" distances in mm².
"""

from __future__ import annotations

import math

import numba
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["bin_boxes", "cell_of", "clip_step", "point_segment2", "segment_offset", "segments2"]


@numba.njit(cache=True, nogil=True)
def cell_of(v, v0, cell, n):  # pragma: no cover
    """Grid column (or row) of the coordinate ``v``, clamped to the grid.

    Every binning and every look-up goes through this one monotone function, which
    is all the scans rely on (an item is listed in every cell its box reaches);
    ``math.floor`` of a quotient, as a float ``//`` is compiled to a call to fmod.
    """
    return min(max(math.floor((v - v0) / cell), 0), n - 1)


@numba.njit(cache=True, nogil=True, inline="always")
def clip_step(p, q, t0, t1):  # pragma: no cover
    """One Liang–Barsky step: the parameter interval [t0, t1] of a segment cut by the
    half-plane ``p·t ≤ q`` (``p`` the direction's component along its normal, ``q`` the
    start's room inside it); (1, 0), an empty interval, when the segment runs parallel
    outside it. The footprint test and the bead union clip with it, each with its own
    margins in ``q``."""
    if p == 0.0:
        if q < 0.0:
            return 1.0, 0.0
    elif p > 0.0:
        t = q / p
        if t < t1:
            t1 = t
    else:
        t = q / p
        if t > t0:
            t0 = t
    return t0, t1


@numba.njit(cache=True, nogil=True)
def segment_offset(px, py, ax, ay, bx, by):  # pragma: no cover
    """The point p less its nearest point on the segment [a, b] (a vector, mm)."""
    dx = bx - ax
    dy = by - ay
    ll = dx * dx + dy * dy
    t = 0.0
    if ll > 0.0:
        t = min(1.0, max(0.0, ((px - ax) * dx + (py - ay) * dy) / ll))
    return px - (ax + t * dx), py - (ay + t * dy)


@numba.njit(cache=True, nogil=True)
def point_segment2(px, py, ax, ay, bx, by):  # pragma: no cover
    """Squared distance from a point to the segment [a, b]."""
    ex, ey = segment_offset(px, py, ax, ay, bx, by)
    return ex * ex + ey * ey


@numba.njit(cache=True, nogil=True)
def segments2(ax, ay, bx, by, cx, cy, dx, dy):  # pragma: no cover
    """Squared distance between the segments [a, b] and [c, d] (0 when they cross)."""
    o1 = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    o2 = (bx - ax) * (dy - ay) - (by - ay) * (dx - ax)
    o3 = (dx - cx) * (ay - cy) - (dy - cy) * (ax - cx)
    o4 = (dx - cx) * (by - cy) - (dy - cy) * (bx - cx)
    if o1 * o2 < 0.0 and o3 * o4 < 0.0:
        return 0.0
    return min(point_segment2(ax, ay, cx, cy, dx, dy), point_segment2(bx, by, cx, cy, dx, dy),
               point_segment2(cx, cy, ax, ay, bx, by), point_segment2(dx, dy, ax, ay, bx, by))


@numba.njit(cache=True, nogil=True)
def bin_boxes(lo_x, lo_y, hi_x, hi_y, x0, y0, cell, nx, ny):  # pragma: no cover
    """CSR ``(start, items)`` of the grid cells each box overlaps: box ``i`` is listed, in
    the order of ``i``, in every cell ``iy·nx + ix`` its [lo, hi] range reaches
    (:func:`cell_of`). Two passes (count, fill); O(boxes + their cells)."""
    count = np.zeros(nx * ny + 1, np.int64)
    items = np.empty(0, np.int64)
    fill = np.empty(0, np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            for c in range(nx * ny):
                count[c + 1] += count[c]
            items = np.empty(count[nx * ny], np.int64)
            fill = count[:-1].copy()
        for i in range(len(lo_x)):
            for iy in range(cell_of(lo_y[i], y0, cell, ny), cell_of(hi_y[i], y0, cell, ny) + 1):
                for ix in range(cell_of(lo_x[i], x0, cell, nx),
                                cell_of(hi_x[i], x0, cell, nx) + 1):
                    c = iy * nx + ix
                    if pass_ == 0:
                        count[c + 1] += 1
                    else:
                        items[fill[c]] = i
                        fill[c] += 1
    return count, items

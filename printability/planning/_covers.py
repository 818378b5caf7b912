"""The exact test of convex footprints, given as rings and half-planes, against G.

For one footprint P (the polygon of the ring ``shapely.covers`` would be
given; its vertices lie within rounding, δ ≪ ε = 1e-9 mm, of the half-plane
polygon):

* **Reject** when one vertex of P lies strictly outside G
  (``shapely.intersects_xy`` false), or when some edge of ∂G has a piece of
  positive length inside every half-plane shrunk by ε: that piece is a point
  of ∂G in the interior of P, and every neighbourhood of a boundary point
  holds points outside G, so P ⊄ G.
* **Accept** when a vertex of P lies in G and no edge of ∂G meets the
  half-planes grown by ε (which contain P): P is connected, holds a point of
  G and meets no point of ∂G, so it lies in the interior of G.
* Otherwise (∂G grazes P within ε) ``shapely.covers`` decides.

Each decision is therefore the one ``shapely.covers`` gives; only the time
changes. :func:`covers_rings` applies these rules to given rings, the edges
near P found on the grid of :mod:`printability.planning._boundary_grid`; the
fused kernel of :mod:`printability.planning._first_fits` applies them through the
same edge test (:func:`edges_state`, :func:`clip_fraction`, half-planes visited in
the order of :func:`direction_order`). :func:`contains_xy` and :func:`covers` are the
shapely answers for a shapely target or a bead union.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.planning._boundary_grid import boundary_grid
from printability.planning._kernels import cell_of as _cell
from printability.planning._kernels import clip_step as _clip_step
from printability.planning.beadunion import BeadUnion, union_contains_xy, union_covers

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["EPS", "clip_fraction", "contains_xy", "covers", "covers_rings", "direction_order",
           "edges_state"]


EPS = 1e-9
"""Margin (mm) of the half-plane tests against rounding of the ring's vertices."""


@numba.njit(cache=True, _nrt=False)
def clip_fraction(ax, ay, bx, by, cu, su, h, off, order):  # pragma: no cover
    """Fraction of [a, b] inside all half-planes ``cu·x + su·y ≤ h + off`` (Liang–Barsky).

    The half-planes are visited in ``order`` (the two sides and the two caps of
    the move first: most edges are cut off by one of them); min and max do not
    depend on the order, so neither does the result.
    """
    t0 = 0.0
    t1 = 1.0
    dx = bx - ax
    dy = by - ay
    for jj in range(len(order)):
        j = order[jj]
        t0, t1 = _clip_step(cu[j] * dx + su[j] * dy, h[j] + off - (cu[j] * ax + su[j] * ay),
                            t0, t1)
        if t1 < t0:
            return -1.0
    return t1 - t0


@numba.njit(cache=True)
def _decide(rings, planes, grid, todo, eps, order, out):  # pragma: no cover
    """Per ring of ``todo``: 1 inside, 0 not inside, -1 undecided (∂G within ``eps``).

    ``planes`` holds the rings' half-planes (``cu``, ``su``, ``h``, each (n, k)), ``grid``
    the :class:`~printability.planning.records.BoundaryGrid` of ∂G. A hand-written kernel
    because the candidates are few (a grid cell or two of ∂G per footprint) and the test
    per edge is 64 multiply-adds: GEOS's general covers builds a noded graph of both
    boundaries for every footprint.
    """
    cu, su, h = planes
    k = rings.shape[1] - 1
    found = np.zeros(1, np.int64)
    for m in range(len(todo)):
        i = todo[m]
        bx0 = rings[i, 0, 0]
        bx1 = bx0
        by0 = rings[i, 0, 1]
        by1 = by0
        for v in range(1, k):
            x = rings[i, v, 0]
            y = rings[i, v, 1]
            bx0 = min(bx0, x)
            bx1 = max(bx1, x)
            by0 = min(by0, y)
            by1 = max(by1, y)
        out[i] = edges_state(cu[i], su[i], h[i], (bx0 - eps, by0 - eps, bx1 + eps, by1 + eps),
                             grid.cells, grid.packed, eps, order, found)


@numba.njit(cache=True, _nrt=False)
def edges_state(cu, su, h, box, cells, packed, eps, order, found):  # pragma: no cover
    """One footprint of :func:`_decide`: 0 if ∂G enters it, -1 if ∂G grazes it, else 1.

    ``box`` is the ring's bounding box ``(x0, y0, x1, y1)`` already grown by ``eps``; the
    edges are read from the ``packed`` rows of a
    :class:`~printability.planning.records.BoundaryGrid` (its ``cells`` list them);
    ``found[0]`` is set to the edge that enters it.
    """
    bx0, by0, bx1, by1 = box
    start, items, x0, y0, cell, nx, ny = cells
    ix0 = _cell(bx0, x0, cell, nx)
    ix1 = _cell(bx1, x0, cell, nx)
    iy0 = _cell(by0, y0, cell, ny)
    iy1 = _cell(by1, y0, cell, ny)
    state = 1
    for iy in range(iy0, iy1 + 1):
        for ix in range(ix0, ix1 + 1):
            c = iy * nx + ix
            for q in range(start[c], start[c + 1]):
                ax = packed[q, 0]
                ay = packed[q, 1]
                bx = packed[q, 2]
                by = packed[q, 3]
                if max(ax, bx) < bx0 or min(ax, bx) > bx1 or max(ay, by) < by0 \
                        or min(ay, by) > by1:
                    continue
                if clip_fraction(ax, ay, bx, by, cu, su, h, eps, order) < 0.0:
                    continue
                t = clip_fraction(ax, ay, bx, by, cu, su, h, -eps, order)
                # (a square root, not libm's hypot: coordinates in mm cannot overflow)
                if t > 0.0 and t * math.sqrt((bx - ax) ** 2 + (by - ay) ** 2) > eps:
                    found[0] = items[q]
                    return 0
                state = -1
    return state


@functools.lru_cache(maxsize=8)
def direction_order(d: int) -> np.ndarray:
    """Every direction once, coarse to fine: 0 and d/2 (normal to the move), d/4 and 3d/4
    (along it), then the diagonals, then halfway between those…

    An edge outside the footprint is usually cut off by a half-plane of the coarsest
    polygon around it: visiting the directions so, it leaves after two or three instead
    of a third of them on average when they are taken in turn.
    """
    out = [0]
    k = d
    while k > 1:
        k //= 2
        out += [j for j in range(k, d, 2 * k) if j % k == 0]
    head = [0, d // 2, d // 4, (3 * d) // 4]
    order = np.array(list(dict.fromkeys([*head, *out, *range(d)])), dtype=np.int64)
    order.setflags(write=False)
    return order


def covers_rings(target: BaseGeometry, rings: np.ndarray, cu: np.ndarray, su: np.ndarray,
                 h: np.ndarray) -> np.ndarray:
    """``shapely.covers(target, shapely.polygons(rings))``, deciding the clear cases exactly.

    Parameters
    ----------
    target
        G (prepared).
    rings
        (n, k + 1, 2) closed rings of convex footprints.
    cu, su, h
        (n, k) their half-planes ``cu·x + su·y ≤ h`` (the ring's vertices are
        where adjacent boundary lines cross).

    Returns
    -------
    bool ndarray, shape (n,)
    """
    n = len(rings)
    out = np.zeros(n, dtype=bool)
    if n == 0:
        return out
    # a vertex strictly outside G: not inside; otherwise that vertex is a point of G
    inside = contains_xy(target, rings[:, 0, 0], rings[:, 0, 1])
    todo = np.flatnonzero(inside)
    if todo.size == 0:
        return out
    state = np.full(n, 0, np.int8)
    grid = boundary_grid(target)
    planes = (np.ascontiguousarray(cu), np.ascontiguousarray(su), np.ascontiguousarray(h))
    _decide(np.ascontiguousarray(rings), planes, grid, todo, EPS, direction_order(h.shape[1]),
            state)
    out[state == 1] = True
    rest = np.flatnonzero(state == -1)
    if rest.size:
        out[rest] = covers(target, shapely.polygons(rings[rest]))
    return out


def contains_xy(target: BaseGeometry | BeadUnion, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``shapely.intersects_xy(target, x, y)``, for a shapely target or a bead union."""
    if isinstance(target, BeadUnion):
        return union_contains_xy(target, x, y)
    return shapely.intersects_xy(target, x, y)


def covers(target: BaseGeometry | BeadUnion, polygons: np.ndarray) -> np.ndarray:
    """``shapely.covers(target, polygons)``, for a shapely target or a bead union."""
    if isinstance(target, BeadUnion):
        return union_covers(target, polygons)
    return shapely.covers(target, polygons)

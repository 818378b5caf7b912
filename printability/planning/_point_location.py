"""Whether a point of a footprint lies in G: the accept case of the fused kernel.

Where no edge of ∂G comes within ``EPS`` of a footprint, one of its points, at
least ~``EPS`` from ∂G, is located (:func:`locate`): in the polygons of a bead
union when the target is one (:func:`locator` gives them and their beads; a
bead's axis is tried first, :func:`_near_axis`), else by the parity of a ray's
crossings of ∂G on the boundary grid (:func:`_inside`).

Coordinates in mm.
"""

from __future__ import annotations

import numba
import numpy as np
from shapely.geometry.base import BaseGeometry

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.planning._kernels import cell_of as _cell
from printability.planning._kernels import point_segment2 as _point_segment2
from printability.planning.beadunion import BeadUnion, in_polygons
from printability.planning.records import Beads, CellGrid, HalfPlanes, Locator

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["_AXIS", "_near_axis", "locate", "locator"]


@numba.njit(cache=True, _nrt=False)
def _inside(px, py, grid):  # pragma: no cover
    """Whether a point at least ~``EPS`` away from ∂G lies in G (parity of a ray's crossings
    of the edges of the :class:`~printability.planning.records.BoundaryGrid` ``grid``).

    The ray runs along the point's grid row towards the nearer side of the grid;
    an edge listed in several cells of the row is counted in the first cell the
    ray reaches. Edges meet the ray under the half-open rule (one end strictly
    above), so a ray through a vertex counts it once; the crossing abscissa is
    only compared with the point's, which is far from the edge, so its rounding
    cannot flip the count.
    """
    ex0, ey0, ex1, ey1, cells, _ = grid
    start, items, x0, y0, cell, nx, ny = cells
    iy = _cell(py, y0, cell, ny)
    ix = _cell(px, x0, cell, nx)
    right = nx - 1 - ix <= ix
    lo = ix if right else 0
    hi = nx - 1 if right else ix
    inside = False
    for c in range(iy * nx + lo, iy * nx + hi + 1):
        col = c - iy * nx
        for q in range(start[c], start[c + 1]):
            e = items[q]
            ax = ex0[e]
            ay = ey0[e]
            bx = ex1[e]
            by = ey1[e]
            if (ay > py) == (by > py):
                continue
            if right:
                first = max(ix, _cell(min(ax, bx), x0, cell, nx))
            else:
                first = min(ix, _cell(max(ax, bx), x0, cell, nx))
            if col != first:
                continue  # counted in another cell of the row
            xc = ax + (py - ay) * (bx - ax) / (by - ay)
            if (xc > px) if right else (xc < px):
                inside = not inside
    return inside


_NO_POLYGONS = Locator(HalfPlanes(np.zeros(1, np.int64), np.zeros(0), np.zeros(0), np.zeros(0)),
                       CellGrid(np.zeros(2, np.int64), np.zeros(0, np.int64), 0.0, 0.0, 1.0, 1,
                                1),
                       Beads(np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0)))


def locator(target: BaseGeometry | BeadUnion) -> Locator:
    """What :func:`first_fits` locates points with: a bead union's polygons, their grid
    and their beads (axis ends and radius), or nothing (a shapely target: parity of ∂G's
    crossings)."""
    if isinstance(target, BeadUnion):
        return Locator(target.half_planes, target.grid,
                       Beads(target.ax, target.ay, target.bx, target.by, target.rho))
    return _NO_POLYGONS


_AXIS = 1e-6
"""Margin (mm) of :func:`_near_axis`: far above the rounding of a bead polygon's half-planes."""


@numba.njit(cache=True, _nrt=False)
def _near_axis(px, py, cells, beads):  # pragma: no cover
    """Whether the point is within ``rho - _AXIS`` of the axis of a bead listed in its cell
    (``cells`` a :class:`~printability.planning.records.CellGrid`, ``beads`` the
    :class:`~printability.planning.records.Beads`).

    A sufficient test of :func:`~printability.planning.beadunion.in_polygons`: a bead
    polygon holds the points within ``rho`` of its axis (its half-planes are tangent to
    that capsule), and its box, by which it is listed in the cells, holds them too; at
    ``_AXIS`` inside, every half-plane holds them despite rounding. The points located
    are mostly on some move's axis, where the half-planes are many (a polygon's 2k) and
    this test is one distance.
    """
    start, items, x0, y0, cell, nx, ny = cells
    ax, ay, bx, by, rho = beads
    c = _cell(py, y0, cell, ny) * nx + _cell(px, x0, cell, nx)
    for q in range(start[c], start[c + 1]):
        i = items[q]
        r = rho[i] - _AXIS
        if r > 0.0 and _point_segment2(px, py, ax[i], ay[i], bx[i], by[i]) < r * r:
            return True
    return False


@numba.njit(cache=True, _nrt=False)
def locate(px, py, grid, loc):  # pragma: no cover
    """Whether a point at least ~``EPS`` from ∂G lies in G: in one of the polygons of a
    bead union when there are any (near a bead's axis first), else by the parity of ∂G's
    crossings (``grid`` the :class:`~printability.planning.records.BoundaryGrid`, ``loc``
    the :class:`~printability.planning.records.Locator`)."""
    if len(loc.polygons.off) > 1:
        if _near_axis(px, py, loc.cells, loc.beads):
            return True
        return in_polygons(px, py, loc.polygons, loc.cells)
    return _inside(px, py, grid)

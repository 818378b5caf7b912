"""The edges of ∂G binned on a uniform grid, built once per layer target.

The footprint tests (:mod:`printability.planning._covers`,
:mod:`printability.planning._first_fits`) and the ray parity of
:mod:`printability.planning._point_location` find the edges of ∂G near a footprint
or a point through this grid instead of scanning ∂G: per cell, the edges whose
bounding box overlaps it (CSR), ~1 mm cells, with each entry's edge also packed
in one row of 4 for the scans. The grids of the last few targets are cached.
Cells are found with :func:`printability.planning._kernels.cell_of`, the binning
shared with :mod:`printability.planning.beadunion`.

Coordinates in mm.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.planning._kernels import bin_boxes
from printability.planning.beadunion import BeadUnion
from printability.planning.records import BoundaryGrid, CellGrid

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["boundary_grid"]


_cache: list[tuple[BaseGeometry, BoundaryGrid]] = []


def boundary_grid(target: BaseGeometry | BeadUnion) -> BoundaryGrid:
    """Edges of ∂G binned on a uniform grid (CSR), cached for the last few targets.

    ``target`` is a shapely geometry or a :class:`~printability.planning.beadunion.BeadUnion`
    (whose boundary edges are already computed).

    Returns
    -------
    BoundaryGrid
        The edge ends, the grid listing them per cell, and per entry of the grid's
        ``items`` its edge's ends (:func:`_pack_edges`).
    """
    for g, grid in _cache:
        if g is target:
            return grid
    if isinstance(target, BeadUnion):
        ex0, ey0, ex1, ey1 = target.ex0, target.ey0, target.ex1, target.ey1
    else:
        parts = shapely.get_parts(shapely.boundary(target))
        coords, which = shapely.get_coordinates(parts, return_index=True)
        same = which[1:] == which[:-1]
        a = coords[:-1][same]
        b = coords[1:][same]
        ex0, ey0, ex1, ey1 = (np.ascontiguousarray(v)
                              for v in (a[:, 0], a[:, 1], b[:, 0], b[:, 1]))
    if len(ex0):
        x0, y0 = float(min(ex0.min(), ex1.min())), float(min(ey0.min(), ey1.min()))
        w = float(max(ex0.max(), ex1.max())) - x0
        hgt = float(max(ey0.max(), ey1.max())) - y0
    else:
        x0 = y0 = w = hgt = 0.0
    # ~1 mm cells (a footprint spans a few), at most ~250 k of them
    cell = max(1.0, math.sqrt(max(w * hgt, 1e-12) / 250_000.0))
    nx = int(w // cell) + 1
    ny = int(hgt // cell) + 1
    start, items = bin_boxes(np.minimum(ex0, ex1), np.minimum(ey0, ey1), np.maximum(ex0, ex1),
                             np.maximum(ey0, ey1), x0, y0, cell, nx, ny)
    grid = BoundaryGrid(ex0, ey0, ex1, ey1, CellGrid(start, items, x0, y0, cell, nx, ny),
                        _pack_edges(ex0, ey0, ex1, ey1, items))
    _cache.insert(0, (target, grid))
    del _cache[4:]
    return grid


@numba.njit(cache=True)
def _pack_edges(ex0, ey0, ex1, ey1, items):  # pragma: no cover
    """Per entry of the grid's ``items``: its edge's x0, y0, x1, y1, one row of 4 read in turn
    as a cell is scanned (two entries to a cache line: the scans are bound by memory, and
    an edge's box costs four comparisons of these, less than a second line)."""
    out = np.empty((len(items), 4))
    for q in range(len(items)):
        e = items[q]
        out[q, 0] = ex0[e]
        out[q, 1] = ey0[e]
        out[q, 2] = ex1[e]
        out[q, 3] = ey1[e]
    return out

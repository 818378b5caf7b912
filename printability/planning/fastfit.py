"""Exact shortcut for "does this swept footprint lie inside the target?".

:func:`printability.planning.footprints.fits` asks ``shapely.covers(G, P)``
for hundreds of thousands of convex swept polygons P (64 vertices each) per
part. GEOS answers each with a general overlay-style test (noding P's ring
against ∂G); for a convex P known as an intersection of half-planes
``u_j·x ≤ h_j`` a far cheaper test is exact: clip each nearby edge of ∂G
against those half-planes (Liang–Barsky, one pass over the 64 half-planes).

This module is the public face of that test; the code is in pieces, each
re-exported here (import from this module):

* :mod:`printability.planning._boundary_grid` — ∂G's edges binned on a uniform
  grid, built once per layer target (:func:`boundary_grid`);
* :mod:`printability.planning._covers` — the edge tests and why their decisions
  are those of ``shapely.covers`` (:data:`EPS`) and the order they visit the
  directions in (:func:`direction_order`), applied to given rings
  (:func:`covers_rings`), and the shapely answers for a shapely target or a
  bead union (:func:`contains_xy`, :func:`covers`);
* :mod:`printability.planning._point_location` — whether a point lies in G
  (:func:`locator`);
* :mod:`printability.planning._sweep` — the half-planes and ring of an ellipse or
  rectangle swept along a move (:func:`swept_kernel`) and the refusal shortcut
  in the swept ellipse's frame;
* :mod:`printability.planning._first_fits` — the fused planner kernel
  (:func:`first_fits`).

The kernels take their arrays grouped in the records of
:mod:`printability.planning.records` (the nozzle's pieces, the moves, the orientations, ∂G's
grid, the point locator).

Conventions: lengths in mm. The helpers called per footprint or per edge only
read and write arrays they are given: they are compiled without the runtime
(``_nrt=False``), else every call increfs and decrefs each array argument
(atomic operations that cost more than a footprint's test).
"""

from __future__ import annotations

from printability.planning._boundary_grid import boundary_grid
from printability.planning._covers import (
    EPS,
    contains_xy,
    covers,
    covers_rings,
    direction_order,
)
from printability.planning._first_fits import first_fits
from printability.planning._point_location import locator
from printability.planning._sweep import swept_kernel

__all__ = ["EPS", "boundary_grid", "contains_xy", "covers", "covers_rings", "direction_order",
           "first_fits", "locator", "swept_kernel"]


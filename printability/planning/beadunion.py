"""A layer target grown by the tolerance, as the union of convex bead polygons.

The post-processor tests every swept footprint against G ⊕ τ, where G is the
union of the layer's beads (capsules: the points within w/2 of a move, see
:mod:`printability.sources.gcode`). Building G with GEOS (a buffer per chain,
``union_all``, then a buffer by τ) costs more than the slicer's own slicing
on busy parts, yet the footprint test (:mod:`printability.planning.fastfit`)
only needs the edges of the boundary and a point-in-region test. This module
computes exactly those, without an overlay.

The region
----------
Each bead of radius r along the segment [a, b] becomes the convex polygon

    C = [a, b] ⊕ Q,

with Q a regular 2k-gon circumscribed about the circle of radius
ρ = r + sτ (s = :data:`SIDE`), its corners at the angles (m + ½)·π/k, m = 0 … 2k − 1,
the same for every bead: the caps of two chords that meet at a point of a path
(equal widths) are then the same corners, and their union's boundary there is one
arc of Q, not the two polygons' corners poking through each other's edges in turn (on
the calibration cube 97 000 boundary pieces, 69 000 of them under 10 µm, against
40 000, 4 000; every footprint test reads fewer). C's straight sides, parallel to
the segment through Q's extreme corners, stand between ρ and ρ / cos(π/2k) from the
path. k is the smallest count whose corners stay within r·c + τ of the segment,
where c is the inner factor of the GEOS reconstruction (:data:`INNER`, quad_segs 32).
Hence, with G₃₂ the polygonal G the rest of the project builds,

    capsule(r + sτ) ⊆ C ⊆ capsule(r·c + τ) ⊆ G₃₂ ⊕ τ,

and the union G' of the C's lies between G ⊕ sτ and G₃₂ ⊕ τ: every
footprint accepted against G' lies inside the target within the tolerance,
and a footprint laying exactly the planned width (half-width r) clears the
sides by at least sτ. The rest of the tolerance, (1 − s)τ less the reference polygon's
own shortfall r(1 − c), is the room the corners have: the smaller s, the
fewer corners (k) and the faster the boundary and every footprint test on it.

Polygon i has 2k + 2 half-planes (its layout: :mod:`printability.planning._bead_polygons`).

The boundary
------------
∂G' is made of the pieces of the polygons' edges that no other polygon
covers. An edge of C_i is clipped against each overlapping C_j (Liang–Barsky
on C_j's half-planes) and the covered intervals are removed, with one tie
rule so that coincident edges facing the same way (a move printed twice, the
sides of a path's consecutive chords) leave one copy: C_j with j < i removes
what lies in C_j grown by ε, C_j with j > i what lies in C_j shrunk by ε
(ε = 1e-9 mm); each half-plane of C_j is moved out by a further ε(1 − cos φ),
φ its angle to the edge's outward normal, so that an edge lying on an
opposite edge of C_j (two beads that just touch) is covered by ε and leaves
no copy. The margin keeps every decision about edges that run along each
other well away from rounding; in exchange two pieces meeting where edges
cross at an angle θ may miss each other by up to about 2ε/sin θ. Any point
of ∂G' is therefore within that of a kept piece, and a footprint that meets
no kept piece leaves G' by at most about 2ε, far inside the tolerance. Points are located in G'
by the polygons themselves (:func:`union_contains_xy`), never by counting
boundary crossings, so those gaps cannot mislead it.

The polygons are built by :mod:`printability.planning._bead_polygons`, the boundary's
pieces by :mod:`printability.planning._bead_boundary` (which clips each edge against only the
planes of a neighbour that face it); this module holds the region and its queries.

Conventions: coordinates and lengths in mm; edges as four arrays
(x0, y0, x1, y1). Cost: linear in the beads times the number of beads
overlapping each (a uniform grid finds them): on Benchy (76 000 beads in 240
layers) about 0.7 s, against 3.9 s for GEOS's union and buffer of the same beads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
import shapely

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.base.parallel import shared_out
from printability.errors import InputError
from printability.planning._bead_boundary import boundary_pieces, green_area
from printability.planning._bead_polygons import bead_polygons, cell_grid
from printability.planning._kernels import cell_of as _cell
from printability.planning.records import BeadPolygons, Beads, CellGrid, HalfPlanes

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["INNER", "SIDE", "BeadUnion", "bead_union", "in_polygons", "union_contains_xy",
           "union_covers"]

INNER = math.cos(math.pi / 128)
"""Inner factor of a circle polygonised with 32 segments per quarter (GEOS quad_segs=32):
the polygon holds the disc of radius r·INNER."""

SIDE = 0.35
"""The polygons' straight sides stand s·τ out of their bead (see the module docs). Measured
on eight sliced files with the ellipse 0.8 × 0.3 (τ = 0.95 µm): 0.35 instead of an even
0.5 has 23 corners per half turn instead of 27 and cuts the post-processor's CPU by 4-6 %
on the cube, 10-17 % on Tolerance and Benchy; the dropped length moves by -0.3 to +0.4 % on
four of five files and by +6 % on Cura's sample (0.03 % of its extruded length); 0.25 and
0.15 gain little more and drop more there."""

_EPS = 1e-9
_PARALLEL_MIN = 1000
"""Fewest beads :func:`bead_union` gives a thread of its own."""


@dataclass(frozen=True, eq=False)
class BeadUnion:
    """G' for one layer: the bead polygons, their grid, and the edges of the union's boundary.

    Compared by identity (caches key on it). Arrays are read-only by convention.

    Attributes
    ----------
    ax, ay, bx, by, rho : ndarray
        Each bead's segment and side offset ρ (mm).
    off : ndarray
        Polygon i has half-planes ``ux·x + uy·y ≤ h`` and corners ``vx, vy`` at
        ``off[i]:off[i + 1]`` (corner j ends edge j).
    ux, uy, h, vx, vy : ndarray
        Half-planes and corners of every polygon.
    box : ndarray
        (n, 4) bounding box of each polygon.
    k, phase : ndarray
        Each polygon's edges per half turn and the angle (radians, clockwise) from its
        left side's normal to the next plane's (the module docs).
    grid : CellGrid
        The polygons whose box meets each cell.
    ex0, ey0, ex1, ey1 : ndarray
        Edges of ∂G'.
    beyond : ndarray
        How far each edge's line stands beyond ρ from its bead's path, mm (0 on the
        caps; on the sides, Q's extreme corner's excess, below ρ(1/cos(π/2k) − 1)).
    area : float
        Area of G' (mm²), from the boundary by Green's theorem (the pieces'
        gaps at shallow crossings leave it within about 1e-6 of GEOS's area of
        the same union, relative).
    perimeter : float
        Length of ∂G' (mm).
    """

    ax: np.ndarray
    ay: np.ndarray
    bx: np.ndarray
    by: np.ndarray
    rho: np.ndarray
    off: np.ndarray
    ux: np.ndarray
    uy: np.ndarray
    h: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    box: np.ndarray
    k: np.ndarray
    phase: np.ndarray
    grid: CellGrid
    ex0: np.ndarray
    ey0: np.ndarray
    ex1: np.ndarray
    ey1: np.ndarray
    beyond: np.ndarray
    area: float
    perimeter: float

    @property
    def is_empty(self) -> bool:
        return len(self.ax) == 0

    @property
    def half_planes(self) -> HalfPlanes:
        """The polygons' half-planes, as the kernels take them."""
        return HalfPlanes(self.off, self.ux, self.uy, self.h)

    def polygons(self, index: np.ndarray | None = None) -> np.ndarray:
        """The bead polygons (shapely), all or those of ``index``."""
        idx = np.arange(len(self.ax)) if index is None else np.asarray(index, np.int64)
        rings = [np.column_stack([self.vx[self.off[i]:self.off[i + 1]],
                                  self.vy[self.off[i]:self.off[i + 1]]]) for i in idx]
        return np.array([shapely.Polygon(r) for r in rings], dtype=object)

    def geometry(self):
        """G' as one shapely geometry (a GEOS union: for tests and small inputs)."""
        return shapely.union_all(self.polygons())


def bead_union(p0: np.ndarray, p1: np.ndarray, radius: np.ndarray, *, grow: float,
               inner: float = INNER, workers: int = 1) -> BeadUnion:
    """G' (see the module docs) of the beads ``p0[i] → p1[i]`` of radius ``radius[i]``.

    Parameters
    ----------
    p0, p1
        (n, 2) segment ends, mm.
    radius
        (n,) bead half-widths r > 0, mm.
    grow
        The tolerance τ > 0 the union may stand outside the beads, mm.
    inner
        The inner factor c of the reference polygons (:data:`INNER`).
    workers
        Threads the beads' boundary pieces are computed on (the same union on any number).

    Complexity: O(Σ k_i · m_i) for k_i ≈ π / (2·acos((r + sτ)/(r·c + τ))) edges per
    half turn (s = :data:`SIDE`) and m_i overlapping beads; k is 23 for r = 0.225 mm,
    τ = 0.95 µm.
    """
    p0 = np.ascontiguousarray(p0, dtype=float).reshape(-1, 2)
    p1 = np.ascontiguousarray(p1, dtype=float).reshape(-1, 2)
    r = np.ascontiguousarray(radius, dtype=float).reshape(-1)
    if not (grow > 0 and math.isfinite(grow)):
        raise InputError(f"bead_union needs a positive tolerance to grow by; got {grow!r}")
    if len(r) != len(p0) or len(p1) != len(p0):
        raise InputError("bead_union: p0, p1 and radius must have one row per bead")
    if len(r) and not (np.all(np.isfinite(r)) and r.min() > 0):
        raise InputError("bead_union: every bead radius must be positive and finite")
    rho = r + grow * SIDE
    rmax = r * inner + grow
    if len(r) and np.any(rho >= rmax):
        raise InputError(f"bead_union: the tolerance {grow!r} mm is too small for beads of "
                         f"radius up to {float(r.max())!r} mm")
    ax, ay = np.ascontiguousarray(p0[:, 0]), np.ascontiguousarray(p0[:, 1])
    bx, by = np.ascontiguousarray(p1[:, 0]), np.ascontiguousarray(p1[:, 1])
    if len(r) == 0:
        z = np.zeros(0)
        zi = np.zeros(1, np.int64)
        return BeadUnion(z, z, z, z, z, zi, z, z, z, z, z, np.zeros((0, 4)),
                         np.zeros(0, np.int64), z,
                         CellGrid(np.zeros(2, np.int64), np.zeros(0, np.int64), 0.0, 0.0, 1.0,
                                  1, 1),
                         z, z, z, z, z, 0.0, 0.0)
    off, ux, uy, h, vx, vy, box, k, phase = bead_polygons(ax, ay, bx, by, rho, rmax)
    grid = cell_grid(box)
    beads = Beads(ax, ay, bx, by, rho)
    polys = BeadPolygons(HalfPlanes(off, ux, uy, h), vx, vy, box, k, phase)
    parts: dict[int, np.ndarray] = {}

    def run(part: slice) -> None:
        parts[part.start] = boundary_pieces(beads, polys, grid, _EPS, part.start, part.stop)

    shared_out(run, np.ones(len(ax)), workers, min_items=_PARALLEL_MIN)
    edges = parts[0] if len(parts) == 1 else np.concatenate([parts[p] for p in sorted(parts)])
    area = green_area(edges, grid[2], grid[3])
    ex0, ey0, ex1, ey1, beyond = (np.ascontiguousarray(edges[:, c]) for c in range(5))
    return BeadUnion(ax, ay, bx, by, rho, off, ux, uy, h, vx, vy, box, k, phase, grid,
                     ex0, ey0, ex1, ey1, beyond, abs(float(area)),
                     float(np.hypot(ex1 - ex0, ey1 - ey0).sum()))


def union_contains_xy(u: BeadUnion, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Whether each point lies in G' (its closure: a point on ∂G' counts), like
    ``shapely.intersects_xy``."""
    x = np.ascontiguousarray(x, dtype=float).reshape(-1)
    y = np.ascontiguousarray(y, dtype=float).reshape(-1)
    out = np.zeros(len(x), dtype=bool)
    if len(u.ax):
        _contains(u.half_planes, u.grid, x, y, out)
    return out


def union_covers(u: BeadUnion, polygons: np.ndarray) -> np.ndarray:
    """``shapely.covers(G', polygon)`` for each polygon, with G' built only where it is.

    A polygon lies in G' exactly when it lies in the union of the bead polygons
    meeting its bounding box, so each test unions a handful of convex polygons;
    from :data:`_MANY` polygons on, G' is built whole once (and kept for the next
    calls on the same union).
    """
    polys = np.asarray(polygons, dtype=object).reshape(-1)
    out = np.zeros(len(polys), dtype=bool)
    if len(u.ax) == 0:
        return out
    if len(polys) >= _MANY:
        # many at once (the reference path of the tests): G' whole, built once per union
        return shapely.covers(_whole(u), polys)
    bounds = shapely.bounds(polys)
    for i, (poly, b) in enumerate(zip(polys, bounds, strict=True)):
        near = np.flatnonzero((u.box[:, 0] <= b[2]) & (u.box[:, 2] >= b[0])
                              & (u.box[:, 1] <= b[3]) & (u.box[:, 3] >= b[1]))
        if near.size:
            out[i] = bool(shapely.covers(shapely.union_all(u.polygons(near)), poly))
    return out


_MANY = 32
_whole_cache: list[tuple[BeadUnion, object]] = []


def _whole(u: BeadUnion):
    """G' as one prepared GEOS geometry, cached for the last few unions."""
    for v, g in _whole_cache:
        if v is u:
            return g
    g = u.geometry()
    shapely.prepare(g)
    _whole_cache.insert(0, (u, g))
    del _whole_cache[4:]
    return g


# ---------------------------------------------------------------------------- kernels


@numba.njit(cache=True, nogil=True)
def _contains(polygons, cells, x, y, out):  # pragma: no cover
    """Points in any bead polygon (closed), through the grid."""
    for p in range(len(x)):
        out[p] = in_polygons(x[p], y[p], polygons, cells)


@numba.njit(cache=True, nogil=True)
def in_polygons(px, py, polygons, cells):  # pragma: no cover
    """Whether the point lies in one of the bead polygons (closed): a point of G'.

    ``polygons`` is a :class:`~printability.planning.records.HalfPlanes`, ``cells`` the
    :class:`~printability.planning.records.CellGrid` listing them.
    """
    off, ux, uy, h = polygons
    c = _cell(py, cells.y0, cells.cell, cells.ny) * cells.nx \
        + _cell(px, cells.x0, cells.cell, cells.nx)
    start = cells.start
    items = cells.items
    for q in range(start[c], start[c + 1]):
        i = items[q]
        inside = True
        for j in range(off[i], off[i + 1]):
            if ux[j] * px + uy[j] * py > h[j]:
                inside = False
                break
        if inside:
            return True
    return False

"""Containment of a placed orifice in G, for :mod:`printability.mmc.sampled`.

A^u ⊆ int G for a connected orifice ⟺ one of its points is inside G and no edge of
∂G meets it. The kernel tests the edges near the placed orifice against the exact
shape in the orifice's own frame: a circle or ellipse (the edge, scaled to the unit
disk, comes within distance 1 of the origin), a rectangle (Liang–Barsky clipping),
or a polygon (an end inside, or an edge crossing).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.mmc.orifices import Orifice, offset_orifice
from printability.model.geometry import polygons_of
from printability.model.shapes import BOX, CONIC, POLYGON

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["ContainmentTest", "Edges", "boundary_edges", "containment_test",
           "run_containment_test"]



@numba.njit(cache=True)
def _segment_meets(kind, a, b, x0, y0, x1, y1, vx, vy, closed):  # pragma: no cover
    """Does the segment (local frame) meet the shape? ``closed``: touching counts."""
    if kind == CONIC:  # ellipse of semi-axes a, b (circle: a == b)
        x0, y0, x1, y1 = x0 / a, y0 / b, x1 / a, y1 / b
        dx, dy = x1 - x0, y1 - y0
        ll = dx * dx + dy * dy
        s = 0.0
        if ll > 0:
            s = min(1.0, max(0.0, -(x0 * dx + y0 * dy) / ll))
        px, py = x0 + s * dx, y0 + s * dy
        d2 = px * px + py * py
        # closed: a hair of margin so that tangency lost to rounding still counts
        return d2 <= 1.0 + 1e-9 if closed else d2 < 1.0
    if kind == BOX:
        if closed:  # a hair of margin so that tangency lost to rounding still counts
            a *= 1.0 + 1e-9
            b *= 1.0 + 1e-9
        else:  # the open box: shrink by a hair
            a *= 1.0 - 1e-12
            b *= 1.0 - 1e-12
        t0, t1 = 0.0, 1.0
        dx, dy = x1 - x0, y1 - y0
        for p, q in ((-dx, x0 + a), (dx, a - x0), (-dy, y0 + b), (dy, b - y0)):
            if p == 0.0:
                if q < 0.0:
                    return False
            else:
                r = q / p
                if p < 0.0:
                    t0 = max(t0, r)
                else:
                    t1 = min(t1, r)
                if t0 > t1:
                    return False
        return True
    # polygon rings as edges vx/vy pairs: (vx[2k], vy[2k]) -> (vx[2k+1], vy[2k+1])
    inside = False
    for k in range(0, len(vx), 2):
        ax, ay, bx, by = vx[k], vy[k], vx[k + 1], vy[k + 1]
        if (ay > y0) != (by > y0) and x0 < (bx - ax) * (y0 - ay) / (by - ay) + ax:
            inside = not inside
        d1 = (bx - ax) * (y0 - ay) - (by - ay) * (x0 - ax)
        d2 = (bx - ax) * (y1 - ay) - (by - ay) * (x1 - ax)
        d3 = (x1 - x0) * (ay - y0) - (y1 - y0) * (ax - x0)
        d4 = (x1 - x0) * (by - y0) - (y1 - y0) * (bx - x0)
        if closed:
            if d1 == 0.0 and d2 == 0.0:
                # collinear: they meet only if their extents overlap along the line
                if abs(bx - ax) >= abs(by - ay):
                    lo1, hi1 = min(ax, bx), max(ax, bx)
                    lo2, hi2 = min(x0, x1), max(x0, x1)
                else:
                    lo1, hi1 = min(ay, by), max(ay, by)
                    lo2, hi2 = min(y0, y1), max(y0, y1)
                if lo2 <= hi1 and lo1 <= hi2:
                    return True
            elif d1 * d2 <= 0.0 and d3 * d4 <= 0.0:
                return True
        elif d1 * d2 < 0.0 and d3 * d4 < 0.0:
            return True
    return inside


class Edges(NamedTuple):
    """The edges (x0, y0) → (x1, y1) of ∂G in square buckets, for the containment kernel.

    Bucket (gx, gy), of side ``cs`` from the corner (gx0, gy0) on a ``gnx`` × ``gny`` grid,
    holds the edges ``items[start[c]:start[c + 1]]``, c = gy·gnx + gx (CSR).
    """

    x0: np.ndarray
    y0: np.ndarray
    x1: np.ndarray
    y1: np.ndarray
    start: np.ndarray
    items: np.ndarray
    gx0: float
    gy0: float
    cs: float
    gnx: int
    gny: int


class _PlacedShape(NamedTuple):
    """A :class:`ContainmentTest` as the kernel reads it: the shape's centre (cx, cy) in
    the nozzle frame, its frame turned by ``psi`` radians, its kind and semi-axes (a, b),
    its reach, its polygon edge ends (vx, vy) and whether touching counts."""

    cx: float
    cy: float
    psi: float
    kind: int
    a: float
    b: float
    reach: float
    vx: np.ndarray
    vy: np.ndarray
    closed: bool


@numba.njit(cache=True)
def _clear_of_boundary(tx, ty, phi, shape, edges):  # pragma: no cover
    """Per pose (t, φ radians): no edge of ``edges`` (∂G) meets ``shape`` placed there."""
    n = len(tx)
    ok = np.ones(n, dtype=np.bool_)
    cs, gx0, gy0, gnx = edges.cs, edges.gx0, edges.gy0, edges.gnx
    reach = shape.reach
    for i in range(n):
        c, s = math.cos(phi[i]), math.sin(phi[i])
        wx = tx[i] + c * shape.cx - s * shape.cy  # orifice centre
        wy = ty[i] + s * shape.cx + c * shape.cy
        cp, sp = math.cos(phi[i] + shape.psi), math.sin(phi[i] + shape.psi)
        ix0 = max(math.floor((wx - reach - gx0) / cs), 0)
        ix1 = min(math.floor((wx + reach - gx0) / cs), gnx - 1)
        iy0 = max(math.floor((wy - reach - gy0) / cs), 0)
        iy1 = min(math.floor((wy + reach - gy0) / cs), edges.gny - 1)
        hit = False
        for gy in range(iy0, iy1 + 1):
            for gx in range(ix0, ix1 + 1):
                cell = gy * gnx + gx
                for m in range(edges.start[cell], edges.start[cell + 1]):
                    e = edges.items[m]
                    # the edge in the orifice's frame: R(−(φ+ψ))·(p − w)
                    ax, ay = edges.x0[e] - wx, edges.y0[e] - wy
                    bx, by = edges.x1[e] - wx, edges.y1[e] - wy
                    lx0, ly0 = cp * ax + sp * ay, -sp * ax + cp * ay
                    lx1, ly1 = cp * bx + sp * by, -sp * bx + cp * by
                    if _segment_meets(shape.kind, shape.a, shape.b, lx0, ly0, lx1, ly1,
                                      shape.vx, shape.vy, shape.closed):
                        hit = True
                        break
                if hit:
                    break
            if hit:
                break
        ok[i] = not hit
    return ok


def boundary_edges(g: BaseGeometry, cell: float) -> Edges:
    """The edges of ∂G in square buckets of side ``cell`` mm (an edge in every bucket its
    bounding box overlaps)."""
    segs = []
    for poly in polygons_of(g):
        for ring in (poly.exterior, *poly.interiors):
            c = np.asarray(ring.coords)
            segs.append(np.column_stack([c[:-1], c[1:]]))
    e = np.concatenate(segs)
    minx, miny, maxx, maxy = g.bounds
    gx0, gy0 = minx - cell, miny - cell
    gnx = math.ceil((maxx - gx0) / cell) + 2
    gny = math.ceil((maxy - gy0) / cell) + 2
    bx0 = np.floor((np.minimum(e[:, 0], e[:, 2]) - gx0) / cell).astype(np.int64)
    bx1 = np.floor((np.maximum(e[:, 0], e[:, 2]) - gx0) / cell).astype(np.int64)
    by0 = np.floor((np.minimum(e[:, 1], e[:, 3]) - gy0) / cell).astype(np.int64)
    by1 = np.floor((np.maximum(e[:, 1], e[:, 3]) - gy0) / cell).astype(np.int64)
    cells, ids = [], []
    for k in range(len(e)):  # an edge goes in every cell its bounding box overlaps
        xs = np.arange(bx0[k], bx1[k] + 1)
        ys = np.arange(by0[k], by1[k] + 1)
        cc = (ys[:, None] * gnx + xs[None, :]).ravel()
        cells.append(cc)
        ids.append(np.full(len(cc), k))
    cells_a = np.concatenate(cells)
    ids_a = np.concatenate(ids)
    order = np.argsort(cells_a, kind="stable")
    counts = np.bincount(cells_a, minlength=gnx * gny)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    col = [np.ascontiguousarray(e[:, i]) for i in range(4)]
    return Edges(*col, start, ids_a[order].astype(np.int64), float(gx0), float(gy0),
                  float(cell), int(gnx), int(gny))


@dataclass(frozen=True, eq=False)
class ContainmentTest:
    """Containment test of one orifice (or a shrunk version of it) at many poses."""

    center: tuple[float, float]   # an interior point, nozzle frame
    psi: float                    # orientation of the shape frame, degrees
    kind: int
    a: float
    b: float
    reach: float                  # the shape lies within this distance of ``center``
    edges: np.ndarray             # (2k,) x then y of polygon edge ends (polygons only)
    closed: bool                  # touching ∂G counts as leaving G (feasibility test)
    empty: bool = False


def containment_test(o: Orifice, shrink: float, *, closed: bool) -> ContainmentTest:
    """The exact test of orifice ``o``, shrunk by ``shrink`` mm (inside the true erosion)."""
    axes = o.shape.eroded(shrink)
    if axes is not None:
        a, b = axes
        return ContainmentTest(o.center, o.frame_angle, o.shape.code, a, b,
                               math.hypot(a, b) * 1.000001, np.zeros(0), closed,
                               empty=min(a, b) <= 0)
    poly = offset_orifice(o, "outer" if closed else "inner", -shrink) if shrink else (
        o.outer if closed else o.inner)
    ends = []
    for part in polygons_of(poly):
        for ring in (part.exterior, *part.interiors):
            c = np.asarray(ring.coords)
            ends.append(np.column_stack([c[:-1], c[1:]]).reshape(-1, 2))
    if not ends:
        return ContainmentTest(o.center, 0.0, POLYGON, 0.0, 0.0, 0.0, np.zeros(0), closed,
                               empty=True)
    pts = np.concatenate(ends)
    edges = np.concatenate([pts[:, 0], pts[:, 1]])
    reach = float(np.hypot(pts[:, 0], pts[:, 1]).max()) * 1.000001
    # polygons are tested in the nozzle frame itself: centre (0, 0), no extra turn
    return ContainmentTest((0.0, 0.0), 0.0, POLYGON, 0.0, 0.0, reach, edges, closed)


def run_containment_test(test: ContainmentTest, inside_pt: tuple[float, float], g: BaseGeometry,
                         edges: Edges, phi: np.ndarray, t: np.ndarray,
                         candidates: np.ndarray) -> tuple[np.ndarray, int]:
    """Which poses (among ``candidates``) put the tested shape inside G.

    ``inside_pt`` is a point of the shape (nozzle frame): it must be over G.
    Also returns how many candidates have that point over G.
    """
    ok = np.zeros(len(phi), dtype=bool)
    idx = np.flatnonzero(candidates)
    if len(idx) == 0 or test.empty:
        return ok, 0
    a = np.deg2rad(phi[idx])
    cx, cy = inside_pt
    wx = t[idx, 0] + np.cos(a) * cx - np.sin(a) * cy
    wy = t[idx, 1] + np.sin(a) * cx + np.cos(a) * cy
    minx, miny, maxx, maxy = g.bounds
    inb = (wx > minx) & (wx < maxx) & (wy > miny) & (wy < maxy)
    idx = idx[inb]
    inside = shapely.contains_xy(g, wx[inb], wy[inb])
    idx = idx[inside]
    if len(idx) == 0:
        return ok, 0
    n_v = len(test.edges) // 2
    vx = np.ascontiguousarray(test.edges[:n_v]) if n_v else np.zeros(2)
    vy = np.ascontiguousarray(test.edges[n_v:]) if n_v else np.zeros(2)
    shape = _PlacedShape(test.center[0], test.center[1], math.radians(test.psi), test.kind,
                         test.a, test.b, test.reach, vx, vy, test.closed)
    ok[idx] = _clear_of_boundary(
        np.ascontiguousarray(t[idx, 0]), np.ascontiguousarray(t[idx, 1]),
        np.ascontiguousarray(np.deg2rad(phi[idx])), shape, edges)
    return ok, len(idx)



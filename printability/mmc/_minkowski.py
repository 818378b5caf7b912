"""Minkowski erosion and dilation by a polygonal footprint, for the exact engine.

Rectangles and polygons (SVG outlines) need no offsets. Notation as in
:mod:`printability.mmc.exact`.

For a path-connected footprint K and any k₀ ∈ K,

    P = (G − k₀) \\ (∂G ⊕ (−K)),     P ⊕ K = (P + k₀) ∪ (∂P ⊕ K),

up to boundaries (sets of zero area). *Proof.* t ∈ ∂G ⊕ (−K) ⟺ (K + t)
meets ∂G. If K + t lies in the interior of G it contains k₀ + t ∈ G and
misses ∂G. Conversely, if k₀ + t ∈ G and K + t misses ∂G, the connected
set K + t cannot leave G without crossing ∂G, so K + t ⊆ G. For the
dilation, ⊇ is clear since ∂P ⊆ P (P closed). For ⊆, take x = p + k with
p ∈ P, k ∈ K and x ∉ P + k₀; follow a path k(s) in K from k₀ to k: the
point x − k(s) starts outside P and ends in P, so for some s it lies on
∂P, and x = (x − k(s)) + k(s) ∈ ∂P ⊕ K. ∎ With K = ∪ K_i (convex pieces,
a constrained Delaunay triangulation when K is not convex) and ∂G the
union of its segments e, e ⊕ K_i is the convex hull of the two translated
copies of K_i, so both sets are unions of convex hulls: no approximation
beyond floating point.

P and S are thus unions and differences of convex hulls, exact up to
rounding; P is then checked with exact predicates (no hull of positions where
the footprint meets ∂G may share interior with P) and any such hull is cut
again (:func:`minkowski_erode`).

Complexity: O(n·m) convex hulls for n boundary segments and m convex pieces
of the footprint, then a union. Memory O(n·m).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

from printability.mmc._offset_bands import (
    EMPTY,
    as_multi,
    boundary_segments,
    union_in_order,
)
from printability.model.geometry import polygons_of
from printability.model.shapes import convex_decomposition

__all__ = ["convex_pieces", "largest_polygon", "minkowski_dilate", "minkowski_erode"]


def convex_pieces(k: Polygon) -> list[Polygon]:
    """K as a union of convex polygons (itself, or a constrained Delaunay triangulation),
    normalized first so that the pieces do not depend on K's vertex order."""
    return list(convex_decomposition(shapely.normalize(k)))


def _boundary_minkowski(geom: BaseGeometry, pieces: Sequence[Polygon], sign: float) -> BaseGeometry:
    """∂geom ⊕ (sign·K) for K = ∪ pieces (convex), as a union of convex hulls."""
    hulls = _boundary_hulls(geom, pieces, sign)
    return union_in_order(hulls) if len(hulls) else EMPTY


def _boundary_hulls(geom: BaseGeometry, pieces: Sequence[Polygon], sign: float) -> np.ndarray:
    """The convex hulls e ⊕ sign·K_i, one per boundary segment e and convex piece K_i."""
    segs = boundary_segments(geom)
    if len(segs) == 0 or not pieces:
        return np.empty(0, dtype=object)
    hulls = []
    for piece in pieces:
        v = sign * np.asarray(piece.exterior.coords)[:-1]
        pts = np.concatenate([segs[:, :1, :] + v[None], segs[:, 1:, :] + v[None]], axis=1)
        mp = shapely.multipoints(pts.reshape(-1, 2), indices=np.repeat(np.arange(len(segs)),
                                                                       pts.shape[1]))
        hulls.append(shapely.convex_hull(mp))
    return np.concatenate(hulls)


def minkowski_erode(g: BaseGeometry, k: BaseGeometry) -> MultiPolygon:
    """P = {t : K + t ⊆ G} for a connected polygonal footprint K (exact up to rounding).

    Computed as (G − k₀) \\ (∂G ⊕ (−K)), k₀ a point of K (proof in the
    module docstring). Cost O(n·m) convex hulls for n boundary segments and
    m convex pieces of K, then a union.
    """
    k = largest_polygon(k)
    if k is None or g.is_empty:
        return EMPTY
    k0 = k.representative_point()
    hulls = _boundary_hulls(g, convex_pieces(k), -1.0)
    moved = shapely.affinity.translate(g, -k0.x, -k0.y)
    p = as_multi(shapely.difference(moved, union_in_order(hulls)))
    # MMC check with exact predicates: no hull (a set of positions where the
    # footprint meets ∂G) may share interior points with P; cut any that does
    tree = shapely.STRtree(hulls)
    for _ in range(3):
        parts = np.asarray(polygons_of(p), dtype=object)
        if len(parts) == 0:
            break
        ip, ih = tree.query(parts, predicate="intersects")
        inside = shapely.relate_pattern(parts[ip], hulls[ih], "T********")
        ip, ih = ip[inside], ih[inside]
        # ignore rounding slivers along the shared boundary
        common = shapely.area(shapely.intersection(parts[ip], hulls[ih]))
        bad = np.unique(ih[common > 1e-9 * shapely.area(hulls[ih])])
        if len(bad) == 0:
            break
        cut = hulls[bad[0]]
        for h in hulls[bad[1:]]:
            cut = shapely.union(cut, h)
        p = as_multi(shapely.difference(p, cut))
    return p


def minkowski_dilate(p: BaseGeometry, pieces: Sequence[Polygon]) -> MultiPolygon:
    """P ⊕ K for K = ∪ pieces (convex polygons forming a connected set).

    Computed as (P + k₀) ∪ (∂P ⊕ K) (proof in the module docstring).
    """
    if p.is_empty or not pieces:
        return EMPTY
    k0 = pieces[0].representative_point()
    moved = shapely.affinity.translate(p, k0.x, k0.y)
    band = _boundary_minkowski(p, pieces, 1.0)
    return as_multi(shapely.union(moved, band))


def largest_polygon(geom: BaseGeometry) -> Polygon | None:
    """The polygon of ``geom`` of largest area (None when it has none)."""
    polys = polygons_of(geom)
    return max(polys, key=lambda q: q.area) if polys else None

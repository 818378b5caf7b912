"""Certified offsets by a disk: inner and outer G ⊖ D_r and P ⊕ D_r, for the exact engine.

D_r is the closed disk of radius r about the origin; P, S and the footprints
are as in :mod:`printability.mmc.exact`, which offsets the unit disk of its
affine trick with :func:`erode_disk` and :func:`dilate_disk`.

How the offsets are certified
-----------------------------
GEOS (behind shapely) offsets by replacing every circular arc of radius d by
chords whose end points lie *on* the arc: a fillet of turn θ gets
round(θ/q₀) chords, q₀ = π/(2·quad_segs), so a chord spans at most 1.5·q₀
and stays ≥ κ·d from the centre, κ = cos(3π/(8·quad_segs)) (0.99932 at the
default 32); full circles and round caps use exactly q₀ per chord. GEOS also
takes shortcuts: (i) before offsetting a ring or line it deletes "shallow
concavities", vertices turning towards the offset side closer than 0.01·d
to their neighbours' chord, and this cascades (on a finely drawn round cap
of radius ≈ r it cuts the cap, and the tip of P behind it retreats by up to
r/sin(half-angle)); (ii) it snaps the two offset points of a vertex when
they are closer than 10⁻³·d (a turn under 10⁻³ rad); (iii) at an inside turn
whose offset segments miss each other it adds closing segments towards the
vertex (this only shrinks the offset region). A plain ``buffer(-r).buffer(r)``
therefore both loses and *leaks* material (past reflex corners). We never
offset a polygon; we offset its boundary as open lines, one side at a time,
and check. For a disk of radius r (the unit disk in the affine trick's
mapped plane):

* **Bands without shortcuts.** Each ring is cut into open lines at two
  vertices at least (GEOS buffers a closed line as a ring) and at every
  vertex where a shortcut could act on the side being offset: shallow
  vertices turning towards that side (closer than 0.0125·d to their
  neighbours' chord) and turns under 2·10⁻³ rad or within 2·10⁻³ of a
  U-turn. GEOS never deletes a line's vertex 1, so the first pass of its
  simplifier finds nothing and stops. A one-sided offset of each piece by
  d = r·(1 − 10⁻⁵), plus a disk at piece ends that may turn towards that
  side, is then a subset of the true band ∂G ⊕ D_r on that side: exact on
  straight parts, inscribed on arcs. A piece GEOS fails on is left out (a
  smaller band). Unions are re-checked with a point inside every part (GEOS's
  cascaded union was seen to drop a nearly degenerate part silently).
* **P_inner ⊆ P (the MMC promise).** P_raw = G minus the inner band at
  r·(1 + 10⁻⁷) is *verified*: the distance to ∂G has no local minimum inside
  G, so P_raw ⊆ G ⊖ D_r iff each boundary edge of P_raw is ≥ r from each
  segment of ∂G; an STR tree lists the closer pairs (exact segment
  distances). A chord (a, b) of an arc round a reflex vertex v is replaced by
  a → t → b with t where the tangents at a and b meet (edges ≥ r from v; the
  triangle holds the part of D(v, r) beyond the chord); any other violation
  cuts a fan (reflex vertex), a disk (other vertex) or a stadium (segment)
  containing the offending disk part. New edges are checked again; after
  four rounds a global inflation by 1/(κ − 1.05·10⁻³) covering every
  shortcut is used instead. *This is the set the engine reports as P.*
* **S_inner ⊆ P_inner ⊕ D_r ⊆ S.** P ⊕ D_r = P ∪ (∂P ⊕ D_r), and the outer
  band is a subset of ∂P ⊕ D_r.
* **P ⊆ P_outer and S ⊆ S_outer.** P_outer = G minus the two-sided band of
  ∂G (a subset of ∂G ⊕ D_r that holds ∂G strictly inside, so no rounding
  slivers are left along ∂G to be dilated later), a superset of P. S_outer = the complement of
  the verified erosion of P_outer's complement (within a frame),
  intersected with G: (Pᶜ ⊖ D_r)ᶜ = P ⊕ D_r.
* Zero-area holes (slits left by unions of touching pieces) are closed:
  their points are limits of the region's points, and every set above is
  closed, so no area or containment changes (an eroded slit would otherwise
  kill every position within r of it).

The argument relies on GEOS's offset algorithm as published
(OffsetSegmentGenerator, BufferInputLineSimplifier: the constants of
:mod:`printability.mmc._offset_bands`) for the bands; P_inner does not rely
on it (verified). In the functions' terms: P_inner is :func:`erode_disk`
(inner, :func:`certified_erosion`), S_inner :func:`dilate_disk` (inner,
:func:`~printability.mmc._offset_bands.side_band`), P_outer
:func:`erode_disk` with ``outer``
(:func:`~printability.mmc._offset_bands.two_sided_band`) and S_outer
:func:`dilate_disk` with ``outer``, intersected with G by the engine. The
bands, and the cutting of the rings into lines, are in
:mod:`printability.mmc._offset_bands`.

Complexity
----------
For n boundary vertices: O(n) one-sided offset pieces and their union (the
dominant cost), STR-tree checks O(n log n). That is the price of the
certificate: tens to hundreds of times a plain ``buffer(-r).buffer(r)`` (see
``benchmarks/bench_exact.py``).
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Point, Polygon
from shapely.geometry.base import BaseGeometry

from printability.errors import InputError
from printability.mmc._offset_bands import (
    EMPTY,
    FLOAT_MARGIN,
    REDUNDANT,
    as_multi,
    boundary_segments,
    side_band,
    two_sided_band,
    union_in_order,
)
from printability.model.geometry import polygons_of

__all__ = [
    "certified_erosion",
    "chord_factor",
    "dilate_disk",
    "disk_cover",
    "erode_disk",
]

_MAX_FIXES = 4  # rounds of local repair of a verified erosion before the global fallback


def chord_factor(quad_segs: int) -> float:
    """κ = cos(3π/(8·quad_segs)): GEOS fillet chords keep ≥ κ·d from the arc's centre.

    GEOS splits a fillet of turn θ into round(θ/q₀) chords, q₀ = π/(2·quad_segs), so
    a chord spans at most 1.5·q₀. κ = 0.99932 at 32 segments, 0.98079 at 4.
    """
    if quad_segs < 2:
        raise InputError(f"quad_segs={quad_segs} is too coarse for a certified offset; use ≥ 2")
    return math.cos(3.0 * math.pi / (8.0 * quad_segs))


def disk_cover(quad_segs: int) -> float:
    """Radius factor of a GEOS point/segment buffer that contains the exact disk/stadium.

    Circles and caps use exactly quad_segs chords per quarter: chord midpoints at
    R·cos(π/(4·quad_segs)).
    """
    return (1.0 + FLOAT_MARGIN) / math.cos(math.pi / (4.0 * quad_segs))


def certified_erosion(g: BaseGeometry, r: float, quad_segs: int) -> MultiPolygon:
    """A subset of G ⊖ D_r, checked point by point against ∂G.

    A negative buffer by r·(1 + 10⁻⁷) is exact on straight parts but, near
    reflex corners (chords inside the arcs) or where GEOS took a shortcut,
    may come closer than r to ∂G. Since the distance to ∂G has no local
    minimum inside G, the whole region is ≥ r from ∂G iff its boundary edges
    are; an STR tree finds every boundary edge closer than r to a segment of
    ∂G. Where the nearest point is a reflex vertex v of G, a fan polygon
    containing the sector of D(v, r) between the normals of v's two segments
    (where the arc's chords lie) is cut away; at any other vertex the whole
    disk, inside a segment s the stadium around s. The check is repeated on
    the edges the cuts created; should it still fail after
    :data:`_MAX_FIXES` rounds, the global inflation by 1/(κ − 1.05·10⁻³) −
    which covers every shortcut at once − is used.
    """
    polys = [shapely.geometry.polygon.orient(q, 1.0) for q in polygons_of(g)]
    if not polys:
        return EMPTY
    g = MultiPolygon(polys)  # exteriors CCW, holes CW: G's interior on the left
    # not a negative polygon buffer: GEOS would first simplify G's rings, and on
    # a finely drawn round cap of radius ≈ r that cascades into cutting the cap
    # (a tip of P retreating by up to r/sin(half-angle))
    raw = as_multi(shapely.difference(g, side_band(g, r * (1 + FLOAT_MARGIN) / (1 - REDUNDANT),
                                                      quad_segs, +1)))
    segs, nxt = _ring_segments(g)
    prv = np.empty_like(nxt)
    prv[nxt] = np.arange(len(nxt))
    seg_geoms = shapely.linestrings(segs)
    tree = shapely.STRtree(seg_geoms)
    cover = r * disk_cover(quad_segs)
    # rounding slivers along ∂G (where the band's edge meets G's) have no area:
    # drop them (a subset stays a subset) instead of cutting them round by round
    minx, miny, maxx, maxy = g.bounds
    tiny = 1e-12 * max(maxx - minx, maxy - miny) ** 2
    passed: set[bytes] = set()  # edges found ≥ r from ∂G (exact coordinates)
    for _ in range(_MAX_FIXES):
        raw = MultiPolygon([q for q in raw.geoms if q.area > tiny])
        edges = boundary_segments(raw)
        if len(edges) == 0:
            return raw
        keys = [e.tobytes() for e in edges]
        fresh = np.fromiter((k not in passed for k in keys), bool, len(keys))
        fresh_idx = np.flatnonzero(fresh)  # position of each checked edge in raw's rings
        edges = edges[fresh]
        if len(edges) == 0:
            return raw
        e_geoms = shapely.linestrings(edges)
        ie, js = tree.query(e_geoms, predicate="dwithin", distance=r)
        near = shapely.distance(e_geoms[ie], seg_geoms[js]) < r
        ie, js = ie[near], js[near]
        # only edges that passed are remembered: a violating edge that survives
        # a cut with the same coordinates is checked (and cut) again
        bad_edges = np.zeros(len(edges), bool)
        bad_edges[ie] = True
        passed.update(k for k, bad in zip((keys[i] for i in fresh_idx), bad_edges, strict=True)
                      if not bad)
        if len(ie) == 0:
            return raw
        foot = shapely.get_coordinates(shapely.shortest_line(seg_geoms[js], e_geoms[ie]))[::2]
        ends = segs[js]
        tol = 1e-9 * (1.0 + np.abs(ends).max())
        at0 = np.hypot(*(foot - ends[:, 0]).T) <= tol
        at1 = np.hypot(*(foot - ends[:, 1]).T) <= tol
        at_vertex = at0 | at1
        v = np.where(at0[:, None], ends[:, 0], ends[:, 1])
        # the usual case: a fillet chord (a, b) of the arc of radius r' round v.
        # Cut the triangle (a, t, b), t where the tangents at a and b meet: its
        # new edges are tangent to that circle, so ≥ r' > r from v, and it holds
        # the part of D(v, r) beyond the chord. No notch in the straight offsets.
        a, b = edges[ie, 0], edges[ie, 1]
        rr = r * (1 + FLOAT_MARGIN)
        on_arc = (at_vertex & (np.abs(np.hypot(*(a - v).T) / rr - 1) < 1e-6)
                  & (np.abs(np.hypot(*(b - v).T) / rr - 1) < 1e-6))
        mid = (a + b) / 2 - v
        m2 = np.einsum("ij,ij->i", mid, mid)
        on_arc &= m2 > (0.5 * rr) ** 2  # chords under 120°: the tangents meet nearby
        tip = v + mid * (rr * rr / np.where(on_arc, m2, 1.0))[:, None]
        # cut the triangles by inserting their tips into the rings (a union of
        # thousands of adjacent triangles costs seconds; this is linear)
        notched = _insert_tips(raw, fresh_idx[ie[on_arc]], tip[on_arc])
        cutters: list[BaseGeometry] = []
        if notched is None:
            tri = np.stack([a, tip, b, a], axis=1)[on_arc]
            cutters = list(shapely.polygons(tri)) if len(tri) else []
        # anything else: a fan at a reflex vertex, a disk elsewhere, a stadium
        # round a segment (a vertex is named by its incoming segment)
        rest = at_vertex & ~on_arc
        corners = np.unique(np.concatenate([prv[js[rest & at0 & ~at1]], js[rest & at1]]))
        if len(corners):
            u = segs[corners, 1] - segs[corners, 0]
            w = segs[nxt[corners], 1] - segs[nxt[corners], 0]
            fan = (u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]) < 0
            cutters += [_corner_cutter(segs[i], segs[nxt[i]], r, quad_segs, cover)
                        for i in corners[fan]]
            cutters += list(shapely.buffer(shapely.points(segs[corners[~fan], 1]), cover,
                                           quad_segs=quad_segs))
        inner = np.unique(js[~at_vertex])
        if len(inner):
            cutters += list(shapely.buffer(seg_geoms[inner], cover, quad_segs=quad_segs))
        if notched is not None:
            raw = notched
        if cutters:
            raw = shapely.difference(raw, union_in_order(np.asarray(cutters)))
        # drop the collinear vertices the tangent triangles leave at chord ends (a
        # 10⁻⁹·r move, re-verified next round): they would split the offset pieces
        raw = as_multi(shapely.simplify(raw, 1e-9 * r))
        # edges that survived the cut keep their coordinates and stay verified; the
        # ones just checked and found too close are gone with the cut
    # global fallback: every GEOS shortcut moves the offset by < 1.05·10⁻³·d
    fallback = r * (1 + FLOAT_MARGIN) / (chord_factor(quad_segs) - 1.05e-3)
    return as_multi(shapely.intersection(shapely.buffer(g, -fallback, quad_segs=quad_segs), g))


def _insert_tips(raw: MultiPolygon, seg_idx: np.ndarray, tips: np.ndarray) -> MultiPolygon | None:
    """``raw`` with ``tips[k]`` inserted after the start of boundary segment ``seg_idx[k]``.

    Segment numbers are those of :func:`boundary_segments` (rings in order).
    Each insertion cuts the triangle (a, tip, b) from the region. Returns None
    when the result is not a valid polygon (a part thinner than a notch), so
    the caller can cut the triangles by an overlay instead.
    """
    if len(seg_idx) == 0:
        return raw
    seg_idx, first = np.unique(seg_idx, return_index=True)
    tips = tips[first]
    parts = np.asarray(polygons_of(raw), dtype=object)
    rings = shapely.get_rings(parts)
    coords, ring_idx = shapely.get_coordinates(rings, return_index=True)
    start = np.flatnonzero(ring_idx[1:] == ring_idx[:-1])  # coordinate index of each segment
    at = start[seg_idx] + 1
    coords = np.insert(coords, at, tips, axis=0)
    ring_idx = np.insert(ring_idx, at, ring_idx[at - 1])
    new_rings = shapely.linearrings(coords, indices=ring_idx)
    per_poly = shapely.get_num_interior_rings(parts) + 1
    polys = shapely.polygons(new_rings, indices=np.repeat(np.arange(len(parts)), per_poly))
    out = MultiPolygon(list(polys))
    return out if out.is_valid else None


def _ring_segments(g: MultiPolygon) -> tuple[np.ndarray, np.ndarray]:
    """Boundary segments (m, 2, 2) in ring order and, for each, the next one in its ring."""
    rings = shapely.get_rings(np.asarray(polygons_of(g), dtype=object))
    coords, idx = shapely.get_coordinates(rings, return_index=True)
    same = idx[1:] == idx[:-1]
    segs = np.stack([coords[:-1][same], coords[1:][same]], axis=1)
    ring = idx[:-1][same]
    nxt = np.arange(1, len(segs) + 1)
    last = np.r_[ring[1:] != ring[:-1], True]
    first = np.r_[True, ring[1:] != ring[:-1]]
    nxt[last] = np.flatnonzero(first)
    return segs, nxt


def _corner_cutter(
    s_in: np.ndarray, s_out: np.ndarray, r: float, quad_segs: int, cover: float
) -> Polygon:
    """A polygon containing D(v, r) wherever P's arc round the vertex v can be.

    v joins segment ``s_in`` to ``s_out``. At a reflex vertex (G's interior on
    the left, the boundary turns right by α) the offset arc spans the inward
    normals from n(s_in) clockwise to n(s_out): the cutter is the fan from v
    through points at radius r/cos(step/2) over that range widened by a
    quarter quantum each side (its chords stay ≥ r from v). Elsewhere: the
    whole disk cover.
    """
    v = s_in[1]
    u, w = s_in[1] - s_in[0], s_out[1] - s_out[0]
    lu, lw = math.hypot(*u), math.hypot(*w)
    cross = u[0] * w[1] - u[1] * w[0]
    if lu == 0 or lw == 0 or cross >= 0:
        return shapely.buffer(Point(*v), cover, quad_segs=quad_segs)
    q0 = math.pi / (2 * quad_segs)
    turn = math.atan2(-cross, float(u @ w))
    a0 = math.atan2(u[0], -u[1]) + q0 / 4  # left normal of u, widened
    span = turn + q0 / 2
    k = max(1, math.ceil(span / q0))
    step = span / k
    rad = r * (1 + FLOAT_MARGIN) / math.cos(step / 2)
    ang = a0 - step * np.arange(k + 1)
    fan = np.vstack([v, v + rad * np.column_stack([np.cos(ang), np.sin(ang)])])
    return Polygon(fan)


def erode_disk(g: BaseGeometry, r: float, *, quad_segs: int, outer: bool = False) -> MultiPolygon:
    """G ⊖ D_r, as an inner (default) or outer polygonal approximation.

    Parameters
    ----------
    g
        The region (polygonal geometry), mm.
    r
        Disk radius, mm (≥ 0).
    quad_segs
        Chords per quarter circle used by GEOS.
    outer
        False: a subset of the exact erosion (:func:`certified_erosion`).
        True: a superset, G minus a subset of ∂G ⊕ D_r
        (:func:`two_sided_band`).

    Notes
    -----
    Both are exact along straight offsets (up to 10⁻⁵·r); they differ from
    the exact erosion only within r·(1/κ − 1) of the arcs around reflex
    corners (κ from :func:`chord_factor`). Cost: a union of O(n) one-sided
    offset pieces for n vertices, plus O(n log n) checks (inner).
    """
    if r <= 0:
        return as_multi(g)
    if not outer:
        return certified_erosion(g, r, quad_segs)
    return as_multi(shapely.difference(g, two_sided_band(g, r, quad_segs)))


def dilate_disk(p: BaseGeometry, r: float, *, quad_segs: int, outer: bool = False) -> MultiPolygon:
    """P ⊕ D_r, as an inner (default) or outer polygonal approximation.

    Inner: P ∪ :func:`side_band` (∂P, r, outer side), a subset of
    P ⊕ D_r = P ∪ (∂P ⊕ D_r).
    Outer: the complement of a certified erosion of P's complement (within a
    frame): (Pᶜ ⊖ D_r)ᶜ = P ⊕ D_r, so a subset of the erosion gives a superset.
    Both are exact along straight offsets; the arcs differ by ≤ r·(1/κ − 1).
    The inner one's slits (:func:`as_multi`: holes narrower than 10⁻⁶·r, inside
    the band's margin of 10⁻⁵·r) are closed.
    """
    if r <= 0 or p.is_empty:
        return as_multi(p)
    if outer:
        minx, miny, maxx, maxy = p.bounds
        m = 2.0 * r + 1.0
        frame = shapely.box(minx - m, miny - m, maxx + m, maxy + m)
        eroded = certified_erosion(shapely.difference(frame, p), r, quad_segs)
        grown = 1.01 * r
        return as_multi(shapely.difference(
            shapely.box(minx - grown, miny - grown, maxx + grown, maxy + grown), eroded))
    return as_multi(shapely.union(p, side_band(p, r, quad_segs, -1)), thin=1e-6 * r)

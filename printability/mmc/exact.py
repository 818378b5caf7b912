"""The exact (vector) MMC engine: P and S as shapely polygons, with certified bounds.

For a separable machine (XY, T-T-R) the nozzle at angle φ is the footprint
A_φ = R(φ)·A⁰ and (DESIGN.md §2, conventions in :mod:`printability.geometry`)

    P_φ = {t : A_φ + t ⊆ G} = G ⊖ A_φ,      S = ∪_φ (P_φ ⊕ A_φ).

Three footprint families are handled without rasterising anything.

Circles and ellipses (the affine trick)
    An elliptical orifice is A = c + L·D with D the unit disk, c its centre
    and L = R(φ + ρ)·diag(a, b) (a circle is a = b). Since L is invertible,
    A + t ⊆ G ⟺ D + L⁻¹(t + c) ⊆ L⁻¹G, so P = L·(L⁻¹G ⊖ D) − c and
    P ⊕ A = L·(L⁻¹(P + c) ⊕ D): one inward and one outward offset of a unit
    disk in the mapped plane (:func:`shapely.affinity.affine_transform`),
    then mapped back. Affine maps preserve inclusions, so every containment
    proved below in the mapped plane holds after mapping back.
Rectangles and polygons (Minkowski operations)
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
Heads with several orifices
    Every orifice must stay inside G: P = ∩_j P_j (each orifice's own P) and
    S = ∪_j (P ⊕ A_j).

Why the result is safe (MMC) and how the bounds are certified
-------------------------------------------------------------
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

Hence λ(G \\ S_outer) ≤ λ(G \\ S) ≤ λ(G \\ S_inner): the reported
``lost_area_bounds`` contain the exact lost area of the sampled angles, and
differ from it only by slivers within r·(1/κ − 1) of arcs (≈ 10⁻³ of the
lost area on the rectangle test). The argument relies on GEOS's offset
algorithm as published (OffsetSegmentGenerator, BufferInputLineSimplifier:
the constants above) for the bands; P_inner does not rely on it (verified).

Polygons (rectangles, SVG outlines) need no offsets: P and S are unions
and differences of convex hulls, exact up to rounding; P is then checked
with exact predicates (no hull of positions where the footprint meets ∂G
may share interior with P) and any such hull is cut again.

T-T-R between samples. Turning by |Δ| ≤ Δφ/2 (half the largest gap between
consecutive sampled angles, wrapping over the symmetry period) moves no
nozzle point by more than δ = ρ·Δφ/2 (ρ = ``nozzle.radius``, Δφ in radians),
so A_k ⊖ D_δ ⊆ A_φ ⊆ A_k ⊕ D_δ for the nearest sample φ_k. Then
P_φ ⊆ G ⊖ (A_k ⊖ D_δ) and S_φ ⊆ (G ⊖ K⁻) ⊕ K⁺ for any K⁻ ⊆ A_k ⊖ D_δ and
K⁺ ⊇ A_k ⊕ D_δ. For an ellipse (semi-minor b) K^∓ = c + (1 ∓ δ/b)(A_k − c),
because D_δ ⊆ (δ/b)(A_k − c) and convexity gives sE ⊕ tE = (s + t)E; for a
polygon K⁻ is its verified erosion by δ and K⁺ the union over its convex
pieces K_i of hull(K_i ⊕ a polygon containing D_δ). So the lower bound also
holds for the continuous rotary range, whose exact lost area can only be
smaller than the sampled one (more angles print more).

Complexity
----------
Per angle and orifice, for n boundary vertices: O(n) one-sided offset
pieces and their union (the dominant cost), STR-tree checks O(n log n).
That is the price of the certificate: tens to hundreds of times a plain
``buffer(-r).buffer(r)`` (see ``benchmarks/bench_exact.py``). Polygons:
O(n·m) convex hulls for m convex pieces of the footprint, then a union.
Memory O(n·m).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely
import shapely.affinity
from shapely.geometry import MultiPolygon, Point, Polygon
from shapely.geometry.base import BaseGeometry

from printability.errors import InputError
from printability.geometry import polygons_of, rotation_matrix
from printability.machine import Machine
from printability.mmc.components import angle_ranges, component_labels
from printability.mmc.result import Components, MMCResult, MotionRestriction
from printability.nozzle import Footprint, Nozzle
from printability.settings import DEFAULT_SETTINGS, Settings

__all__ = [
    "angular_margin",
    "chord_factor",
    "dilate_disk",
    "erode_disk",
    "minkowski_dilate",
    "minkowski_erode",
    "mmc_exact",
    "sampled_angles",
]

# GEOS behaviour the certificate relies on (see the module docstring).
_SPLIT = 0.0125  # split lines at vertices this shallow (× d): above GEOS's 0.01 simplify factor
_SNAP_TURN = 2e-3  # split at turns below this (rad): GEOS snaps offsets closer than 1e-3·d
_REDUNDANT = 1e-5  # GEOS drops curve points within 1e-6·d of the previous one
_FLOAT = 1e-7  # relative margin for floating-point rounding in offsets and distances
_MAX_FIXES = 4  # rounds of local repair of a verified erosion before the global fallback

_EMPTY = MultiPolygon()


def chord_factor(quad_segs: int) -> float:
    """κ = cos(3π/(8·quad_segs)): GEOS fillet chords keep ≥ κ·d from the arc's centre.

    GEOS splits a fillet of turn θ into round(θ/q₀) chords, q₀ = π/(2·quad_segs), so
    a chord spans at most 1.5·q₀. κ = 0.99932 at 32 segments, 0.98079 at 4.
    """
    if quad_segs < 2:
        raise InputError(f"quad_segs={quad_segs} is too coarse for a certified offset; use ≥ 2")
    return math.cos(3.0 * math.pi / (8.0 * quad_segs))


def _disk_cover(quad_segs: int) -> float:
    """Radius factor of a GEOS point/segment buffer that contains the exact disk/stadium.

    Circles and caps use exactly quad_segs chords per quarter: chord midpoints at
    R·cos(π/(4·quad_segs)).
    """
    return (1.0 + _FLOAT) / math.cos(math.pi / (4.0 * quad_segs))


# --------------------------------------------------------------------- disk primitives


def _as_multi(geom: BaseGeometry) -> MultiPolygon:
    """The polygons of ``geom`` as a MultiPolygon, without zero-area holes.

    Unions of touching pieces can leave holes of no area (slits); their points
    are limits of the region's points, so closing them changes no area and no
    containment proved here (every such set is closed), while an eroded slit
    would kill every position within r of it.
    """
    polys = polygons_of(geom)
    out = []
    for p in polys:
        if p.interiors:
            tiny = 1e-12 * max(p.area, 1e-300)
            holes = [h for h in p.interiors if Polygon(h).area > tiny]
            if len(holes) < len(p.interiors):
                p = Polygon(p.exterior, holes)
        out.append(p)
    return MultiPolygon(out) if out else _EMPTY


def _split_lines(
    geom: BaseGeometry, d: float, *, side: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Boundary of ``geom`` as open lines that GEOS offsets without any shortcut.

    GEOS deletes "shallow concavities" (vertices closer than 0.01·d to their
    neighbours' chord, turning towards the offset side) and snaps the offset
    points of a vertex turning by less than ~10⁻³ rad. Every ring is cut into
    open lines at two vertices at least (a closed line is buffered as a ring)
    and at every vertex where either could happen (with margins: 0.0125·d,
    2·10⁻³ rad, or within 2·10⁻³ of a U-turn), so inside a piece neither does
    (GEOS never deletes a line's vertex 1, which lets a two-vertex piece
    absorb the next one). Each piece's buffer is then exact on straight
    parts, with fillets and round caps drawn by chords whose end points lie
    on the arcs; where an inside turn's offsets miss each other GEOS adds
    closing segments towards the vertex, which only shrink the buffer.

    With ``side`` = −1 (+1) the rings are oriented with the interior on the
    left and only the right, outer (left, inner) side will be offset: GEOS
    then only simplifies vertices concave on that side − the reflex (convex)
    vertices of ``geom`` − so only those need a cut when shallow, and there
    the two one-sided offsets already cover the wedge on that side (no cap).

    Returns
    -------
    lines
        The pieces (LineStrings).
    caps
        Points (k, 2) where a one-sided piece ends at a vertex that may be
        convex (ring starts and shortcut-prone vertices): the caller adds a
        disk there.
    """
    polys = polygons_of(geom)
    if polys:
        # slivers of no area have no reliable orientation (a one-sided offset
        # could go to the wrong side): leave them out, which only shrinks a band
        minx, miny, maxx, maxy = shapely.total_bounds(np.asarray(polys, dtype=object))
        tiny = 1e-12 * max(maxx - minx, maxy - miny, d) ** 2
        polys = [q for q in polys if q.area > tiny]
    if side:
        polys = [shapely.geometry.polygon.orient(q, 1.0) for q in polys]
    rings = shapely.get_rings(np.asarray(polys, dtype=object))
    if len(rings) == 0:
        return np.empty(0, dtype=object), np.empty((0, 2))
    coords, ring_idx = shapely.get_coordinates(rings, return_index=True)
    # drop the closing vertex of each ring, and every vertex closer than 10⁻⁹·d
    # to the one before (GEOS fails on zero-length pieces; the bands' 10⁻⁵·d
    # margin covers the move); rings left with fewer than 3 vertices have no
    # area and are dropped (leaving out a piece only shrinks a band)
    counts = np.bincount(ring_idx, minlength=len(rings))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    keep = np.ones(len(coords), bool)
    keep[starts + counts - 1] = False
    step = np.r_[np.inf, np.hypot(*np.diff(coords, axis=0).T)]
    step[starts] = np.inf
    keep &= step > 1e-9 * d
    # the last kept vertex of a ring must not sit on its first one either
    last = np.array([np.flatnonzero(keep[s0:s0 + c])[-1] + s0 if keep[s0:s0 + c].any() else -1
                     for s0, c in zip(starts, counts, strict=True)])
    ok = last >= 0
    close = np.zeros(len(rings), bool)
    close[ok] = np.hypot(*(coords[last[ok]] - coords[starts[ok]]).T) <= 1e-9 * d
    keep[last[close & (last != starts)]] = False
    n = np.bincount(ring_idx[keep], minlength=len(rings))
    keep &= (n >= 3)[ring_idx]
    pts = coords[keep]
    n = n[n >= 3]
    if len(n) == 0:
        return np.empty(0, dtype=object), np.empty((0, 2))
    first = np.concatenate([[0], np.cumsum(n)[:-1]])
    ridx = np.repeat(np.arange(len(n)), n)
    local = np.arange(len(pts)) - first[ridx]
    prev = first[ridx] + (local - 1) % n[ridx]
    nxt = first[ridx] + (local + 1) % n[ridx]
    a, p, b = pts[prev], pts, pts[nxt]
    ab = b - a
    ab2 = np.einsum("ij,ij->i", ab, ab)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.clip(np.einsum("ij,ij->i", p - a, ab) / ab2, 0.0, 1.0)
    s = np.where(ab2 > 0, s, 0.0)
    shallow = np.hypot(*(a + s[:, None] * ab - p).T) < _SPLIT * d
    u, w = p - a, b - p
    turn = np.arctan2(np.abs(u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]), np.einsum("ij,ij->i", u, w))
    if side:
        # only one side is offset: the simplifier can only delete vertices
        # concave on that side (turning right for the right side, left for the left)
        shallow &= side * (u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]) > 0
    # a snap (offset points closer than 10⁻³·d) needs a turn under 10⁻³ rad, or a
    # near U-turn; where an inside turn's offsets miss each other GEOS adds
    # closing segments towards the vertex, which only shrink the band: safe
    risky = (turn < _SNAP_TURN) | (turn > math.pi - _SNAP_TURN)
    # two cuts per ring at least: GEOS buffers a closed line as a ring (another
    # code path, and a one-sided one fills the inside)
    ends = (local == 0) | (local == n[ridx] // 2)
    cut = shallow | risky | ends
    caps = pts[risky | ends]
    # pieces run from one cut vertex to the next (the ring's closing vertex ends the last)
    cut_pos = np.flatnonzero(cut)
    cut_ring = ridx[cut_pos]
    nxt_cut = np.empty_like(cut_pos)
    nxt_cut[:-1] = cut_pos[1:]
    last_in_ring = np.r_[cut_ring[1:] != cut_ring[:-1], True]
    # the last piece of a ring ends at its vertex 0, written as index first + n
    nxt_cut[last_in_ring] = first[cut_ring[last_in_ring]] + n[cut_ring[last_in_ring]]
    # GEOS's simplifier never deletes a line's vertex 1 (its window starts at
    # index 1), so a two-vertex piece may absorb the next piece of the same ring
    # when the vertex between them was cut only for being shallow: this halves
    # the count along arcs, where every vertex is shallow.
    keep_start, keep_end = [], []
    i, m = 0, len(cut_pos)
    while i < m:
        s0, e0 = cut_pos[i], nxt_cut[i]
        if e0 - s0 == 1 and i + 1 < m and cut_ring[i + 1] == cut_ring[i] and not risky[e0]:
            e0 = nxt_cut[i + 1]
            i += 2
        else:
            i += 1
        keep_start.append(s0)
        keep_end.append(e0)
    cut_pos, nxt_cut = np.asarray(keep_start), np.asarray(keep_end)
    cut_ring = ridx[cut_pos]
    lengths = nxt_cut - cut_pos + 1
    offs = np.repeat(cut_pos, lengths) + (
        np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    )
    # index first + n (one past the ring) wraps to the ring's vertex 0
    owner = np.repeat(cut_ring, lengths)
    wrapped = offs >= first[owner] + n[owner]
    offs = np.where(wrapped, first[owner], offs)
    piece_id = np.repeat(np.arange(len(cut_pos)), lengths)
    return shapely.linestrings(pts[offs], indices=piece_id), caps


def _two_sided_band(geom: BaseGeometry, r: float, quad_segs: int) -> BaseGeometry:
    """A subset of ∂geom ⊕ D_r covering both sides of the boundary.

    Used where slivers along ∂geom would matter (G minus a one-sided band
    leaves rounding slivers on ∂G, which a later dilation would grow into a
    band of width r): the boundary lies strictly inside this band.
    """
    d = r * (1.0 - _REDUNDANT)
    lines, _ = _split_lines(geom, d)
    if len(lines) == 0:
        return _EMPTY
    return _union_in_order(_buffer_pieces(lines, d, quad_segs))


def _side_band(geom: BaseGeometry, r: float, quad_segs: int, side: int) -> BaseGeometry:
    r"""A subset of ∂geom ⊕ D_r on one side of the boundary: −1 outside, +1 inside.

    geom ⊕ D_r = geom ∪ (∂geom ⊕ D_r) needs only the outer side, and
    geom ⊖ D_r = geom \ (∂geom ⊕ D_r) only the inner one. One-sided offsets
    of the boundary pieces (split as in :func:`_split_lines` with ``side``),
    plus disks at the pieces' ends that may be turns towards that side:
    four-vertex quadrilaterals instead of stadiums, a much cheaper union.
    Every part lies within r·(1 − 10⁻⁵) of ∂geom.
    """
    d = r * (1.0 - _REDUNDANT)
    lines, caps = _split_lines(geom, d, side=side)
    if len(lines) == 0:
        return _EMPTY
    # GEOS: a positive distance offsets the left side, a negative one the right
    parts = _buffer_pieces(lines, side * d, quad_segs, single_sided=True)
    if len(caps):
        disks = shapely.buffer(shapely.points(caps), d, quad_segs=quad_segs)
        parts = np.concatenate([parts, disks])
    return _union_in_order(parts)


def _buffer_pieces(lines: np.ndarray, d: float, quad_segs: int, **kw) -> np.ndarray:
    """GEOS buffers of many lines; a piece GEOS cannot buffer is left out.

    Leaving a piece out only shrinks a band, and every band here is used as a
    subset (the erosions built from one are verified afterwards), so this is
    safe; a note of it is not needed for correctness.
    """
    try:
        return shapely.buffer(lines, d, quad_segs=quad_segs, **kw)
    except shapely.errors.GEOSException:
        out = []
        for line in lines:
            try:
                out.append(shapely.buffer(line, d, quad_segs=quad_segs, **kw))
            except shapely.errors.GEOSException:
                continue
        return np.asarray(out, dtype=object)


def _union_in_order(parts: np.ndarray, chunk: int = 256) -> BaseGeometry:
    """Union of pieces listed along rings: consecutive chunks first (they overlap most).

    About twice as fast as one cascaded union on coastlines.
    """
    parts = np.asarray(parts, dtype=object)
    if len(parts) <= chunk:
        out = shapely.union_all(parts)
    else:
        out = shapely.union_all([shapely.union_all(parts[i:i + chunk])
                                 for i in range(0, len(parts), chunk)])
    return _repair_union(out, parts)


def _repair_union(union: BaseGeometry, parts: np.ndarray) -> BaseGeometry:
    """Add back parts a cascaded union dropped.

    GEOS's cascaded union can silently lose a piece when many nearly
    coincident convex pieces meet (seen with hulls of a very short segment:
    2 mm² lost on a 25 mm² layer). A point inside every part is tested
    against the result (exact predicates); each part whose point is not
    covered is merged again one at a time.
    """
    parts = parts[~shapely.is_empty(parts)]
    if len(parts) == 0:
        return union
    probes = shapely.point_on_surface(parts)
    shapely.prepare(union)
    missing = parts[~shapely.covers(union, probes)]
    for piece in missing:
        union = shapely.union(union, piece)
    return union


def _certified_erosion(g: BaseGeometry, r: float, quad_segs: int) -> MultiPolygon:
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
        return _EMPTY
    g = MultiPolygon(polys)  # exteriors CCW, holes CW: G's interior on the left
    # not a negative polygon buffer: GEOS would first simplify G's rings, and on
    # a finely drawn round cap of radius ≈ r that cascades into cutting the cap
    # (a tip of P retreating by up to r/sin(half-angle))
    raw = _as_multi(shapely.difference(g, _side_band(g, r * (1 + _FLOAT) / (1 - _REDUNDANT),
                                                      quad_segs, +1)))
    segs, nxt = _ring_segments(g)
    prv = np.empty_like(nxt)
    prv[nxt] = np.arange(len(nxt))
    seg_geoms = shapely.linestrings(segs)
    tree = shapely.STRtree(seg_geoms)
    cover = r * _disk_cover(quad_segs)
    # rounding slivers along ∂G (where the band's edge meets G's) have no area:
    # drop them (a subset stays a subset) instead of cutting them round by round
    minx, miny, maxx, maxy = g.bounds
    tiny = 1e-12 * max(maxx - minx, maxy - miny) ** 2
    passed: set[bytes] = set()  # edges found ≥ r from ∂G (exact coordinates)
    for _ in range(_MAX_FIXES):
        raw = MultiPolygon([q for q in raw.geoms if q.area > tiny])
        edges = _boundary_segments(raw)
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
        rr = r * (1 + _FLOAT)
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
            raw = shapely.difference(raw, _union_in_order(np.asarray(cutters)))
        # drop the collinear vertices the tangent triangles leave at chord ends (a
        # 10⁻⁹·r move, re-verified next round): they would split the offset pieces
        raw = _as_multi(shapely.simplify(raw, 1e-9 * r))
        # edges that survived the cut keep their coordinates and stay verified; the
        # ones just checked and found too close are gone with the cut
    # global fallback: every GEOS shortcut moves the offset by < 1.05·10⁻³·d
    fallback = r * (1 + _FLOAT) / (chord_factor(quad_segs) - 1.05e-3)
    return _as_multi(shapely.intersection(shapely.buffer(g, -fallback, quad_segs=quad_segs), g))


def _insert_tips(raw: MultiPolygon, seg_idx: np.ndarray, tips: np.ndarray) -> MultiPolygon | None:
    """``raw`` with ``tips[k]`` inserted after the start of boundary segment ``seg_idx[k]``.

    Segment numbers are those of :func:`_boundary_segments` (rings in order).
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
    rad = r * (1 + _FLOAT) / math.cos(step / 2)
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
        False: a subset of the exact erosion (:func:`_certified_erosion`).
        True: a superset, G minus a subset of ∂G ⊕ D_r
        (:func:`_two_sided_band`).

    Notes
    -----
    Both are exact along straight offsets (up to 10⁻⁵·r); they differ from
    the exact erosion only within r·(1/κ − 1) of the arcs around reflex
    corners (κ from :func:`chord_factor`). Cost: a union of O(n) one-sided
    offset pieces for n vertices, plus O(n log n) checks (inner).
    """
    if r <= 0:
        return _as_multi(g)
    if not outer:
        return _certified_erosion(g, r, quad_segs)
    return _as_multi(shapely.difference(g, _two_sided_band(g, r, quad_segs)))


def dilate_disk(p: BaseGeometry, r: float, *, quad_segs: int, outer: bool = False) -> MultiPolygon:
    """P ⊕ D_r, as an inner (default) or outer polygonal approximation.

    Inner: P ∪ :func:`_side_band` (∂P, r, outer side), a subset of
    P ⊕ D_r = P ∪ (∂P ⊕ D_r).
    Outer: the complement of a certified erosion of P's complement (within a
    frame): (Pᶜ ⊖ D_r)ᶜ = P ⊕ D_r, so a subset of the erosion gives a superset.
    Both are exact along straight offsets; the arcs differ by ≤ r·(1/κ − 1).
    """
    if r <= 0 or p.is_empty:
        return _as_multi(p)
    if outer:
        minx, miny, maxx, maxy = p.bounds
        m = 2.0 * r + 1.0
        frame = shapely.box(minx - m, miny - m, maxx + m, maxy + m)
        eroded = _certified_erosion(shapely.difference(frame, p), r, quad_segs)
        grown = 1.01 * r
        return _as_multi(shapely.difference(
            shapely.box(minx - grown, miny - grown, maxx + grown, maxy + grown), eroded))
    return _as_multi(shapely.union(p, _side_band(p, r, quad_segs, -1)))


# --------------------------------------------------------------- polygon primitives


def _convex_pieces(k: Polygon) -> list[Polygon]:
    """K as a union of convex polygons (itself, or a constrained Delaunay triangulation)."""
    k = shapely.normalize(k)
    if k.convex_hull.area - k.area <= 1e-12 * max(k.area, 1e-300):
        return [Polygon(k.exterior)]
    return polygons_of(shapely.constrained_delaunay_triangles(k))


def _boundary_segments(geom: BaseGeometry) -> np.ndarray:
    """All boundary segments of a polygonal geometry, shape (m, 2, 2)."""
    rings = shapely.get_rings(np.asarray(polygons_of(geom), dtype=object))
    if len(rings) == 0:
        return np.empty((0, 2, 2))
    coords, idx = shapely.get_coordinates(rings, return_index=True)
    same = idx[1:] == idx[:-1]
    return np.stack([coords[:-1][same], coords[1:][same]], axis=1)


def _boundary_minkowski(geom: BaseGeometry, pieces: Sequence[Polygon], sign: float) -> BaseGeometry:
    """∂geom ⊕ (sign·K) for K = ∪ pieces (convex), as a union of convex hulls."""
    hulls = _boundary_hulls(geom, pieces, sign)
    return _union_in_order(hulls) if len(hulls) else _EMPTY


def _boundary_hulls(geom: BaseGeometry, pieces: Sequence[Polygon], sign: float) -> np.ndarray:
    """The convex hulls e ⊕ sign·K_i, one per boundary segment e and convex piece K_i."""
    segs = _boundary_segments(geom)
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
    k = _largest(k)
    if k is None or g.is_empty:
        return _EMPTY
    k0 = k.representative_point()
    hulls = _boundary_hulls(g, _convex_pieces(k), -1.0)
    moved = shapely.affinity.translate(g, -k0.x, -k0.y)
    p = _as_multi(shapely.difference(moved, _union_in_order(hulls)))
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
        p = _as_multi(shapely.difference(p, cut))
    return p


def minkowski_dilate(p: BaseGeometry, pieces: Sequence[Polygon]) -> MultiPolygon:
    """P ⊕ K for K = ∪ pieces (convex polygons forming a connected set).

    Computed as (P + k₀) ∪ (∂P ⊕ K) (proof in the module docstring).
    """
    if p.is_empty or not pieces:
        return _EMPTY
    k0 = pieces[0].representative_point()
    moved = shapely.affinity.translate(p, k0.x, k0.y)
    band = _boundary_minkowski(p, pieces, 1.0)
    return _as_multi(shapely.union(moved, band))


def _largest(geom: BaseGeometry) -> Polygon | None:
    polys = polygons_of(geom)
    return max(polys, key=lambda q: q.area) if polys else None


# ------------------------------------------------------------------------- orifices


@dataclass(frozen=True)
class _Placed:
    """One orifice at one sampled angle, in the machine frame at the origin."""

    kind: str  # "disk" (circle / ellipse: c + L·D) or "poly"
    c: tuple[float, float] = (0.0, 0.0)
    lmat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 1.0)  # row-major L
    b: float = 0.0  # semi-minor axis (disk kind), mm
    poly: Polygon | None = None


def _place(f: Footprint, total_angle: float) -> _Placed:
    rot = rotation_matrix(total_angle)
    if f.kind in ("circle", "ellipse"):
        c = rot @ np.asarray(f.center, float)
        lm = rotation_matrix(total_angle + f.rotation) @ np.diag([f.a, f.b])
        return _Placed("disk", (float(c[0]), float(c[1])), tuple(float(x) for x in lm.ravel()),
                       b=min(f.a, f.b))
    poly = f.polygon(mode="inner")
    if total_angle % 360.0:
        poly = shapely.affinity.rotate(poly, total_angle, origin=(0.0, 0.0))
    return _Placed("poly", poly=poly)


def _affine(m: np.ndarray, shift: np.ndarray | tuple[float, float] = (0.0, 0.0)) -> list[float]:
    return [m[0, 0], m[0, 1], m[1, 0], m[1, 1], float(shift[0]), float(shift[1])]


def _p_disk(g: BaseGeometry, o: _Placed, scale: float, quad_segs: int, outer: bool) -> MultiPolygon:
    """P for the orifice c + scale·L·D (affine trick)."""
    lm = scale * np.asarray(o.lmat).reshape(2, 2)
    inv = np.linalg.inv(lm)
    g1 = shapely.affinity.affine_transform(g, _affine(inv))
    p1 = erode_disk(g1, 1.0, quad_segs=quad_segs, outer=outer)
    # P = L·P' − c
    return _as_multi(shapely.affinity.affine_transform(p1, _affine(lm, (-o.c[0], -o.c[1]))))


def _s_disk(p: BaseGeometry, o: _Placed, scale: float, quad_segs: int, outer: bool) -> MultiPolygon:
    """P ⊕ (c + scale·L·D) (affine trick)."""
    if p.is_empty:
        return _EMPTY
    lm = scale * np.asarray(o.lmat).reshape(2, 2)
    inv = np.linalg.inv(lm)
    # L⁻¹(P + c)
    p1 = shapely.affinity.affine_transform(p, _affine(inv, inv @ np.asarray(o.c)))
    s1 = dilate_disk(p1, 1.0, quad_segs=quad_segs, outer=outer)
    return _as_multi(shapely.affinity.affine_transform(s1, _affine(lm)))


@dataclass(frozen=True)
class _AngleResult:
    p_inner: MultiPolygon
    s_inner: MultiPolygon
    s_outer: MultiPolygon


def _one_angle(
    g: MultiPolygon, placed: Sequence[_Placed], delta: float, quad_segs: int
) -> _AngleResult:
    """P_inner, S_inner and S_outer (outer: covering angles within δ of this one)."""
    p_in: BaseGeometry | None = None
    p_out: BaseGeometry | None = None
    grown: list[tuple[_Placed, float, list[Polygon] | None]] = []
    whole_g = False
    for o in placed:
        if o.kind == "disk":
            pi = _p_disk(g, o, 1.0, quad_segs, outer=False)
            s_minus = 1.0 - delta / o.b
            if s_minus <= 0:
                whole_g = True  # K⁻ is empty: no upper bound on S from this orifice
                po = None
            else:
                po = _p_disk(g, o, s_minus, quad_segs, outer=True)
            grown.append((o, 1.0 + delta / o.b, None))
        else:
            k = o.poly
            pi = minkowski_erode(g, k)
            if delta > 0:
                k_minus = _largest(_certified_erosion(k, delta, quad_segs))
                # K_i ⊕ D_δ ⊆ hull(K_i's vertices + a polygon containing D_δ)
                ring = shapely.get_coordinates(shapely.buffer(
                    Point(0.0, 0.0), delta * _disk_cover(quad_segs), quad_segs=quad_segs))
                pieces_plus = []
                for c in _convex_pieces(k):
                    v = np.asarray(c.exterior.coords)[:-1]
                    sums = (v[:, None, :] + ring[None, :, :]).reshape(-1, 2)
                    pieces_plus.append(shapely.convex_hull(shapely.multipoints(sums)))
            else:
                k_minus, pieces_plus = k, _convex_pieces(k)
            if k_minus is None:
                whole_g, po = True, None
            else:
                po = minkowski_erode(g, k_minus)
            grown.append((o, 1.0, pieces_plus))
        p_in = pi if p_in is None else p_in.intersection(pi)
        if po is not None:
            p_out = po if p_out is None else p_out.intersection(po)
    p_in = _as_multi(p_in if p_in is not None else _EMPTY)
    s_in_parts = []
    s_out_parts = []
    for o, s_plus, pieces_plus in grown:
        if o.kind == "disk":
            s_in_parts.append(_s_disk(p_in, o, 1.0, quad_segs, outer=False))
            if not whole_g and p_out is not None:
                s_out_parts.append(_s_disk(p_out, o, s_plus, quad_segs, outer=True))
        else:
            s_in_parts.append(minkowski_dilate(p_in, _convex_pieces(o.poly)))
            if not whole_g and p_out is not None:
                s_out_parts.append(minkowski_dilate(p_out, pieces_plus or []))
    s_in = _as_multi(shapely.union_all(s_in_parts)) if s_in_parts else _EMPTY
    if whole_g:
        s_out = g
    elif p_out is None:
        s_out = _EMPTY
    else:
        s_out = _as_multi(shapely.union_all(s_out_parts)) if s_out_parts else _EMPTY
    return _AngleResult(p_in, s_in, s_out)


# --------------------------------------------------------------------------- angles


def sampled_angles(
    nozzle: Nozzle, machine: Machine, settings: Settings
) -> tuple[np.ndarray, float, bool]:
    """The sampled angles, the largest gap Δφ between neighbours (degrees) and the wrap flag.

    A round nozzle, or an XY machine, has one angle and Δφ = 0 (nothing
    turns, or turning changes nothing). On a full turn (or a range covering
    the nozzle's symmetry period) the gap wraps from the last angle to the
    first plus the period.
    """
    period = nozzle.symmetry_period
    angles = np.asarray(machine.angles(step=settings.angle_step, period=period), dtype=float)
    if machine.kind != "ttr" or period == 0.0 or len(angles) == 1:
        return angles[:1], 0.0, False
    span = machine.angle_max - machine.angle_min
    periodic = machine.full_turn or (0 < period < 360.0 and span >= period - 1e-9)
    gaps = list(np.diff(angles))
    if periodic:
        gaps.append(angles[0] + min(period, 360.0) - angles[-1])
    return angles, float(max(gaps)), periodic


def angular_margin(nozzle: Nozzle, gap_deg: float) -> float:
    """δ = ρ·Δφ/2: how far any nozzle point moves between a sample and the mid-gap, mm."""
    return nozzle.radius * math.radians(gap_deg) / 2.0


# ----------------------------------------------------------------------------- engine


def _progress(items: Sequence[float], enabled: bool, what: str):
    if not enabled:
        return items
    from rich.console import Console
    from rich.progress import track

    return track(items, description=what, console=Console(stderr=True), transient=True)


def mmc_exact(
    region: MultiPolygon, nozzle: Nozzle, machine: Machine, *, settings: Settings = DEFAULT_SETTINGS
) -> MMCResult:
    """The exact vector engine: P, S and the lost area with certified bounds.

    Parameters
    ----------
    region
        The layer target G, already validated (:func:`printability.geometry.as_region`).
    nozzle, machine
        Any nozzle; a separable machine (``xy`` or ``ttr``).
    settings
        ``quad_segs`` (chords per quarter circle), ``angle_step`` (T-T-R
        sampling, degrees; ``None`` uses the machine's), ``progress``.

    Returns
    -------
    MMCResult
        ``motion.regions``: P_φ per sampled angle (an inner approximation:
        every position keeps the whole nozzle in G). ``as_built``: S_inner ⊆
        S ⊆ G. ``lost_area`` = λ(G) − λ(S_inner). ``lost_area_bounds``:
        certified, also covering angles between samples on T-T-R (module
        docstring). ``extra["as_built_outer"]``: the outer S.

    Notes
    -----
    Approximation: curved footprints are offset with ``quad_segs`` chords per
    quarter circle; straight offsets are exact and arcs deviate by at most
    a·(1/κ − 1) for semi-major a (about 7·10⁻⁴·a at 32 segments), only near
    corners. Polygons and rectangles are exact up to floating point. Cost: see
    the module docstring; linear in the number of sampled angles.
    """
    if not machine.separable:
        raise InputError(
            f"the exact engine needs a separable machine (xy or ttr); machine {machine.name!r} "
            "is a joint chain: use engine='sampled'"
        )
    t0 = time.perf_counter()
    q = settings.quad_segs
    g = region if isinstance(region, MultiPolygon) else _as_multi(region)
    angles, gap, wrap = sampled_angles(nozzle, machine, settings)
    delta = angular_margin(nozzle, gap)
    results: list[_AngleResult] = []
    for phi in _progress(list(angles), settings.progress, "exact MMC over angles"):
        placed = [_place(f, nozzle.mount_angle + float(phi)) for f in nozzle.footprints]
        results.append(_one_angle(g, placed, delta, q))

    s_in = _as_multi(shapely.union_all([r.s_inner for r in results]))
    # safety net: S ⊆ G holds by construction; should a GEOS failure break it,
    # clip (true S ⊆ G, so clipping keeps S_inner ⊆ S) and say so
    leak = float(shapely.difference(s_in, g).area)
    if leak > 1e-9 * float(g.area):
        s_in = _as_multi(shapely.intersection(s_in, g))
    s_out = _as_multi(shapely.intersection(shapely.union_all([r.s_outer for r in results]), g))
    target_area = float(g.area)
    built = float(s_in.area)
    lost = max(target_area - built, 0.0)
    lo = max(target_area - float(s_out.area), 0.0)
    lo = min(lo, lost)  # S_inner ⊆ S_outer in exact arithmetic; rounding must not invert

    pieces = [polygons_of(r.p_inner) for r in results]
    components = _components(pieces, angles, wrap)
    curved = [f.a for f in nozzle.footprints if f.kind in ("circle", "ellipse")]
    kappa = chord_factor(q)
    notes = []
    if curved:
        notes.append(f"curved orifices offset with {q} chords per quarter circle; boundary "
                     f"error ≤ {max(curved) * (1 / kappa - 1):.2g} mm")
    if len(angles) > 1:
        notes.append(f"{len(angles)} sampled angles, largest gap {gap:.4g}°; bounds cover the "
                     f"continuous range (δ = {delta:.3g} mm)")
    if leak > 1e-9 * float(g.area):
        notes.append(f"internal check: {leak:.3g} mm² of the as-built region fell outside "
                     "the part and was clipped (a geometry-library failure; please report)")
    if all(r.p_inner.is_empty for r in results):
        notes.append("the nozzle fits nowhere in the region: nothing is printed")
    return MMCResult(
        engine="exact",
        nozzle=nozzle,
        machine=machine,
        target=g,
        as_built=s_in,
        target_area=target_area,
        as_built_area=built,
        lost_area=lost,
        lost_area_bounds=(lo, lost),
        motion=MotionRestriction(angles=angles, regions=tuple(r.p_inner for r in results)),
        components=components,
        resolution=max(curved) * (1 / kappa - 1) if curved else 0.0,
        angle_step=gap,
        elapsed=time.perf_counter() - t0,
        notes=tuple(notes),
        extra={"as_built_outer": s_out, "angular_margin": delta},
    )


def _components(pieces: list[list[Polygon]], angles: np.ndarray, wrap: bool) -> Components:
    boxes = [[p.bounds for p in row] for row in pieces]
    flat = {id(p): i for row in pieces for i, p in enumerate(row)}

    def overlap(k: int, a: Polygon, k2: int, b: Polygon) -> bool:
        ba, bb = boxes[k][flat[id(a)]], boxes[k2][flat[id(b)]]
        if ba[2] < bb[0] or bb[2] < ba[0] or ba[3] < bb[1] or bb[3] < ba[1]:
            return False
        return bool(a.intersects(b))

    labels = component_labels(pieces, overlap, wrap=wrap)
    count = 1 + max((max(row) for row in labels if row), default=-1)
    members: list[list[Polygon]] = [[] for _ in range(count)]
    for row, lab in zip(pieces, labels, strict=True):
        for p, c in zip(row, lab, strict=True):
            members[c].append(p)
    geoms = tuple(shapely.union_all(m) for m in members)
    ranges = tuple(angle_ranges(labels, angles)) if count else ()
    return Components(count=count, geometries=geoms, angle_ranges=ranges)

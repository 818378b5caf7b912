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
(OffsetSegmentGenerator, BufferInputLineSimplifier: the constants below) for
the bands; P_inner does not rely on it (verified). In the functions' terms:
P_inner is :func:`erode_disk` (inner, :func:`_certified_erosion`), S_inner
:func:`dilate_disk` (inner, :func:`_side_band`), P_outer :func:`erode_disk`
with ``outer`` (:func:`_two_sided_band`) and S_outer :func:`dilate_disk` with
``outer``, intersected with G by the engine.

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
from printability.geometry import polygons_of

__all__ = [
    "_EMPTY",
    "_as_multi",
    "_boundary_segments",
    "_certified_erosion",
    "_disk_cover",
    "_union_in_order",
    "chord_factor",
    "dilate_disk",
    "erode_disk",
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


def _as_multi(geom: BaseGeometry, *, thin: float = 0.0) -> MultiPolygon:
    """The polygons of ``geom`` as a MultiPolygon, without zero-area holes, nor, for
    ``thin`` > 0, holes that hold no disk of radius ``thin``.

    Unions of touching pieces can leave holes of no area (slits); their points
    are limits of the region's points, so closing them changes no area and no
    containment proved here (every such set is closed), while an eroded slit
    would kill every position within r of it. Where rounding parts the two copies
    of the shared edge, the slit has an area after all: 5.5 mm × 1.4 nm in P ∪ its
    band for an L turned by 1e-5°, whose erosion by the same disk then lost 4.75 mm².
    Every point of a hole that holds no disk of radius ``thin`` is within ``thin``
    of the region: a caller whose region may grow by that much passes it (one
    negative buffer per hole of area at most ``thin`` × its perimeter; a hole of more
    area is kept, which only ever makes the region smaller).
    """
    polys = polygons_of(geom)
    out = []
    for p in polys:
        if p.interiors:
            tiny = 1e-12 * max(p.area, 1e-300)
            holes = [h for h in p.interiors if not _slit(Polygon(h), tiny, thin)]
            if len(holes) < len(p.interiors):
                p = Polygon(p.exterior, holes)
        out.append(p)
    return MultiPolygon(out) if out else _EMPTY


def _slit(hole: Polygon, tiny: float, thin: float) -> bool:
    if hole.area <= tiny:
        return True
    return (thin > 0 and hole.area <= thin * hole.length
            and shapely.buffer(hole, -thin).is_empty)


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
    # the count along arcs, where every vertex is shallow. A ring end is never
    # absorbed: on a triangle (ends at vertices 0 and 1) the two pieces would
    # merge back into the closed ring, whose one-sided buffer GEOS fills (the
    # inner band then covered all of G and P came out empty: issue #26).
    absorbable = shallow & ~risky & ~ends
    keep_start, keep_end = [], []
    i, m = 0, len(cut_pos)
    while i < m:
        s0, e0 = cut_pos[i], nxt_cut[i]
        if e0 - s0 == 1 and i + 1 < m and cut_ring[i + 1] == cut_ring[i] and absorbable[e0]:
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
    parts = _drop_wrong_faces(lines, parts, side * d, quad_segs)
    if len(caps):
        disks = shapely.buffer(shapely.points(caps), d, quad_segs=quad_segs)
        parts = np.concatenate([parts, disks])
    return _union_in_order(parts)


def _drop_wrong_faces(lines: np.ndarray, parts: np.ndarray, d: float,
                      quad_segs: int) -> np.ndarray:
    """Replace one-sided buffers that GEOS built on the wrong face.

    When a piece nearly closes on itself and its offset curve crosses itself (a U whose
    ends lie closer than the offset), GEOS's single-sided buffer can return the face the
    offset curve encloses instead of the strip along the line (seen: a 10 × 6 mm ring cut
    at one vertex, offset by 1.0000001 mm, gave the 8 × 4 interior, and the erosion lost
    the whole polygon). Every face of a true piece lies within |d| of its line (d signed
    as GEOS takes it), so a face whose probe point lies farther marks a wrong piece. It is
    replaced by the one-sided buffers of its single segments (rectangles, which GEOS
    cannot get wrong); they leave out the wedges at the turns, which only shrinks the band
    (every band is used as a subset). Cost: one probe and one distance per face.
    """
    if len(parts) == 0:
        return parts
    faces, owner = shapely.get_parts(parts, return_index=True)
    if len(faces) == 0:
        return parts
    far = shapely.distance(shapely.point_on_surface(faces), lines[owner]) > abs(d) * (1 + 1e-6)
    if not far.any():
        return parts
    bad = np.unique(owner[far])
    keep = np.ones(len(parts), bool)
    keep[bad] = False
    pieces = [parts[keep]]
    for line in lines[bad]:
        xy = shapely.get_coordinates(line)
        segs = shapely.linestrings(np.stack([xy[:-1], xy[1:]], axis=1))
        pieces.append(_buffer_pieces(segs, d, quad_segs, single_sided=True))
    return np.concatenate(pieces)


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


def _boundary_segments(geom: BaseGeometry) -> np.ndarray:
    """All boundary segments of a polygonal geometry, shape (m, 2, 2)."""
    rings = shapely.get_rings(np.asarray(polygons_of(geom), dtype=object))
    if len(rings) == 0:
        return np.empty((0, 2, 2))
    coords, idx = shapely.get_coordinates(rings, return_index=True)
    same = idx[1:] == idx[:-1]
    return np.stack([coords[:-1][same], coords[1:][same]], axis=1)


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
    The inner one's slits (:func:`_as_multi`: holes narrower than 10⁻⁶·r, inside
    the band's margin of 10⁻⁵·r) are closed.
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
    return _as_multi(shapely.union(p, _side_band(p, r, quad_segs, -1)), thin=1e-6 * r)

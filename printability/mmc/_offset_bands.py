"""Offset bands of a boundary by a disk, cut so that GEOS takes none of its shortcuts.

The building blocks of :mod:`printability.mmc._disk_offsets` (whose docstring states
what GEOS does and what these bands certify): :func:`split_lines` cuts the rings of a
region into open lines at every vertex where GEOS could simplify or snap;
:func:`side_band` and :func:`two_sided_band` offset them into subsets of ∂G ⊕ D_r;
:func:`union_in_order` unites many pieces and re-checks that none was dropped;
:func:`as_multi` closes the zero-area holes unions leave.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

from printability.model.geometry import polygons_of

__all__ = [
    "EMPTY",
    "FLOAT_MARGIN",
    "REDUNDANT",
    "as_multi",
    "boundary_segments",
    "side_band",
    "split_lines",
    "two_sided_band",
    "union_in_order",
]

# GEOS behaviour the bands rely on (see printability.mmc._disk_offsets).
_SPLIT = 0.0125  # split lines at vertices this shallow (× d): above GEOS's 0.01 simplify factor
_SNAP_TURN = 2e-3  # split at turns below this (rad): GEOS snaps offsets closer than 1e-3·d
REDUNDANT = 1e-5  # GEOS drops curve points within 1e-6·d of the previous one
FLOAT_MARGIN = 1e-7  # relative margin for floating-point rounding in offsets and distances

EMPTY = MultiPolygon()


def as_multi(geom: BaseGeometry, *, thin: float = 0.0) -> MultiPolygon:
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
    return MultiPolygon(out) if out else EMPTY


def _slit(hole: Polygon, tiny: float, thin: float) -> bool:
    if hole.area <= tiny:
        return True
    return (thin > 0 and hole.area <= thin * hole.length
            and shapely.buffer(hole, -thin).is_empty)


def split_lines(
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
    rings = _rings(geom, d, side)
    if len(rings) == 0:
        return np.empty(0, dtype=object), np.empty((0, 2))
    pts, n = _ring_vertices(rings, d)
    if len(n) == 0:
        return np.empty(0, dtype=object), np.empty((0, 2))
    v = _vertices(pts, n, d, side)
    # two cuts per ring at least: GEOS buffers a closed line as a ring (another
    # code path, and a one-sided one fills the inside)
    ends = (v.local == 0) | (v.local == n[v.ridx] // 2)
    cut = v.shallow | v.risky | ends
    caps = pts[v.risky | ends]
    cut_pos, nxt_cut = _pieces(v, n, cut, v.shallow & ~v.risky & ~ends)
    cut_ring = v.ridx[cut_pos]
    lengths = nxt_cut - cut_pos + 1
    offs = np.repeat(cut_pos, lengths) + (
        np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    )
    # index first + n (one past the ring) wraps to the ring's vertex 0
    owner = np.repeat(cut_ring, lengths)
    wrapped = offs >= v.first[owner] + n[owner]
    offs = np.where(wrapped, v.first[owner], offs)
    piece_id = np.repeat(np.arange(len(cut_pos)), lengths)
    return shapely.linestrings(pts[offs], indices=piece_id), caps


def _rings(geom: BaseGeometry, d: float, side: int) -> np.ndarray:
    """The rings of ``geom``'s polygons of some area, oriented when ``side`` is set."""
    polys = polygons_of(geom)
    if polys:
        # slivers of no area have no reliable orientation (a one-sided offset
        # could go to the wrong side): leave them out, which only shrinks a band
        minx, miny, maxx, maxy = shapely.total_bounds(np.asarray(polys, dtype=object))
        tiny = 1e-12 * max(maxx - minx, maxy - miny, d) ** 2
        polys = [q for q in polys if q.area > tiny]
    if side:
        polys = [shapely.geometry.polygon.orient(q, 1.0) for q in polys]
    return shapely.get_rings(np.asarray(polys, dtype=object))


def _ring_vertices(rings: np.ndarray, d: float) -> tuple[np.ndarray, np.ndarray]:
    """The rings' distinct vertices (m, 2), ring after ring, and each ring's count.

    Drops the closing vertex of each ring, and every vertex closer than 10⁻⁹·d to
    the one before (GEOS fails on zero-length pieces; the bands' 10⁻⁵·d margin
    covers the move); rings left with fewer than 3 vertices have no area and are
    dropped (leaving out a piece only shrinks a band).
    """
    coords, ring_idx = shapely.get_coordinates(rings, return_index=True)
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
    return coords[keep], n[n >= 3]


@dataclass(frozen=True, eq=False)
class _Vertices:
    """Per vertex of :func:`_ring_vertices`: its ring's first index (``first``, per
    ring), its ring (``ridx``), its index in the ring (``local``), and whether GEOS may
    delete it (``shallow``) or snap its offsets (``risky``)."""

    first: np.ndarray
    ridx: np.ndarray
    local: np.ndarray
    shallow: np.ndarray
    risky: np.ndarray


def _vertices(pts: np.ndarray, n: np.ndarray, d: float, side: int) -> _Vertices:
    """Where GEOS could take a shortcut at each vertex, offsetting by d on ``side``."""
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
    return _Vertices(first, ridx, local, shallow, risky)


def _pieces(v: _Vertices, n: np.ndarray, cut: np.ndarray,
            absorbable: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pieces' first and last vertex indices (the last may be first + n: vertex 0).

    Pieces run from one cut vertex to the next (the ring's closing vertex ends the
    last). GEOS's simplifier never deletes a line's vertex 1 (its window starts at
    index 1), so a two-vertex piece may absorb the next piece of the same ring when
    the vertex between them was cut only for being shallow (``absorbable``): this
    halves the count along arcs, where every vertex is shallow. A ring end is never
    absorbed: on a triangle (ends at vertices 0 and 1) the two pieces would merge
    back into the closed ring, whose one-sided buffer GEOS fills (the inner band
    then covered all of G and P came out empty: issue #26).
    """
    cut_pos = np.flatnonzero(cut)
    cut_ring = v.ridx[cut_pos]
    nxt_cut = np.empty_like(cut_pos)
    nxt_cut[:-1] = cut_pos[1:]
    last_in_ring = np.r_[cut_ring[1:] != cut_ring[:-1], True]
    # the last piece of a ring ends at its vertex 0, written as index first + n
    nxt_cut[last_in_ring] = v.first[cut_ring[last_in_ring]] + n[cut_ring[last_in_ring]]
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
    return np.asarray(keep_start), np.asarray(keep_end)


def two_sided_band(geom: BaseGeometry, r: float, quad_segs: int) -> BaseGeometry:
    """A subset of ∂geom ⊕ D_r covering both sides of the boundary.

    Used where slivers along ∂geom would matter (G minus a one-sided band
    leaves rounding slivers on ∂G, which a later dilation would grow into a
    band of width r): the boundary lies strictly inside this band.
    """
    d = r * (1.0 - REDUNDANT)
    lines, _ = split_lines(geom, d)
    if len(lines) == 0:
        return EMPTY
    return union_in_order(_buffer_pieces(lines, d, quad_segs))


def side_band(geom: BaseGeometry, r: float, quad_segs: int, side: int) -> BaseGeometry:
    r"""A subset of ∂geom ⊕ D_r on one side of the boundary: −1 outside, +1 inside.

    geom ⊕ D_r = geom ∪ (∂geom ⊕ D_r) needs only the outer side, and
    geom ⊖ D_r = geom \ (∂geom ⊕ D_r) only the inner one. One-sided offsets
    of the boundary pieces (split as in :func:`split_lines` with ``side``),
    plus disks at the pieces' ends that may be turns towards that side:
    four-vertex quadrilaterals instead of stadiums, a much cheaper union.
    Every part lies within r·(1 − 10⁻⁵) of ∂geom.
    """
    d = r * (1.0 - REDUNDANT)
    lines, caps = split_lines(geom, d, side=side)
    if len(lines) == 0:
        return EMPTY
    # GEOS: a positive distance offsets the left side, a negative one the right
    parts = _buffer_pieces(lines, side * d, quad_segs, single_sided=True)
    parts = _drop_wrong_faces(lines, parts, side * d, quad_segs)
    if len(caps):
        disks = shapely.buffer(shapely.points(caps), d, quad_segs=quad_segs)
        parts = np.concatenate([parts, disks])
    return union_in_order(parts)


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


def union_in_order(parts: np.ndarray, chunk: int = 256) -> BaseGeometry:
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


def boundary_segments(geom: BaseGeometry) -> np.ndarray:
    """All boundary segments of a polygonal geometry, shape (m, 2, 2)."""
    rings = shapely.get_rings(np.asarray(polygons_of(geom), dtype=object))
    if len(rings) == 0:
        return np.empty((0, 2, 2))
    coords, idx = shapely.get_coordinates(rings, return_index=True)
    same = idx[1:] == idx[:-1]
    return np.stack([coords[:-1][same], coords[1:][same]], axis=1)

"""Settling the raster engine's uncertain band below the pixel: exact slides, quadtree leaves.

The raster engine's upper bound ``hi`` counts every pixel that its inner pass
does not certify as built. Most of that uncertainty is a thin band along ∂G
where S actually reaches the boundary: the cut pixels and the ring of inside
pixels beside them (issue #26: 95 % of hi − exact on a star). No finer grid
removes it (it shrinks as h); this module settles it below the pixel with
exact geometry, for nozzles made of one circle or ellipse.

Notation and frame
------------------
A disk-type footprint at angle φ is E_φ = c + L·D, L = R(φ + ρ)·diag(a, b), D
the unit disk (the affine trick of :mod:`printability.mmc.exact`); only the
footprint's shape matters for S, not where the machine's origin is. In the
mapped plane x' = L⁻¹x the region is H = L⁻¹G and the footprint a unit disk.
Rings are oriented with G on their left (shells CCW, holes CW), so every edge
e' = [a', b'] has the inward unit normal n' (left of t' = (b' − a')/|b' − a'|);
L preserves orientation (det L = ab > 0).

Slides (certified placements)
-----------------------------
For an edge e' the centres p(s) = a' + (1 + ε)·n' + s·t', 0 ≤ s ≤ |e'|, put the
unit disk at distance 1 + ε from e's line, on its inner side. Every other edge g'
of the region within reach forbids an open interval of s: the s where the disk
of radius r = 1 + ε/2 about p(s) meets g' (a line meets the stadium g' ⊕ D(r),
a convex set, in an interval: the hull of the line's intersections with the
two end disks and the middle strip, computed in closed form and widened by η
for rounding). Edges farther than 2.02·a from e in the world cannot come within
r of p(s) (``neighbour_pairs``). A free s is then a centre whose disk D(p, r)
meets no edge; D(p, 1) lies in H's interior exactly when p itself lies in H
(a parity test; p is ≥ b from ∂G in the world, so its pixel is not cut at the
default resolutions and the raster classification decides, else shapely does).
So every free interval [s₀, s₁] is a segment of the motion restriction P at
that angle, and the union of the disks along it covers, exactly, the
parallelogram L·{a' + s·t' + z·n' : s₀ ≤ s ≤ s₁, ε ≤ z ≤ 2 + ε}; the end disks
(caps) cover D(p(s₀), 1) and D(p(s₁), 1). At reflex vertices, pivot disks about
the vertex at intermediate normals (each checked the same way) cover the fan
between the slides of the two edges. These pieces are the *certified* part of
S: ``quads`` (with their base on ∂G: z from 0, the sliver 0 ≤ z < ε is added
to ``hi`` as slack, ε·Σ|e'|·ab) and ``caps`` (ellipses, strict containment).

Quadtree leaves (the accounting)
--------------------------------
For each uncertain pixel p (covered fraction > 0, not in the raster's S_in),
a quadtree of squares down to ``max_level`` settles U(p) ≥ λ(p ∩ G \\ S):

* the edges of ∂G crossing a leaf are those of the pixel's list (every edge
  within eps of the closed pixel) meeting the leaf box grown by τ;
* no edge: the leaf is wholly in G or wholly out (parity of a point of it:
  the pixel centre's parity from the conservative classification, flipped by
  each edge crossing the segment from the centre to the point; degenerate
  positions or a pixel whose centre lies on ∂G count the leaf as inside);
  inside and contained in a piece (all corners, strictly, in a convex piece)
  → built, 0;
* one edge: it crosses the leaf from side to side (an end inside the leaf
  would bring the next edge in too), so leaf ∩ G = R, the leaf clipped to the
  edge's inner half-plane (convex, ≤ 5 vertices); contained in a piece → 0
  (a quad's base may be met up to τ below: R's points on e are on its line);
* two edges meeting at a convex vertex: leaf ∩ G is the leaf clipped by both
  inner half-planes, handled as one edge;
* otherwise the leaf is split, and at ``max_level`` its area (R's area for
  one edge) is counted as not built.

A leaf disjoint from every piece is counted as not built without splitting
(correct for the bound; the pieces are then simply not enough). So
``hi = Σ_p min(cov(p)·h², U(p)) + slack`` contains the exact lost area of the
sampled angles, hence of the continuous range.

Lower bound. A leaf that no piece covers may be *proved lost* by the convex
chain model (:func:`settle_band`): when the edges within 2a of it form one
convex chain (a corner, a rounded tip drawn with several edges, a small convex
island), every footprint that could cover it lies in the chain's inner
half-planes; with the exact minimum of the ellipse's support function over each
angle cell (every angle the machine can take is in a cell) and the cell's margin
δ = (a − b)·half-width, a leaf whose image misses every cell's eroded polygon
⊕ footprint is lost at every angle. ``lo`` adds those leaves and the pixels the
raster's outer pass proves lost. Other lost parts (a narrow neck, a fjord) keep
the raster's lower bound.

Estimate. Leaves proved lost or reached by no piece count in full, leaves still
undecided at the last level (straddling the boundary of the pieces' union) by
half: with the pieces of every sampled angle this is the sampled loss to within
half those leaves.

Two tiers. Pieces of at most ``coarse_angles`` of the angles settle every
uncertain pixel first (along ∂G one angle that slides is enough); the pixels
left open (leaves no piece covers and none proved lost) are settled again with
the pieces of every angle, made only for the edges within reach of them.

The numba kernels are in ``_band_slides`` (slides and pivots), ``_band_lists`` (the
per-pixel lists), ``_band_settle`` (the quadtree), ``_band_lower`` (the convex chain
model) and ``_band_geometry`` (their plane geometry), modules whose cached kernels the
kernel-cache check keeps in step; they take the records of ``_band_records``. This module
makes their inputs.

Complexity
----------
Slides: O(pairs · angles) for the neighbour pairs within 2.02·a (the first tier
on a subset of the angles, the second on the edges near open pixels). Bucketing:
O(Σ pieces' bounding boxes in pixels). Quadtree: O(uncertain pixels × leaves ×
candidate pieces), leaves ∝ the length of the union's boundary in the pixel
over the leaf size; a leaf's children test only the pieces that touch it; the
lower bound adds O(chain edges × cells) per leaf it tries. Memory: ~80 bytes per
piece and 8 bytes per (pixel, piece) candidate. Measured (``benchmarks/
bench_bounds.py``): 0.3–2 s on a layer of a few hundred mm², 5–8 s on Japan's
coastline at 100 mm with 180 angles, a few times the raster passes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from printability.mmc._band_lists import TILE, bucket_pieces, edge_pixels
from printability.mmc._band_records import (
    BandPixels,
    ChainModel,
    PieceArrays,
    PixelLists,
    Rings,
)
from printability.mmc._band_settle import settle_pixels
from printability.mmc._band_slides import pivot_centres, slide_intervals
from printability.model.geometry import Grid

__all__ = [
    "EPS_SLIDE",
    "BandBoundary",
    "BandFootprint",
    "BandPieces",
    "BandRaster",
    "band_pieces",
    "edges_of",
    "neighbour_pairs",
    "settle_band",
]

#: ε of the module docstring: slides at 1 + ε from their edge, tests at r = 1 + ε/2 (mapped).
EPS_SLIDE = 1e-7


# --------------------------------------------------------------------------- edges


def edges_of(xs: np.ndarray, ys: np.ndarray, starts: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges of concatenated closed rings as ``(m, 4)`` [ax, ay, bx, by], with the index of
    the previous and next edge on the same ring (G on the left of every edge)."""
    seg, prev, nxt = [], [], []
    base = 0
    for r in range(len(starts) - 1):
        i0, i1 = int(starts[r]), int(starts[r + 1])
        n = i1 - i0 - 1
        if n < 3:
            continue
        a = np.column_stack([xs[i0:i1 - 1], ys[i0:i1 - 1], xs[i0 + 1:i1], ys[i0 + 1:i1]])
        seg.append(a)
        k = np.arange(n)
        prev.append(base + (k - 1) % n)
        nxt.append(base + (k + 1) % n)
        base += n
    if not seg:
        z = np.zeros((0, 4))
        return z, np.zeros(0, np.int64), np.zeros(0, np.int64)
    return (np.ascontiguousarray(np.concatenate(seg)), np.concatenate(prev).astype(np.int64),
            np.concatenate(nxt).astype(np.int64))


def neighbour_pairs(edges: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """CSR (ptr, idx) of the edges within ``reach`` (world, mm) of each edge, itself excluded."""
    m = len(edges)
    if m == 0:
        return np.zeros(1, np.int64), np.zeros(0, np.int64)
    lines = shapely.linestrings(edges.reshape(m, 2, 2))
    tree = shapely.STRtree(lines)
    a, b = tree.query(lines, predicate="dwithin", distance=reach)
    keep = a != b
    a, b = a[keep], b[keep]
    order = np.lexsort((b, a))
    a, b = a[order], b[order]
    ptr = np.zeros(m + 1, np.int64)
    np.add.at(ptr, a + 1, 1)
    return np.cumsum(ptr), b.astype(np.int64)


# --------------------------------------------------------------------------- pieces


@dataclass(frozen=True, eq=False)
class BandPieces:
    """Certified pieces of S (world coordinates, mm), see the module docstring.

    Attributes
    ----------
    quads
        ``(q, 8)``: parallelograms x0, y0, …, x3, y3, counter-clockwise, side 0 → 1 on ∂G.
    quad_edge
        ``(q,)``: the edge of ∂G each quad's base lies on.
    caps
        ``(c, 6)``: ellipses cx, cy and the inverse of their matrix L (row-major):
        the cap is {x : |L⁻¹(x − c)| ≤ 1}.
    slack
        Area the quads claim without proving it (their sliver z < ε along ∂G), mm².
    """

    quads: np.ndarray
    quad_edge: np.ndarray
    caps: np.ndarray
    slack: float

    def __len__(self) -> int:
        return len(self.quads) + len(self.caps)


def _inside_world(x: np.ndarray, y: np.ndarray, region, grid: Grid, cls: np.ndarray
                  ) -> np.ndarray:
    """Point-in-G for points ≥ b from ∂G: their pixel's classification when not cut."""
    j = np.floor((x - grid.x0) / grid.h).astype(np.int64)
    i = np.floor((y - grid.y0) / grid.h).astype(np.int64)
    ok = (i >= 0) & (i < grid.ny) & (j >= 0) & (j < grid.nx)
    out = np.zeros(len(x), bool)
    c = np.full(len(x), 1, np.uint8)
    c[ok] = cls[i[ok], j[ok]]
    out[c == 3] = True
    unsure = (c == 1) | (c == 2)
    if unsure.any():
        out[unsure] = shapely.contains_xy(region, x[unsure], y[unsure])
    return out


def band_pieces(region, edges: np.ndarray, prev_: np.ndarray, ptr: np.ndarray,
                idx: np.ndarray, lmats: list[np.ndarray], grid: Grid, cls: np.ndarray, *,
                want: np.ndarray | None = None, max_free: int = 6,
                fan_step: float = math.radians(30.0)) -> BandPieces:
    """The certified slides, caps and pivots of every angle (module docstring).

    Parameters
    ----------
    region
        G (for the parity of the rare centres whose pixel is cut).
    edges, prev_
        From :func:`edges_of`.
    ptr, idx
        Neighbours within 2.02·a (world) from :func:`neighbour_pairs`.
    lmats
        L per angle (2 × 2, det > 0).
    grid, cls
        The raster's grid and classification (parity of centres).
    want
        Which edges get pieces (all by default); every edge still blocks.
    """
    if want is None:
        want = np.ones(len(edges), bool)
    quads, quad_edge, caps = [], [], []
    slack = 0.0
    eps = EPS_SLIDE
    for lm in lmats:
        mi = np.linalg.inv(lm)
        me = np.empty_like(edges)
        me[:, 0:2] = edges[:, 0:2] @ mi.T
        me[:, 2:4] = edges[:, 2:4] @ mi.T
        e, s0, s1 = slide_intervals(me, ptr, idx, eps, 1e-12, max_free, want)
        if len(e):
            d = me[e, 2:4] - me[e, 0:2]
            le = np.hypot(d[:, 0], d[:, 1])
            t = d / le[:, None]
            n = np.column_stack([-t[:, 1], t[:, 0]])
            a = me[e, 0:2]
            # centres of the slide midpoints: must lie in H (parity)
            mid = a + (1 + eps) * n + 0.5 * (s0 + s1)[:, None] * t
            wmid = mid @ lm.T
            ok = _inside_world(wmid[:, 0], wmid[:, 1], region, grid, cls)
            e, s0, s1, t, n, a, le = e[ok], s0[ok], s1[ok], t[ok], n[ok], a[ok], le[ok]
            p0 = a + s0[:, None] * t
            p1 = a + s1[:, None] * t
            top = 2.0 * n
            corners = np.stack([p0, p1, p1 + top, p0 + top], axis=1) @ lm.T  # (q, 4, 2)
            quads.append(corners.reshape(-1, 8))
            quad_edge.append(e)
            slack += eps * float(np.sum(s1 - s0)) * abs(float(np.linalg.det(lm)))
            for s in (s0, s1):
                cen = (a + (1 + eps) * n + s[:, None] * t) @ lm.T
                caps.append(np.column_stack([cen, np.tile(mi.ravel(), (len(cen), 1))]))
        pe, px, py = pivot_centres(me, prev_, ptr, idx, eps, fan_step, want)
        if len(pe):
            wc = np.column_stack([px, py]) @ lm.T
            ok = _inside_world(wc[:, 0], wc[:, 1], region, grid, cls)
            wc = wc[ok]
            caps.append(np.column_stack([wc, np.tile(mi.ravel(), (len(wc), 1))]))
    q = np.ascontiguousarray(np.concatenate(quads)) if quads else np.zeros((0, 8))
    qe = np.concatenate(quad_edge).astype(np.int64) if quad_edge else np.zeros(0, np.int64)
    c = np.ascontiguousarray(np.concatenate(caps)) if caps else np.zeros((0, 6))
    return BandPieces(q, qe, c, slack)


# --------------------------------------------------------------------------- bucketing


def _csr(kernel, *args) -> tuple[np.ndarray, np.ndarray]:
    n = args[0]
    ptr = np.zeros(n + 1, np.int64)
    kernel(*args[1:], True, ptr, np.zeros(0, np.int64))
    ptr = np.cumsum(ptr)
    out = np.empty(int(ptr[-1]), np.int64)
    kernel(*args[1:], False, ptr, out)
    return ptr, out


# --------------------------------------------------------------------------- quadtree


@dataclass(frozen=True, eq=False)
class BandRaster:
    """The raster's view of the band (world coordinates, mm).

    Attributes
    ----------
    grid, cls, cov
        The raster's grid, classification and covered fractions.
    uncertain
        Boolean ``(ny, nx)``: the pixels to settle (cov > 0, not in S_in).
    outer
        Boolean ``(ny, nx)``: the raster's outer S (a pixel outside it is wholly lost).
    """

    grid: Grid
    cls: np.ndarray
    cov: np.ndarray
    uncertain: np.ndarray
    outer: np.ndarray


@dataclass(frozen=True, eq=False)
class BandBoundary:
    """∂G as edges, with their rings and neighbours.

    Attributes
    ----------
    edges, prev_, next_
        ∂G's edges and their neighbours on the ring (:func:`edges_of`).
    ptr, idx
        Neighbours within 2.02·a (:func:`neighbour_pairs`).
    """

    edges: np.ndarray
    prev_: np.ndarray
    next_: np.ndarray
    ptr: np.ndarray
    idx: np.ndarray

    @property
    def rings(self) -> Rings:
        """The edges and their ring neighbours as the kernels' record."""
        return Rings(self.edges, self.prev_, self.next_)


@dataclass(frozen=True, eq=False)
class BandFootprint:
    """The footprint (one circle or ellipse) at the sampled angles and over the angle cells.

    Attributes
    ----------
    lmats
        L per sampled angle: the pieces are made for these.
    cells
        ``(k, 6)`` per angle cell: L⁻¹ (row-major), the footprint's total angle θ_k
        and the cell's half-width (radians) — every angle the machine can take is in a
        cell.
    a, b
        The footprint's semi-axes, mm.
    delta
        A bound on how far the footprint's boundary moves within half a cell, mm: its
        support function changes by at most (a − b) per radian (the largest
        |∂h/∂ψ| of an ellipse), so (a − b)·half-width.
    """

    lmats: list[np.ndarray]
    cells: np.ndarray
    a: float
    b: float
    delta: float


def settle_band(region, raster: BandRaster, boundary: BandBoundary, footprint: BandFootprint,
                *, max_level: int = 6, coarse_angles: int = 24, full_levels: int = 4
                ) -> dict[str, float]:
    """Certified bounds and an estimate of λ(G \\ S) over the uncertain pixels.

    Parameters
    ----------
    region
        G.
    raster
        The raster's pixels: which to settle and what the raster knows of them.
    boundary
        ∂G's edges and their neighbours.
    footprint
        The footprint's matrices per sampled angle and its angle cells.
    max_level
        Leaves down to h / 2^max_level.
    coarse_angles
        Two tiers: the pieces of at most this many of the angles settle every pixel
        first; the pixels still open are settled again with the pieces of every angle,
        made only for the edges within reach of them (both tiers are certified, so each
        pixel keeps the tighter ends).
    full_levels
        Quadtree depth of the second tier (its pixels are mostly in lost parts, where
        deeper leaves cost much and settle little).

    Returns
    -------
    dict
        ``upper`` (Σ U(p) plus the pieces' slack: ≥ the exact lost area in those pixels),
        ``lower`` (Σ of the leaves proved lost, and of the pixels the raster's outer pass
        proves lost: ≤ it), ``estimate`` (leaves proved lost or reached by no piece in
        full, undecided leaves that a piece reaches by half) and ``undecided``, mm²;
        ``pieces``: how many certified pieces both tiers made.

    Notes
    -----
    The lower bound (the *convex chain model*): let the edges within 2a of a leaf Q be
    consecutive edges of one ring (or a whole ring) turning left at every joint, a
    convex chain. Then G ∩ B(Q, 2a) lies in W, the intersection of their inner
    half-planes: each edge's line has the whole chain on its closed left side (a convex
    chain), so B minus that side is a convex set that meets no boundary and borders the
    edge from outside: it is outside G. A footprint covering a point of Q lies in B, so
    its position t is in W eroded by it: n·(t − A) ≥ h_φ(n) for every chain edge (A on
    it, n its inward normal, h_φ the support function of E_φ); and within a of Q. For φ
    in cell k, h_φ(n) ≥ m_k(n), the exact minimum over the cell (the support of an
    ellipse is sqrt(b² + (a² − b²)·cos²ψ), smallest where cos²ψ is), so t is in the
    convex polygon P_k cut from that box by the half-planes n·(t − A) ≥ m_k(n), and
    E_φ ⊆ E_k ⊕ D(δ) (convex sets whose support functions differ by at most δ;
    δ = (a − b)·half-width, as |∂h/∂ψ| = (a² − b²)|sin ψ cos ψ|/h ≤ a − b, attained at
    cos²ψ = b/(a + b)). So if the box Q grown by δ misses P_k ⊕ E_k for every cell (in
    E_k's unit-disk frame: the images of the two convex polygons are farther than 1
    apart), no footprint covers Q: λ(Q ∩ G) is lost. Q ∩ G is the leaf, R, or the leaf
    clipped by two edges meeting at a convex vertex, all exact. (Two edges at a convex
    vertex are the wedge of a corner; a whole convex ring, an island smaller than the
    nozzle.)
    """
    grid, edges, lmats = raster.grid, boundary.edges, footprint.lmats
    scale = float(np.max(np.abs(edges))) if len(edges) else 1.0
    tau = 1e-12 * scale + 1e-9 * grid.h
    step = max(1, math.ceil(len(lmats) / max(coarse_angles, 1)))
    coarse = _pieces_of(region, raster, boundary, lmats[::step])
    pix_i, pix_j, up, lo, und, est, reopen = _settle(raster.uncertain, coarse, raster, boundary,
                                                     footprint, max_level=max_level, tau=tau)
    slack = coarse.slack + tau * _bases(coarse)
    count = len(coarse)
    # pixels where pieces of more angles may settle more: leaves no piece covered and none
    # proved lost (not those split at the last level by two edges: a vertex's speck)
    open_ = reopen > 1e-4 * grid.h * grid.h
    if step > 1 and open_.any():
        residual = np.zeros(grid.shape, bool)
        residual[pix_i[open_], pix_j[open_]] = True
        want = _edges_near(residual, edges, grid, 2.02 * max(footprint.a, footprint.b))
        full = _pieces_of(region, raster, boundary, lmats, want=want)
        ri, rj, up2, lo2, und2, est2, _ = _settle(residual, full, raster, boundary, footprint,
                                                  max_level=min(full_levels, max_level),
                                                  tau=tau)
        pos = np.full(grid.shape, -1, np.int64)
        pos[pix_i, pix_j] = np.arange(len(pix_i))
        k = pos[ri, rj]
        up[k] = np.minimum(up[k], up2)
        lo[k] = np.maximum(lo[k], lo2)
        und[k] = np.minimum(und2, up[k] - lo[k])
        est[k] = np.clip(est2, lo[k], up[k])
        slack += full.slack + tau * _bases(full)
        count += len(full)
    return {"upper": float(up.sum()) + slack, "lower": float(lo.sum()),
            "estimate": float(est.sum()), "undecided": float(und.sum()), "pieces": count}


def _pieces_of(region, raster: BandRaster, boundary: BandBoundary, lmats: list[np.ndarray], *,
               want: np.ndarray | None = None) -> BandPieces:
    """:func:`band_pieces` of the boundary at the angles of ``lmats``."""
    return band_pieces(region, boundary.edges, boundary.prev_, boundary.ptr, boundary.idx,
                       lmats, raster.grid, raster.cls, want=want)


def _bases(pieces: BandPieces) -> float:
    """Total length of the quads' bases, mm: a leaf clipped by an edge may sit up to tau
    below a base (rounding of the clip), so tau × this bounds the area claimed beyond."""
    q = pieces.quads
    return float(np.hypot(q[:, 2] - q[:, 0], q[:, 3] - q[:, 1]).sum()) if len(q) else 0.0


def _edges_near(pixels: np.ndarray, edges: np.ndarray, grid: Grid, reach: float
                ) -> np.ndarray:
    """Which edges come within ``reach`` of a pixel of the mask."""
    i, j = np.nonzero(pixels)
    if len(i) == 0 or len(edges) == 0:
        return np.zeros(len(edges), bool)
    boxes = shapely.box(grid.x0 + j * grid.h, grid.y0 + i * grid.h,
                        grid.x0 + (j + 1) * grid.h, grid.y0 + (i + 1) * grid.h)
    lines = shapely.linestrings(edges.reshape(len(edges), 2, 2))
    tree = shapely.STRtree(lines)
    _, hit = tree.query(boxes, predicate="dwithin", distance=reach)
    want = np.zeros(len(edges), bool)
    want[hit] = True
    return want


def _settle(uncertain: np.ndarray, pieces: BandPieces, raster: BandRaster,
            boundary: BandBoundary, footprint: BandFootprint, *, max_level: int, tau: float):
    """One tier of :func:`settle_band`: per-pixel arrays over the ``uncertain`` pixels."""
    grid, edges = raster.grid, boundary.edges
    a, b = footprint.a, footprint.b
    pix_i, pix_j = np.nonzero(uncertain)
    index = np.full(grid.shape, -1, np.int64)
    index[pix_i, pix_j] = np.arange(len(pix_i))
    scale = float(np.max(np.abs(edges))) if len(edges) else 1.0
    eps = 1e-6 * grid.h + 1e-12 * scale
    n = len(pix_i)
    eptr, eidx = _csr(edge_pixels, n, edges, index, grid.x0, grid.y0, grid.h, grid.ny,
                      grid.nx, eps)
    reach = 2.0 * max(a, b) * (1.0 + 1e-9) + tau
    # edges within reach of a pixel's box: grow each edge's pixel test by the reach
    nptr, nidx = _csr(edge_pixels, n, edges, index, grid.x0, grid.y0, grid.h, grid.ny,
                      grid.nx, reach + eps)
    t = 1 << TILE
    tiles = np.zeros(((grid.ny + t - 1) // t, (grid.nx + t - 1) // t), np.bool_)
    tiles[pix_i >> TILE, pix_j >> TILE] = True
    pptr, pidx = _csr(bucket_pieces, n, pieces.quads, pieces.caps, index, tiles, grid.x0,
                      grid.y0, grid.h, grid.ny, grid.nx)
    band = BandPixels(pix_i.astype(np.int64), pix_j.astype(np.int64), raster.cls, raster.cov,
                      raster.outer, grid.x0, grid.y0, grid.h)
    lists = PixelLists(eptr, eidx, nptr, nidx, pptr, pidx)
    model = ChainModel(np.ascontiguousarray(footprint.cells, dtype=float), float(a), float(b),
                       float(footprint.delta), reach)
    upper, lower, und, est, reopen = settle_pixels(
        band, boundary.rings, lists, PieceArrays(pieces.quads, pieces.quad_edge, pieces.caps),
        model, max_level, tau)
    return pix_i, pix_j, upper, lower, und, est, reopen

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
* otherwise the leaf is split, and at ``max_level`` its area (R's area for
  one edge) is counted as not built.

A leaf disjoint from every piece is counted as not built without splitting
(correct for the bound; the pieces are then simply not enough). So
``hi = Σ_p min(cov(p)·h², U(p)) + slack`` contains the exact lost area of the
sampled angles, hence of the continuous range. Leaves still undecided at the
last level straddle the boundary of the pieces' union: the **estimate** counts
half of them (the pieces of all sampled angles are the sampled-angle S near ∂G,
so this is the sampled loss to within half those leaves).

Complexity
----------
Slides: O(pairs · angles) for the neighbour pairs within 2.02·a. Bucketing:
O(Σ pieces' bounding boxes in pixels). Quadtree: O(uncertain pixels × leaves ×
candidate pieces), leaves ∝ the length of the union's boundary in the pixel
over the leaf size. Memory: ~80 bytes per piece and 8 bytes per (pixel, piece)
candidate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np
import shapely

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.geometry import Grid

_guard_kernel_caches()

__all__ = [
    "EPS_SLIDE",
    "BandPieces",
    "band_pieces",
    "edges_of",
    "neighbour_pairs",
    "settle_band",
]

#: ε of the module docstring: slides at 1 + ε from their edge, tests at r = 1 + ε/2 (mapped).
EPS_SLIDE = 1e-7
_INF = np.inf
_TILE = 4  # log2 of the tile side, pixels, of the bucketing's occupancy map


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


# --------------------------------------------------------------------------- slides


@nb.njit(cache=True, inline="always")
def _blocked(p0x, p0y, tx, ty, nx_, ny_, g0x, g0y, g1x, g1y, r):  # pragma: no cover - numba
    """The s (hull) where the line p0 + s·t comes closer than r to segment g (unit t, n)."""
    lo = _INF
    hi = -_INF
    for e in range(2):
        qx = g0x if e == 0 else g1x
        qy = g0y if e == 0 else g1y
        dx = qx - p0x
        dy = qy - p0y
        sq = dx * tx + dy * ty
        dq = dx * nx_ + dy * ny_
        w2 = r * r - dq * dq
        if w2 > 0.0:
            w = math.sqrt(w2)
            lo = min(lo, sq - w)
            hi = max(hi, sq + w)
    vx = g1x - g0x
    vy = g1y - g0y
    l2 = vx * vx + vy * vy
    if l2 > 0.0:
        lg = math.sqrt(l2)
        mx = -vy / lg
        my = vx / lg
        f0 = (p0x - g0x) * mx + (p0y - g0y) * my
        ft = tx * mx + ty * my
        if ft == 0.0:
            if abs(f0) < r:
                a1, b1 = -_INF, _INF
            else:
                a1, b1 = _INF, -_INF
        else:
            a1 = (-r - f0) / ft
            b1 = (r - f0) / ft
            if a1 > b1:
                a1, b1 = b1, a1
        u0 = ((p0x - g0x) * vx + (p0y - g0y) * vy) / l2
        ut = (tx * vx + ty * vy) / l2
        if ut == 0.0:
            if 0.0 <= u0 <= 1.0:
                a2, b2 = -_INF, _INF
            else:
                a2, b2 = _INF, -_INF
        else:
            a2 = -u0 / ut
            b2 = (1.0 - u0) / ut
            if a2 > b2:
                a2, b2 = b2, a2
        a = max(a1, a2)
        b = min(b1, b2)
        if a < b:
            lo = min(lo, a)
            hi = max(hi, b)
    return lo, hi


@nb.njit(cache=True)
def _dist_point_segment(px, py, ax, ay, bx, by):  # pragma: no cover - numba
    vx = bx - ax
    vy = by - ay
    l2 = vx * vx + vy * vy
    t = 0.0
    if l2 > 0.0:
        t = ((px - ax) * vx + (py - ay) * vy) / l2
        t = min(max(t, 0.0), 1.0)
    dx = px - (ax + t * vx)
    dy = py - (ay + t * vy)
    return math.sqrt(dx * dx + dy * dy)


@nb.njit(cache=True)
def slide_intervals(me, ptr, idx, eps, eta_rel, max_free, want):  # pragma: no cover - numba
    """Free slide intervals of every mapped edge ``me`` (m, 4) against its neighbours.

    Returns (edge, s0, s1) arrays: the centres a' + (1 + eps)·n' + s·t', s0 ≤ s ≤ s1,
    whose disks of radius 1 + eps/2 meet no neighbour (module docstring). At most
    ``max_free`` intervals per edge (the longest kept; dropping some only loses
    coverage). Only the edges with ``want[e]`` slide (all still block).
    """
    m = me.shape[0]
    r = 1.0 + 0.5 * eps
    cap = m * max_free
    out_e = np.empty(cap, np.int64)
    out_0 = np.empty(cap)
    out_1 = np.empty(cap)
    most = 1
    for e in range(m):
        most = max(most, ptr[e + 1] - ptr[e])
    los = np.empty(most)
    his = np.empty(most)
    fs0 = np.empty(most + 1)
    fs1 = np.empty(most + 1)
    k = 0
    for e in range(m):
        if not want[e]:
            continue
        ax, ay, bx, by = me[e, 0], me[e, 1], me[e, 2], me[e, 3]
        dx = bx - ax
        dy = by - ay
        le = math.sqrt(dx * dx + dy * dy)
        if le <= 0.0:
            continue
        tx = dx / le
        ty = dy / le
        nx_ = -ty
        ny_ = tx
        p0x = ax + (1.0 + eps) * nx_
        p0y = ay + (1.0 + eps) * ny_
        eta = eta_rel * (abs(p0x) + abs(p0y) + le + 1.0)
        rr = r + eta
        c = 0
        for q in range(ptr[e], ptr[e + 1]):
            g = idx[q]
            g0x, g0y, g1x, g1y = me[g, 0], me[g, 1], me[g, 2], me[g, 3]
            # a segment wholly beyond r on one side of the line, or beyond either end of
            # the slide, cannot block it (the stadium's extents)
            d0 = (g0x - p0x) * nx_ + (g0y - p0y) * ny_
            d1 = (g1x - p0x) * nx_ + (g1y - p0y) * ny_
            if (d0 > rr and d1 > rr) or (d0 < -rr and d1 < -rr):
                continue
            s0_ = (g0x - p0x) * tx + (g0y - p0y) * ty
            s1_ = (g1x - p0x) * tx + (g1y - p0y) * ty
            if (s0_ < -rr and s1_ < -rr) or (s0_ > le + rr and s1_ > le + rr):
                continue
            lo, hi = _blocked(p0x, p0y, tx, ty, nx_, ny_, g0x, g0y, g1x, g1y, r)
            if lo < hi and hi > -eta and lo < le + eta:
                # insertion by lo (few blocking edges per slide)
                t = c
                while t > 0 and los[t - 1] > lo - eta:
                    los[t] = los[t - 1]
                    his[t] = his[t - 1]
                    t -= 1
                los[t] = lo - eta
                his[t] = hi + eta
                c += 1
        cur = 0.0
        nfree = 0
        for t in range(c):
            lo = los[t]
            hi = his[t]
            if lo > cur:
                fs0[nfree] = cur
                fs1[nfree] = min(lo, le)
                if fs1[nfree] > fs0[nfree]:
                    nfree += 1
            cur = max(cur, hi)
            if cur >= le:
                break
        if cur < le:
            fs0[nfree] = cur
            fs1[nfree] = le
            nfree += 1
        if nfree > max_free:
            lens = fs1[:nfree] - fs0[:nfree]
            keep = np.sort(np.argsort(-lens)[:max_free])
            for t in range(max_free):
                out_e[k] = e
                out_0[k] = fs0[keep[t]]
                out_1[k] = fs1[keep[t]]
                k += 1
            continue
        for t in range(nfree):
            out_e[k] = e
            out_0[k] = fs0[t]
            out_1[k] = fs1[t]
            k += 1
    return out_e[:k], out_0[:k], out_1[:k]


@nb.njit(cache=True)
def pivot_centres(me, prev_, ptr, idx, eps, step, want):  # pragma: no cover - numba
    """Feasible pivot centres about reflex vertices (mapped): (vertex edge, cx, cy).

    At the start vertex a' of edge e, when it is reflex (the previous edge turns
    right into e), centres a' + (1 + eps)·u at normals u strictly between the two
    edges' normals, spaced at most ``step`` radians, whose disks of radius 1 + eps/2
    meet no neighbour of either edge.
    """
    m = me.shape[0]
    r = 1.0 + 0.5 * eps
    out_e = np.empty(m * 12, np.int64)
    out_x = np.empty(m * 12)
    out_y = np.empty(m * 12)
    k = 0
    for e in range(m):
        if not want[e]:
            continue
        f = prev_[e]
        ax, ay = me[e, 0], me[e, 1]
        ex = me[e, 2] - ax
        ey = me[e, 3] - ay
        fx = me[f, 2] - me[f, 0]
        fy = me[f, 3] - me[f, 1]
        le = math.sqrt(ex * ex + ey * ey)
        lf = math.sqrt(fx * fx + fy * fy)
        if le <= 0.0 or lf <= 0.0:
            continue
        cross = fx * ey - fy * ex
        if cross >= 0.0:
            continue  # convex (left turn) or straight: no fan
        th_f = math.atan2(fx / lf, -fy / lf)  # angle of f's normal (−fy, fx)
        th_e = math.atan2(ex / le, -ey / le)
        turn = th_f - th_e  # normals turn clockwise at a right turn
        while turn <= 0.0:
            turn += 2.0 * math.pi
        while turn > 2.0 * math.pi:
            turn -= 2.0 * math.pi
        n_int = int(np.ceil(turn / step)) - 1
        if n_int > 10:
            n_int = 10
        for j in range(1, n_int + 1):
            th = th_f - turn * j / (n_int + 1)
            cx = ax + (1.0 + eps) * math.cos(th)
            cy = ay + (1.0 + eps) * math.sin(th)
            ok = True
            for src in range(2):
                ee = e if src == 0 else f
                for q in range(ptr[ee], ptr[ee + 1]):
                    g = idx[q]
                    if _dist_point_segment(cx, cy, me[g, 0], me[g, 1], me[g, 2], me[g, 3]) < r:
                        ok = False
                        break
                if not ok:
                    break
            if ok and k < out_e.shape[0]:
                out_e[k] = e
                out_x[k] = cx
                out_y[k] = cy
                k += 1
    return out_e[:k], out_x[:k], out_y[:k]


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


@nb.njit(cache=True)
def _bucket(quads, caps, pix_index, tiles, x0, y0, h, ny, nx, count_only, ptr, out):
    # pragma: no cover - numba
    """Pieces whose bounding box meets each uncertain pixel (CSR over ``pix_index``);
    ``tiles`` marks the 2^_TILE-pixel tiles that hold such a pixel."""
    nq = quads.shape[0]
    fill = ptr.copy() if not count_only else ptr
    for p in range(nq + caps.shape[0]):
        if p < nq:
            mnx = min(quads[p, 0], quads[p, 2], quads[p, 4], quads[p, 6])
            mxx = max(quads[p, 0], quads[p, 2], quads[p, 4], quads[p, 6])
            mny = min(quads[p, 1], quads[p, 3], quads[p, 5], quads[p, 7])
            mxy = max(quads[p, 1], quads[p, 3], quads[p, 5], quads[p, 7])
        else:
            c = p - nq
            # L = inverse of the stored L⁻¹: half-widths of the ellipse's box are the
            # row norms of L
            a00, a01, a10, a11 = caps[c, 2], caps[c, 3], caps[c, 4], caps[c, 5]
            det = a00 * a11 - a01 * a10
            l00, l01, l10, l11 = a11 / det, -a01 / det, -a10 / det, a00 / det
            wx = math.sqrt(l00 * l00 + l01 * l01)
            wy = math.sqrt(l10 * l10 + l11 * l11)
            mnx = caps[c, 0] - wx
            mxx = caps[c, 0] + wx
            mny = caps[c, 1] - wy
            mxy = caps[c, 1] + wy
        j0 = max(int(np.floor((mnx - x0) / h)), 0)
        j1 = min(int(np.floor((mxx - x0) / h)), nx - 1)
        i0 = max(int(np.floor((mny - y0) / h)), 0)
        i1 = min(int(np.floor((mxy - y0) / h)), ny - 1)
        for ti in range(i0 >> _TILE, (i1 >> _TILE) + 1):
            for tj in range(j0 >> _TILE, (j1 >> _TILE) + 1):
                if not tiles[ti, tj]:
                    continue  # no pixel to settle in this tile
                for i in range(max(i0, ti << _TILE), min(i1, ((ti + 1) << _TILE) - 1) + 1):
                    for j in range(max(j0, tj << _TILE), min(j1, ((tj + 1) << _TILE) - 1) + 1):
                        u = pix_index[i, j]
                        if u < 0:
                            continue
                        if count_only:
                            ptr[u + 1] += 1
                        else:
                            out[fill[u]] = p
                            fill[u] += 1


@nb.njit(cache=True)
def _edge_pixels(edges, pix_index, x0, y0, h, ny, nx, eps, count_only, ptr, out):
    # pragma: no cover - numba
    """Edges within eps of each uncertain pixel (CSR), as the classification's cut test."""
    fill = ptr.copy() if not count_only else ptr
    for e in range(edges.shape[0]):
        ax, ay, bx, by = edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3]
        i0 = max(int(np.floor((min(ay, by) - eps - y0) / h)), 0)
        i1 = min(int(np.floor((max(ay, by) + eps - y0) / h)), ny - 1)
        for i in range(i0, i1 + 1):
            bl = y0 + i * h - eps
            bh = y0 + (i + 1) * h + eps
            if ay == by:
                xa, xb = ax, bx
            else:
                ta = min(max((bl - ay) / (by - ay), 0.0), 1.0)
                tb = min(max((bh - ay) / (by - ay), 0.0), 1.0)
                xa = ax + ta * (bx - ax)
                xb = ax + tb * (bx - ax)
            if xa > xb:
                xa, xb = xb, xa
            j0 = max(int(np.floor((xa - eps - x0) / h)), 0)
            j1 = min(int(np.floor((xb + eps - x0) / h)), nx - 1)
            for j in range(j0, j1 + 1):
                u = pix_index[i, j]
                if u < 0:
                    continue
                if count_only:
                    ptr[u + 1] += 1
                else:
                    out[fill[u]] = e
                    fill[u] += 1


def _csr(kernel, *args) -> tuple[np.ndarray, np.ndarray]:
    n = args[0]
    ptr = np.zeros(n + 1, np.int64)
    kernel(*args[1:], True, ptr, np.zeros(0, np.int64))
    ptr = np.cumsum(ptr)
    out = np.empty(int(ptr[-1]), np.int64)
    kernel(*args[1:], False, ptr, out)
    return ptr, out


# --------------------------------------------------------------------------- quadtree


@nb.njit(cache=True, inline="always")
def _orient(ax, ay, bx, by, cx, cy):  # pragma: no cover - numba
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@nb.njit(cache=True)
def _seg_meets_box(ax, ay, bx, by, x0, y0, x1, y1):  # pragma: no cover - numba
    """Whether segment ab meets the closed box (Liang–Barsky)."""
    t0 = 0.0
    t1 = 1.0
    dx = bx - ax
    dy = by - ay
    for k in range(4):
        if k == 0:
            p, q = -dx, ax - x0
        elif k == 1:
            p, q = dx, x1 - ax
        elif k == 2:
            p, q = -dy, ay - y0
        else:
            p, q = dy, y1 - ay
        if p == 0.0:
            if q < 0.0:
                return False
        else:
            r = q / p
            if p < 0.0:
                if r > t1:
                    return False
                if r > t0:
                    t0 = r
            else:
                if r < t0:
                    return False
                if r < t1:
                    t1 = r
    return True


@nb.njit(cache=True)
def _clip_left(px, py, n, ax, ay, bx, by, ox, oy):  # pragma: no cover - numba
    """Clip the convex polygon (px, py)[:n] to the left of the line a→b; result in (ox, oy)."""
    m = 0
    for k in range(n):
        cx, cy = px[k], py[k]
        dx, dy = px[(k + 1) % n], py[(k + 1) % n]
        sc = _orient(ax, ay, bx, by, cx, cy)
        sd = _orient(ax, ay, bx, by, dx, dy)
        if sc >= 0.0:
            ox[m] = cx
            oy[m] = cy
            m += 1
        if (sc >= 0.0) != (sd >= 0.0):
            t = sc / (sc - sd)
            ox[m] = cx + t * (dx - cx)
            oy[m] = cy + t * (dy - cy)
            m += 1
    return m


@nb.njit(cache=True, inline="always")
def _area(px, py, n):  # pragma: no cover - numba
    s = 0.0
    for k in range(n):
        s += px[k] * py[(k + 1) % n] - px[(k + 1) % n] * py[k]
    return 0.5 * s


@nb.njit(cache=True)
def _in_quad(quads, q, x, y, tau, base_tol):  # pragma: no cover - numba
    """Point strictly inside quad q (≥ tau from sides 1–3; side 0, the base, down to
    −base_tol)."""
    for s in range(4):
        ax, ay = quads[q, 2 * s], quads[q, 2 * s + 1]
        bx, by = quads[q, (2 * s + 2) % 8], quads[q, (2 * s + 3) % 8]
        ln = math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
        if ln == 0.0:
            return False
        d = _orient(ax, ay, bx, by, x, y) / ln
        if s == 0:
            if d < -base_tol:
                return False
        elif d < tau:
            return False
    return True


@nb.njit(cache=True, inline="always")
def _in_cap(caps, c, x, y):  # pragma: no cover - numba
    dx = x - caps[c, 0]
    dy = y - caps[c, 1]
    u = caps[c, 2] * dx + caps[c, 3] * dy
    v = caps[c, 4] * dx + caps[c, 5] * dy
    return u * u + v * v <= 1.0 - 1e-9


@nb.njit(cache=True)
def _disjoint_quad(quads, q, px, py, n):  # pragma: no cover - numba
    """Separating-axis test between quad q and the convex polygon (px, py)[:n]."""
    for poly in range(2):
        cnt = 4 if poly == 0 else n
        for s in range(cnt):
            if poly == 0:
                ax, ay = quads[q, 2 * s], quads[q, 2 * s + 1]
                bx, by = quads[q, (2 * s + 2) % 8], quads[q, (2 * s + 3) % 8]
            else:
                ax, ay = px[s], py[s]
                bx, by = px[(s + 1) % n], py[(s + 1) % n]
            ux = -(by - ay)
            uy = bx - ax
            amin, amax = _INF, -_INF
            for k in range(4):
                v = quads[q, 2 * k] * ux + quads[q, 2 * k + 1] * uy
                amin = min(amin, v)
                amax = max(amax, v)
            bmin, bmax = _INF, -_INF
            for k in range(n):
                v = px[k] * ux + py[k] * uy
                bmin = min(bmin, v)
                bmax = max(bmax, v)
            if amax < bmin or bmax < amin:
                return True
    return False


@nb.njit(cache=True)
def _disjoint_cap(caps, c, px, py, n):  # pragma: no cover - numba
    """Whether the convex polygon misses the ellipse (distance > 1 in its unit-disk frame)."""
    inside = True
    best = _INF
    for k in range(n):
        ax = caps[c, 2] * (px[k] - caps[c, 0]) + caps[c, 3] * (py[k] - caps[c, 1])
        ay = caps[c, 4] * (px[k] - caps[c, 0]) + caps[c, 5] * (py[k] - caps[c, 1])
        k2 = (k + 1) % n
        bx = caps[c, 2] * (px[k2] - caps[c, 0]) + caps[c, 3] * (py[k2] - caps[c, 1])
        by = caps[c, 4] * (px[k2] - caps[c, 0]) + caps[c, 5] * (py[k2] - caps[c, 1])
        if _orient(ax, ay, bx, by, 0.0, 0.0) < 0.0:
            inside = False
        best = min(best, _dist_point_segment(0.0, 0.0, ax, ay, bx, by))
    if inside:
        return False
    return best > 1.0


@nb.njit(cache=True)
def _parity_flips(edges, elist, ax, ay, bx, by):  # pragma: no cover - numba
    """Crossings of segment a→b with the listed edges; −1 when a position is degenerate."""
    flips = 0
    for t in range(elist.shape[0]):
        e = elist[t]
        px, py, qx, qy = edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3]
        o1 = _orient(ax, ay, bx, by, px, py)
        o2 = _orient(ax, ay, bx, by, qx, qy)
        o3 = _orient(px, py, qx, qy, ax, ay)
        o4 = _orient(px, py, qx, qy, bx, by)
        if o1 == 0.0 or o2 == 0.0 or o3 == 0.0 or o4 == 0.0:
            # touching or collinear: only degenerate when the boxes overlap
            if (min(px, qx) <= max(ax, bx) and min(ax, bx) <= max(px, qx)
                    and min(py, qy) <= max(ay, by) and min(ay, by) <= max(py, qy)):
                return -1
            continue
        if (o1 > 0.0) != (o2 > 0.0) and (o3 > 0.0) != (o4 > 0.0):
            flips += 1
    return flips


@nb.njit(cache=True)
def _dist_seg_box(ax, ay, bx, by, x0, y0, x1, y1):  # pragma: no cover - numba
    """Distance from segment ab to the closed box [x0, x1] × [y0, y1]."""
    if _seg_meets_box(ax, ay, bx, by, x0, y0, x1, y1):
        return 0.0
    best = _INF
    for k in range(2):
        px = ax if k == 0 else bx
        py = ay if k == 0 else by
        dx = max(x0 - px, 0.0, px - x1)
        dy = max(y0 - py, 0.0, py - y1)
        best = min(best, math.sqrt(dx * dx + dy * dy))
    for k in range(4):
        cx = x0 if k == 0 or k == 3 else x1
        cy = y0 if k < 2 else y1
        best = min(best, _dist_point_segment(cx, cy, ax, ay, bx, by))
    return best


@nb.njit(cache=True)
def _wedge_of(edges, nlist, prev_, x0, y0, x1, y1, reach):  # pragma: no cover - numba
    """(e_in, e_out) when the only edges within ``reach`` of the box are two edges meeting
    at a convex vertex, whose other ends are beyond it; else (−1, −1)."""
    e1 = -1
    e2 = -1
    for t in range(nlist.shape[0]):
        e = nlist[t]
        if _dist_seg_box(edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3],
                         x0, y0, x1, y1) <= reach:
            if e1 < 0:
                e1 = e
            elif e2 < 0:
                e2 = e
            else:
                return -1, -1
    if e2 < 0:
        return -1, -1
    if prev_[e1] == e2:
        e_in, e_out = e2, e1
    elif prev_[e2] == e1:
        e_in, e_out = e1, e2
    else:
        return -1, -1
    dix = edges[e_in, 2] - edges[e_in, 0]
    diy = edges[e_in, 3] - edges[e_in, 1]
    dox = edges[e_out, 2] - edges[e_out, 0]
    doy = edges[e_out, 3] - edges[e_out, 1]
    if dix * doy - diy * dox <= 0.0:
        return -1, -1  # reflex or straight: no wedge
    for k in range(2):
        px = edges[e_in, 0] if k == 0 else edges[e_out, 2]
        py = edges[e_in, 1] if k == 0 else edges[e_out, 3]
        dx = max(x0 - px, 0.0, px - x1)
        dy = max(y0 - py, 0.0, py - y1)
        if math.sqrt(dx * dx + dy * dy) <= reach:
            return -1, -1
    return e_in, e_out


@nb.njit(cache=True, inline="always")
def _min_support(alpha, theta, hw, a, b):  # pragma: no cover - numba
    """min over |θ' − θ| ≤ hw of the support of R(θ')·diag(a, b)·D in direction alpha."""
    lo = alpha - theta - hw
    hi = alpha - theta + hw
    if hi - lo >= math.pi:
        c2 = 0.0
    else:
        j = math.ceil((lo - 0.5 * math.pi) / math.pi)
        if 0.5 * math.pi + j * math.pi <= hi:
            c2 = 0.0
        else:
            c2 = min(math.cos(lo) ** 2, math.cos(hi) ** 2)
    return math.sqrt(b * b + (a * a - b * b) * c2) * (1.0 - 1e-12)


@nb.njit(cache=True)
def _seg_seg_dist(ax, ay, bx, by, cx, cy, dx, dy):  # pragma: no cover - numba
    o1 = _orient(ax, ay, bx, by, cx, cy)
    o2 = _orient(ax, ay, bx, by, dx, dy)
    o3 = _orient(cx, cy, dx, dy, ax, ay)
    o4 = _orient(cx, cy, dx, dy, bx, by)
    if ((o1 > 0.0) != (o2 > 0.0)) and ((o3 > 0.0) != (o4 > 0.0)):
        return 0.0
    return min(_dist_point_segment(ax, ay, cx, cy, dx, dy),
               _dist_point_segment(bx, by, cx, cy, dx, dy),
               _dist_point_segment(cx, cy, ax, ay, bx, by),
               _dist_point_segment(dx, dy, ax, ay, bx, by))


@nb.njit(cache=True)
def _cone_dist(qx, qy, n, r1x, r1y, r2x, r2y):  # pragma: no cover - numba
    """Distance from the convex polygon (qx, qy)[:n] to the cone {s·r1 + t·r2 : s, t ≥ 0}
    (r2 counter-clockwise from r1 by less than π)."""
    far = 0.0
    for k in range(n):
        if (r1x * qy[k] - r1y * qx[k] >= 0.0) and (qx[k] * r2y - qy[k] * r2x >= 0.0):
            return 0.0
        far = max(far, math.sqrt(qx[k] * qx[k] + qy[k] * qy[k]))
    inside = True
    for k in range(n):
        k2 = (k + 1) % n
        if _orient(qx[k], qy[k], qx[k2], qy[k2], 0.0, 0.0) < 0.0:
            inside = False
    if inside:
        return 0.0
    t = far + 2.0
    l1 = math.sqrt(r1x * r1x + r1y * r1y)
    l2 = math.sqrt(r2x * r2x + r2y * r2y)
    e1x, e1y = r1x / l1 * t, r1y / l1 * t
    e2x, e2y = r2x / l2 * t, r2y / l2 * t
    best = _INF
    for k in range(n):
        k2 = (k + 1) % n
        best = min(best, _seg_seg_dist(qx[k], qy[k], qx[k2], qy[k2], 0.0, 0.0, e1x, e1y),
                   _seg_seg_dist(qx[k], qy[k], qx[k2], qy[k2], 0.0, 0.0, e2x, e2y))
    return best


@nb.njit(cache=True)
def _wedge_lost(edges, e_in, e_out, x0, y0, x1, y1, cells, a, b, delta, start
                ):  # pragma: no cover - numba
    """(lost, k): whether no footprint at any angle of any cell covers a point of the box
    (the wedge model of :func:`settle_band`), and the first cell that may cover it (−1
    when lost). Cells are tried from ``start`` on (the last one that covered a
    neighbouring leaf usually covers this one too)."""
    vx, vy = edges[e_out, 0], edges[e_out, 1]
    dox = edges[e_out, 2] - vx
    doy = edges[e_out, 3] - vy
    lo_ = math.sqrt(dox * dox + doy * doy)
    dox /= lo_
    doy /= lo_
    dix = edges[e_in, 2] - edges[e_in, 0]
    diy = edges[e_in, 3] - edges[e_in, 1]
    li = math.sqrt(dix * dix + diy * diy)
    dix /= li
    diy /= li
    nex, ney = -doy, dox  # inward normal of e_out
    nfx, nfy = -diy, dix  # inward normal of e_in
    al_e = math.atan2(ney, nex)
    al_f = math.atan2(nfy, nfx)
    det = nex * nfy - ney * nfx
    qx = np.empty(4)
    qy = np.empty(4)
    nc = cells.shape[0]
    for kk in range(nc):
        k = (start + kk) % nc
        theta, hw = cells[k, 4], cells[k, 5]
        me = _min_support(al_e, theta, hw, a, b)
        mf = _min_support(al_f, theta, hw, a, b)
        ax = vx + (nfy * me - ney * mf) / det
        ay = vy + (-nfx * me + nex * mf) / det
        m00, m01, m10, m11 = cells[k, 0], cells[k, 1], cells[k, 2], cells[k, 3]
        for c in range(4):
            px = (x0 - delta if c == 0 or c == 3 else x1 + delta) - ax
            py = (y0 - delta if c < 2 else y1 + delta) - ay
            qx[c] = m00 * px + m01 * py
            qy[c] = m10 * px + m11 * py
        r1x = m00 * dox + m01 * doy
        r1y = m10 * dox + m11 * doy
        r2x = -(m00 * dix + m01 * diy)
        r2y = -(m10 * dix + m11 * diy)
        if _cone_dist(qx, qy, 4, r1x, r1y, r2x, r2y) <= 1.0 + 1e-9:
            return False, k
    return True, -1


@nb.njit(cache=True)
def _candidates(plist, quads, quad_edge, caps, elist, px0, py0, h):  # pragma: no cover
    """The pieces that meet the pixel, those on the pixel's own edges first (they are the
    ones that cover a pixel along ∂G), then caps, then the other quads."""
    nq = quads.shape[0]
    sqx = np.empty(4)
    sqy = np.empty(4)
    sqx[0], sqy[0] = px0, py0
    sqx[1], sqy[1] = px0 + h, py0
    sqx[2], sqy[2] = px0 + h, py0 + h
    sqx[3], sqy[3] = px0, py0 + h
    out = np.empty(plist.shape[0], np.int64)
    rank = np.empty(plist.shape[0], np.int64)
    m = 0
    for t in range(plist.shape[0]):
        p = plist[t]
        if p < nq:
            if _disjoint_quad(quads, p, sqx, sqy, 4):
                continue
            own = False
            for k in range(elist.shape[0]):
                if quad_edge[p] == elist[k]:
                    own = True
                    break
            rank[m] = 0 if own else 2
        else:
            if _disjoint_cap(caps, p - nq, sqx, sqy, 4):
                continue
            rank[m] = 1
        out[m] = p
        m += 1
    order = np.argsort(rank[:m], kind="mergesort")
    return out[:m][order]


@nb.njit(cache=True)
def _settle_pixels(pix_i, pix_j, cls, cov, outer, x0, y0, h, edges, prev_, eptr, eidx,
                   nptr, nidx, quads, quad_edge, caps, pptr, pidx, cells, a, b, delta, reach,
                   max_level, tau):  # pragma: no cover - numba
    """Per uncertain pixel: certified upper and lower bounds of λ(p ∩ G \\ S) and the area
    left undecided (module docstring), mm²."""
    n = pix_i.shape[0]
    upper = np.empty(n)
    lower = np.empty(n)
    undecided = np.empty(n)
    estimate = np.empty(n)
    reopen = np.zeros(n)
    nq = quads.shape[0]
    sx = np.empty(4 * (max_level + 2) + 8)
    sy = np.empty_like(sx)
    sz = np.empty_like(sx)
    sl = np.empty(sx.shape[0], np.int64)
    px = np.empty(8)
    py = np.empty(8)
    rx = np.empty(8)
    ry = np.empty(8)
    most = 1
    for u in range(n):
        most = max(most, pptr[u + 1] - pptr[u])
    # candidates per level: a leaf's children only test the pieces that touch the leaf
    cbuf = np.empty((max_level + 2, most), np.int64)
    clen = np.zeros(max_level + 2, np.int64)
    for u in range(n):
        i = pix_i[u]
        j = pix_j[u]
        c = cls[i, j]
        cap_area = cov[i, j] * h * h
        if not outer[i, j]:
            # the raster's outer pass proves no footprint reaches it: all of it is lost
            upper[u] = cap_area
            lower[u] = cap_area
            undecided[u] = 0.0
            estimate[u] = cap_area
            continue
        elist = eidx[eptr[u]:eptr[u + 1]]
        nlist = nidx[nptr[u]:nptr[u + 1]]
        plist = _candidates(pidx[pptr[u]:pptr[u + 1]], quads, quad_edge, caps, elist,
                            x0 + j * h, y0 + i * h, h)
        cbuf[0, :plist.shape[0]] = plist
        clen[0] = plist.shape[0]
        cxp = x0 + (j + 0.5) * h
        cyp = y0 + (i + 0.5) * h
        centre_in = c >= 2
        # a centre on ∂G has no trustworthy parity: every leaf without an edge counts as inside
        centre_ok = True
        for t in range(elist.shape[0]):
            e = elist[t]
            if _dist_point_segment(cxp, cyp, edges[e, 0], edges[e, 1], edges[e, 2],
                                   edges[e, 3]) <= tau:
                centre_ok = False
        up = 0.0
        low = 0.0
        und = 0.0
        est = 0.0
        hint = 0
        sx[0] = x0 + j * h
        sy[0] = y0 + i * h
        sz[0] = h
        sl[0] = 0
        top = 1
        while top > 0:
            top -= 1
            lx, ly, ls, lev = sx[top], sy[top], sz[top], sl[top]
            cand = cbuf[lev, :clen[lev]]
            g = tau
            ne = 0
            one = -1
            two = -1
            for t in range(elist.shape[0]):
                e = elist[t]
                if _seg_meets_box(edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3],
                                  lx - g, ly - g, lx + ls + g, ly + ls + g):
                    ne += 1
                    if ne == 1:
                        one = e
                    elif ne == 2:
                        two = e
                    else:
                        break
            px[0], py[0] = lx, ly
            px[1], py[1] = lx + ls, ly
            px[2], py[2] = lx + ls, ly + ls
            px[3], py[3] = lx, ly + ls
            npts = 4
            base_ok = False
            exact_area = True  # whether ``area`` is λ(leaf ∩ G) (else only ≥ it)
            if ne == 0:
                inside = True
                if c == 3:
                    inside = True
                elif centre_ok:
                    fl = -1
                    for attempt in range(3):
                        fx = 0.5 if attempt == 0 else (0.3141 if attempt == 1 else 0.7183)
                        fy = 0.5 if attempt == 0 else (0.6931 if attempt == 1 else 0.2718)
                        qx = lx + fx * ls
                        qy = ly + fy * ls
                        fl = _parity_flips(edges, elist, cxp, cyp, qx, qy)
                        if fl >= 0:
                            break
                    if fl >= 0:
                        inside = centre_in != (fl % 2 == 1)
                    else:
                        exact_area = False
                else:
                    exact_area = False
                if not inside:
                    continue
                area = ls * ls
            elif ne == 1 or (ne == 2 and (prev_[one] == two or prev_[two] == one)
                             and _convex_pair(edges, prev_, one, two)):
                m = _clip_left(px, py, 4, edges[one, 0], edges[one, 1], edges[one, 2],
                               edges[one, 3], rx, ry)
                if ne == 2 and m >= 3:
                    for k in range(m):
                        px[k] = rx[k]
                        py[k] = ry[k]
                    m = _clip_left(px, py, m, edges[two, 0], edges[two, 1], edges[two, 2],
                                   edges[two, 3], rx, ry)
                if m < 3:
                    continue
                for k in range(m):
                    px[k] = rx[k]
                    py[k] = ry[k]
                npts = m
                area = _area(px, py, npts)
                if area <= 0.0:
                    continue
                base_ok = ne == 1
            else:
                area = ls * ls
                if lev >= max_level:
                    up += area
                    und += area
                    est += 0.5 * area
                    continue
                cbuf[lev + 1, :cand.shape[0]] = cand
                clen[lev + 1] = cand.shape[0]
                for dy in range(2):
                    for dx in range(2):
                        sx[top] = lx + dx * 0.5 * ls
                        sy[top] = ly + dy * 0.5 * ls
                        sz[top] = 0.5 * ls
                        sl[top] = lev + 1
                        top += 1
                continue
            covered = False
            for t in range(cand.shape[0]):
                p = cand[t]
                ok = True
                for k in range(npts):
                    if p < nq:
                        if not _in_quad(quads, p, px[k], py[k], tau,
                                        tau if base_ok else -tau):
                            ok = False
                            break
                    elif not _in_cap(caps, p - nq, px[k], py[k]):
                        ok = False
                        break
                if ok:
                    covered = True
                    break
            if covered:
                continue
            e_in, e_out = _wedge_of(edges, nlist, prev_, lx, ly, lx + ls, ly + ls, reach)
            if e_in >= 0 and exact_area:
                lost, k = _wedge_lost(edges, e_in, e_out, lx, ly, lx + ls, ly + ls, cells, a,
                                      b, delta, hint)
                if lost:
                    up += area
                    low += area
                    est += area
                    continue
                hint = k
            nt = 0
            for t in range(cand.shape[0]):
                p = cand[t]
                if p < nq:
                    if not _disjoint_quad(quads, p, px, py, npts):
                        cbuf[lev + 1, nt] = p
                        nt += 1
                elif not _disjoint_cap(caps, p - nq, px, py, npts):
                    cbuf[lev + 1, nt] = p
                    nt += 1
            clen[lev + 1] = nt
            touching = nt > 0
            if not touching and e_in < 0:
                up += area
                est += area
                reopen[u] += area
                continue
            if lev >= max_level:
                up += area
                und += area
                # no piece of any sampled angle reaches it: the estimate counts it lost
                est += 0.5 * area if touching else area
                reopen[u] += area
                continue
            for dy in range(2):
                for dx in range(2):
                    sx[top] = lx + dx * 0.5 * ls
                    sy[top] = ly + dy * 0.5 * ls
                    sz[top] = 0.5 * ls
                    sl[top] = lev + 1
                    top += 1
        upper[u] = min(up, cap_area)
        lower[u] = min(low, upper[u])
        undecided[u] = min(und, upper[u] - lower[u])
        estimate[u] = min(max(est, lower[u]), upper[u])
    return upper, lower, undecided, estimate, reopen


@nb.njit(cache=True, inline="always")
def _convex_pair(edges, prev_, e1, e2):  # pragma: no cover - numba
    """Whether the adjacent edges e1, e2 meet at a convex vertex (a left turn)."""
    if prev_[e1] == e2:
        e_in, e_out = e2, e1
    else:
        e_in, e_out = e1, e2
    dix = edges[e_in, 2] - edges[e_in, 0]
    diy = edges[e_in, 3] - edges[e_in, 1]
    dox = edges[e_out, 2] - edges[e_out, 0]
    doy = edges[e_out, 3] - edges[e_out, 1]
    return dix * doy - diy * dox > 0.0


def settle_band(region, grid: Grid, cls: np.ndarray, cov: np.ndarray, uncertain: np.ndarray,
                outer: np.ndarray, edges: np.ndarray, prev_: np.ndarray, ptr: np.ndarray,
                idx: np.ndarray, lmats: list[np.ndarray], cells: np.ndarray, a: float,
                b: float, delta: float, *, max_level: int = 6, coarse_angles: int = 24,
                full_levels: int = 4) -> dict[str, float]:
    """Certified bounds and an estimate of λ(G \\ S) over the uncertain pixels.

    Parameters
    ----------
    region
        G.
    grid, cls, cov
        The raster's grid, classification and covered fractions.
    uncertain
        Boolean ``(ny, nx)``: the pixels to settle (cov > 0, not in S_in).
    outer
        Boolean ``(ny, nx)``: the raster's outer S (a pixel outside it is wholly lost).
    edges, prev_
        ∂G's edges (:func:`edges_of`).
    ptr, idx
        Neighbours within 2.02·a (:func:`neighbour_pairs`).
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
    The lower bound (the *wedge model*): a leaf Q whose only edges within 2a are two
    edges e_in, e_out meeting at a convex vertex v, their other ends beyond 2a, sees
    G ∩ B(Q, 2a) = W ∩ B(Q, 2a) with W the wedge at v: the ball B is convex and only
    the two edges enter it, as two chords meeting at v (v in B) or as two disjoint
    chords (v outside), and the part of B left of both is G's. A footprint covering a
    point of Q lies in that ball, so its position t is in the wedge eroded by it:
    n·(t − v) ≥ h_φ(n) for both inward normals n, h_φ the support function of E_φ. For φ in cell k,
    h_φ(n) ≥ m_k(n), the exact minimum over the cell (the support of an ellipse is
    sqrt(b² + (a² − b²)·cos²ψ), smallest where cos²ψ is), so t ∈ A_k + W (apex A_k
    solving n·(A_k − v) = m_k(n)), and E_φ ⊆ E_k ⊕ D(δ) (convex sets whose support
    functions differ by at most δ; δ = (a − b)·half-width, as
    |∂h/∂ψ| = (a² − b²)|sin ψ cos ψ|/h ≤ a − b, attained at cos²ψ = b/(a + b)). So if
    the box Q grown by δ misses A_k + W ⊕ E_k for every cell (in E_k's unit-disk frame:
    its image is farther than 1 from the image cone), no footprint covers Q: λ(Q ∩ G)
    is lost. Q ∩ G is the leaf, R, or the leaf clipped by both wedge edges, all exact.
    """
    scale = float(np.max(np.abs(edges))) if len(edges) else 1.0
    tau = 1e-12 * scale + 1e-9 * grid.h
    step = max(1, math.ceil(len(lmats) / max(coarse_angles, 1)))
    coarse = band_pieces(region, edges, prev_, ptr, idx, lmats[::step], grid, cls)
    args = (grid, cls, cov, outer, edges, prev_, cells, a, b, delta, max_level, tau)
    pix_i, pix_j, up, lo, und, est, reopen = _settle(uncertain, coarse, *args)
    slack = coarse.slack + tau * _bases(coarse)
    count = len(coarse)
    # pixels where pieces of more angles may settle more: leaves no piece covered and none
    # proved lost (not those split at the last level by two edges: a vertex's speck)
    open_ = reopen > 1e-4 * grid.h * grid.h
    if step > 1 and open_.any():
        residual = np.zeros(grid.shape, bool)
        residual[pix_i[open_], pix_j[open_]] = True
        want = _edges_near(residual, edges, grid, 2.02 * max(a, b))
        full = band_pieces(region, edges, prev_, ptr, idx, lmats, grid, cls, want=want)
        args2 = (*args[:-2], min(full_levels, max_level), tau)
        ri, rj, up2, lo2, und2, est2, _ = _settle(residual, full, *args2)
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


def _settle(uncertain: np.ndarray, pieces: BandPieces, grid: Grid, cls: np.ndarray,
            cov: np.ndarray, outer: np.ndarray, edges: np.ndarray, prev_: np.ndarray,
            cells: np.ndarray, a: float, b: float, delta: float, max_level: int, tau: float):
    """One tier of :func:`settle_band`: per-pixel arrays over the ``uncertain`` pixels."""
    pix_i, pix_j = np.nonzero(uncertain)
    index = np.full(grid.shape, -1, np.int64)
    index[pix_i, pix_j] = np.arange(len(pix_i))
    scale = float(np.max(np.abs(edges))) if len(edges) else 1.0
    eps = 1e-6 * grid.h + 1e-12 * scale
    n = len(pix_i)
    eptr, eidx = _csr(_edge_pixels, n, edges, index, grid.x0, grid.y0, grid.h, grid.ny,
                      grid.nx, eps)
    reach = 2.0 * max(a, b) * (1.0 + 1e-9) + tau
    # edges within reach of a pixel's box: grow each edge's pixel test by the reach
    nptr, nidx = _csr(_edge_pixels, n, edges, index, grid.x0, grid.y0, grid.h, grid.ny,
                      grid.nx, reach + eps)
    t = 1 << _TILE
    tiles = np.zeros(((grid.ny + t - 1) // t, (grid.nx + t - 1) // t), np.bool_)
    tiles[pix_i >> _TILE, pix_j >> _TILE] = True
    pptr, pidx = _csr(_bucket, n, pieces.quads, pieces.caps, index, tiles, grid.x0, grid.y0,
                      grid.h, grid.ny, grid.nx)
    upper, lower, und, est, reopen = _settle_pixels(
        pix_i.astype(np.int64), pix_j.astype(np.int64), cls, cov, outer, grid.x0, grid.y0,
        grid.h, edges, prev_, eptr, eidx, nptr, nidx, pieces.quads, pieces.quad_edge,
        pieces.caps, pptr, pidx, np.ascontiguousarray(cells, dtype=float), float(a), float(b),
        float(delta), reach, max_level, tau)
    return pix_i, pix_j, upper, lower, und, est, reopen

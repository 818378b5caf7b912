"""The quadtree of the band settling: per uncertain pixel, certified bounds of its loss.

:func:`settle_pixels` runs, for every uncertain pixel, the quadtree of leaves that
:mod:`printability.mmc._band` describes (its mathematics and guarantees are documented
there): a leaf is cut to leaf ∩ G when at most one edge (or two at a convex vertex) crosses
it, counted built when a certified piece contains it, proved lost by the convex chain model
(:mod:`printability.mmc._band_lower`), or split down to the last level. The kernels take the
records of :mod:`printability.mmc._band_records`.

The leaves' common path (edges met, leaf ∩ G, containment in a candidate) is written out in
one loop rather than in helpers: a helper called per leaf costs about 10 % of the quadtree's
time, and an inlined one as much (its array arguments are reference-counted at each call).
"""

from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from printability.base.kernel_cache import guard as _guard_kernel_caches
from printability.mmc._band_geometry import (
    clip_left,
    disjoint_cap,
    disjoint_quad,
    dist_point_segment,
    in_cap,
    in_quad,
    parity_flips,
    polygon_area,
    seg_meets_box,
)
from printability.mmc._band_lower import MAX_CHAIN, chain_lost, chain_of
from printability.mmc._band_records import ClipBuffers

_guard_kernel_caches()  # the cache check runs before a kernel here loads

__all__ = ["settle_pixels"]


class _Work(NamedTuple):
    """Work arrays of :func:`settle_pixels`, allocated once for all pixels."""

    sx: np.ndarray      # the stack of leaves: corner, side, level
    sy: np.ndarray
    sz: np.ndarray
    sl: np.ndarray
    px: np.ndarray      # leaf ∩ G (convex, ≤ 8 vertices) and a clipping buffer
    py: np.ndarray
    rx: np.ndarray
    ry: np.ndarray
    cbuf: np.ndarray    # candidate pieces per level: a leaf's children test only these
    clen: np.ndarray
    chain: np.ndarray   # the convex chain model's edges
    clip: ClipBuffers


@nb.njit(cache=True)
def _work(max_level, most):  # pragma: no cover - numba
    """The work arrays for leaves down to ``max_level`` and at most ``most`` candidates."""
    sx = np.empty(4 * (max_level + 2) + 8)
    wx = np.empty(MAX_CHAIN + 8)
    return _Work(sx, np.empty_like(sx), np.empty_like(sx), np.empty(sx.shape[0], np.int64),
                 np.empty(8), np.empty(8), np.empty(8), np.empty(8),
                 np.empty((max_level + 2, most), np.int64), np.zeros(max_level + 2, np.int64),
                 np.empty(MAX_CHAIN, np.int64),
                 ClipBuffers(wx, np.empty_like(wx), np.empty_like(wx), np.empty_like(wx)))


@nb.njit(cache=True)
def _candidates(plist, pieces, elist, px0, py0, h):  # pragma: no cover - numba
    """The pieces that meet the pixel, those on the pixel's own edges first (they are the
    ones that cover a pixel along ∂G), then caps, then the other quads."""
    quads, quad_edge, caps = pieces.quads, pieces.quad_edge, pieces.caps
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
            if disjoint_quad(quads, p, sqx, sqy, 4):
                continue
            own = False
            for k in range(elist.shape[0]):
                if quad_edge[p] == elist[k]:
                    own = True
                    break
            rank[m] = 0 if own else 2
        else:
            if disjoint_cap(caps, p - nq, sqx, sqy, 4):
                continue
            rank[m] = 1
        out[m] = p
        m += 1
    order = np.argsort(rank[:m], kind="mergesort")
    return out[:m][order]


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


@nb.njit(cache=True)
def _centre(band, edges, elist, u, tau):  # pragma: no cover - numba
    """The facts of uncertain pixel u its leaves share: (classification, centre inside by
    parity, that parity trustworthy, centre x, centre y)."""
    i = band.pix_i[u]
    j = band.pix_j[u]
    c = band.cls[i, j]
    cxp = band.x0 + (j + 0.5) * band.h
    cyp = band.y0 + (i + 0.5) * band.h
    # a centre on ∂G has no trustworthy parity: every leaf without an edge counts as inside
    centre_ok = True
    for t in range(elist.shape[0]):
        e = elist[t]
        if dist_point_segment(cxp, cyp, edges[e, 0], edges[e, 1], edges[e, 2],
                              edges[e, 3]) <= tau:
            centre_ok = False
    return c, c >= 2, centre_ok, cxp, cyp


@nb.njit(cache=True)
def _leaf_parity(edges, elist, cxp, cyp, lx, ly, ls):  # pragma: no cover - numba
    """Crossings of the segment from the pixel's centre to a point of the leaf (corner lx,
    ly, side ls) with the pixel's edges: up to three points are tried; −1 when every one is
    degenerate."""
    fl = -1
    for attempt in range(3):
        fx = 0.5 if attempt == 0 else (0.3141 if attempt == 1 else 0.7183)
        fy = 0.5 if attempt == 0 else (0.6931 if attempt == 1 else 0.2718)
        qx = lx + fx * ls
        qy = ly + fy * ls
        fl = parity_flips(edges, elist, cxp, cyp, qx, qy)
        if fl >= 0:
            break
    return fl


@nb.njit(cache=True)
def _narrow(cand, quads, caps, px, py, npts, out):  # pragma: no cover - numba
    """The candidates that meet the polygon ``px, py`` (npts), into ``out``; how many."""
    nq = quads.shape[0]
    nt = 0
    for t in range(cand.shape[0]):
        p = cand[t]
        if p < nq:
            if not disjoint_quad(quads, p, px, py, npts):
                out[nt] = p
                nt += 1
        elif not disjoint_cap(caps, p - nq, px, py, npts):
            out[nt] = p
            nt += 1
    return nt


@nb.njit(cache=True)
def _push_children(sx, sy, sz, sl, top, lx, ly, ls, lev):  # pragma: no cover - numba
    """Push the four quarters of the leaf (corner lx, ly, side ls) at level ``lev + 1`` on
    the stack; the new top."""
    for dy in range(2):
        for dx in range(2):
            sx[top] = lx + dx * 0.5 * ls
            sy[top] = ly + dy * 0.5 * ls
            sz[top] = 0.5 * ls
            sl[top] = lev + 1
            top += 1
    return top


@nb.njit(cache=True)
def _settle_pixel(u, band, rings, lists, pieces, model, max_level, tau, work
                  ):  # pragma: no cover - numba
    """The quadtree of uncertain pixel u: (upper, lower, undecided, estimate, reopened)
    areas before clipping to its covered area (its leaves' common path written out here:
    module docstring)."""
    edges, prev_, quads, caps = rings.edges, rings.prev_, pieces.quads, pieces.caps
    sx, sy, sz, sl = work.sx, work.sy, work.sz, work.sl
    px, py, rx, ry = work.px, work.py, work.rx, work.ry
    cbuf, clen, chain = work.cbuf, work.clen, work.chain
    elist = lists.eidx[lists.eptr[u]:lists.eptr[u + 1]]
    nlist = lists.nidx[lists.nptr[u]:lists.nptr[u + 1]]
    c, centre_in, centre_ok, cxp, cyp = _centre(band, edges, elist, u, tau)
    h = band.h
    sx[0], sy[0], sz[0], sl[0] = band.x0 + band.pix_j[u] * h, band.y0 + band.pix_i[u] * h, h, 0
    plist = _candidates(lists.pidx[lists.pptr[u]:lists.pptr[u + 1]], pieces, elist, sx[0],
                        sy[0], h)
    cbuf[0, :plist.shape[0]] = plist
    clen[0] = plist.shape[0]
    up = low = und = est = reo = 0.0
    hint, top = 0, 1
    nq = quads.shape[0]
    while top > 0:
        top -= 1
        lx, ly, ls, lev = sx[top], sy[top], sz[top], sl[top]
        cand = cbuf[lev, :clen[lev]]
        ne, one, two = 0, -1, -1
        for t in range(elist.shape[0]):
            e = elist[t]
            if seg_meets_box(edges[e, 0], edges[e, 1], edges[e, 2], edges[e, 3],
                             lx - tau, ly - tau, lx + ls + tau, ly + ls + tau):
                ne += 1
                if ne == 1:
                    one = e
                elif ne == 2:
                    two = e
                else:
                    break
        px[0], py[0], px[1], py[1] = lx, ly, lx + ls, ly
        px[2], py[2], px[3], py[3] = lx + ls, ly + ls, lx, ly + ls
        npts, base_ok, exact_area = 4, False, True  # exact: area = λ(leaf ∩ G), else ≥
        if ne == 0:
            inside = True
            if c != 3:
                fl = _leaf_parity(edges, elist, cxp, cyp, lx, ly, ls) if centre_ok else -1
                if fl >= 0:
                    inside = centre_in != (fl % 2 == 1)
                else:
                    exact_area = False
            if not inside:
                continue
            area = ls * ls
        elif ne == 1 or (ne == 2 and (prev_[one] == two or prev_[two] == one)
                         and _convex_pair(edges, prev_, one, two)):
            m = clip_left(px, py, 4, edges[one, 0], edges[one, 1], edges[one, 2],
                          edges[one, 3], rx, ry)
            if ne == 2 and m >= 3:
                for k in range(m):
                    px[k], py[k] = rx[k], ry[k]
                m = clip_left(px, py, m, edges[two, 0], edges[two, 1], edges[two, 2],
                              edges[two, 3], rx, ry)
            if m < 3:
                continue
            for k in range(m):
                px[k], py[k] = rx[k], ry[k]
            npts = m
            area = polygon_area(px, py, npts)
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
            top = _push_children(sx, sy, sz, sl, top, lx, ly, ls, lev)
            continue
        covered = False
        for t in range(cand.shape[0]):
            p = cand[t]
            ok = True
            for k in range(npts):
                if p < nq:
                    if not in_quad(quads, p, px[k], py[k], tau, tau if base_ok else -tau):
                        ok = False
                        break
                elif not in_cap(caps, p - nq, px[k], py[k]):
                    ok = False
                    break
            if ok:
                covered = True
                break
        if covered:
            continue
        box = (lx, ly, lx + ls, ly + ls)
        nch = chain_of(rings, nlist, box, model.reach, chain)
        if nch > 0 and exact_area:
            lost, k = chain_lost(edges, chain, nch, box, model, hint, work.clip)
            if lost:
                up += area
                low += area
                est += area
                continue
            hint = k
        nt = _narrow(cand, quads, caps, px, py, npts, cbuf[lev + 1])
        clen[lev + 1] = nt
        if (nt == 0 and nch == 0) or lev >= max_level:
            # lost when no piece reaches it and no chain bounds it; else undecided at the
            # last level (the estimate counts it lost when no piece of any angle reaches it)
            up += area
            und += 0.0 if nt == 0 and nch == 0 else area
            est += area if nt == 0 else 0.5 * area
            reo += area
            continue
        top = _push_children(sx, sy, sz, sl, top, lx, ly, ls, lev)
    return up, low, und, est, reo


@nb.njit(cache=True)
def settle_pixels(band, rings, lists, pieces, model, max_level, tau):  # pragma: no cover
    """Per uncertain pixel: certified upper and lower bounds of λ(p ∩ G \\ S), the area left
    undecided, the estimate and the area reopened for the second tier, mm².

    Parameters
    ----------
    band, rings, lists, pieces, model
        The records of :mod:`printability.mmc._band_records`: :class:`BandPixels`,
        :class:`Rings`, :class:`PixelLists`, :class:`PieceArrays`, :class:`ChainModel`.
    max_level
        Leaves down to h / 2^max_level.
    tau
        The tolerance of the edge and containment tests, mm.
    """
    n = band.pix_i.shape[0]
    upper = np.empty(n)
    lower = np.empty(n)
    undecided = np.empty(n)
    estimate = np.empty(n)
    reopen = np.zeros(n)
    most = 1
    for u in range(n):
        most = max(most, lists.pptr[u + 1] - lists.pptr[u])
    work = _work(max_level, most)
    for u in range(n):
        i = band.pix_i[u]
        j = band.pix_j[u]
        cap_area = band.cov[i, j] * band.h * band.h
        if not band.outer[i, j]:
            # the raster's outer pass proves no footprint reaches it: all of it is lost
            upper[u] = cap_area
            lower[u] = cap_area
            undecided[u] = 0.0
            estimate[u] = cap_area
            continue
        up, low, und, est, reo = _settle_pixel(u, band, rings, lists, pieces, model,
                                               max_level, tau, work)
        reopen[u] = reo
        upper[u] = min(up, cap_area)
        lower[u] = min(low, upper[u])
        undecided[u] = min(und, upper[u] - lower[u])
        estimate[u] = min(max(est, lower[u]), upper[u])
    return upper, lower, undecided, estimate, reopen
